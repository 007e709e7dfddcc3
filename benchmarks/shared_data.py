"""Where the benchmarks find the project's reference data (never copied into the repository):
``$GNSS_CITYGML_SHARED_DATA``, by default ``../shared/data`` beside the repository."""

import os
from pathlib import Path

SHARED_DATA = Path(
    os.environ.get(
        "GNSS_CITYGML_SHARED_DATA", Path(__file__).resolve().parents[2] / "shared" / "data"
    )
)
GRIDS = SHARED_DATA / "geodesy"

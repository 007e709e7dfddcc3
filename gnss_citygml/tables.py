"""Reading and writing the toolkit's tables (CSV or Parquet).

Outputs are written to a temporary file in the target folder and renamed into place only when
complete, so a failed run never leaves a half-written file behind."""

from __future__ import annotations

import contextlib
import os
import tempfile
from pathlib import Path

import numpy as np
import pandas as pd

from .errors import InputError
from .paths import input_file

__all__ = ["atomic_path", "read_table", "write_layer", "write_table"]


@contextlib.contextmanager
def atomic_path(path, *, overwrite: bool = True):
    """Yield a temporary path beside ``path``; rename it to ``path`` if the block succeeds."""
    path = Path(path)
    if path.exists() and not overwrite:
        raise InputError("output exists", where=str(path), fix="choose another name or --overwrite")
    folder = path.parent if str(path.parent) else Path(".")
    if not folder.is_dir():
        raise InputError("output folder does not exist", where=str(folder), fix="create it first")
    try:
        # the temporary name keeps the suffix: drivers (GDAL's GeoPackage) check it
        fd, tmp = tempfile.mkstemp(
            prefix=f".{path.name}.", suffix=f".part{path.suffix}", dir=folder
        )
    except OSError as exc:
        raise InputError(
            "cannot write to the output folder",
            where=str(folder),
            fix=f"check its permissions ({exc.strerror})",
        ) from None
    os.close(fd)
    try:
        yield Path(tmp)
        os.chmod(tmp, 0o666 & ~_umask())  # mkstemp makes it private; a new file is not
        os.replace(tmp, path)
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def read_table(path) -> pd.DataFrame:
    """Read a CSV or Parquet table, with a one-line error for a missing or unreadable file."""
    path = input_file(path)
    suffix = _suffix(path)
    try:
        return pd.read_csv(path) if suffix == ".csv" else pd.read_parquet(path)
    except (ValueError, OSError, pd.errors.ParserError) as exc:
        first = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        raise InputError(
            f"cannot read the table: {first}",
            where=str(path),
            fix="give a well-formed CSV (with a header row) or Parquet file",
        ) from None


def _suffix(path: Path) -> str:
    suffix = path.suffix.lower()
    if suffix not in (".csv", ".parquet"):
        raise InputError(
            f"unknown table format {suffix or '(none)'!r}",
            where=str(path),
            fix="name the file .csv or .parquet",
        )
    return suffix


def write_table(table: pd.DataFrame, path, *, overwrite: bool = True) -> None:
    """Write a table as CSV or Parquet (by the file's suffix), atomically."""
    suffix = _suffix(Path(path))
    with atomic_path(path, overwrite=overwrite) as tmp:
        if suffix == ".csv":
            table.to_csv(tmp, index=False)
        else:
            table.to_parquet(tmp, index=False)


def write_layer(frame, path, layer: str, *, overwrite: bool = True) -> None:
    """Write a GeoDataFrame as a new GeoPackage holding one ``layer``, atomically.

    List-valued attributes (OS MasterMap's ``descriptiveGroup``, read by GDAL as lists) are
    written as text joined by ``|``, which every GIS reads."""
    out = frame.copy()
    for column in out.columns.drop(out.geometry.name):
        if out[column].map(lambda v: isinstance(v, list | tuple | np.ndarray)).any():
            out[column] = out[column].map(
                lambda v: "|".join(map(str, v)) if isinstance(v, list | tuple | np.ndarray) else v
            )
    with atomic_path(path, overwrite=overwrite) as tmp:
        out.to_file(tmp, layer=layer, driver="GPKG")

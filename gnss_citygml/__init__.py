"""gnss-citygml: 3D city maps (CityGML LOD1 / CityJSON) from crowdsourced smartphone GNSS data.

The public API is re-exported here; see DESIGN.md for the tables that pass between stages.
"""

from .errors import GnssCityGMLError, InputError, MissingColumnError, ModelError
from .model import HEIGHTS_COLUMNS, METHODS, SignalClassifier, estimate_heights

__version__ = "0.1.0"

__all__ = [
    "HEIGHTS_COLUMNS",
    "METHODS",
    "GnssCityGMLError",
    "InputError",
    "MissingColumnError",
    "ModelError",
    "SignalClassifier",
    "__version__",
    "estimate_heights",
]

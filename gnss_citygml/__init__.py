"""gnss-citygml: 3D city maps (CityGML LOD1 / CityJSON) from crowdsourced smartphone GNSS data.

The public API is re-exported here; see DESIGN.md for the tables that pass between stages.
Stages with heavy dependencies (GDAL, PROJ) are imported on first use, so that
``import gnss_citygml`` and the command line start fast.
"""

from importlib import import_module

from .errors import GnssCityGMLError, InputError, MissingColumnError, ModelError
from .model import HEIGHTS_COLUMNS, METHODS, SignalClassifier, estimate_heights

__version__ = "0.1.0"

#: Public names defined in submodules that are imported when first asked for.
_LAZY = {
    "check_observations": "observations",
    "read_observations": "observations",
    "write_observations": "observations",
    "to_osgb": "geodesy",
    "from_osgb": "geodesy",
    "grid_bearing": "geodesy",
    "meridian_convergence": "geodesy",
    "GridError": "geodesy",
    "OutsideExtentError": "geodesy",
    "read_footprints": "footprints",
    "building_ground": "terrain",
    "sample_ground": "terrain",
    "observe": "gnss.observe",
    "read_gnsslogger": "gnss.gnsslogger",
    "load_orbits": "gnss.orbits",
}

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
    *_LAZY,
]


def __getattr__(name):
    if name in _LAZY:
        value = getattr(import_module(f".{_LAZY[name]}", __name__), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")

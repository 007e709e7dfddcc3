"""gnss-citygml: 3D city maps (CityGML LOD1 / CityJSON) from crowdsourced smartphone GNSS data.

The public API is the job, with GeoDataFrames in and out; see DESIGN.md for the tables that
pass between the stages. Every name but the errors is imported from its module when first
asked for (:data:`_LAZY`), so that ``import gnss_citygml`` and the command line start without
loading numpy, pandas, scipy, GDAL or PROJ.

- :func:`read_observations` and :func:`read_footprints` read the inputs (footprints leave in
  EPSG:27700, converted with OSTN15 from ETRS89 or WGS 84);
- :func:`estimate` runs the pipeline: observations + footprints + DEM -> one row per footprint
  with its height (:func:`estimate_heights` is the height model alone, on intersections);
- :func:`write_cityjson`, :func:`write_cityjsonseq` and :func:`write_citygml` write that
  GeoDataFrame as an LOD1 city model, validated before it is renamed into place, and
  :func:`write_3dtiles` as 3D Tiles for web viewers;
- :func:`validate_file` checks a CityGML or CityJSON file;
- :class:`Rays`, :class:`ReceiverHeights`, :class:`Estimator` (with :class:`Acceptance`),
  :class:`PositionError`, :class:`Calibration` and :class:`Tiling` are the options of
  :func:`estimate` (one :class:`RunSettings`, or each by name) and :func:`estimate_heights`,
  with their defaults (:mod:`gnss_citygml.settings`).

>>> import gnss_citygml
>>> gnss_citygml.METHODS
('4PL-B', '4PL', 'hinge', 'bayes')
>>> str(gnss_citygml.InputError("no DEM", where="estimate", fix="give one"))
'no DEM (estimate): give one'
"""

from __future__ import annotations

from importlib import import_module
from typing import TYPE_CHECKING

from .errors import GnssCityGMLError, InputError, MissingColumnError, ModelError

#: Public names defined in submodules, imported from them when first asked for.
_LAZY = {
    # the job
    "estimate": "pipeline",
    "estimate_heights": "model.estimate",
    "heights_and_signal_model": "model.estimate",
    "read_observations": "observations",
    "read_footprints": "footprints",
    "write_cityjson": "export.cityjson",
    "write_cityjsonseq": "export.cityjson",
    "write_citygml": "export.citygml",
    "write_3dtiles": "export.tiles3d",
    "validate_file": "validate",
    # the stages and tables
    "HEIGHTS_COLUMNS": "model.estimate",
    "METHODS": "model",
    "SignalClassifier": "model.classifier",
    "check_observations": "observations",
    "write_observations": "observations",
    "to_osgb": "geodesy",
    "from_osgb": "geodesy",
    "grid_bearing": "geodesy",
    "meridian_convergence": "geodesy",
    "building_ground": "terrain",
    "sample_ground": "terrain",
    "observe": "gnss.observe",
    "read_gnsslogger": "gnss.gnsslogger",
    "load_orbits": "gnss.orbits",
    # the options (frozen dataclasses with their defaults)
    "Rays": "settings",
    "ReceiverHeights": "settings",
    "Estimator": "settings",
    "Acceptance": "settings",
    "PositionError": "settings",
    "Calibration": "settings",
    "Tiling": "settings",
    "RunSettings": "settings",
    # the errors of the geodesy
    "GridError": "geodesy.grids",
    "OutsideExtentError": "geodesy",
}

if TYPE_CHECKING:  # the same names, for type checkers (tests/test_package.py compares them)
    from .export.citygml import write_citygml
    from .export.cityjson import write_cityjson, write_cityjsonseq
    from .export.tiles3d import write_3dtiles
    from .footprints import read_footprints
    from .geodesy import (
        OutsideExtentError,
        from_osgb,
        grid_bearing,
        meridian_convergence,
        to_osgb,
    )
    from .geodesy.grids import GridError
    from .gnss.gnsslogger import read_gnsslogger
    from .gnss.observe import observe
    from .gnss.orbits import load_orbits
    from .model import METHODS
    from .model.classifier import SignalClassifier
    from .model.estimate import HEIGHTS_COLUMNS, estimate_heights, heights_and_signal_model
    from .observations import check_observations, read_observations, write_observations
    from .pipeline import estimate
    from .settings import (
        Acceptance,
        Calibration,
        Estimator,
        PositionError,
        Rays,
        ReceiverHeights,
        RunSettings,
        Tiling,
    )
    from .terrain import building_ground, sample_ground
    from .validate import validate_file

    __version__: str

__all__ = [
    # the job
    "estimate",
    "estimate_heights",
    "heights_and_signal_model",
    "read_observations",
    "read_footprints",
    "write_cityjson",
    "write_cityjsonseq",
    "write_citygml",
    "write_3dtiles",
    "validate_file",
    # the stages and tables
    "HEIGHTS_COLUMNS",
    "METHODS",
    "SignalClassifier",
    "check_observations",
    "write_observations",
    "to_osgb",
    "from_osgb",
    "grid_bearing",
    "meridian_convergence",
    "building_ground",
    "sample_ground",
    "observe",
    "read_gnsslogger",
    "load_orbits",
    # the options
    "Rays",
    "ReceiverHeights",
    "Estimator",
    "Acceptance",
    "PositionError",
    "Calibration",
    "Tiling",
    "RunSettings",
    # the errors
    "GnssCityGMLError",
    "InputError",
    "MissingColumnError",
    "ModelError",
    "GridError",
    "OutsideExtentError",
    "__version__",
]


def __getattr__(name: str):
    """The lazily imported names of :data:`_LAZY`, and ``__version__`` from the metadata."""
    if name == "__version__":
        from importlib.metadata import version

        value = version("gnss-citygml")
    elif name in _LAZY:
        value = getattr(import_module(f".{_LAZY[name]}", __name__), name)
    else:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(__all__))

"""3D city models from the buildings table: CityJSON 2.0, CityJSONSeq and CityGML 2.0 LOD1, and
3D Tiles 1.1 for web viewers (:func:`write_3dtiles`).

Each writer checks the table (:func:`prepare_buildings`), skips and lists the buildings without
a usable height, extrudes the footprints into LOD1 solids (:func:`extrude`), writes a temporary
file beside the output, validates it (:func:`gnss_citygml.validate.validate_file`) and only then
renames it into place.
"""

from .citygml import gml_ids, write_citygml
from .cityjson import write_cityjson, write_cityjsonseq
from .heights import buildings_with_heights, footprints_with_heights
from .output import ExportResult, InvalidOutputError
from .plan import prepare_buildings
from .prisms import Prisms, extrude, snap_footprints
from .tiles3d import write_3dtiles

__all__ = [
    "ExportResult",
    "InvalidOutputError",
    "Prisms",
    "buildings_with_heights",
    "extrude",
    "footprints_with_heights",
    "gml_ids",
    "prepare_buildings",
    "snap_footprints",
    "write_3dtiles",
    "write_citygml",
    "write_cityjson",
    "write_cityjsonseq",
]

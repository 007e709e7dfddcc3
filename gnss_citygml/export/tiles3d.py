"""3D Tiles 1.1 of the LOD1 buildings, for CesiumJS, deck.gl, QGIS 3.34+ and city portals.

``write_3dtiles(buildings, "city/tileset.json")`` writes the folder ``city``::

    city/tileset.json            the tileset: OS grid squares of 100 km, 10 km and 1 km
    city/tiles/TQ2982.glb        the buildings of 1 km square TQ2982 (glTF 2.0, binary)
    city/viewer.html             CesiumJS on the tileset (serve the folder over HTTP)

Each 1 km square's buildings are one mesh (:mod:`.meshes`: placed on the Earth through
OSTN15/OSGM15) relative to the square's centre (the tile's ``transform``: float32 positions
then keep a tenth of a millimetre), each building one feature (``EXT_mesh_features``) with its
row of a property table (``EXT_structural_metadata``): id, height (m ODN), ground, measured
height, and, when the table has them, the interval (``height_lower``, ``height_upper``),
``status``, ``n_signals``, ``method`` and ``height_source``; the measured height (roof above
ground) and ``part`` are the tool's own (an input column of either name is left out, with a
warning). With ``ranges``, a second, translucent prism from ``height_lower`` to
``height_upper`` shows each height's uncertainty; a range no building can have (a bound
missing or infinite, more than 400 m tall or from the ground) is not drawn, with a warning.

The squares are written one at a time (:meth:`~gnss_citygml.export.plan.Plan.chunks` of their
rows), so memory holds one square's buildings besides the table. The folder appears whole
or not at all (:func:`~gnss_citygml.files.folders.atomic_folder`).
"""

from __future__ import annotations

import json
import warnings
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import geopandas as gpd
import numpy as np
import pandas as pd
import shapely

from ..errors import InputError, listing
from ..files.folders import atomic_folder
from ..files.paths import StrPath
from ..files.provenance import KEY
from ..geodesy.grid_refs import tile_index, tile_names
from ..validate import Report
from .glb import ELEMENT_ARRAY_BUFFER, Glb
from .meshes import Mesh, prism_mesh
from .output import ExportResult, Progress, check_title, checked
from .plan import MAX_HEIGHT_ABOVE_GROUND, Plan, prepare_buildings

__all__ = ["TILESET", "write_3dtiles"]

#: The tileset's file, in the folder written.
TILESET = "tileset.json"
#: The squares of the tileset's levels (m), largest first: the last holds the buildings.
LEVELS = (100_000.0, 10_000.0, 1_000.0)
#: A square's geometric error (m) per metre of its side: a viewer (16 px of screen-space
#: error) opens a 1 km square's buildings from about 3 km away.
ERROR_PER_SIDE = 0.05
#: The buildings' colour and the ranges' (RGBA, linear).
BUILDING_COLOUR = [0.8, 0.8, 0.78, 1.0]
RANGE_COLOUR = [0.9, 0.35, 0.1, 0.35]
#: What stands for a missing number in the property table (3D Metadata's ``noData``).
NO_DATA = {"FLOAT64": -9999.0, "UINT32": 4_294_967_295}
#: The property table's columns besides id and height, when the table has them, with their
#: metadata types.
OPTIONAL = {
    "ground": "FLOAT64",
    "height_lower": "FLOAT64",
    "height_upper": "FLOAT64",
    "n_signals": "UINT32",
    "status": "STRING",
    "method": "STRING",
    "height_source": "STRING",
}
#: The tiles' own properties, made by the tool (an input column of that name is left out).
OWN = {
    "measured_height": "the roof's height above the ground, height - ground",
    "part": "building or range",
}


def write_3dtiles(
    buildings: gpd.GeoDataFrame,
    path: StrPath,
    *,
    validate: bool = True,
    schema_dir: StrPath | None = None,
    overwrite: bool = False,
    strict: bool = False,
    ranges: bool = False,
    grid_dir: StrPath | None = None,
    title: str | None = None,
    provenance: dict | None = None,
    progress: Progress | None = None,
) -> ExportResult:
    """Write the buildings (as :func:`~gnss_citygml.export.cityjson.write_cityjson` takes
    them) as a 3D Tiles 1.1 tileset: ``path`` is the tileset's ``tileset.json`` in a folder of
    its own, written whole (``overwrite`` replaces only a tileset this toolkit wrote, and keeps
    the files of the user's in its folder). ``ranges`` adds each height's interval as a
    translucent prism; ``grid_dir`` is where the OSTN15 and OSGM15 grids are (default: as
    :func:`gnss_citygml.geodesy.from_osgb` finds them);
    ``title`` and ``provenance`` (:func:`gnss_citygml.files.provenance.provenance`) go in the
    tileset's ``asset.extras``.

    With ``validate``, the tileset is checked before the folder is renamed into place
    (:func:`gnss_citygml.validate.tiles3d.validate_tileset`: the 3D Tiles 1.1 JSON schemas in
    ``schema_dir`` or its ``3dtiles-1.1`` folder, else those bundled with the package; every
    GLB by the package's own checks, and by Khronos' glTF validator when node is found; the
    metadata extensions; the report's notes say which ran); an invalid tileset raises
    :class:`~gnss_citygml.export.output.InvalidOutputError` and is not kept, and a schema
    folder named that is not there is an :class:`InputError`."""
    path = Path(path)
    if path.name != TILESET:
        raise InputError(
            f"a 3D Tiles output is a folder's {TILESET}",
            where=str(path),
            fix=f"give -o FOLDER/{TILESET} (the folder is written whole)",
        )
    check_title(title)
    plan = prepare_buildings(buildings, strict=strict)
    _warn_shadowed(buildings)
    _check_numbers(plan)
    squares = _squares(plan)
    leaves, refused = [], []
    with atomic_folder(path.parent, overwrite=overwrite, mark=TILESET) as work:
        (work / "tiles").mkdir()
        for name, rows in squares:
            frame = _frame(plan, rows)
            if frame is None:
                continue
            leaf, not_drawn = _write_square(work, name, frame, ranges, grid_dir)
            leaves.append(leaf)
            refused += not_drawn
            if progress is not None:
                progress(len(frame))
        if not leaves:
            plan.result(path, None)  # raises: nothing to write
        tileset = _tileset(leaves)
        extras = {"title": title, KEY: provenance}
        extras = {k: v for k, v in extras.items() if v is not None}
        if extras:
            tileset["asset"]["extras"] = extras
        (work / TILESET).write_text(json.dumps(tileset, indent=1, allow_nan=False))
        (work / "viewer.html").write_text(_viewer())
        report = _validated(work, path, schema_dir) if validate else None
    if refused:
        warnings.warn(
            f"{len(refused)} building(s)' height range not drawn: {listing(refused)} (a bound "
            "missing or not finite, the upper not above the lower, or more than "
            f"{MAX_HEIGHT_ABOVE_GROUND:.0f} m from the ground or tall: no structure in Great "
            "Britain is; the tiles' properties keep their height_lower and height_upper, a "
            "value that is not finite as no data)",
            stacklevel=2,
        )
    return plan.result(path, report)


def _warn_shadowed(buildings: pd.DataFrame) -> None:
    """Warn of input columns named like the tiles' own properties (:data:`OWN`), which are
    left out: the tool's win."""
    for column in OWN:
        if column in buildings.columns:
            warnings.warn(
                f"the input's column {column} is left out of the tiles: their {column} is "
                f"the tool's ({OWN[column]}); rename the column to keep it elsewhere",
                stacklevel=3,
            )


def _validated(work: Path, path: Path, schema_dir: StrPath | None) -> Report:
    """The report of the tileset written in ``work`` (to be ``path``); raise if invalid."""
    from ..validate.tiles3d import validate_tileset

    try:
        report = validate_tileset(work / TILESET, schema_dir=schema_dir)
    except InputError as err:
        raise InputError(
            f"cannot validate the tileset: {err.what}",
            where=err.where,
            fix=f"{err.fix}; or write it without validating (--no-validate)",
        ) from None
    return checked(report, path, "tileset")


def _squares(plan: Plan) -> Iterator[tuple[str, np.ndarray]]:
    """The 1 km squares holding the buildings to write (their bounds' centre), in name order,
    with their rows (positions in the plan's table)."""
    bounds = shapely.bounds(plan.frame.geometry.to_numpy()[plan.rows])
    ix, iy = tile_index((bounds[:, 0] + bounds[:, 2]) / 2, (bounds[:, 1] + bounds[:, 3]) / 2)
    names = tile_names(ix, iy, LEVELS[-1]) if len(ix) else np.empty(0, dtype=object)
    groups = pd.Series(plan.rows).groupby(names, sort=True)
    for name, rows in groups:
        yield str(name), rows.to_numpy()


def _check_numbers(plan: Plan) -> None:
    """Refuse a numeric property of a building to write that its type cannot hold, rather
    than write another number: text, or a count (``UINT32``) below 0, not whole, infinite or
    not below the no-data value (-5 would be 4294967291, 2.5 would be 2)."""
    for column, kind in OPTIONAL.items():
        if kind == "STRING" or column not in plan.frame.columns:
            continue
        values = plan.frame[column].iloc[plan.rows]
        numbers = pd.to_numeric(values, errors="coerce").to_numpy(dtype=float, na_value=np.nan)
        bad = np.isnan(numbers) & values.notna().to_numpy()
        what = "a number"
        if kind == "UINT32":
            with np.errstate(invalid="ignore"):
                bad |= np.isinf(numbers) | (numbers % 1 != 0) & np.isfinite(numbers)
                bad |= (numbers < 0) | (numbers >= NO_DATA[kind])
            what = f"a whole number, 0 or more and below {NO_DATA[kind]}"
        if bad.any():
            ids = plan.frame["id"].iloc[plan.rows][bad].astype(str).tolist()
            raise InputError(
                f"column {column!r} is not {what} (buildings {listing(ids)})",
                where="buildings",
                fix=f"give {column} so, or drop the column",
            )


def _frame(plan: Plan, rows: np.ndarray) -> gpd.GeoDataFrame | None:
    """The buildings of one square, snapped (None if none is left)."""
    frames = list(plan.chunks(subset=rows))
    return pd.concat(frames, ignore_index=True) if frames else None


def _write_square(
    work: Path, name: str, frame, ranges: bool, grid_dir
) -> tuple[dict[str, Any], list[str]]:
    """Write one square's GLB; return its leaf of the tileset and the buildings whose range
    was not drawn (:func:`_band`)."""
    footprints = frame.geometry.to_numpy()
    mesh = prism_mesh(
        footprints, frame["ground"].to_numpy(float), frame["height"].to_numpy(float), grid_dir
    )
    centre = (mesh.ecef.min(axis=0) + mesh.ecef.max(axis=0)) / 2
    glb = Glb()
    band, known, refused = _band(frame, footprints, grid_dir) if ranges else (None, [], [])
    table = _property_table(glb, frame, known)
    building = _material(glb, BUILDING_COLOUR)
    primitives = [_primitive(glb, mesh, centre, len(frame), building)]
    lon, lat, h = [mesh.lon], [mesh.lat], [mesh.h]
    if band is not None:
        primitives.append(_primitive(glb, band, centre, len(known), _material(glb, RANGE_COLOUR)))
        lon, lat, h = lon + [band.lon], lat + [band.lat], h + [band.h]
    glb.gltf.update(
        scene=0,
        scenes=[{"nodes": [0]}],
        nodes=[{"mesh": 0, "name": name}],
        meshes=[{"name": name, "primitives": primitives}],
    )
    glb.extension("EXT_structural_metadata", table)
    glb.extension("EXT_mesh_features")
    (work / "tiles" / f"{name}.glb").write_bytes(glb.to_bytes())
    lon, lat, h = np.concatenate(lon), np.concatenate(lat), np.concatenate(h)
    region = [lon.min(), lat.min(), lon.max(), lat.max(), h.min(), h.max()]
    leaf = {
        "name": name,
        "region": [float(v) for v in region],
        "transform": [1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, *map(float, centre), 1],
    }
    return leaf, refused


def _band(
    frame: pd.DataFrame, footprints: np.ndarray, grid_dir
) -> tuple[Mesh | None, Any, list[str]]:
    """The prisms from each building's ``height_lower`` to its ``height_upper``, their
    features numbered after the buildings' (:func:`_property_table`), the rows of the
    buildings with an interval drawn (None and none if no building has one), and the
    buildings with an interval no building can have, not drawn (``id (lower to upper m)``):
    a bound missing or not finite, the upper not above the lower, or more than
    :data:`~.plan.MAX_HEIGHT_ABOVE_GROUND` tall or from the ground."""
    missing = pd.Series(np.nan, index=frame.index)
    lower, upper = (frame.get(c, missing).to_numpy(float) for c in ("height_lower", "height_upper"))
    ground, most = frame["ground"].to_numpy(float), MAX_HEIGHT_ABOVE_GROUND
    with np.errstate(invalid="ignore"):
        drawn = np.isfinite(lower) & np.isfinite(upper) & (upper > lower)
        drawn &= (upper - lower <= most) & (upper <= ground + most) & (lower >= ground - most)
    refused = [
        f"{frame['id'].iloc[i]} ({lower[i]:g} to {upper[i]:g} m)"
        for i in np.flatnonzero(~drawn & ~(np.isnan(lower) & np.isnan(upper)))
    ]
    known = np.flatnonzero(drawn)
    if not known.size:
        return None, known, refused
    mesh = prism_mesh(footprints[known], lower[known], upper[known], grid_dir)
    return _renumbered(mesh, len(frame) + np.arange(known.size)), known, refused


def _renumbered(mesh: Mesh, rows: np.ndarray) -> Mesh:
    """``mesh`` whose features are ``rows`` of the square's table."""
    return Mesh(
        mesh.ecef, mesh.normals, rows[mesh.feature], mesh.indices, mesh.lon, mesh.lat, mesh.h
    )


def _primitive(
    glb: Glb, mesh: Mesh, centre: np.ndarray, count: int, material: int
) -> dict[str, Any]:
    """A triangle primitive of ``mesh``, its positions about ``centre`` turned glTF's y axis
    up (x, z, -y: 3D Tiles turns it back), each vertex's feature the building's row."""
    local = mesh.ecef - centre
    position = np.column_stack([local[:, 0], local[:, 2], -local[:, 1]]).astype(np.float32)
    normal = np.column_stack([mesh.normals[:, 0], mesh.normals[:, 2], -mesh.normals[:, 1]])
    feature = mesh.feature.astype(np.float32)  # exact to 2^24; a vertex attribute of
    # 8 or 16 bits would need a stride of 4 bytes anyway (glTF 2.0, 3.6.2.4)
    return {
        "attributes": {
            "POSITION": glb.accessor(position, bounds=True),
            "NORMAL": glb.accessor(np.ascontiguousarray(normal, dtype=np.float32)),
            "_FEATURE_ID_0": glb.accessor(feature),
        },
        "indices": glb.accessor(mesh.indices.ravel(), target=ELEMENT_ARRAY_BUFFER),
        "material": material,
        "mode": 4,
        "extensions": {
            "EXT_mesh_features": {
                "featureIds": [{"featureCount": count, "attribute": 0, "propertyTable": 0}]
            }
        },
    }


def _material(glb: Glb, colour: list[float]) -> int:
    """A plain material of ``colour`` (translucent if its alpha is below 1)."""
    materials = glb.gltf.setdefault("materials", [])
    material: dict[str, Any] = {
        "pbrMetallicRoughness": {
            "baseColorFactor": colour,
            "metallicFactor": 0.0,
            "roughnessFactor": 1.0,
        }
    }
    if colour[3] < 1:
        material.update(alphaMode="BLEND", doubleSided=True)
    materials.append(material)
    return len(materials) - 1


def _property_table(glb: Glb, frame: pd.DataFrame, ranged: Any) -> dict[str, Any]:
    """The ``EXT_structural_metadata`` of the square's buildings: the schema and one table, a
    row per building, then one per range (the ``ranged`` rows again, ``part`` ``range``): a
    viewer styles one table per model, and so tells a range from its building."""
    rows = frame if not len(ranged) else pd.concat([frame, frame.iloc[ranged]])
    columns = {"id": "STRING", "height": "FLOAT64", **OPTIONAL}
    properties, values = {}, {}
    for column, kind in columns.items():
        if column not in rows.columns:
            continue
        properties[column] = _schema_property(kind)
        values[column] = _values(glb, rows[column], kind)
    properties["measured_height"] = _schema_property("FLOAT64")  # (the input's: _warn_shadowed)
    values["measured_height"] = _values(glb, rows["height"] - rows["ground"], "FLOAT64")
    properties["part"] = _schema_property("STRING")
    part = ["building"] * len(frame) + ["range"] * len(ranged)
    values["part"] = _values(glb, pd.Series(part), "STRING")
    return {
        "schema": {
            "id": "gnss_citygml",
            "classes": {"building": {"name": "Building", "properties": properties}},
        },
        "propertyTables": [{"class": "building", "count": len(rows), "properties": values}],
    }


def _schema_property(kind: str) -> dict[str, Any]:
    """A property of the class: a string, or a number with its no-data value (a missing value:
    a building without an interval, say)."""
    if kind == "STRING":
        return {"type": "STRING"}
    return {"type": "SCALAR", "componentType": kind, "noData": NO_DATA[kind]}


def _values(glb: Glb, column: pd.Series, kind: str) -> dict[str, Any]:
    """A property's buffer views: its values (a missing number as its no-data value) and a
    string's offsets."""
    if kind != "STRING":
        data = column.to_numpy(dtype=float)
        data = np.where(np.isfinite(data), data, NO_DATA[kind])
        return {"values": glb.view(data.astype({"FLOAT64": np.float64, "UINT32": np.uint32}[kind]))}
    texts = [str(v).encode("utf-8") if pd.notna(v) else b"" for v in column]
    offsets = np.r_[0, np.cumsum([len(t) for t in texts])].astype(np.uint32)
    return {
        "values": glb.view(np.frombuffer(b"".join(texts), dtype=np.uint8)),
        "stringOffsets": glb.view(offsets),
        "stringOffsetType": "UINT32",
    }


def _tileset(leaves: list[dict[str, Any]]) -> dict[str, Any]:
    """The tileset: the root, then the 100 km squares (``TQ``) and 10 km squares (``TQ28``)
    holding the 1 km leaves (``TQ2982``), each with the union of its children's regions."""
    squares: dict[str, dict[str, list[dict[str, Any]]]] = {}
    for leaf in leaves:
        name = leaf["name"]
        tile = {
            "boundingVolume": {"region": leaf["region"]},
            "geometricError": 0.0,
            "refine": "ADD",
            "transform": leaf["transform"],
            "content": {"uri": f"tiles/{name}.glb"},
        }
        squares.setdefault(name[:2], {}).setdefault(name[:3] + name[4], []).append(tile)
    hundreds = [
        _parent(LEVELS[0], [_parent(LEVELS[1], tens) for tens in ten_km.values()])
        for ten_km in squares.values()
    ]
    root = _parent(4 * LEVELS[0], hundreds)
    return {
        "asset": {"version": "1.1", "generator": "gnss-citygml"},
        "geometricError": root["geometricError"],
        "root": root,
    }


def _parent(side: float, children: list[dict[str, Any]]) -> dict[str, Any]:
    """A square of ``side`` metres holding ``children``, with no content of its own."""
    regions = np.array([c["boundingVolume"]["region"] for c in children])
    region = [*regions[:, :2].min(axis=0), *regions[:, 2:4].max(axis=0)]
    region += [regions[:, 4].min(), regions[:, 5].max()]
    return {
        "boundingVolume": {"region": [float(v) for v in region]},
        "geometricError": side * ERROR_PER_SIDE,
        "refine": "ADD",
        "children": children,
    }


def _viewer() -> str:
    """A CesiumJS page on the tileset beside it."""
    from importlib.resources import files

    return files("gnss_citygml.data").joinpath("viewer/viewer.html").read_text(encoding="utf-8")

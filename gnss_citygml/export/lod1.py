"""LOD1 block models: what the CityJSON and CityGML writers share.

A building's LOD1 model is its footprint extruded from the ground to the roof: a prism whose
bottom face lies at ``ground`` (m ODN), whose top face lies at ``height`` (the absolute roof
height, m ODN) and which has one vertical wall per footprint edge, holes included. This module
checks the *buildings* table with heights (:func:`prepare_buildings`), turns any footprint layer
with a height attribute into that table (:func:`buildings_with_heights`) and extrudes the
footprints of many buildings at once (:func:`extrude`), with numpy and shapely, never one
building at a time.

Rules
-----
- **Millimetres**: coordinates are snapped to a 1 mm grid before extrusion (repeated points
  removed; a footprint made invalid by the snapping is repaired with GEOS snap-rounding), so
  both formats carry the same integer-millimetre vertices. CityJSON stores them as integers
  with ``transform.scale`` 0.001.
- **Orientation**: exterior rings run anticlockwise seen from above and holes clockwise; the
  bottom face is written reversed (normal down), the top face as is (normal up) and each wall
  ``(b_i, b_i+1, t_i+1, t_i)``, so that every face's normal points out of the solid.
- **Parts**: a MultiPolygon footprint becomes one solid per polygon (a ``BuildingPart`` each in
  both formats), since one solid has one connected shell.
- **Collinear vertices** are kept: they may be shared with a neighbour's footprint, and the two
  coplanar walls they make are valid.
- **Skipped buildings**: a building without a usable height is never written with a guessed
  one. No ground, no height, an estimate that did not converge, a roof not above the ground
  (after rounding to mm), heights that no building in Great Britain has (a roof more than
  :data:`MAX_HEIGHT_ABOVE_GROUND` above the ground, a ground outside :data:`GROUND_RANGE`), a
  footprint outside the British National Grid (:data:`GRID_EXTENT`) or one that vanishes at
  1 mm precision: the building is left out and listed with its reason (or, with
  ``strict=True``, the export stops with an error).
"""

from __future__ import annotations

import datetime as dt
from collections.abc import Callable, Iterator
from dataclasses import dataclass

import geopandas as gpd
import numpy as np
import pandas as pd
import shapely

from ..errors import GnssCityGMLError, InputError, MissingColumnError
from ..validate import Report, validate_file

__all__ = [
    "CHECK_CHUNK",
    "CHUNK",
    "GRID_EXTENT",
    "GROUND_RANGE",
    "MAX_HEIGHT_ABOVE_GROUND",
    "SCALE",
    "SURFACES",
    "ExportResult",
    "InvalidOutputError",
    "Plan",
    "Prisms",
    "Progress",
    "attribute_columns",
    "attribute_values",
    "booleans",
    "buildings_with_heights",
    "chunks",
    "creation_date",
    "extrude",
    "footprints_with_heights",
    "hash_texts",
    "measured_heights",
    "nested_text",
    "part_ids",
    "prepare_buildings",
    "repeated_positions",
    "snap_footprints",
    "validated_output",
]

#: Metres per integer unit of the vertices: whole millimetres.
SCALE = 0.001
#: Buildings extruded and written at once by the streaming writers.
CHUNK = 2048
#: Rows of the buildings table checked at once by :func:`prepare_buildings`.
CHECK_CHUNK = 8 * CHUNK
#: Semantic surface kinds, in the order of :attr:`Prisms.face_kind`.
SURFACES = ("GroundSurface", "RoofSurface", "WallSurface")

#: Highest roof above the ground (m) that is written. The tallest structures in Great Britain
#: stand about 330 m (Emley Moor mast; The Shard 310 m); a higher "building" is an error in the
#: data (a height in millimetres or feet, a wrong field), not a building.
MAX_HEIGHT_ABOVE_GROUND = 400.0
#: Ground heights (m ODN) that exist in Great Britain, with a margin: Holme Fen is 2.75 m below
#: sea level, Ben Nevis 1,345 m above it.
GROUND_RANGE = (-10.0, 1400.0)
#: Where British National Grid coordinates exist (m: min E, min N, max E, max N), with a margin.
GRID_EXTENT = (-100_000.0, -100_000.0, 800_000.0, 1_400_000.0)
_TOO_TALL = (
    f"roof more than {MAX_HEIGHT_ABOVE_GROUND:.0f} m above the ground (no structure in Great "
    "Britain is; a height in mm or feet, or the wrong field?)"
)
_GROUND_OUTSIDE = (
    f"ground outside {GROUND_RANGE[0]:.0f}..{GROUND_RANGE[1]:.0f} m ODN (no ground in Great "
    "Britain is; a height in mm or feet, or the wrong field?)"
)
_TRUE = {"true", "t", "yes", "y", "1", "1.0"}
_FALSE = {"false", "f", "no", "n", "0", "0.0"}

_SHOWN = 10


class InvalidOutputError(GnssCityGMLError):
    """A file the toolkit wrote failed its own validation (a bug: the file is not kept)."""


@dataclass
class ExportResult:
    """What a writer did.

    Attributes
    ----------
    path
        The file written.
    written
        Number of buildings written.
    skipped
        The buildings left out: ``id`` and ``reason``.
    report
        The validation report of the file (None with ``validate=False``).
    """

    path: str
    written: int
    skipped: pd.DataFrame
    report: Report | None = None


@dataclass(frozen=True)
class Prisms:
    """The LOD1 solids of many buildings as flat (ragged) arrays.

    A building has one solid per polygon of its footprint; a solid has faces (the bottom, the
    top, then one wall per ring edge); a face has rings (exterior first, then holes); a ring has
    vertex indices (not repeating the first). ``X_start`` arrays hold where each item's
    children start, with one extra entry at the end, as in Apache Arrow.

    Attributes
    ----------
    vertices
        (V, 3) int64 coordinates in millimetres (EPSG:27700 easting, northing; ODN height).
    vertex_start
        (B + 1,) first vertex of each building when vertices are numbered per building, else
        all zeros (one numbering for all buildings).
    ring_vertices
        Indices into ``vertices`` (counted from the building's first vertex when numbered per
        building) of every ring, one ring after another.
    ring_start, face_start, solid_start, building_start
        Where each ring's vertices, each face's rings, each solid's faces and each building's
        solids start.
    face_kind
        Index into :data:`SURFACES` of each face: 0 ground, 1 roof, 2 wall.
    """

    vertices: np.ndarray
    vertex_start: np.ndarray
    ring_vertices: np.ndarray
    ring_start: np.ndarray
    face_start: np.ndarray
    face_kind: np.ndarray
    solid_start: np.ndarray
    building_start: np.ndarray

    def take(self, buildings: slice) -> Prisms:
        """The solids of a contiguous range of buildings (``slice(start, stop)``)."""
        b0, b1 = buildings.start, buildings.stop
        s0, s1 = self.building_start[b0], self.building_start[b1]
        f0, f1 = self.solid_start[s0], self.solid_start[s1]
        r0, r1 = self.face_start[f0], self.face_start[f1]
        v0, v1 = self.vertex_start[b0], self.vertex_start[b1]
        shared = not self.vertex_start.any()  # one numbering for all buildings
        return Prisms(
            vertices=self.vertices if shared else self.vertices[v0:v1],
            vertex_start=self.vertex_start[b0 : b1 + 1] - v0,
            ring_vertices=self.ring_vertices[self.ring_start[r0] : self.ring_start[r1]],
            ring_start=self.ring_start[r0 : r1 + 1] - self.ring_start[r0],
            face_start=self.face_start[f0 : f1 + 1] - r0,
            face_kind=self.face_kind[f0:f1],
            solid_start=self.solid_start[s0 : s1 + 1] - f0,
            building_start=self.building_start[b0 : b1 + 1] - s0,
        )


def snap_footprints(footprints) -> np.ndarray:
    """Footprints on the 1 mm grid, valid, oriented, without repeated points.

    Parameters
    ----------
    footprints
        Polygons and MultiPolygons (an array or a GeoSeries), in metres.

    Returns
    -------
    numpy.ndarray
        shapely geometries with exteriors anticlockwise and holes clockwise; a footprint that
        vanishes at 1 mm is empty.

    Examples
    --------
    >>> snap_footprints([shapely.box(0, 0, 2.0004, 1.0)])[0].wkt
    'POLYGON ((2 0, 2 1, 0 1, 0 0, 2 0))'
    """
    geoms = np.asarray(footprints, dtype=object)
    snapped = shapely.set_precision(geoms, SCALE, mode="pointwise")
    broken = ~shapely.is_valid(snapped)
    if broken.any():  # snap-rounding repairs what rounding each point broke
        snapped[broken] = shapely.set_precision(geoms[broken], SCALE)
    return shapely.orient_polygons(shapely.remove_repeated_points(snapped, 0.0))


def extrude(footprints, ground, roof, *, numbering: str = "building") -> Prisms:
    """Extrude footprints into LOD1 solids with outward faces and shared vertices.

    Parameters
    ----------
    footprints
        Non-empty Polygons and MultiPolygons from :func:`snap_footprints`.
    ground, roof
        Bottom and top heights of each building (m); the roof above the ground.
    numbering
        ``"building"``: vertices numbered per building (a CityJSONFeature each), identical
        vertices of one building shared; ``"all"``: one numbering, identical vertices of all
        buildings shared (one CityJSON file).

    Returns
    -------
    Prisms

    Examples
    --------
    >>> p = extrude(snap_footprints([shapely.box(0, 0, 2, 1)]), [10.0], [13.5])
    >>> p.vertices.shape, len(p.face_kind), p.face_kind.tolist()
    ((8, 3), 6, [0, 1, 2, 2, 2, 2])
    >>> p.vertices[p.ring_vertices[p.ring_start[1]:p.ring_start[2]]].tolist()  # the roof
    [[2000, 0, 13500], [2000, 1000, 13500], [0, 1000, 13500], [0, 0, 13500]]
    """
    if numbering not in ("building", "all"):
        raise ValueError(f"numbering must be 'building' or 'all', not {numbering!r}")
    footprints = np.asarray(footprints, dtype=object)
    ground_mm = np.rint(np.asarray(ground, dtype=float) * 1000).astype(np.int64)
    roof_mm = np.rint(np.asarray(roof, dtype=float) * 1000).astype(np.int64)
    parts, part_building = shapely.get_parts(footprints, return_index=True)
    rings, ring_part = shapely.get_rings(parts, return_index=True)
    coords, coord_ring = shapely.get_coordinates(rings, return_index=True)
    closed_size = np.bincount(coord_ring, minlength=len(rings))
    last = np.cumsum(closed_size) - 1
    keep = np.ones(len(coords), dtype=bool)
    keep[last] = False  # drop each ring's closing point
    xy = np.rint(coords[keep] * 1000).astype(np.int64)
    size = closed_size - 1
    start = np.concatenate([[0], np.cumsum(size)])
    point_ring = np.repeat(np.arange(len(rings)), size)
    point_building = part_building[ring_part[point_ring]]

    bottom, top, vertices, vertex_start = _shared_vertices(
        xy, point_building, ground_mm, roof_mm, len(footprints), numbering
    )
    j = np.arange(len(xy))
    ring_end = start[point_ring] + size[point_ring] - 1
    following = np.where(j == ring_end, start[point_ring], j + 1)
    reversed_ = start[point_ring] + ring_end - j
    walls = np.stack([bottom[j], bottom[following], top[following], top[j]], axis=1).ravel()

    # Rings in output order: per solid (part), bottom rings, top rings, then one quad per edge.
    n_rings, n_points = len(rings), len(xy)
    record_part = np.concatenate([ring_part, ring_part, ring_part[point_ring]])
    record_section = np.repeat([0, 1, 2], [n_rings, n_rings, n_points])
    record_sub = np.concatenate([np.arange(n_rings), np.arange(n_rings), j])
    record_size = np.concatenate([size, size, np.full(n_points, 4)])
    payload = np.concatenate([bottom[reversed_], top, walls])
    payload_start = np.concatenate([[0], np.cumsum(record_size)[:-1]])
    order = np.lexsort((record_sub, record_section, record_part))
    ring_vertices = _ragged_take(payload, payload_start[order], record_size[order])
    ring_start = np.concatenate([[0], np.cumsum(record_size[order])])

    part, section = record_part[order], record_section[order]
    new_face = np.ones(len(order), dtype=bool)
    new_face[1:] = (part[1:] != part[:-1]) | (section[1:] != section[:-1]) | (section[1:] == 2)
    face_first = np.flatnonzero(new_face)
    face_start = np.append(face_first, len(order))
    face_part = part[face_first]
    solid_start = np.append(np.flatnonzero(np.diff(face_part, prepend=-1)), len(face_first))
    building_start = np.searchsorted(part_building, np.arange(len(footprints) + 1))
    return Prisms(
        vertices=vertices,
        vertex_start=vertex_start,
        ring_vertices=ring_vertices,
        ring_start=ring_start,
        face_start=face_start,
        face_kind=section[face_first],
        solid_start=solid_start,
        building_start=building_start,
    )


def _shared_vertices(xy, point_building, ground_mm, roof_mm, n_buildings, numbering):
    """Bottom and top vertex index of every footprint point, and the unique vertices."""
    n = len(xy)
    owner = np.tile(point_building, 2)
    x, y = np.tile(xy[:, 0], 2), np.tile(xy[:, 1], 2)
    z = np.concatenate([ground_mm[point_building], roof_mm[point_building]])
    group = owner if numbering == "building" else np.zeros_like(owner)
    order = np.lexsort((z, y, x, group))
    new = np.ones(2 * n, dtype=bool)
    sorted_keys = np.column_stack([group[order], x[order], y[order], z[order]])
    new[1:] = (np.diff(sorted_keys, axis=0) != 0).any(axis=1)
    inverse = np.empty(2 * n, dtype=np.int64)
    inverse[order] = np.cumsum(new) - 1
    vertices = sorted_keys[new, 1:]
    if numbering == "all":
        vertex_start = np.zeros(n_buildings + 1, dtype=np.int64)
    else:
        vertex_start = np.searchsorted(sorted_keys[new, 0], np.arange(n_buildings + 1))
        inverse -= vertex_start[owner]
    return inverse[:n], inverse[n:], vertices, vertex_start


def nested_text(tokens, levels) -> list[str]:
    """Serialise ragged nested groups of text tokens: one text per outermost group.

    Parameters
    ----------
    tokens
        The leaves (texts), in order.
    levels
        From the innermost level out, one ``(start, open, close, separator)`` each: ``start``
        says where each group's children (tokens, or the groups of the level inside) start,
        with a final end entry; ``open`` and ``close`` are written before and after each group,
        ``separator`` between two children of a group.

    Returns
    -------
    list of str

    Notes
    -----
    Before a token come the ``open`` texts of the levels whose groups start at it; after it the
    ``close`` texts of the levels whose groups end at it, then the separator of the next level
    up. Both are counted with numpy, so Python only glues three texts per token.

    Examples
    --------
    >>> levels = [([0, 2, 3, 4], "[", "]", ","), ([0, 2, 3], "[", "]", ",")]
    >>> nested_text(["1", "2", "3", "4"], levels)
    ['[[1,2],[3]]', '[[4]]']
    """
    tokens = list(tokens)
    n = len(tokens)
    first = last = np.arange(n)
    opened = np.zeros(n, dtype=np.int64)  # levels whose groups start at each token
    closed = np.zeros(n, dtype=np.int64)  # levels whose groups end at each token
    starts = np.ones(n, dtype=bool)
    ends = np.ones(n, dtype=bool)
    for start, *_ in levels:
        start = np.asarray(start)
        first, last = first[start[:-1]], last[start[1:] - 1]
        at_start = np.zeros(n, dtype=bool)
        at_start[first] = True
        at_end = np.zeros(n, dtype=bool)
        at_end[last] = True
        starts &= at_start
        ends &= at_end
        opened += starts
        closed += ends
    before, after, closings = [""], [], ""
    for _, opening, closing, separator in levels:  # texts by number of levels opened/closed
        before.append(opening + before[-1])
        after.append(closings + separator)
        closings += closing
    after.append(closings)
    parts = [
        before[i] + t + after[j]
        for i, t, j in zip(opened.tolist(), tokens, closed.tolist(), strict=True)
    ]
    return ["".join(parts[a : b + 1]) for a, b in zip(first.tolist(), last.tolist(), strict=True)]


def _ragged_take(values: np.ndarray, starts: np.ndarray, sizes: np.ndarray) -> np.ndarray:
    """``concatenate([values[s:s + k] for s, k in zip(starts, sizes)])``, vectorised."""
    offsets = np.cumsum(sizes) - sizes
    return values[np.repeat(starts - offsets, sizes) + np.arange(sizes.sum())]


# --- the buildings table --------------------------------------------------------------------


def footprints_with_heights(
    footprints: gpd.GeoDataFrame, heights: pd.DataFrame, *, where: str = "heights table"
) -> gpd.GeoDataFrame:
    """The footprints joined with a heights table (``id`` and the heights columns), e.g. one
    written by ``gnss-citygml heights``. Footprints without a row keep empty heights (the
    writers skip and list them); a ``ground`` already on the footprints (from a DEM) wins over
    the table's. Heights of ids that are not among the footprints are an error."""
    if "id" not in heights.columns:
        raise MissingColumnError(["id"], where=where, have=list(heights.columns))
    table = heights.assign(id=heights["id"].astype(str))
    repeated = pd.unique(table["id"][table["id"].duplicated()])
    if repeated.size:
        raise InputError(
            f"{repeated.size} building id(s) with more than one height: {_listing(repeated)}",
            where=where,
            fix="keep one row per building",
        )
    if "ground" in footprints.columns:
        table = table.drop(columns=["ground"], errors="ignore")
    unknown = ~table["id"].isin(footprints["id"])
    if unknown.any():
        raise InputError(
            f"{int(unknown.sum())} height(s) for buildings not among the footprints: "
            + ", ".join(table["id"][unknown].head(10)),
            where=where,
            fix="give the footprints the heights were estimated for",
        )
    return footprints.merge(table, on="id", how="left")


def buildings_with_heights(
    frame: gpd.GeoDataFrame,
    height_field: str = "height",
    *,
    relative: bool = False,
    ground_field: str | None = None,
) -> gpd.GeoDataFrame:
    """Any footprint layer with a height attribute as the buildings table the writers take.

    Parameters
    ----------
    frame
        Footprints (``id``, ``geometry``) with a height attribute, e.g. the ``heights`` layer of
        ``estimate`` or OS Building Height Attribute fields (``abshmax``, ``relh2``). The ground
        comes from ``ground_field`` or from a ``ground`` column (e.g. added from a DEM by
        :func:`gnss_citygml.buildings.building_ground`).
    height_field
        The column with the roof height (m): absolute (ODN) by default.
    relative
        The height field is the height above the ground (m); the roof is ground + height.
    ground_field
        The column with the ground height (m ODN), moved to ``ground``.

    Returns
    -------
    geopandas.GeoDataFrame
        A copy with ``ground`` and ``height`` (absolute roof height, m ODN; the input field is
        kept under its own name) and, unless present, ``method`` saying where the height came
        from (e.g. ``attribute relh2 + ground``).

    Raises
    ------
    MissingColumnError
        The height or ground field is missing.
    InputError
        A field is not numeric, or the layer already has other ``height``/``ground`` columns.

    Examples
    --------
    >>> frame = gpd.GeoDataFrame({"id": ["a"], "relh2": [9.5], "base": [12.0]},
    ...                          geometry=[shapely.box(0, 0, 5, 5)], crs="EPSG:27700")
    >>> out = buildings_with_heights(frame, "relh2", relative=True, ground_field="base")
    >>> out[["ground", "height", "method"]].values.tolist()
    [[12.0, 21.5, 'attribute relh2 + ground']]
    """
    columns = list(frame.columns)
    for name in (height_field, ground_field):
        if name is not None and name not in columns:
            raise MissingColumnError([name], where="footprint layer", have=columns)
    if ground_field is None and "ground" not in columns:
        raise MissingColumnError(
            ["ground"], where="footprint layer (give a ground field or a DEM)", have=columns
        )
    out = frame.copy()
    for target, name in (("ground", ground_field), ("height", height_field)):
        if name is not None and name != target and target in columns:
            raise InputError(
                f"the layer has a column {target!r} besides the {target} field {name!r}",
                where="footprint layer",
                fix=f"rename or drop the column {target!r}",
            )
    ground = _numeric(out, ground_field or "ground")
    height = _numeric(out, height_field)
    out["ground"] = ground
    out["height"] = ground + height if relative else height
    if ground_field not in (None, "ground"):
        out = out.drop(columns=[ground_field])
    if "method" not in out.columns and height_field != "height":
        out["method"] = f"attribute {height_field}" + (" + ground" if relative else "")
    return out


def _numeric(frame: pd.DataFrame, name: str) -> np.ndarray:
    try:
        return pd.to_numeric(frame[name], errors="raise").to_numpy(dtype=float, na_value=np.nan)
    except (ValueError, TypeError):
        bad = pd.to_numeric(frame[name], errors="coerce").isna() & frame[name].notna()
        ids = frame["id"][bad] if "id" in frame.columns else frame.index[bad]
        raise InputError(
            f"column {name!r} is not numeric ({_listing(list(ids))})",
            where="footprint layer",
            fix="give heights in metres as numbers",
        ) from None


class Plan:
    """The buildings to write, handed out a chunk at a time (from :func:`prepare_buildings`).

    The caller's table is not copied: each chunk is taken from it, its footprints snapped to
    the millimetre grid, so the writers' memory does not grow with the number of buildings.

    Attributes
    ----------
    frame
        The caller's buildings table.
    rows
        Positions (in ``frame``) of the buildings with a usable height.
    skipped
        ``(id, reason)`` of the buildings left out so far.
    written
        Buildings handed out so far.
    """

    def __init__(
        self,
        frame: gpd.GeoDataFrame,
        rows: np.ndarray,
        skipped: list,
        strict: bool,
        bounds: np.ndarray,
    ):
        self.frame = frame
        self.rows = rows
        self.skipped = skipped
        self.strict = strict
        self.written = 0
        self._bounds = bounds

    def chunks(self, size: int = CHUNK) -> Iterator[gpd.GeoDataFrame]:
        """The buildings, ``size`` at a time: text ``id``, snapped footprints, a fresh index."""
        for part in chunks(len(self.rows), size):
            rows = self.frame.iloc[self.rows[part]].reset_index(drop=True)
            footprints = snap_footprints(rows.geometry.to_numpy())
            gone = shapely.is_empty(footprints)
            rows["id"] = rows["id"].astype(str)
            if gone.any():
                ids = rows["id"][gone].tolist()
                self.skipped.extend((i, "footprint vanishes at 1 mm precision") for i in ids)
                if self.strict:
                    raise InputError(
                        f"{len(ids)} footprint(s) vanish at 1 mm precision: {_listing(ids)}",
                        where="buildings",
                        fix="drop them, or leave out --strict to skip them",
                    )
                rows, footprints = rows[~gone].reset_index(drop=True), footprints[~gone]
            if len(rows):
                self.written += len(rows)
                yield rows.set_geometry(footprints)

    def bounds_mm(self) -> np.ndarray:
        """(min e, min n, min ground, max e, max n, max roof) of the buildings, in mm."""
        return np.rint(self._bounds * 1000).astype(np.int64)

    def result(self, path, report: Report | None) -> ExportResult:
        """What was written; an error if nothing was."""
        if not self.written:
            raise InputError(
                f"none of the {len(self.frame)} buildings can be modelled "
                f"({_reason_counts(self.skipped)})",
                where="buildings",
                fix="check their footprints and heights",
            )
        skipped = pd.DataFrame(self.skipped, columns=["id", "reason"], dtype=object)
        return ExportResult(str(path), self.written, skipped, report)


def prepare_buildings(buildings: gpd.GeoDataFrame, *, strict: bool = False) -> Plan:
    """Check the buildings table and set aside the buildings without a usable height.

    The table is read :data:`CHECK_CHUNK` rows at a time; across chunks only a hash of each id
    (8 bytes), the positions of the usable buildings and the bounds are kept, so the memory
    used does not grow with the table beyond a few bytes per building.

    Parameters
    ----------
    buildings
        GeoDataFrame in EPSG:27700 with ``id``, ``geometry`` (Polygon/MultiPolygon), ``ground``
        and ``height`` (absolute roof height, m ODN); ``converged`` (and ``status``, the reason)
        is honoured when present.
    strict
        Raise instead of skipping buildings without a usable height.

    Returns
    -------
    Plan
        The buildings to write, a chunk at a time, and the skipped ones with their reasons.

    Raises
    ------
    InputError
        Not a GeoDataFrame in EPSG:27700, missing columns, missing or duplicate ids, non-polygon
        footprints, non-numeric heights, part ids taken by buildings, no usable height, or
        (``strict``) skipped buildings.
    """
    if not isinstance(buildings, gpd.GeoDataFrame):
        raise InputError(
            f"the buildings must be a GeoDataFrame, not {type(buildings).__name__}",
            fix="read them with read_footprints or geopandas",
        )
    missing = [c for c in ("id", "ground", "height") if c not in buildings.columns]
    if missing:
        raise MissingColumnError(missing, where="buildings", have=list(buildings.columns))
    if buildings.crs is None or buildings.crs.to_epsg() not in (27700, 7405):
        raise InputError(
            f"the buildings are in {buildings.crs or 'no CRS'}, not EPSG:27700",
            where="buildings",
            fix="read them with read_footprints, which transforms them with OSTN15",
        )
    checks = _Checks(len(buildings))
    for part in chunks(len(buildings), CHECK_CHUNK):
        checks.add(buildings.iloc[part], part.start)
    checks.raise_errors(buildings)
    skipped = checks.skipped
    if strict and skipped:
        raise InputError(
            f"{len(skipped)} building(s) without a usable height: "
            + _listing([f"{i} ({r})" for i, r in skipped]),
            where="buildings",
            fix="drop them, or leave out --strict to skip them",
        )
    if not checks.usable.any():
        raise InputError(
            f"none of the {len(buildings)} buildings has a usable height "
            f"({_reason_counts(skipped)})",
            where="buildings",
            fix="check the height and ground columns",
        )
    bounds = np.concatenate([checks.low, checks.high])
    return Plan(buildings, np.flatnonzero(checks.usable), skipped, strict, bounds)


class _Checks:
    """What :func:`prepare_buildings` gathers over the chunks of a table of n buildings."""

    def __init__(self, n: int):
        self.hashes = np.zeros(n, dtype=np.int64)  # of each id
        self.usable = np.zeros(n, dtype=bool)
        self.low, self.high = np.full(3, np.inf), np.full(3, -np.inf)  # e, n, z
        self.skipped: list[tuple[str, str]] = []
        self.no_id: list[np.ndarray] = []  # positions
        self.not_polygon: list[str] = []  # ids
        self.part_hashes: list[np.ndarray] = []  # of each part id of a MultiPolygon
        self.part_rows: list[np.ndarray] = []  # position of the building of each part
        self.numeric = True

    def add(self, frame: gpd.GeoDataFrame, first: int) -> None:
        """Check the buildings ``frame``, which start at position ``first`` of the table."""
        self.no_id.append(np.flatnonzero(frame["id"].isna().to_numpy()) + first)
        ids = frame["id"].astype(str).to_numpy(dtype=object)
        self.hashes[first : first + len(ids)] = hash_texts(ids)
        geoms = frame.geometry.to_numpy()
        kind = shapely.get_type_id(geoms)
        self.not_polygon.extend(ids[~np.isin(kind, [3, 6])].tolist())
        multi = kind == 6
        if multi.any():
            groups = part_ids(ids[multi], geoms[multi])
            self.part_hashes.append(hash_texts([p for group in groups for p in group]))
            sizes = [len(group) for group in groups]
            self.part_rows.append(np.repeat(np.flatnonzero(multi) + first, sizes))
        try:
            ground, height = _numeric(frame, "ground"), _numeric(frame, "height")
        except InputError:  # reported for the whole table by raise_errors
            self.numeric = False
            return
        reason = _reasons(frame, ground, height)
        skip = reason != None  # noqa: E711 - elementwise comparison of an object array
        self.skipped.extend(zip(ids[skip].tolist(), reason[skip].tolist(), strict=True))
        keep = ~skip
        self.usable[first : first + len(ids)] = keep
        if keep.any():
            e0, n0, e1, n1 = shapely.total_bounds(geoms[keep])
            self.low = np.minimum(self.low, [e0, n0, ground[keep].min()])
            self.high = np.maximum(self.high, [e1, n1, height[keep].max()])

    def raise_errors(self, buildings: gpd.GeoDataFrame) -> None:
        """Raise the first error found, in the order the checks are documented."""
        no_id = np.concatenate(self.no_id) if self.no_id else np.zeros(0, dtype=np.int64)
        if no_id.size:
            raise InputError(
                f"{no_id.size} building(s) without an id (rows {_listing(no_id)})",
                where="buildings",
                fix="give every building an id",
            )
        ids = buildings["id"]
        suspects = repeated_positions(self.hashes)
        texts = ids.iloc[suspects].astype(str).to_numpy(dtype=object)
        repeated = pd.unique(texts[pd.Series(texts, dtype=object).duplicated().to_numpy()])
        if repeated.size:
            raise InputError(
                f"{repeated.size} duplicate building id(s): {_listing(repeated)}",
                where="buildings",
                fix="give each building its own id",
            )
        if self.not_polygon:
            raise InputError(
                f"{len(self.not_polygon)} building(s) without a polygon footprint: "
                + _listing(self.not_polygon),
                where="buildings",
                fix="give Polygon or MultiPolygon footprints (drop or repair the others)",
            )
        if self.part_hashes:
            parts = np.concatenate(self.part_hashes), np.concatenate(self.part_rows)
            _check_part_ids(buildings, self.hashes, *parts)
        if not self.numeric:
            _numeric(buildings, "ground"), _numeric(buildings, "height")  # raises


def _reasons(frame: gpd.GeoDataFrame, ground: np.ndarray, height: np.ndarray) -> np.ndarray:
    """Why each building cannot be modelled, or None."""
    reason = np.full(len(frame), None, dtype=object)
    with np.errstate(invalid="ignore", over="ignore"):
        above = height - ground
        rules = [
            (above > MAX_HEIGHT_ABOVE_GROUND, _TOO_TALL),
            (np.rint(height * 1000) <= np.rint(ground * 1000), "roof not above the ground"),
            ((ground < GROUND_RANGE[0]) | (ground > GROUND_RANGE[1]), _GROUND_OUTSIDE),
            (
                _outside_grid(frame.geometry.to_numpy()),
                "footprint outside the British National Grid",
            ),
            (~np.isfinite(ground), "no ground height"),
            (~np.isfinite(height), "no height"),
        ]
    for mask, text in rules:  # the last rule that applies wins: the most basic one
        reason[mask] = text
    if "converged" in frame.columns:
        converged = booleans(frame["converged"], "converged", frame)  # missing: no estimate
        failed = (~converged).fillna(False).to_numpy(dtype=bool)
        status = frame["status"].astype(str).to_numpy() if "status" in frame else None
        reason[failed] = [
            "height estimate did not converge" + (f" ({status[i]})" if status is not None else "")
            for i in np.flatnonzero(failed)
        ]
    return reason


def _outside_grid(geoms: np.ndarray) -> np.ndarray:
    e0, n0, e1, n1 = shapely.bounds(geoms).T
    with np.errstate(invalid="ignore"):
        return (
            (e0 < GRID_EXTENT[0])
            | (n0 < GRID_EXTENT[1])
            | (e1 > GRID_EXTENT[2])
            | (n1 > GRID_EXTENT[3])
        )


def booleans(column: pd.Series, name: str, frame: pd.DataFrame) -> pd.Series:
    """A column of flags as pandas' nullable booleans: True/False, 1/0 or their spellings in
    text (true/false, yes/no, t/f, y/n, any case); empty is missing. Anything else is an error
    naming the buildings, never a guess.

    Examples
    --------
    >>> frame = pd.DataFrame({"id": ["a", "b", "c"], "ok": ["Yes", "no", None]})
    >>> booleans(frame["ok"], "ok", frame).tolist()
    [True, False, <NA>]
    """
    if pd.api.types.is_bool_dtype(column):
        return column.astype("boolean")
    text = column.astype("string").str.strip().str.lower()
    out = pd.Series(pd.NA, index=column.index, dtype="boolean")
    out[text.isin(_TRUE).fillna(False)] = True
    out[text.isin(_FALSE).fillna(False)] = False
    bad = (out.isna() & text.notna() & (text != "")).to_numpy()
    if bad.any():
        ids = frame["id"][bad].astype(str) if "id" in frame.columns else frame.index[bad]
        values = pd.unique(column[bad].astype(str))
        raise InputError(
            f"column {name!r} is not true/false: {_listing(map(repr, values))} "
            f"(buildings {_listing(list(ids))})",
            where="buildings",
            fix="give true or false (yes/no, 1/0)",
        )
    return out


def hash_texts(texts) -> np.ndarray:
    """A 64-bit hash of each of a sequence of texts (Python's: comparable within a process)."""
    return np.fromiter(map(hash, texts), dtype=np.int64, count=len(texts))


def repeated_positions(hashes: np.ndarray) -> np.ndarray:
    """Sorted positions of the hashes that occur more than once (texts that may repeat).

    Examples
    --------
    >>> repeated_positions(np.array([5, 3, 5, 7, 3, 9])).tolist()
    [0, 1, 2, 4]
    """
    order = np.argsort(hashes, kind="stable")
    ranked = hashes[order]
    same = ranked[1:] == ranked[:-1]
    twice = np.zeros(len(hashes), dtype=bool)
    twice[1:] = same
    twice[:-1] |= same
    return np.sort(order[twice])


def _reason_counts(skipped) -> str:
    """``"no height: 3 (a, b, c); ..."``: the skipped buildings by reason, most first."""
    by_reason: dict[str, list] = {}
    for building, reason in skipped:
        by_reason.setdefault(reason, []).append(building)
    ranked = sorted(by_reason.items(), key=lambda item: -len(item[1]))
    return "; ".join(f"{r}: {len(ids)} ({_listing(ids[:3])})" for r, ids in ranked)


def _listing(items) -> str:
    items = list(items)
    shown = ", ".join(str(item) for item in items[:_SHOWN])
    return shown + (f" and {len(items) - _SHOWN} more" if len(items) > _SHOWN else "")


# --- attributes -----------------------------------------------------------------------------


def attribute_columns(frame: pd.DataFrame) -> list[tuple[str, str]]:
    """(name, kind) of the columns written as attributes: every column but id and geometry.

    ``kind`` is ``"bool"``, ``"int"``, ``"double"`` or ``"string"`` (dates and anything else
    become ISO or plain text).
    """
    out = []
    for name in frame.columns:
        if name in ("id", frame.geometry.name):
            continue
        dtype = frame[name].dtype
        if pd.api.types.is_bool_dtype(dtype):
            kind = "bool"
        elif pd.api.types.is_integer_dtype(dtype):
            kind = "int"
        elif pd.api.types.is_float_dtype(dtype):
            kind = "double"
        else:
            kind = "string"
        out.append((str(name), kind))
    return out


def attribute_values(column: pd.Series, kind: str) -> list:
    """The column's values as Python objects of the given kind; None where missing.

    Text columns give ``str``, or a list of ``str`` for list-like values.
    """
    if kind == "double":
        values = column.to_numpy(dtype=float, na_value=np.nan)
        missing = ~np.isfinite(values)
        out = values.tolist()
    elif pd.api.types.is_datetime64_any_dtype(column.dtype):
        missing = column.isna().to_numpy()
        out = [None if m else v.isoformat() for v, m in zip(column, missing, strict=True)]
    else:
        missing = column.isna().to_numpy()  # elementwise: a list value is not missing
        convert = {"int": int, "bool": bool, "string": _text}[kind]
        objects = column.astype(object).tolist()
        return [None if m else convert(v) for v, m in zip(objects, missing.tolist(), strict=True)]
    if missing.any():
        out = [None if m else v for v, m in zip(out, missing, strict=True)]
    return out


def _text(value) -> str | list[str]:
    """Text, or a list of texts for a list-like value (e.g. MasterMap's descriptiveGroup)."""
    if isinstance(value, str):
        return value
    return [str(v) for v in value] if isinstance(value, list | tuple | np.ndarray) else str(value)


def creation_date(date: dt.date | str | None) -> str:
    """The ISO date written as creationDate/referenceDate (default: today, UTC)."""
    if date is None:
        return dt.datetime.now(dt.UTC).date().isoformat()
    if isinstance(date, str):
        try:
            return dt.date.fromisoformat(date).isoformat()
        except ValueError:
            raise InputError(f"not a date: {date!r}", where="date", fix="give YYYY-MM-DD") from None
    return date.isoformat() if isinstance(date, dt.date) else str(date)


def chunks(n: int, size: int = CHUNK) -> list[slice]:
    """Slices of ``range(n)`` of at most ``size`` items."""
    return [slice(i, min(i + size, n)) for i in range(0, n, size)]


def measured_heights(ground: np.ndarray, roof: np.ndarray) -> list[float]:
    """roof - ground in metres, from the millimetre values the geometry uses."""
    mm = np.rint(np.asarray(roof) * 1000).astype(np.int64) - np.rint(
        np.asarray(ground) * 1000
    ).astype(np.int64)
    return (mm / 1000).tolist()


def part_ids(ids, footprints) -> list[list[str]]:
    """Per building, the ids of its parts (``<id>-1``, ...; none for a single polygon)."""
    geoms = np.asarray(footprints, dtype=object)
    counts = np.where(shapely.get_type_id(geoms) == 3, 0, shapely.get_num_geometries(geoms))
    counts = counts.tolist()
    return [[f"{i}-{k}" for k in range(1, n + 1)] for i, n in zip(ids, counts, strict=True)]


def _check_part_ids(buildings: gpd.GeoDataFrame, hashes, part_hashes, part_rows) -> None:
    """Refuse part ids (of MultiPolygon footprints) that are building ids.

    ``hashes`` are those of the building ids, ``part_hashes`` those of the part ids and
    ``part_rows`` the position of the building of each part; texts are compared only where
    hashes match.
    """
    suspects = np.flatnonzero(np.isin(hashes, part_hashes))
    if not suspects.size:
        return
    owners = np.unique(part_rows[np.isin(part_hashes, hashes[suspects])])
    rows = buildings.iloc[owners]
    ids = rows["id"].astype(str).to_numpy(dtype=object)
    parts = {p for group in part_ids(ids, rows.geometry.to_numpy()) for p in group}
    texts = buildings["id"].iloc[suspects].astype(str).to_numpy(dtype=object)
    taken = texts[pd.Index(texts, dtype=object).isin(parts)]
    if taken.size:
        raise InputError(
            f"building part ids clash with building ids: {_listing(sorted(taken))}",
            where="buildings",
            fix="rename those buildings (the parts of building X are named X-1, X-2, ...)",
        )


def validated_output(tmp, path, validate: bool, schema_dir) -> Report | None:
    """The validation report of a file just written to ``tmp``; raise if it is invalid."""
    if not validate:
        return None
    report = validate_file(tmp, schema_dir=schema_dir)
    if not report.valid:
        first = report.errors[0]
        raise InvalidOutputError(
            f"the file written is not valid: {len(report.errors)} error(s), the first "
            f"{first.rule} ({first.object_id}): {first.message}",
            where=str(path),
            fix="please report this bug with the input; the file was not kept",
        )
    report.path = str(path)
    return report


#: A callback told how many more buildings were written.
Progress = Callable[[int], None]

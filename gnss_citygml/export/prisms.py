"""LOD1 prisms: the geometry of a block model, for many buildings at once.

A building's LOD1 model is its footprint extruded from the ground to the roof: a prism whose
bottom face lies at ``ground`` (m ODN), whose top face lies at ``height`` (the absolute roof
height, m ODN) and which has one vertical wall per footprint edge, holes included. This module
snaps footprints to the millimetre grid (:func:`snap_footprints`) and extrudes many of them at
once (:func:`extrude`) into flat arrays (:class:`Prisms`) that both writers serialise, with
numpy and shapely, never one building at a time. Which buildings get a prism is decided by
:mod:`gnss_citygml.export.plan`.

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
  both formats, named by :func:`part_ids`), since one solid has one connected shell.
- **Collinear vertices** are kept: they may be shared with a neighbour's footprint, and the two
  coplanar walls they make are valid.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt
import shapely

__all__ = ["SCALE", "SURFACES", "Prisms", "extrude", "part_ids", "snap_footprints"]

#: Metres per integer unit of the vertices: whole millimetres.
SCALE = 0.001
#: Semantic surface kinds, in the order of :attr:`Prisms.face_kind`.
SURFACES = ("GroundSurface", "RoofSurface", "WallSurface")


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


def snap_footprints(footprints: npt.ArrayLike) -> np.ndarray:
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


def extrude(
    footprints: npt.ArrayLike,
    ground: npt.ArrayLike,
    roof: npt.ArrayLike,
    *,
    numbering: str = "building",
) -> Prisms:
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
    >>> p.vertices.shape, p.face_kind.tolist()
    ((8, 3), [0, 1, 2, 2, 2, 2])
    >>> p.vertices[p.ring_vertices[p.ring_start[1]:p.ring_start[2]]].tolist()  # the roof
    [[2000, 0, 13500], [2000, 1000, 13500], [0, 1000, 13500], [0, 0, 13500]]
    """
    if numbering not in ("building", "all"):
        raise ValueError(f"numbering must be 'building' or 'all', not {numbering!r}")
    footprints = np.asarray(footprints, dtype=object)
    ground_mm = np.rint(np.asarray(ground, dtype=float) * 1000).astype(np.int64)
    roof_mm = np.rint(np.asarray(roof, dtype=float) * 1000).astype(np.int64)
    part_building, ring_part, xy, size = _ring_points(footprints)
    start = np.concatenate([[0], np.cumsum(size)])
    point_ring = np.repeat(np.arange(len(ring_part)), size)
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
    n_rings, n_points = len(ring_part), len(xy)
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


def _ring_points(footprints: np.ndarray):
    """The footprints' polygons (parts) and rings: each part's building, each ring's part,
    the rings' points in mm without their closing ones, and each ring's number of points."""
    parts, part_building = shapely.get_parts(footprints, return_index=True)
    rings, ring_part = shapely.get_rings(parts, return_index=True)
    coords, coord_ring = shapely.get_coordinates(rings, return_index=True)
    closed_size = np.bincount(coord_ring, minlength=len(rings))
    last = np.cumsum(closed_size) - 1
    keep = np.ones(len(coords), dtype=bool)
    keep[last] = False  # drop each ring's closing point
    xy = np.rint(coords[keep] * 1000).astype(np.int64)
    return part_building, ring_part, xy, closed_size - 1


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


def _ragged_take(values: np.ndarray, starts: np.ndarray, sizes: np.ndarray) -> np.ndarray:
    """``concatenate([values[s:s + k] for s, k in zip(starts, sizes)])``, vectorised."""
    offsets = np.cumsum(sizes) - sizes
    return values[np.repeat(starts - offsets, sizes) + np.arange(sizes.sum())]


def part_ids(ids: Iterable[str], footprints: npt.ArrayLike) -> list[list[str]]:
    """Per building, the ids of its parts (``<id>-1``, ...; none for a single polygon)."""
    geoms = np.asarray(footprints, dtype=object)
    counts = np.where(shapely.get_type_id(geoms) == 3, 0, shapely.get_num_geometries(geoms))
    counts = counts.tolist()
    return [[f"{i}-{k}" for k in range(1, n + 1)] for i, n in zip(ids, counts, strict=True)]

"""LOD1 prisms as triangle meshes on the Earth: what a 3D viewer draws.

A building's footprint (snapped to the millimetre and oriented,
:func:`~gnss_citygml.export.prisms.snap_footprints`: exteriors anticlockwise, holes clockwise)
becomes its walls (one quad, two triangles, per ring edge), its roof at ``top`` and its floor
at ``bottom`` (the polygon's constrained Delaunay triangles, holes kept). Every vertex is
placed in Earth-centred, Earth-fixed coordinates through the official transformation: British
National Grid + ODN height -> ETRS89 latitude, longitude and ellipsoidal height with OSTN15 and
OSGM15 (:func:`gnss_citygml.geodesy.from_osgb`, never a ballpark), then ETRS89 geocentric
(EPSG:4936), which web viewers take as WGS 84's (EPSG:4978; the two frames part by well under
a metre, the convention of Ordnance Survey's own web maps). The (E, N) pairs are transformed
once each: the ellipsoidal height is the ODN height plus the geoid's height there.

Faces do not share vertices, so each carries its own normal (flat shading, as a block model
looks). All of it is numpy and shapely over all buildings of a tile at once.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np
import shapely
from pyproj import Transformer

from ..files.paths import StrPath
from ..geodesy import from_osgb

__all__ = ["Mesh", "prism_mesh"]


@dataclass(frozen=True)
class Mesh:
    """Triangles of many buildings, in ECEF (m): ``ecef`` (V, 3) float64, ``normals`` (V, 3)
    float32 unit vectors, ``feature`` (V,) the building (row) of each vertex, ``indices``
    (T, 3) uint32; and each vertex's geodetic ``lon``, ``lat`` (radians) and ellipsoidal
    height ``h`` (m), for the bounding regions."""

    ecef: np.ndarray
    normals: np.ndarray
    feature: np.ndarray
    indices: np.ndarray
    lon: np.ndarray
    lat: np.ndarray
    h: np.ndarray


def prism_mesh(
    footprints: np.ndarray,
    bottom: np.ndarray,
    top: np.ndarray,
    grid_dir: StrPath | None = None,
) -> Mesh:
    """The prisms of ``footprints`` (snapped, oriented Polygons and MultiPolygons, EPSG:27700)
    from ``bottom`` to ``top`` (m ODN), one feature per footprint."""
    polygons, owner = shapely.get_parts(footprints, return_index=True)
    e, n, z, feature, wall = _walls(polygons, owner, bottom, top)
    ce, cn, cz, cfeature = _caps(polygons, owner, bottom, top)
    e, n, z = np.r_[e, ce], np.r_[n, cn], np.r_[z, cz]
    feature = np.r_[feature, cfeature]
    lon, lat, h = _geodetic(e, n, z, grid_dir)
    x, y, zz = _geocentric().transform(np.degrees(lon), np.degrees(lat), h)
    ecef = np.column_stack([x, y, zz])
    quads = np.arange(wall, dtype=np.uint32).reshape(-1, 4)
    indices = np.concatenate(
        [quads[:, [0, 1, 2]], quads[:, [0, 2, 3]], wall + np.arange(len(e) - wall).reshape(-1, 3)]
    ).astype(np.uint32)
    normals = _normals(ecef, quads, wall)
    return Mesh(ecef, normals, feature, indices, lon, lat, h)


@functools.cache
def _geocentric() -> Transformer:
    """ETRS89 geographic 3D (EPSG:4937) -> ETRS89 geocentric (EPSG:4936): a conversion."""
    return Transformer.from_crs("EPSG:4937", "EPSG:4936", always_xy=True, allow_ballpark=False)


def _walls(polygons, owner, bottom, top):
    """Each ring edge's quad (p bottom, q bottom, q top, p top), counter-clockwise seen from
    outside: exteriors run anticlockwise and holes clockwise, so the outside is on the right."""
    rings, polygon = shapely.get_rings(polygons, return_index=True)
    xy, ring = shapely.get_coordinates(rings, return_index=True)
    edge = np.flatnonzero(ring[:-1] == ring[1:])  # p = xy[edge], q = xy[edge + 1]
    building = owner[polygon[ring[edge]]]
    p, q = xy[edge], xy[edge + 1]
    e = np.column_stack([p[:, 0], q[:, 0], q[:, 0], p[:, 0]]).ravel()
    n = np.column_stack([p[:, 1], q[:, 1], q[:, 1], p[:, 1]]).ravel()
    low, high = bottom[building], top[building]
    z = np.column_stack([low, low, high, high]).ravel()
    return e, n, z, np.repeat(building, 4), len(e)


def _caps(polygons, owner, bottom, top):
    """Each polygon's roof (anticlockwise triangles, seen from above) and floor (the same,
    reversed: seen from below)."""
    triangles, polygon = shapely.get_parts(
        shapely.constrained_delaunay_triangles(polygons), return_index=True
    )
    xy = shapely.get_coordinates(triangles).reshape(-1, 4, 2)[:, :3]
    a, b, c = xy[:, 0], xy[:, 1], xy[:, 2]
    clockwise = (b[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1]) - (b[:, 1] - a[:, 1]) * (
        c[:, 0] - a[:, 0]
    ) < 0
    xy[clockwise] = xy[clockwise][:, [0, 2, 1]]
    building = owner[polygon]
    roof, floor = xy, xy[:, ::-1]
    both = np.concatenate([roof, floor]).reshape(-1, 2)
    z = np.r_[np.repeat(top[building], 3), np.repeat(bottom[building], 3)]
    return both[:, 0], both[:, 1], z, np.tile(np.repeat(building, 3), 2)


def _geodetic(e, n, z, grid_dir):
    """ETRS89 longitude, latitude (radians) and ellipsoidal height of BNG + ODN points, each
    distinct (E, N) transformed once (to the millimetre of the snapped footprints)."""
    keys = np.rint(e * 1000).astype(np.int64) * 2_000_000_000 + np.rint(n * 1000).astype(np.int64)
    unique, first, back = np.unique(keys, return_index=True, return_inverse=True)
    lat, lon, geoid = from_osgb(e[first], n[first], np.zeros(unique.size), grid_dir=grid_dir)
    return np.radians(lon)[back], np.radians(lat)[back], geoid[back] + z


def _normals(ecef, quads, wall):
    """Each face's outward unit normal, on its vertices: a wall's from its bottom edge and its
    side, a triangle's from two of its edges."""
    p = ecef[quads[:, 0]]
    wall_normal = np.cross(ecef[quads[:, 1]] - p, ecef[quads[:, 3]] - p)
    tri = ecef[wall:].reshape(-1, 3, 3)
    tri_normal = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    normals = np.concatenate([np.repeat(wall_normal, 4, axis=0), np.repeat(tri_normal, 3, axis=0)])
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    return normals.astype(np.float32)

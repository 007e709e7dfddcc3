"""Where satellite rays first enter building footprints: vectorised 2D ray casting.

A ray leaves its receiver on a grid bearing (degrees clockwise from grid north) and rises with
slope ``tan(elevation)``. In plan it is a segment of length ``max_range``; it *enters* a
footprint at the first point where it crosses the footprint's boundary (exterior ring or a hole;
multipolygons are one footprint). An STRtree prunes ray x footprint pairs, then the distance to
the first boundary crossing is found for all candidate (pair, edge) combinations at once with
numpy, batch by batch of rays, the batches in threads (:mod:`.threads`). A ray starting
inside a footprint enters nothing there: a receiver cannot be inside a building, so such a pair
says nothing about the building and is left out.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
import numpy.typing as npt
import shapely

from .threads import in_threads, threads

__all__ = ["footprint_entries"]

#: Rays cast per batch, and (ray x footprint, edge) combinations per numpy chunk within a
#: batch: they bound the memory of a large cast and keep its arrays in the CPU's cache.
_RAYS = 1 << 13
_CHUNK = 1 << 16


class _Shapes(NamedTuple):
    """The footprints as the cast reads them, each part derived once (the same arithmetic as
    per pair, so the same bits): the shapes; their boxes, rows xmin, ymin, xmax, ymax
    (``bounds``) and cx, cy, hx, hy (centre and half sizes, ``box``); and their boundary edges,
    rows x1, y1 (first point), ex, ey (second point minus first), with their ``length``
    (floored at 1e-12 m), footprint ``f``'s ``edge_count[f]`` from ``first_edge[f]`` on."""

    shapes: np.ndarray
    bounds: np.ndarray
    box: np.ndarray
    edges: np.ndarray
    length: np.ndarray
    first_edge: np.ndarray
    edge_count: np.ndarray

    @classmethod
    def of(cls, footprints: np.ndarray) -> _Shapes:
        bounds = shapely.bounds(footprints).T
        half = 0.5 * (bounds[2:] - bounds[:2])
        seg, start, count = _edges(footprints)
        edges = np.vstack([seg[:, :2].T, (seg[:, 2:] - seg[:, :2]).T])
        length = np.maximum(np.hypot(edges[2], edges[3]), 1e-12)
        box = np.vstack([bounds[:2] + half, half])
        return cls(footprints, bounds, box, edges, length, start, count)


def footprint_entries(
    x: npt.ArrayLike,
    y: npt.ArrayLike,
    bearing: npt.ArrayLike,
    footprints: npt.ArrayLike,
    max_range: float = 500.0,
    *,
    gradient: bool = False,
    shifts: npt.ArrayLike | None = None,
) -> tuple[np.ndarray, ...]:
    """The distance along each ray to each footprint it enters within ``max_range``.

    Parameters
    ----------
    x, y
        Ray origins (grid easting and northing, m).
    bearing
        Grid bearing of each ray (deg clockwise from grid north).
    footprints
        Sequence or array of shapely Polygons / MultiPolygons in the same grid.
    max_range
        Horizontal length of the rays (m).
    gradient
        Also return how each distance changes with the ray's origin.
    shifts
        Optional moves (m, in the grid) of the origins, ``(k, 2)`` for every ray or
        ``(n, k, 2)`` for each: each ray is cast from each of its moved origins, ray ``i`` from
        move ``j`` numbered ``i * k + j`` (one pruning query a ray for all its moves: shadow
        matching's candidate positions).

    Returns
    -------
    (ray, footprint, distance, incidence)
        Integer index of the ray and of the footprint, the horizontal distance (m) from the
        origin to the entry point, and the cosine of the angle between the ray and the normal of
        the wall it enters through (1 head-on, near 0 grazing), one entry per ray x footprint
        crossing, sorted by ray and distance. With ``gradient``, a fifth array of shape
        ``(n, 2)``: the derivative of the distance with respect to the origin's ``x`` and ``y``
        (the entry wall held fixed), e.g. ``(-1, 0)`` for a wall straight ahead to the east.

    Examples
    --------
    >>> square = shapely.box(10, -5, 20, 5)
    >>> footprint_entries([0.0], [0.0], [90.0], [square])
    (array([0]), array([0]), array([10.]), array([1.]))
    """
    x = np.asarray(x, dtype=float)
    y = np.asarray(y, dtype=float)
    rad = np.radians(np.asarray(bearing, dtype=float))
    dx, dy = np.sin(rad), np.cos(rad)
    moves = np.zeros((1, 1, 2)) if shifts is None else np.asarray(shifts, dtype=float)
    moves = moves[None] if moves.ndim == 2 else moves
    k = moves.shape[1]
    footprints = np.asarray(footprints, dtype=object)
    if x.size == 0 or footprints.size == 0 or k == 0:
        return _nothing(gradient)
    tree = shapely.STRtree(footprints)
    shapes = _Shapes.of(footprints)
    step = max(1, _RAYS // k)

    def batch(lo: int) -> tuple[np.ndarray, ...]:
        rays = slice(lo, lo + step)
        some = moves[rays] if len(moves) > 1 else moves
        pairs = _pairs(x[rays], y[rays], dx[rays], dy[rays], tree, max_range, some)
        ray, fp, *rest = _entries(
            (x[rays, None] + some[:, :, 0]).ravel(),
            (y[rays, None] + some[:, :, 1]).ravel(),
            np.repeat(dx[rays], k),
            np.repeat(dy[rays], k),
            pairs,
            shapes,
            max_range,
            gradient,
        )
        return (ray + lo * k, fp, *rest)

    starts = range(0, x.size, step)  # batches of rays in threads, joined in order: one pass's
    batches = in_threads(batch, starts, min(threads(), len(starts)))
    return tuple(np.concatenate(column) for column in zip(*batches, strict=True))


def _nothing(gradient: bool) -> tuple[np.ndarray, ...]:
    """:func:`footprint_entries`' answer where no ray enters anything."""
    none = (np.array([], dtype=np.intp), np.array([], dtype=np.intp), np.array([]), np.array([]))
    return (*none, np.zeros((0, 2))) if gradient else none


def _pairs(x, y, dx, dy, tree, max_range, moves):
    """The (ray, footprint) pairs whose bounding boxes overlap (the tree's query, by envelope),
    each ray's box that of its segment from every moved origin; rays numbered
    ``ray * len(moves) + move``."""
    ex, ey = x + dx * max_range, y + dy * max_range
    low, high = moves.min(axis=1), moves.max(axis=1)  # (rays or 1, 2)
    corners = np.stack(  # the box's diagonal: a line has the box as its envelope
        [
            np.column_stack([np.minimum(x, ex) + low[:, 0], np.minimum(y, ey) + low[:, 1]]),
            np.column_stack([np.maximum(x, ex) + high[:, 0], np.maximum(y, ey) + high[:, 1]]),
        ],
        axis=1,
    )
    ray, fp = tree.query(shapely.linestrings(corners))
    k = moves.shape[1]
    return (ray[:, None] * k + np.arange(k)).ravel(), np.repeat(fp, k)


def _entries(x, y, dx, dy, pairs, shapes, max_range, gradient=False):
    """:func:`footprint_entries` for one batch of rays and their candidate ``pairs``: an exact
    ray x bounding-box test in numpy, then the distance to each entry wall."""
    ray_idx, fp_idx = pairs
    cx, cy, hx, hy = _at(shapes.box, fp_idx)
    near = _crosses_box(x[ray_idx], y[ray_idx], dx[ray_idx], dy[ray_idx], cx, cy, hx, hy)
    ray_idx, fp_idx = ray_idx[near], fp_idx[near]
    px, py = x[ray_idx], y[ray_idx]
    outside = ~_inside(px, py, fp_idx, shapes)
    ray_idx, fp_idx = ray_idx[outside], fp_idx[outside]
    ray = (px[outside], py[outside], dx[ray_idx], dy[ray_idx])
    found = _first_crossings(*ray, fp_idx, shapes, gradient)
    keep = np.flatnonzero(found[0] <= max_range)
    order = keep[_by_ray_and_distance(ray_idx[keep], found[0][keep], x.size)]
    return tuple(column[order] for column in (ray_idx, fp_idx, *found))


def _by_ray_and_distance(ray, dist, n):
    """The order sorting entries by ray, then distance, ties kept in their order (lexsort's):
    by distance, then by ray in a stable radix sort of the ray numbers (``n`` rays) in the
    fewest bits. The sort by distance is a fast unstable one unless two entries of one ray are
    at the same distance, the only ones whose order it could change."""
    key = ray.astype(np.min_scalar_type(n))
    order = _then_by(key, np.argsort(dist))
    along, at = ray[order], dist[order]
    if np.any((along[1:] == along[:-1]) & (at[1:] == at[:-1])):
        order = _then_by(key, np.argsort(dist, kind="stable"))
    return order


def _then_by(key, order):
    """``order`` sorted by ``key``, stably."""
    return order[np.argsort(key[order], kind="stable")]


def _inside(x, y, fp_idx, shapes):
    """Whether each origin is inside (or on the boundary of) its pair's footprint; asked of
    shapely only for the origins inside the footprint's box, the only ones that can be."""
    xmin, ymin, xmax, ymax = _at(shapes.bounds, fp_idx)
    maybe = np.flatnonzero((x >= xmin) & (x <= xmax) & (y >= ymin) & (y <= ymax))
    inside = np.zeros(x.size, dtype=bool)
    inside[maybe] = shapely.intersects_xy(shapes.shapes[fp_idx[maybe]], x[maybe], y[maybe])
    return inside


def _first_crossings(x, y, dx, dy, fp_idx, shapes, gradient):
    """For each ray (origin ``x``, ``y``, unit direction ``dx``, ``dy``) and its footprint,
    the distance to the first boundary crossing (inf if none), the cosine of incidence there
    and, with ``gradient``, the distance's derivative with respect to the origin: every edge
    of the footprint tried, in chunks of about :data:`_CHUNK` (pair, edge) combinations."""
    dist = np.full(x.size, np.inf)
    cos_inc = np.zeros(x.size)
    grad = np.zeros((x.size if gradient else 0, 2))
    per_pair = shapes.edge_count[fp_idx]
    bounds = np.concatenate([[0], np.cumsum(per_pair)])
    inner = np.searchsorted(bounds, np.arange(_CHUNK, bounds[-1], _CHUNK))
    cuts = np.unique(np.concatenate([[0], inner, [x.size]]))
    for lo, hi in zip(cuts[:-1], cuts[1:], strict=True):
        counts = per_pair[lo:hi]
        rep = np.repeat(np.arange(lo, hi), counts)
        # combination g of pair p is edge first_edge[fp] + g - bounds[p] of its footprint
        shift = shapes.first_edge[fp_idx[lo:hi]] - bounds[lo:hi]
        edge = np.arange(bounds[lo], bounds[hi]) + np.repeat(shift, counts)
        x1, y1, ex, ey = _at(shapes.edges, edge)
        t, denom = _ray_segment_distance(x[rep], y[rep], dx[rep], dy[rep], x1, y1, ex, ey)
        dist[lo:hi] = np.minimum.reduceat(t, bounds[lo:hi] - bounds[lo])
        first = np.flatnonzero(np.isfinite(t) & (t == np.repeat(dist[lo:hi], counts)))
        cos_inc[rep[first]] = np.abs(denom[first]) / shapes.length[edge[first]]
        if gradient:  # d t / d origin for the entry edge: t = (q x edge) / (ray x edge)
            grad[rep[first]] = np.column_stack([-ey[first], ex[first]]) / denom[first, None]
    return (dist, cos_inc, grad) if gradient else (dist, cos_inc)


def _at(rows, index):
    """Each of the ``rows`` (a 2D array) at ``index``, gathered row by row: several times
    faster than numpy's ``rows[:, index]``."""
    return [row[index] for row in rows]


def _crosses_box(x, y, dx, dy, cx, cy, hx, hy):
    """Whether the line through each origin (unit direction ``dx``, ``dy``) passes through the
    axis-aligned box of centre (cx, cy) and half sizes (hx, hy): the separating-axis test
    along the line's normal. With the boxes of the ray segment and the footprint overlapping
    (the tree query), this makes the segment x box test exact."""
    return np.abs(dx * (cy - y) - dy * (cx - x)) <= hx * np.abs(dy) + hy * np.abs(dx)


def _edges(footprints):
    """All boundary edges (x1, y1, x2, y2) of every footprint, grouped by footprint."""
    boundaries = shapely.boundary(footprints)
    parts, part_of = shapely.get_parts(boundaries, return_index=True)
    coords, coord_of = shapely.get_coordinates(parts, return_index=True)
    same = coord_of[1:] == coord_of[:-1]
    seg = np.column_stack([coords[:-1][same], coords[1:][same]])
    seg_fp = part_of[coord_of[:-1][same]]
    order = np.argsort(seg_fp, kind="stable")
    seg, seg_fp = seg[order], seg_fp[order]
    count = np.bincount(seg_fp, minlength=len(footprints))
    start = np.concatenate([[0], np.cumsum(count)[:-1]])
    return seg, start, count


def _ray_segment_distance(x, y, dx, dy, x1, y1, ex, ey):
    """Distance along rays (unit direction dx, dy) to segments from (x1, y1) to (x1 + ex,
    y1 + ey) (inf where they miss), and the cross product of ray and segment directions."""
    denom = dx * ey - dy * ex
    qx, qy = x1 - x, y1 - y
    with np.errstate(divide="ignore", invalid="ignore"):
        t = (qx * ey - qy * ex) / denom
        u = (qx * dy - qy * dx) / denom
    hit = (np.abs(denom) > 1e-12) & (t >= 0) & (u >= 0) & (u <= 1)
    return np.where(hit, t, np.inf), denom

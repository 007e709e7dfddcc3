"""Where satellite rays first enter building footprints: vectorised 2D ray casting.

A ray leaves its receiver on a grid bearing (degrees clockwise from grid north) and rises with
slope ``tan(elevation)``. In plan it is a segment of length ``max_range``; it *enters* a
footprint at the first point where it crosses the footprint's boundary (exterior ring or a hole;
multipolygons are one footprint). An STRtree prunes ray x footprint pairs, then the distance to
the first boundary crossing is found for all candidate (pair, edge) combinations at once with
numpy, batch by batch of rays, the batches in threads (:mod:`.threads`). A ray starting
inside a footprint enters nothing there: a receiver cannot be inside a building, so such a pair
says nothing about the building and is left out.

*Near misses.* A receiver's position error moves its ray sideways: it may miss a footprint it
enters as cast, or enter one it passes. With a ``reach`` (m across the ray), each entry says how
far its footprint's boundary within the ray's length (0 to ``max_range`` along it) lies to the
ray's right (negative) and left (positive), ``across``: the ray misses the footprint once its
origin moves more than ``-across[0]`` to the right or ``across[1]`` to the left. A footprint the
ray passes within the reach gives an entry too, both of one sign, at the distance and incidence
of its point nearest the ray's line (where the moved ray would touch it).
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
    reach: npt.ArrayLike | None = None,
    sidestep: npt.ArrayLike | None = None,
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
        Optional moves (m) of the origins, ``(k, 2)`` for every ray or ``(n, k, 2)`` for each:
        each ray is cast from each moved origin, ray ``i`` from move ``j`` numbered ``i * k +
        j`` (one pruning query a ray for all its moves: shadow matching's candidates).
    reach, sidestep
        Optional distances (m, one for every ray or one each) across the ray: near misses
        within ``reach`` (above); ``across`` with two more columns, the first crossing of the
        ray moved ``sidestep`` to its right and to its left (needs ``reach``).

    Returns
    -------
    (ray, footprint, distance, incidence)
        Index of the ray and of the footprint, the horizontal distance (m) to the entry, and the
        cosine of incidence on the wall entered (1 head-on, near 0 grazing), one entry per ray x
        footprint crossing, sorted by ray and distance. With ``gradient``, a fifth ``(n, 2)``
        array: the distance's derivative in the origin's ``x`` and ``y`` (the entry wall held
        fixed; ``(-1, 0)`` for a wall ahead to the east). With ``reach``, ``across`` (above).

    Examples
    --------
    >>> square = shapely.box(10, -5, 20, 5)
    >>> footprint_entries([0.0], [0.0], [90.0], [square])
    (array([0]), array([0]), array([10.]), array([1.]))
    >>> footprint_entries([0.0, 0.0], [0.0, 7.0], [90.0, 90.0], [square], reach=3.0)[-1]
    array([[ -5.,   5.],
           [-12.,  -2.]])
    """
    x, y = np.asarray(x, dtype=float), np.asarray(y, dtype=float)
    dx, dy = (f(np.radians(np.asarray(bearing, dtype=float))) for f in (np.sin, np.cos))
    moves = np.zeros((1, 1, 2)) if shifts is None else np.asarray(shifts, dtype=float)
    moves = moves[None] if moves.ndim == 2 else moves
    k = moves.shape[1]
    wide, aside = (_each(v, x.size) for v in (reach, None if reach is None else sidestep))
    footprints = np.asarray(footprints, dtype=object)
    if x.size == 0 or footprints.size == 0 or k == 0:
        return _nothing(gradient, wide is not None, aside is not None)
    tree = shapely.STRtree(footprints)
    shapes = _Shapes.of(footprints)
    step = max(1, _RAYS // k)

    def batch(lo: int) -> tuple[np.ndarray, ...]:
        rays = slice(lo, lo + step)
        some = moves[rays] if len(moves) > 1 else moves
        near = None if wide is None else wide[rays]
        pairs = _pairs(x[rays], y[rays], dx[rays], dy[rays], tree, max_range, some, near)
        ox, oy = ((v[rays, None] + some[:, :, i]).ravel() for i, v in enumerate((x, y)))
        way = (np.repeat(dx[rays], k), np.repeat(dy[rays], k))
        near, sides = (None if v is None else np.repeat(v[rays], k) for v in (wide, aside))
        ray, fp, *rest = _entries(ox, oy, *way, pairs, shapes, max_range, gradient, near, sides)
        return (ray + lo * k, fp, *rest)

    starts = range(0, x.size, step)  # batches of rays in threads, joined in order: one pass's
    batches = in_threads(batch, starts, min(threads(), len(starts)))
    return tuple(np.concatenate(column) for column in zip(*batches, strict=True))


def _each(value: npt.ArrayLike | None, n: int) -> np.ndarray | None:
    """``value`` (one, or one each) for each of ``n`` rays; None stays None."""
    return None if value is None else np.broadcast_to(np.asarray(value, dtype=float), (n,))


def _nothing(gradient: bool, sides: bool, steps: bool) -> tuple[np.ndarray, ...]:
    """:func:`footprint_entries`' answer where no ray enters anything."""
    none = (np.array([], dtype=np.intp), np.array([], dtype=np.intp), np.array([]), np.array([]))
    return none + (np.zeros((0, 2)),) * gradient + (np.zeros((0, 4 if steps else 2)),) * sides


def _pairs(x, y, dx, dy, tree, max_range, moves, reach=None):
    """The (ray, footprint) pairs whose bounding boxes overlap (the tree's query, by envelope),
    each ray's box that of its segment from every moved origin, widened by its ``reach``;
    rays numbered ``ray * len(moves) + move``."""
    ex, ey = x + dx * max_range, y + dy * max_range
    low, high = moves.min(axis=1), moves.max(axis=1)  # (rays or 1, 2)
    if reach is not None:
        low, high = low - reach[:, None], high + reach[:, None]
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


def _entries(x, y, dx, dy, pairs, shapes, max_range, gradient=False, reach=None, step=None):
    """:func:`footprint_entries` for one batch of rays and their candidate ``pairs``: an exact
    ray x bounding-box test in numpy (the box widened by each ray's ``reach``), then the
    distance to each entry wall (with ``reach``, or to each near miss's nearest point)."""
    ray_idx, fp_idx = pairs
    cx, cy, hx, hy = _at(shapes.box, fp_idx)
    wide = 0.0 if reach is None else reach[ray_idx]
    near = _crosses_box(x[ray_idx], y[ray_idx], dx[ray_idx], dy[ray_idx], cx, cy, hx, hy, wide)
    ray_idx, fp_idx = ray_idx[near], fp_idx[near]
    px, py = x[ray_idx], y[ray_idx]
    outside = ~_inside(px, py, fp_idx, shapes)
    ray_idx, fp_idx = ray_idx[outside], fp_idx[outside]
    ray = (px[outside], py[outside], dx[ray_idx], dy[ray_idx])
    found = _first_crossings(*ray, fp_idx, shapes, gradient)
    keep = found[0] <= max_range
    if reach is not None:
        moved = None if step is None else step[ray_idx]
        across = _across(*ray, fp_idx, shapes, max_range, moved)
        found, keep = _near_misses(found, across, keep, reach[ray_idx], gradient)
    keep = np.flatnonzero(keep)
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
    of the footprint tried (:func:`_combinations`)."""
    dist = np.full(x.size, np.inf)
    cos_inc = np.zeros(x.size)
    grad = np.zeros((x.size if gradient else 0, 2))
    for lo, hi, rep, edge, starts in _combinations(fp_idx, shapes):
        x1, y1, ex, ey = _at(shapes.edges, edge)
        t, denom = _ray_segment_distance(x[rep], y[rep], dx[rep], dy[rep], x1, y1, ex, ey)
        dist[lo:hi] = np.minimum.reduceat(t, starts)
        first = np.flatnonzero(np.isfinite(t) & (t == dist[rep]))
        cos_inc[rep[first]] = np.abs(denom[first]) / shapes.length[edge[first]]
        if gradient:  # d t / d origin for the entry edge: t = (q x edge) / (ray x edge)
            grad[rep[first]] = np.column_stack([-ey[first], ex[first]]) / denom[first, None]
    return (dist, cos_inc, grad) if gradient else (dist, cos_inc)


def _across(x, y, dx, dy, fp_idx, shapes, max_range, step=None):
    """For each ray and its footprint, how far the footprint's boundary within the ray's
    reach (0 to ``max_range`` along it) lies to the ray's right (negative) and left
    (positive), ``(n, 2)``, and with ``step`` (m, per pair) two more columns, the distance to
    the first crossing of the ray moved ``step`` to its right and to its left (inf: none); and
    the distance along the ray and the cosine of incidence of the boundary point nearest the
    ray's line (where a ray moved sideways would first touch it; of several within a
    nanometre, the first along the ray)."""
    side = np.full((x.size, 2 if step is None else 4), np.inf)
    side[:, 1] = -np.inf
    along = np.full(x.size, np.inf)
    cos_inc = np.zeros(x.size)
    for lo, hi, rep, edge, starts in _combinations(fp_idx, shapes):
        x1, y1, ex, ey = _at(shapes.edges, edge)
        rx, ry = dx[rep], dy[rep]
        qx, qy = x1 - x[rep], y1 - y[rep]
        t1, dt = qx * rx + qy * ry, ex * rx + ey * ry  # along the ray, and its change on the edge
        s1, ds = rx * qy - ry * qx, rx * ey - ry * ex  # across it (left positive)
        u_lo, u_hi = _clipped(t1, dt, max_range)  # the edge's part within the ray's reach
        inside = u_lo <= u_hi
        s_lo, s_hi = s1 + u_lo * ds, s1 + u_hi * ds
        side[lo:hi, 0] = np.minimum.reduceat(
            np.where(inside, np.minimum(s_lo, s_hi), np.inf), starts
        )
        side[lo:hi, 1] = np.maximum.reduceat(
            np.where(inside, np.maximum(s_lo, s_hi), -np.inf), starts
        )
        u = np.where(np.abs(s_lo) <= np.abs(s_hi), u_lo, u_hi)  # the part's end nearest the line
        gap = np.where(inside, np.abs(s1 + u * ds), np.inf)
        nearest = gap <= np.minimum.reduceat(gap, starts)[rep - lo] + 1e-9  # ties: rounding
        at = np.where(nearest & np.isfinite(gap), t1 + u * dt, np.inf)  # the first such point
        along[lo:hi] = np.minimum.reduceat(at, starts)
        first = np.flatnonzero(np.isfinite(at) & (at == along[rep]))
        cos_inc[rep[first]] = np.abs(ds[first]) / shapes.length[edge[first]]
        if step is not None:
            for column, moved in ((2, -step[rep]), (3, step[rep])):
                with np.errstate(divide="ignore", invalid="ignore"):
                    at_edge = (moved - s1) / ds  # where the moved ray's line crosses the edge
                    t = t1 + at_edge * dt
                hit = (at_edge >= 0) & (at_edge <= 1) & (t >= 0) & (t <= max_range)
                side[lo:hi, column] = np.minimum.reduceat(np.where(hit, t, np.inf), starts)
    return side, along, cos_inc


def _clipped(t1, dt, max_range):
    """The part ``u`` in [u_lo, u_hi] of each edge (``t1 + u dt`` along the ray, ``u`` from 0
    to 1) that lies 0 to ``max_range`` along the ray; empty where u_lo > u_hi."""
    flat = dt == 0
    with np.errstate(divide="ignore", invalid="ignore"):
        ua, ub = -t1 / dt, (max_range - t1) / dt
    within = (t1 >= 0) & (t1 <= max_range)
    u_lo = np.where(flat, np.where(within, 0.0, 1.0), np.maximum(np.fmin(ua, ub), 0.0))
    u_hi = np.where(flat, np.where(within, 1.0, 0.0), np.minimum(np.fmax(ua, ub), 1.0))
    return u_lo, u_hi


def _near_misses(found, across, entered, reach, gradient):
    """:func:`_entries`' columns with each footprint's extent ``across`` its ray (from
    :func:`_across`) added, and which pairs to keep: those ``entered``, and those the ray passes
    within its ``reach`` of, at the distance and incidence of their point nearest the ray
    (their gradient 0: no wall is entered)."""
    side, along, cos_near = across
    lo, hi = side[:, 0], side[:, 1]
    gap = np.where(lo > 0, lo, np.where(hi < 0, -hi, np.inf))
    near = ~entered & (gap <= reach)
    dist, cos_inc, *grad = found
    dist = np.where(near, along, dist)
    cos_inc = np.where(near, cos_near, cos_inc)
    if gradient:
        grad[0][near] = 0.0
    return (dist, cos_inc, *grad, side), entered | near


def _combinations(fp_idx, shapes):
    """The (pair, edge) combinations of each ray x footprint pair with every edge of its
    footprint, in chunks of about :data:`_CHUNK`: each chunk's first and last pair (``lo``,
    ``hi``), each combination's pair (``rep``) and edge, and where each pair's run of
    combinations starts in the chunk (for ``reduceat``)."""
    per_pair = shapes.edge_count[fp_idx]
    bounds = np.concatenate([[0], np.cumsum(per_pair)])
    inner = np.searchsorted(bounds, np.arange(_CHUNK, bounds[-1], _CHUNK))
    cuts = np.unique(np.concatenate([[0], inner, [fp_idx.size]]))
    for lo, hi in zip(cuts[:-1], cuts[1:], strict=True):
        counts = per_pair[lo:hi]
        rep = np.repeat(np.arange(lo, hi), counts)
        # combination g of pair p is edge first_edge[fp] + g - bounds[p] of its footprint
        shift = shapes.first_edge[fp_idx[lo:hi]] - bounds[lo:hi]
        edge = np.arange(bounds[lo], bounds[hi]) + np.repeat(shift, counts)
        yield lo, hi, rep, edge, bounds[lo:hi] - bounds[lo]


def _at(rows, index):
    """Each of the ``rows`` (a 2D array) at ``index``, gathered row by row: several times
    faster than numpy's ``rows[:, index]``."""
    return [row[index] for row in rows]


def _crosses_box(x, y, dx, dy, cx, cy, hx, hy, reach=0.0):
    """Whether the line through each origin (unit direction ``dx``, ``dy``) passes through the
    axis-aligned box of centre (cx, cy) and half sizes (hx, hy), or within ``reach`` of it:
    the separating-axis test along the line's normal. With the boxes of the ray segment and
    the footprint overlapping (the tree query), this makes the segment x box test exact."""
    return np.abs(dx * (cy - y) - dy * (cx - x)) <= hx * np.abs(dy) + hy * np.abs(dx) + reach


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

"""Where satellite rays first enter building footprints: vectorised 2D ray casting.

A ray leaves its receiver on a grid bearing (degrees clockwise from grid north) and rises with
slope ``tan(elevation)``. In plan it is a segment of length ``max_range``; it *enters* a
footprint at the first point where it crosses the footprint's boundary (exterior ring or a hole;
multipolygons are one footprint). An STRtree prunes ray x footprint pairs, then the distance to
the first boundary crossing is found for all candidate (pair, edge) combinations at once with
numpy. A ray starting inside a footprint enters nothing there: a receiver cannot be inside a
building, so such a pair says nothing about the building and is left out.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt
import shapely

__all__ = ["footprint_entries"]

#: Rays cast per batch, and (ray x footprint, edge) combinations per numpy chunk within a
#: batch: they bound the memory of a large cast and keep its arrays in the CPU cache.
_RAYS = 1 << 15
_CHUNK = 1 << 18


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
    geometry = (footprints, shapely.bounds(footprints), _edges(footprints))
    batches = []
    step = max(1, _RAYS // k)
    for lo in range(0, x.size, step):
        rays = slice(lo, lo + step)
        some = moves[rays] if len(moves) > 1 else moves
        pairs = _pairs(x[rays], y[rays], dx[rays], dy[rays], tree, max_range, some)
        ray, fp, *rest = _entries(
            (x[rays, None] + some[:, :, 0]).ravel(),
            (y[rays, None] + some[:, :, 1]).ravel(),
            np.repeat(dx[rays], k),
            np.repeat(dy[rays], k),
            pairs,
            *geometry,
            max_range,
            gradient,
        )
        batches.append((ray + lo * k, fp, *rest))
    out = tuple(np.concatenate(column) for column in zip(*batches, strict=True))
    return out if gradient else out[:4]


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


def _entries(x, y, dx, dy, pairs, footprints, boxes, edges, max_range, gradient=False):
    """:func:`footprint_entries` for one batch of rays and their candidate ``pairs``: an exact
    ray x bounding-box test in numpy, then the distance to each entry wall."""
    ray_idx, fp_idx = pairs
    near = _crosses_box(x[ray_idx], y[ray_idx], dx[ray_idx], dy[ray_idx], boxes[fp_idx])
    ray_idx, fp_idx = ray_idx[near], fp_idx[near]
    inside = shapely.intersects_xy(footprints[fp_idx], x[ray_idx], y[ray_idx])  # or on an edge
    ray_idx, fp_idx = ray_idx[~inside], fp_idx[~inside]
    edge_xy, edge_start, edge_count = edges
    dist = np.full(ray_idx.size, np.inf)
    cos_inc = np.zeros(ray_idx.size)
    grad = np.zeros((ray_idx.size, 2))
    # Expand every pair to the edges of its footprint, in chunks of bounded size.
    per_pair = edge_count[fp_idx]
    bounds = np.concatenate([[0], np.cumsum(per_pair)])
    inner = np.searchsorted(bounds, np.arange(_CHUNK, bounds[-1], _CHUNK))
    cuts = np.unique(np.concatenate([[0], inner, [ray_idx.size]]))
    for lo, hi in zip(cuts[:-1], cuts[1:], strict=True):
        pairs = np.arange(lo, hi)
        counts = per_pair[pairs]
        rep = np.repeat(pairs, counts)
        offs = np.arange(counts.sum()) - np.repeat(bounds[pairs] - bounds[lo], counts)
        e = edge_xy[edge_start[fp_idx[rep]] + offs]
        t, cos, denom = _ray_segment_distance(
            x[ray_idx[rep]], y[ray_idx[rep]], dx[ray_idx[rep]], dy[ray_idx[rep]], e
        )
        block = bounds[pairs] - bounds[lo]  # where each pair's edges start in this chunk
        dist[pairs] = np.minimum.reduceat(t, block)
        first = np.isfinite(t) & (t == dist[rep])
        cos_inc[rep[first]] = cos[first]
        if not gradient:
            continue
        # d t / d origin for the entry edge: t = (q x edge) / (ray x edge) with q = start - origin
        hit = e[first]
        grad[rep[first]] = (
            np.column_stack([-(hit[:, 3] - hit[:, 1]), hit[:, 2] - hit[:, 0]])
            / (denom[first][:, None])
        )
    keep = dist <= max_range
    ray_idx, fp_idx, dist, cos_inc, grad = (v[keep] for v in (ray_idx, fp_idx, dist, cos_inc, grad))
    order = np.lexsort((dist, ray_idx))
    return ray_idx[order], fp_idx[order], dist[order], cos_inc[order], grad[order]


def _crosses_box(x, y, dx, dy, box):
    """Whether the line through each origin (unit direction ``dx``, ``dy``) passes through the
    axis-aligned box (xmin, ymin, xmax, ymax): the separating-axis test along the line's
    normal. With the boxes of the ray segment and the footprint overlapping (the tree query),
    this makes the segment x box test exact."""
    hx, hy = 0.5 * (box[:, 2] - box[:, 0]), 0.5 * (box[:, 3] - box[:, 1])
    cx, cy = box[:, 0] + hx, box[:, 1] + hy
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


def _ray_segment_distance(x, y, dx, dy, e):
    """Distance along rays (unit direction dx, dy) to segments e (inf where they miss), the
    cosine of the angle between each ray and the segment's normal, and the cross product of
    ray and segment directions."""
    ex, ey = e[:, 2] - e[:, 0], e[:, 3] - e[:, 1]
    denom = dx * ey - dy * ex
    qx, qy = e[:, 0] - x, e[:, 1] - y
    with np.errstate(divide="ignore", invalid="ignore"):
        t = (qx * ey - qy * ex) / denom
        u = (qx * dy - qy * dx) / denom
    hit = (np.abs(denom) > 1e-12) & (t >= 0) & (u >= 0) & (u <= 1)
    cos = np.abs(denom) / np.maximum(np.hypot(ex, ey), 1e-12)
    return np.where(hit, t, np.inf), cos, denom

"""Square tiles of British National Grid: the unit of work of a run split over many workers.

A national run cannot hold every signal and building at once, so it is cut into square tiles
aligned to the OS grid (``size`` metres, 1 km by default), which get stable names: the OS grid
reference of the tile's south-west corner at the tile's resolution (``TQ2982`` for the 1 km
square of Gower Street, ``TQ28`` for 10 km). A tile size that is not a power of ten gets the
corner to the metre and its size (``TQ2950082000-500m``).

- A **building** belongs to the one tile that holds its representative point
  (:func:`building_tiles`), so every building is estimated exactly once.
- A **receiver** belongs to every tile whose buildings one of its rays can reach: those within
  ``max_range`` of the tile's buildings' extent (:func:`receiver_tiles`), so every ray that can
  cross a tile's buildings is cast in that tile, also from a receiver in a neighbouring one.
- A tile's rays are cast against its own buildings and its **halo**: every other building
  within ``max_range`` of its receivers (:func:`plan_tiles`). A signal that crosses one of
  the tile's buildings then has every crossing the single run gives it, neighbours across the
  tile's edge included, so the visibility model sees the same rays.
"""

from __future__ import annotations

from dataclasses import dataclass

import geopandas as gpd
import numpy as np
import numpy.typing as npt
import pandas as pd
import shapely

from ..errors import InputError
from ..geodesy.grid_refs import tile_index, tile_names
from ..settings import DEFAULT_TILE_SIZE, check_tile_size

__all__ = [
    "DEFAULT_TILE_SIZE",
    "MAX_TILES",
    "Tile",
    "building_tiles",
    "check_reach",
    "check_tile_count",
    "plan_tiles",
    "receiver_tiles",
    "tile_index",
    "tile_names",
]


#: Receivers per block of :func:`receiver_tiles`: its candidate pairs (9 per receiver for
#: 1 km tiles and a 500 m reach) stay within tens of MB.
_CHUNK = 1 << 16

#: The most tiles a run makes: more than the 910,000 1 km squares of the whole national grid
#: (a run's tasks, each iteration, are a few per tile).
MAX_TILES = 1_000_000

#: A tile is at least the rays' reach over this: each receiver is tested against the
#: ``(2 x reach / size + 1)^2`` tiles around it (441 at most; 9 for 1 km tiles, 500 m rays).
_REACH_PER_TILE = 10.0


def check_tile_count(count: int, size: float) -> None:
    """Refuse a run in more than :data:`MAX_TILES` tiles of ``size`` metres (counted before
    any is made)."""
    if count > MAX_TILES:
        raise InputError(
            f"tiles of {size:g} m would make {count:,} tiles, more than a run takes "
            f"({MAX_TILES:,})",
            fix="give a larger --tile-size, e.g. 1000",
        )


def check_reach(size: float, max_range: float) -> None:
    """Refuse tiles of ``size`` metres much smaller than the rays' reach (``max_range``): each
    tile's work is its buildings' surroundings within the reach, so smaller tiles repeat it
    over more tiles, and each receiver is tested against more of them."""
    if size * _REACH_PER_TILE < max_range:
        raise InputError(
            f"tiles of {size:g} m are too small for rays of {max_range:g} m (a tile at least "
            f"1/{_REACH_PER_TILE:g} of the reach)",
            fix=f"give --tile-size {np.ceil(max_range / _REACH_PER_TILE):.0f} or more",
        )


def building_tiles(buildings: gpd.GeoDataFrame, size: float = DEFAULT_TILE_SIZE) -> np.ndarray:
    """The name of the one tile each building belongs to: the tile of its representative point
    (a point inside the footprint, so an L-shaped building is not placed by a corner outside
    it). More than :data:`MAX_TILES` tiles are refused before any is named."""
    points = shapely.point_on_surface(buildings.geometry.to_numpy())
    ix, iy = tile_index(shapely.get_x(points), shapely.get_y(points), size)
    check_tile_count(np.unique(_key(ix, iy)).size, size)
    return tile_names(ix, iy, size)


def receiver_tiles(
    e: npt.ArrayLike,
    n: npt.ArrayLike,
    buildings: gpd.GeoDataFrame,
    max_range: float,
    size: float = DEFAULT_TILE_SIZE,
    bearing: npt.ArrayLike | None = None,
    widen: float = 0.0,
) -> pd.DataFrame:
    """Which tiles each receiver position serves: every tile whose buildings lie, at least in
    part, within ``max_range`` (m, the rays' horizontal reach) of it. With ``bearing`` (deg,
    one per row: each row is then a ray), only the tiles whose buildings' bounding box the
    ray's ``max_range`` long segment enters: a ray pointing away from a tile is not its work.
    ``widen`` (m) grows each tile's box first: a ray that passes that near a building gives it
    a row too (:class:`~gnss_citygml.settings.PositionError`'s ``crossing``).

    A tile's reach is the bounding box of its own buildings' footprints (which may cross the
    tile's edges) grown by ``max_range``: a receiver outside it has no ray that can enter any
    of them. Returns one row per (``row``: position in ``e``/``n``, ``tile``: name), in order
    of ``row`` then tile; a receiver near no building is in no tile. Each receiver is tested
    against the few tiles around it that can reach it (vectorised: no loop over tiles or
    receivers).
    """
    e, n = np.asarray(e, dtype=float), np.asarray(n, dtype=float)
    if not (np.isfinite(max_range) and max_range > 0):
        raise InputError(f"max_range must be a positive number of metres, not {max_range!r}")
    check_tile_size(size)
    check_reach(size, max_range)
    if len(buildings) == 0:
        return pd.DataFrame({"row": np.empty(0, dtype=np.int64), "tile": np.empty(0, dtype=object)})
    points = shapely.point_on_surface(buildings.geometry.to_numpy())
    bx, by = tile_index(shapely.get_x(points), shapely.get_y(points), size)
    bounds = pd.DataFrame(
        shapely.bounds(buildings.geometry.to_numpy()), columns=["x0", "y0", "x1", "y1"]
    )
    box = bounds.groupby([bx, by]).agg({"x0": "min", "y0": "min", "x1": "max", "y1": "max"})
    tx, ty = (box.index.get_level_values(i).to_numpy(dtype=np.int64) for i in (0, 1))
    grown = box.to_numpy() + np.array([-widen, -widen, widen, widen])
    reach = grown + np.array([-max_range, -max_range, max_range, max_range])
    # how far beyond its own square a tile reaches: the candidates around each receiver
    beyond = np.max(
        [
            tx * size - reach[:, 0],
            ty * size - reach[:, 1],
            reach[:, 2] - (tx + 1) * size,
            reach[:, 3] - (ty + 1) * size,
        ]  # fmt: skip
    )
    span = int(np.ceil(2.0 * beyond / size)) + 1  # candidate tiles across, around a receiver
    dx, dy = (g.ravel() for g in np.meshgrid(np.arange(span), np.arange(span), indexing="ij"))
    keys = _key(tx, ty)  # sorted: the groupby sorted the tiles
    rows, tiles = [], []
    chunk = max(1, _CHUNK * 9 // dx.size)  # a chunk's candidates stay within memory
    for start in range(0, e.size, chunk):
        part = slice(start, start + chunk)
        px, py = np.repeat(e[part], dx.size), np.repeat(n[part], dx.size)
        ix0, iy0 = tile_index(e[part] - beyond, n[part] - beyond, size)
        candidate = _key(
            np.repeat(ix0, dx.size) + np.tile(dx, ix0.size),
            np.repeat(iy0, dx.size) + np.tile(dy, iy0.size),
        )
        at = np.clip(np.searchsorted(keys, candidate), 0, keys.size - 1)
        x0, y0, x1, y1 = reach[at].T
        hit = (keys[at] == candidate) & (px >= x0) & (px <= x1) & (py >= y0) & (py <= y1)
        if bearing is not None:
            way = np.radians(np.repeat(np.asarray(bearing, dtype=float)[part], dx.size))
            ends = (max_range * np.sin(way), max_range * np.cos(way))
            hit &= _segment_enters(px, py, *ends, grown[at])
        rows.append(start + np.flatnonzero(hit) // dx.size)
        tiles.append(at[hit])
    names = tile_names(tx, ty, size)  # once per tile, not per pair
    return pd.DataFrame(
        {"row": np.concatenate(rows), "tile": names[np.concatenate(tiles).astype(np.intp)]}
    )


@dataclass(frozen=True)
class Tile:
    """One tile's work: positions (``iloc``) of its own buildings, of the other buildings its
    receivers' rays may cross (``halo``) and of its receivers."""

    name: str
    buildings: np.ndarray
    halo: np.ndarray
    receivers: np.ndarray


def plan_tiles(
    e: npt.ArrayLike,
    n: npt.ArrayLike,
    buildings: gpd.GeoDataFrame,
    max_range: float,
    size: float = DEFAULT_TILE_SIZE,
    bearing: npt.ArrayLike | None = None,
    widen: float = 0.0,
) -> list[Tile]:
    """The tiles of a run, in name order: each tile's buildings (:func:`building_tiles`), the
    receivers (or, with ``bearing``, the rays) that serve it (:func:`receiver_tiles`, its
    ``widen``) and its halo, the other buildings within ``max_range`` (plus ``widen``) of the
    bounding box of those receivers. A tile that no receiver serves is still listed (its
    buildings have no signal)."""
    e, n = np.asarray(e, dtype=float), np.asarray(n, dtype=float)
    names = building_tiles(buildings, size)
    pairs = receiver_tiles(e, n, buildings, max_range, size, bearing, widen)
    served = {str(k): v.to_numpy() for k, v in pairs.groupby("tile")["row"]}
    tree = shapely.STRtree(buildings.geometry.to_numpy())
    tiles = []
    for key, own in pd.Series(np.arange(len(names))).groupby(names):
        name = str(key)
        rows = served.get(name, np.empty(0, dtype=np.int64))
        halo = np.empty(0, dtype=np.int64)
        if rows.size:
            far = max_range + widen
            reach = shapely.box(
                e[rows].min() - far, n[rows].min() - far, e[rows].max() + far, n[rows].max() + far
            )
            near = np.sort(tree.query(reach))
            halo = near[names[near] != name]
        tiles.append(Tile(name, own.to_numpy(), halo, rows))
    return tiles


def _segment_enters(x, y, dx, dy, boxes) -> np.ndarray:
    """Whether each segment from (``x``, ``y``) to (``x + dx``, ``y + dy``) meets its box
    (``x0, y0, x1, y1`` per row): Liang-Barsky clipping, vectorised."""
    t0, t1 = np.zeros(x.size), np.ones(x.size)
    for p, d, lo, hi in ((x, dx, boxes[:, 0], boxes[:, 2]), (y, dy, boxes[:, 1], boxes[:, 3])):
        moving = d != 0.0
        with np.errstate(divide="ignore", invalid="ignore"):
            a, b = (lo - p) / d, (hi - p) / d
        inside = (p >= lo) & (p <= hi)  # a segment along the axis: inside the slab or never
        t0 = np.where(moving, np.maximum(t0, np.minimum(a, b)), np.where(inside, t0, np.inf))
        t1 = np.where(moving, np.minimum(t1, np.maximum(a, b)), t1)
    return t0 <= t1


def _key(ix: np.ndarray, iy: np.ndarray) -> np.ndarray:
    """One int64 per tile, ordered as (column, row): both fit in 31 bits for 1 m tiles."""
    return (ix.astype(np.int64) << 31) + iy.astype(np.int64)

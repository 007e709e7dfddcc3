"""OS national grid references of square tiles of British National Grid: which square holds a
point (:func:`tile_index`) and its name (:func:`tile_names`: ``TQ2982`` for the 1 km square of
Gower Street, ``TQ28`` for its 10 km square, ``TQ`` for its 100 km square). The runs in tiles
(:mod:`gnss_citygml.tiling`) and the 3D Tiles writer (:mod:`gnss_citygml.export.tiles3d`)
both name their squares so.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from ..errors import InputError
from ..settings import DEFAULT_TILE_SIZE, check_tile_size

__all__ = ["tile_index", "tile_names"]

#: The extent of the OS national grid's lettered 100 km squares (m): eastings 0-700 km,
#: northings 0-1300 km.
_GRID_E, _GRID_N = 700_000.0, 1_300_000.0


def tile_index(
    e: npt.ArrayLike, n: npt.ArrayLike, size: float = DEFAULT_TILE_SIZE
) -> tuple[np.ndarray, np.ndarray]:
    """Column and row (int64) of the tile holding each point (``e``, ``n`` in BNG metres)."""
    check_tile_size(size)
    e, n = np.asarray(e, dtype=float), np.asarray(n, dtype=float)
    return np.floor(e / size).astype(np.int64), np.floor(n / size).astype(np.int64)


def tile_names(ix: npt.ArrayLike, iy: npt.ArrayLike, size: float = DEFAULT_TILE_SIZE) -> np.ndarray:
    """The name of each tile (:func:`tile_index`): the OS grid reference of its south-west
    corner at the tile's resolution.

    Examples
    --------
    >>> tile_names([529], [182]).tolist()
    ['TQ2982']
    >>> tile_names([52], [18], 10_000).tolist()
    ['TQ28']
    >>> tile_names([1059], [364], 500).tolist()
    ['TQ2950082000-500m']
    """
    check_tile_size(size)
    ix, iy = np.asarray(ix, dtype=np.int64), np.asarray(iy, dtype=np.int64)
    e, n = ix * size, iy * size
    outside = (e < 0) | (n < 0) | (e >= _GRID_E) | (n >= _GRID_N)
    if outside.any():
        k = int(np.flatnonzero(outside)[0])
        raise InputError(
            f"a tile at E {e[k]:.0f} m, N {n[k]:.0f} m is outside the OS national grid "
            "(eastings 0-700 km, northings 0-1300 km)",
            fix="check that the data are in British National Grid (EPSG:27700)",
        )
    letters = _letters(e, n)
    digits = round(5 - np.log10(size))
    if size == 10.0 ** (5 - digits):  # 1 m .. 100 km: the OS's own references
        width = max(digits, 0)
        east = (np.mod(e, 100_000) // size).astype(np.int64)
        north = (np.mod(n, 100_000) // size).astype(np.int64)
        if width == 0:
            return letters
        return np.array(
            [
                f"{a}{x:0{width}d}{y:0{width}d}"
                for a, x, y in zip(letters, east, north, strict=True)
            ],
            dtype=object,
        )
    east = np.mod(e, 100_000).astype(np.int64)
    north = np.mod(n, 100_000).astype(np.int64)
    return np.array(
        [f"{a}{x:05d}{y:05d}-{size:g}m" for a, x, y in zip(letters, east, north, strict=True)],
        dtype=object,
    )


def _letters(e: np.ndarray, n: np.ndarray) -> np.ndarray:
    """The two letters of the OS 100 km square holding each (``e``, ``n``): the first names
    the 500 km square (S, T, N, O, H, J from the false origin), the second the 100 km square in
    it; each letter counts A-Z without I across a 5 x 5 block."""
    e100, n100 = (e // 100_000).astype(np.int64), (n // 100_000).astype(np.int64)
    first = (19 - n100) - (19 - n100) % 5 + (e100 + 10) // 5
    second = (19 - n100) * 5 % 25 + e100 % 5
    first, second = first + (first > 7), second + (second > 7)  # no I
    return np.array(
        [chr(65 + a) + chr(65 + b) for a, b in zip(first, second, strict=True)], dtype=object
    )

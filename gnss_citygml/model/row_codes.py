"""How a part codes and sorts its rows (:class:`~.parts.Part`): whole-number codes in the
fewest bytes, ranks and factorizations that avoid hashing where a table does, the rows by
building then height, and each row's order along its ray."""

from __future__ import annotations

import numpy as np
import numpy.typing as npt
import pandas as pd

__all__ = [
    "building_order",
    "compact",
    "factorized",
    "near_behind",
    "phone_codes",
    "ranks",
    "ray_order",
]


def ranks(values: np.ndarray) -> np.ndarray:
    """Each value's rank among the distinct ``values`` (``pd.factorize(values, sort=True)``'s
    codes): by a table of the values where they are small whole numbers (a signal's number,
    a row of the observations: ten times faster than hashing), else by hashing."""
    if values.dtype.kind in "iu" and values.size and values.min() >= 0:
        top = int(values.max())
        if top < 4 * values.size:
            present = np.zeros(top + 1, dtype=bool)
            present[values] = True
            return (np.cumsum(present) - 1)[values]
    return pd.factorize(values, sort=True)[0]


def compact(codes: np.ndarray) -> np.ndarray:
    """Whole-number codes (a building's, a signal's, an order along the ray) as int32 where
    they fit: a run in tiles holds every part's rows for the whole run, so 4 bytes a column
    less is memory that a national run needs (68 -> 48 bytes a row). Anything else (an order
    with gaps or fractions from a user's table) is kept as it is."""
    if codes.size == 0:
        return codes.astype(np.int32)
    whole = codes.dtype.kind in "iu" or bool(
        np.all(np.isfinite(codes) & (codes == np.floor(codes)))
    )
    if whole and -(2**31) <= codes.min() and codes.max() < 2**31:
        return codes.astype(np.int32)
    return codes


def building_order(g: np.ndarray, h: np.ndarray) -> np.ndarray:
    """The rows sorted by building ``g``, then height ``h`` (``np.lexsort((h, g))``): by height
    then, stably, by building, whose codes sort by radix where they fit in 16 bits (faster)."""
    by_height = np.argsort(h, kind="stable")
    small = g.size == 0 or (g.min() >= 0 and g.max() < 2**15)
    return by_height[np.argsort(g[by_height].astype(np.int16 if small else g.dtype), kind="stable")]


def phone_codes(
    phone: npt.ArrayLike | None, elevation: npt.ArrayLike | None, by: np.ndarray
) -> tuple[np.ndarray, np.ndarray] | tuple[None, None]:
    """Each row's phone (of ``phone``, rows in the order ``by``) coded into the phones' names
    (-1 where the elevation is not known: neither counted nor levelled); (None, None) without
    phones or elevations."""
    if phone is None or elevation is None:
        return None, None
    code, names = factorized(phone, by)
    unknown = ~np.isfinite(np.asarray(elevation, dtype=float)[by])
    return np.where(unknown, -1, compact(code)), names.astype(str).astype(object)


def factorized(
    values: npt.ArrayLike, by: np.ndarray, sort: bool = False
) -> tuple[np.ndarray, np.ndarray]:
    """``pd.factorize(values[by], sort=sort)`` as codes (-1: missing) and names (an object
    array), hashing ``values`` as they come (a categorical by its codes, Arrow strings as
    such) and not as one Python object a row."""
    code, names = pd.factorize(pd.Series(values, copy=False))  # first appearance in ``values``
    names = np.asarray(names, dtype=object)
    if sort:
        rank = pd.factorize(names, sort=True)[0]
    else:  # in order of first appearance in ``values[by]``
        first = pd.unique(code[by])
        first = first[first >= 0]
        rank = np.empty(names.size, dtype=np.intp)
        rank[first] = np.arange(first.size)
    names = names[np.argsort(rank)]
    return np.append(rank, -1)[code[by]], names  # the last entry keeps a missing one's -1


def ray_order(
    order: npt.ArrayLike | None, by_group: np.ndarray, sig: np.ndarray, h: np.ndarray
) -> tuple[np.ndarray | None, np.ndarray | None]:
    """Each row's ``order`` along its ray as a part keeps it (the rows sorted ``by_group``, of
    signals ``sig`` and heights ``h``): only how a ray's rows compare, so ranks where the
    orders are not whole numbers (NaN last); and which rows' rays enter their footprint (None:
    all), the footprints a ray passes near (order below 0) after those it enters
    (:func:`near_behind`)."""
    if order is None:
        return None, None
    order = compact(np.asarray(order)[by_group])
    if order.dtype.kind == "f":
        return compact(np.unique(order, return_inverse=True)[1]), None
    if order.size == 0 or order.min() >= 0:
        return order, None
    entered = order >= 0
    return near_behind(order, entered, sig, h), entered


def near_behind(
    order: np.ndarray, entered: np.ndarray, sig: np.ndarray, h: np.ndarray
) -> np.ndarray:
    """``order`` along each ray with the rows of footprints the ray passes near (not
    ``entered``) after every footprint it enters, in order of height (of distance: a ray
    rises), so that every part of a run that holds a ray orders its rows alike."""
    near = np.flatnonzero(~entered)
    near = near[np.lexsort((h[near], sig[near]))]
    first = np.r_[True, sig[near][1:] != sig[near][:-1]]
    rank = np.arange(near.size) - np.maximum.accumulate(np.where(first, np.arange(near.size), 0))
    out = order.astype(np.int64)
    out[near] = int(order.max()) + 1 + rank
    return compact(out)

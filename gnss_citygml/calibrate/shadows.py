"""Shadow matching: where each window of a recording can have been, by which of its signals
arrive and which do not, against the footprints and the heights known so far.

A phone fix pushed across a street by the reflections there is off the same way for every phone
in that street: the roof lines absorb such a shared offset (:mod:`gnss_citygml.calibrate`'s
first method cannot see it), but the shadows cannot. A ray that crosses no footprint from where
the phone really was arrives in sight; one that enters a wall below the building's roof does
not; from a position a few metres across the street the same rays cross other walls at other
heights. :func:`shadow_offsets` weighs a grid of candidate shifts of each window by how well
the rays cast exactly from there explain its signals' labels, with a Gaussian prior on the
shift, and takes the posterior mean: along a street, where the shadows say nothing, the shift
stays the prior's (none) instead of wandering to the best of many equal candidates. No
candidate puts the window inside a building. A roof given with the map carries its
uncertainty: a ray blocked with the chance that the roof is above it. Measured in
docs/issue-28-positions.md.
"""

from __future__ import annotations

import numpy as np
import shapely
from scipy.special import ndtr

from ..errors import InputError
from ..raycast import footprint_entries

__all__ = ["label_chances", "shadow_offsets"]

#: Candidates per axis of a window's grid, and its half-width: this many of the window's prior
#: standard deviations (as for the roof lines' search), at most :data:`CAP` metres.
GRID = 11
SEARCH_SDS = 2.5
CAP = 25.0

#: The candidates of a window's grid, in its half-widths (east, north).
_SX, _SY = (
    a.ravel() for a in np.meshgrid(np.linspace(-1.0, 1.0, GRID), np.linspace(-1.0, 1.0, GRID))
)

#: Height (m) above the antenna that any building is taken to reach when its own is not known
#: (not converged, or a map without heights): a one-storey building's eaves (about 4 m) less a
#: hand-held antenna's height. A ray entering its wall below that is blocked; above, unknown.
MIN_WALL = 3.0

#: Rays cast at once (memory: about 100 bytes a ray).
CHUNK = 2_000_000

#: Epochs of one satellite in one window cast from every candidate, at most, evenly spread:
#: they are one vote (their mean log-likelihood), and within a window a satellite moves by a
#: fraction of a degree, so its epochs differ by where the walker was, which a few of them
#: sample (a 10 s window of 1 Hz epochs: 3 of 10 rows, a third of the casts).
EPOCHS = 3


def shadow_offsets(
    rays: dict[str, np.ndarray],
    chances: tuple[np.ndarray, np.ndarray],
    unit: np.ndarray,
    sd: np.ndarray,
    footprints: np.ndarray,
    heights: np.ndarray,
    max_range: float,
    height_sd: np.ndarray | None = None,
) -> np.ndarray:
    """Each window's offset (east, north; m): the posterior mean over its candidate grid.

    Parameters
    ----------
    rays
        Per row: ``e``, ``n``, ``z`` (antenna, m), ``bearing`` (deg), ``tan_el`` (tangent of the
        elevation) and ``satellite`` (an integer per satellite; each counts once per window,
        its rows' mean log-likelihood: its epochs share their reflections and the map's misfit).
    chances
        Per row: the chance of what its signal shows (its label, its C/N0) if its ray is open,
        and if it is blocked (e.g. :func:`label_chances`).
    unit
        Per row: its window (``0 .. n - 1``, e.g. of
        :func:`~gnss_citygml.recordings.recording_windows`).
    sd
        Per window: the prior standard deviation of its offset (m per axis).
    footprints, heights
        The footprints and their roofs (m, as ``z``; NaN: not known, :data:`MIN_WALL`).
    max_range
        The rays' horizontal length (m).
    height_sd
        Per footprint: the standard deviation of its roof (m; a height given with the map, a
        prior), or 0 (default): the roof is where ``heights`` says. A ray entering the wall
        at ``h`` is blocked with the chance that the roof is above ``h``.
    """
    if not all(np.all((c > 0.0) & (c <= 1.0)) for c in chances):
        raise InputError(
            "shadow matching's chances must be above 0 and at most 1",
            fix="give every signal some chance either way (e.g. labels right 95 % of the time): "
            "a chance of 0 rules out every candidate that one ray of a grazed wall contradicts",
        )
    vote = np.unique(  # one satellite in one window
        rays["satellite"] * (int(unit.max(initial=0)) + 1) + unit, return_inverse=True
    )[1]
    cast = _spread(vote, EPOCHS)
    weight = 1.0 / np.bincount(vote[cast])[vote[cast]]
    some = {name: values[cast] for name, values in rays.items()}
    roofs = (heights, np.zeros_like(heights) if height_sd is None else height_sd)
    half = np.minimum(SEARCH_SDS * sd, CAP)
    score = _log_likelihoods(
        some,
        (chances[0][cast], chances[1][cast]),
        unit[cast],
        weight,
        footprints,
        roofs,
        half,
        max_range,
    )
    score -= 0.5 * (_SX**2 + _SY**2)[None, :] * (half / sd)[:, None] ** 2
    score[_inside(rays, unit, half, footprints)] = -np.inf
    score -= score.max(axis=1, keepdims=True)
    p = np.nan_to_num(np.exp(score))
    p /= np.maximum(p.sum(axis=1, keepdims=True), 1e-300)
    return np.column_stack([half * (p @ _SX), half * (p @ _SY)])


def _spread(vote: np.ndarray, most: int) -> np.ndarray:
    """Indices of at most ``most`` rows of each vote, evenly spread over its rows in their
    order (all of a vote with fewer)."""
    order = np.argsort(vote, kind="stable")
    size = np.bincount(vote)[vote[order]]
    first = np.r_[0, np.flatnonzero(np.diff(vote[order])) + 1]
    rank = np.arange(order.size) - np.repeat(first, np.diff(np.r_[first, order.size]))
    part = rank * most // size
    keep = (rank == 0) | (part != (rank - 1) * most // size)
    return np.sort(order[keep])


def label_chances(labels: np.ndarray, p_seen: tuple[float, float]) -> tuple[np.ndarray, np.ndarray]:
    """Per row, the chance of its label if its ray is open and if it is blocked, given the
    chances ``p_seen`` that a signal is labelled open when its ray is open, and when blocked."""
    labels = np.asarray(labels, dtype=bool)
    return np.where(labels, p_seen[0], 1.0 - p_seen[0]), np.where(
        labels, p_seen[1], 1.0 - p_seen[1]
    )


def _log_likelihoods(rays, chances, unit, weight, footprints, roofs, half, max_range):
    """Per window and candidate: the weighted log-likelihood of the window's signals. A ray is
    open with the chance that no roof it enters is above it; one entering a building of unknown
    height above :data:`MIN_WALL` says only how surely the others block it."""
    n_cand = _SX.size
    if_open, if_blocked = chances
    score = np.zeros(half.size * n_cand)
    per_chunk = max(1, CHUNK // n_cand)
    moves = np.column_stack([_SX, _SY])
    for start in range(0, if_open.size, per_chunk):
        rows = np.arange(start, min(start + per_chunk, if_open.size))
        r, s = np.repeat(rows, n_cand), np.tile(np.arange(n_cand), rows.size)
        ray, part, dist, _ = footprint_entries(  # ray: r's and s's index
            rays["e"][rows],
            rays["n"][rows],
            rays["bearing"][rows],
            footprints,
            max_range,
            shifts=half[unit[rows], None, None] * moves,
        )
        above = dist * rays["tan_el"][r[ray]]  # the ray's height above the antenna at the wall
        top = roofs[0][part] - rays["z"][r[ray]]
        unknown = np.isnan(top)
        low = above < MIN_WALL  # every building reaches this high
        high = unknown & ~low
        block = np.where(unknown | low, low, _above(top - above, roofs[1][part]))
        clear = np.exp(
            np.bincount(ray, np.log1p(-np.minimum(block, 1.0 - 1e-12)), minlength=r.size)
        )
        silent = np.bincount(ray, high, minlength=r.size) > 0
        # p(label) = clear p(label | open) + (1 - clear) p(label | blocked); where a building of
        # unknown height may block it too, its open part is no evidence (1)
        ll = np.log(np.where(silent, clear, clear * if_open[r]) + (1.0 - clear) * if_blocked[r])
        score += np.bincount(unit[r] * n_cand + s, ll * weight[r], minlength=score.size)
    return score.reshape(half.size, n_cand)


def _above(margin: np.ndarray, sd: np.ndarray) -> np.ndarray:
    """The chance that a roof ``margin`` metres (its estimate) above a ray is above it, with
    the roof's standard deviation ``sd`` (0: sure)."""
    sure = sd <= 0
    return np.where(sure, margin > 0, ndtr(margin / np.where(sure, 1.0, sd)))


def _inside(rays, unit, half, footprints) -> np.ndarray:
    """Per window and candidate: whether the window's mean position, moved there, is inside a
    footprint (a pedestrian is not)."""
    n_units = half.size
    count = np.bincount(unit, minlength=n_units)
    mean_e = np.bincount(unit, rays["e"], minlength=n_units) / np.maximum(count, 1)
    mean_n = np.bincount(unit, rays["n"], minlength=n_units) / np.maximum(count, 1)
    points = shapely.points(
        (mean_e[:, None] + half[:, None] * _SX).ravel(),
        (mean_n[:, None] + half[:, None] * _SY).ravel(),
    )
    inside = np.zeros(points.size, bool)
    inside[shapely.STRtree(footprints).query(points, predicate="within")[0]] = True
    return inside.reshape(n_units, _SX.size)

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
uncertainty: a ray blocked with the chance that the roof is above it. A building whose roof is
not known yet (not converged, a map without heights) is taken to be as tall as those that are:
a ray entering its wall is blocked with the share of the known roofs above it. Measured in
docs/issue-28-positions.md and docs/issue-48-shadows.md.

What is cast does not depend on the roofs: :class:`Candidates` casts the rows once from every
candidate, and each round of a calibration weighs those casts against the roofs it has
reached. With the windows' walks (:mod:`.walks`) each window's shift is carried by its
neighbours along the walk instead of its own prior alone.
"""

from __future__ import annotations

import numpy as np
import shapely
from scipy.special import ndtr

from ..errors import InputError
from ..raycast import footprint_entries
from .walks import walk_offsets

__all__ = ["label_chances", "shadow_offsets"]

#: Candidates per axis of a window's grid, and its half-width: this many of the window's prior
#: standard deviations (as for the roof lines' search), at most :data:`CAP` metres.
GRID = 11
SEARCH_SDS = 2.5
CAP = 25.0

#: The candidates of a window's grid, in its half-widths (east, north).
_AXIS = np.linspace(-1.0, 1.0, GRID)
_SX, _SY = (a.ravel() for a in np.meshgrid(_AXIS, _AXIS))

#: Height (m) above the antenna that any building is taken to reach when its own is not known
#: (not converged, or a map without heights): a one-storey building's eaves (about 4 m) less a
#: hand-held antenna's height. A ray entering its wall below that is blocked; above, unknown.
MIN_WALL = 3.0

#: Known roofs (converged, or given with the map) that the buildings not known yet are taken to
#: be like, at least (:meth:`Candidates._survival`); fewer: those say only :data:`MIN_WALL`.
MIN_KNOWN = 5

#: Rays cast at once (memory: about 100 bytes a ray).
CHUNK = 2_000_000

#: Bytes of casts kept from one round for the next (12 bytes an entry where a ray enters a
#: footprint): the rest is cast again each round, so that a calibration's memory stays bounded
#: beside the fits' (the 1 M-signal benchmark casts about 4 GB of entries).
KEPT_BYTES = 500_000_000

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
    walks: tuple[np.ndarray, np.ndarray] | None = None,
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
    walks
        Per window: its recording and its time (s), to carry each window's shift along its walk
        (:func:`.walks.walk_offsets`); None: each window alone, with its own prior.
    """
    candidates = Candidates(rays, unit, sd, footprints, max_range, keep=0)  # weighed once
    return candidates.offsets(chances, heights, height_sd, walks)


class Candidates:
    """Where each window may have been: a few epochs of each satellite in each window (one
    vote: :data:`EPOCHS`), cast from every candidate shift of the window's grid against the
    footprints. What is cast does not depend on the roofs, so the rounds of a calibration weigh
    the same casts against the heights they have reached (:meth:`offsets`): the casts of the
    first round are kept for the next ones up to ``keep`` bytes (:data:`KEPT_BYTES`; 0 for one
    round), the others cast again."""

    def __init__(self, rays, unit, sd, footprints, max_range, keep=KEPT_BYTES):
        vote = np.unique(  # one satellite in one window
            rays["satellite"] * (int(unit.max(initial=0)) + 1) + unit, return_inverse=True
        )[1]
        self.rows = _spread(vote, EPOCHS)
        self.weight = 1.0 / np.bincount(vote[self.rows])[vote[self.rows]]
        self.unit = unit[self.rows]
        self.sd = sd
        self.half = np.minimum(SEARCH_SDS * sd, CAP)
        self.rays = {name: values[self.rows] for name, values in rays.items()}
        self.footprints, self.max_range = footprints, max_range
        self.antenna = _antennas(rays, footprints, max_range)
        self.inside = _inside(rays, unit, self.half, footprints)
        self.kept: dict[int, tuple[np.ndarray, ...]] = {}
        self.kept_bytes, self.keep = 0, keep

    def offsets(self, chances, heights, height_sd=None, walks=None) -> np.ndarray:
        """Each window's offset (east, north; m) given the rows' ``chances`` and the roofs
        (:func:`shadow_offsets`)."""
        if not all(np.all((c > 0.0) & (c <= 1.0)) for c in chances):
            raise InputError(
                "shadow matching's chances must be above 0 and at most 1",
                fix="give every signal some chance either way (e.g. labels right 95 % of the "
                "time): a chance of 0 rules out every candidate that one ray of a grazed wall "
                "contradicts",
            )
        roofs = (heights, np.zeros_like(heights) if height_sd is None else height_sd)
        chosen = (chances[0][self.rows], chances[1][self.rows])
        score = self._log_likelihoods(chosen, roofs)
        score[self.inside] = -np.inf
        if walks is not None:
            return walk_offsets(score, _AXIS, self.half, self.sd, *walks)[0]
        half, sd = self.half, self.sd
        score -= 0.5 * (_SX**2 + _SY**2)[None, :] * (half / sd)[:, None] ** 2
        peak = score.max(axis=1, keepdims=True)
        p = np.exp(score - np.where(np.isfinite(peak), peak, 0.0))
        p /= np.maximum(p.sum(axis=1, keepdims=True), 1e-300)
        return np.column_stack([half * (p @ _SX), half * (p @ _SY)])

    @property
    def per_chunk(self) -> int:
        """Rows cast at once (each from every candidate)."""
        return max(1, CHUNK // _SX.size)

    def _casts(self):
        """Per chunk of rows: its first row and, per entry, its cell within the chunk (row x
        candidate, ``row * candidates + candidate``), the footprint entered and the ray's height
        above the antenna at the wall (m, to the millimetre in single precision), in order of
        cell; kept while they fit in ``keep`` bytes, else cast again each round."""
        n_cand = _SX.size
        for first in range(0, self.rows.size, self.per_chunk):
            if first in self.kept:
                yield first, *self.kept[first]
                continue
            rows = slice(first, first + self.per_chunk)
            cell, part, dist, _ = footprint_entries(
                self.rays["e"][rows],
                self.rays["n"][rows],
                self.rays["bearing"][rows],
                self.footprints,
                self.max_range,
                shifts=self.half[self.unit[rows], None, None] * np.column_stack([_SX, _SY]),
            )
            entries = (
                cell.astype(np.int32),  # a chunk's cells are CHUNK at most
                part.astype(np.int32),
                (dist * self.rays["tan_el"][rows][cell // n_cand]).astype(np.float32),
            )
            size = sum(a.nbytes for a in entries)
            if self.kept_bytes + size <= self.keep:
                self.kept[first] = entries
                self.kept_bytes += size
            yield first, *entries

    def _survival(self, heights):
        """The chance that a roof not known yet is above a ray that enters its wall a given
        height above the antenna: the share of the known roofs (each above the antennas whose
        rays enter it) above it, half a roof given either way; None with
        fewer than :data:`MIN_KNOWN` known roofs (only :data:`MIN_WALL` is known then). As
        ``(heights, chances)`` for :func:`numpy.interp`."""
        top = heights - self.antenna
        known = np.sort(top[np.isfinite(top) & (top > MIN_WALL)])
        if known.size < MIN_KNOWN:
            return None
        share = (known.size - np.arange(known.size) - 0.5) / known.size
        return np.r_[MIN_WALL, known], np.r_[1.0 - 0.5 / known.size, share]

    def _log_likelihoods(self, chances, roofs):
        """Per window and candidate: the weighted log-likelihood of the window's signals. A ray
        is open with the chance that no roof it enters is above it; a roof not known yet is
        above a ray with the chance that known roofs are (:meth:`_survival`), or, with too few
        of those, only below :data:`MIN_WALL`: above, such a ray says only how surely the others
        block it."""
        n_cand = _SX.size
        if_open, if_blocked = chances
        score = np.zeros(self.half.size * n_cand)
        survival = self._survival(roofs[0])
        for first, ray, part, above in self._casts():
            rows = np.arange(first, min(first + self.per_chunk, self.rows.size))
            cells = rows.size * n_cand
            r, s = np.repeat(rows, n_cand), np.tile(np.arange(n_cand), rows.size)
            top = roofs[0][part] - self.rays["z"][r[ray]]
            low = above < MIN_WALL  # every building reaches this high
            unknown = np.isnan(top) & ~low
            block = np.where(low, 1.0, _above(top - above, roofs[1][part]))
            if survival is None:  # how surely the others block it, no more
                block[unknown] = 0.0
                silent = np.bincount(ray, unknown, minlength=cells) > 0
            else:
                block[unknown] = np.interp(above[unknown], *survival)
                silent = np.zeros(cells, dtype=bool)
            clear = np.exp(
                np.bincount(ray, np.log1p(-np.minimum(block, 1.0 - 1e-12)), minlength=cells)
            )
            # p(label) = clear p(label | open) + (1 - clear) p(label | blocked); where a building
            # of unknown height may block it too, its open part is no evidence (1)
            ll = np.log(np.where(silent, clear, clear * if_open[r]) + (1.0 - clear) * if_blocked[r])
            score += np.bincount(
                self.unit[r] * n_cand + s, ll * self.weight[r], minlength=score.size
            )
        return score.reshape(self.half.size, n_cand)


def _antennas(rays, footprints, max_range) -> np.ndarray:
    """Per footprint, the mean height (m) of the antennas whose rays, cast as they are, enter
    it (NaN: none does): what a roof is above, for :meth:`Candidates._survival`. Cast
    :data:`CHUNK` rays at a time."""
    total, entered = np.zeros(len(footprints)), np.zeros(len(footprints))
    for first in range(0, rays["e"].size, CHUNK):
        rows = slice(first, first + CHUNK)
        ray, part, _, _ = footprint_entries(
            rays["e"][rows], rays["n"][rows], rays["bearing"][rows], footprints, max_range
        )
        total += np.bincount(part, rays["z"][rows][ray], minlength=total.size)
        entered += np.bincount(part, minlength=total.size)
    return np.where(entered > 0, total / np.maximum(entered, 1), np.nan)


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

"""4PL-B: the bootstrapped four-parameter logistic building-height estimator (Algorithm 1).

For every building, a 4PL in intersection height (the *map classifier*) is fitted to signals
labelled by a C/N0 *signal classifier*; the signals are then relabelled by the map (open where
the intersection height is above the fitted inflection point ``c``), the signal classifier is
refitted to those labels, and the loop repeats until fewer than 1 % of the map labels change or
10 iterations have run (the paper's rule; beyond it, the loop runs until every building's roof
line has settled, :mod:`.settling`, up to 30 iterations by default). The paper's height
estimate is ``c + 1.5/b`` with range ``(c, c + 3/b)``; by default the height is ``c`` itself
(``Estimator.height_rule``), with the transition's range ``(c - 1.5/b, c + 1.5/b)`` around it:
where a roof edge is blurred alike above and below (by position errors, by diffraction), ``c``
is on it.

Beyond the paper, the range is stretched over every roof line the data fit about as well as
``c`` (:func:`~.fourpl.c_interval`, a 95 % likelihood-ratio interval): a building seen only
below and far above its roof (a few satellites from a few places) fits any ``c`` in between,
and the paper's range, as wide as the transition, then claimed a precision the data do not
have (the truth was inside it for 16 % of the converged buildings of street scenes, issue 14).
The interval counts each *look* once (:func:`look_ids`: one recording's view of one satellite
within a metre of height): a phone at 1 Hz repeats one ray's geometry, its position error and
its multipath fading (which a static phone's reflections keep for minutes) epoch after epoch,
so its rows are not independent evidence of where the roof line is.

The signal classifier belongs to a dataset (one device): in a run over many buildings it is
co-trained on all buildings' relabelled signals at once, while each building keeps its own
height 4PL. When the table says which rows are the same signal (``signal``), a signal is
labelled open only when its ray clears every building it crosses.

Beyond the paper (``estimator.signal_model = "mixture"``): the signal model may be the
generative :class:`~.mixture.Cn0Mixture` instead of the threshold. Each building's 4PL is then
the prior chance that a ray clears it, the rows carry soft labels (each ray's chance of clearing
its building given its C/N0 and elevation and every building along it), and the classes are
refitted to the signals weighted by them, with the rays that cross no footprint as open ones
(``open_sky``); the loop also waits for the mixture to settle.

Beyond the paper: the height fit can reweight the data by the distribution of intersection
heights (``weighting``), as the paper's discussion proposes for buildings seen mostly from one
side of their roof line (a canyon where nearly all signals are blocked, a terrace where nearly
all are open). Measured on the simulated sites, neither reweighting beat the paper's unweighted
MLE once every fit starts from its likeliest step (DESIGN.md, "Design notes"), so ``none`` is
the default.
A visibility model (``signal`` and ``order``) leaves out, for each building, the signals that
another building blocks. Given how far each intersection height may be off from its receiver's
position error (``height_sd``), the height fits model that error, as the paper's discussion
plans ("modelling location error"): ``b`` is then the sharpness of the roof line itself, not
of the blur that position errors add, and the range carries the roof line's own position
uncertainty (:func:`position_margin`).

This module holds the per-building maths: the weights and looks of the height fit, which fits
may stand in front of others or teach the classifier, the position margin and the judgement of
a fit (:class:`BuildingFits`). The loop itself runs over a run's parts (:mod:`.parts`, which
imports this module); :func:`~.estimate.fourplb` runs it on coded arrays.
"""

from __future__ import annotations

from dataclasses import dataclass, fields

import numpy as np
import numpy.typing as npt
import pandas as pd

from ..settings import WEIGHTINGS
from .classifier import SignalClassifier
from .fourpl import B_BOUNDS, FourPLFit, group_range
from .mixture import Cn0Mixture

#: What labels the signals: the paper's C/N0 threshold, or the mixture (:mod:`.mixture`).
SignalModel = SignalClassifier | Cn0Mixture

__all__ = [
    "BuildingFits",
    "height_weights",
    "look_ids",
    "position_margin",
]

#: With the visibility model, at least this fraction of the signals crossing a building below
#: its fitted roof line must be unblocked by other buildings; otherwise the lower edge of the
#: remaining data is where the buildings in front end, not where this one does.
MIN_VISIBLE = 0.1

#: Width (m) of the intersection-height bins of the ``height`` weighting: finer than any
#: building's height uncertainty, coarse enough to hold several signals each.
HEIGHT_BIN = 1.0


@dataclass(frozen=True)
class BuildingFits:
    """Per-building results of a height estimator (arrays of length ``n_buildings``)."""

    a: np.ndarray
    b: np.ndarray
    c: np.ndarray
    d: np.ndarray
    n_signals: np.ndarray
    iterations: np.ndarray
    converged: np.ndarray
    status: np.ndarray
    height: np.ndarray
    height_lower: np.ndarray
    height_upper: np.ndarray
    #: The paper's height ``c + 1.5/b`` (NaN where not converged), whichever rule ``height`` is.
    height_paper: np.ndarray

    def columns(self) -> dict[str, np.ndarray]:
        """The columns of the heights table (:data:`~.estimate.HEIGHTS_COLUMNS`) these fits
        give, by name."""
        return {f.name: getattr(self, f.name) for f in fields(self)}


def height_weights(
    height: np.ndarray,
    groups: np.ndarray,
    n_groups: int,
    scheme: str,
    c: np.ndarray | None = None,
    mask: np.ndarray | None = None,
    looks: np.ndarray | None = None,
) -> np.ndarray:
    """Sample weights of the height fit, normalised to a mean of 1 within each building
    (``looks``: to its number of looks).

    Rows outside ``mask`` (default: all rows are in) get weight 0.

    ``none``
        Every signal counts once (the paper's MLE).
    ``height``
        Inverse density of intersection heights in :data:`HEIGHT_BIN` bins, so that each metre
        of height counts the same whatever the number of signals that happen to cross it.
        A bin's count is floored at the building's mean count per occupied bin, so that a
        sparsely crossed height does not weigh more than an average one.
    ``balanced``
        Signals above and below the current inflection point ``c`` carry equal total weight.
    ``looks``
        Each *look* counts once (``looks``: each row's look, :func:`look_ids`; default: a
        building's rows within one :data:`HEIGHT_BIN` are one look).
    """
    height = np.asarray(height, dtype=float)
    groups = np.asarray(groups, dtype=np.intp)
    mask = np.ones(height.size, dtype=bool) if mask is None else np.asarray(mask, dtype=bool)
    if scheme == "none":
        return mask.astype(float)
    out = np.zeros(height.size)
    if scheme == "looks":
        ids = look_ids(height, groups) if looks is None else np.asarray(looks)
        rows = np.bincount(ids[mask])
        out[mask] = 1.0 / rows[ids[mask]]
        return out
    out[mask] = _weights(height[mask], groups[mask], n_groups, scheme, c)
    return out


def look_ids(
    height: np.ndarray, groups: np.ndarray, track: npt.ArrayLike | None = None
) -> np.ndarray:
    """Each row's *look* (a code from 0): a building's rows of one ``track`` (one recording's
    view of one satellite, any hashable codes; default: all rows one track) within one
    :data:`HEIGHT_BIN` of height.

    A phone logging at 1 Hz repeats the same ray geometry, and the same position error, for
    minutes: 300 epochs of one satellite from one standing point are one piece of geometric
    evidence, not 300. Counted as 300, a ray clipping a footprint's corner or one reflection
    outweighs the rest, and the likelihood interval of ``c`` is far too narrow.
    """
    bins = np.floor(np.asarray(height, dtype=float) / HEIGHT_BIN).astype(np.int64)
    bins -= bins.min(initial=0)
    key = np.zeros(bins.size, np.int64) if track is None else pd.factorize(np.asarray(track))[0]
    # codes of (track, bin), then of (building, that): each below the number of rows, so the
    # int64 keys cannot overflow, and hashing one int64 column is fast; made in place, and
    # each array let go once used (a run's every row: memory)
    key *= int(bins.max(initial=0)) + 1
    key += bins
    del bins
    pair = pd.factorize(key)[0]
    del key
    pair += np.multiply(groups, int(pair.max(initial=0)) + 1, dtype=np.int64, casting="unsafe")
    return pd.factorize(pair)[0]


def _weights(height, groups, n_groups, scheme, c):
    n = np.bincount(groups, minlength=n_groups).astype(float)
    if (scheme == "balanced" and c is None) or height.size == 0:
        return np.ones_like(height)
    if scheme == "height":
        bins = np.floor(height / HEIGHT_BIN).astype(np.int64)
        key = groups.astype(np.int64) * (1 << 32) + (bins - bins.min())
        _, first, inverse, counts = np.unique(
            key, return_index=True, return_inverse=True, return_counts=True
        )
        occupied = np.bincount(groups[first], minlength=n_groups)
        floor = n / np.maximum(occupied, 1)
        raw = 1.0 / np.maximum(counts[inverse], floor[groups])
    elif scheme == "balanced":
        above = height > np.asarray(c)[groups]
        n_above = np.bincount(groups, weights=above.astype(float), minlength=n_groups)
        n_below = n - n_above
        raw = np.where(
            above, 1.0 / np.maximum(n_above, 1)[groups], 1.0 / np.maximum(n_below, 1)[groups]
        )
    else:
        raise ValueError(f"unknown weighting {scheme!r}; use one of {', '.join(WEIGHTINGS)}")
    total = np.bincount(groups, weights=raw, minlength=n_groups)
    return raw * (n / np.maximum(total, 1e-300))[groups]


def _plausible(fit, lo, hi, min_separation):
    """Buildings whose current fit may stand in front of others: separated asymptotes and an
    inflection point inside the heights they were fitted on (from ``lo`` to ``hi``,
    :func:`~.fourpl.group_range`)."""
    return (fit.a - fit.d >= min_separation) & (fit.c >= lo) & (fit.c <= hi)


def _unoccluded(h, g, sig, c, b, plausible, order=None, entered=None):
    """Rows whose ray surely clears every *other* building at the current estimates (``c``,
    ``b`` per building): it passes above the top of each one's height range, c + 3/b. A
    signal that may have been blocked by another building tells nothing about this one,
    whatever its C/N0. A building without a plausible estimate may stand at any height: with
    ``order`` (whole numbers), the rows behind it along the ray are left out too. Rows of
    footprints the ray only passes near (not ``entered``) are never kept: where the ray may
    not cross the building, its C/N0 says little of it."""
    known = plausible[g]
    blocks = known & (h < (c + 3.0 / b)[g])
    n_sig = int(sig.max(initial=-1)) + 1
    n_blocking = np.bincount(sig[blocks], minlength=n_sig)
    clear = (n_blocking[sig] - blocks) == 0
    if order is not None:
        first_unknown = np.full(n_sig, np.iinfo(order.dtype).max, dtype=order.dtype)
        np.minimum.at(first_unknown, sig[~known], order[~known])  # fast: of one dtype
        clear &= order <= first_unknown[sig]
    return clear if entered is None else clear & entered


def position_margin(
    fit: FourPLFit,
    g: np.ndarray,
    h: np.ndarray,
    sd: np.ndarray,
    recording: np.ndarray | None,
    n_groups: int,
) -> np.ndarray:
    """How far (m) the roof line may be off owing to the receivers' position errors: twice
    the standard error of ``c`` when every recording's error is shared by all its rows.

    The errors-in-variables fit averages the position errors of rows as if independent, but a
    recording's offset (a point picked on a map, a phone's drifting fix) moves all its rows
    alike. So each recording's rows within the transition (``|h - c| <= 1.5/b + sd``) move
    ``c`` together, each by its ``sd`` in proportion to what it tells of ``c``: its Fisher
    information, the square of its slope at the roof line, ``kappa^2 = 1 / (1 + pi b^2 sd^2 /
    8)`` (:mod:`.fourpl`). ``se(c)^2 = sum_r (sum_{i in r} w_i s_i)^2 / (sum_i w_i)^2``: one
    recording of rows alike moves ``c`` by their ``sd``, ``R`` such recordings by ``sd /
    sqrt(R)``, and a grazing ray whose height a metre of position moves by tens of metres
    tells little of ``c`` and moves it little. Without recordings all rows are one recording
    (the widest margin).
    """
    near = np.abs(h - fit.c[g]) <= 1.5 / fit.b[g] + sd
    g, sd = g[near], sd[near]
    w = 1.0 / (1.0 + np.pi * (fit.b[g] * sd) ** 2 / 8.0)
    rec = np.zeros(g.size, dtype=np.intp) if recording is None else recording[near]
    key, pair = np.unique(np.column_stack([g, rec]), axis=0, return_inverse=True)
    shift = np.bincount(pair, w * sd, minlength=len(key))
    num = np.bincount(key[:, 0], shift**2, minlength=n_groups)
    den = np.bincount(g, w, minlength=n_groups)
    return 2.0 * np.sqrt(num) / np.maximum(den, 1e-300)


#: Why a range is too wide, where the data say (after ``height range wider than ... m: ``):
#: the receivers' shared position errors move the roof line more than the data leave it open,
POSITIONS_UNCERTAIN = "the receivers' positions are too uncertain"
#: or fewer than ``min_signals`` rays cross the building within a quarter of the widest range
#: of the roof line (a static phone sees a building at a few heights only).
NO_RAYS = "no rays near the roof line"
#: or the roof line lies in a gap of the rays' heights wider than its transition, anywhere in
#: which the data fit it alike (:data:`~.fourpl.GAP_AFTER`).
IN_GAP = "the roof line is anywhere in a gap between the rays"


def _far_from(h, g, c, reach, n_groups, min_signals):
    """Buildings with fewer than ``min_signals`` rows within ``reach`` of their ``c``."""
    near = np.abs(h - c[g]) <= reach
    return np.bincount(g, near, n_groups) < min_signals


def _hidden(h, g, c, seen, n_groups) -> np.ndarray:
    """Per building: whether fewer than :data:`MIN_VISIBLE` of the signals crossing it below
    its roof line ``c`` are ``seen`` (not blocked by other buildings)."""
    below = h < c[g]
    return np.bincount(g, below & seen, n_groups) < MIN_VISIBLE * np.bincount(g, below, n_groups)


def _height_range(b, c, offset, c_lo, c_hi, margin) -> tuple[np.ndarray, np.ndarray]:
    """The range of a height ``c + offset``: the 3/b-wide transition centred on it, widened at
    each end by that side of the interval ``(c_lo, c_hi)`` of ``c`` and the ``margin`` in
    quadrature (the data's uncertainty of c and the receivers' shared position errors are
    independent; the transition, the roof line's own blur, adds to both)."""
    lower = c + offset - 1.5 / b - np.hypot(c - c_lo, margin)
    upper = c + offset + 1.5 / b + np.hypot(c_hi - c, margin)
    return lower, upper


def _why_wide(wide, fit, h, g, c_range, margin, accept) -> list[tuple[np.ndarray, str]]:
    """The checks of a range wider than ``accept.max_uncertainty``, the more telling reason
    last: the receivers' positions, no rays near the roof line, a roof line in a gap."""
    c, (c_lo, c_hi) = fit.c, c_range
    max_uncertainty, n_groups = accept.max_uncertainty, c.size
    text = f"height range wider than {max_uncertainty:g} m"
    far = _far_from(h, g, c, max_uncertainty / 4, n_groups, accept.min_signals)
    return [
        (wide, text),
        (wide & (margin > np.maximum(c - c_lo, c_hi - c)), f"{text}: {POSITIONS_UNCERTAIN}"),
        (wide & far, f"{text}: {NO_RAYS}"),
        (wide & ~np.isnan(fit.gap_lower), f"{text}: {IN_GAP}"),
    ]


def _judge(
    fit,
    g,
    h,
    labels,
    seen,
    n_groups,
    change,
    settled,
    iterations,
    accept,
    *,
    strict=True,
    margin=0.0,
    c_range=None,
    paper_rule=False,
):
    """Turn a fit on the ``seen`` rows into heights, with an explicit reason wherever it is
    not to be trusted (``strict``: also where 4PL-B's loop or the fit itself is implausible:
    labels that changed by ``change`` of them, a roof line that has not ``settled``).
    The height is ``c`` (``c + 1.5/b`` by the ``paper_rule``), its range the 3/b-wide
    transition centred on it, widened at each end by that side of the interval of ``c`` and
    the ``margin`` in quadrature."""
    hidden = _hidden(h, g, fit.c, seen, n_groups)
    g, h, labels = g[seen], h[seen], labels[seen]
    min_signals, max_uncertainty = accept.min_signals, accept.max_uncertainty
    a, b, c, d = (v.copy() for v in (fit.a, fit.b, fit.c, fit.d))
    n_rows = np.bincount(g, minlength=n_groups)
    usable = n_rows >= min_signals
    lo, hi = group_range(h, g, n_groups)
    n_open = np.bincount(g, weights=labels > 0.5, minlength=n_groups)  # soft labels: likelier
    n_below = np.bincount(g, h < c[g], minlength=n_groups)
    c_lo, c_hi = (c, c) if c_range is None else c_range  # c_interval's ends hold c
    offset = 1.5 / b if paper_rule else 0.0
    lower, upper = _height_range(b, c, offset, c_lo, c_hi, margin)
    wide = upper - lower > max_uncertainty
    status = np.full(n_groups, "ok", dtype=object)
    plausibility = [
        (~settled, f"roof line still moving after {iterations} iterations"),
        (change >= accept.label_tol, f"labels still changing after {iterations} iterations"),
        (b <= B_BOUNDS[0] * 1.0001, "no slope: the height does not change the open probability"),
        ((c < lo) | (c > hi), "inflection point outside the observed intersection heights"),
        (a - d < accept.min_separation, f"asymptotes closer than {accept.min_separation} (a - d)"),
        # Relabelling by h > c presumes the map classifies below c as closed and above as open.
        ((d >= 0.5) | (a <= 0.5), "the roof line does not separate open from closed signals"),
        *_why_wide(wide, fit, h, g, (c_lo, c_hi), margin, accept),
        (hidden, "roof line hidden: most signals below it are blocked by other buildings"),
        (
            np.minimum(n_below, n_rows - n_below) < min_signals,
            f"fewer than {min_signals} signals on one side of the roof line",
        ),
    ]
    checks = [
        (~fit.converged, "the 4PL optimiser did not converge"),
        *(plausibility if strict else []),
        (n_open == 0, "no signal is labelled open"),
        (n_open == n_rows, "every signal is labelled open"),
        (~usable, f"fewer than {min_signals} signals"),
    ]
    for bad, reason in checks:  # the last failing check is the most basic one: it wins
        status[bad] = reason
    converged = status == "ok"
    return BuildingFits(
        a=a,
        b=b,
        c=c,
        d=d,
        n_signals=n_rows,
        iterations=np.where(usable, iterations, 0),
        converged=converged,
        status=status,
        height=np.where(converged, c + offset, np.nan),
        height_lower=np.where(converged, lower, np.nan),
        height_upper=np.where(converged, upper, np.nan),
        height_paper=np.where(converged, c + 1.5 / b, np.nan),
    )

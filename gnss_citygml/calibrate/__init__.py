"""Self-calibration of receiver positions against the roof lines they see.

A receiver position that is off by a constant vector for a whole recording (a point picked on a
map, a phone fix biased by the street around it) moves every intersection height of that
recording: ``height = z + distance * tan(elevation)`` and the distance to a wall changes with
the receiver's position. Close to a wall this is a large effect (a receiver 3.5 m from a wall
that is off by 1 m scales every intersection height above the antenna by 30 %), and recordings
with different offsets blur each building's open/closed transition into a gentle slope.

The same offset must explain the transitions of *every* building one recording sees: moving a
receiver towards the block on one side of a street raises the roof line of the block on the
other side. :func:`calibrate_receivers` therefore estimates one horizontal offset per recording
(``receiver``, or per time window of it) jointly with the building heights, alternating

1. 4PL-B on the intersections cast from the current positions (heights given offsets);
2. per recording, the offset maximising the Bernoulli likelihood of its signals' labels under
   every building's fitted map classifier, plus a Gaussian prior on the offset (offsets given
   heights); the intersection heights are moved to first order in the offset, using each
   ray's entry wall (:func:`~gnss_citygml.raycast.footprint_entries` with ``gradient``);

and re-casting the rays exactly from the corrected positions after each round. The prior's
standard deviation is what the positions are believed to be worth (about 1 m for hand-placed
points; several metres for phone fixes) and removes the common-mode degeneracy: shifting every
recording the same way can be absorbed by the heights, so only the prior pins it.

``Calibration(matching="shadows")`` finds each offset in step 2 by shadow matching instead
(:mod:`.shadows`): the rays cast exactly from a grid of candidates against the converged roofs,
the rays that cross no footprint included, which a shared offset does not escape. The labels
are the current signal model's, their error rates counted on the current cast (open sky,
and rays surely below a converged roof); each window's prior is its fixes' own ``position_sd``,
and with a window each window's shift is carried along its walk (:mod:`.walks`: the prior's
scale, for phones that understate their errors, and the errors' memory told by the shadows).
The candidates are cast once; every round weighs them against the roofs it has reached.
Roofs fitted from fixes that all share a shift explain the shadows from there as the true ones
do from the truth (the shift scales every ray's way to a wall), so with
``Calibration(heights=FIELD)`` the map's own roof heights, with their uncertainty, are matched
against instead wherever the map has one: they place the phones, the signals give the heights.
"""

from __future__ import annotations

import warnings

import geopandas as gpd
import numpy as np
import pandas as pd

from ..errors import InputError, MissingColumnError
from ..model.estimate import fourplb
from ..model.fourpl import logistic4
from ..model.mixture import Cn0Moments, elevation_units
from ..raycast import footprint_entries
from ..recordings import recording_windows, window_walks
from ..settings import Calibration, Estimator, Rays
from .shadows import KEPT_BYTES, SEARCH_SDS, Candidates, label_chances

__all__ = ["calibrate_receivers", "check_map_heights"]

_REQUIRED = ["receiver", "e", "n", "z", "bearing", "elevation", "cn0"]

#: Rows whose distance changes faster than this with the receiver position (grazing walls,
#: |d distance / d position| = 1 / sin(angle between ray and wall)) are left out of the offset
#: likelihood: their first-order height change is not to be trusted over a metre.
MAX_DISTANCE_GRADIENT = 4.0

#: Cap (m) of the half-width of the offset search of one round (:data:`.shadows.SEARCH_SDS`
#: prior standard deviations): several rounds, each re-casting exactly, cover larger offsets.
SEARCH_CAP = 4.0

#: Seconds over which one satellite's signals at one receiver are taken as one piece of
#: evidence: its intersection height moves by about a transition width per minute (0.5 deg of
#: elevation), and fading, multipath and the map's misfit are shared within that time. The
#: log-likelihood of a recording's signals is scaled by ``epoch interval / CORRELATION_TIME``
#: so that a few strongly-fitting but misspecified buildings cannot outweigh the prior.
CORRELATION_TIME = 60.0


def calibrate_receivers(
    receivers: pd.DataFrame,
    buildings: gpd.GeoDataFrame,
    calibration: Calibration,
    *,
    estimator: Estimator = Estimator(),
    rays: Rays = Rays(),
) -> pd.DataFrame:
    """Receiver positions corrected by one offset per recording, estimated with the heights.

    Parameters
    ----------
    receivers
        Observations with the receiver columns (DESIGN.md): ``receiver``, ``e``, ``n``, ``z``,
        ``bearing``, ``elevation``, ``cn0`` (and ``time_utc`` with a window; ``constellation``
        and ``svid`` for shadow matching, and each row's ``position_sd`` if it has one).
    buildings
        Table with ``id`` and ``geometry`` (footprints in the receivers' grid), and with the
        calibration's ``heights`` field (m above the ground) their ``ground`` (m, as ``z``).
    calibration
        The prior standard deviation (m per axis) of a recording's offset: what the positions
        are believed to be worth; the window (s): one offset per window of each recording (for
        positions whose error drifts, e.g. phone fixes; windows of
        :func:`~gnss_citygml.recordings.recording_windows`) instead of one per recording; the
        rounds of (heights | offsets) alternation; how each offset is found, against the
        roof lines or by shadow matching (:class:`~gnss_citygml.settings.Calibration`).
    estimator
        The 4PL-B settings (:class:`~gnss_citygml.settings.Estimator`, method 4PL-B).
    rays
        The rays' horizontal range (``max_range``, m).

    Returns
    -------
    pandas.DataFrame
        ``receivers`` with ``e`` and ``n`` corrected and the applied offsets in ``offset_e``
        and ``offset_n`` (m).
    """
    if calibration.prior_sd is None:  # not calibration.on, in words mypy follows
        raise InputError(
            "self-calibration without a prior",
            fix="give Calibration(prior_sd=...), e.g. 1 m for hand-placed points",
        )
    calibration.check_method(estimator)
    missing = [c for c in _REQUIRED if c not in receivers.columns]
    if calibration.window is not None and "time_utc" not in receivers.columns:
        missing.append("time_utc")
    if calibration.matching == "shadows":
        missing += [c for c in ("constellation", "svid") if c not in receivers.columns]
    if missing:
        raise MissingColumnError(missing, where="receivers table", have=list(receivers.columns))
    sd = calibration.prior_sd
    unit = recording_windows(receivers, calibration.window)
    n_units = int(unit.max(initial=-1)) + 1
    temper = min(1.0, _interval(receivers) / CORRELATION_TIME)
    origins = _Rays(receivers, buildings, rays.max_range)
    shadows = _shadow_matching(receivers, buildings, calibration, unit, origins)
    offsets = np.zeros((n_units, 2))
    best = None
    for _ in range(calibration.rounds):
        cast = origins.cast(offsets[unit])
        fits, classifier = _heights(origins, cast, estimator)
        n_ok = int(fits.converged.sum())
        if best is not None and n_ok < best[0]:
            offsets = best[1]  # the fits fell apart: keep the last offsets that held them
            break
        best = (n_ok, offsets)
        if shadows is not None:
            step = _shadow_step(origins, cast, fits, classifier, unit, offsets, *shadows)
        else:
            step = _offset_step(origins, cast, fits, classifier, unit, n_units, offsets, sd, temper)
        offsets = offsets + step
        if np.max(np.abs(step), initial=0.0) < 0.01 * sd:
            break
    out = receivers.copy()
    out["offset_e"], out["offset_n"] = offsets[unit, 0], offsets[unit, 1]
    out["e"] = out["e"] + out["offset_e"]
    out["n"] = out["n"] + out["offset_n"]
    return out


def _heights(origins, cast, estimator):
    """4PL-B on the intersections cast from the current positions: the fits and classifier."""
    return fourplb(
        cast.building,
        cast.height,
        cast.cn0,
        origins.n_buildings,
        estimator,
        signal=cast.ray,
        order=cast.order,
        elevation=origins.elevation[cast.ray],
        open_sky=origins.open_sky(cast, estimator),
    )


def _offset_step(origins, cast, fits, classifier, unit, n_units, offsets, sd, temper):
    """Each recording's (or window's) step of offset given the heights: the usable rows'
    labels under the classifier and their buildings' fitted 4PLs (:func:`_best_offsets`)."""
    use = _usable(cast, fits)
    labels = classifier.label(cast.cn0[use], elevation_units(origins.elevation[cast.ray[use]]))
    slope = cast.height_gradient[use]
    params = np.column_stack([fits.a, fits.b, fits.c, fits.d])[cast.building[use]]
    return _best_offsets(
        cast.height[use], slope, labels, params, unit[cast.ray[use]], n_units, offsets, sd, temper
    )


def _shadow_step(origins, cast, fits, classifier, unit, offsets, candidates, walks, prior):
    """Each window's step of offset by shadow matching (:meth:`.shadows.Candidates.offsets`)
    against the roofs given with the map (``prior``: heights and their standard deviations,
    NaN where none) and, for the others, the buildings that converged, labelled by the current
    classifier; none where the labels' error rates cannot be told (:func:`_label_rates`)."""
    labels = classifier.label(origins.cn0, elevation_units(origins.elevation))
    given = np.isfinite(prior[0])
    heights = np.where(given, prior[0], np.where(fits.converged, fits.c, np.nan))
    height_sd = np.where(given, prior[1], 0.0)
    rates = _label_rates(cast, fits, labels, np.where(given, prior[0] - 2.0 * prior[1], -np.inf))
    if rates is None:
        return np.zeros_like(offsets)
    found = candidates.offsets(label_chances(labels, rates), heights, height_sd, walks)
    return found - offsets


#: Rows each of the label's error rates is counted on, at least (fewer: no shadow matching).
MIN_RATE_ROWS = 30


def _label_rates(cast, fits, labels, below) -> tuple[float, float] | None:
    """The chances that a signal is labelled open where the map leaves its ray open (it crosses
    no footprint) and where the map surely blocks it (it enters a converged building more than
    two transition widths, 2/b, below its roof, or one whose roof is given above ``below``),
    from the current cast; None where either has fewer than :data:`MIN_RATE_ROWS` rows or the
    labels tell the two apart by less than 0.1."""
    crossing = np.zeros(labels.size, dtype=bool)
    crossing[cast.ray] = True
    slope = np.where(fits.converged, fits.b, 1.0)  # a fit that did not converge may have none
    surely_below = np.where(fits.converged, fits.c - 2.0 / slope, -np.inf)
    surely_below = np.fmax(surely_below, below)
    low = cast.height < surely_below[cast.building]
    blocked = np.zeros(labels.size, dtype=bool)
    blocked[cast.ray[low]] = True
    if min((~crossing).sum(), blocked.sum()) < MIN_RATE_ROWS:
        return None
    p_open = float(np.clip(labels[~crossing].mean(), 0.5, 0.99))
    p_blocked = float(np.clip(labels[blocked].mean(), 0.01, 0.5))
    return (p_open, p_blocked) if p_open - p_blocked >= 0.1 else None


def _shadow_matching(receivers, buildings, calibration, unit, origins):
    """For shadow matching (None for the roof lines): the windows' candidates cast once
    (:class:`.shadows.Candidates`: each row's satellite, one vote a window; each window's
    prior standard deviation (m), the median of its rows' own ``position_sd`` (a phone fix's
    accuracy) where they have a positive one, else the calibration's prior), with a window the
    walks that carry each window's shift (:func:`~gnss_citygml.recordings.window_walks`), and
    the roofs given with the map (:func:`_given_roofs`)."""
    if calibration.matching != "shadows":
        return None
    n_units = int(unit.max(initial=-1)) + 1
    satellite = receivers.groupby(["constellation", "svid"], sort=False).ngroup().to_numpy()
    sds = np.full(n_units, float(calibration.prior_sd))
    if "position_sd" in receivers.columns:
        own = pd.to_numeric(receivers["position_sd"], errors="coerce")
        own = own.where(own > 0).groupby(unit).median().reindex(range(n_units))
        sds = own.fillna(calibration.prior_sd).to_numpy(float)
    candidates = Candidates(
        origins.shadow_rays(satellite),
        unit,
        sds,
        origins.footprints,
        origins.max_range,
        keep=KEPT_BYTES if calibration.rounds > 1 else 0,  # one round weighs them once
    )
    walks = None if calibration.window is None else window_walks(receivers, unit)
    return candidates, walks, _given_roofs(buildings, calibration)


def check_map_heights(footprints: pd.DataFrame, calibration: Calibration) -> None:
    """Refuse, before any work, a field of the map's roof heights (``calibration.heights``)
    that the footprints lack or that holds no number (a field of names, or all empty), and warn
    where none of its numbers is a height (all 0 or less): the matching would go on without
    the map's heights, silently."""
    field = calibration.heights
    if field is None:
        return
    if field not in footprints.columns:
        raise MissingColumnError([field], where="footprints", have=list(footprints.columns))
    heights = _heights_above_ground(footprints, field)
    if np.isnan(heights).all():
        seen = footprints[field].dropna().astype(str).unique()[:3]
        raise InputError(
            f"the footprints' field {field!r} holds no height (e.g. "
            f"{', '.join(seen) if len(seen) else 'only empty values'})",
            where="footprints",
            fix="give --calibration-heights a numeric field of roof heights above the ground "
            "in metres, e.g. relh2",
        )
    if not (heights > 0).any():
        warnings.warn(
            f"no building has a positive height in the footprints' field {field!r}: the phones "
            "are matched against the roofs being estimated alone",
            UserWarning,
            stacklevel=2,
        )


def _given_roofs(buildings, calibration) -> tuple[np.ndarray, np.ndarray]:
    """Each building's roof given with the map (m, as the receivers' ``z``: its ``ground``
    plus the calibration's field of heights, where that is a positive number) and its
    standard deviation, NaN where none is given."""
    n = len(buildings)
    field = calibration.heights
    if field is None:
        return np.full(n, np.nan), np.full(n, np.nan)
    check_map_heights(buildings, calibration)
    if "ground" not in buildings.columns:
        raise MissingColumnError(["ground"], where="footprints", have=list(buildings.columns))
    above = _heights_above_ground(buildings, field)
    above[~(above > 0)] = np.nan  # none given (a map's 0 or empty)
    ground = pd.to_numeric(buildings["ground"], errors="coerce").to_numpy(float)
    return ground + above, np.full(n, calibration.heights_sd)


def _heights_above_ground(footprints, field) -> np.ndarray:
    """The field's values as numbers (NaN where not one)."""
    return pd.to_numeric(footprints[field], errors="coerce").to_numpy(float, copy=True)


class _Cast:
    """Intersections of one cast, as arrays (rows sorted by ray, then distance)."""

    def __init__(self, ray, building, height, order, cn0, height_gradient):
        self.ray, self.building, self.height = ray, building, height
        self.order, self.cn0, self.height_gradient = order, cn0, height_gradient


class _Rays:
    """The rays of the receivers table, cast against the footprints from shifted origins."""

    def __init__(self, receivers, buildings, max_range):
        self.e = receivers["e"].to_numpy(dtype=float)
        self.n = receivers["n"].to_numpy(dtype=float)
        self.z = receivers["z"].to_numpy(dtype=float)
        self.bearing = receivers["bearing"].to_numpy(dtype=float)
        self.elevation = receivers["elevation"].to_numpy(dtype=float)
        self.tan_el = np.tan(np.radians(self.elevation))
        self.cn0 = receivers["cn0"].to_numpy(dtype=float)
        self.footprints = np.asarray(buildings.geometry, dtype=object)
        self.n_buildings = len(self.footprints)
        self.max_range = max_range

    def shadow_rays(self, satellite: np.ndarray) -> dict[str, np.ndarray]:
        """The rows as :func:`.shadows.shadow_offsets` takes them, with their ``satellite``."""
        return {
            "e": self.e,
            "n": self.n,
            "z": self.z,
            "bearing": self.bearing,
            "tan_el": self.tan_el,
            "satellite": satellite,
        }

    def open_sky(self, cast: _Cast, estimator: Estimator) -> Cn0Moments | None:
        """What the rays that ``cast`` finds entering no footprint teach the mixture signal
        model (None for another model)."""
        if estimator.signal_model != "mixture":
            return None
        sky = np.ones(self.cn0.size, dtype=bool)
        sky[cast.ray] = False
        return Cn0Moments.of(self.cn0[sky], elevation_units(self.elevation[sky]), 1.0)

    def cast(self, shift) -> _Cast:
        ray, fp, dist, _, grad = footprint_entries(
            self.e + shift[:, 0],
            self.n + shift[:, 1],
            self.bearing,
            self.footprints,
            self.max_range,
            gradient=True,
        )
        first = np.r_[True, ray[1:] != ray[:-1]]
        start = np.maximum.accumulate(np.where(first, np.arange(ray.size), 0))
        tan_el = self.tan_el[ray]
        return _Cast(
            ray,
            fp,
            self.z[ray] + dist * tan_el,
            np.arange(ray.size) - start,
            self.cn0[ray],
            np.where(
                np.hypot(grad[:, 0], grad[:, 1])[:, None] <= MAX_DISTANCE_GRADIENT,
                grad * tan_el[:, None],
                np.nan,
            ),
        )


def _usable(cast: _Cast, fits) -> np.ndarray:
    """Rows that inform an offset: their building's estimate converged, no building in front
    of it along the ray may block it (at the top of its height range, c + 3/b) and the wall
    they enter is not grazed."""
    good = fits.converged[cast.building]
    top = fits.c + 3.0 / fits.b
    blocks = ~good | (cast.height < top[cast.building])
    n_rays = int(cast.ray.max()) + 1 if cast.ray.size else 0
    first_block = np.full(n_rays, np.iinfo(np.int64).max)
    np.minimum.at(first_block, cast.ray[blocks], cast.order[blocks])
    clear = cast.order <= first_block[cast.ray]
    return good & clear & np.isfinite(cast.height_gradient[:, 0])


def _interval(receivers) -> float:
    """Median seconds between a receiver's epochs (1 s without ``time_utc``)."""
    if "time_utc" not in receivers.columns:
        return 1.0
    when = pd.to_datetime(receivers["time_utc"])
    t = (when - when.min()).dt.total_seconds().to_numpy()
    key = pd.factorize(receivers["receiver"])[0]
    order = np.lexsort((t, key))
    t, key = t[order], key[order]
    gaps = np.diff(t)[(np.diff(key) == 0) & (np.diff(t) > 0)]
    return float(np.median(gaps)) if gaps.size else 1.0


def _best_offsets(height, slope, labels, params, unit, n_units, current, sd, temper=1.0):
    """Per unit, the step (added to ``current``) maximising the labels' 4PL log-likelihood
    with heights moved to first order, plus the Gaussian prior on the total offset: a coarse
    grid, then a finer one around its best point."""
    radius = min(SEARCH_SDS * sd, SEARCH_CAP)
    centre = np.zeros((n_units, 2))
    for half, count in ((radius, 11), (radius / 5.0, 9)):
        axis = np.linspace(-half, half, count)
        grid = np.stack(np.meshgrid(axis, axis, indexing="ij"), -1).reshape(-1, 2)
        score = np.empty((n_units, len(grid)))
        for k, delta in enumerate(grid):
            step = centre + delta
            h = height + np.einsum("ij,ij->i", slope, step[unit])
            score[:, k] = temper * _loglik(h, labels, params, unit, n_units)
            total = current + step
            score[:, k] -= 0.5 * np.sum(total**2, axis=1) / sd**2
        centre = centre + grid[np.argmax(score, axis=1)]
    informed = np.bincount(unit, minlength=n_units) > 0
    return np.where(informed[:, None], centre, 0.0)  # no signal, no evidence: stay


def _loglik(h, labels, params, unit, n_units):
    p = np.clip(logistic4(h, *params.T), 1e-9, 1 - 1e-9)
    return np.bincount(unit, np.where(labels, np.log(p), np.log1p(-p)), n_units)

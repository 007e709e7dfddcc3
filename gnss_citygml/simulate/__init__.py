"""Synthetic scenes with ground truth: buildings, satellites, receivers and their signals.

:func:`simulate` turns a preset scene (see :mod:`.scenes`) into the observations and
intersections tables of DESIGN.md plus the true building heights:

1. satellites of four Keplerian constellations over the site (:mod:`.constellations`);
2. the true line of sight of every satellite above the mask from every receiver epoch, tested
   against the true 2.5D roofs;
3. C/N0 from the physics of clear, diffracted and reflected signals (:mod:`.signals`);
4. the positions a user would have: manual (about 1-2 m off) or the phone's GNSS fixes (solved
   from simulated pseudoranges: 5-20 m off, worse across a canyon);
5. the intersections the estimator sees: rays from the *reported* positions cast against the
   building footprints, with ODN heights from the DEM plus a 1 m antenna (as in the paper).

Positions are in the scene's local grid (metres, bearings from grid north taken equal to true
azimuths over the few hundred metres of a scene).
"""

from __future__ import annotations

import math
import numbers
from collections.abc import Sequence
from dataclasses import dataclass

import geopandas as gpd
import numpy as np
import numpy.typing as npt
import pandas as pd
from pyproj import Transformer
from scipy.special import ndtr

from ..errors import InputError
from ..observations import satellites
from ..raycast import footprint_entries
from ..settings.checks import MAX_RANGES
from .constellations import satellite_ecef, sky
from .scenes import PRESETS, Scene, Session, make_scene
from .signals import SignalModel, ar1, diffraction_loss, gnss_fix_errors

__all__ = ["LOCATIONS", "PRESETS", "Simulation", "local_to_wgs84", "simulate", "wgs84_to_local"]

#: Where the receiver positions come from.
LOCATIONS = ("manual", "gnss")

#: The simulated recordings start here (the day of the paper's London GnssLogger log).
EPOCH = pd.Timestamp("2020-02-11T10:00:00Z")

#: Antenna height above the ground the pipeline assumes (m), as in the paper.
ASSUMED_ANTENNA = 1.0

#: Seconds between epochs: from 100 Hz (beyond any phone's logging) to one an hour.
INTERVALS = (0.01, 3600.0)

#: Most epochs (of all sessions) a simulation makes: each holds about 40 signals and their
#: satellites' orbits, so this many is a few GB in memory.
MAX_EPOCHS = 200_000

#: The simulated recordings may start from the GPS epoch to 2200 (nanosecond times reach 2262).
STARTS = (pd.Timestamp("1980-01-06T00:00:00Z"), pd.Timestamp("2200-01-01T00:00:00Z"))


@dataclass(frozen=True)
class Simulation:
    """A simulated dataset: the scene, its tables and the truth."""

    scene: Scene
    observations: pd.DataFrame
    intersections: pd.DataFrame
    truth: pd.DataFrame

    @property
    def rays(self) -> pd.DataFrame:
        """The observations as the pipeline's receivers table in the scene's grid (``bearing``
        = ``azimuth``: the grid's north is true north), to cast with
        :func:`~gnss_citygml.pipeline.intersections` as a user's data would be."""
        return self.observations.assign(bearing=self.observations["azimuth"])

    @property
    def buildings(self) -> gpd.GeoDataFrame:
        """The footprints in the scene's grid: ``id`` and ``geometry``."""
        return gpd.GeoDataFrame(
            {"id": [b.id for b in self.scene.buildings]},
            geometry=[b.footprint for b in self.scene.buildings],
        )


def simulate(
    preset: str | Scene,
    *,
    locations: str = "manual",
    seed: int = 0,
    interval: float = 1.0,
    max_range: float = 500.0,
    start: str | pd.Timestamp = EPOCH,
    physics: SignalModel | Sequence[SignalModel] = SignalModel(),
) -> Simulation:
    """Simulate a preset site.

    Parameters
    ----------
    preset
        ``ucl``, ``goodchild``, ``hermitage`` or ``city``, or a :class:`~.scenes.Scene` of
        one's own (e.g. a large :func:`~.scenes.city_scene`).
    locations
        ``manual`` (surveyed by hand, ~1-2 m) or ``gnss`` (the phone's own fixes).
    seed
        Seed of every random choice: receiver placement, device, fading, errors.
    interval
        Seconds between epochs (1 Hz like the paper's recordings by default).
    max_range
        Horizontal range (m) of the rays cast for the intersections.
    start
        UTC time of the scene's first recording; the satellites move on from there.
    physics
        The signals' and positions' physics (:class:`~.signals.SignalModel`): reflection
        losses and shares, device and body losses, tracking threshold, manual position error.
        One for every session (one phone, its offset drawn once from ``device_sd``), or one per
        session of the scene: each recording its own phone (its own offset drawn from its
        ``device_sd``, its tracking threshold and body loss).

    Returns
    -------
    Simulation
        ``observations`` (one row per epoch x satellite above the mask, with ``cn0`` NaN for
        blocked signals; the reported position as ``lat``, ``lon`` (WGS84) with ``h`` empty, as
        the DEM gives receiver heights, and in the scene's grid as ``e``, ``n``, ``z`` (ODN);
        ``position_sd``, the error a phone reports with its fix (empty for positions placed by
        hand, whose error the user does not know);
        the truth as ``e_true``, ``n_true``, ``z_true`` and ``los``), ``intersections``
        (``signal``, ``building``, ``height``, ``distance``, ``order``, ``cn0``, ``receiver``)
        and ``truth`` (``id``, ``height``, ``ground``, ``target``, and the roof span
        ``roof_low``, ``roof_high``: its lowest and highest point, ODN).

    Examples
    --------
    >>> sim = simulate("goodchild", interval=30.0)
    >>> sorted(sim.truth.loc[sim.truth.target, "id"])
    ['goodchild_block']
    """
    if not isinstance(preset, Scene) and preset not in PRESETS:
        raise InputError(
            f"unknown simulator preset {preset!r}", fix="use one of " + ", ".join(PRESETS)
        )
    if locations not in LOCATIONS:
        raise InputError(
            f"unknown locations {locations!r}", fix="use one of " + ", ".join(LOCATIONS)
        )
    start = _check_arguments(seed, interval, max_range, start)
    rng = np.random.default_rng(seed)
    scene = preset if isinstance(preset, Scene) else make_scene(preset, rng)
    _check_size(scene, interval)
    site = _site(rng, scene, physics, start)
    frames = [_session(rng, site, k, s, locations, interval) for k, s in enumerate(scene.sessions)]
    obs = pd.concat(frames, ignore_index=True)
    inter = _intersections(obs, scene, site.footprints, max_range)
    return Simulation(scene, obs, inter, _truth(scene))


def _site(rng, scene: Scene, physics, start: pd.Timestamp) -> _Site:
    """What the scene's sessions share: its roof parts, footprints and phones (their offsets
    drawn)."""
    phones = _phones(physics, scene)
    parts = [(p, top) for b in scene.buildings for p, top in b.parts]
    return _Site(
        scene=scene,
        parts=np.array([p for p, _ in parts], dtype=object),
        tops=np.array([t for _, t in parts]),
        footprints=np.array([b.footprint for b in scene.buildings], dtype=object),
        device=_devices(rng, physics, phones),
        physics=phones,
        start=start,
    )


def _truth(scene: Scene) -> pd.DataFrame:
    """The truth table of :class:`Simulation`: each building's heights and whether a target."""
    targets = set(scene.targets) or {b.id for b in scene.buildings}
    return pd.DataFrame(
        {
            "id": [b.id for b in scene.buildings],
            "height": [b.true_height for b in scene.buildings],
            "ground": [b.ground for b in scene.buildings],
            "target": [b.id in targets for b in scene.buildings],
            "roof_low": [b.roof_span[0] for b in scene.buildings],
            "roof_high": [b.roof_span[1] for b in scene.buildings],
        }
    )


def _check_arguments(seed, interval, max_range, start) -> pd.Timestamp:
    """Refuse, in one line, a seed, interval, ray length or start the simulator cannot use;
    the start as a timestamp."""
    if isinstance(seed, bool) or not (isinstance(seed, numbers.Integral) and int(seed) >= 0):
        raise InputError(
            f"the seed must be a whole number, 0 or more, not {seed!r}", fix="give --seed, e.g. 0"
        )
    lo, hi = INTERVALS
    if not (_real(interval) and lo <= interval <= hi):
        raise InputError(
            f"--interval must be a number of seconds from {lo:g} to {hi:g}, not {interval!r}",
            fix="give --interval in seconds between epochs, e.g. 1 (1 Hz, as a phone logs)",
        )
    if not (_real(max_range) and MAX_RANGES[0] < max_range <= MAX_RANGES[1]):
        raise InputError(
            f"max_range must be a positive number of metres up to {MAX_RANGES[1]:g}, "
            f"not {max_range!r}",
            fix="e.g. 500",
        )
    try:
        first = pd.Timestamp(start)
        if isinstance(first, pd.Timestamp) and first.tzinfo is None:
            first = first.tz_localize("UTC")  # as the observations' reader takes it
    except (TypeError, ValueError, OverflowError):
        first = pd.NaT
    if not (isinstance(first, pd.Timestamp) and STARTS[0] <= first <= STARTS[1]):
        raise InputError(
            f"the start {start!r} is not a UTC time from {STARTS[0]:%Y-%m-%d} to "
            f"{STARTS[1]:%Y-%m-%d}",
            fix="give the start as ISO 8601, e.g. 2020-02-11T10:00:00Z",
        )
    return first


def _phones(physics, scene: Scene) -> tuple[SignalModel, ...]:
    """The physics of each session's phone: ``physics`` for each, or one per session."""
    if isinstance(physics, SignalModel):
        return (physics,) * len(scene.sessions)
    phones = tuple(physics)
    if len(phones) != len(scene.sessions) or not all(isinstance(p, SignalModel) for p in phones):
        raise InputError(
            f"the physics must be one SignalModel or one per session "
            f"({len(scene.sessions)}), not {len(phones)} values",
            where=f"scene {scene.name}",
            fix="give one SignalModel, or a list with one for each of the scene's sessions",
        )
    return phones


def _devices(rng, physics, phones) -> np.ndarray:
    """Each session's phone's C/N0 offset (dB): one drawn for all, or one each."""
    if isinstance(physics, SignalModel):
        return np.full(len(phones), rng.normal(0.0, physics.device_sd))
    return rng.normal(0.0, [p.device_sd for p in phones])


def _real(value) -> bool:
    return isinstance(value, numbers.Real) and not isinstance(value, bool) and math.isfinite(value)


def _check_size(scene: Scene, interval: float) -> None:
    """Refuse, before anything is made, a simulation whose epochs would not fit in memory."""
    seconds = sum(s.duration for s in scene.sessions)
    epochs = sum(math.ceil(s.duration / interval) for s in scene.sessions)
    if epochs > MAX_EPOCHS:
        least = seconds / MAX_EPOCHS
        raise InputError(
            f"--interval {interval:g} s makes {epochs:,} epochs of {seconds:g} s of recordings, "
            f"more than the {MAX_EPOCHS:,} a simulation holds in memory",
            where=f"scene {scene.name}",
            fix=f"give --interval {math.ceil(least * 100) / 100:g} or more",
        )


@dataclass(frozen=True)
class _Site:
    """What every session of a simulation shares."""

    scene: Scene
    parts: np.ndarray  # flat-topped roof parts of all buildings
    tops: np.ndarray  # their tops (ODN, m)
    footprints: np.ndarray  # one per building
    device: np.ndarray  # C/N0 offset of each session's phone (dB)
    start: pd.Timestamp
    physics: tuple[SignalModel, ...]  # each session's


def _line_of_sight(site: _Site, xt, yt, zt, s_az, s_el) -> tuple[np.ndarray, np.ndarray]:
    """Each signal's true line of sight against the true roofs: blocked or not, and the
    diffraction loss (dB) of its direct path over the roof edges it passes."""
    ray, part, dist, _ = footprint_entries(xt, yt, s_az, site.parts)
    clearance = site.tops[part] - (zt + dist * np.tan(np.radians(s_el[ray])))
    blocked = np.zeros(s_az.size, dtype=bool)
    blocked[ray[clearance > 0]] = True
    loss = np.zeros(s_az.size)
    np.maximum.at(loss, ray, diffraction_loss(clearance, dist, s_el[ray]))
    return blocked, loss


def _position_errors(
    rng, m, session, locations, interval, az, el, visible, signals, received, nlos, cn0
) -> tuple[np.ndarray, np.ndarray]:
    """The errors (east, north; m) of the positions the user has, epoch by epoch, and the
    error they are reported with (none for points placed by hand: the user does not know it,
    and the estimator's default applies). ``signals``: each signal's epoch and satellite."""
    n_ep = az.shape[0]
    reported_sd = np.full(n_ep, np.nan)
    if locations == "manual":
        if session.walking:
            return ar1(rng, n_ep, interval, 30.0, m.manual_sd, (2,)), reported_sd
        return np.tile(rng.normal(0.0, m.manual_sd, 2), (n_ep, 1)), reported_sd
    rec, nl, c = np.zeros(az.shape, bool), np.zeros(az.shape, bool), np.full(az.shape, np.nan)
    rec[signals], nl[signals], c[signals] = received, nlos, cn0
    de, dn, reported_sd = gnss_fix_errors(
        rng,
        np.where(visible, az, np.nan),
        np.where(visible, el, np.nan),
        rec,
        nl,
        c,
        dt=interval,
        nlos_delay=m.nlos_delay,
        understatement=m.understatement,
        fix_seconds=m.fix_seconds,
    )
    return np.column_stack([de, dn]), reported_sd


def _session(rng, site: _Site, k: int, session: Session, locations, interval):
    scene = site.scene
    t = session.start + np.arange(0.0, session.duration, interval)
    true_xy = _positions(session, t)
    antenna = rng.normal(1.1, 0.1)  # a phone held in the hand
    letters, svids, sat_xyz = satellite_ecef(t + (site.start - EPOCH).total_seconds())
    az, el = sky(scene.lat, scene.lon, scene.ground, sat_xyz)
    visible = (el >= scene.min_elevation) & (el <= scene.max_elevation)
    ep, sat = np.nonzero(visible)
    s_az, s_el = az[ep, sat], el[ep, sat]
    xt, yt = true_xy[ep, 0], true_xy[ep, 1]
    zt = scene.ground + antenna

    blocked, loss = _line_of_sight(site, xt, yt, zt, s_az, s_el)

    # C/N0 of the direct (possibly diffracted) and reflected components.
    m = site.physics[k]
    base = (
        m.zenith_cn0
        - m.horizon_loss * (1.0 - np.sin(np.radians(s_el)))
        + site.device[k]
        + rng.normal(0.0, m.session_sd)
        - m.body_loss
    )
    direct = base - loss + rng.normal(0.0, m.fading_sd, ep.size)
    behind, _, _, _ = footprint_entries(
        xt, yt, (s_az + 180.0) % 360.0, site.footprints, max_range=60.0
    )
    facade = np.zeros(ep.size, dtype=bool)
    facade[behind] = True
    share = np.where(facade, m.reflected_facade, m.reflected_open)
    reflects = blocked & (_reflection_draws(rng, m, (ep, sat), az.shape[0], interval) < share)
    reflected = np.where(
        reflects, base - rng.normal(m.reflection_loss, m.reflection_sd, ep.size), -np.inf
    )
    cn0 = 10.0 * np.log10(10 ** (direct / 10.0) + 10 ** (reflected / 10.0))
    received = cn0 >= m.tracking_threshold
    nlos = received & blocked & (reflected > direct)
    cn0 = np.where(received, np.round(cn0, 1), np.nan)

    err, reported_sd = _position_errors(
        rng, m, session, locations, interval, az, el, visible, (ep, sat), received, nlos, cn0
    )
    rep = true_xy + err
    lon, lat = local_to_wgs84(scene, rep[:, 0], rep[:, 1])
    return pd.DataFrame(
        {
            "time_utc": site.start + pd.to_timedelta(t[ep], unit="s"),
            "receiver": session.receiver,
            "constellation": letters[sat],
            "svid": svids[sat],
            "azimuth": s_az,
            "elevation": s_el,
            "cn0": cn0,
            "lat": lat[ep],
            "lon": lon[ep],
            "h": np.nan,
            "position_sd": reported_sd[ep],
            "e": rep[ep, 0],
            "n": rep[ep, 1],
            "z": scene.ground + ASSUMED_ANTENNA,
            "e_true": xt,
            "n_true": yt,
            "z_true": zt,
            "los": ~blocked,
        }
    )


def _reflection_draws(rng, m: SignalModel, signals, n_epochs: int, interval: float) -> np.ndarray:
    """Uniform draws per signal (``signals``: epoch and satellite indices) below which a
    blocked signal arrives reflected: anew each epoch, or, with ``m.reflection_seconds``, from
    a Gauss-Markov process per satellite lasting that long, so that a reflection holds while
    its facade does."""
    ep, sat = signals
    if m.reflection_seconds <= 0:
        return rng.random(ep.size)
    n_sat = int(sat.max()) + 1 if sat.size else 0
    return ndtr(ar1(rng, n_epochs, interval, m.reflection_seconds, 1.0, (n_sat,)))[ep, sat]


def local_to_wgs84(
    scene: Scene, x: npt.ArrayLike, y: npt.ArrayLike
) -> tuple[np.ndarray, np.ndarray]:
    """WGS84 longitude and latitude (deg) of points of the scene's local grid (m east and north
    of the scene's origin on the WGS84 ellipsoid): an exact conversion, no datum shift."""
    x = np.asarray(x, dtype=float)
    lon, lat, _ = _geodetic(scene).transform(x, np.asarray(y, dtype=float), np.zeros_like(x))
    return lon, lat


def wgs84_to_local(
    scene: Scene, lon: npt.ArrayLike, lat: npt.ArrayLike
) -> tuple[np.ndarray, np.ndarray]:
    """The scene's local grid coordinates (m east, m north) of WGS84 points (deg): the
    inverse of :func:`local_to_wgs84`."""
    lon = np.asarray(lon, dtype=float)
    x, y, _ = _geodetic(scene).transform(
        lon, np.asarray(lat, dtype=float), np.zeros_like(lon), direction="INVERSE"
    )
    return x, y


def _geodetic(scene: Scene):
    return Transformer.from_pipeline(
        "+proj=pipeline +step +inv +proj=topocentric +ellps=WGS84 "
        f"+lat_0={scene.lat} +lon_0={scene.lon} +h_0=0 "
        "+step +inv +proj=cart +ellps=WGS84 +step +proj=unitconvert +xy_in=rad +xy_out=deg"
    )


def _positions(session: Session, t):
    path = np.asarray(session.path, dtype=float)
    if not session.walking or len(path) == 1:
        return np.tile(path[0], (t.size, 1))
    frac = (t - session.start) / session.duration
    seg = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(path, axis=0).T))])
    along = frac * seg[-1]
    return np.column_stack([np.interp(along, seg, path[:, 0]), np.interp(along, seg, path[:, 1])])


def _intersections(obs: pd.DataFrame, scene: Scene, footprints, max_range):
    ray, b, dist, cos = footprint_entries(
        obs["e"].to_numpy(), obs["n"].to_numpy(), obs["azimuth"].to_numpy(), footprints, max_range
    )
    el = np.radians(obs["elevation"].to_numpy()[ray])
    first = np.r_[True, ray[1:] != ray[:-1]]
    start = np.maximum.accumulate(np.where(first, np.arange(ray.size), 0))
    ids = np.array([bd.id for bd in scene.buildings], dtype=object)
    return pd.DataFrame(
        {
            "signal": ray,
            "building": ids[b],
            "height": obs["z"].to_numpy()[ray] + dist * np.tan(el),
            "distance": dist,
            "order": np.arange(ray.size) - start,
            "cn0": obs["cn0"].to_numpy()[ray],
            "receiver": obs["receiver"].to_numpy()[ray],
            "satellite": satellites(obs)[ray],
        }
    )

"""4PL-B on city scenes the estimator was never looked at with: do the presets' figures hold?

Each scene is drawn at random (seed 100 + k): a grid of 3-7 x 3-6 blocks with flat, pitched
and multi-part buildings of 8-45 m, 4-11 people walking for 200-600 s, on a random day of
2020 at a random time (so another sky). It is simulated with manual and with GNSS positions
and estimated with the initial thresholds 20, 30 and 40 dB-Hz; one line per scene and
locations, then the totals. The constants of the estimator are the paper's and the physics';
none was chosen on these scenes or on the presets.

With ``--physics``, each scene also draws its physics (issue 14) from the ranges of
:data:`PHYSICS`: reflection losses of 3-15 dB, the share of blocked signals that arrive
reflected, device offsets, tracking thresholds of 10-20 dB-Hz, body losses of 0-8 dB and
manual position errors of 0.3-2 m; each line says which.

With ``--regimes``, the scenes are streets instead (:func:`street_scene`), drawn in each of
the regimes of :data:`REGIMES` (a narrow canyon with receivers 3-8 m from the wall, a street,
a square), with their physics drawn too; the totals are then per regime and locations.
``--regime`` chooses among them and a walked district (:func:`district_scene`, issue 28).

With ``--labels los`` the signals are labelled by the simulator's line of sight (a perfect
signal classifier) and with ``--positions true`` the rays start from the true positions: the
two together give what the height fits can do with perfect information, the floor of the
estimator on these scenes (issue 14).

Each estimate is judged by its distance to the building's roof span [lowest, highest roof
point] (0 inside) and its range by whether it meets the span (issue 27, decision 1), with the
error to the true height (the span's middle) beside them. With ``--reference los`` each scene
is estimated a second time with the signals labelled by the line of sight, from the same
(recorded) positions: the converged count of that perfect classifier, and the share of it
the labels of ``--labels`` reach (issue 27, decision 2: at least 80 %), and its right answers.
Beside the RMSE every line counts the right answers (converged, within :data:`RIGHT_WITHIN` of
the span: 1 m with hand-placed points, 2 m with phone fixes) and the wrong ones (converged, the
range missing the span), with their share of the answers (issue 47, decision 3).

With ``--phones each`` every session of a scene is recorded by its own phone: its own C/N0
offset, tracking threshold and body loss (issue 27, decision 3).

With ``--harsh`` the phones' fixes are as bad as in real dense streets (issue 48,
:data:`HARSH`: reflections' extra paths of tens of metres that hold while a walker passes a
facade, fixes the phone smooths, claimed errors 1.3-2x too small), and with ``--days N`` the
walked district is walked on N days, each by other people under another sky.

With ``--outside M`` every phone fix inside a footprint is moved out across the nearest wall,
M metres beyond it, and with ``--outside mean`` to where its reported error puts the true
position on average, given that a pedestrian is not inside a building (the mean of its
Gaussian beyond the wall): issue 28, item 1.

With ``--sd-scale K`` the phone fixes' reported errors (``position_sd``) are multiplied by K
before anything else: what the fits would do if a phone's claim were K times as honest (issue
28, item 3; the simulator's fixes are 1.1-1.6 times as far off as they claim).

With ``--match known`` the phone fixes are shadow-matched (``shadow_matching.py``: one shift
per ``--match-window`` seconds of each recording) against the scene's true heights before the
rays are cast: a perfect map, with the signals' C/N0 or (``--match-labels los``) their line of
sight, the floor of shadow matching (issue 28, item 2).

With ``--calibrate`` the receivers are self-calibrated first (one offset per recording, or per
``--calibration-window`` seconds of it, prior sd manual 1 m, phone fixes 5 m: issue 27, item 3),
for each initial threshold, with the C/N0 classifier (the reference's perfect labels are judged
on the uncalibrated positions), ``--calibration-rounds`` rounds; with ``--calibration-matching
shadows`` by shadow matching (issue 28, item 2; each window's prior its fixes' own
``position_sd``), with ``--prior-heights SD`` against each building's height given with the
map (the truth's with a normal error of SD m, which it claims).

    python benchmarks/scenes.py [--scenes 8] [--physics | --regimes]
                                [--position-errors data|exact|fixed] [--position-window 30]
                                [--position-distance 50|recording]
                                [--weighting looks] [--labels cn0|los] [--reference los]
                                [--positions reported|common|true]
                                [--calibrate [--calibration-window 30]] [--phones each]
                                [--regimes [--regime district ...]] [--sd-scale 1.5]
                                [--outside 1|mean] [--match known]
                                [--calibrate --calibration-matching shadows]
"""

from __future__ import annotations

import argparse
from dataclasses import replace

import numpy as np
import pandas as pd
import shapely
from accuracy import (
    LABELS,
    POSITION_ERRORS,
    POSITION_SD,
    POSITIONS,
    judge,
    labelled,
    position_error,
    site_tables,
)
from scipy.stats import norm
from shadow_matching import shadow_matched

from gnss_citygml import Estimator, estimate_heights
from gnss_citygml.calibrate import calibrate_receivers
from gnss_citygml.pipeline import intersections, open_sky
from gnss_citygml.settings import BLAMES, MATCHINGS, SIGNAL_MODELS, WEIGHTINGS, Calibration
from gnss_citygml.simulate import EPOCH, LOCATIONS, simulate
from gnss_citygml.simulate.scenes import city_scene, city_walks, street_scene
from gnss_citygml.simulate.signals import SignalModel

THRESHOLDS = (20.0, 30.0, 40.0)

#: A right answer: converged and at most this far (m) from the roof span, by locations; a
#: wrong answer: converged and its range misses the span (issue 47, decision 3).
RIGHT_WITHIN = {"manual": 1.0, "gnss": 2.0}

#: Street width and receivers' distance from the nearest wall (m, uniform) of each regime.
REGIMES = {
    "narrow street": ((8.0, 15.0), (3.0, 8.0)),
    "street": ((15.0, 40.0), (5.0, 20.0)),
    "square": ((80.0, 240.0), (40.0, 120.0)),
}

#: The ranges (uniform) the physics of a scene is drawn from with --physics.
PHYSICS = {
    "reflection_loss": (3.0, 15.0),
    "reflected_facade": (0.3, 0.9),
    "reflected_open": (0.05, 0.4),
    "device_sd": (1.0, 4.0),
    "tracking_threshold": (10.0, 20.0),
    "body_loss": (0.0, 8.0),
    "manual_sd": (0.3, 2.0),
}


def random_scene(k: int):
    """Scene ``k`` and its start time."""
    rng = np.random.default_rng(100 + k)
    columns, rows = int(rng.integers(3, 8)), int(rng.integers(3, 7))
    walkers, seconds = int(rng.integers(4, 12)), float(rng.uniform(200.0, 600.0))
    scene = city_scene(rng, columns, rows, walkers, seconds)
    start = EPOCH + pd.Timedelta(days=int(rng.integers(0, 300)), hours=float(rng.uniform(0, 24)))
    return scene, start, f"{columns}x{rows} blocks, {walkers} walkers x {seconds:.0f} s"


#: The ranges (uniform) of the phones' fixes in streets as harsh as real ones (issue 48,
#: ``--harsh``): a reflected-only signal's extra path on a scale of 50-100 m (a reflection off
#: a facade across or beyond a 15-40 m street travels one to three widths farther), reflections
#: that hold for 10-30 s (a walker passing a 10-25 m facade), fixes the phone's filter smooths
#: over 5-15 s (which averages their errors but not the error the phone claims), and claimed
#: errors 1.3-2x smaller than the fix's own estimate (phones understate theirs 1.3-2x in dense
#: streets).
HARSH = {
    "nlos_delay": (50.0, 100.0),
    "understatement": (1.3, 2.0),
    "reflection_seconds": (10.0, 30.0),
    "fix_seconds": (5.0, 15.0),
}

#: The walked district (issue 28): a grid of blocks (:func:`city_scene`) of this many columns
#: and rows, walked by a number of people drawn from ``WALKERS`` (uniform).
DISTRICT = (6, 6)
WALKERS = (20, 40)


def district_scene(k: int):
    """District scene ``k``: :data:`DISTRICT` blocks walked by 20-40 people, each for 200-600 s,
    one after another, its start time and a description."""
    rng = np.random.default_rng(9000 + k)
    walkers, seconds = int(rng.integers(WALKERS[0], WALKERS[1] + 1)), float(rng.uniform(200, 600))
    scene = city_scene(rng, *DISTRICT, walkers, seconds)
    start = EPOCH + pd.Timedelta(days=int(rng.integers(0, 300)), hours=float(rng.uniform(0, 24)))
    return scene, start, f"district: {walkers} people walking {seconds:.0f} s each"


def district_days(k: int, days: int):
    """District scene ``k`` walked on ``days`` days: the first day's walks
    (:func:`district_scene`), then each other day 20-40 other people at another time of day
    (a day's satellites are another day's four minutes earlier, Galileo's repeat ten days),
    with the first day's start and a description. Days past the first start 1-7 days apart."""
    scene, start, text = district_scene(k)
    sessions, offset = list(scene.sessions), 0.0
    for day in range(2, days + 1):
        rng = np.random.default_rng(9000 + 1000 * day + k)
        offset += 86400.0 * int(rng.integers(1, 8)) + float(rng.uniform(-6, 6)) * 3600.0
        walkers, seconds = int(rng.integers(WALKERS[0], WALKERS[1] + 1)), rng.uniform(200, 600)
        walks = city_walks(rng, *DISTRICT, walkers, float(seconds), name=f"day{day}_walker")
        sessions += [replace(w, start=w.start + offset) for w in walks]
    return replace(scene, sessions=tuple(sessions)), start, f"{text}; {days} days"


def regime_scene(k: int, regime: str, days: int = 1):
    """Street scene ``k`` of ``regime`` (the district walked on ``days`` days), its start time
    and a description."""
    if regime == "district":
        return district_days(k, days) if days > 1 else district_scene(k)
    rng = np.random.default_rng(5000 + 97 * k + sorted(REGIMES).index(regime))
    (w0, w1), (o0, o1) = REGIMES[regime]
    width = float(rng.uniform(w0, w1))
    offset = float(min(rng.uniform(o0, o1), width / 2))
    walking = bool(rng.random() < 0.5)
    scene = street_scene(rng, width, offset, walkers=int(rng.integers(3, 7)), walking=walking)
    start = EPOCH + pd.Timedelta(days=int(rng.integers(0, 300)), hours=float(rng.uniform(0, 24)))
    kind = "walking" if walking else "static"
    return (
        scene,
        start,
        f"{regime}: {width:.0f} m wide, receivers {offset:.0f} m from the wall, {kind}",
    )


def random_physics(k: int) -> SignalModel:
    """The physics of scene ``k``: every constant of :data:`PHYSICS` drawn in its range."""
    rng = np.random.default_rng(1000 + k)
    return SignalModel(**{name: float(rng.uniform(*bounds)) for name, bounds in PHYSICS.items()})


#: What differs from one phone to another with ``--phones each``: drawn per session from the
#: ranges of :data:`PHYSICS` (the C/N0 offset is drawn by the simulator from ``device_sd``).
PHONE = ("tracking_threshold", "body_loss")


def harsh(k: int, physics: SignalModel) -> SignalModel:
    """Scene ``k``'s ``physics`` with the phones' fixes of :data:`HARSH` streets."""
    rng = np.random.default_rng(4000 + k)
    return replace(physics, **{name: float(rng.uniform(*HARSH[name])) for name in HARSH})


def phones(k: int, physics: SignalModel, sessions: int) -> list[SignalModel]:
    """Scene ``k``'s ``physics`` for each of its ``sessions``, each recorded by its own phone
    (issue 27, decision 3)."""
    rng = np.random.default_rng(3000 + k)
    return [
        replace(physics, **{name: float(rng.uniform(*PHYSICS[name])) for name in PHONE})
        for _ in range(sessions)
    ]


def _physics_text(physics: SignalModel) -> str:
    return (
        f"reflection -{physics.reflection_loss:.0f} dB, "
        f"{physics.reflected_facade:.0%}/{physics.reflected_open:.0%} reflected, "
        f"tracking {physics.tracking_threshold:.0f} dB-Hz, body -{physics.body_loss:.0f} dB, "
        f"manual {physics.manual_sd:.1f} m{_fixes_text(physics)}"
    )


def _fixes_text(physics: SignalModel) -> str:
    """The phones' fixes' physics where it is not the simulator's default (``--harsh``)."""
    today = SignalModel()
    fixes = ("nlos_delay", "understatement", "reflection_seconds", "fix_seconds")
    if all(getattr(physics, name) == getattr(today, name) for name in fixes):
        return ""
    return (
        f", reflections' extra path {physics.nlos_delay:.0f} m, "
        f"lasting {physics.reflection_seconds:.0f} s, smoothed {physics.fix_seconds:.0f} s, "
        f"claimed errors {physics.understatement:.2f}x small"
    )


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenes", type=int, default=8, help="number of random scenes")
    parser.add_argument(
        "--position-errors",
        choices=POSITION_ERRORS,
        default="data",
        help="what the fits are told of the position errors: the observations' (default), "
        "none (exact, as the paper) or fixed sizes (manual 1 m, phone fixes 5 m per axis)",
    )
    parser.add_argument(
        "--position-distance",
        type=lambda v: None if v == "recording" else float(v),
        default=...,
        help="metres a moving receiver goes with one position error (default: the API's 50); "
        "'recording': one per recording (before issue 28)",
    )
    parser.add_argument(
        "--position-window",
        type=float,
        default=None,
        help="instead of the distance: seconds one position error of a moving receiver lasts",
    )
    parser.add_argument(
        "--physics", action="store_true", help="draw each scene's physics too (PHYSICS)"
    )
    parser.add_argument(
        "--weighting", choices=WEIGHTINGS, default="none", help="weighting of the height fits"
    )
    parser.add_argument(
        "--signal-model",
        choices=SIGNAL_MODELS,
        default="paper",
        help="how 4PL-B labels the signals (the reference's perfect labels are always hard)",
    )
    parser.add_argument(
        "--blame",
        choices=BLAMES,
        default=Estimator.blame,
        help="what a closed ray crossing several buildings tells each (the reference's too)",
    )
    parser.add_argument(
        "--crossing",
        action="store_true",
        help="each row weighs by its chance of crossing its building, near misses give rows "
        "(PositionError(crossing=True))",
    )
    parser.add_argument("--save", help="write every converged run to this CSV")
    parser.add_argument(
        "--days",
        type=int,
        default=1,
        help="the walked district on this many days, each with other people, phones and sky "
        "(district_days)",
    )
    parser.add_argument(
        "--interval", type=float, default=1.0, help="seconds between epochs (default 1)"
    )
    parser.add_argument(
        "--harsh",
        action="store_true",
        help="the phones' fixes of streets as harsh as real ones (HARSH: reflections' extra "
        "path 50-100 m, lasting 10-30 s, fixes smoothed over 5-15 s, claimed errors 1.3-2x "
        "smaller)",
    )
    parser.add_argument(
        "--no-open-sky",
        action="store_true",
        help="the mixture learns without the signals whose rays cross no footprint",
    )
    parser.add_argument(
        "--regimes", action="store_true", help="street scenes in each regime (REGIMES)"
    )
    parser.add_argument(
        "--regime",
        action="append",
        choices=[*REGIMES, "district"],
        help="with --regimes: only this regime (repeatable; default: those of REGIMES); "
        "district: a walked district (DISTRICT blocks, 20-40 people)",
    )
    parser.add_argument(
        "--labels",
        choices=LABELS,
        default="cn0",
        help="label the signals by their C/N0 (default) or by the simulator's line of sight",
    )
    parser.add_argument(
        "--reference",
        choices=LABELS,
        default=None,
        help="estimate each scene with these labels too (los: the perfect classifier) and "
        "report the converged count relative to it",
    )
    parser.add_argument(
        "--positions",
        choices=POSITIONS,
        default="reported",
        help="cast the rays from the positions a user has (default) or the true ones",
    )
    parser.add_argument(
        "--phones",
        choices=("one", "each"),
        default="one",
        help="one phone records every session of a scene (default), or each session its own "
        "(its C/N0 offset, tracking threshold and body loss)",
    )
    parser.add_argument(
        "--sd-scale",
        type=float,
        default=1.0,
        help="multiply the phone fixes' reported position errors by this (default 1: as claimed)",
    )
    parser.add_argument(
        "--outside",
        help="move the phone fixes inside a footprint out of it: this many metres beyond the "
        "nearest wall, or 'mean': the mean of the fix's Gaussian beyond it",
    )
    parser.add_argument(
        "--match",
        choices=("known",),
        help="shadow-match the phone fixes (shadow_matching.py) before the rays are cast, "
        "against the scene's true heights (known: a perfect map, the floor of map matching)",
    )
    parser.add_argument(
        "--match-labels",
        choices=("cn0", "los"),
        default="cn0",
        help="with --match: what a signal says, its C/N0 or (los) the simulator's line of sight",
    )
    parser.add_argument(
        "--match-window", type=float, default=10.0, help="with --match: seconds of one shift"
    )
    parser.add_argument(
        "--no-level-phones",
        action="store_true",
        help="the C/N0 as recorded: no phone levelled by its open sky (the paper's)",
    )
    parser.add_argument(
        "--calibrate", action="store_true", help="self-calibrate the receivers' offsets first"
    )
    parser.add_argument(
        "--calibration-matching",
        choices=MATCHINGS,
        default="roof lines",
        help="with --calibrate: how each offset is found (shadows: shadow matching)",
    )
    parser.add_argument(
        "--calibration-rounds", type=int, default=3, help="with --calibrate: rounds"
    )
    parser.add_argument(
        "--calibration-window",
        type=float,
        default=None,
        help="with --calibrate: one offset per this many seconds (default: per recording)",
    )
    parser.add_argument(
        "--prior-heights",
        type=float,
        metavar="SD",
        help="with --calibration-matching shadows: each building's height given with the map, "
        "its true height plus a normal error of this standard deviation (m), which it claims",
    )
    return parser


def main():
    args = _parser().parse_args()
    runs, totals, reached = [], {}, {}
    header = (
        "converged | RMSE to span | RMSE to middle | median abs. error to middle | worst to span | "
        "RMSE of c + 1.5/b | range covers middle | range meets span | right | wrong |"
    )
    if args.reference:
        header += (
            f" converged, {args.reference} labels | share of it | its RMSE to span | its right |"
        )
    print(f"| scene | layout | locations | {header}")
    print("|---" * (3 + header.count("|")) + "|")
    if args.regimes:
        regimes = args.regime or list(REGIMES)
        drawn = [
            (k, r, *regime_scene(k, r, args.days)) for k in range(args.scenes) for r in regimes
        ]
    else:
        drawn = [(k, None, *random_scene(k)) for k in range(args.scenes)]
    for k, regime, scene, start, layout in drawn:
        physics = random_physics(k) if args.physics or args.regimes else SignalModel()
        if args.harsh:
            physics = harsh(k, physics)
        if args.physics or args.regimes:
            layout = f"{layout}; {_physics_text(physics)}"
        if args.phones == "each":
            physics = phones(k, physics, len(scene.sessions))
            layout += "; each session its own phone"
        for locations in LOCATIONS:
            sim = simulate(
                scene,
                locations=locations,
                seed=k,
                start=start,
                physics=physics,
                interval=args.interval,
            )
            if args.outside is not None and locations == "gnss":
                moved = outside_buildings(sim.observations, sim.buildings, args.outside)
                sim = replace(sim, observations=moved)
            if args.sd_scale != 1.0:
                claimed = sim.observations["position_sd"] * args.sd_scale
                sim = replace(sim, observations=sim.observations.assign(position_sd=claimed))
            error = position_error(
                args.position_errors, locations, args.position_window, args.position_distance
            )
            error = replace(error, crossing=args.crossing)
            estimator = Estimator(
                weighting=args.weighting,
                blame=args.blame,
                signal_model=args.signal_model,
                level_phones=not args.no_level_phones and args.labels == "cn0",
            )
            if args.match is not None and locations == "gnss":
                sim = _matched(sim, args)
            rays, _, cast = site_tables(sim, positions=args.positions, position_error=error)
            sky = None if args.no_open_sky else open_sky(rays, cast)
            recast = None
            if args.calibrate:
                calibration = Calibration(
                    prior_sd=POSITION_SD[locations],
                    window=args.calibration_window,
                    rounds=args.calibration_rounds,
                    matching=args.calibration_matching,
                    heights=None if args.prior_heights is None else "prior",
                    heights_sd=args.prior_heights or 2.0,
                )
                buildings = sim.buildings
                if args.prior_heights is not None:
                    buildings = _with_priors(sim, args.prior_heights, k)
                recast = _calibrated(sim, buildings, rays, error, calibration, sky is not None)
            err = _judged(sim, cast, args.labels, estimator, sky, recast)
            n_runs = len(sim.truth) * len(THRESHOLDS)
            group = locations if regime is None else f"{regime}, {locations}"
            err = err.assign(group=group, scene=k, locations=locations)
            runs.append(err)
            totals[group] = totals.get(group, 0) + n_runs
            cells = _cells(err, n_runs)
            if args.reference:
                perfect = Estimator(weighting=args.weighting, blame=args.blame, level_phones=False)
                ref = _judged(sim, cast, args.reference, perfect, sky).assign(locations=locations)
                reached.setdefault(group, []).append(ref)
                cells += f" | {_reference_cells(err, ref, n_runs)}"
            print(f"| {k} | {layout} | {locations} | {cells} |", flush=True)
    every = pd.concat(runs)
    if args.save:
        every.rename_axis("id").reset_index().to_csv(args.save, index=False)
    print("\nAll scenes, thresholds 20/30/40:\n")
    print(f"| {'regime, locations' if args.regimes else 'locations'} | {header}")
    print("|---" * (1 + header.count("|")) + "|")
    for group, n_runs in totals.items():
        err = every[every["group"] == group]
        cells = _cells(err, n_runs)
        if args.reference:
            cells += f" | {_reference_cells(err, pd.concat(reached[group]), n_runs)}"
        print(f"| {group} | {cells} |")


def outside_buildings(obs: pd.DataFrame, buildings, beyond: str) -> pd.DataFrame:
    """``obs`` with each fix (``e``, ``n``) inside a footprint moved out across the nearest wall:
    ``beyond`` metres past it, or (``"mean"``) the mean distance past it of the fix's Gaussian
    (``position_sd``) given that the true position is outside, ``sd phi(z) / Q(z) - depth``
    with ``z = depth / sd`` (the wall taken as straight)."""
    fixes = obs[["e", "n", "position_sd"]].drop_duplicates(["e", "n"])
    e, n = fixes["e"].to_numpy().copy(), fixes["n"].to_numpy().copy()
    points = shapely.points(e, n)
    polygons = buildings.geometry.to_numpy()
    inside, building = shapely.STRtree(polygons).query(points, predicate="within")
    if inside.size:
        wall = shapely.boundary(polygons[building])
        near = shapely.get_coordinates(shapely.shortest_line(points[inside], wall))[1::2]
        out = near - np.column_stack([e[inside], n[inside]])
        depth = np.maximum(np.hypot(out[:, 0], out[:, 1]), 1e-9)
        if beyond == "mean":
            sd = fixes["position_sd"].to_numpy()[inside]
            z = depth / sd
            past = sd * norm.pdf(z) / np.maximum(norm.sf(z), 1e-300) - depth
        else:
            past = np.full(inside.size, float(beyond))
        moved = near + out / depth[:, None] * past[:, None]
        e[inside], n[inside] = moved[:, 0], moved[:, 1]
    where = pd.MultiIndex.from_frame(obs[["e", "n"]])
    new = pd.DataFrame({"e": e, "n": n}, index=pd.MultiIndex.from_arrays([fixes["e"], fixes["n"]]))
    new = new.reindex(where)
    return obs.assign(e=new["e"].to_numpy(), n=new["n"].to_numpy())


def _matched(sim, args):
    """``sim`` with its fixes shadow-matched (:func:`shadow_matching.shadow_matched`) against
    the scene's true heights (``--match known``)."""
    heights = sim.truth.set_index("id")["height"].reindex(sim.buildings["id"])
    matched = shadow_matched(
        sim.observations, sim.buildings.geometry, heights, args.match_window, args.match_labels
    )
    return replace(sim, observations=matched)


def _judged(sim, cast, labels, estimator, sky, recast=None) -> pd.DataFrame:
    """The converged runs of one scene, thresholds 20/30/40, with the signals labelled by
    ``labels`` (:func:`accuracy.judge`: errors to the middle and to the span) and
    ``estimator``'s settings (its phones levelled by, and its mixture learning from, the
    ``sky``'s signals, those crossing no footprint). ``recast`` (:func:`_calibrated`) gives
    each estimator its own intersections and sky."""
    judged = []
    for threshold in THRESHOLDS:
        estimator = replace(estimator, init_threshold=threshold)
        if recast is not None:
            cast, sky = recast(estimator)
        heights = estimate_heights(labelled(sim, cast, labels), estimator, open_sky=sky)
        judged.append(judge(heights, sim.truth).assign(threshold=threshold))
    return pd.concat(judged)


def _calibrated(sim, buildings, rays, error, calibration, with_sky):
    """For :func:`_judged`: the intersections (and open sky) of the rays cast from the positions
    self-calibrated with an estimator (against ``buildings``, with any heights they give)."""

    def recast(estimator):
        fixed = calibrate_receivers(rays, buildings, calibration, estimator=estimator)
        cast = intersections(fixed, sim.buildings, position_error=error)
        return cast, (open_sky(fixed, cast) if with_sky else None)

    return recast


def _with_priors(sim, sd: float, k: int):
    """``sim``'s buildings with their ``ground`` and a height above it given with the map
    (``prior``): the truth's with a normal error of ``sd`` (m; scene ``k``'s draw)."""
    truth = sim.truth.set_index("id").reindex(sim.buildings["id"])
    error = np.random.default_rng(7000 + k).normal(0.0, sd, len(truth))
    prior = (truth["height"] - truth["ground"]).to_numpy() + error
    return sim.buildings.assign(ground=truth["ground"].to_numpy(), prior=prior)


def _cells(err: pd.DataFrame, n_runs: int) -> str:
    if err.empty:
        return f"0/{n_runs} | - | - | - | - | - | - | - | 0 | 0"
    rmse = np.sqrt(np.mean(err["span_error"] ** 2))
    middle_rmse = np.sqrt(np.mean(err["error"] ** 2))
    paper_rmse = np.sqrt(np.mean(err["paper_error"] ** 2))
    a = err["error"].abs()
    figures = (rmse, middle_rmse, a.median(), err["span_error"].max(), paper_rmse)
    cells = [f"{len(err)}/{n_runs}", *(f"{v:.2f} m" for v in figures)]
    cells += [f"{err['covered'].mean():.0%}", f"{err['meets'].mean():.0%}"]
    wrong = int((~err["meets"].astype(bool)).sum())
    cells += [str(_right(err)), f"{wrong} ({wrong / len(err):.0%})"]
    return " | ".join(cells)


def _right(err: pd.DataFrame) -> int:
    """The right answers among converged runs: within :data:`RIGHT_WITHIN` of the span."""
    near = err["locations"].map(RIGHT_WITHIN)
    return int((err["span_error"] <= near).sum())


def _reference_cells(err: pd.DataFrame, ref: pd.DataFrame, n_runs: int) -> str:
    """The reference's converged count, the share of it that the converged runs ``err``
    reach, the reference's RMSE to the span and its right answers."""
    share = f"{len(err) / len(ref):.0%}" if len(ref) else "-"
    rmse = f"{np.sqrt(np.mean(ref['span_error'] ** 2)):.2f} m" if len(ref) else "-"
    return f"{len(ref)}/{n_runs} | {share} | {rmse} | {_right(ref) if len(ref) else 0}"


if __name__ == "__main__":
    main()

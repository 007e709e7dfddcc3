"""Accuracy of the height estimators on simulated sites, as in the paper's results table.

Research code, not part of the installed package: ``paper_table.py`` and ``scenes.py`` run it
(tests/test_accuracy.py checks it).

For each preset site and each source of receiver positions, every method is run once per
initial C/N0 threshold; the RMSE against the true heights is taken over all runs and target
buildings that converged (the paper excludes non-converged 4PL-B runs the same way) and the
converged count is reported beside it. Beside the error to the true height (the middle of the
roof span), each run has its distance to the roof span (0 inside; issue 27) and whether its
range meets the span (:func:`judge`).
"""

from __future__ import annotations

import tempfile
import time

import numpy as np
import pandas as pd

from gnss_citygml.calibrate import calibrate_receivers
from gnss_citygml.compare import roof_span, span_distance
from gnss_citygml.footprints import read_footprints
from gnss_citygml.model import METHODS
from gnss_citygml.model.estimate import estimate_heights
from gnss_citygml.observations import read_observations
from gnss_citygml.pipeline import intersections, open_sky, receivers
from gnss_citygml.settings import Calibration, Estimator, PositionError
from gnss_citygml.simulate import simulate
from gnss_citygml.simulate.files import write_site

__all__ = [
    "PAPER_THRESHOLDS",
    "judge",
    "POSITION_ERRORS",
    "LABELS",
    "POSITIONS",
    "labelled",
    "position_error",
    "markdown_table",
    "run_accuracy",
    "site_tables",
    "summarise",
]

#: The paper's initial thresholds: 20, 21, ..., 40 dB-Hz.
PAPER_THRESHOLDS = tuple(float(t) for t in range(20, 41))

#: Where the rays start: the positions a user has (``reported``), the true ones (``true``), or
#: the true ones moved by the mean error of all recordings (``common``): what remains when
#: every recording's offset relative to the others is known, as perfect self-calibration would
#: know it. Nothing in the signals tells that shared offset apart from the buildings' heights
#: (it moves the rays to one building up and to the one opposite down), so ``common`` measures
#: the information floor of a site's data; ``true`` the floor of the estimator itself.
POSITIONS = ("reported", "common", "true")

#: What the signals say: their C/N0 (``cn0``, as a user has it), or the simulator's truth of
#: whether each had a line of sight (``los``: a perfect signal classifier, the floor of the
#: height fits given the rays).
LABELS = ("cn0", "los")
#: The C/N0 (dB-Hz) that ``los`` gives a signal with a line of sight and a received one
#: without: any initial threshold of 20-40 dB-Hz, and the classifier fitted on them, tells
#: them apart.
LOS_CN0, NLOS_CN0 = 45.0, 15.0

#: What the fits are told of the receivers' position errors: what the observations say (the
#: toolkit's default: a phone's reported accuracy; 1 m for points placed by hand, which say
#: nothing), nothing (``exact``, as in the paper), or the sizes of :data:`POSITION_SD`.
POSITION_ERRORS = ("data", "exact", "fixed")
#: Position error (m per axis) of ``fixed``: hand-placed points "below 2 m" (the paper),
#: smartphone fixes several metres.
POSITION_SD = {"manual": 1.0, "gnss": 5.0}


def position_error(
    kind: str, locations: str, window: float | None = None, distance: float | None = ...
) -> PositionError:
    """The :class:`~gnss_citygml.settings.PositionError` of ``kind`` (one of
    :data:`POSITION_ERRORS`) for positions of ``locations``, its moving receivers' errors
    lasting ``window`` seconds or ``distance`` metres (default: the API's; None: a whole
    recording)."""
    if kind not in POSITION_ERRORS:
        raise ValueError(
            f"position errors must be one of {', '.join(POSITION_ERRORS)}, not {kind!r}"
        )
    sd = {"data": None, "exact": 0.0, "fixed": POSITION_SD[locations]}[kind]
    if distance is ...:
        return PositionError(sd=sd, window=window)
    return PositionError(sd=sd, window=window, distance=distance)


def run_accuracy(
    presets,
    locations=("manual", "gnss"),
    methods=METHODS,
    thresholds=PAPER_THRESHOLDS,
    *,
    seed=0,
    interval=1.0,
    progress=None,
    pipeline_grids=None,
    position_errors="data",
    position_window=None,
    calibration_sd=None,
    calibration_window=None,
    positions="reported",
    **options,
) -> pd.DataFrame:
    """One row per (preset, locations, method, threshold, target building).

    ``options`` are the 4PL methods' :class:`~gnss_citygml.settings.Estimator` settings
    (e.g. ``weighting``).
    ``position_errors`` (one of :data:`POSITION_ERRORS`) is what the 4PL fits are told of the
    position errors (``height_sd`` of :func:`~gnss_citygml.pipeline.intersections`), a moving
    receiver's lasting ``position_window`` seconds. ``calibration_sd`` (a
    mapping alike) turns on the self-calibration of receiver offsets
    (:mod:`gnss_citygml.calibrate`) for 4PL-B with that prior, run for each initial threshold,
    with one offset per recording or, with ``calibration_window`` (s), per window of it; the
    time it takes is part of ``seconds``.
    ``progress`` is an optional callable receiving a short text per finished run. The fit time
    of each run is in ``seconds`` and the number of intersections in ``n_rows``. With
    ``pipeline_grids`` (the OSTN15/OSGM15 grid folder), the intersections are not the
    simulator's own but the pipeline's, from the site written as files (observations,
    footprints in British National Grid, DEM): geodesy and ray casting are judged too.
    ``positions`` (one of :data:`POSITIONS`, with the simulator's own intersections) moves the
    rays' origins to measure the floors of the estimator and of the data.
    """
    _check_positions(positions, pipeline_grids)
    rows = []
    for preset in presets:
        for loc in locations:
            sim = simulate(preset, locations=loc, seed=seed, interval=interval)
            errors = position_error(position_errors, loc, position_window)
            rays, footprints, inter_all = site_tables(sim, pipeline_grids, positions, errors)
            truth = sim.truth.set_index("id")
            targets = truth.index[truth["target"]]
            low, high = (pd.Series(v, truth.index) for v in roof_span(truth))
            for method in methods:
                opts = options if method in ("4PL-B", "4PL") else {}
                if method != "4PL-B":  # the signal model is 4PL-B's
                    opts = {k: v for k, v in opts.items() if k != "signal_model"}
                for threshold in thresholds:
                    start = time.perf_counter()
                    inter = inter_all
                    estimator = Estimator(method=method, init_threshold=threshold, **opts)
                    if calibration_sd is not None and method == "4PL-B":
                        calibration = Calibration(
                            prior_sd=calibration_sd[loc], window=calibration_window
                        )
                        fixed = calibrate_receivers(
                            rays, footprints, calibration, estimator=estimator
                        )
                        inter = _recast(fixed, footprints, errors)
                    out = estimate_heights(inter, estimator, open_sky=open_sky(rays, inter))
                    seconds = time.perf_counter() - start
                    out = out.set_index("id").reindex(targets)
                    for bid, r in out.iterrows():
                        rows.append(
                            {
                                "preset": preset,
                                "locations": loc,
                                "method": method,
                                "threshold": threshold,
                                "building": bid,
                                "height": r["height"],
                                "c": r["c"],
                                "lower": r["height_lower"],
                                "upper": r["height_upper"],
                                "truth": truth.loc[bid, "height"],
                                "roof_low": low[bid],
                                "roof_high": high[bid],
                                "converged": bool(r["converged"])
                                if pd.notna(r["converged"])
                                else False,
                                "status": r["status"],
                                "seconds": seconds,
                                "n_rows": len(inter),
                            }
                        )
                    if progress:
                        progress(f"{preset}/{loc}/{method}/{threshold:g}")
    result = pd.DataFrame(rows)
    result["error"] = result["height"] - result["truth"]
    result["span_error"] = span_distance(result["height"], result["roof_low"], result["roof_high"])
    result["meets"] = (result["lower"] <= result["roof_high"]) & (
        result["roof_low"] <= result["upper"]
    )
    return result


def judge(heights: pd.DataFrame, truth: pd.DataFrame) -> pd.DataFrame:
    """The converged buildings of an :func:`~gnss_citygml.model.estimate.estimate_heights`
    result against a simulator's truth table, by id: ``error`` (to the true height, the
    middle of the roof span), ``paper_error`` (c + 1.5/b's), ``span_error`` (the distance to
    the roof span, 0 inside), ``covered`` (the range holds the true height) and ``meets``
    (the range meets the span)."""
    out = heights.set_index("id")
    out = out[out["converged"].astype(bool)]
    true = truth.set_index("id").reindex(out.index)
    low, high = roof_span(true)
    middle = true["height"]
    lower, upper = out["height_lower"], out["height_upper"]
    return pd.DataFrame(
        {
            "error": out["height"] - middle,
            "paper_error": out["height_paper"] - middle,
            "span_error": span_distance(out["height"], low, high),
            "covered": (lower <= middle) & (middle <= upper),
            "meets": (lower <= high) & (low <= upper),
        }
    )


def site_tables(
    sim, grid_dir=None, positions="reported", position_error: PositionError = PositionError()
):
    """The rays (receivers with ``e``, ``n``, ``z``, ``bearing``), footprints and intersections
    of a simulated site: the simulator's own in its local grid, or, with ``grid_dir``, the
    pipeline's from the site written as files (British National Grid). ``positions`` (one of
    :data:`POSITIONS`) moves the rays' origins; with a ``position_error`` the intersections
    have the ``height_sd`` (and ``recording``) of :func:`~gnss_citygml.pipeline.intersections`."""
    _check_positions(positions, grid_dir)
    if grid_dir is None:
        rays, footprints = sim.rays, sim.buildings
        if positions != "reported":
            rays = _oracle_rays(rays, positions)
        if positions == "reported" and position_error.exact:
            return rays, footprints, sim.intersections
        return rays, footprints, _recast(rays, footprints, position_error)
    with tempfile.TemporaryDirectory() as folder:
        paths = write_site(sim, folder, grid_dir=grid_dir)
        rays = receivers(
            read_observations(paths["observations"]), str(paths["dem"]), grid_dir=grid_dir
        )
        footprints = read_footprints(paths["footprints"])
    return rays, footprints, _recast(rays, footprints, position_error)


def labelled(sim, intersections: pd.DataFrame, labels: str = "cn0") -> pd.DataFrame:
    """The intersections with their signals' ``cn0``, or (``los``) with the simulator's line of
    sight as a C/N0 that no classifier mistakes (:data:`LOS_CN0` for every signal with one,
    received or not; :data:`NLOS_CN0` for a received signal without; one neither received
    nor in sight stays empty)."""
    if labels not in LABELS:
        raise ValueError(f"labels must be one of {', '.join(LABELS)}, not {labels!r}")
    if labels == "cn0":
        return intersections
    los = sim.observations["los"].to_numpy(dtype=bool)[intersections["signal"].to_numpy()]
    received = intersections["cn0"].notna().to_numpy()
    cn0 = np.where(los, LOS_CN0, np.where(received, NLOS_CN0, np.nan))
    return intersections.assign(cn0=cn0)


def _check_positions(positions, grid_dir):
    if positions not in POSITIONS:
        raise ValueError(f"positions must be one of {', '.join(POSITIONS)}, not {positions!r}")
    if positions != "reported" and grid_dir is not None:
        raise ValueError("positions other than 'reported' need the simulator's intersections")


def _oracle_rays(rays: pd.DataFrame, positions: str) -> pd.DataFrame:
    """The simulated rays from their true origins, or from those moved by the mean error of
    all recordings (each recording's mean error, averaged over recordings)."""
    e, n = rays["e_true"].to_numpy(), rays["n_true"].to_numpy()
    if positions == "common":
        error = pd.DataFrame({"e": rays["e"].to_numpy() - e, "n": rays["n"].to_numpy() - n})
        shared = error.groupby(rays["receiver"].to_numpy()).mean().mean()
        e, n = e + shared["e"], n + shared["n"]
    return rays.assign(e=e, n=n)


def _recast(rays, footprints, position_error: PositionError) -> pd.DataFrame:
    """The intersections table of rays cast from (corrected) positions."""
    return intersections(rays, footprints, position_error=position_error)


def summarise(results: pd.DataFrame) -> pd.DataFrame:
    """Per preset, locations and method: the RMSE (m) over converged runs to the true height
    (``rmse``) and to the roof span (``rmse_span``), the share of their ranges meeting the span
    (``meets``) and the converged count."""

    def agg(g):
        ok = g["converged"] & g["error"].notna()

        def rmse(column):
            return float(np.sqrt(np.mean(g.loc[ok, column] ** 2))) if ok.any() else float("nan")

        meets = float(g.loc[ok, "meets"].mean()) if ok.any() else float("nan")
        return pd.Series(
            {
                "rmse": rmse("error"),
                "rmse_span": rmse("span_error"),
                "meets": meets,
                "converged": int(ok.sum()),
                "runs": len(g),
            }
        )

    keys = ["locations", "method", "preset"]
    columns = ["converged", "error", "span_error", "meets"]
    out = results.groupby(keys, sort=False)[columns].apply(agg).reset_index()
    return out.astype({"converged": int, "runs": int})


def markdown_table(summary: pd.DataFrame) -> str:
    """The paper's layout: one row per (locations, method), one column per preset,
    cells ``RMSE m (converged/runs)``."""
    presets = list(dict.fromkeys(summary["preset"]))
    lines = [
        "| locations | method | " + " | ".join(presets) + " |",
        "|---|---|" + "---|" * len(presets),
    ]
    for (loc, method), g in summary.groupby(["locations", "method"], sort=False):
        cells = []
        for p in presets:
            r = g[g["preset"] == p]
            if r.empty:
                cells.append("")
                continue
            r = r.iloc[0]
            rmse = "-" if np.isnan(r["rmse"]) else f"{r['rmse']:.2f} m"
            cells.append(f"{rmse} ({r['converged']}/{r['runs']})")
        lines.append(f"| {loc} | {method} | " + " | ".join(cells) + " |")
    return "\n".join(lines)

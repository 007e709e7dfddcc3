"""Why 4PL-B's fits do not settle (issue 46, item 1): each height fit's reason to stop, and
what raising the caps does to the heights.

Runs 4PL-B (the paper's signal model, or ``--signal-model mixture``) on

- the sample city (``gnss_citygml/data/city``, the one ``gnss-citygml demo`` runs);
- a smaller benchmark city of ``benchmarks/raycast.py`` (its scene builder, cached in
  benchmarks/out/: ``--signals`` signals over ``--blocks`` x ``--blocks`` blocks, by default
  150,000 over 40 x 40, the density of raycast.py's 1 M over 100 x 100);
- ``--scenes`` scenes of each regime of ``--regime`` (benchmarks/scenes.py's street scenes with
  their physics drawn, phone fixes as positions, the errors the observations claim),

with the fits instrumented (``fit_4pl(stops=True)``: the same numbers) and classifies every
building's height fit, in each of 4PL-B's iterations, by why it did or did not meet the
tolerance (:func:`classify`, first that applies):

``converged``
    met the tolerance (gain below ``tol``, or no step left);
``rejected steps``
    at least half of the last 20 steps of the cap rejected (the damping cycling);
``c in a gap``
    ``c`` still moving (more than 1 mm over the cap's second half) inside an empty stretch of
    heights wider than the transition (3/b) around it: between the highest closed and the
    lowest open crossing where the data are separated, else between the crossings next to
    ``c``;
``b at bound``
    ``log b`` on its upper bound or still rising (separated data);
``a/d at bound``
    the logit of ``a`` or of ``d / a`` on its bound or still running to it;
``flat``
    the last gain within 100 x the tolerance, parameters still moving;
``other``
    none of these;
``no data``
    no rows fitted (a building the fits leave out).

Then runs again with the height fit's cap ten times higher (``fit_max_iter`` 2000), and with
both caps at issue 46's higher caps (``max_iter`` 100 too: ten times the paper's 10), and
counts, per class of the default run's final fit and per building's state at the end of the
loop (settled, held in a cycle or swing, still moving, as the loop saw it; whether any of its
fits hit the cap), the heights (of buildings converged in both runs) that
move by more than 1 mm, 1 cm, 1 m, and the statuses that change. For 4PL-B's loop: per
iteration, the share of the fits' rows whose map label (above ``c``) changes, the buildings
whose labels change by 1 % or more (those that keep the loop going), how many of them cycle
(``c`` back within 1 mm of where it was 2 to 6 iterations before, but more than 1 mm from the
last), and the share of label changes that undo the change of the iteration before. Counts
per iteration are summed over the runs still iterating.

    python benchmarks/fit_settling.py [--signals 150000] [--blocks 40] [--scenes 3]
                                      [--regime "narrow street" --regime street]
                                      [--signal-model paper|mixture] [--only city|benchmark|regimes]
"""

from __future__ import annotations

import argparse
import functools
import time
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd
from accuracy import labelled, position_error, site_tables
from raycast import OUT, prepare
from scenes import random_physics, regime_scene
from shared_data import GRIDS

from gnss_citygml.footprints import read_footprints
from gnss_citygml.model import classifier, parts
from gnss_citygml.model.estimate import estimate_heights
from gnss_citygml.model.fit_stops import STOPS_WINDOW
from gnss_citygml.model.fourpl import FourPLFit
from gnss_citygml.observations import read_observations
from gnss_citygml.pipeline import in_mask, intersections, open_sky, receivers
from gnss_citygml.settings import Estimator, Rays
from gnss_citygml.simulate import simulate
from gnss_citygml.terrain import building_ground

CLASSES = ("converged", "rejected steps", "c in a gap", "b at bound", "a/d at bound", "flat")
CLASSES += ("other", "no data")
#: How far (m) a height may move before it counts as moved.
MOVES = (1e-3, 1e-2, 1.0)
#: Higher caps: issue 46's, ten times the paper's (the default ``max_iter`` is 30 since).
HIGH = {"fit_max_iter": 2000, "max_iter": 100}
#: A parameter moving by more than this over the cap's second half (c 1 mm, the others in
#: their logs or logits) is still moving.
STILL = np.full(4, 1e-3)


@dataclass
class Record:
    """What the instrumented run saw: per 4PL-B iteration, each building's class and ``c``,
    its fit's gap width, and each fitted row's map label; the classifier fits' caps."""

    classes: list[np.ndarray] = field(default_factory=list)
    gaps: list[np.ndarray] = field(default_factory=list)
    c: list[np.ndarray] = field(default_factory=list)
    labels: list[np.ndarray] = field(default_factory=list)
    change: list[np.ndarray] = field(default_factory=list)
    #: Each building's roof line settled, and held (4PL-B's own record, model/settling.py).
    settled: list[np.ndarray] = field(default_factory=list)
    held: list[np.ndarray] = field(default_factory=list)
    #: The C/N0 threshold (dB-Hz) of the classifier that labelled each iteration's rows
    #: (NaN for the mixture).
    threshold: list[float] = field(default_factory=list)
    #: The signal classifier's fits (paper's model): how many, and how many hit the cap.
    classifier_fits: list[int] = field(default_factory=lambda: [0, 0])


def gaps(x, y, g, c, n):
    """Per group: the width of the empty stretch of heights around ``c`` (the separated
    data's, from the highest closed to the lowest open crossing, where there is one)."""
    closed_top = np.full(n, -np.inf)
    open_low = np.full(n, np.inf)
    np.maximum.at(closed_top, g[y < 0.5], x[y < 0.5])
    np.minimum.at(open_low, g[y >= 0.5], x[y >= 0.5])
    below = np.full(n, -np.inf)
    above = np.full(n, np.inf)
    np.maximum.at(below, g[x <= c[g]], x[x <= c[g]])
    np.minimum.at(above, g[x > c[g]], x[x > c[g]])
    separated = closed_top < open_low
    return np.where(separated, open_low - closed_top, above - below)


def classify(fit: FourPLFit, gap: np.ndarray, tol: float = 1e-9) -> np.ndarray:
    """Each group's class of :data:`CLASSES` (see the module's docstring)."""
    s = fit.stops
    theta_moving = np.abs(s.drift) > STILL
    out = np.full(fit.c.size, "other", dtype=object)
    logit = np.column_stack([np.log(fit.a / (1 - fit.a)), np.log(fit.d / (fit.a - fit.d))])
    outward = (np.sign(s.drift[:, [0, 3]]) == np.sign(logit)) & theta_moving[:, [0, 3]]
    rules = [
        ("flat", (np.abs(s.gain) <= 100 * tol) & theta_moving.any(axis=1)),
        ("a/d at bound", (s.at_lower | s.at_upper)[:, [0, 3]].any(axis=1) | outward.any(axis=1)),
        ("b at bound", s.at_upper[:, 1] | (s.drift[:, 1] > STILL[1])),
        ("c in a gap", theta_moving[:, 2] & (gap > 3.0 / fit.b)),
        ("rejected steps", s.rejected_late >= STOPS_WINDOW // 2),
    ]
    for name, where in rules:  # the last that applies wins: the order of CLASSES
        out[where] = name
    out[fit.converged] = "converged"
    out[~np.isfinite(fit.c)] = "no data"
    return out


def instrumented(record: Record):
    """``Part.fitted`` that records each iteration's classes (its fits asked for their
    stops: the same numbers)."""
    original = parts.Part.fitted

    @functools.wraps(original)
    def fitted(self, model):
        inner = parts.fit_4pl
        seen_data = {}

        def fit_4pl(x, y, w, g, n, **kwargs):
            fit = inner(x, y, w, g, n, stops=True, **kwargs)
            seen_data["gap"] = gaps(x, y, g, fit.c, n)
            return fit

        parts.fit_4pl = fit_4pl
        try:
            part = original(self, model)
        finally:
            parts.fit_4pl = inner
        fit, own = part.last.fit, part._own
        record.classes.append(classify(fit, seen_data["gap"]))
        record.gaps.append(seen_data["gap"])
        record.c.append(fit.c.copy())
        record.labels.append(part.h[own] > fit.c[part.g[own]])
        record.change.append(part.last.change.copy())
        record.settled.append(part.last.settling.settled.copy())
        record.held.append(part.last.settling.held.copy())
        record.threshold.append(getattr(model, "threshold", np.nan))
        return part

    return fitted


def run(inter, sky, estimator):
    """4PL-B on ``inter`` (open sky ``sky``), instrumented: its heights table and record."""
    record = Record()
    original, inner = parts.Part.fitted, classifier.fit_4pl

    def counted(*args, **kwargs):
        fit = inner(*args, **kwargs)
        record.classifier_fits[0] += 1
        record.classifier_fits[1] += int(not fit.converged[0])
        return fit

    parts.Part.fitted, classifier.fit_4pl = instrumented(record), counted
    try:
        heights = estimate_heights(inter, estimator, open_sky=sky)
    finally:
        parts.Part.fitted, classifier.fit_4pl = original, inner
    return heights, record


def sample_city():
    """The sample city's intersections and open sky (cast as ``gnss-citygml demo`` does)."""
    city = Path(__file__).resolve().parents[1] / "gnss_citygml" / "data" / "city"
    obs = in_mask(read_observations(city / "observations.parquet"), Rays())
    return [_cast(obs, city)]


def benchmark_city(signals: int, blocks: int):
    """A benchmark city of raycast.py's builder (cached in benchmarks/out/), cast as
    raycast.py casts it."""
    folder = OUT / f"city_{blocks}x{blocks}_{signals}"
    if not (folder / "dem.tif").exists():
        prepare(folder, signals, blocks, GRIDS, "manual")
    return [_cast(read_observations(folder / "observations.parquet"), folder)]


def _cast(obs, folder: Path):
    """The intersections and open sky of observations ``obs`` in a site ``folder``."""
    dem = str(folder / "dem.tif")
    rx = receivers(obs, dem, grid_dir=GRIDS)
    inter = intersections(rx, building_ground(read_footprints(folder / "footprints.gpkg"), dem))
    return inter, open_sky(rx, inter)


def regime_scenes(regime: str, n: int):
    """Scenes 0 to ``n - 1`` of ``regime`` as benchmarks/scenes.py --regimes makes them
    (their physics drawn), with phone fixes as positions and the errors they claim."""
    out = []
    for k in range(n):
        scene, start, _ = regime_scene(k, regime)
        sim = simulate(scene, locations="gnss", seed=k, start=start, physics=random_physics(k))
        rays, _, cast = site_tables(sim, position_error=position_error("data", "gnss"))
        out.append((labelled(sim, cast, "cn0"), open_sky(rays, cast)))
    return out


def measure(runs, signal_model: str):
    """Each run's heights and records with the default caps (``0``), the height fit's cap
    ten times higher (``f``) and both (``1``): a list of dicts."""
    caps = {"0": {}, "f": {"fit_max_iter": HIGH["fit_max_iter"]}, "1": HIGH}
    out = []
    for inter, sky in runs:
        result: dict = {"seconds": {}}
        for key, changed in caps.items():
            start = time.perf_counter()
            estimator = Estimator(signal_model=signal_model, **changed)
            result[f"h{key}"], result[f"r{key}"] = run(inter, sky, estimator)
            result["seconds"][key] = time.perf_counter() - start
        out.append(result)
    return out


def moves(h0: pd.DataFrame, h1: pd.DataFrame) -> dict[str, np.ndarray]:
    """Per building of ``h0``: whether its height (converged in both) moved by more than each
    of :data:`MOVES` in ``h1``, and whether its status changed."""
    h1 = h1.set_index("id").reindex(h0["id"])
    both = h0["converged"].to_numpy() & h1["converged"].to_numpy(dtype=bool)
    moved = np.abs(h1["height"].to_numpy() - h0["height"].to_numpy())
    out = {f"> {m * 100:g} cm": both & (moved > m) for m in MOVES}
    out["status"] = h0["status"].to_numpy() != h1["status"].to_numpy()
    out["largest"] = np.where(both, moved, 0.0)
    return out


def class_table(results) -> str:
    """Per class of the final fits (default caps): buildings, the gaps around their c, and
    how their heights and statuses move with the height fit's cap ten times higher, and with
    both caps (then also: how many are still not converged)."""
    rows = []
    for r in results:
        fit_only, both = moves(r["h0"], r["hf"]), moves(r["h0"], r["h1"])
        rows.append(
            pd.DataFrame(
                {
                    "class": r["r0"].classes[-1],
                    "gap": r["r0"].gaps[-1],
                    "f1mm": fit_only["> 0.1 cm"],
                    "f1cm": fit_only["> 1 cm"],
                    "fstatus": fit_only["status"],
                    "still": ~np.isin(r["r1"].classes[-1], ["converged", "no data"]),
                    **both,
                }
            )
        )
    every = pd.concat(rows)
    columns = ["f1mm", "f1cm", "fstatus", "still", "> 0.1 cm", "> 1 cm", "> 100 cm", "status"]
    lines = [
        "| final fit's class | buildings | gap around c (m): median, max | fit cap x10: "
        "height moves > 1 mm | > 1 cm | status changes | both caps x10: fit not converged | "
        "height moves > 1 mm | > 1 cm | > 1 m | status changes |",
        "|---|---:|---|" + "---:|" * len(columns),
    ]
    for name in [*CLASSES, "all"]:
        part = every if name == "all" else every[every["class"] == name]
        if part.empty:
            continue
        gap = part["gap"][np.isfinite(part["gap"])]
        gaps_text = f"{gap.median():.2f}, {gap.max():.2f}" if gap.size else "-"
        counts = " | ".join(str(int(part[c].sum())) for c in columns)
        lines.append(f"| {name} | {len(part)} | {gaps_text} | {counts} |")
    return "\n".join(lines)


#: Periods of the cycles of 4PL-B's loop looked for: c back within 1 mm of where it was this
#: many iterations before.
PERIODS = range(2, 7)


def outer_state(record: Record) -> np.ndarray:
    """Each building's state at the end of 4PL-B's loop, as the loop saw it
    (:mod:`gnss_citygml.model.settling`): ``held`` (its roof line came back to an earlier
    one, or swung, and was held there), ``settled`` (it moved by at most 1 mm in the last
    iteration), else ``moving``; ``fit capped`` is added where any of its fits hit the cap."""
    c = np.array(record.c)
    state = np.where(record.settled[-1], "settled", "moving").astype(object)
    state[record.held[-1]] = "held"
    state[~np.isfinite(c[-1])] = "no data"
    capped = np.any([_capped(k) for k in record.classes], axis=0)
    return np.where(capped, state + ", fit capped", state)


def state_table(results) -> str:
    """Per building's state at the end of the default run's loop (:func:`outer_state`): how
    its height and status move with the fit's cap ten times higher, and with both caps."""
    rows = []
    for r in results:
        fit_only, both = moves(r["h0"], r["hf"]), moves(r["h0"], r["h1"])
        state = outer_state(r["r0"])
        rows.append(
            pd.DataFrame(
                {"state": state, "f1mm": fit_only["> 0.1 cm"], "fstatus": fit_only["status"]}
            ).assign(**both)
        )
    every = pd.concat(rows)
    columns = ["f1mm", "fstatus", "> 0.1 cm", "> 1 cm", "> 100 cm", "status"]
    lines = [
        "| state at the end of the loop | buildings | fit cap x10: height moves > 1 mm | "
        "status changes | both caps x10: height moves > 1 mm | > 1 cm | > 1 m | status changes "
        "| largest move (m) |",
        "|---|---:|" + "---:|" * (len(columns) + 1),
    ]
    for name, part in [*every.groupby("state", sort=True), ("all", every)]:
        counts = " | ".join(str(int(part[c].sum())) for c in columns)
        lines.append(f"| {name} | {len(part)} | {counts} | {part['largest'].max():.3f} |")
    return "\n".join(lines)


def loop_table(records, every: int = 1) -> str:
    """Per 4PL-B iteration (summed over the runs' ``records``): the fits' classes, the share
    of fitted rows whose map label changed, the buildings whose labels changed by 1 % or more
    and those of them in a cycle (:data:`PERIODS`), the share of changed labels that undo the
    change before, and the roof lines the loop holds and those still moving
    (:mod:`gnss_citygml.model.settling`)."""
    short = [c for c in CLASSES if c != "no data"]
    lines = [
        "| iteration | " + " | ".join(short) + " | rows changing label | buildings changing >= "
        "1 % | of them in a cycle (period 2-6) | changes undoing the last | roof lines held | "
        "roof lines moving | signal model's threshold (dB-Hz) |",
        "|---:" * (len(short) + 8) + "|",
    ]
    n_iter = max(len(r.classes) for r in records)
    for k in range(n_iter):
        if k not in (0, 1, 2, n_iter - 1) and (k + 1) % every:
            continue
        counts, flips, rows, busy, cycles, undo = Counter(), 0, 0, 0, 0, 0
        held = moving_c = 0
        for r in records:
            if k >= len(r.classes):
                continue
            counts.update(r.classes[k])
            held += int(r.held[k].sum())
            moving_c += int((~r.settled[k] & np.isfinite(r.c[k])).sum())
            rows += r.labels[k].size
            busy_k = r.change[k] >= 0.01
            busy += int(busy_k.sum()) if k else 0
            if k >= 1:
                flipped = r.labels[k] != r.labels[k - 1]
                flips += int(flipped.sum())
            if k >= 2:
                undo += int((flipped & (r.labels[k] == r.labels[k - 2])).sum())
                moving = np.abs(r.c[k] - r.c[k - 1]) > 1e-3
                back = np.any(
                    [np.abs(r.c[k] - r.c[k - p]) <= 1e-3 for p in PERIODS if k >= p], axis=0
                )
                cycles += int((busy_k & moving & back).sum())
        cells = " | ".join(str(counts.get(c, 0)) for c in short)
        lines.append(
            f"| {k + 1} | {cells} | {flips / max(rows, 1):.2%} | {busy if k else '-'} | "
            f"{cycles if k >= 2 else '-'} | {undo / max(flips, 1):.0%} | {held} | {moving_c} | "
            f"{_threshold(records, k)} |"
        )
    return "\n".join(lines)


def spread_table(results) -> str:
    """Per 4PL-B iteration (summed over the runs): the buildings whose ``c`` differs by more
    than 1 mm between the default run and the run with the height fit's cap ten times higher,
    how many of them had a fit that hit the cap (in either run, up to then), and the largest
    difference of the signal model's threshold: how a few capped fits spread to the others
    through what the buildings share (the signal model, the visibility model)."""
    lines = [
        "| iteration | buildings whose c differs > 1 mm | of them with a capped fit so far | "
        "threshold difference (dB-Hz) |",
        "|---:|---:|---:|---:|",
    ]
    for k in range(max(min(len(r["r0"].c), len(r["rf"].c)) for r in results)):
        differ = capped = 0
        threshold = 0.0
        for r in results:
            r0, rf = r["r0"], r["rf"]
            if k >= min(len(r0.c), len(rf.c)):
                continue
            apart = np.abs(r0.c[k] - rf.c[k]) > 1e-3
            ever = np.any(
                [_capped(rec.classes[j]) for rec in (r0, rf) for j in range(k + 1)], axis=0
            )
            differ += int(apart.sum())
            capped += int((apart & ever).sum())
            if np.isfinite(r0.threshold[k]):
                threshold = max(threshold, abs(r0.threshold[k] - rf.threshold[k]))
        lines.append(f"| {k + 1} | {differ} | {capped} | {threshold:.4f} |")
    return "\n".join(lines)


def _capped(classes: np.ndarray) -> np.ndarray:
    """Fits that did not meet the tolerance (of those with data)."""
    return (classes != "converged") & (classes != "no data")


def _threshold(records, k: int) -> str:
    """The classifier's threshold of iteration ``k`` of a single run ('-' for several runs
    or the mixture)."""
    if len(records) > 1 or not np.isfinite(records[0].threshold[k]):
        return "-"
    return f"{records[0].threshold[k]:.2f}"


def report(name: str, results) -> None:
    """Print one site's tables."""
    n = sum(len(r["h0"]) for r in results)
    iterations = [(len(r["r0"].classes), len(r["r1"].classes)) for r in results]
    seconds = [sum(r["seconds"][k] for r in results) for k in ("0", "1")]
    signal_fits = np.sum([r[k].classifier_fits for r in results for k in ("r0", "r1")], axis=0)
    print(f"\n### {name}\n")
    print(
        f"{n} buildings in {len(results)} run(s); 4PL-B iterations (default caps; x10 caps): "
        f"{', '.join(f'{a}; {b}' for a, b in iterations)}; fit {seconds[0]:.0f} s, "
        f"with x10 caps {seconds[1]:.0f} s; the signal classifier's fits (both runs) that "
        f"hit their cap: {signal_fits[1]} of {signal_fits[0]}.\n"
    )
    print(class_table(results))
    print("\nBy each building's state at the end of 4PL-B's loop (default caps):\n")
    print(state_table(results))
    print("\nHow the fits that hit the cap spread (default vs the fit's cap x10):\n")
    print(spread_table(results))
    print("\nEach 4PL-B iteration's fits, default caps:\n")
    print(loop_table([r["r0"] for r in results]))
    print("\nEach 4PL-B iteration's fits, x10 caps:\n")
    print(loop_table([r["r1"] for r in results], every=10))


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--signals", type=int, default=150_000)
    parser.add_argument("--blocks", type=int, default=40)
    parser.add_argument("--scenes", type=int, default=3, help="scenes per regime")
    parser.add_argument("--regime", action="append", help="default: narrow street, street")
    parser.add_argument("--signal-model", default="paper", help="paper or mixture")
    parser.add_argument("--only", choices=("city", "benchmark", "regimes"), action="append")
    args = parser.parse_args()
    only = args.only or ["city", "benchmark", "regimes"]
    sites = []
    if "city" in only:
        sites.append(("The sample city (gnss_citygml/data/city)", sample_city))
    if "benchmark" in only:
        sites.append(
            (
                f"Benchmark city, {args.signals:,} signals x {args.blocks} x {args.blocks} blocks",
                functools.partial(benchmark_city, args.signals, args.blocks),
            )
        )
    if "regimes" in only:
        for regime in args.regime or ["narrow street", "street"]:
            sites.append(
                (
                    f"Regime '{regime}', scenes 0-{args.scenes - 1}, phone fixes",
                    functools.partial(regime_scenes, regime, args.scenes),
                )
            )
    print(f"signal model: {args.signal_model}")
    for name, make in sites:
        report(name, measure(make(), args.signal_model))


if __name__ == "__main__":
    main()

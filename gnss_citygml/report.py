"""The report of a run: what the estimator did, as figures a GNSS or GIS person reads at a glance.

:func:`write_report` writes one self-contained HTML page (``report.html``, the images embedded)
and the same figures as PNGs (``figures/``) into a folder:

- a map of the buildings coloured by height above the ground, those without a height hatched
  by their status, with the receivers' positions and tracks;
- the range widths (the uncertainty): a map and a histogram;
- per building, the height 4PL over the binned share of open signals, with the estimate and
  its range marked, as the paper's figures: the worst, the best and a sample, not every one;
- a skyplot per receiver (the busiest ones): signals open, closed (received, but by the
  signal classifier not on a clear line of sight) and blocked (not received);
- the C/N0 of the received signals by their final label (open where the ray clears every
  fitted roof line) with the fitted signal classifier;
- a table of every building (with the truth, for simulated data), and the counts by status.

matplotlib is an extra (``pip install 'gnss-citygml[plot]'``); without it the report is a
one-line error saying so. The figures' data (:func:`signal_states`, :func:`fit_sample`,
:func:`binned_open`) are plain tables, tested without matplotlib.
"""

from __future__ import annotations

import base64
import html
import io
import json
from collections.abc import Callable, Iterable
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import pandas as pd

from .errors import InputError, user_text
from .files.ids import id_named
from .files.paths import StrPath, atomic_path, check_output_folder, make_folder
from .files.provenance import summary
from .model.fourpl import logistic4
from .model.mixture import Cn0Mixture, elevation_units
from .stages import entered

if TYPE_CHECKING:
    from .pipeline import Run

__all__ = [
    "REPORT",
    "binned_open",
    "blocked_by_others",
    "check_report",
    "fit_sample",
    "signal_states",
    "write_report",
]

#: The page's name in the report folder.
REPORT = "report.html"

#: Per-building fit plots: this many of the worst, of the best and of a sample.
FITS_EACH = 4

#: Skyplots: the receivers with the most signals, at most this many.
SKYPLOTS = 12

#: Width (m) of the intersection-height bins of the fit plots.
HEIGHT_BIN = 1.0

#: The fit plots show intersection heights this far (m) either side of the roof line ``c``:
#: rays that pass high over a building say little about where its roof is.
FIT_WINDOW = 25.0

#: Colours of the signal states (open, closed, blocked) and of the two final labels.
STATE_COLOURS = {"open": "#21918c", "closed": "#fde725", "blocked": "#440154"}

#: matplotlib settings of the figures: every text drawn literally. Ids and receiver names
#: (log file names) are the user's: ``$...$`` would be parsed as math text (and a bad one
#: stop the report), ``\`` ``_`` ``^`` as TeX with usetex.
_LITERAL = {"text.parse_math": False, "text.usetex": False, "axes.formatter.use_mathtext": False}

#: Hatches of the buildings without a height, one per status.
HATCHES = ["////", "\\\\\\\\", "xxxx", "....", "oo", "++", "--", "||"]


def signal_states(run: Run) -> pd.DataFrame:
    """Every signal of the run (a row of ``run.receivers``) with ``state``: ``open`` (received
    and labelled open by the final signal classifier), ``closed`` (received, labelled closed)
    or ``blocked`` (not received); and ``map_open``: whether its ray clears every roof line the
    fits placed (``c`` of each building with a fit), the label the classifier was taught."""
    rx = run.receivers
    cn0 = rx["cn0"].to_numpy(float)
    received = ~np.isnan(cn0)
    if run.classifier is not None:
        open_ = run.classifier.label(cn0, elevation_units(rx["elevation"].to_numpy(float)))
    else:
        open_ = received
    state = np.where(~received, "blocked", np.where(open_, "open", "closed"))
    inter = _intersections(run)
    below = _below_roofs(inter, id_named(run.heights).set_index("id")["c"])
    hidden = np.zeros(len(rx), dtype=bool)
    hidden[inter["signal"].to_numpy()[below]] = True
    return pd.DataFrame(
        {
            "receiver": rx["receiver"].astype(str).to_numpy(),
            "azimuth": rx["azimuth"].to_numpy(float),
            "elevation": rx["elevation"].to_numpy(float),
            "cn0": cn0,
            "state": state,
            "map_open": ~hidden,
        }
    )


def blocked_by_others(intersections: pd.DataFrame, roofs: pd.Series) -> np.ndarray:
    """For each intersection, whether its ray passes below the fitted roof line (``roofs``:
    ``c`` by building id) of another building it crosses: such a signal says little about
    this building (its fit weighs a closed one by the chance that this building alone blocked
    it, :mod:`.model.blame`), so the fit plots leave it out."""
    below = _below_roofs(intersections, roofs)
    signal = intersections["signal"].to_numpy()
    n_below = np.bincount(signal, weights=below.astype(float), minlength=signal.max(initial=-1) + 1)
    return (n_below[signal] - below) > 0


def _below_roofs(intersections: pd.DataFrame, roofs: pd.Series) -> np.ndarray:
    """For each intersection, whether its ray passes below its building's fitted roof line
    (``roofs``: ``c`` by building id; a building without a fit has none to pass below)."""
    roof = roofs.reindex(intersections["building"].astype(str)).to_numpy(float)
    return intersections["height"].to_numpy(float) <= roof  # (NaN roof: False)


def fit_sample(heights: pd.DataFrame, each: int = FITS_EACH, seed: int = 0) -> pd.DataFrame:
    """The buildings whose fit the report draws, with ``why``: the ``each`` worst (converged
    with the widest ranges, or, with an ``error`` column, the largest errors), the ``each``
    best (the narrowest ranges or smallest errors) and ``each`` drawn at random (``seed``) from
    the rest of those with a fit, not-converged ones included."""
    table = id_named(heights)
    table = table[np.isfinite(table["c"].to_numpy(float))]
    if "error" in table:
        score = table["error"].abs()
    else:
        score = table["height_upper"] - table["height_lower"]
    ranked = table.assign(score=score.to_numpy()).dropna(subset=["score"])
    ranked = ranked[ranked["converged"].astype(bool)].sort_values("score", kind="stable")
    worst = ranked.tail(each).iloc[::-1]
    best = ranked.head(each)
    best = best[~best["id"].isin(worst["id"])]
    rest = table[~table["id"].isin(pd.concat([worst["id"], best["id"]]))]
    sample = rest.sample(min(each, len(rest)), random_state=seed) if len(rest) else rest
    parts = [(worst, "worst"), (best, "best"), (sample, "sample")]
    return pd.concat([part.assign(why=why) for part, why in parts], ignore_index=True)


def binned_open(heights: np.ndarray, open_: np.ndarray, width: float = HEIGHT_BIN) -> pd.DataFrame:
    """The share of open signals in bins of intersection height (``width`` m): ``height``
    (the bin's middle), ``share`` and ``n``.

    >>> binned_open(np.array([0.2, 0.7, 1.5]), np.array([True, False, True]))
       height  share  n
    0     0.5    0.5  2
    1     1.5    1.0  1
    """
    if heights.size == 0:
        return pd.DataFrame({"height": [], "share": [], "n": []})
    key = np.floor(heights / width).astype(np.int64)
    keys, inverse, n = np.unique(key, return_inverse=True, return_counts=True)
    k = np.bincount(inverse, weights=open_.astype(float))
    return pd.DataFrame({"height": (keys + 0.5) * width, "share": k / n, "n": n})


def check_report(folder: StrPath, *, overwrite: bool, inputs: Iterable[object] = ()) -> None:
    """Check, before the work starts, that a report can be written to ``folder`` (its files
    are new, or ``overwrite``, and none of the run's ``inputs``) and that matplotlib is there
    to draw it."""
    folder = Path(folder)
    check_output_folder(
        folder, [folder / REPORT], overwrite=overwrite, what="report folder", inputs=inputs
    )
    pngs = [folder / "figures" / f"{name}.png" for name, _, _ in _FIGURES]
    check_output_folder(
        folder / "figures", pngs, overwrite=overwrite, what="figures folder", inputs=inputs
    )
    _pyplot()


def check_report_request(
    report: StrPath | None, truth: StrPath | None, *, overwrite: bool, inputs: Iterable[object]
) -> pd.DataFrame | None:
    """A job's report request, checked before the work starts: a truth table only with a
    report folder, the folder writable (:func:`check_report`). Returns the truth table, read
    and checked (None without one)."""
    if truth is not None and report is None:
        raise InputError(
            "a truth table is for the report, and no report was asked for",
            where=str(truth),
            fix="give a report folder too (--report DIR), or leave the truth out",
        )
    if report is None:
        return None
    check_report(report, overwrite=overwrite, inputs=inputs)
    if truth is None:
        return None
    from .compare import check_truth
    from .files.tables import read_table

    return check_truth(read_table(truth), str(truth))


def write_report(
    run: Run,
    folder: StrPath,
    *,
    truth: pd.DataFrame | None = None,
    title: str = "gnss-citygml report",
    overwrite: bool = True,
    provenance: dict | None = None,
    progress: Callable[[str], None] | None = None,
) -> Path:
    """Write the report of ``run`` (:func:`gnss_citygml.pipeline.run`) into ``folder``:
    ``report.html`` and ``figures/*.png``, each file written atomically; returns the page.

    ``truth`` (a simulator's truth table: ``id``, ``height``, ``ground``) adds the true
    heights and the errors to the table, and the worst and best fits are then those with the
    largest and smallest errors. ``provenance`` (:func:`gnss_citygml.files.provenance.provenance`)
    heads the page, as a line and as JSON in ``<script type="application/json"
    id="provenance">``. ``progress`` is told the name of each figure as it starts.
    Without ``overwrite``, existing report files are an error (:func:`check_report`)."""
    check_report(folder, overwrite=overwrite)
    plt = _pyplot()
    say = progress or (lambda what: None)
    table = _table(run, truth)
    states = signal_states(run)
    sections = []
    with plt.rc_context(_LITERAL):
        for name, heading, draw in _FIGURES:  # every figure drawn before any file is written
            say(name)
            sections.append((heading, name, _png(plt, draw(plt, run, table, states))))
    say("page")
    page = _page(title, run, table, sections, provenance)
    folder = make_folder(folder)
    figures = make_folder(Path(folder) / "figures")
    for _, name, png in sections:
        with atomic_path(figures / f"{name}.png", overwrite=overwrite) as tmp:
            tmp.write_bytes(png)
    with atomic_path(Path(folder) / REPORT, overwrite=overwrite) as tmp:
        tmp.write_text(page, encoding="utf-8")
    return Path(folder) / REPORT


def _pyplot() -> Any:
    """matplotlib's pyplot on a file-only backend, or the one-line error naming the extra."""
    try:
        import matplotlib
    except ImportError:
        raise InputError(
            "the report needs matplotlib, which is not installed",
            fix="pip install 'gnss-citygml[plot]' (or matplotlib)",
        ) from None
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _table(run: Run, truth: pd.DataFrame | None) -> pd.DataFrame:
    """Every building: id, heights above the ground, range, n_signals, converged, status (and
    with a truth table its true height, roof span, error, distance to the span and whether
    the range holds the height and meets the span)."""
    heights = id_named(run.heights)
    ground = heights["ground"].to_numpy(float)
    table = pd.DataFrame(
        {
            "id": heights["id"].astype(str),
            "height": heights["relative_height"],
            "lower": heights["height_lower"] - ground,
            "upper": heights["height_upper"] - ground,
            "n_signals": heights["n_signals"],
            "converged": heights["converged"].astype(bool),
            "status": heights["status"].astype(str),
            "c": heights["c"],
        }
    )
    if truth is not None:
        from .compare import compare

        compared = compare(run.heights, truth)
        for column in (
            "truth", "roof_low", "roof_high", "error", "span_error", "inside", "meets"
        ):  # fmt: skip
            table[column] = compared[column].to_numpy()
    return table


def _png(plt: Any, figure: Any) -> bytes:
    buffer = io.BytesIO()
    figure.savefig(buffer, format="png", dpi=110, bbox_inches="tight")
    plt.close(figure)
    return buffer.getvalue()


def _map(plt: Any, run: Run, table: pd.DataFrame, states: pd.DataFrame) -> Any:
    """Buildings by height above the ground; the rest hatched by status; receivers' tracks."""
    from matplotlib.patches import Patch

    figure, ax = plt.subplots(figsize=(9, 7.5))
    buildings = run.heights.assign(_status=table["status"].to_numpy())
    converged = table["converged"].to_numpy()
    if converged.any():
        _coloured(
            ax, buildings[converged], "relative_height", "viridis", "height above the ground (m)"
        )
    handles = []
    groups = buildings[~converged].groupby("_status")
    for k, (status, group) in enumerate(groups):
        hatch = HATCHES[k % len(HATCHES)]
        group.plot(ax=ax, facecolor="#e0e0e0", edgecolor="#707070", hatch=hatch, linewidth=0.3)
        label = f"{status} ({len(group)})"
        handles.append(Patch(facecolor="#e0e0e0", edgecolor="#707070", hatch=hatch, label=label))
    _tracks(ax, run.receivers)
    if handles:
        ax.legend(handles=handles, title="no height", loc="upper center", fontsize=7,
                  bbox_to_anchor=(0.5, -0.16))  # fmt: skip
    ax.set_title(f"{int(converged.sum())} of {len(table)} buildings with a height")
    _axes_bng(ax)
    return figure


def _coloured(ax: Any, buildings: pd.DataFrame, column: str, cmap: str, label: str) -> None:
    """Footprints filled by ``column`` on ``cmap``, with a colour bar saying ``label``."""
    buildings.plot(
        column=column,
        cmap=cmap,
        ax=ax,
        edgecolor="#303030",
        linewidth=0.3,
        legend=True,
        legend_kwds={"label": label, "shrink": 0.65},
    )


def _tracks(ax: Any, receivers: pd.DataFrame) -> None:
    """Each receiver's positions in time order, as a thin line with a dot where it starts."""
    from matplotlib.collections import LineCollection

    positions = receivers[["receiver", "time_utc", "e", "n"]].drop_duplicates(
        ["receiver", "time_utc"]
    )
    positions = positions.sort_values(["receiver", "time_utc"], kind="stable")
    lines = [group[["e", "n"]].to_numpy() for _, group in positions.groupby("receiver", sort=False)]
    ax.add_collection(LineCollection(lines, colors="#c0392b", linewidths=0.8, alpha=0.8))
    starts = np.array([line[0] for line in lines])
    ax.scatter(starts[:, 0], starts[:, 1], s=8, color="#c0392b", zorder=3, label="receivers")


def _axes_bng(ax: Any) -> None:
    ax.set_xlabel("easting (m, EPSG:27700)")
    ax.set_ylabel("northing (m)")
    ax.set_aspect("equal")
    ax.ticklabel_format(useOffset=False, style="plain")
    ax.tick_params(axis="x", labelrotation=30)


def _ranges(plt: Any, run: Run, table: pd.DataFrame, states: pd.DataFrame) -> Any:
    """The width of each converged building's range: a map and a histogram."""
    figure, (left, right) = plt.subplots(1, 2, figsize=(12, 5), width_ratios=[1.3, 1])
    width = (table["upper"] - table["lower"]).to_numpy()
    converged = table["converged"].to_numpy() & np.isfinite(width)  # (baselines: no range)
    if converged.any():
        buildings = run.heights.assign(_width=width)
        _coloured(left, buildings[converged], "_width", "magma_r", "range width (m)")
        right.hist(
            width[converged], bins=min(30, max(5, int(converged.sum()) // 3)), color="#31688e"
        )
        right.yaxis.get_major_locator().set_params(integer=True)
    run.heights[~converged].plot(ax=left, facecolor="none", edgecolor="#b0b0b0", linewidth=0.3)
    _axes_bng(left)
    left.set_title("range width (the uncertainty)")
    right.set_xlabel("range width (m)")
    right.set_ylabel("buildings")
    median = np.nanmedian(width[converged]) if converged.any() else float("nan")
    right.set_title(f"median {median:.2f} m over {int(converged.sum())} buildings")
    return figure


def _fits(plt: Any, run: Run, table: pd.DataFrame, states: pd.DataFrame) -> Any:
    """The height 4PL of the worst, best and sampled buildings over their binned data (the
    ``FIT_WINDOW`` m either side of the roof line), the estimate a line, the range shaded."""
    chosen = fit_sample(table.assign(height_lower=table["lower"], height_upper=table["upper"]))
    heights = id_named(run.heights).set_index("id")
    inter = _intersections(run)
    codes = inter["building"].astype(str).to_numpy()
    open_ = states["state"].to_numpy()[inter["signal"].to_numpy()] == "open"
    shown = ~blocked_by_others(inter, heights["c"])
    n = max(len(chosen), 1)
    cols = min(4, n)
    rows = -(-n // cols)
    figure, axes = plt.subplots(rows, cols, figsize=(3.6 * cols, 3 * rows), squeeze=False)
    for ax in axes.flat[len(chosen) :]:
        ax.set_visible(False)
    for ax, row in zip(axes.flat, chosen.itertuples(index=False), strict=False):
        fit = heights.loc[str(row.id)]
        mine = (codes == row.id) & shown
        height = inter["height"].to_numpy(float)[mine]
        a, b, c, d = heights.loc[str(row.id), ["a", "b", "c", "d"]].to_numpy(float)
        low, high = c - FIT_WINDOW, c + FIT_WINDOW  # the roof line, not the sky
        keep = (height >= low) & (height <= high)
        bins = binned_open(height[keep], open_[mine][keep])
        ax.scatter(bins["height"], bins["share"], s=6 + 40 * bins["n"] / bins["n"].max(),
                   color="#31688e", alpha=0.7)  # fmt: skip
        x = np.linspace(low, high, 200)
        ax.plot(x, logistic4(x, a, b, c, d), color="#c0392b")
        if bool(fit["converged"]):
            ax.axvspan(fit["height_lower"], fit["height_upper"], color="#fde725", alpha=0.35)
            ax.axvline(fit["height"], color="#303030", linewidth=1)
        ax.set_ylim(-0.05, 1.05)
        ax.set_title(f"{row.why}: {user_text(row.id, 40)}\nn = {fit['n_signals']}, "
                     f"{fit['status']}", fontsize=8)  # fmt: skip
        ax.set_xlabel("intersection height (m ODN)", fontsize=8)
        ax.set_ylabel("share open", fontsize=8)
        ax.tick_params(labelsize=7)
    figure.tight_layout()
    return figure


def _skyplots(plt: Any, run: Run, table: pd.DataFrame, states: pd.DataFrame) -> Any:
    """Azimuth/elevation of every signal of the busiest receivers, by state."""
    busiest = states["receiver"].value_counts().index[:SKYPLOTS]
    cols = min(4, max(len(busiest), 1))
    rows = -(-max(len(busiest), 1) // cols)
    figure, axes = plt.subplots(
        rows, cols, figsize=(3.3 * cols, 3.4 * rows), subplot_kw={"projection": "polar"},
        squeeze=False,
    )  # fmt: skip
    for ax in axes.flat[len(busiest) :]:
        ax.set_visible(False)
    for ax, receiver in zip(axes.flat, busiest, strict=False):
        mine = states[states["receiver"] == receiver]
        for state, colour in STATE_COLOURS.items():
            part = mine[mine["state"] == state]
            ax.scatter(np.radians(part["azimuth"]), 90 - part["elevation"], s=2, color=colour,
                       label=state)  # fmt: skip
        ax.set_theta_zero_location("N")
        ax.set_theta_direction(-1)
        ax.set_ylim(0, 90)
        ax.set_yticks([30, 60])
        ax.set_yticklabels(["60°", "30°"], fontsize=6)
        ax.tick_params(labelsize=6)
        ax.set_title(f"{user_text(receiver, 30)} ({len(mine)})", fontsize=8)
    axes.flat[0].legend(loc="lower left", bbox_to_anchor=(-0.25, -0.2), fontsize=7, markerscale=3)
    figure.tight_layout()
    return figure


def _cn0(plt: Any, run: Run, table: pd.DataFrame, states: pd.DataFrame) -> Any:
    """C/N0 of the received signals by final label, with the signal classifier's Pr(open)."""
    figure, ax = plt.subplots(figsize=(8, 4.5))
    received = states[np.isfinite(states["cn0"])]
    cn0 = received["cn0"].to_numpy()
    bins = np.arange(
        np.floor(cn0.min()) if cn0.size else 0, (np.ceil(cn0.max()) if cn0.size else 50) + 1
    )
    for label, mask, colour in (
        ("ray clears every roof (open)", received["map_open"].to_numpy(), STATE_COLOURS["open"]),
        ("ray below a roof (closed)", ~received["map_open"].to_numpy(), STATE_COLOURS["blocked"]),
    ):
        ax.hist(cn0[mask], bins=bins, alpha=0.6, color=colour, label=f"{label}: {int(mask.sum())}")
    ax.set_xlabel("C/N0 (dB-Hz)")
    ax.set_ylabel("received signals")
    if run.classifier is not None:
        twin = ax.twinx()
        x = np.linspace(bins[0], bins[-1], 200)
        twin.plot(x, run.classifier.prob(x), color="#c0392b", label="Pr(open | C/N0)")
        twin.axvline(run.classifier.threshold, color="#c0392b", linestyle="--", linewidth=0.8)
        twin.set_ylim(0, 1)
        twin.set_ylabel("signal classifier: Pr(open)")
        where = " at 45° elevation" if isinstance(run.classifier, Cn0Mixture) else ""
        ax.set_title(
            f"final signal classifier: 50 % at {run.classifier.threshold:.1f} dB-Hz{where}"
        )
        twin.legend(loc="upper right", fontsize=8)
    ax.legend(loc="upper left", fontsize=8)
    return figure


#: The figures, in the page's order: file name, heading, drawing function.
_FIGURES: list[tuple[str, str, Callable[..., Any]]] = [
    ("map", "Buildings and receivers", _map),
    ("ranges", "Uncertainty: the range of each height", _ranges),
    ("fits", "Height fits: the worst, the best and a sample", _fits),
    ("skyplots", "Skyplots of the busiest receivers", _skyplots),
    ("cn0", "C/N0 by final label, and the signal classifier", _cn0),
]


def _made(provenance: dict | None) -> list[str]:
    """The page's lines on where it came from: the summary, the settings, the record."""
    if provenance is None:
        return []
    record = json.dumps(provenance).replace("</", "<\\/")  # (never closes the script)
    settings = json.dumps(provenance.get("settings", {}), indent=1)
    return [
        f'<p class="made">{html.escape(summary(provenance))}</p>',
        f"<details><summary>Settings</summary><pre>{html.escape(settings)}</pre></details>",
        f'<script type="application/json" id="provenance">{record}</script>',
    ]


def _page(title: str, run: Run, table: pd.DataFrame, sections: list, provenance) -> str:
    """The HTML page: a summary, the figures (embedded), the counts by status and the table."""
    converged = int(table["converged"].sum())
    lines = [
        f"{len(table)} buildings, {converged} with a height; {len(run.receivers)} signals from "
        f"{run.receivers['receiver'].nunique()} receivers, {len(_intersections(run))} "
        "intersections."
    ]
    if "error" in table:
        from .compare import summary

        lines.append(summary(table))
    parts = [
        "<!doctype html>",
        '<html lang="en"><head><meta charset="utf-8">',
        f"<title>{html.escape(title)}</title>",
        f"<style>{_STYLE}</style></head><body>",
        f"<h1>{html.escape(title)}</h1>",
        *_made(provenance),
        *(f"<p>{html.escape(line)}</p>" for line in lines),
    ]
    for heading, name, png in sections:
        data = base64.b64encode(png).decode("ascii")
        parts.append(
            f'<h2>{html.escape(heading)}</h2><img alt="{name}" src="data:image/png;base64,{data}">'
        )
    counts = table.groupby("status").size().rename("buildings").reset_index()
    parts.append("<h2>Buildings by status</h2>")
    parts.append(counts.to_html(index=False, border=0))
    parts.append("<h2>Every building</h2><p>Heights above the ground (m).</p>")
    shown = table.drop(columns="c")
    parts.append(
        shown.to_html(index=False, border=0, float_format=lambda v: f"{v:.2f}", na_rep="-")
    )
    parts.append("</body></html>")
    return "\n".join(parts)


_STYLE = (
    "body{font-family:sans-serif;max-width:1100px;margin:2em auto;color:#222}"
    "img{max-width:100%;border:1px solid #ddd}"
    "table{border-collapse:collapse;font-size:13px}"
    "td,th{padding:2px 8px;border-bottom:1px solid #eee;text-align:right}"
    "h2{margin-top:2em}"
)


def _intersections(run: Run) -> pd.DataFrame:
    """The run's intersections, which a run in tiles never gathers: those where a ray enters
    a footprint (not a footprint it passes near, ``order`` -1)."""
    if run.intersections is None:
        raise InputError(
            "the report needs every intersection of the run on one machine, and a run on a "
            "Dask scheduler does not gather them",
            fix="run without --scheduler for the report",
        )
    return entered(run.intersections)

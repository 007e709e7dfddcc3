"""The accuracy runs behind the paper's table and its floors (rays from true positions):
``benchmarks/accuracy.py``, research code outside the installed package."""

import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
from accuracy import (  # noqa: E402
    LOS_CN0,
    NLOS_CN0,
    judge,
    labelled,
    markdown_table,
    run_accuracy,
    site_tables,
    summarise,
)

from gnss_citygml import Estimator, estimate_heights  # noqa: E402
from gnss_citygml.simulate import simulate  # noqa: E402


@pytest.fixture(scope="module")
def runs():
    return {
        positions: run_accuracy(
            ["goodchild"],
            ["manual"],
            ["4PL-B"],
            [30.0],
            interval=30.0,
            positions=positions,
            position_errors="exact",  # the floors: rays from true (or commonly offset) positions
        )
        for positions in ("reported", "common", "true")
    }


def test_one_row_per_run_and_target(runs):
    res = runs["reported"]
    assert list(res["building"]) == ["goodchild_block"]
    row = res.iloc[0]
    assert row["error"] == pytest.approx(row["height"] - row["truth"])
    assert row["lower"] < row["height"] < row["upper"]


def test_true_positions_find_the_roof_with_the_inflection_point(runs):
    # From the true positions only diffraction blurs the roof line, symmetrically: c finds it.
    row = runs["true"].iloc[0]
    assert row["converged"], row["status"]
    assert row["c"] == row["height"] == pytest.approx(row["truth"], abs=1.0)


def test_common_offset_moves_the_rays(runs):
    heights = {k: runs[k].iloc[0]["lower"] for k in runs}
    assert len({round(h, 6) for h in heights.values()}) == 3


def test_summary_table_cells(runs):
    summary = summarise(runs["true"])
    assert summary.loc[0, "converged"] == 1 and summary.loc[0, "runs"] == 1
    rmse = abs(runs["true"].iloc[0]["error"])
    assert summary.loc[0, "rmse"] == pytest.approx(rmse)
    assert f"{rmse:.2f} m (1/1)" in markdown_table(summary)


def test_unknown_positions_are_refused():
    with pytest.raises(ValueError, match="positions must be one of"):
        run_accuracy(["goodchild"], positions="guessed")
    with pytest.raises(ValueError, match="simulator's intersections"):
        run_accuracy(["goodchild"], positions="true", pipeline_grids="grids")


def test_line_of_sight_labels_replace_the_c_n0():
    sim = simulate("goodchild", interval=60.0)
    inter = site_tables(sim)[2]
    assert labelled(sim, inter) is inter
    oracle = labelled(sim, inter, "los")
    los = sim.observations["los"].to_numpy()[inter["signal"].to_numpy()]
    received = inter["cn0"].notna().to_numpy()
    assert (oracle["cn0"][los] == LOS_CN0).all()
    assert (oracle["cn0"][~los & received] == NLOS_CN0).all()
    assert oracle["cn0"][~los & ~received].isna().all()
    assert 0 < los.sum() < los.size  # the canyon blocks some signals, not all
    with pytest.raises(ValueError, match="labels must be one of"):
        labelled(sim, inter, "snr")


def test_runs_are_judged_by_the_roof_span_too(runs):
    """Issue 27: each run's distance to the roof span (0 inside) and whether its range meets
    it, beside the error to the true height; the summary has both RMSEs."""
    res = runs["reported"]
    row = res.iloc[0]
    assert row["roof_low"] == row["roof_high"] == row["truth"]  # a flat block: one height
    assert row["span_error"] == pytest.approx(abs(row["error"]))
    assert row["meets"] == (row["lower"] <= row["truth"] <= row["upper"])
    spanned = res.assign(roof_low=row["truth"] - 2.0, roof_high=row["truth"] + 2.0)
    spanned["span_error"] = np.maximum(abs(row["error"]) - 2.0, 0.0)
    summary = summarise(spanned)
    assert summary.loc[0, "rmse"] == pytest.approx(abs(row["error"]))
    assert summary.loc[0, "rmse_span"] == pytest.approx(max(abs(row["error"]) - 2.0, 0.0))


def test_judge_uses_the_span_of_a_pitched_roof():
    """A run on the pitched terrace: the span is its eaves and ridge (33-35 m ODN)."""
    res = run_accuracy(
        ["hermitage"], ["manual"], ["4PL-B"], [30.0], interval=60.0, position_errors="exact"
    )
    row = res.iloc[0]
    assert (row["roof_low"], row["roof_high"]) == (33.0, 35.0)
    outside = max(33.0 - row["height"], row["height"] - 35.0, 0.0)
    assert row["span_error"] == pytest.approx(outside)
    assert row["meets"] == (row["lower"] <= 35.0 and 33.0 <= row["upper"])


def test_judge_reads_an_estimate_against_the_truth():
    sim = simulate("hermitage", interval=60.0)
    heights = estimate_heights(sim.intersections, Estimator(init_threshold=30.0))
    judged = judge(heights, sim.truth)
    ok = heights.set_index("id")["converged"].astype(bool)
    assert list(judged.index) == list(ok.index[ok])
    truth = sim.truth.set_index("id").loc[judged.index]
    h = heights.set_index("id").loc[judged.index]
    np.testing.assert_allclose(judged["error"], h["height"] - truth["height"])
    off = np.maximum(truth["roof_low"] - h["height"], 0) + np.maximum(
        h["height"] - truth["roof_high"], 0
    )
    np.testing.assert_allclose(judged["span_error"], off)
    assert (judged["meets"] >= judged["covered"]).all()  # the span holds the height

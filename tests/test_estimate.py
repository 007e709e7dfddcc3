import numpy as np
import pandas as pd
import pytest
from conftest import occluded_pair, synthetic_intersections

from gnss_citygml import (
    HEIGHTS_COLUMNS,
    Acceptance,
    Estimator,
    InputError,
    MissingColumnError,
    ModelError,
    estimate_heights,
    heights_and_signal_model,
)
from gnss_citygml.model.estimate import _tracks
from gnss_citygml.model.fourplb import height_weights, look_ids


@pytest.mark.parametrize("method", ["4PL-B", "4PL", "hinge", "bayes"])
def test_every_method_returns_the_heights_table(rng, method):
    table = pd.concat(
        [
            synthetic_intersections(rng, 45.0, building="a"),
            synthetic_intersections(rng, 30.0, building="b"),
        ]
    )
    out = estimate_heights(table, Estimator(method=method))
    assert list(out.columns) == HEIGHTS_COLUMNS
    assert list(out["id"]) == ["a", "b"]
    assert (out["method"] == method).all()
    assert out["converged"].all()
    np.testing.assert_allclose(out["height"], [45.0, 30.0], atol=3.0)


@pytest.mark.parametrize("threshold", [20.0, 30.0, 40.0])
def test_4plb_is_robust_to_the_initial_threshold(rng, threshold):
    table = synthetic_intersections(rng, 45.0, n=6000)
    out, classifier = heights_and_signal_model(table, Estimator(init_threshold=threshold))
    row = out.iloc[0]
    assert row["converged"], row["status"]
    assert row["height_lower"] <= row["height"] <= row["height_upper"]
    assert row["height"] == pytest.approx(45.0, abs=1.5)
    assert 1 <= row["iterations"] <= 10
    assert 20 < classifier.c < 40


def test_the_height_rules(rng):
    table = synthetic_intersections(rng)
    row = estimate_heights(table).iloc[0]
    # by default the inflection point c, in the transition 3/b wide centred on it, widened by
    # where else the data would put c
    assert row["height"] == row["c"]
    half = 1.5 / row["b"]
    assert row["height_lower"] <= row["c"] - half and row["c"] + half <= row["height_upper"]
    assert row["height_upper"] - row["height_lower"] < 3.0 / row["b"] + 1.0
    # the paper's rule c + 1.5/b, with the paper's range (c, c + 3/b) widened alike; the
    # paper's height is in the table whichever rule gave the height
    paper = estimate_heights(table, Estimator(height_rule="paper")).iloc[0]
    assert paper["height"] == pytest.approx(paper["c"] + 1.5 / paper["b"])
    assert paper["height"] == row["height_paper"] == paper["height_paper"]
    assert paper[["c", "b"]].tolist() == row[["c", "b"]].tolist()
    assert paper["height_lower"] == pytest.approx(row["height_lower"] + half)
    assert paper["height_upper"] == pytest.approx(row["height_upper"] + half)
    with pytest.raises(ModelError, match="unknown height rule 'top'"):
        Estimator(height_rule="top")
    with pytest.raises(ModelError, match="height_rule not used by method hinge"):
        Estimator(method="hinge", height_rule="paper")
    assert np.isnan(estimate_heights(table, Estimator(method="hinge"))["height_paper"]).all()


@pytest.mark.parametrize(
    "case, reason",
    [
        ("all_open", "every signal is labelled open"),
        ("all_closed", "no signal is labelled open"),
        ("few", "fewer than 10 signals"),
        ("blocked", "no signal is labelled open"),
    ],
)
def test_degenerate_buildings_are_reported_not_guessed(rng, case, reason):
    good = synthetic_intersections(rng, 45.0, building="good")
    n = 5 if case == "few" else 200
    h = rng.uniform(20, 60, n)
    cn0 = {
        "all_open": np.full(n, 45.0),
        "all_closed": np.full(n, 15.0),
        "few": np.full(n, 45.0),
        "blocked": np.full(n, np.nan),
    }[case]
    bad = pd.DataFrame({"building": "bad", "height": h, "cn0": cn0})
    for method in ("4PL-B", "4PL"):
        out = estimate_heights(pd.concat([good, bad]), Estimator(method=method)).set_index("id")
        assert out.loc["good", "converged"]
        assert not out.loc["bad", "converged"]
        assert np.isnan(out.loc["bad", "height"])
        assert out.loc["bad", "status"] == reason


def test_signal_ids_share_labels_across_buildings(rng):
    a = synthetic_intersections(rng, 45.0, building="a")
    a["signal"] = np.arange(len(a))
    out = estimate_heights(a)
    assert out["converged"].all()


def test_mapping_input_and_mismatched_lengths():
    with pytest.raises(InputError, match="different lengths"):
        estimate_heights({"building": ["a", "a"], "height": [1.0], "cn0": [30.0, 31.0]})


def test_missing_columns_are_named():
    with pytest.raises(MissingColumnError, match="'cn0'"):
        estimate_heights(pd.DataFrame({"building": ["a"], "height": [1.0]}))


def test_nan_heights_are_refused_with_rows():
    table = pd.DataFrame({"building": ["a"] * 3, "height": [1.0, np.nan, 2.0], "cn0": 30.0})
    with pytest.raises(InputError, match="rows 1"):
        estimate_heights(table)
    many = pd.DataFrame({"building": "a", "height": [np.nan] * 8 + [1.0], "cn0": 30.0})
    with pytest.raises(InputError, match=r"rows 0, 1, 2, 3, 4 and 3 more\)"):
        estimate_heights(many)


def test_non_numeric_values_are_refused():
    table = pd.DataFrame({"building": ["a"] * 2, "height": [1.0, "high"], "cn0": 30.0})
    with pytest.raises(InputError, match="not numbers"):
        estimate_heights(table)


def test_unknown_method_and_option():
    with pytest.raises(ModelError, match="unknown method"):
        Estimator(method="lidar")
    with pytest.raises(ModelError, match="weighting not used by method hinge"):
        Estimator(method="hinge", weighting="height")
    with pytest.raises(ModelError, match="acceptance not used by method bayes"):
        Estimator(method="bayes", acceptance=Acceptance(max_uncertainty=5.0))
    with pytest.raises(ModelError, match="unknown weighting"):
        Estimator(weighting="magic")
    with pytest.raises(ModelError, match="unknown blame 'front'.*ray, drop"):
        Estimator(blame="front")
    with pytest.raises(ModelError, match="blame not used by method hinge"):
        Estimator(method="hinge", blame="ray")
    # without the visibility model there is nothing to share a ray among: refused, not ignored
    with pytest.raises(ModelError, match="visibility model, which is off.*keep visibility on"):
        Estimator(visibility=False, blame="ray")
    # a baseline's own settings are its initial threshold and min_signals
    table = pd.DataFrame({"building": ["a"] * 3, "height": [1.0, 2.0, 3.0], "cn0": [30.0] * 3})
    few = Estimator(method="hinge", acceptance=Acceptance(min_signals=3))
    assert estimate_heights(table, few)["n_signals"].iloc[0] == 3


def test_error_messages_say_what_where_and_how():
    err = MissingColumnError(["cn0"], where="intersections.csv", have=["building"])
    expected = "missing column(s) 'cn0' (intersections.csv): add the column(s)"
    assert str(err) == expected + " (the table has: building)"


def test_visibility_model_ignores_signals_blocked_by_a_nearer_building(rng):
    table = occluded_pair(rng)
    seen = estimate_heights(table).set_index("id")
    assert seen.loc["A", "converged"] and seen.loc["B", "converged"]
    assert seen.loc["A", "height"] == pytest.approx(30.0, abs=1.5)
    assert seen.loc["B", "height"] == pytest.approx(20.0, abs=1.5)
    blind = estimate_heights(table, Estimator(visibility=False)).set_index("id")
    # Without it, signals blocked by A count as closed above B's roof: the upper asymptote
    # (the open fraction of signals clearing B) sinks.
    assert seen.loc["B", "a"] > 0.9 > blind.loc["B", "a"]
    assert seen.loc["B", "n_signals"] < (table["building"] == "B").sum()


@pytest.mark.parametrize("dtype", ["int32", "Int64", "float64"])
def test_the_order_along_the_ray_is_read_whatever_its_number_type(rng, dtype):
    """A user's table may hold the order as numpy's or pandas' nullable integers (from
    Parquet) or as floats: the same heights."""
    table = occluded_pair(rng)
    expected = estimate_heights(table)
    table["order"] = table["order"].astype(dtype)
    assert estimate_heights(table).equals(expected)


def test_a_building_seen_only_behind_another_is_not_guessed(rng):
    table = occluded_pair(rng, alone=0.0)
    out = estimate_heights(table).set_index("id")
    assert out.loc["A", "converged"]
    assert not out.loc["B", "converged"]
    assert np.isnan(out.loc["B", "height"])
    assert "roof line" in out.loc["B", "status"]


def test_a_blurred_roof_line_is_reported_as_too_uncertain(rng):
    table = synthetic_intersections(rng, 45.0, n=6000, noise=12.0)
    out = estimate_heights(table).iloc[0]
    assert not out["converged"]
    assert out["status"] == "height range wider than 10 m"
    loose = estimate_heights(table, Estimator(acceptance=Acceptance(max_uncertainty=100.0)))
    loose = loose.iloc[0]
    assert loose["converged"]
    assert loose["height_upper"] - loose["height_lower"] > 10.0


def test_the_one_shot_4pl_always_answers_when_its_fit_converges(rng):
    table = synthetic_intersections(rng, 45.0, n=6000, noise=12.0)
    out = estimate_heights(table, Estimator(method="4PL")).iloc[0]
    assert out["converged"] and np.isfinite(out["height"])


def _blurred_by_positions(rng, truth=45.0, n=8000, recordings=4):
    """Signals whose heights err by a known sd each (a receiver position error), the roof
    line itself sharp; each recording's rows share part of the error."""
    h_true = rng.uniform(20.0, 80.0, n)
    is_open = h_true > truth
    cn0 = np.where(is_open, rng.normal(40.0, 4.0, n), rng.normal(25.0, 5.0, n))
    cn0[cn0 < 12.0] = np.nan
    sd = rng.uniform(0.0, 3.0, n)
    receiver = rng.integers(0, recordings, n)
    height = h_true + sd * rng.normal(0.0, 1.0, n)
    return pd.DataFrame(
        {"building": "b1", "height": height, "cn0": cn0, "receiver": receiver, "height_sd": sd}
    )


def test_position_errors_are_modelled_and_widen_the_range(rng):
    table = _blurred_by_positions(rng)
    plain = estimate_heights(table.drop(columns="height_sd")).iloc[0]
    row = estimate_heights(table).iloc[0]
    assert row["converged"], row["status"]
    assert row["b"] > 1.5 * plain["b"]  # the roof line's own sharpness, not the blur's
    assert row["height"] == row["c"] == pytest.approx(45.0, abs=0.5)
    margin = row["c"] - 1.5 / row["b"] - row["height_lower"]
    assert margin > 0.1
    assert row["height_upper"] == pytest.approx(row["c"] + 1.5 / row["b"] + margin)


def test_recordings_share_position_errors(rng):
    # four recordings leave half the margin of one (their errors average); a `recording`
    # column overrides `receiver`
    table = _blurred_by_positions(rng)
    four = estimate_heights(table).iloc[0]
    one = estimate_heights(table.assign(recording=0)).iloc[0]
    margin_four = four["c"] - 1.5 / four["b"] - four["height_lower"]
    margin_one = one["c"] - 1.5 / one["b"] - one["height_lower"]
    assert margin_one == pytest.approx(2.0 * margin_four, rel=0.1)


def test_position_margin_counts_each_recording_once():
    from gnss_citygml.model.fourpl import FourPLFit
    from gnss_citygml.model.fourplb import position_margin

    one = np.ones(1)
    nan = np.full(1, np.nan)
    fit = FourPLFit(0.9 * one, one, 10.0 * one, 0.1 * one, one, one > 0, one, one < 0, nan, nan)
    n = 400
    g, h, sd = np.zeros(n, dtype=np.intp), np.full(n, 10.5), np.full(n, 2.0)
    far = np.r_[h[:-10], np.full(10, 30.0)]  # rows far from the roof line do not count
    assert position_margin(fit, g, far, sd, None, 1)[0] == pytest.approx(4.0)
    four = np.arange(n) % 4
    assert position_margin(fit, g, h, sd, four, 1)[0] == pytest.approx(2.0)


def test_bad_height_sd_is_refused(rng):
    table = _blurred_by_positions(rng, n=200)
    table.loc[[3, 7], "height_sd"] = [-1.0, np.nan]
    with pytest.raises(InputError, match=r"height_sd must be.*rows 3, 7"):
        estimate_heights(table)


def test_looks_count_a_tracks_repeated_epochs_once_per_metre():
    # one satellite seen for 300 epochs from one place, and 30 others seen once each
    table = pd.DataFrame(
        {
            "building": "b",
            "height": np.r_[np.full(300, 36.2), np.linspace(20.0, 49.0, 30)],
            "receiver": "r",
            "satellite": ["G01"] * 300 + [f"E{k:02d}" for k in range(30)],
        }
    )
    looks = look_ids(table["height"], np.zeros(330, int), _tracks(table))
    weights = height_weights(table["height"], np.zeros(330, int), 1, "looks", looks=looks)
    assert weights[:300] == pytest.approx(1 / 300) and weights[300:] == pytest.approx(1.0)
    assert weights.sum() == pytest.approx(31.0)  # the building was looked at 31 times
    # without satellites, a recording's rows within one metre are one look
    alone = height_weights(table["height"], np.zeros(330, int), 1, "looks")
    assert alone.sum() == pytest.approx(30.0)  # 36.2 falls in the metre of one of the others


def test_the_range_holds_where_the_data_leave_the_roof_line(rng):
    # signals only at 20-30 m (closed) and 50-60 m (open): the roof is somewhere between
    h = np.r_[rng.uniform(20.0, 30.0, 3000), rng.uniform(50.0, 60.0, 3000)]
    table = pd.DataFrame({"building": "b", "height": h, "cn0": np.where(h > 40.0, 42.0, np.nan)})
    wide = estimate_heights(table).iloc[0]
    assert not wide["converged"]
    gap = "the roof line is anywhere in a gap between the rays"
    assert wide["status"] == f"height range wider than 10 m: {gap}"
    lax = Estimator(acceptance=Acceptance(max_uncertainty=30.0))
    row = estimate_heights(table, lax).iloc[0]
    assert row["converged"]
    assert row["height_lower"] <= h[h < 40].max() and row["height_upper"] >= h[h > 40].min()
    # the data fit any roof line in the gap alike: the height is its middle, whatever the caps
    assert row["height"] == pytest.approx(0.5 * (h[h < 40].max() + h[h > 40].min()))
    high = Estimator(acceptance=Acceptance(max_uncertainty=30.0), max_iter=100, fit_max_iter=2000)
    assert estimate_heights(table, high).iloc[0]["height"] == row["height"]


def test_the_datas_and_the_positions_uncertainties_add_in_quadrature():
    from gnss_citygml.model.fourpl import FourPLFit
    from gnss_citygml.model.fourplb import _judge

    one = np.ones(1)
    fit = FourPLFit(
        a=0.9 * one, b=one, c=30.0 * one, d=0.05 * one, loglik=-one,
        converged=one.astype(bool), n_iter=one, separable=~one.astype(bool),
        gap_lower=np.nan * one, gap_upper=np.nan * one,
    )  # fmt: skip
    h = np.r_[np.linspace(20.0, 29.0, 20), np.linspace(31.0, 40.0, 20)]
    labels = h > 30.0
    g = np.zeros(h.size, dtype=np.intp)
    interval = (30.0 - 3.0) * one, (30.0 + 1.0) * one  # the data's: 3 m below c, 1 m above
    judged = _judge(
        fit, g, h, labels, np.ones(h.size, bool), 1, np.zeros(1), np.ones(1, bool), 3,
        Acceptance(max_uncertainty=20.0), margin=4.0 * one, c_range=interval,
    )  # fmt: skip
    assert judged.converged[0] and judged.height[0] == 30.0
    # 1.5/b of transition on each side, then the two uncertainties of c: hypot(3, 4) = 5
    assert judged.height_lower[0] == pytest.approx(30.0 - 1.5 - 5.0)
    assert judged.height_upper[0] == pytest.approx(30.0 + 1.5 + np.hypot(1.0, 4.0))


def test_a_range_too_wide_from_the_positions_says_so(rng):
    """One recording whose shared position error moves each height by 6 m: the data place the
    roof line well, the receiver's position does not."""
    table = synthetic_intersections(rng, 45.0, n=6000, noise=0.5).assign(
        height_sd=6.0, receiver="phone"
    )
    out = estimate_heights(table).iloc[0]
    assert not out["converged"]
    assert (
        out["status"] == "height range wider than 10 m: the receivers' positions are too uncertain"
    )
    # without the shared error the same rows give a height
    assert estimate_heights(table.drop(columns="height_sd")).iloc[0]["converged"]


def test_the_height_fits_iteration_cap_is_the_estimators(rng):
    """``fit_max_iter`` is the cap of every height fit's Levenberg-Marquardt iterations: the
    default is the cap the fits always had (the same bits), and a cap too small to reach the
    tolerance changes the fits (the setting is used, not only checked)."""
    table = pd.concat(
        [
            synthetic_intersections(rng, 45.0, building="a"),
            synthetic_intersections(rng, 30.0, n=600, building="b", noise=3.0),
        ]
    )
    default = estimate_heights(table)
    pd.testing.assert_frame_equal(estimate_heights(table, Estimator(fit_max_iter=200)), default)
    for cap in (1, 3):
        cut = estimate_heights(table, Estimator(fit_max_iter=cap))
        assert not np.array_equal(cut[["a", "b", "c", "d"]], default[["a", "b", "c", "d"]])
    one_shot = Estimator(method="4PL", fit_max_iter=2)
    assert not np.array_equal(
        estimate_heights(table, one_shot)["c"],
        estimate_heights(table, Estimator(method="4PL"))["c"],
    )

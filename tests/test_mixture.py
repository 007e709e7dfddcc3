"""The mixture signal model (gnss_citygml.model.mixture) and 4PL-B with it."""

import numpy as np
import pandas as pd
import pytest

from gnss_citygml.errors import InputError, ModelError
from gnss_citygml.model.classifier import SignalClassifier
from gnss_citygml.model.estimate import estimate_heights, heights_and_signal_model
from gnss_citygml.model.mixture import Cn0Mixture, Cn0Moments, elevation_units
from gnss_citygml.settings import Estimator

#: The classes of the synthetic signals: C/N0 = alpha + beta e + N(0, sigma), received with q.
OPEN = {"alpha": 36.0, "beta": 9.0, "sigma": 3.0, "q": 0.98}
CLOSED = {"alpha": 25.0, "beta": 7.0, "sigma": 4.0, "q": 0.7}


def draw(rng, is_open, elevation):
    """C/N0 of signals of each class at ``elevation`` (deg); NaN where not received."""
    e = elevation / 90.0
    out = np.full(is_open.size, np.nan)
    for mask, k in ((is_open, OPEN), (~is_open, CLOSED)):
        got = mask & (rng.random(is_open.size) < k["q"])
        out[got] = k["alpha"] + k["beta"] * e[got] + rng.normal(0, k["sigma"], got.sum())
    return out


def test_the_fit_recovers_both_classes():
    rng = np.random.default_rng(1)
    n = 40_000
    is_open = rng.random(n) < 0.5
    elevation = rng.uniform(10, 80, n)
    cn0 = draw(rng, is_open, elevation)
    model = Cn0Mixture.fitted(Cn0Moments.of(cn0, elevation_units(elevation), is_open))
    for k, truth in enumerate((OPEN, CLOSED)):
        assert model.alpha[k] == pytest.approx(truth["alpha"], abs=0.3)
        assert model.beta[k] == pytest.approx(truth["beta"], abs=0.6)
        assert model.sigma[k] == pytest.approx(truth["sigma"], abs=0.15)
        assert model.q[k] == pytest.approx(truth["q"], abs=0.02)
    # at 45 degrees the classes' likelihoods cross between their means
    assert CLOSED["alpha"] + 3.5 < model.threshold < OPEN["alpha"] + 4.5


def test_moments_add_and_subtract():
    rng = np.random.default_rng(2)
    cn0 = np.where(rng.random(100) < 0.2, np.nan, rng.normal(35, 5, 100))
    e, r = rng.random(100), rng.random(100)
    whole = Cn0Moments.of(cn0, e, r)
    first, second = Cn0Moments.of(cn0[:30], e[:30], r[:30]), Cn0Moments.of(cn0[30:], e[30:], r[30:])
    np.testing.assert_allclose((first + second).sums, whole.sums)
    np.testing.assert_allclose((whole - first).sums, second.sums)
    np.testing.assert_allclose((whole - whole).sums, Cn0Moments.empty().sums)


def test_a_closed_class_above_the_open_one_is_put_below_it():
    """Weights that make the closed class the stronger (nothing separates them) cannot let
    it take the open signals' place: a reflection does not gain power."""
    rng = np.random.default_rng(3)
    cn0 = rng.normal(35, 3, 2_000)
    backwards = (cn0 > 35).astype(float)  # "closed" signals are the strong ones
    model = Cn0Mixture.fitted(Cn0Moments.of(cn0, 0.5, 1.0 - backwards))
    for e in (0.0, 1.0):
        assert model.alpha[1] + model.beta[1] * e <= model.alpha[0] + model.beta[0] * e


def test_the_posterior_weighs_prior_and_signal():
    model = Cn0Mixture((40.0, 28.0), (0.0, 0.0), (3.0, 4.0), (0.99, 0.6))
    strong, weak, lost = 41.0, 27.0, np.nan
    post = model.posterior(np.array([strong, weak, lost]), 0.0, 0.5)
    assert post[0] > 0.99 and post[1] < 0.01 and post[2] < 0.05
    # a signal the map is sure of needs strong evidence to be turned
    assert model.posterior(np.array([34.0]), 0.0, 0.999)[0] > 0.9
    assert model.posterior(np.array([34.0]), 0.0, 0.001)[0] < 0.1
    # its 50 % point with an even prior lies between the classes
    assert 28.0 < model.threshold < 40.0
    assert model.label(np.array([model.threshold + 0.5, model.threshold - 0.5])).tolist() == [
        True,
        False,
    ]


def test_a_closed_ray_is_blamed_on_the_building_likely_to_block_it():
    """One weak signal crossing two buildings: the one whose roof it surely clears keeps the
    label open; the other takes the blame. A signal of one building is closed for it."""
    model = Cn0Mixture((40.0, 28.0), (0.0, 0.0), (3.0, 4.0), (0.99, 0.6))
    cn0 = np.array([27.0, 27.0, 27.0])
    prior = np.array([0.999, 0.3, 0.3])
    signal = np.array([0, 0, 1])
    labels = model.row_labels(cn0, np.zeros(3), prior, signal)
    assert labels[0] > 0.99  # surely cleared: the other building blocks
    assert labels[1] < 0.05
    assert labels[2] < 0.05
    strong = model.row_labels(np.array([41.0, 41.0]), np.zeros(2), np.array([0.5, 0.5]), signal[:2])
    assert (strong > 0.99).all()  # an open ray clears both


def street(seed, n_buildings=6, reflected=0.8, loss=10.0, below=15.0, above=15.0):
    """Buildings seen from a narrow street: most signals below a roof arrive reflected,
    ``loss`` dB weaker than a clear one at the same elevation; the rays that cross no
    footprint are open. The intersections table and the open sky."""
    rng = np.random.default_rng(seed)
    roofs = rng.uniform(15, 45, n_buildings)
    rows = []
    for k, roof in enumerate(roofs):
        n = 3_000
        height = rng.uniform(roof - below, roof + above, n)
        elevation = np.clip(np.degrees(np.arctan2(height - 1.5, rng.uniform(4, 10, n))), 5, 85)
        is_open = height > roof
        e = elevation / 90.0
        cn0 = OPEN["alpha"] + OPEN["beta"] * e + rng.normal(0, OPEN["sigma"], n)
        got = is_open | (rng.random(n) < reflected)
        cn0 = np.where(is_open, cn0, cn0 - loss + rng.normal(0, 2, n))
        cn0[~got] = np.nan
        rows.append(pd.DataFrame({"building": f"b{k}", "height": height, "cn0": cn0,
                                  "elevation": elevation}))  # fmt: skip
    table = pd.concat(rows, ignore_index=True)
    table["signal"] = np.arange(len(table))
    sky_elevation = rng.uniform(50, 88, 2_000)
    sky = pd.DataFrame(
        {
            "cn0": OPEN["alpha"] + OPEN["beta"] * sky_elevation / 90 + rng.normal(0, 3, 2_000),
            "elevation": sky_elevation,
        }
    )
    return table, sky, pd.Series(roofs, index=[f"b{k}" for k in range(n_buildings)])


@pytest.mark.parametrize("seed", [0, 1, 2])
@pytest.mark.parametrize("threshold", [20.0, 30.0, 40.0])
def test_the_mixture_finds_roofs_where_reflections_are_strong(seed, threshold):
    table, sky, roofs = street(seed)
    estimator = Estimator(init_threshold=threshold, signal_model="mixture")
    out, model = heights_and_signal_model(table, estimator, open_sky=sky)
    out = out.set_index("id")
    assert out["converged"].all(), out["status"].tolist()
    error = out["height"] - roofs[out.index]
    assert np.abs(error).max() < 1.0
    lower, upper = out["height_lower"], out["height_upper"]
    assert ((lower <= roofs[out.index]) & (roofs[out.index] <= upper)).mean() >= 0.8
    assert isinstance(model, Cn0Mixture)
    assert model.alpha[0] == pytest.approx(OPEN["alpha"], abs=1.5)


def test_the_open_sky_is_only_for_the_mixture():
    table, sky, _ = street(0, n_buildings=2)
    paper, model = heights_and_signal_model(table, Estimator())
    with_sky = estimate_heights(table, Estimator(), open_sky=sky)
    pd.testing.assert_frame_equal(paper, with_sky)
    assert isinstance(model, SignalClassifier)  # the paper's classifier


def test_the_mixture_is_for_4plb_only():
    with pytest.raises(ModelError, match="signal model mixture needs method 4PL-B"):
        Estimator(method="4PL", signal_model="mixture")
    with pytest.raises(ModelError, match="unknown signal model"):
        Estimator(signal_model="magic")


@pytest.mark.parametrize(
    "sky, message",
    [
        (
            pd.DataFrame({"cn0": [35.0, np.inf]}),
            r"C/N0 is infinite \(open-sky signals, column 'cn0', rows 1\)",
        ),
        (pd.DataFrame({"cn0": [35.0, "strong"]}), "column 'cn0' holds values that are not numbers"),
        (pd.DataFrame({"cn0": [35.0], "elevation": ["high"]}), "column 'elevation' holds values"),
        (pd.DataFrame({"snr": [35.0]}), "missing column.*cn0"),
    ],
    ids=["infinite", "text", "text elevation", "no cn0"],
)
def test_bad_open_sky_signals_are_named(sky, message):
    table, _, _ = street(0, n_buildings=1)
    with pytest.raises(InputError, match=message):
        estimate_heights(table, Estimator(signal_model="mixture"), open_sky=sky)


def test_infinite_cn0_in_the_intersections_is_named():
    table, _, _ = street(0, n_buildings=1)
    table.loc[3, "cn0"] = -np.inf
    with pytest.raises(
        InputError, match=r"C/N0 is infinite \(intersections, column 'cn0', rows 3\)"
    ):
        estimate_heights(table)

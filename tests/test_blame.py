"""Whole-ray blame (gnss_citygml.model.blame): what a closed ray that crosses several buildings
tells each one's height fit."""

import numpy as np
import pytest
from conftest import occluded_pair

from gnss_citygml import Estimator, estimate_heights
from gnss_citygml.model.blame import blamed, others_clear, sole_blocker


def test_a_ray_that_crosses_one_building_is_all_its_own():
    prior = np.array([0.2, 0.7, 0.999])
    rest = others_clear(prior, np.arange(3))
    np.testing.assert_allclose(rest, 1.0)
    np.testing.assert_allclose(sole_blocker(prior, rest), 1.0)
    label, weight = blamed(np.array([0.0, 1.0, 0.25]), prior, rest)
    np.testing.assert_allclose(weight, 1.0)
    np.testing.assert_allclose(label, [0.0, 1.0, 0.25])


def test_a_closed_ray_is_blamed_on_the_building_that_surely_blocks_it_in_front_or_behind():
    # rays 0 and 1 cross a building that surely blocks them (p = 0) and one that surely does not
    # (p = 1): the first is blamed, whichever is first along the ray
    prior = np.array([0.0, 1.0, 1.0, 0.0])
    signal = np.array([0, 0, 1, 1])
    w = sole_blocker(prior, others_clear(prior, signal))
    np.testing.assert_allclose(w, [1.0, 0.0, 0.0, 1.0], atol=1e-5)
    # two buildings that both surely block it: it tells neither anything
    both = np.array([0.0, 0.0])
    assert sole_blocker(both, others_clear(both, np.array([0, 0]))).max() < 1e-5
    # two buildings nothing is known of: each the sole blocker a third of the time
    half = np.array([0.5, 0.5])
    np.testing.assert_allclose(sole_blocker(half, others_clear(half, np.array([0, 0]))), 1 / 3)


@pytest.mark.parametrize("prior", [(0.3, 0.8), (0.05, 0.5, 0.9), (0.6, 0.6, 0.6, 0.99)])
def test_the_weighted_label_has_the_gradient_of_the_rays_own_likelihood(prior):
    """A closed ray's likelihood is 1 - prod(p); the weighted closed label's log-likelihood
    w_k log(1 - p_k) has the same gradient in each p_k, so fits iterated with each other's
    current fits stop at the rays' own maximum likelihood."""
    p = np.array(prior)
    rest = others_clear(p, np.zeros(p.size, dtype=int))
    w = sole_blocker(p, rest)
    own = -np.prod(p) / p / (1.0 - np.prod(p))  # d/dp_k log(1 - prod p)
    np.testing.assert_allclose(-w / (1.0 - p), own, rtol=1e-9)
    # an uncertain signal: its open part weighs rho with label 1, its closed part the rest
    rho = 0.3
    label, weight = blamed(np.full(p.size, rho), p, rest)
    np.testing.assert_allclose(weight * label, rho)
    np.testing.assert_allclose(weight * (1 - label), (1 - rho) * w)


def test_open_rays_behind_a_taller_building_count_for_the_one_behind(rng):
    table = occluded_pair(rng)
    ray = estimate_heights(table, Estimator(blame="ray")).set_index("id")
    drop = estimate_heights(table).set_index("id")
    for out in (ray, drop):
        assert out.loc["A", "height"] == pytest.approx(30.0, abs=1.5)
        assert out.loc["B", "height"] == pytest.approx(20.0, abs=1.5)
    # the drop leaves out every ray A may block, open or not; blame keeps the open ones
    assert ray.loc["B", "n_signals"] > drop.loc["B", "n_signals"]
    assert ray.loc["B", "height_lower"] <= 20.0 <= ray.loc["B", "height_upper"]

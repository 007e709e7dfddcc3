"""Whole-ray blame (gnss_citygml.model.blame): what a closed ray that crosses several buildings
tells each one's height fit."""

import numpy as np
import pytest
from conftest import occluded_pair

from gnss_citygml import Estimator, estimate_heights
from gnss_citygml.model.blame import blamed, cleared, others_clear, sole_blocker
from gnss_citygml.model.classifier import SignalClassifier
from gnss_citygml.model.parts import Part


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


@pytest.mark.parametrize("crossing", [(1.0, 0.3), (0.02, 0.9, 0.5), (0.7, 0.7, 1.0, 0.1)])
def test_with_each_rays_chance_of_crossing_the_labels_have_the_rays_gradient(crossing):
    """A ray crosses building k with chance q_k: it clears it with 1 - q_k (1 - p_k). The
    weighted labels' log-likelihood has the gradient in each p_k of the ray's own, closed
    (1 - prod) and open (prod): a row that may well miss its building says little of it."""
    q = np.array(crossing)
    p = np.linspace(0.2, 0.9, q.size)
    clear = cleared(p, q)
    rest = others_clear(clear, np.zeros(q.size, dtype=int))
    closed = -q * rest / (1.0 - np.prod(clear))  # d/dp_k log(1 - prod(clear))
    opened = q / clear  # d/dp_k log(prod(clear))
    _, w = blamed(np.zeros(q.size), p, rest, q)
    np.testing.assert_allclose(-w / (1.0 - p), closed, rtol=1e-9)
    label, v = blamed(np.ones(q.size), p, rest, q)
    np.testing.assert_allclose(label, 1.0)
    np.testing.assert_allclose(v / p, opened, rtol=1e-9)
    # a ray sure to cross: the weights without the chance
    sure = blamed(np.full(2, 0.4), p[:2], rest[:2], np.ones(2))
    for one, other in zip(sure, blamed(np.full(2, 0.4), p[:2], rest[:2]), strict=True):
        np.testing.assert_allclose(one, other, rtol=1e-14)


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


def test_a_neighbour_is_taken_as_tall_as_its_lowest_open_rays(rng):
    """What a building's range takes a neighbour for (``Shared.top``): its roof line, or, where
    that lies below them, the lowest of its open rays (5 %): whole-ray blame may have given
    all of a building's closed rays to a neighbour and left it a roof line far below its data,
    but the roof may stand up to where its rays are open."""
    h = np.concatenate([rng.uniform(10, 50, 400), rng.uniform(40, 90, 400)])
    cn0 = np.concatenate([np.where(h[:400] > 30, 45.0, 20.0), np.full(400, 45.0)])
    g = np.repeat([0, 1], 400)  # 0: closed below 30 m; 1: every ray open
    part = Part.of(g, h, cn0, 2, Estimator(blame="ray")).fitted(SignalClassifier(c=35.0))
    top, fit = part.shared().top, part.last.fit if part.last else None
    assert fit is not None and fit.c[0] == pytest.approx(30.0, abs=0.5)
    floors = [np.quantile(h[:400][h[:400] > 30], 0.05), np.quantile(h[400:], 0.05)]
    assert fit.c[1] < floors[1]  # a roof line below every ray of building 1
    np.testing.assert_allclose(top, np.fmax(fit.c, floors), atol=0.5)

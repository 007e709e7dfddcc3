"""Shadow matching (:mod:`gnss_citygml.calibrate.shadows`): a fix pushed across a street is taken
back by which signals arrive, and no window is put inside a building."""

import numpy as np
import pytest
import shapely

from gnss_citygml.calibrate import shadows
from gnss_citygml.calibrate.shadows import _spread, label_chances, shadow_offsets
from gnss_citygml.errors import InputError
from gnss_citygml.raycast import footprint_entries

#: Two rows of a street running east to west, 16 m wide, and their roofs (m; the antenna at 1).
ROWS = np.array([shapely.box(-200, 8, 200, 30), shapely.box(-200, -30, 200, -8)])
ROOFS = np.array([21.0, 16.0])
SD = 3.0


def _rays(true_n: float, reported_n: float, n_epochs: int = 10, speed: float = 0.0):
    """A phone at (0, ``true_n``), walking east at ``speed`` (m an epoch), and reporting
    ``reported_n``: 168 satellites over the whole sky each epoch, and which of them the map
    leaves in sight."""
    azimuth, elevation = (
        np.tile(a.ravel(), n_epochs)
        for a in np.meshgrid(np.arange(0.0, 360.0, 15.0), np.arange(10.0, 80.0, 10.0))
    )
    east = np.repeat(speed * np.arange(n_epochs), azimuth.size // n_epochs)
    ray, part, dist, _ = footprint_entries(
        east, np.full(azimuth.size, true_n), azimuth, ROWS, 300.0
    )
    rise = 1.0 + dist * np.tan(np.radians(elevation[ray]))
    seen = np.bincount(ray, ROOFS[part] > rise, minlength=azimuth.size) == 0
    rays = {
        "e": east,
        "n": np.full(azimuth.size, reported_n),
        "z": np.ones(azimuth.size),
        "bearing": azimuth,
        "tan_el": np.tan(np.radians(elevation)),
        "satellite": np.tile(np.arange(azimuth.size // n_epochs), n_epochs),
    }
    return rays, seen


def _offsets(rays, seen, heights, p_seen=(0.95, 0.05), height_sd=None):
    unit = np.zeros(seen.size, dtype=np.intp)
    sd = np.array([SD])
    chances = label_chances(seen, p_seen)
    return shadow_offsets(rays, chances, unit, sd, ROWS, heights, 300.0, height_sd)[0]


@pytest.mark.parametrize("true_n", [-5.0, -2.0, 3.0])
@pytest.mark.parametrize("push", [4.0, -4.0])
@pytest.mark.parametrize("p_seen", [(0.95, 0.05), (0.85, 0.3)])
def test_a_fix_pushed_across_the_street_comes_back(true_n, push, p_seen):
    rays, seen = _rays(true_n, true_n + push)
    east, north = _offsets(rays, seen, ROOFS, p_seen)
    assert abs(push + north) < 1.6  # from 4 m off to within the grid's step (1.5 m)
    assert abs(east) < 1.0  # along the street the shadows say nothing: the prior holds


def test_every_sky_is_explained_where_the_fix_is_right():
    rays, seen = _rays(-3.0, -3.0)
    assert np.hypot(*_offsets(rays, seen, ROOFS)) < 1.0


def test_roofs_fitted_from_a_biased_fix_hold_it_and_the_maps_roofs_take_it_back():
    """Every phone of a street 4 m north: the roofs fitted from there are the true ones scaled
    by the distances to the walls, which explain the shadows from the biased fix as well as the
    true roofs do from the truth (a roof line absorbs a shift across the street). Roofs given
    with the map, 1 m off either way and saying so, take the bias back."""
    true_n, reported_n = -3.0, 1.0
    rays, seen = _rays(true_n, reported_n)
    scale = np.array([(8.0 - reported_n) / (8.0 - true_n), (8.0 + reported_n) / (8.0 + true_n)])
    fitted = 1.0 + (ROOFS - 1.0) * scale
    assert abs(_offsets(rays, seen, fitted, (0.85, 0.3))[1]) < 0.5
    for error in (1.0, -1.0):
        given = ROOFS + np.array([error, -error])
        north = _offsets(rays, seen, given, (0.85, 0.3), np.full(2, 1.0))[1]
        assert abs(reported_n + north - true_n) < 1.6


def test_each_satellite_is_cast_from_a_few_of_its_epochs_evenly_spread():
    vote = np.r_[np.zeros(10, int), np.ones(2, int), np.full(11, 2), np.full(3, 3)]
    rows = _spread(np.random.default_rng(0).permutation(vote), 3)
    kept = np.bincount(np.random.default_rng(0).permutation(vote)[rows])
    assert kept.tolist() == [3, 2, 3, 3]
    order = _spread(vote, 3)
    assert order[:3].tolist() == [0, 4, 7]  # of 10 rows: the first of each third


def test_a_few_epochs_of_a_walker_say_what_all_of_them_say(monkeypatch):
    rays, seen = _rays(-3.0, 1.0, speed=1.4)  # 10 epochs, 14 m walked
    few = _offsets(rays, seen, ROOFS)
    monkeypatch.setattr(shadows, "EPOCHS", 10)
    assert np.hypot(*(few - _offsets(rays, seen, ROOFS))) < 0.5
    assert abs(1.0 + few[1] + 3.0) < 1.6


def test_a_map_without_heights_keeps_the_window_out_of_the_buildings():
    rays, seen = _rays(-5.0, 10.0)  # reported 2 m inside the north row
    east, north = _offsets(rays, seen, np.full(2, np.nan))
    assert -8.0 < 10.0 + north < 8.0 and abs(east) < 1.0


def test_chances_of_nothing_either_way_are_refused():
    """A chance of 0 would rule out every candidate one ray contradicts: no window would move,
    silently."""
    rays, seen = _rays(-3.0, 1.0)
    with pytest.raises(InputError, match="above 0"):
        _offsets(rays, seen, ROOFS, (1.0, 0.0))


#: The street's rows as 60 m buildings (six each side), with the same roofs as :data:`ROOFS`.
BLOCKS = np.array(
    [
        shapely.box(x, y0, x + 60.0, y1)
        for y0, y1 in ((8, 30), (-30, -8))
        for x in range(-180, 180, 60)
    ]
)
BLOCK_ROOFS = np.repeat(ROOFS, 6)


def test_the_casts_weighed_again_are_the_casts_made_again():
    """:class:`~gnss_citygml.calibrate.shadows.Candidates` casts once; weighed against other
    roofs it gives what casting anew against them gives."""
    rays, seen = _rays(-3.0, 1.0, speed=1.4)
    unit, sd = np.zeros(seen.size, dtype=np.intp), np.array([SD])
    chances = label_chances(seen, (0.85, 0.3))
    candidates = shadows.Candidates(rays, unit, sd, ROWS, 300.0)
    for roofs in (ROOFS, ROOFS + 3.0, np.array([np.nan, 16.0])):
        again = shadow_offsets(rays, chances, unit, sd, ROWS, roofs, 300.0)
        np.testing.assert_array_equal(candidates.offsets(chances, roofs), again)


def test_roofs_not_known_yet_are_taken_as_tall_as_the_known_ones(monkeypatch):
    """The blocks beside one walker have no height yet; the street's others, which two other
    walkers see, do. The walker's fix pushed 4 m across the street comes back on the shadows
    of the blocks beside it, taken to be as tall as the street's others; with too few known
    roofs those say only that they reach 3 m."""
    walkers = [_rays(-3.0, -3.0) for _ in range(3)]
    rays = {name: np.concatenate([w[0][name] for w in walkers]) for name in walkers[0][0]}
    unit = np.repeat(np.arange(3), walkers[0][1].size)
    rays["e"] = rays["e"] + np.array([0.0, -150.0, 150.0])[unit]
    ray, part, dist, _ = footprint_entries(rays["e"], rays["n"], rays["bearing"], BLOCKS, 300.0)
    rise = 1.0 + dist * rays["tan_el"][ray]
    seen = np.bincount(ray, BLOCK_ROOFS[part] > rise, minlength=unit.size) == 0
    rays["n"] = np.where(unit == 0, 1.0, rays["n"])
    sd = np.full(3, SD)
    chances = label_chances(seen, (0.95, 0.05))
    roofs = BLOCK_ROOFS.copy()
    roofs[[2, 3, 8, 9]] = np.nan  # the blocks at x = -60 .. 60
    candidates = shadows.Candidates(rays, unit, sd, BLOCKS, 300.0)
    north = candidates.offsets(chances, roofs)[0, 1]
    assert abs(1.0 + north + 3.0) < 1.6
    monkeypatch.setattr(shadows, "MIN_KNOWN", 100)  # too few known: they reach 3 m, no more
    assert abs(1.0 + candidates.offsets(chances, roofs)[0, 1] + 3.0) > 2.0
    monkeypatch.undo()
    few = np.full(BLOCK_ROOFS.size, np.nan)
    few[[0, 6]] = BLOCK_ROOFS[[0, 6]]
    assert candidates._survival(few) is None
    heights, share = candidates._survival(roofs)
    assert np.all(np.diff(heights) >= 0.0) and np.all(np.diff(share) <= 0.0)
    assert share[0] == pytest.approx(1.0 - 0.5 / 8) and share[-1] == pytest.approx(0.5 / 8)


def test_casts_beyond_what_is_kept_are_cast_again_alike(monkeypatch):
    """Casts kept from the first round, and those cast again where the memory kept is full,
    weigh alike."""
    rays, seen = _rays(-3.0, 1.0, speed=1.4)
    unit, sd = np.arange(seen.size) // 168, np.full(10, SD)  # one window an epoch
    chances = label_chances(seen, (0.85, 0.3))
    monkeypatch.setattr(shadows, "CHUNK", 121 * 200)  # chunks of 200 rows
    kept = shadows.Candidates(rays, unit, sd, ROWS, 300.0)
    first = kept.offsets(chances, ROOFS)
    assert len(kept.kept) > 1 and kept.kept_bytes > 0
    some = shadows.Candidates(rays, unit, sd, ROWS, 300.0, keep=kept.kept_bytes // 2)
    np.testing.assert_array_equal(some.offsets(chances, ROOFS), first)
    assert 0 < len(some.kept) < len(kept.kept)
    for roofs in (ROOFS + 2.0, ROOFS):
        np.testing.assert_array_equal(some.offsets(chances, roofs), kept.offsets(chances, roofs))

"""Shadow matching (:mod:`gnss_citygml.calibrate.shadows`): a fix pushed across a street is taken
back by which signals arrive, and no window is put inside a building."""

import numpy as np
import pytest
import shapely

from gnss_citygml.calibrate.shadows import shadow_offsets
from gnss_citygml.raycast import footprint_entries

#: Two rows of a street running east to west, 16 m wide, and their roofs (m; the antenna at 1).
ROWS = np.array([shapely.box(-200, 8, 200, 30), shapely.box(-200, -30, 200, -8)])
ROOFS = np.array([21.0, 16.0])
SD = 3.0


def _rays(true_n: float, reported_n: float, n_epochs: int = 10):
    """A phone standing at (0, ``true_n``) and reporting (0, ``reported_n``): 168 satellites over
    the whole sky each epoch, and which of them the map leaves in sight."""
    azimuth, elevation = (
        a.ravel() for a in np.meshgrid(np.arange(0.0, 360.0, 15.0), np.arange(10.0, 80.0, 10.0))
    )
    ray, part, dist, _ = footprint_entries(
        np.zeros(azimuth.size), np.full(azimuth.size, true_n), azimuth, ROWS, 300.0
    )
    rise = 1.0 + dist * np.tan(np.radians(elevation[ray]))
    seen = np.bincount(ray, ROOFS[part] > rise, minlength=azimuth.size) == 0
    rays = {
        "e": np.zeros(azimuth.size * n_epochs),
        "n": np.full(azimuth.size * n_epochs, reported_n),
        "z": np.ones(azimuth.size * n_epochs),
        "bearing": np.tile(azimuth, n_epochs),
        "tan_el": np.tile(np.tan(np.radians(elevation)), n_epochs),
        "satellite": np.tile(np.arange(azimuth.size), n_epochs),
    }
    return rays, np.tile(seen, n_epochs)


def _offsets(rays, seen, heights, p_seen=(0.95, 0.05)):
    unit = np.zeros(seen.size, dtype=np.intp)
    return shadow_offsets(rays, seen, p_seen, unit, np.array([SD]), ROWS, heights, 300.0)[0]


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


def test_a_map_without_heights_keeps_the_window_out_of_the_buildings():
    rays, seen = _rays(-5.0, 10.0)  # reported 2 m inside the north row
    east, north = _offsets(rays, seen, np.full(2, np.nan))
    assert -8.0 < 10.0 + north < 8.0 and abs(east) < 1.0

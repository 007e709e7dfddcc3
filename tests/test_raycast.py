import numpy as np
import pytest
import shapely

from gnss_citygml import raycast
from gnss_citygml.raycast import footprint_entries

SQUARE = shapely.box(10, -5, 20, 5)
HOLED = shapely.Polygon(
    [(10, -10), (30, -10), (30, 10), (10, 10)], [[(15, -5), (25, -5), (25, 5), (15, 5)]]
)
STRIP = ((0, -500), (0, 500), (100, 500), (100, -500))
TWO_PARTS = shapely.MultiPolygon([shapely.box(10, -1, 11, 1), shapely.box(20, -1, 21, 1)])


def test_head_on_entry():
    ray, fp, dist, cos = footprint_entries([0.0], [0.0], [90.0], [SQUARE])
    assert ray.tolist() == [0] and fp.tolist() == [0]
    assert dist[0] == pytest.approx(10.0)
    assert cos[0] == pytest.approx(1.0)


def test_oblique_entry_distance_and_incidence():
    # bearing 45 deg from (0, 0) enters the face x = 10 at (10, 10) of a tall box
    box = shapely.box(10, -50, 20, 50)
    _, _, dist, cos = footprint_entries([0.0], [0.0], [45.0], [box])
    assert dist[0] == pytest.approx(10.0 * np.sqrt(2))
    assert cos[0] == pytest.approx(np.cos(np.radians(45.0)))


def test_rays_that_miss_or_fall_short():
    ray, *_ = footprint_entries([0.0, 0.0], [0.0, 0.0], [270.0, 0.0], [SQUARE])
    assert ray.size == 0
    ray, *_ = footprint_entries([0.0], [0.0], [90.0], [SQUARE], max_range=5.0)
    assert ray.size == 0


def test_holes_and_origins_inside():
    x = [0.0, 20.0, 20.0, 12.0]
    ray, fp, dist, _ = footprint_entries(x, [0.0] * 4, [90.0, 90.0, 270.0, 90.0], [HOLED])
    # from the west: the exterior at 10 m; from inside the hole: the hole's walls at 5 m;
    # from inside the solid part: nothing (a receiver cannot stand in a building)
    assert ray.tolist() == [0, 1, 2]
    np.testing.assert_allclose(dist, [10.0, 5.0, 5.0])


def test_multipolygon_is_one_footprint_entered_at_its_first_part():
    ray, fp, dist, _ = footprint_entries([0.0, 15.0], [0.0, 0.0], [90.0, 90.0], [TWO_PARTS])
    np.testing.assert_allclose(dist, [10.0, 5.0])


def test_several_footprints_sorted_by_distance_along_each_ray():
    far, near = shapely.box(50, -5, 60, 5), shapely.box(10, -5, 20, 5)
    ray, fp, dist, _ = footprint_entries([0.0, 0.0], [0.0, 1.0], [90.0, 90.0], [far, near])
    assert ray.tolist() == [0, 0, 1, 1]
    assert fp.tolist() == [1, 0, 1, 0]
    np.testing.assert_allclose(dist, [10, 50, 10, 50])


def test_matches_shapely_intersection_on_random_rays():
    rng = np.random.default_rng(1)
    polys = [
        shapely.Polygon(shapely.affinity.rotate(shapely.box(0, 0, 12, 7), ang).exterior)
        for ang in (0, 17, 33)
    ]
    polys = [shapely.affinity.translate(p, 30 * k, 10 * k) for k, p in enumerate(polys)]
    x, y = rng.uniform(-40, 100, 300), rng.uniform(-40, 60, 300)
    bearing = rng.uniform(0, 360, 300)
    ray, fp, dist, _ = footprint_entries(x, y, bearing, polys, max_range=200)
    for r, f, d in zip(ray, fp, dist, strict=False):
        end = (
            x[r] + 200 * np.sin(np.radians(bearing[r])),
            y[r] + 200 * np.cos(np.radians(bearing[r])),
        )
        line = shapely.LineString([(x[r], y[r]), end])
        hit = shapely.intersection(line, polys[f])
        assert shapely.Point(x[r], y[r]).distance(hit) == pytest.approx(d, abs=1e-6)


@pytest.mark.parametrize("bearing", [80.0, 100.0, 135.0])
def test_distance_gradient_matches_finite_differences(bearing):
    box = shapely.box(10, -50, 20, 50)
    x, y, step = np.array([0.0, 1e-4, 0.0]), np.array([0.0, 0.0, 1e-4]), 1e-4
    *_, grad = footprint_entries([0.0], [0.0], [bearing], [box], gradient=True)
    _, _, dist, _ = footprint_entries(x, y, [bearing] * 3, [box])
    assert grad.shape == (1, 2)
    np.testing.assert_allclose(grad[0], (dist[1:] - dist[0]) / step, rtol=1e-4)


def test_gradient_of_no_entries_has_two_columns():
    *_, grad = footprint_entries([0.0], [0.0], [270.0], [SQUARE], gradient=True)
    assert grad.shape == (0, 2)


@pytest.mark.parametrize("per_ray", [False, True])
def test_rays_cast_from_moved_origins_are_those_cast_from_each(per_ray):
    """``shifts``: every ray cast from each of its moved origins, in one pruning query a ray,
    gives what casting from each moved origin does (ray i from move j numbered i * k + j)."""
    rng = np.random.default_rng(3)
    corners = rng.uniform(-80, 80, (25, 2))
    footprints = shapely.box(*corners.T, *(corners + rng.uniform(4, 20, (25, 2))).T)
    x, y, bearing = rng.uniform(-60, 60, 40), rng.uniform(-60, 60, 40), rng.uniform(0, 360, 40)
    moves = rng.uniform(-12, 12, (40, 6, 2) if per_ray else (6, 2))
    got = footprint_entries(x, y, bearing, footprints, 120.0, shifts=moves)
    each = moves if per_ray else np.broadcast_to(moves, (40, 6, 2))
    ray, fp, dist, cos = footprint_entries(
        (x[:, None] + each[:, :, 0]).ravel(),
        (y[:, None] + each[:, :, 1]).ravel(),
        np.repeat(bearing, 6),
        footprints,
        120.0,
    )
    assert ray.size > 100
    for one, other in zip(got, (ray, fp, dist, cos), strict=True):
        np.testing.assert_array_equal(one, other)


@pytest.mark.parametrize("gradient", [False, True])
def test_batches_chunks_and_threads_give_one_pass_bits(rng, monkeypatch, gradient):
    """The cast in small batches of rays and small chunks, the batches in threads, is the cast
    in one batch, bit for bit and in the same order: blocks sharing walls, one drawn twice (rays
    entering two footprints at the same distance), a courtyard, rays along the axes."""
    blocks = [shapely.box(x, y, x + 10, y + 10) for x in range(0, 60, 10) for y in (0, 30)]
    yard = shapely.box(0, 60, 30, 90).difference(shapely.box(10, 70, 20, 80))
    footprints = [*blocks, yard, blocks[3]]
    n = 3000
    x, y = rng.uniform(-20, 80, n), rng.uniform(-20, 100, n)
    bearing = np.where(rng.random(n) < 0.2, rng.integers(0, 4, n) * 90.0, rng.uniform(0, 360, n))
    monkeypatch.setenv("OMP_NUM_THREADS", "1")
    one = footprint_entries(x, y, bearing, footprints, 200.0, gradient=gradient)
    monkeypatch.setenv("OMP_NUM_THREADS", "3")
    monkeypatch.setattr(raycast, "_RAYS", 64)
    monkeypatch.setattr(raycast, "_CHUNK", 500)
    many = footprint_entries(x, y, bearing, footprints, 200.0, gradient=gradient)
    ray, distance = one[0], one[2]
    assert ray.size > n // 2 and np.any((np.diff(ray) == 0) & (np.diff(distance) == 0))  # ties
    for a, b in zip(one, many, strict=True):
        assert np.array_equal(a, b)


def test_reach_gives_each_footprints_extent_across_the_ray_and_its_near_misses():
    """``reach``: how far the footprint lies to each side of the ray (right negative), and a row
    for a footprint passed within the reach, at its point nearest the ray's line."""
    ray, fp, dist, cos, across = footprint_entries(
        [0.0, 0.0, 0.0, 0.0], [0.0, 7.0, -8.0, 9.0], [90.0] * 4, [SQUARE], reach=3.5
    )
    assert ray.tolist() == [0, 1, 2]  # the ray 4 m beside the square is beyond reach
    np.testing.assert_allclose(across, [[-5, 5], [-12, -2], [3, 13]])
    np.testing.assert_allclose(dist, 10.0)  # near misses: at the corner nearest the line
    assert np.all((cos >= 0) & (cos <= 1))


def test_reach_counts_only_the_footprint_within_the_rays_length():
    """A footprint behind the receiver or beyond the ray's length gives no row, however near
    its line; one the ray enters spans across it only as far as its part within that length."""
    ray, *_ = footprint_entries([0.0, 0.0], [0.0, 0.0], [270.0, 90.0], [SQUARE], 5.0, reach=9.0)
    assert ray.size == 0
    wedge = shapely.Polygon([(10, -1), (40, -30), (40, 30)])  # widens along the ray
    *_, across = footprint_entries([0.0], [0.0], [90.0], [wedge], 20.0, reach=1.0)
    np.testing.assert_allclose(across, [[-1 - 29 / 3, -1 + 31 / 3]])  # its width at 20 m


def test_reach_matches_shapely_on_random_rays(rng):
    """Every pair the plain cast finds is found with ``reach``, with the same distance and
    incidence; a near miss is a pair whose ray's line passes the footprint within the reach,
    its extent across the ray that of the footprint's boundary within the ray's length."""
    corners = rng.uniform(-80, 80, (30, 2))
    footprints = shapely.box(*corners.T, *(corners + rng.uniform(4, 20, (30, 2))).T)
    footprints = shapely.affinity.rotate(footprints[0], 20), *footprints[1:]
    x, y, bearing = rng.uniform(-60, 60, 300), rng.uniform(-60, 60, 300), rng.uniform(0, 360, 300)
    plain = footprint_entries(x, y, bearing, footprints, 100.0)
    ray, fp, dist, cos, across = footprint_entries(x, y, bearing, footprints, 100.0, reach=5.0)
    entered = (across[:, 0] <= 0) & (across[:, 1] >= 0)
    for one, other in zip(plain, (ray, fp, dist, cos), strict=True):
        np.testing.assert_array_equal(one, other[entered])
    assert (~entered).sum() > 50
    for r, f, lo, hi in zip(ray, fp, across[:, 0], across[:, 1], strict=True):
        dx, dy = np.sin(np.radians(bearing[r])), np.cos(np.radians(bearing[r]))
        strip = shapely.Polygon(  # 0-100 m along the ray, any distance across it
            [(x[r] + t * dx - s * dy, y[r] + t * dy + s * dx) for t, s in STRIP]
        )
        inside = shapely.intersection(shapely.boundary(footprints[f]), strip)
        pts = shapely.get_coordinates(inside)
        side = dx * (pts[:, 1] - y[r]) - dy * (pts[:, 0] - x[r])
        np.testing.assert_allclose([lo, hi], [side.min(), side.max()], atol=1e-6)
        gap = min(abs(lo), abs(hi)) if lo * hi > 0 else 0.0
        assert gap <= 5.0 + 1e-9

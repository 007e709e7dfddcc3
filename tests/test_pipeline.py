"""The whole pipeline on simulated sites written as real files: GeoPackage, GeoTIFF, Parquet."""

from dataclasses import replace

import geopandas as gpd
import numpy as np
import pandas as pd
import pytest
import shapely
from scipy.stats import norm

from gnss_citygml.errors import InputError
from gnss_citygml.footprints import read_footprints
from gnss_citygml.geodesy import from_osgb
from gnss_citygml.observations import read_observations
from gnss_citygml.pipeline import STAGES, estimate, intersections, receivers
from gnss_citygml.settings import (
    Calibration,
    Estimator,
    PositionError,
    Rays,
    ReceiverHeights,
    RunSettings,
)
from gnss_citygml.simulate import simulate, wgs84_to_local
from gnss_citygml.simulate.files import write_site
from gnss_citygml.simulate.scenes import Building, Scene, Session


@pytest.fixture(scope="module")
def site(grid_dir, tmp_path_factory):
    sim = simulate("hermitage", locations="manual", seed=0, interval=20.0)
    folder = tmp_path_factory.mktemp("hermitage")
    paths = write_site(sim, folder, grid_dir=grid_dir)
    return sim, paths, grid_dir


def test_heights_from_files(site):
    sim, paths, grids = site
    stages = []
    out = estimate(
        read_observations(paths["observations"]),
        read_footprints(paths["footprints"]),
        str(paths["dem"]),
        grid_dir=grids,
        progress=stages.append,
    )
    assert stages == list(STAGES)
    assert out.crs.to_epsg() == 27700 and len(out) == len(sim.truth)
    truth = sim.truth.set_index("id")
    row = out.set_index("id").loc["hermitage_terrace"]
    assert row["converged"] and row["status"] == "ok"
    assert abs(row["height"] - truth.loc["hermitage_terrace", "height"]) < 1.0
    assert row["ground"] == pytest.approx(truth.loc["hermitage_terrace", "ground"])
    assert row["relative_height"] == pytest.approx(row["height"] - row["ground"])
    assert row["height_lower"] < row["height"] < row["height_upper"]
    # never a guess: a building without a converged fit has no height
    bad = out[~out["converged"]]
    assert bad["height"].isna().all() and (bad["status"] != "ok").all()


def test_the_run_settings_as_one_object_or_by_their_parts_give_the_same_heights(site):
    """``run(..., settings)`` and ``run(..., estimator=...)`` are one run: the parts named
    replace those of the settings (or of the defaults)."""
    _, paths, grids = site
    inputs = (
        read_observations(paths["observations"]),
        read_footprints(paths["footprints"]),
        str(paths["dem"]),
    )
    four = Estimator(method="4PL")
    settings = RunSettings(estimator=four, grid_dir=grids)
    whole = estimate(*inputs, settings)
    by_parts = estimate(*inputs, estimator=four, grid_dir=grids)
    changed = estimate(*inputs, RunSettings(grid_dir=grids), estimator=four)
    assert (whole["method"] == "4PL").all() and whole["converged"].any()
    pd.testing.assert_frame_equal(whole, by_parts)
    pd.testing.assert_frame_equal(whole, changed)


def test_pipeline_intersections_match_the_simulators(site):
    """Geodesy + DEM + ray casting from the files reproduce the simulator's own intersections
    (cast in its local grid): same signals and buildings, heights within centimetres."""
    sim, paths, grids = site
    obs = read_observations(paths["observations"])
    rx = receivers(obs, str(paths["dem"]), grid_dir=grids)
    ours = intersections(rx, read_footprints(paths["footprints"]))
    theirs = sim.intersections
    key = ["signal", "building"]
    both = ours.merge(theirs, on=key, suffixes=("", "_sim"))
    assert len(both) >= 0.99 * max(len(ours), len(theirs))
    diff = np.abs(both["height"] - both["height_sim"])
    assert np.median(diff) < 0.02 and np.percentile(diff, 99) < 0.1


def test_antenna_height_and_log_heights(site):
    sim, paths, grids = site
    obs = read_observations(paths["observations"]).head(50)
    rx = receivers(
        obs, str(paths["dem"]), grid_dir=grids, heights=ReceiverHeights(antenna_height=1.5)
    )
    np.testing.assert_allclose(rx["z"], sim.scene.ground + 1.5, atol=1e-4)
    with pytest.raises(InputError, match="without an ellipsoidal height"):
        receivers(obs, heights=ReceiverHeights(source="log"), grid_dir=grids)
    with_h = obs.assign(h=80.0)
    rx = receivers(with_h, heights=ReceiverHeights(source="log"), grid_dir=grids)
    assert (rx["z"] - 80.0).between(-50.0, -44.0).all()  # ODN is ~47 m above the ellipsoid


def test_observations_far_from_the_footprints(site):
    _, paths, grids = site
    fp = read_footprints(paths["footprints"])
    far = fp.assign(geometry=fp.geometry.translate(5000.0, 0.0))
    with pytest.raises(InputError, match="outside the footprints' area") as err:
        estimate(read_observations(paths["observations"]), far, str(paths["dem"]), grid_dir=grids)
    assert "receiver hermitage_" in err.value.where


def test_footprint_no_ray_enters(site):
    _, paths, grids = site
    fp = read_footprints(paths["footprints"])
    x0, y0, *_ = fp.total_bounds
    shed = gpd.GeoDataFrame(
        {"id": ["shed"]}, geometry=[shapely.box(x0 - 45, y0 - 45, x0 - 40, y0 - 40)], crs=fp.crs
    )
    both = gpd.GeoDataFrame(pd.concat([fp, shed], ignore_index=True), crs=fp.crs)
    obs = read_observations(paths["observations"])
    out = estimate(
        obs, both, str(paths["dem"]), grid_dir=grids, rays=Rays(max_range=30.0)
    ).set_index("id")
    assert not out.loc["shed", "converged"] and np.isnan(out.loc["shed", "height"])
    assert out.loc["shed", "n_signals"] == 0
    assert out.loc["shed", "status"] == "no signal's ray enters the footprint"


def test_real_mastermap_footprints(shared_data, grid_dir, tmp_path):
    """Real OS MasterMap footprints (Bloomsbury: courtyards, party walls, odd shapes) given
    simulated heights and phones in the streets around them: the pipeline, reading the GML
    itself, finds heights for the buildings the phones see well, within a few metres."""
    real = read_footprints(shared_data / "footprints" / "mastermap-topo_3473984_0.gml")
    centre = (529540.0, 182293.0)  # Gower Street, where the London log was recorded
    near = real[real.distance(shapely.Point(centre)) < 100.0].reset_index(drop=True)
    rng = np.random.default_rng(7)
    ground = 25.0
    # MasterMap splits terraces house by house: touching polygons form a block of similar
    # height (+- 1 m), blocks differ (10-30 m)
    blocks = shapely.get_parts(shapely.union_all(near.geometry.buffer(0.2).to_numpy()))
    block = shapely.STRtree(blocks).query(near.geometry.to_numpy(), predicate="within")[1]
    assert block.size == len(near)
    tops = ground + rng.uniform(10.0, 30.0, blocks.size)[block] + rng.uniform(-1, 1, len(near))
    lat0, lon0, _ = from_osgb(*centre, 0.0, grid_dir=grid_dir)
    origin = Scene("bloomsbury", float(lat0), float(lon0), ground, (), ())

    def local(xy):
        lat, lon, _ = from_osgb(xy[:, 0], xy[:, 1], 0.0, grid_dir=grid_dir)
        return np.column_stack(wgs84_to_local(origin, lon, lat))

    shapes = shapely.transform(near.geometry.to_numpy(), local)
    buildings = tuple(
        Building(bid, ((shape, top),), ground, top)
        for bid, shape, top in zip(near["id"], shapes, tops, strict=True)
    )
    candidates = rng.uniform(-90.0, 90.0, (400, 2))
    free = shapely.distance(shapely.union_all(shapes), shapely.points(candidates)) > 2.0
    spots = candidates[free][:12]
    sessions = tuple(
        Session(f"phone_{k}", 900.0 * k, 600.0, (tuple(map(float, xy)),))
        for k, xy in enumerate(spots)
    )
    scene = replace(origin, buildings=buildings, sessions=sessions)
    sim = simulate(scene, seed=0, interval=5.0)
    paths = write_site(sim, tmp_path, grid_dir=grid_dir)  # the flat DEM; footprints not used
    out = estimate(sim.observations, near, str(paths["dem"]), grid_dir=grid_dir)
    ok = out[out["converged"]].set_index("toid")  # MasterMap's TOIDs keep their name
    error = ok["height"] - sim.truth.set_index("id").loc[ok.index, "height"]
    # measured: 7 of 48 converge (31 say their range would be over 10 m: twelve phones
    # standing 10 min each, 1 m off), median error 0.5 m; houses inside terraces, seen only
    # over their neighbours' party walls, are the outliers (up to 12 m)
    assert len(ok) >= 7
    assert np.median(np.abs(error)) < 2.5
    assert out["toid"].str.startswith("osgb").all() and out.crs.to_epsg() == 27700


def test_calibration_with_another_method_is_refused_before_any_work():
    # the check comes first: the observations are not even looked at
    with pytest.raises(InputError, match="self-calibration needs method 4PL-B, not bayes"):
        estimate(
            pd.DataFrame(),
            gpd.GeoDataFrame(geometry=[], crs="EPSG:27700"),
            estimator=Estimator(method="bayes"),
            calibration=Calibration(prior_sd=1.0),
        )


def rays_from(bearing, n=0.0, z=1.0):
    """One receiver's rays at 45 deg elevation on ``bearing`` (from (0, ``n``))."""
    return pd.DataFrame(
        {
            "e": 0.0,
            "n": n,
            "z": z,
            "bearing": bearing,
            "elevation": 45.0,
            "cn0": 40.0,
            "receiver": "r",
            "time_utc": pd.Timestamp("2020-02-11T10:00:00Z"),
        }
    )


def test_height_errors_of_position_errors():
    # A wall 10 m east of the receiver: head-on, at 60 deg from its normal, and grazing.
    wall = gpd.GeoDataFrame({"id": ["w"]}, geometry=[shapely.box(10, -500, 20, 500)])
    rx = rays_from([90.0, 30.0, 3.0])
    exact = intersections(rx, wall, position_error=PositionError(sd=0.0))
    assert "height_sd" not in exact and "recording" not in exact
    out = intersections(rx, wall, position_error=PositionError(sd=2.0))
    np.testing.assert_allclose(out["height"], exact["height"])
    # tan 45 = 1; 1 / cos 60 = 2; grazing (cos 3 deg from the wall = 0.05) capped at 10
    np.testing.assert_allclose(out["height_sd"], [2.0, 4.0, 20.0])
    # by default each row's own position_sd, 1 m where it is empty or missing
    np.testing.assert_allclose(intersections(rx, wall)["height_sd"], [1.0, 2.0, 10.0])
    given = rx.assign(position_sd=[0.5, np.nan, 3.0])
    np.testing.assert_allclose(intersections(given, wall)["height_sd"], [0.5, 2.0, 30.0])
    overridden = intersections(given, wall, position_error=PositionError(sd=2.0))
    np.testing.assert_allclose(overridden["height_sd"], [2.0, 4.0, 20.0])


def test_each_rows_chance_of_crossing_and_the_near_misses():
    """``PositionError(crossing=True)``: each row's chance that its ray crosses the footprint
    given the position error across it, and rows for footprints passed within three sds."""
    blocks = gpd.GeoDataFrame(
        {"id": ["mid", "corner", "near", "far"]},
        geometry=[
            shapely.box(10, -20, 20, 20),  # the ray through its middle: crosses surely
            shapely.box(30, -10, 40, 0.5),  # 0.5 m from its corner: crosses 69 % of the time
            shapely.box(50, 2, 60, 10),  # missed by 2 m: 2.3 % (2 sds)
            shapely.box(70, 4, 80, 10),  # missed by 4 m: beyond three sds
        ],
    )
    rx = rays_from([90.0])
    plain = intersections(rx, blocks, position_error=PositionError(sd=1.0))
    out = intersections(rx, blocks, position_error=PositionError(sd=1.0, crossing=True))
    assert out["building"].tolist() == ["mid", "corner", "near"]
    assert plain["building"].tolist() == ["mid", "corner"]
    np.testing.assert_allclose(
        out["crossing"], [1.0, norm.cdf(0.5) - norm.cdf(-10.5), norm.cdf(-2.0)], rtol=1e-12
    )
    assert out["order"].tolist() == [0, 1, -1]
    pd.testing.assert_frame_equal(out.iloc[:2].drop(columns="crossing"), plain)
    assert out["height"].iloc[2] == pytest.approx(1.0 + 50.0)  # where the moved ray meets it
    # exact positions: every ray crosses what it enters, and nothing else
    exact = PositionError(sd=0.0, crossing=True)
    assert "crossing" not in intersections(rx, blocks, position_error=exact)


def test_a_position_error_at_a_corner_moves_the_entry_far():
    """A ray that enters a long building's end wall just past its corner: 2 m to the side and
    it runs along the side wall and enters it 50 m on. With the crossing chance the height's
    error is what the rays moved sideways find (``distance_sd``), not the end wall's head-on
    ``sd``; a wall the moved rays enter alike keeps ``sd / cos(incidence)``."""
    long_block = gpd.GeoDataFrame({"id": ["b"]}, geometry=[shapely.box(10, 0.3, 200, 20)])
    # just past the corner at (10, 0.3); the end wall's middle
    rx = rays_from([88.0, 60.0], n=[0.2, 5.0], z=0.0)
    plain = intersections(rx, long_block, position_error=PositionError(sd=1.0))
    moved = intersections(rx, long_block, position_error=PositionError(sd=1.0, crossing=True))
    assert plain["distance"].tolist() == moved["distance"].tolist()
    assert plain["height_sd"].iloc[0] == pytest.approx(1.0, abs=0.01)  # head-on
    corner, wall = moved["height_sd"].to_numpy()
    assert corner > 15.0  # one side's ray enters 50 m on: (50 / 2) / sqrt(2) a sd
    assert wall == pytest.approx(plain["height_sd"].iloc[1], rel=1e-9)


def test_position_errors_shared_per_window():
    wall = gpd.GeoDataFrame({"id": ["w"]}, geometry=[shapely.box(10, -50, 20, 50)])
    start = pd.Timestamp("2020-02-11T10:00:00Z")
    rx = pd.DataFrame(
        {
            "time_utc": start + pd.to_timedelta([0, 10, 40, 0], unit="s"),
            "receiver": ["a", "a", "a", "b"],
            "e": [0.0, 1.0, 2.0, 0.0],  # a walks
            "n": 0.0,
            "z": 1.0,
            "bearing": 90.0,
            "elevation": 30.0,
            "cn0": 40.0,
        }
    )
    walker = PositionError(sd=1.0, window=30.0)
    out = intersections(rx, wall, position_error=walker)
    rec = out["recording"].to_numpy()
    assert rec[0] == rec[1] and len({rec[0], rec[2], rec[3]}) == 3
    # by default a moving receiver's whole recording shares one error
    rec = intersections(rx, wall)["recording"].to_numpy()
    assert rec[0] == rec[1] == rec[2] != rec[3]
    with pytest.raises(InputError, match="position errors need the observations' time_utc"):
        intersections(rx.drop(columns="time_utc"), wall)

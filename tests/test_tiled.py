"""A run in tiles (gnss_citygml.tiling.run) gives the single run's heights: in one process, and on
a real Dask LocalCluster of 2 worker processes, also when one of them is killed mid-run."""

import os
import re
import signal
import subprocess
import sys
from dataclasses import asdict

import geopandas as gpd
import numpy as np
import pandas as pd
import pytest
import shapely
from shapely.geometry import box
from test_cli import run
from test_outputs import estimate

from gnss_citygml.errors import InputError
from gnss_citygml.model.engine import InProcess, in_windows
from gnss_citygml.model.estimate import heights_and_signal_model
from gnss_citygml.pipeline import intersections, open_sky, write_tiles
from gnss_citygml.settings import Estimator, PositionError, Tiling
from gnss_citygml.simulate import simulate
from gnss_citygml.simulate.scenes import city_scene
from gnss_citygml.tiling.grid import building_tiles
from gnss_citygml.tiling.output import TileFolder
from gnss_citygml.tiling.run import failed_tiles, tiled_heights

#: The simulated city's corner in British National Grid (its grid is local): the city's
#: 350 m x 290 m cut by 100 m tiles across TQ2981, TQ3081, TQ2982 and TQ3082.
ORIGIN = (529_950.0, 181_950.0)


def city(seed):
    """A simulated city of 6 x 5 blocks walked by 8 phones, moved into BNG: receivers and
    footprints."""
    sim = simulate(
        city_scene(np.random.default_rng(seed), 6, 5, 8), locations="gnss", seed=seed, interval=2.0
    )
    rx = sim.rays.assign(e=sim.rays["e"] + ORIGIN[0], n=sim.rays["n"] + ORIGIN[1])
    moved = shapely.transform(sim.buildings.geometry.to_numpy(), lambda xy: xy + ORIGIN)
    return rx, sim.buildings.set_geometry(moved).set_crs(27700)


@pytest.fixture(scope="module")
def scene():
    return city(0)


def one_run(rx, buildings, estimator=Estimator()):
    """The single run's heights and signal model (:func:`gnss_citygml.pipeline.run`'s: with
    the open sky)."""
    inter = intersections(rx, buildings)
    return heights_and_signal_model(inter, estimator, open_sky=open_sky(rx, inter))


@pytest.fixture(scope="module")
def single(scene):
    return one_run(*scene)


def assert_close_heights(tiled, single, tol=1e-3):
    """The mixture signal model's run in tiles: the same buildings, converged set and
    statuses, heights within ``tol`` metres (its sums are floats added in another order)."""
    a, b = (t.set_index("id").sort_index() for t in (single, tiled))
    assert a.index.tolist() == b.index.tolist()
    assert (a["converged"] == b["converged"]).all()
    assert (a["status"] == b["status"]).all()
    for column in ("height", "height_lower", "height_upper", "c"):
        np.testing.assert_allclose(b[column], a[column], atol=tol, err_msg=column)


def assert_same_heights(tiled_run, single_run):
    """Same buildings, converged set, statuses and iterations; the heights and the classifier
    bit for bit (the issue asks 1 mm; a tile sums each building's rows as the whole run does,
    and anything less than the same bits can turn into metres where the likelihood is flat).
    The tiled run is a :class:`TileRun`, the single its heights and its signal model."""
    tiled, tiled_model = tiled_run.table, tiled_run.classifier
    single, single_model = single_run
    a, b = (t.set_index("id").sort_index() for t in (single, tiled))
    assert a.index.tolist() == b.index.tolist()
    assert (a["converged"] == b["converged"]).all()
    assert (a["status"] == b["status"]).all()
    for column in ("height", "height_lower", "height_upper", "height_paper", "a", "b", "c", "d"):
        np.testing.assert_array_equal(b[column], a[column], err_msg=column)
    assert (a["n_signals"] == b["n_signals"]).all()
    assert (a["iterations"] == b["iterations"]).all()
    assert asdict(tiled_model) == asdict(single_model)


def test_the_scene_spans_tiles_and_rays_cross_their_edges(scene, single):
    """What the identity tests stand on: several tiles, a good share of converged buildings,
    and signals whose rays cross buildings of two tiles."""
    rx, buildings = scene
    tiles = building_tiles(buildings, 100.0)
    assert len(set(tiles)) >= 9
    assert single[0]["converged"].sum() >= 5
    inter = intersections(rx, buildings)
    owner = pd.Series(tiles, index=buildings["id"].astype(str))
    inter["tile"] = owner.reindex(inter["building"].astype(str)).to_numpy()
    assert (inter.groupby("signal")["tile"].nunique() > 1).sum() > 1000


@pytest.mark.parametrize("size", [60.0, 100.0, 250.0])
def test_tiles_in_one_process_give_the_single_runs_heights(scene, single, size):
    rx, buildings = scene
    tiled = tiled_heights(rx, buildings, tile_size=size)
    assert_same_heights(tiled, single)


@pytest.mark.parametrize(
    "estimator",
    [
        Estimator(weighting="balanced"),
        Estimator(method="4PL"),
        Estimator(fit_max_iter=3),
        Estimator(blame="ray"),
    ],
    ids=["balanced weights", "4PL", "height fits cut at 3 iterations", "whole-ray blame"],
)
def test_tiles_hold_for_other_settings(scene, estimator):
    rx, buildings = scene
    tiled = tiled_heights(rx, buildings, estimator=estimator, tile_size=100.0)
    assert_same_heights(tiled, one_run(rx, buildings, estimator))


@pytest.mark.parametrize("blame", ["drop", "ray"])
def test_tiles_hold_with_each_rows_chance_of_crossing(scene, blame):
    """``PositionError(crossing=True)``: rays give rows for the footprints they pass near, so a
    tile takes the rays that pass near its buildings, and its halo the buildings near them."""
    rx, buildings = scene
    estimator, error = Estimator(blame=blame), PositionError(crossing=True)
    inter = intersections(rx, buildings, position_error=error)
    assert (inter["order"] < 0).sum() > 1000 and inter["crossing"].between(0, 1).all()
    single = heights_and_signal_model(inter, estimator, open_sky=open_sky(rx, inter))
    assert single[0]["converged"].sum() >= 5
    tiled = tiled_heights(rx, buildings, estimator=estimator, position_error=error, tile_size=100)
    assert_same_heights(tiled, single)


@pytest.mark.parametrize("size", [60.0, 250.0])
def test_tiles_hold_for_the_mixture_signal_model(scene, size):
    """The mixture learns from the signals crossing no footprint: the tiles find them as
    all signals less those each crossed first, and give the single run's heights."""
    rx, buildings = scene
    estimator = Estimator(signal_model="mixture")
    single, fitted = one_run(rx, buildings, estimator)
    assert single["converged"].sum() >= 5
    done = tiled_heights(rx, buildings, estimator=estimator, tile_size=size)
    tiled, model = done.table, done.classifier
    assert_close_heights(tiled, single)
    np.testing.assert_allclose(np.ravel(list(asdict(model).values())),
                               np.ravel(list(asdict(fitted).values())), rtol=1e-6)  # fmt: skip


def test_a_tile_without_signals_takes_part_and_reports_its_buildings(scene):
    """A building 3 km from every receiver makes a tile no ray reaches: the run goes on, and
    the building is left out of the heights table as in the single run (no ray enters it)."""
    rx, buildings = scene
    far = buildings.iloc[[0]].assign(id="far")
    far = far.set_geometry([box(ORIGIN[0] + 3000, ORIGIN[1], ORIGIN[0] + 3020, ORIGIN[1] + 20)])
    both = pd.concat([buildings, far], ignore_index=True)
    tiled = tiled_heights(rx, both, tile_size=100.0)
    assert "far" not in set(tiled.table["id"])
    assert_same_heights(tiled, one_run(rx, both))


def test_progress_names_the_plan_and_each_iteration(scene, single):
    rx, buildings = scene
    said = []
    tiled_heights(rx, buildings, tile_size=100.0, progress=said.append)
    assert said[0].startswith("tile plan: ") and "tiles of 100 m" in said[0]
    assert re.fullmatch(r"8 phones levelled by their open sky: offsets \S+ to \S+ dB-Hz", said[1])
    assert said[2:] == [f"iteration {k}" for k in range(1, single[0]["iterations"].max() + 1)]


def test_on_a_dask_cluster_of_two_workers_the_heights_are_the_single_runs(scene, single, engine):
    rx, buildings = scene
    assert len(engine.client.scheduler_info()["workers"]) == 2
    tiled = tiled_heights(rx, buildings, tile_size=100.0, engine=engine)
    assert_same_heights(tiled, single)


def killer(engine, at: str = "iteration 2"):
    """A progress callback that SIGKILLs one of ``engine``'s worker processes when told
    ``at``, and the list of the killed one's pid (to check that it is gone)."""
    pids = engine.client.run(os.getpid)
    killed = []

    def kill_one(text):
        if text == at:
            victim = sorted(pids.values())[0]
            os.kill(victim, signal.SIGKILL)
            killed.append(victim)

    return kill_one, killed


def test_killing_a_worker_mid_run_does_not_change_the_heights(scene, single, engine):
    """SIGKILL to one worker process after the second iteration: its results are lost, Dask
    recomputes them from the steps that made them (its nanny starts a new worker)."""
    rx, buildings = scene
    kill_one, killed = killer(engine)
    tiled = tiled_heights(rx, buildings, tile_size=100.0, engine=engine, progress=kill_one)
    assert killed
    assert killed[0] not in engine.client.run(os.getpid).values()
    assert_same_heights(tiled, single)


def test_a_tile_that_fails_twice_is_reported_by_name_and_the_others_go_on(scene, engine, tmp_path):
    """One signal, whose ray crosses the buildings of one tile only, has a negative position
    error: that tile refuses its rows (twice: Dask retries it), its buildings say so, and the
    other tiles estimate theirs. In one process the same input stops the run."""
    rx, buildings = scene
    inter = intersections(rx, buildings)
    owner = pd.Series(building_tiles(buildings, 100.0), index=buildings["id"].astype(str))
    inter["tile"] = owner.reindex(inter["building"].astype(str)).to_numpy()
    one = inter.groupby("signal")["tile"].agg(["nunique", "first"])
    signal_, tile = next((s, t) for s, (k, t) in one.iterrows() if k == 1)
    broken = rx.assign(position_sd=np.where(rx.index == signal_, -1.0, rx["position_sd"]))
    said = []
    done = tiled_heights(broken, buildings, tile_size=100.0, engine=engine, progress=said.append)
    tiled = done.table
    failed = [t for t in said if " failed: " in t]
    assert len(failed) == 1 and failed[0].startswith(f"tile {tile} failed: InputError: ")
    assert "height_sd must be a finite number" in failed[0]
    lost = tiled["status"].str.startswith(f"tile {tile} failed: ")
    assert set(tiled.loc[lost, "id"]) == set(owner.index[owner == tile])
    assert not tiled.loc[lost, "converged"].any()
    assert tiled.loc[~lost, "converged"].sum() >= 3
    summary = done.failed  # what the command's warning says
    assert summary["tile"].tolist() == [tile] and summary["buildings"].tolist() == [lost.sum()]
    assert summary["reason"][0].startswith("InputError: height_sd must be a finite number")
    # the heights joined onto the footprints name each building's tile and its failure
    tiled_buildings = tiled.assign(tile=tiled["id"].map(owner), failed="")
    tiled_buildings.loc[lost, "failed"] = summary["reason"][0]
    pd.testing.assert_frame_equal(failed_tiles(tiled_buildings), summary)
    # written tile by tile: the failed tile is in the index, its file says why
    out = TileFolder(str(tmp_path / "t"), "4PL-B", "id", 100.0)
    flat = buildings.assign(ground=0.0)  # the simulator's ground
    written_run = tiled_heights(broken, flat, tile_size=100.0, engine=engine, output=out)
    pd.testing.assert_frame_equal(written_run.failed, summary)
    pd.testing.assert_frame_equal(failed_tiles(written_run.table), summary)
    written = gpd.read_parquet(tmp_path / "t" / "heights" / f"tile={tile}")
    assert written["status"].str.startswith(f"tile {tile} failed: InputError: ").all()
    assert set(written["id"]) == set(owner.index[owner == tile])
    with pytest.raises(InputError, match="height_sd must be"):
        tiled_heights(broken, buildings, tile_size=100.0)


class _Counting:
    """An engine that counts the steps submitted and not yet gathered."""

    def __init__(self, engine):
        self.engine, self.waiting, self.most = engine, 0, 0

    def submit(self, func, *args, key=None):
        self.waiting += 1
        self.most = max(self.most, self.waiting)
        return self.engine.submit(func, *args, key=key)

    def gather(self, futures):
        self.waiting -= len(futures)
        return self.engine.gather(futures)


@pytest.mark.parametrize("on_dask", [False, True])
def test_steps_in_windows_keep_their_order_and_at_most_a_window_in_flight(on_dask, request):
    """A step per tile (writes, checks) runs a window at a time, so the client holds one
    window's tasks whatever the number of tiles; the values come back in the steps' order."""
    engine = _Counting(request.getfixturevalue("engine") if on_dask else InProcess())
    steps = ((f"square-{k}-{on_dask}", pow, k, 2) for k in range(23))
    assert in_windows(engine, steps, window=5) == [k * k for k in range(23)]
    assert engine.most == 5 and engine.waiting == 0


@pytest.mark.parametrize(
    "options, message",
    [
        ({"scheduler": "udp://x"}, "unknown scheduler 'udp://x'"),
        ({"scheduler": "tcp://x:8786", "workers": 2}, "--workers 2 is for --scheduler local"),
        ({"scheduler": "local", "workers": 0}, "--workers 0 is for --scheduler local"),
        ({"scheduler": "local", "size": 250.5}, "whole number of metres"),
        ({"size": 500.0}, "a tile size is for a run on a Dask scheduler"),
    ],
)
def test_tiling_options_are_checked(options, message):
    with pytest.raises(InputError, match=message):
        Tiling(**options)


def test_the_core_does_not_import_dask():
    code = (
        "import sys, gnss_citygml, gnss_citygml.cli, gnss_citygml.pipeline, "
        "gnss_citygml.tiling.run; "
        "print([m for m in sys.modules if m.split('.')[0] in ('dask', 'distributed')])"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]"


def test_the_command_line_runs_in_tiles_on_a_local_cluster(grid_args, tmp_path, capsys):
    """``estimate --scheduler local`` on the sample city (30 buildings over TQ3181 and
    TQ3281) in 100 m tiles writes the heights the single run writes."""
    tiled = ["--scheduler", "local", "--workers", "2", "--tile-size", "100"]
    for name, extra in (("single", []), ("tiled", tiled)):
        code, out, err = run(estimate(tmp_path, grid_args, f"{name}.gpkg", *extra), capsys)
        assert code == 0, err
        assert "buildings have a height" in out
    single, tiles = (
        gpd.read_file(tmp_path / f"{name}.gpkg", layer="heights").set_index("id").sort_index()
        for name in ("single", "tiled")
    )
    assert single["converged"].sum() >= 10
    assert single.index.tolist() == tiles.index.tolist()
    assert (single["status"] == tiles["status"]).all()
    for column in ("height", "height_lower", "height_upper", "relative_height"):
        np.testing.assert_array_equal(tiles[column], single[column], err_msg=column)


@pytest.mark.parametrize(
    "extra, message",
    [
        (["--scheduler", "local", "--report", "r"], "the report needs every intersection"),
        (["--tile-size", "500"], "a tile size is for a run on a Dask scheduler"),
        (["--scheduler", "local", "--method", "hinge"], "runs 4PL-B or 4PL, not hinge"),
        (["--scheduler", "local", "--calibration-sd", "5"], "self-calibration is not available"),
        ([], "an output without a suffix is a folder of tiles, which only a run in tiles"),
    ],
)
def test_what_a_run_in_tiles_cannot_do_is_refused_before_any_work(
    grid_args, tmp_path, capsys, extra, message
):
    extra = [str(tmp_path / e) if e == "r" else e for e in extra]
    output = "h.gpkg" if extra else "tiles"
    code, _, err = run(estimate(tmp_path, grid_args, output, *extra), capsys)
    assert code == 2 and err.startswith("error: ") and message in err, err
    assert not list(tmp_path.iterdir())


def test_a_tile_written_again_replaces_its_file(scene, tmp_path):
    """Dask runs a write again when it failed or its worker died: the tile's file is written
    again, the same, and nothing else is left beside it."""
    _, buildings = scene
    own = buildings.iloc[:3].assign(ground=0.0)
    out = TileFolder(str(tmp_path), "4PL-B", "id", 100.0)
    first = out.write(None, own, "TQ2981", "")  # a tile no ray reaches
    assert first["buildings"] == 3 and first["with_height"] == 0 and first["failed"] == ""
    written = gpd.read_parquet(tmp_path / first["location"])
    assert out.write(None, own, "TQ2981", "") == first
    pd.testing.assert_frame_equal(gpd.read_parquet(tmp_path / first["location"]), written)
    assert [p.name for p in (tmp_path / first["location"]).parent.iterdir()] == ["part-0.parquet"]
    assert (written["status"] == "no signal's ray enters the footprint").all()
    assert written["height"].dtype == np.float64 and written["n_signals"].dtype == np.int64


def test_a_tile_folder_is_written_only_by_a_run_in_tiles_and_never_over_a_users_folder(
    grid_args, tmp_path, capsys
):
    """The Python API refuses a folder output without a scheduler, as the command does; and
    --overwrite never replaces a folder that is not a folder of tiles (``-o Documents``)."""
    with pytest.raises(InputError, match="which only a run in tiles writes"):
        write_tiles(pd.DataFrame(), gpd.GeoDataFrame(), None, tmp_path / "tiles", tiling=Tiling())
    mine = tmp_path / "Documents"
    mine.mkdir()
    (mine / "thesis.txt").write_text("years of work")
    tiled = ["--scheduler", "local", "--overwrite"]
    code, _, err = run(estimate(tmp_path, grid_args, "Documents", *tiled), capsys)
    assert code == 2 and "it has no tiles.gpkg" in err and "empty this one" in err, err
    assert [p.name for p in mine.iterdir()] == ["thesis.txt"]

"""`gnss-citygml update` leaves every row of the layer it writes agreeing with itself (issue
45): on `estimate`'s own heights layer it writes estimate's columns too (height,
relative_height, status, a-d, iterations: what its style colours by and `convert` reads), never
a row `converged = 0` with `status = 'ok'` and an old height; on a map of its own columns, a
row without a converged estimate has no height either."""

import json
import shutil
import sqlite3
from pathlib import Path

import numpy as np
import pandas as pd
import pyogrio
import pytest
from test_cli import run

from gnss_citygml.cli import main
from gnss_citygml.errors import InputError
from gnss_citygml.update import update_map

CITY = Path(__file__).resolve().parents[1] / "examples" / "city"
DEM = str(CITY / "dem.tif")

#: The columns of a height, which a row without a converged estimate leaves empty.
HEIGHTS = ["height", "relative_height", "height_lower", "height_upper", "height_paper"]


@pytest.fixture(scope="module")
def halves(tmp_path_factory):
    """The sample city's observations in two batches: the first half of the walk, the rest."""
    folder = tmp_path_factory.mktemp("halves")
    obs = pd.read_parquet(CITY / "observations.parquet")
    time = pd.to_datetime(obs["time_utc"])
    early = (time < time.min() + (time.max() - time.min()) / 2).to_numpy()
    return _saved(obs[early], folder / "a.parquet"), _saved(obs[~early], folder / "b.parquet")


def _saved(table: pd.DataFrame, path: Path) -> Path:
    table.to_parquet(path)
    return path


@pytest.fixture(scope="module")
def estimated(tmp_path_factory, halves, grid_args):
    """`estimate`'s heights layer of the first batch, and that of both batches at once."""
    folder = tmp_path_factory.mktemp("estimated")
    both = _saved(pd.concat([pd.read_parquet(b) for b in halves], ignore_index=True),
                  folder / "both.parquet")  # fmt: skip
    for name, obs in (("first.gpkg", halves[0]), ("both.gpkg", both)):
        args = ["estimate", str(obs), str(CITY / "footprints.gpkg"), "--dem", DEM]
        with pytest.raises(SystemExit) as exc:
            main([*args, "-o", str(folder / name), *grid_args, "-q"])
        assert exc.value.code == 0
    return folder / "first.gpkg", folder / "both.gpkg"


def table(path: Path) -> pd.DataFrame:
    return pyogrio.read_dataframe(path, layer="heights", read_geometry=False).set_index("id")


def check_rows_agree(layer: pd.DataFrame, status: str, heights: list[str]) -> None:
    """Every row agrees with itself: converged <=> status ok <=> heights."""
    converged = layer["converged"].astype(bool)
    assert ((layer[status] == "ok") == converged).all()
    for column in heights:
        assert layer.loc[converged, column].notna().all(), column
        assert layer.loc[~converged, column].isna().all(), column


def test_estimates_own_layer_is_updated_whole(estimated, halves, grid_dir, tmp_path):
    first, both = estimated
    path = tmp_path / "heights.gpkg"
    shutil.copyfile(first, path)
    before = table(path)
    # estimate's layer has no evidence: the first batch is given again, with the second
    result = update_map(path, list(halves), DEM, grid_dir=grid_dir)
    after, full = table(path), table(both).loc[table(path).index]
    check_rows_agree(after, "status", HEIGHTS)
    check_rows_agree(after, "status_gnss", ["height_gnss"])
    was, now = before["converged"].astype(bool), after["converged"].astype(bool)
    assert (was & ~now).any() and (~was & now).any()  # rows lost and gained an estimate
    counts = f"{(~was & now).sum()} with a first height, {(was & ~now).sum()} without one now"
    assert counts in result.lines()[0]
    # the layer is that of one run over both halves, estimate's columns and the update's
    assert (now == full["converged"].astype(bool)).all()
    assert (after["status"] == full["status"]).all()
    for column in [*HEIGHTS, "a", "b", "c", "d", "iterations", "n_signals"]:
        np.testing.assert_allclose(after[column], full[column], rtol=0, atol=1e-9)
    np.testing.assert_allclose(after["height_gnss"], full["height"], rtol=0, atol=1e-9)
    np.testing.assert_allclose(after["relative_height"], after["height"] - after["ground"])


def test_convert_after_an_update_writes_only_the_new_heights(
    estimated, halves, grid_dir, tmp_path, capsys
):
    path = tmp_path / "heights.gpkg"
    shutil.copyfile(estimated[0], path)
    update_map(path, [halves[1]], DEM, grid_dir=grid_dir)
    after = table(path)
    out = tmp_path / "city.city.json"
    code, _, err = run(["convert", str(path), "-o", str(out)], capsys)
    assert code == 0, err
    objects = json.loads(out.read_text())["CityObjects"]
    heights = {k: v["attributes"]["height"] for k, v in objects.items() if v["type"] == "Building"}
    converged = after[after["converged"].astype(bool)]
    assert heights == pytest.approx(converged["height_gnss"].to_dict(), abs=1e-9)


def test_updates_one_after_another_keep_the_rows_agreeing(estimated, halves, grid_dir, tmp_path):
    """Updated with the second batch alone (which the change report says replaces the layer's
    heights from before), then with the first: the rows agree after each, and the same data
    again writes nothing."""
    path = tmp_path / "heights.gpkg"
    shutil.copyfile(estimated[0], path)
    result = update_map(path, [halves[1]], DEM, grid_dir=grid_dir)
    assert any("no evidence" in note for note in result.notes)
    check_rows_agree(table(path), "status", HEIGHTS)
    result = update_map(path, [halves[0]], DEM, grid_dir=grid_dir)
    assert result.written and not any("no evidence" in note for note in result.notes)
    check_rows_agree(table(path), "status", HEIGHTS)
    again = update_map(path, list(halves), DEM, grid_dir=grid_dir)
    assert not again.written and again.updated.empty


def test_a_map_of_the_users_columns_gets_only_the_updates(halves, grid_dir, tmp_path):
    """A map whose columns named like estimate's are the user's own (no relative_height or
    status beside them): the update writes its columns and leaves those alone; its own rows
    agree with themselves."""
    path = tmp_path / "map.gpkg"
    footprints = pyogrio.read_dataframe(CITY / "footprints.gpkg")
    footprints["height"] = 7.5  # the user's, say from a survey
    footprints["c"] = "block C"
    pyogrio.write_dataframe(footprints, path, layer="buildings")
    for batch in halves:
        update_map(path, [batch], DEM, layer="buildings", grid_dir=grid_dir)
        layer = pyogrio.read_dataframe(path, layer="buildings", read_geometry=False)
        assert (layer["height"] == 7.5).all() and (layer["c"] == "block C").all()
        check_rows_agree(layer, "status_gnss", ["height_gnss", "height_lower", "height_upper"])


def test_estimates_column_of_another_type_is_refused(estimated, halves, grid_dir, tmp_path):
    """Estimate's layer whose status is a number: refused before any work, not half written."""
    path = tmp_path / "heights.gpkg"
    shutil.copyfile(estimated[0], path)
    with sqlite3.connect(path) as db:
        db.execute("ALTER TABLE heights DROP COLUMN iterations")
        db.execute("ALTER TABLE heights ADD COLUMN iterations TEXT")
    with pytest.raises(InputError, match="iterations"):
        update_map(path, [halves[1]], DEM, grid_dir=grid_dir)


def test_the_ground_is_that_of_the_heights_after_an_update(estimated, halves, grid_dir, tmp_path):
    """Estimate's layer updated with another DEM (the ground 1 m higher): its ground is the
    one the new heights stand on, and relative_height is height - ground on every row."""
    import rasterio

    with rasterio.open(DEM) as src:
        profile, data = src.profile, src.read(1)
    dem = tmp_path / "dem.tif"
    with rasterio.open(dem, "w", **profile) as dst:
        dst.write(data + np.asarray(1.0, dtype=data.dtype), 1)
    path = tmp_path / "heights.gpkg"
    shutil.copyfile(estimated[0], path)
    before = table(path)
    update_map(path, list(halves), str(dem), grid_dir=grid_dir)
    after = table(path)
    np.testing.assert_allclose(after["ground"], before["ground"] + 1.0)
    np.testing.assert_allclose(after["relative_height"], after["height"] - after["ground"])


@pytest.mark.parametrize("dropped", [["relative_height"], ["relative_height", "a", "b", "d"]])
def test_estimates_layer_without_some_of_its_columns_is_updated_whole(
    estimated, halves, grid_dir, tmp_path, dropped
):
    """Estimate's layer from which the user dropped relative_height (and the fit's a, b, d):
    still estimate's (its iterations say so), so its height and status are the new fit's too,
    never converged 0 beside status ok and the old height (found at the command line: 11 rows
    so, which convert then wrote with their old heights)."""
    path = tmp_path / "heights.gpkg"
    shutil.copyfile(estimated[0], path)
    with sqlite3.connect(path) as db:
        for column in dropped:
            db.execute(f"ALTER TABLE heights DROP COLUMN {column}")
    update_map(path, [halves[1]], DEM, grid_dir=grid_dir)
    after = table(path)
    check_rows_agree(after, "status", [c for c in HEIGHTS if c not in dropped])
    converged = after["converged"].astype(bool)
    np.testing.assert_array_equal(
        after.loc[converged, "height"], after.loc[converged, "height_gnss"]
    )

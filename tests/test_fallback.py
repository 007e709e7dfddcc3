"""A height for every building: `convert --fallback-field` gives the buildings without a GNSS
height an attribute's, and every output says where each height came from."""

import json

import geopandas as gpd
import numpy as np
import pytest
import shapely
from test_cli import run

from gnss_citygml.errors import InputError
from gnss_citygml.export import buildings_with_heights, prepare_buildings


def heights_layer():
    """A heights layer as `estimate` writes it (absolute heights, relative_height beside
    them), with OS's relh2 (relative) among the footprints' attributes: two estimates
    converged, one did not, one has no relh2 either."""
    return gpd.GeoDataFrame(
        {
            "id": ["a", "b", "c", "d"],
            "ground": [20.0, 21.0, 22.0, 23.0],
            "height": [32.0, 30.5, np.nan, 40.0],
            "height_lower": [31.0, 29.5, np.nan, 35.0],
            "height_upper": [33.0, 31.5, np.nan, 45.0],
            "converged": [True, True, False, False],
            "status": ["ok", "ok", "no signal's ray enters the footprint", "flat likelihood"],
            "relative_height": [12.0, 9.5, np.nan, 17.0],
            "relh2": [11.5, 9.0, 7.25, np.nan],
        },
        geometry=[shapely.box(529000 + 20 * k, 181000, 529010 + 20 * k, 181010) for k in range(4)],
        crs="EPSG:27700",
    )


def test_the_fallback_fills_only_the_buildings_without_an_estimate():
    out = buildings_with_heights(heights_layer(), fallback_field="relh2", fallback_relative=True)
    assert out["height_source"].tolist() == ["gnss", "gnss", "relh2", "gnss"]
    assert out["height"].tolist()[:3] == [32.0, 30.5, 22.0 + 7.25]
    assert np.isnan(out.loc[2, "height_lower"]) and out.loc[0, "height_lower"] == 31.0
    assert out.loc[3, "height"] == 40.0  # not converged, and no relh2: left as it was


def test_without_a_fallback_nothing_changes():
    layer = heights_layer()
    out = buildings_with_heights(layer)
    assert "height_source" not in out.columns
    assert out["height"].equals(layer["height"])


def test_relative_is_refused_for_the_absolute_heights_of_a_heights_layer(tmp_path, capsys):
    layer = tmp_path / "h.gpkg"
    heights_layer().to_file(layer, layer="heights")
    code, _, err = run(
        ["convert", str(layer), "--relative", "-o", str(tmp_path / "c.json")], capsys
    )
    assert code == 2 and "'height' holds absolute heights (m ODN)" in err
    assert "--fallback-relative" in err and not (tmp_path / "c.json").exists()


def test_every_output_carries_each_height_source(tmp_path, capsys):
    layer = tmp_path / "h.gpkg"
    heights_layer().to_file(layer, layer="heights")
    options = ["--fallback-field", "relh2", "--fallback-relative"]
    code, _, err = run(["convert", str(layer), *options, "-o", str(tmp_path / "c.city.json")],
                       capsys)  # fmt: skip
    assert code == 0, err
    objects = json.loads((tmp_path / "c.city.json").read_text())["CityObjects"]
    sources = {k: v["attributes"]["height_source"] for k, v in objects.items()}
    assert sources == {"a": "gnss", "b": "gnss", "c": "relh2"}  # d: no height at all
    code, _, err = run(["convert", str(layer), *options, "-o", str(tmp_path / "c.gml")], capsys)
    assert code == 0, err
    gml = (tmp_path / "c.gml").read_text()
    assert gml.count('name="height_source"') == 3 and "<gen:value>relh2</gen:value>" in gml
    tileset = tmp_path / "tiles" / "tileset.json"
    code, _, err = run(["convert", str(layer), *options, "-o", str(tileset), "--no-validate"],
                       capsys)  # fmt: skip
    assert code == 0, err
    glb = (tileset.parent / "tiles" / "TQ2981.glb").read_bytes()
    table = json.loads(glb[20 : 20 + int.from_bytes(glb[12:16], "little")])
    schema = table["extensions"]["EXT_structural_metadata"]["schema"]
    assert schema["classes"]["building"]["properties"]["height_source"] == {"type": "STRING"}


def updated_map():
    """An OS map that `update` wrote into (height_gnss, absolute, and its converged), with OS's
    relh2 (relative) and abshmax (absolute): a converged GNSS roof at 28.39 m ODN, one fit that
    did not converge, one building without any GNSS estimate."""
    return gpd.GeoDataFrame(
        {
            "id": ["a", "b", "c"],
            "ground": [20.0, 21.0, 22.0],
            "relh2": [np.nan, 9.0, 7.25],
            "abshmax": [29.0, np.nan, 30.0],
            "height_gnss": [28.39, np.nan, np.nan],
            "height_lower": [27.5, np.nan, np.nan],
            "height_upper": [29.5, np.nan, np.nan],
            "c_gnss": [28.1, 35.0, np.nan],
            "converged": [True, False, None],
            "status_gnss": ["ok", "flat likelihood", None],
            "method": ["4PL-B", "4PL-B", None],
        },
        geometry=[shapely.box(529000 + 20 * k, 181000, 529010 + 20 * k, 181010) for k in range(3)],
        crs="EPSG:27700",
    )


def test_each_fields_reference_is_its_own():
    """The GNSS height is absolute and the fallback relative: only the fallback gets the ground
    added (the GNSS roof at 28.39 m ODN was written at 48.39 m)."""
    out = buildings_with_heights(
        updated_map(), "height_gnss", fallback_field="relh2", fallback_relative=True
    )
    assert out["height"].tolist() == [28.39, 21.0 + 9.0, 22.0 + 7.25]
    assert out["height_source"].tolist() == ["gnss", "relh2", "relh2"]
    assert out["method"].tolist() == ["4PL-B"] + ["attribute relh2 + ground"] * 2
    # the other way round: a relative height field, an absolute GNSS fallback
    out = buildings_with_heights(
        updated_map(), "relh2", relative=True, fallback_field="height_gnss"
    )
    assert out["height"].tolist()[0] == 28.39 and out["height_source"][0] == "height_gnss"
    # the heights layer's relative_height is above the ground, said or not
    out = buildings_with_heights(heights_layer().drop(columns="height"), "relative_height")
    assert out["height"].tolist()[:2] == [32.0, 30.5]


def fits_only():
    """The heights layer without its height column (so that another field can be the height
    field)."""
    return heights_layer().drop(columns="height")


@pytest.mark.parametrize(
    ("layer", "field", "options", "switch"),
    [
        (updated_map, "height_gnss", {"relative": True, "fallback_field": "relh2"}, "--relative"),
        (updated_map, "relh2", {"relative": True, "fallback_field": "c_gnss",
                                "fallback_relative": True}, "--fallback-relative"),
        (heights_layer, "height", {"relative": True}, "--relative"),
        (fits_only, "relh2", {"relative": True, "fallback_field": "height_upper",
                              "fallback_relative": True}, "--fallback-relative"),
        (lambda: fits_only().assign(c=30.0), "c", {"relative": True}, "--relative"),
    ],
)  # fmt: skip
def test_a_field_said_relative_that_the_layer_says_is_absolute_is_refused(
    layer, field, options, switch
):
    with pytest.raises(InputError, match="holds absolute heights") as caught:
        buildings_with_heights(layer(), field, **options)
    assert caught.value.fix.startswith(f"leave out {switch} ")


def test_an_unconverged_fit_never_comes_back_through_the_fallback():
    """A fit parameter taken as the height (c), with a fallback that has nothing for the
    building whose fit did not converge: that building is left out as it is without the
    fallback; nor does a GNSS field as the fallback bring an unconverged fit back."""
    layer = fits_only().assign(c=[32.5, 30.0, 51.0, 44.0], relh2=np.nan)
    without = prepare_buildings(buildings_with_heights(layer, "c"))
    with_empty = prepare_buildings(buildings_with_heights(layer, "c", fallback_field="relh2"))
    assert dict(with_empty.skipped) == dict(without.skipped)
    assert set(dict(without.skipped)) == {"c", "d"}
    empty = updated_map().assign(relh2=np.nan, abshmax=np.nan)
    for field, fallback in (("c_gnss", "relh2"), ("abshmax", "c_gnss"), ("relh2", "c_gnss")):
        plan = prepare_buildings(buildings_with_heights(empty, field, fallback_field=fallback))
        assert "b" in dict(plan.skipped) and plan.frame["id"][plan.rows].tolist() == ["a"]


def test_a_gnss_fit_does_not_decide_for_another_field():
    """abshmax on a map that update wrote into: a building whose GNSS fit did not converge
    still has its abshmax, and no GNSS interval is drawn around it."""
    out = buildings_with_heights(updated_map(), "abshmax")
    plan = prepare_buildings(out)
    assert dict(plan.skipped) == {"b": "no height"}
    assert out["height_source"].tolist() == ["abshmax"] * 3
    assert out["method"].tolist() == ["attribute abshmax"] * 3  # not the fit's 4PL-B
    assert out["height_lower"].isna().all() and out["height_upper"].isna().all()


@pytest.mark.parametrize("field", ["gnss", "Height", "height "])
def test_a_fallback_field_that_is_not_there_is_named(field, tmp_path, capsys):
    layer = tmp_path / "h.gpkg"
    heights_layer().to_file(layer, layer="heights")
    out = tmp_path / "c.city.json"
    code, _, err = run(["convert", str(layer), "--fallback-field", field, "-o", str(out)], capsys)
    assert code == 2 and repr(field) in err and "relh2" in err and not out.exists()


def test_the_height_field_as_its_own_fallback_is_refused():
    with pytest.raises(InputError, match="the fallback field is the height field"):
        buildings_with_heights(updated_map(), "relh2", relative=True, fallback_field="relh2")


def test_the_command_line_says_each_fields_reference(tmp_path, capsys):
    """convert --relative with an absolute height field and a relative fallback: refused,
    naming --fallback-relative; with it, the GNSS roof stays at 28.39 m."""
    layer = tmp_path / "map.gpkg"
    updated_map().to_file(layer, layer="buildings")
    out = tmp_path / "c.city.json"
    common = ["convert", str(layer), "--height-field", "height_gnss", "--fallback-field", "relh2"]
    code, _, err = run([*common, "--relative", "-o", str(out)], capsys)
    assert code == 2 and "--fallback-relative" in err and not out.exists()
    code, _, err = run([*common, "--fallback-relative", "-o", str(out)], capsys)
    assert code == 0, err
    objects = json.loads(out.read_text())["CityObjects"]
    assert objects["a"]["attributes"]["height"] == 28.39
    assert objects["b"]["attributes"]["height"] == 30.0


def _flat_dem(path, level: float):
    """A flat DEM at ``level`` m ODN under heights_layer's footprints."""
    import rasterio
    from rasterio.transform import from_origin

    profile = dict(driver="GTiff", width=40, height=10, count=1, dtype="float32",
                   crs="EPSG:27700", transform=from_origin(528950, 181030, 5, 5))  # fmt: skip
    with rasterio.open(path, "w", **profile) as dst:
        dst.write(np.full((1, 10, 40), level, dtype="float32"))
    return path


def test_a_dem_beside_the_heights_own_ground_is_refused(tmp_path, capsys):
    """The heights stand on their ground column (estimate's DEM's): another DEM's ground
    would change each building's height above it and leave relative_height saying the old one
    (found at the command line: measuredHeight 3.39 beside relative_height 8.39). Convert of a
    heights layer and export of a heights table alike refuse a DEM then, and take it without
    the column."""
    layer, dem = tmp_path / "heights.gpkg", _flat_dem(tmp_path / "dem.tif", 25.0)
    heights_layer().to_file(layer, layer="heights")
    table = tmp_path / "heights.csv"
    heights_layer().drop(columns="geometry").to_csv(table, index=False)
    footprints = tmp_path / "footprints.gpkg"
    heights_layer()[["id", "geometry"]].to_file(footprints, layer="footprints")
    out = tmp_path / "c.city.json"
    for args in (["convert", str(layer)], ["export", str(table), "--footprints", str(footprints)]):
        code, _, err = run([*args, "--dem", str(dem), "-o", str(out)], capsys)
        assert code == 2 and "the ground is given twice" in err and not out.exists(), err
    heights_layer().drop(columns=["ground", "relative_height"]).to_csv(table, index=False)
    code, _, err = run([*args, "--dem", str(dem), "-o", str(out)], capsys)
    assert code == 0, err
    objects = json.loads(out.read_text())["CityObjects"]
    assert objects["a"]["attributes"]["ground"] == 25.0
    assert objects["a"]["attributes"]["measuredHeight"] == 7.0


def test_the_dem_the_heights_stand_on_may_be_given_again(tmp_path, capsys):
    """A DEM that gives every building the ground of its column (the DEM the heights were
    estimated on) changes nothing and is taken; one building's ground off by 5 cm is refused,
    naming how many differ."""
    dem = _flat_dem(tmp_path / "dem.tif", 25.0)
    layer, out = tmp_path / "heights.gpkg", tmp_path / "c.city.json"
    same = heights_layer().assign(ground=25.0)
    same.to_file(layer, layer="heights")
    code, _, err = run(["convert", str(layer), "--dem", str(dem), "-o", str(out)], capsys)
    assert code == 0, err
    assert json.loads(out.read_text())["CityObjects"]["a"]["attributes"]["ground"] == 25.0
    same.assign(ground=[25.0, 25.05, 25.0, 25.0]).to_file(tmp_path / "off.gpkg", layer="heights")
    args = ["convert", str(tmp_path / "off.gpkg"), "--dem", str(dem), "-o", str(tmp_path / "d.gml")]
    code, _, err = run(args, capsys)
    assert code == 2 and "differ for 1 of 4 buildings (by up to 0.05 m)" in err, err


@pytest.mark.parametrize("column", ["height_source", "method"])
def test_a_users_column_named_like_the_sources_is_not_overwritten(column):
    """A layer with a column of its own named height_source or method (a survey's, say), given
    a fallback: the tool's height_source and method (where each height came from) would
    overwrite it, so it is refused naming the column (found at the command line: 'survey
    2019' and 'lidar' became 'height' and 'attribute height')."""
    frame = heights_layer().drop(columns=["converged", "status", "relative_height"])
    frame[column] = "survey 2019"
    with pytest.raises(InputError, match=f"the layer has a column '{column}'"):
        buildings_with_heights(frame, "height", fallback_field="relh2", fallback_relative=True)
    kept = buildings_with_heights(frame, "height")  # (no fallback: nothing to say, kept)
    assert (kept[column] == "survey 2019").all()


@pytest.mark.parametrize("column", ["ground", "height", "status"])
def test_footprints_with_a_column_of_the_heights_table_are_refused(tmp_path, capsys, column):
    """Footprints with a column of their own named like one of the heights table's: their
    ground won silently over the table's (found at the command line: ground 0 and
    measuredHeight 28.39 beside relative_height 8.39), their height made height_x and height_y
    and a message naming neither. Refused naming the column."""
    table = tmp_path / "heights.csv"
    heights_layer().drop(columns="geometry").to_csv(table, index=False)
    footprints = tmp_path / "footprints.gpkg"
    heights_layer()[["id", "geometry"]].assign(**{column: 0.0}).to_file(footprints)
    out = tmp_path / "c.city.json"
    code, _, err = run(
        ["export", str(table), "--footprints", str(footprints), "-o", str(out)], capsys
    )
    assert code == 2 and f"'{column}'" in err and "both" in err and not out.exists(), err

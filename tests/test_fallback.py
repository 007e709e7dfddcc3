"""A height for every building: `convert --fallback-field` gives the buildings without a GNSS
height an attribute's, and every output says where each height came from."""

import json

import geopandas as gpd
import numpy as np
import shapely
from test_cli import run

from gnss_citygml.export.plan import buildings_with_heights


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
    out = buildings_with_heights(heights_layer(), fallback_field="relh2", relative=True)
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
    assert code == 2 and "the heights layer's heights are absolute" in err
    assert not (tmp_path / "c.json").exists()


def test_every_output_carries_each_height_source(tmp_path, capsys):
    layer = tmp_path / "h.gpkg"
    heights_layer().to_file(layer, layer="heights")
    options = ["--fallback-field", "relh2", "--relative"]
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

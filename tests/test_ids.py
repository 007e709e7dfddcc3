"""The footprints' id field keeps its own name in every output, so that results join back to
the source (OS MasterMap by TOID): read_footprints records the name, estimate returns it, the
layer, CityJSON and CityGML writers write it, convert and export read it back.

The user's side runs the commands on a simulated site whose footprints carry their ids in a
``toid`` column (one of them not a valid XML name, so that CityGML writes it as an attribute).
"""

import json

import geopandas as gpd
import pandas as pd
import pyogrio
import pytest
import shapely
from lxml import etree
from test_cli import run

from gnss_citygml.cli import main
from gnss_citygml.errors import InputError, escape_controls
from gnss_citygml.export import write_citygml, write_cityjson
from gnss_citygml.files.ids import id_field, id_named, source_named, with_id_field
from gnss_citygml.files.tables import write_layer
from gnss_citygml.footprints import read_footprints
from gnss_citygml.observations import read_observations
from gnss_citygml.pipeline import estimate

BOXES = [shapely.box(529500, 182300, 529510, 182308), shapely.box(529520, 182300, 529530, 182308)]
#: The simulated site's buildings and the TOIDs they get here; "1000000000001" starts with a
#: digit, so its gml:id is "id_1000000000001" and the TOID goes in a `toid` attribute.
TOIDS = {
    "hermitage_terrace": "1000000000001",
    "across_terrace": "osgb1000000000002",
    "behind_terrace": "osgb1000000000003",
}
GML = {"gml": "http://www.opengis.net/gml", "gen": "http://www.opengis.net/citygml/generics/2.0"}


def layer(path, **columns):
    """Two footprints with the given attributes (two values each)."""
    gpd.GeoDataFrame(columns, geometry=BOXES, crs="EPSG:27700").to_file(path)
    return path


@pytest.mark.parametrize(
    ("name", "columns", "chosen", "kept", "ids"),
    [
        ("toid.gpkg", {"toid": ["a", "b"]}, None, "toid", ["a", "b"]),
        ("upper.gpkg", {"TOID": ["a", "b"]}, None, "TOID", ["a", "b"]),  # its own spelling
        ("id.gpkg", {"id": ["a", "b"]}, None, "id", ["a", "b"]),
        ("ref.gpkg", {"ref": ["a", "b"], "toid": ["x", "y"]}, "ref", "ref", ["a", "b"]),
        # GDAL's name for the feature id, which a GeoPackage cannot hold as text
        ("fid.geojson", {"fid": ["a", "b"]}, None, "id", ["a", "b"]),
        ("none.gpkg", {"storeys": [2, 3]}, None, "id", ["1", "2"]),  # feature ids
    ],
)
def test_the_layer_written_names_the_id_like_its_source(tmp_path, name, columns, chosen, kept, ids):
    frame = read_footprints(layer(tmp_path / name, **columns), id_field=chosen)
    assert frame["id"].tolist() == ids and id_field(frame) == kept  # the stages see `id`
    write_layer(frame, tmp_path / "out.gpkg", "buildings")
    written = pyogrio.read_dataframe(tmp_path / "out.gpkg")
    assert kept in written.columns and (kept == "id" or "id" not in written.columns)
    back = read_footprints(tmp_path / "out.gpkg", id_field=chosen)
    assert list(back["id"]) == list(frame["id"]) and id_field(back) == kept
    if chosen == "ref":
        assert written["toid"].tolist() == ["x", "y"]  # another field stays an attribute


def test_mastermap_ids_are_named_toid(shared_data):
    frame = read_footprints(shared_data / "footprints" / "mastermap-topo_3473984_0.gml")
    assert id_field(frame) == "toid"  # GDAL reads TOIDs as `fid`, which a GeoPackage reserves


def test_a_name_taken_by_another_column_is_an_error():
    table = with_id_field(pd.DataFrame({"id": ["a"], "toid": ["b"]}), "toid")
    with pytest.raises(InputError, match="column 'id' besides its id field 'toid'"):
        source_named(table)
    with pytest.raises(InputError, match="column 'id' besides its id field 'toid'"):
        id_named(table)


@pytest.fixture(scope="module")
def site(grid_args, tmp_path_factory):
    """A simulated site, its footprints with TOIDs in `toid`, and their heights.gpkg."""
    folder = tmp_path_factory.mktemp("site")
    args = ["simulate", "hermitage", "-o", folder, "--interval", "60", *grid_args]
    with pytest.raises(SystemExit) as exc:
        main([str(a) for a in args])
    assert exc.value.code == 0
    footprints = gpd.read_file(folder / "footprints.gpkg")
    footprints.insert(0, "toid", footprints.pop("id").map(TOIDS))
    footprints.to_file(folder / "toids.gpkg")
    return folder, grid_args


def estimate_args(site, output, *extra):
    folder, grid_args = site
    return [
        *("estimate", str(folder / "observations.csv"), str(folder / "toids.gpkg")),
        *("--dem", str(folder / "dem.tif"), *grid_args, "-q", "-o", str(output)),
        *extra,
    ]


@pytest.fixture(scope="module")
def heights(site):
    """``estimate`` on the footprints with TOIDs: heights.gpkg."""
    path = site[0] / "heights.gpkg"
    with pytest.raises(SystemExit) as exc:
        main(estimate_args(site, path))
    assert exc.value.code == 0
    return path


def test_estimate_writes_a_toid_column_in_every_layer_format(site, heights, tmp_path, capsys):
    layers = {".gpkg": heights}
    for suffix, extra in ((".fgb", ["--id-field", "toid"]), (".parquet", [])):
        layers[suffix] = tmp_path / f"heights{suffix}"
        code, out, err = run(estimate_args(site, layers[suffix], *extra), capsys)
        assert code == 0, err
    for suffix, path in layers.items():
        if suffix == ".parquet":
            table = gpd.read_parquet(path)
        else:
            table = gpd.read_file(path, layer="heights")
        assert "id" not in table.columns, suffix
        assert sorted(table["toid"]) == sorted(TOIDS.values()), suffix
        assert table["converged"].sum() >= 1


def converged_toids(heights):
    table = gpd.read_file(heights, layer="heights")
    return sorted(table["toid"][table["converged"]])


def city_ids(path):
    """The building ids in a CityJSON, CityJSONSeq or CityGML file, and the CityGML `toid`
    attributes (gml:id -> value)."""
    if path.suffix == ".gml":
        tree = etree.parse(path)
        buildings = tree.findall(".//{*}Building")
        ids = [b.get(f"{{{GML['gml']}}}id") for b in buildings]
        toids = {
            b.get(f"{{{GML['gml']}}}id"): b.findtext(
                "gen:stringAttribute[@name='toid']/gen:value", namespaces=GML
            )
            for b in buildings
        }
        names = {a.get("name") for a in tree.findall(".//gen:stringAttribute", GML)}
        assert "id" not in names
        return sorted(ids), {k: v for k, v in toids.items() if v is not None}
    if path.suffix == ".jsonl":
        features = [json.loads(line) for line in path.read_text().splitlines()[1:]]
        objects = {k: v for f in features for k, v in f["CityObjects"].items()}
        assert sorted(f["id"] for f in features) == sorted(objects)
    else:
        objects = json.loads(path.read_text())["CityObjects"]
    for obj in objects.values():
        assert not {"id", "toid"} & set(obj.get("attributes", {}))  # the key is the id
    return sorted(objects), {}


def expected_city_ids(heights, suffix):
    toids = converged_toids(heights)
    if suffix != ".gml":
        return toids, {}
    changed = {t: t if t.startswith("osgb") else f"id_{t}" for t in toids}
    return sorted(changed.values()), {g: t for t, g in changed.items() if g != t}


@pytest.mark.parametrize("name", ["city.city.json", "city.city.jsonl", "city.gml"])
def test_convert_keeps_the_toids(heights, tmp_path, capsys, name):
    """The round trip estimate -> convert: the heights layer's `toid` column is found (as
    read_footprints finds it, and with --id-field) and the city model keeps the TOIDs."""
    want = expected_city_ids(heights, (tmp_path / name).suffix)
    assert "1000000000001" in converged_toids(heights)  # the TOID that is not an XML name
    for extra in ([], ["--id-field", "toid"]):
        path = tmp_path / name
        code, _, err = run(
            ["convert", str(heights), "-o", str(path), "--overwrite", *extra], capsys
        )
        assert code == 0, err
        assert city_ids(path) == want


def test_convert_with_a_dem_keeps_the_toid_attribute(site, heights, tmp_path, capsys):
    path = tmp_path / "city.gml"
    args = ["convert", str(heights), "--dem", str(site[0] / "dem.tif"), "-o", str(path)]
    code, _, err = run(args, capsys)
    assert code == 0, err
    assert city_ids(path) == expected_city_ids(heights, ".gml")


@pytest.mark.parametrize("name", ["city.city.json", "city.city.jsonl", "city.gml"])
def test_export_joins_a_heights_table_by_toid(site, heights, tmp_path, capsys, name):
    """A heights table with the TOIDs in `toid` (estimate's layer as CSV) or in `id` (as
    `heights` writes them) joins to the footprints, and the model keeps the TOIDs."""
    table = pd.DataFrame(gpd.read_file(heights, layer="heights").drop(columns="geometry"))
    want = expected_city_ids(heights, (tmp_path / name).suffix)
    for column, extra in (("toid", []), ("toid", ["--id-field", "toid"]), ("id", [])):
        csv = tmp_path / "h.csv"
        table.rename(columns={"toid": column}).to_csv(csv, index=False)
        path = tmp_path / name
        args = ["export", str(csv), "--footprints", str(site[0] / "toids.gpkg"), *extra]
        code, _, err = run([*args, "-o", str(path), "--overwrite"], capsys)
        assert code == 0, err
        assert city_ids(path) == want
    table.assign(id=table["toid"]).to_csv(csv, index=False)
    code, _, err = run([*args, "-o", str(path), "--overwrite"], capsys)
    assert code == 2 and "column 'id' besides its id field 'toid'" in err and str(csv) in err


def test_python_estimate_returns_a_toid_column(site, grid_dir, tmp_path):
    folder, _ = site
    footprints = read_footprints(folder / "toids.gpkg", id_field="toid")
    obs = read_observations(folder / "observations.csv")
    heights = estimate(obs, footprints, str(folder / "dem.tif"), grid_dir=grid_dir)
    assert "id" not in heights.columns and sorted(heights["toid"]) == sorted(TOIDS.values())
    ok = sorted(heights["toid"][heights["converged"]])
    # the writers take it as it is
    write_cityjson(heights, tmp_path / "c.city.json")
    assert city_ids(tmp_path / "c.city.json") == (ok, {})
    write_citygml(heights, tmp_path / "c.gml")
    assert city_ids(tmp_path / "c.gml")[1] == {"id_1000000000001": "1000000000001"}


def test_a_heights_table_without_the_id_names_it(site, tmp_path, capsys):
    csv = tmp_path / "h.csv"
    pd.DataFrame({"building": ["x"], "height": [30.0]}).to_csv(csv, index=False)
    args = ["export", str(csv), "--footprints", str(site[0] / "toids.gpkg")]
    code, _, err = run([*args, "-o", str(tmp_path / "c.city.json")], capsys)
    assert code == 2 and "missing column(s) 'toid'" in err


def test_id_field_fid_is_the_feature_id(tmp_path):
    """QGIS lists a GeoPackage's feature id as a field "fid": naming it is the feature id."""
    from pathlib import Path

    from gnss_citygml.footprints import read_footprints

    frame = pyogrio.read_dataframe(
        Path(__file__).resolve().parents[1] / "examples/city/footprints.gpkg"
    )
    pyogrio.write_dataframe(frame.drop(columns="id"), tmp_path / "f.gpkg")
    named = read_footprints(tmp_path / "f.gpkg", id_field="fid")
    assert named["id"].tolist() == read_footprints(tmp_path / "f.gpkg")["id"].tolist()
    assert named["id"].iloc[0] == "1"


# --- ids in messages, and ids that are no ids (issue 26) -------------------------------------

#: Ids that could forge or garble a line of output: a line end followed by a fake error, a
#: tab, a carriage return, an ANSI colour, the Unicode line separator, a bidi override.
TAMPERED = ["a\nerror: forged", "b\tc", "d\re", "\x1b[31mred", "f\u2028g", "h\u202eevil"]


@pytest.mark.parametrize("tampered", TAMPERED)
def test_an_id_is_shown_escaped_in_every_message(tmp_path, capsys, tampered):
    # a skipped building's line, an error listing ids and a warning listing ids
    boxes = [*BOXES, shapely.box(529540, 182300, 529550, 182308)]
    table = gpd.GeoDataFrame(
        {"id": [tampered, "ok", "tall"], "ground": [20.0, 20, 20], "height": [1e9, 30, 30]},
        geometry=boxes,
        crs="EPSG:27700",
    )
    source = tmp_path / "heights.gpkg"
    table.to_file(source, layer="heights", driver="GPKG")
    code, _, err = run(["convert", str(source), "-o", str(tmp_path / "c.city.json")], capsys)
    assert code == 0, err
    twice = table.assign(id=[tampered, tampered, "x"]).rename(columns={"id": "toid"})
    twice.to_file(tmp_path / "twice.gpkg", driver="GPKG")
    code2, _, err2 = run(["convert", str(tmp_path / "twice.gpkg"), "-o", "-"], capsys)
    assert code2 == 2
    corners = [(529500, 182300), (529510, 182310), (529510, 182300), (529500, 182310)]
    bowtie = shapely.Polygon(corners)
    table.assign(geometry=[bowtie, *boxes[1:]]).to_file(tmp_path / "bow.gpkg", driver="GPKG")
    with pytest.warns(UserWarning) as caught:
        read_footprints(tmp_path / "bow.gpkg")
    warned = str(caught[0].message)
    for text in (err, err2, warned):
        assert escape_controls(tampered) in text, text
        assert all(ch not in text for ch in "\t\r\x1b\u2028\u202e"), text
    said = [line for line in err.splitlines() if not line.startswith("note: ")]
    assert len(said) == 1 and err.startswith("skipped "), err  # (notes: what was checked)
    assert len(err2.splitlines()) == 1 and err2.startswith("error: "), err2


def test_a_long_id_is_cut_in_messages(tmp_path):
    long = "x" * 5000
    path = tmp_path / "long.gpkg"
    frame = gpd.GeoDataFrame({"toid": [long, long]}, geometry=BOXES, crs="EPSG:27700")
    frame.to_file(path, driver="GPKG")
    with pytest.raises(InputError) as caught:
        read_footprints(path)
    assert "... (5000 characters)" in str(caught.value) and len(str(caught.value)) < 400


@pytest.mark.parametrize("blank", ["", " ", "\t ", "\u3000", "a\x00b"])
def test_blank_ids_and_ids_with_a_nul_are_refused_like_missing_ones(tmp_path, blank):
    # GeoParquet keeps a NUL (GDAL would cut the id there: "a\0b" would become "a")
    frame = gpd.GeoDataFrame({"toid": ["ok", blank]}, geometry=BOXES, crs="EPSG:27700")
    frame.to_parquet(tmp_path / "f.parquet")
    with pytest.raises(InputError, match=r"1 feature\(s\) without an id .* in 'toid': rows 1"):
        read_footprints(tmp_path / "f.parquet")
    if "\x00" not in blank:
        frame.to_file(tmp_path / "f.gpkg", driver="GPKG")
        with pytest.raises(InputError, match=r"without an id .* in 'toid': rows 1"):
            read_footprints(tmp_path / "f.gpkg")
    # a heights table handed to convert: the same rule
    heights = frame.rename(columns={"toid": "id"}).assign(ground=20.0, height=30.0)
    with pytest.raises(InputError, match=r"1 building\(s\) without an id .*rows 1"):
        write_cityjson(heights, tmp_path / "c.city.json")

"""Footprints (GeoPackage, MasterMap GML, any polygon layer): ids, CRS and geometry checks, on
real files.

Synthetic footprints are written to ``tmp_path`` with geopandas; the real OS MasterMap tile is
read in place from the shared data folder.
"""

import gzip
import subprocess
import sys

import geopandas as gpd
import numpy as np
import pytest
import shapely

from gnss_citygml.errors import InputError, MissingColumnError
from gnss_citygml.footprints import read_footprints
from gnss_citygml.geodesy import CrsError, OutsideExtentError, from_osgb

BNG = "EPSG:27700"

# The canonical footprints (BNG, inside the synthetic DEM of test_terrain.py; no edge passes
# through a cell centre: the centres have odd coordinates).
SQUARE = shapely.box(500100.0, 200300.0, 500140.0, 200330.0)
COURTYARD = shapely.Polygon(
    [(500200, 200400), (500260, 200400), (500260, 200460), (500200, 200460)],
    [[(500220, 200420), (500240, 200420), (500240, 200440), (500220, 200440)]],
)
BOWTIE = shapely.Polygon(
    [(500300.4, 200500), (500340.4, 200540), (500340.4, 200500), (500300.4, 200540)]
)
TWO_PARTS = shapely.MultiPolygon(
    [shapely.box(500400, 200600, 500420, 200620), shapely.box(500440, 200600, 500460, 200630)]
)


def write_footprints(folder):
    """A GeoPackage: a square, one with a courtyard, a bow-tie and a multipolygon."""
    path = folder / "footprints.gpkg"
    frame = gpd.GeoDataFrame(
        {"toid": ["sq", "court", "bow", "multi"], "storeys": [2, 5, 1, 3]},
        geometry=[SQUARE, COURTYARD, BOWTIE, TWO_PARTS],
        crs=BNG,
    )
    frame.to_file(path, layer="buildings")
    return path


def test_geopackage_footprints_repaired_with_a_warning(tmp_path):
    with pytest.warns(UserWarning, match=r"repaired 1 invalid footprint\(s\).*bow"):
        b = read_footprints(write_footprints(tmp_path))
    assert b.crs == BNG
    assert list(b.columns) == ["id", "storeys", "geometry"]
    assert b["id"].tolist() == ["sq", "court", "bow", "multi"]
    assert b["storeys"].tolist() == [2, 5, 1, 3]
    assert b.geometry.is_valid.all()
    assert set(b.geom_type) == {"MultiPolygon"}  # as the GeoPackage layer stores them
    # the courtyard keeps its hole, the bow-tie becomes its two triangles (2 x 400 m2)
    assert b.geometry[1].area == pytest.approx(60 * 60 - 20 * 20)
    assert not b.geometry[1].contains(shapely.Point(500230, 200430))
    assert b.geometry[2].geom_type == "MultiPolygon"
    assert b.geometry[2].area == pytest.approx(800.0)
    assert b.geometry[3].equals(TWO_PARTS)


def test_id_rules(tmp_path):
    path = tmp_path / "ids.gpkg"
    frame = gpd.GeoDataFrame(
        {"name": ["x", "y"], "ref": [7.0, 8.0]}, geometry=[SQUARE, TWO_PARTS], crs=BNG
    )
    frame.to_file(path)
    # no toid/id/fid column: the GeoPackage feature id (1, 2, ...)
    assert read_footprints(path)["id"].tolist() == ["1", "2"]
    chosen = read_footprints(path, id_field="ref")
    assert chosen["id"].tolist() == ["7", "8"]  # integral floats as integers
    assert list(chosen.columns) == ["id", "name", "geometry"]  # the id field moved to `id`
    with pytest.raises(MissingColumnError, match=r"'toid'.*name, ref"):
        read_footprints(path, id_field="toid")


def test_footprints_in_wgs84_are_transformed_with_ostn15(tmp_path, grid_dir):
    """Made from BNG with OSTN15, back to within 1 mm (fresh interpreters, the commands and
    ETRS89 / UTM: tests/test_geodesy.py)."""
    building = shapely.box(529540.0, 182290.0, 529560.0, 182305.0)  # by the London GNSS log
    xy = shapely.get_coordinates(building)
    lat, lon, _ = from_osgb(xy[:, 0], xy[:, 1], 0.0, grid_dir=grid_dir)
    path = write_layer(
        tmp_path / "wgs84.gpkg", [shapely.Polygon(np.column_stack([lon, lat]))],
        crs="EPSG:4326", toid=["ucl"],
    )  # fmt: skip
    b = read_footprints(path, grid_dir=grid_dir)
    assert b.crs == BNG and b["id"].tolist() == ["ucl"]
    assert np.abs(shapely.get_coordinates(b.geometry[0]) - xy).max() < 1e-3


def test_footprints_on_another_datum_are_refused(tmp_path, grid_dir):
    """PROJ would move ED50 footprints by its 2 m Helmert transformation: an error instead."""
    square = shapely.box(300000.0, 5700000.0, 300020.0, 5700020.0)
    path = write_layer(tmp_path / "ed50.gpkg", [square], crs="EPSG:23030", toid=["a"])
    with pytest.raises(CrsError, match=r"no exact transformation from ED50 / UTM zone 30N") as info:
        read_footprints(path, grid_dir=grid_dir)
    assert f"({path}, layer ed50: EPSG:23030)" in str(info.value)


def test_footprints_outside_the_grids_are_named_by_id(tmp_path, grid_dir):
    in_gb = shapely.box(-0.1342, 51.5246, -0.1340, 51.5248)
    brest = shapely.box(-4.49, 48.39, -4.48, 48.40)
    path = write_layer(
        tmp_path / "far.gpkg", [in_gb, brest, in_gb], crs="EPSG:4326", toid=["ucl", "brest", "x"]
    )
    with pytest.raises(OutsideExtentError, match=r"^5 point\(s\) outside") as info:
        read_footprints(path, grid_dir=grid_dir)
    assert info.value.where == f"{path}, layer far: footprint brest (lat 48.390000, lon -4.480000)"


def test_bng_bound_to_wgs84_is_bng(tmp_path):
    """A PROJ string's +towgs84 (a Helmert to WGS 84) does not move BNG footprints."""
    bound = (
        "+proj=tmerc +lat_0=49 +lon_0=-2 +k=0.9996012717 +x_0=400000 +y_0=-100000 +ellps=airy "
        "+towgs84=446.448,-125.157,542.06,0.15,0.247,0.842,-20.489 +units=m +no_defs"
    )
    path = write_layer(tmp_path / "bound.gpkg", [SQUARE], crs=bound, toid=["sq"])
    assert gpd.read_file(path).crs.is_bound
    b = read_footprints(path, grid_dir="/nonexistent")  # no grid is needed
    assert b.crs == BNG and b.geometry[0].equals(SQUARE)


def test_mastermap_tile(shared_data):
    folder = shared_data / "footprints"
    before = sorted(p.name for p in folder.iterdir())
    b = read_footprints(folder / "mastermap-topo_3473984_0.gml")
    assert sorted(p.name for p in folder.iterdir()) == before  # no .gfs sidecar left
    assert not list(folder.glob("*.gfs"))
    assert len(b) == 160
    assert b["id"].str.startswith("osgb").all() and b["id"].is_unique
    assert "osgb1000005430576" in set(b["id"])
    assert b.crs == BNG
    assert b.geometry.is_valid.all()
    assert all("Building" in list(group) for group in b["descriptiveGroup"])
    # within the tile's extent of the README (E 527947-530467, N 181967-182983)
    west, south, east, north = b.total_bounds
    assert 527947 <= west and east <= 530467 and 181967 <= south and north <= 182983
    assert (west, south, east, north) == pytest.approx((529289.73, 182059.7, 529755.2, 182542.65))
    # the first building's calculatedAreaValue is OS's own area of its polygon
    assert b.geometry.area.to_numpy() == pytest.approx(b["calculatedAreaValue"], rel=1e-3)


MASTERMAP_GZ = """<?xml version="1.0" encoding="UTF-8"?>
<osgb:FeatureCollection xmlns:osgb="http://www.ordnancesurvey.co.uk/xml/namespaces/osgb"
    xmlns:gml="http://www.opengis.net/gml" fid="test">
  <osgb:topographicMember><osgb:TopographicArea fid="osgb1000000000001">
    <osgb:featureCode>10021</osgb:featureCode>
    <osgb:descriptiveGroup>Building</osgb:descriptiveGroup>
    <osgb:descriptiveGroup>Structure</osgb:descriptiveGroup>
    <osgb:polygon><gml:Polygon srsName="urn:ogc:def:crs:EPSG::27700"><gml:outerBoundaryIs>
      <gml:LinearRing><gml:coordinates>500100,200300 500140,200300 500140,200330 500100,200330
        500100,200300</gml:coordinates></gml:LinearRing></gml:outerBoundaryIs></gml:Polygon>
    </osgb:polygon></osgb:TopographicArea></osgb:topographicMember>
  <osgb:topographicMember><osgb:TopographicArea fid="osgb1000000000002">
    <osgb:featureCode>10056</osgb:featureCode>
    <osgb:descriptiveGroup>General Surface</osgb:descriptiveGroup>
    <osgb:polygon><gml:Polygon srsName="urn:ogc:def:crs:EPSG::27700"><gml:outerBoundaryIs>
      <gml:LinearRing><gml:coordinates>500201,200401 500261,200401 500261,200461
        500201,200401</gml:coordinates></gml:LinearRing></gml:outerBoundaryIs></gml:Polygon>
    </osgb:polygon></osgb:TopographicArea></osgb:topographicMember>
</osgb:FeatureCollection>
"""


def test_gzipped_mastermap_with_repeated_descriptive_group(tmp_path):
    path = tmp_path / "tile.gml.gz"
    path.write_bytes(gzip.compress(MASTERMAP_GZ.encode()))
    b = read_footprints(path)
    assert b["id"].tolist() == ["osgb1000000000001"]
    assert list(b["descriptiveGroup"][0]) == ["Building", "Structure"]
    assert b.geometry[0].equals(SQUARE)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["tile.gml.gz"]  # no .gfs


# --- damaged MasterMap files (each found by tests/fuzz/test_fuzz_footprints.py) ------------------


def test_a_damaged_gzip_file_is_one_error(tmp_path):
    whole = gzip.compress(MASTERMAP_GZ.encode())
    for name, data in [("cut.gml.gz", whole[:40]), ("header.gml.gz", whole[:2])]:
        path = tmp_path / name
        path.write_bytes(data)
        with pytest.raises(InputError, match=r"a damaged gzip file \(Compressed file ended"):
            read_footprints(path)
    path.write_bytes(whole[:2] + b"\x07" + whole[3:])  # byte 2: the compression method
    with pytest.raises(InputError, match=r"a damaged gzip file \(Unknown compression method"):
        read_footprints(path)


def test_a_gml_file_without_layers_is_one_error(tmp_path):
    """No MasterMap namespace (mistyped), so no TopographicArea layer is asked for, and GDAL
    finds no layer in it."""
    path = tmp_path / "empty.gml"
    head = MASTERMAP_GZ[: MASTERMAP_GZ.index("<osgb:topographicMember>")]
    path.write_text(head.replace("ordnancesurvey", "ordnancesurvy") + "</osgb:FeatureCollection>")
    with pytest.raises(InputError, match=r"cannot read the footprints: .*\(.*empty.gml\)"):
        read_footprints(path)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["empty.gml"]


def _big_tile(n: int) -> str:
    """MASTERMAP_GZ with its building repeated ``n`` times (fids 1 to n)."""
    start = MASTERMAP_GZ.index("  <osgb:topographicMember>")
    end = MASTERMAP_GZ.index("  <osgb:topographicMember>", start + 1)
    member = MASTERMAP_GZ[start:end]
    members = "".join(member.replace("osgb1000000000001", f"osgb{k}") for k in range(1, n + 1))
    return MASTERMAP_GZ[:start] + members + MASTERMAP_GZ[end:]


def test_a_cut_gml_file_is_an_error_naming_the_line(tmp_path):
    """GDAL reads no feature at all from it and says nothing ("no building features" before)."""
    text = _big_tile(400)
    assert len(read_footprints(_write(tmp_path / "whole.gml", text))) == 400
    path = _write(tmp_path / "cut.gml", text[: len(text) // 2])
    with pytest.raises(
        InputError, match=r"not well-formed XML: no element found \(.*cut.gml, line"
    ):
        read_footprints(path)
    data = gzip.compress(text.encode())
    path = tmp_path / "cut.gml.gz"
    path.write_bytes(data[: len(data) * 9 // 10])  # cut after the first 64 kB the sniffer reads
    assert len(gzip.decompress(data)[:65536]) == 65536
    with pytest.raises(InputError, match=r"damaged gzip file \(Compressed file ended"):
        read_footprints(path)
    bad = text.replace("<osgb:featureCode>", "<<osgb:featureCode>", 1)
    line = bad[: bad.index("<<")].count("\n") + 1
    with pytest.raises(InputError, match=rf"\(invalid token\) \(.*bad.gml, line {line}, column"):
        read_footprints(_write(tmp_path / "bad.gml", bad))


def test_a_gml_file_in_an_unknown_encoding_is_one_error(tmp_path):
    path = _write(tmp_path / "tf8.gml", MASTERMAP_GZ.replace('encoding="UTF-8"', 'encoding="TF-8"'))
    with pytest.raises(InputError, match=r"declares an encoding .*\(unknown encoding: TF-8\)"):
        read_footprints(path)


def _write(path, text):
    path.write_text(text)
    return path


def test_an_unclosed_ring_is_one_error(tmp_path):
    path = tmp_path / "unclosed.gml"
    path.write_text(MASTERMAP_GZ.replace("500100,200330\n        500100,200300", "500100,200330"))
    with (
        pytest.raises(InputError, match=r"cannot read the footprints: .*closed linestring"),
        pytest.warns(RuntimeWarning, match="Non closed ring detected"),  # GDAL's own
    ):
        read_footprints(path)


def test_a_mastermap_area_without_descriptive_group_is_not_a_building(tmp_path):
    path = tmp_path / "ungrouped.gml"
    path.write_text(
        MASTERMAP_GZ.replace("<osgb:descriptiveGroup>General Surface</osgb:descriptiveGroup>", "")
    )
    assert read_footprints(path)["id"].tolist() == ["osgb1000000000001"]


@pytest.mark.parametrize(
    "text",
    [
        "\ufeff" + MASTERMAP_GZ,  # a byte order mark, as some Windows tools write
        MASTERMAP_GZ.replace("http://www.opengis.net/gml", "htttp://www.opengis.net/gml"),
    ],
    ids=["byte order mark", "mistyped namespace"],
)
def test_gml_that_gdal_reads_never_gets_a_gfs_sidecar(tmp_path, text):
    path = tmp_path / "tile.gml"
    path.write_text(text, encoding="utf-8")
    assert read_footprints(path)["id"].tolist() == ["osgb1000000000001"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["tile.gml"]


# --- bad footprints -----------------------------------------------------------------------------


def write_layer(path, geometries, *, crs=BNG, layer=None, **columns):
    frame = gpd.GeoDataFrame(columns, geometry=list(geometries), crs=crs)
    frame.to_file(path, layer=layer)
    return path


def test_empty_layer(tmp_path):
    path = write_layer(tmp_path / "empty.gpkg", [], layer="none", toid=[])
    with pytest.raises(InputError, match=r"the layer has no features \(.*empty.gpkg, layer none\)"):
        read_footprints(path)


@pytest.mark.filterwarnings("ignore:'crs' was not provided")
def test_no_crs(tmp_path):
    path = write_layer(tmp_path / "nocrs.gpkg", [SQUARE], crs=None, toid=["a"])
    with pytest.raises(InputError, match=r"no CRS \(.*nocrs.gpkg.*-a_srs EPSG:27700"):
        read_footprints(path)


@pytest.mark.filterwarnings("ignore:'crs' was not provided")
def test_degrees_without_crs_or_in_a_projected_crs(tmp_path):
    square = shapely.box(-0.1342, 51.5246, -0.1340, 51.5248)
    path = write_layer(tmp_path / "nocrs.gpkg", [square], crs=None, toid=["a"])
    with pytest.raises(InputError, match=r"no CRS and coordinates that look like longitude"):
        read_footprints(path)
    path = write_layer(tmp_path / "mislabelled.gpkg", [square], toid=["a"])
    with pytest.raises(InputError, match=r"look like degrees but their CRS is OSGB.*EPSG:4326"):
        read_footprints(path)
    path = write_layer(tmp_path / "metres.gpkg", [SQUARE], crs="EPSG:4326", toid=["a"])
    with pytest.raises(InputError, match=r"\(degrees\) but their coordinates look like metres"):
        read_footprints(path)


def test_duplicate_ids(tmp_path):
    path = write_layer(tmp_path / "dup.gpkg", [SQUARE, COURTYARD, TWO_PARTS], toid=["a", "b", "a"])
    with pytest.raises(InputError, match=r"1 duplicate id\(s\) in 'toid': a \(.*dup.gpkg"):
        read_footprints(path)


def test_missing_ids_and_clashing_id_column(tmp_path):
    path = write_layer(tmp_path / "gap.gpkg", [SQUARE, COURTYARD], toid=["a", None])
    with pytest.raises(InputError, match=r"1 feature\(s\) without an id .* in 'toid': rows 1"):
        read_footprints(path)
    path = write_layer(tmp_path / "two.gpkg", [SQUARE], toid=["a"], ID=[1])
    with pytest.raises(InputError, match=r"column 'ID' besides the id field 'toid'"):
        read_footprints(path)


def test_points_and_missing_geometries_are_not_footprints(tmp_path):
    geometries = [SQUARE, shapely.Point(500000, 200000), None]
    path = write_layer(tmp_path / "mixed.geojson", geometries, toid=["a", "p", "n"])
    with pytest.raises(
        InputError, match=r"2 feature\(s\) are not polygons \(Point, missing\): p, n"
    ):
        read_footprints(path)


def test_a_footprint_with_no_area_is_dropped_with_a_warning(tmp_path):
    flat = shapely.Polygon([(500100, 200300), (500120, 200300), (500140, 200300)])
    path = write_layer(tmp_path / "flat.gpkg", [SQUARE, flat], toid=["sq", "flat"])
    with pytest.warns(UserWarning, match=r"dropped 1 footprint\(s\) with no area: flat"):
        b = read_footprints(path)
    assert b["id"].tolist() == ["sq"]


def test_footprints_that_all_have_no_area_are_an_error(tmp_path):
    """Not an empty table (found by tests/fuzz/test_fuzz_footprints.py)."""
    flat = shapely.Polygon([(500100, 200300), (500120, 200300), (500140, 200300)])
    path = write_layer(tmp_path / "flat.gpkg", [flat, flat], toid=["f1", "f2"])
    with pytest.raises(InputError, match=r"none of the 2 footprint\(s\) has an area: f1, f2 \("):
        read_footprints(path)


def test_several_layers_need_a_choice(tmp_path):
    path = tmp_path / "two_layers.gpkg"
    write_layer(path, [SQUARE], layer="old", toid=["a"])
    write_layer(path, [COURTYARD], layer="new", toid=["b"])
    with pytest.raises(InputError, match=r"several layers \(old, new\).*--layer"):
        read_footprints(path)
    assert read_footprints(path, layer="new")["id"].tolist() == ["b"]
    with pytest.raises(InputError, match=r"cannot read the footprints.*layer nope"):
        read_footprints(path, layer="nope")


def test_missing_file(tmp_path):
    with pytest.raises(InputError, match=r"footprint file not found"):
        read_footprints(tmp_path / "nothing.gpkg")


def test_plain_gml_is_read_without_a_gfs_sidecar(tmp_path):
    path = write_layer(tmp_path / "plain.gml", [SQUARE, COURTYARD], toid=["a", "b"])
    (tmp_path / "plain.xsd").unlink()  # without its schema GDAL would write a .gfs
    b = read_footprints(path)
    assert b["id"].tolist() == ["a", "b"]
    assert b.crs == BNG and b.geometry[1].equals(COURTYARD)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["plain.gml"]


def test_reading_writes_nothing_beside_the_input(tmp_path):
    """Found by fuzzing: GDAL's VFK driver claims a file starting with ``&H`` and used to
    leave an SQLite database beside it. Reading must never write beside the user's files."""
    path = tmp_path / "tile.gml"
    path.write_bytes(b"&H")
    with pytest.raises(InputError, match="cannot read the footprints"):
        read_footprints(path)
    assert [p.name for p in tmp_path.iterdir()] == ["tile.gml"]


def test_geoparquet_footprints_a_file_or_a_hive_folder(tmp_path):
    """GeoParquet (GDAL here has no Arrow): a file, and a hive folder such as a run's heights
    written per tile, whose partition key comes as a text column; the rules hold as for any
    source (the bow-tie is repaired)."""
    frame = gpd.GeoDataFrame(
        {"toid": ["sq", "court", "bow", "multi"], "storeys": [2, 5, 1, 3]},
        geometry=[SQUARE, COURTYARD, BOWTIE, TWO_PARTS],
        crs=BNG,
    )
    frame.to_parquet(tmp_path / "one.parquet")
    for tile, rows in (("A", [0, 1]), ("B", [2, 3])):
        (tmp_path / "hive" / f"tile={tile}").mkdir(parents=True)
        frame.iloc[rows].to_parquet(tmp_path / "hive" / f"tile={tile}" / "part-0.parquet")
    with pytest.warns(UserWarning, match="bow"):
        one = read_footprints(tmp_path / "one.parquet")
    assert one["id"].tolist() == ["sq", "court", "bow", "multi"] and one.crs == BNG
    with pytest.warns(UserWarning, match="bow"):
        hive = read_footprints(tmp_path / "hive")
    assert sorted(hive["id"]) == sorted(one["id"])
    assert hive.set_index("id")["tile"].to_dict() == {
        "sq": "A",
        "court": "A",
        "bow": "B",
        "multi": "B",
    }
    assert read_footprints(tmp_path / "hive" / "tile=A")["id"].tolist() == ["sq", "court"]
    with pytest.raises(InputError, match="GeoParquet has no layers to choose"):
        read_footprints(tmp_path / "one.parquet", layer="buildings")
    (tmp_path / "plain.parquet").write_bytes(b"PAR1 not really")
    with pytest.raises(InputError, match="cannot read the footprints as GeoParquet"):
        read_footprints(tmp_path / "plain.parquet")


# --- decompression bombs (issue 26) ------------------------------------------------------------


def _gzip_bomb(path, head: str, filler: bytes, size: int, tail: str = ""):
    """A gzip file of ``head``, ``size`` bytes of ``filler`` and ``tail``: about size / 1000
    bytes on disk."""
    with gzip.open(path, "wb", compresslevel=9) as out:
        out.write(head.encode())
        chunk = filler * (2**20 // len(filler))
        for _ in range(size // len(chunk)):
            out.write(chunk)
        out.write(tail.encode())
    return path


def test_a_gzip_bomb_is_refused_in_bounded_memory(tmp_path):
    """A 0.3 MB .gml.gz of 300 MB (spaces inside a MasterMap file, well-formed) is one error
    naming the ratio and the way round it, read as a stream: memory stays small."""
    start = MASTERMAP_GZ.index("  <osgb:topographicMember>")
    path = _gzip_bomb(
        tmp_path / "bomb.gml.gz", MASTERMAP_GZ[:start], b" ", 300 * 2**20, MASTERMAP_GZ[start:]
    )
    assert path.stat().st_size < 2**20
    # (the peak of this process's own memory, VmHWM: ru_maxrss would keep the peak of the
    # pytest process it was forked from, which exec does not reset)
    script = (
        "import re\n"
        "from gnss_citygml.errors import InputError\n"
        "from gnss_citygml.footprints import read_footprints\n"
        "try:\n"
        f"    read_footprints({str(path)!r})\n"
        "    print('read')\n"
        "except InputError as exc:\n"
        "    print(exc.one_line())\n"
        "status = open('/proc/self/status').read()\n"
        "print(int(re.search(r'VmHWM:\\s+(\\d+) kB', status).group(1)) // 1024)\n"
    )
    done = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True)
    message, rss_mb = done.stdout.splitlines()
    assert "expands more than 100 times its size" in message, done.stdout + done.stderr
    assert "bomb.gml.gz" in message and "gzip -dk" in message
    assert int(rss_mb) < 400, rss_mb  # was 863 MB for 600 MB
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bomb.gml.gz"]


def test_an_orbit_file_gzip_bomb_is_refused(tmp_path, orbits_dir):
    from gnss_citygml.gnss.orbits import load_orbits

    first = (orbits_dir / "grg21553.sp3").read_text().splitlines(keepends=True)
    path = _gzip_bomb(tmp_path / "bomb.sp3.gz", "".join(first[:40]), b" " * 79 + b"\n", 80 * 2**20)
    with pytest.raises(InputError, match=r"gzipped orbit file expands more than 100 times"):
        load_orbits(path)


def test_a_real_mastermap_tile_gzipped_is_read(shared_data, tmp_path, monkeypatch):
    """OS MasterMap compresses about 15 times: well inside the cap, which holds alone here."""
    import gnss_citygml.files.paths

    monkeypatch.setattr(gnss_citygml.files.paths, "FREE_EXPANSION", 0)
    text = (shared_data / "footprints" / "mastermap-topo_3473984_0.gml").read_bytes()
    path = tmp_path / "tile.gml.gz"
    path.write_bytes(gzip.compress(text))
    assert 10 < len(text) / path.stat().st_size < 100
    assert len(read_footprints(path)) > 0


def _geoparquet_variants(folder):
    """The sample city's footprints as Parquet files that are not GeoParquet GeoPandas reads
    (each a one-line error now; several were an internal error), by name."""
    import json

    import pyarrow as pa
    import pyarrow.parquet as pq
    from test_outputs import CITY

    frame = read_footprints(CITY / "footprints.gpkg")[["id", "geometry"]]
    frame.to_parquet(folder / "wkb.parquet")
    table = pq.read_table(folder / "wkb.parquet")
    geo = json.loads(table.schema.metadata[b"geo"])

    def write(name, table, spec=None, raw=None, drop=False):
        meta = dict(table.schema.metadata)
        column = {**geo["columns"]["geometry"], **(spec or {})}
        meta[b"geo"] = (
            raw
            if raw is not None
            else json.dumps({**geo, "columns": {"geometry": column}}).encode()
        )
        if drop:
            del meta[b"geo"]
        pq.write_table(table.replace_schema_metadata(meta), folder / f"{name}.parquet")

    text = table.set_column(
        table.schema.get_field_index("geometry"),
        "geometry",
        pa.array(shapely.to_wkt(frame.geometry.to_numpy())),
    )
    write("wkt", text, {"encoding": "WKT"})
    write("wkt_said_wkb", text)
    write("point_said_of_wkb", table, {"encoding": "point"})
    write("polygon_said_of_wkb", table, {"encoding": "polygon"})
    write("no_geo", table, drop=True)
    write("geo_not_an_object", table, raw=b"[1, 2]")
    write("geo_not_json", table, raw=b"{geo")
    write("crs_not_a_crs", table, {"crs": "nonsense"})
    pq.write_table(
        table.replace_schema_metadata(
            {
                **table.schema.metadata,
                b"geo": json.dumps({**geo, "primary_column": "geom"}).encode(),
            }
        ),
        folder / "primary_not_a_column.parquet",
    )
    (folder / "not_parquet.parquet").write_text("id,geometry\n")
    return frame


@pytest.mark.parametrize(
    "name, message",
    [
        ("wkt", "encoded as 'WKT' and holds string"),
        ("wkt_said_wkb", "encoded as 'WKB' and holds string"),
        ("point_said_of_wkb", "encoded as 'point' and holds binary"),
        ("polygon_said_of_wkb", "encoded as 'polygon' and holds binary"),
        ("no_geo", "has no GeoParquet metadata"),
        ("geo_not_an_object", "names no geometry column"),
        ("geo_not_json", "its geo metadata cannot be read: not valid JSON"),
        ("crs_not_a_crs", "has a CRS that is not one"),
        ("primary_not_a_column", "names no geometry column"),
        ("not_parquet", "not a Parquet file"),
    ],
)
def test_parquet_footprints_that_are_not_geoparquet_are_one_line_errors(
    tmp_path, capsys, name, message
):
    """WKT, a native encoding said of WKB, no or damaged 'geo' metadata, a CRS that is none,
    not Parquet: one line naming the file and how to mend it (exit 2), never an internal
    error."""
    from test_cli import run

    _geoparquet_variants(tmp_path)
    with pytest.raises(InputError, match=message):
        read_footprints(tmp_path / f"{name}.parquet")
    code, _, err = run(
        ["convert", str(tmp_path / f"{name}.parquet"), "-o", str(tmp_path / "x.city.json")], capsys
    )
    assert code == 2 and err.startswith("error: ") and err.count("\n") == 1, err
    assert f"{name}.parquet" in err and "internal error" not in err


def test_geoparquet_footprints_in_geoarrow_or_another_geometry_column_are_read(tmp_path):
    """What can be read is: GeoArrow's native polygon encoding, a geometry column of another
    name, a hive folder with a hidden file pyarrow does not read either."""
    frame = _geoparquet_variants(tmp_path)
    frame.to_parquet(tmp_path / "arrow.parquet", geometry_encoding="geoarrow")
    frame.rename_geometry("geom").to_parquet(tmp_path / "geom.parquet")
    (tmp_path / "hive" / "tile=A").mkdir(parents=True)
    frame.to_parquet(tmp_path / "hive" / "tile=A" / "part-0.parquet")
    (tmp_path / "hive" / "tile=A" / "._part-0.parquet").write_bytes(b"resource fork")
    for name in ("wkb.parquet", "arrow.parquet", "geom.parquet", "hive"):
        got = read_footprints(tmp_path / name)
        assert got["id"].tolist() == frame["id"].tolist(), name
        assert shapely.equals(got.geometry.to_numpy(), frame.geometry.to_numpy()).all(), name


def test_geoparquet_text_that_is_not_utf8_is_named_by_row(tmp_path):
    """Parquet does not check its text (found by fuzzing): an id or attribute that is not
    UTF-8 is one line naming the column and row, not Arrow's error from far inside."""
    import pyarrow.parquet as pq
    from test_observations import _not_utf8
    from test_outputs import CITY

    frame = gpd.read_file(CITY / "footprints.gpkg").assign(name="a building")
    frame.to_parquet(tmp_path / "f.parquet")
    table = pq.read_table(tmp_path / "f.parquet")
    for column in ("id", "name"):
        bad = table.set_column(
            table.schema.get_field_index(column), column, _not_utf8(frame[column].tolist(), 2)
        ).replace_schema_metadata(table.schema.metadata)
        pq.write_table(bad, tmp_path / "bad.parquet")
        message = rf"the column '{column}' is not UTF-8 text \(.*bad.parquet, row 2\)"
        with pytest.raises(InputError, match=message):
            read_footprints(tmp_path / "bad.parquet")


@pytest.mark.parametrize("column", ["toid", "name"])
def test_geopackage_text_that_is_not_utf8_is_named_by_feature(tmp_path, column):
    """A GeoPackage's text is UTF-8 by the standard, but SQLite stores any bytes: an id or an
    attribute that is not UTF-8 is one line naming the field and the feature, read whole or in
    batches (found at the command line: convert and partition stopped with an internal error,
    pyogrio's UnicodeDecodeError or Arrow's "Wrapping ... failed")."""
    import sqlite3

    from gnss_citygml.footprints import footprint_batches

    path = tmp_path / "f.gpkg"
    frame = gpd.read_file(write_footprints(tmp_path)).assign(name="a building")
    frame.to_file(path, layer="buildings", SPATIAL_INDEX="NO")  # (no R-tree triggers to run)
    with sqlite3.connect(path) as db:  # the bytes of a Latin-1 "café"
        db.execute(f"UPDATE buildings SET {column} = CAST(X'636166E9' AS TEXT) WHERE fid = 3")
    message = rf"the field '{column}' is not UTF-8 text \(.*f.gpkg.*, feature 3\)"
    with pytest.raises(InputError, match=message):
        read_footprints(path)
    with pytest.raises(InputError, match=message):
        list(footprint_batches(path, size=2))


def test_a_geopackage_field_name_that_is_not_utf8_is_one_line(tmp_path):
    """A field named in Latin-1 bytes (the table's SQL patched in place): one line, read whole
    or in batches, not pyogrio's UnicodeDecodeError."""
    from gnss_citygml.footprints import footprint_batches

    path = tmp_path / "f.gpkg"
    gpd.read_file(write_footprints(tmp_path)).assign(name="a").to_file(path, layer="buildings")
    data = path.read_bytes()
    assert data.count(b'"name" TEXT') == 1
    path.write_bytes(data.replace(b'"name" TEXT', b'"nam\xe9" TEXT'))
    for read in (read_footprints, lambda p: list(footprint_batches(p, size=2))):
        with pytest.raises(InputError, match=r"a field's name is not UTF-8 text \(.*f.gpkg"):
            read(path)

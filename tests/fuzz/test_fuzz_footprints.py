"""Fuzzing the footprint reader: OS MasterMap Topography GML (plain and gzipped) and GeoPackage.

The MasterMap seed is cut at test time, in memory, from the shared OS tile (a few
TopographicArea features: small buildings, one with a courtyard, a general surface, and a
line): OS MasterMap data is licensed and never written into the repository. The GeoPackage
seed is a tiny layer written by geopandas; a second test mutates its attributes and geometries
(ids missing, repeated, huge; empty, invalid, 3D, point and line geometries) rather than bytes.

Every case must end as footprints in EPSG:27700 or one :class:`GnssCityGMLError` line, and the
GML reader must never leave a ``.gfs`` sidecar beside its input.
"""

from __future__ import annotations

import gzip
import re
import tempfile
import warnings
from pathlib import Path
from xml.sax.saxutils import escape

import geopandas as gpd
import numpy as np
import pytest
import shapely
from hypothesis import event, given, settings
from hypothesis import strategies as st

from gnss_citygml.footprints import read_footprints

from .conftest import TOKENS, mutated

#: Features cut from the shared tile: the smallest buildings, one with a courtyard, the
#: smallest area that is not a building and the smallest line.
_BUILDINGS, _COURTYARDS, _OTHER_AREAS, _LINES = 2, 1, 1, 1


class _Unshown(bytes):
    """Bytes that a test report shows by size only (OS MasterMap content stays out of logs)."""

    def __repr__(self) -> str:
        return f"<{len(self)} bytes cut from the OS MasterMap tile>"


@pytest.fixture(scope="module")
def mastermap_seed(shared_data) -> bytes:
    """A small MasterMap GML file made, in memory only, from features of the shared tile."""
    text = (shared_data / "footprints" / "mastermap-topo_3473984_0.gml").read_text("utf-8")
    members = re.findall(r"  <osgb:topographicMember>.*?</osgb:topographicMember>\n", text, re.S)
    areas = sorted((m for m in members if "<osgb:TopographicArea" in m), key=len)
    buildings = [m for m in areas if ">Building<" in m]
    chosen = (
        buildings[:_BUILDINGS]
        + [m for m in buildings if "innerBoundaryIs" in m][:_COURTYARDS]
        + [m for m in areas if ">Building<" not in m][:_OTHER_AREAS]
        + sorted((m for m in members if "<osgb:TopographicLine" in m), key=len)[:_LINES]
    )
    head = text[: text.index("<gml:boundedBy>")]
    seed = (head + "".join(chosen) + "</osgb:FeatureCollection>\n").encode()
    with tempfile.TemporaryDirectory() as name:
        (Path(name) / "seed.gml").write_bytes(seed)
        footprints = read_footprints(Path(name) / "seed.gml")  # the seed is read as meant
    assert len(footprints) == _BUILDINGS + _COURTYARDS
    assert footprints["id"].str.startswith("osgb").all()
    return _Unshown(seed)


@pytest.fixture
def folder():
    """One folder per test, its file rewritten by every example (hypothesis runs all the
    examples of a test within one call of a function-scoped fixture)."""
    with tempfile.TemporaryDirectory(prefix="fuzz-footprints-") as name:
        yield Path(name)


#: Values an XML-aware edit puts into a text node or an attribute (escaped, so the file stays
#: well-formed XML and the reader, not the XML parser, meets them).
_VALUES = [
    *(token.decode("utf-8", "replace") for token in TOKENS),
    "Building",
    "General Surface",
    "osgb1000005431014",
    "urn:ogc:def:crs:EPSG::4326",
    "EPSG:4326",
    "urn:ogc:def:crs:EPSG::23030",
    "urn:ogc:def:crs:EPSG::99999",
    "529468.1,182211.1 529469.75,182212.3 529468.1,182211.1",
    "529468.1,182211.1 529469.75,182212.3",
    "nan,nan 1,1 2,2 nan,nan",
    "1e308,1e308 -1e308,1e308 0,0 1e308,1e308",
    "-0.134,51.524 -0.133,51.524 -0.133,51.525 -0.134,51.524",
    "529468.1,182211.1,5 529469.75,182212.3,5 529468.7,182213.75,5 529468.1,182211.1,5",
]


@st.composite
def xml_edited(draw, seed: bytes, max_edits: int = 4):
    """``seed`` with 1..max_edits text nodes or attribute values replaced (escaped)."""
    text = seed.decode("utf-8")
    spans = [m.span(1) for m in re.finditer(r">([^<]*)<", text)]
    spans += [m.span(1) for m in re.finditer(r'="([^"]*)"', text)]
    for _ in range(draw(st.integers(1, max_edits))):
        start, end = draw(st.sampled_from(spans))
        value = escape(draw(st.sampled_from(_VALUES)), {'"': "&quot;"})
        text = text[:start] + value + text[end:]
        shift = len(value) - (end - start)
        spans = [(a + shift * (a > start), b + shift * (b > start)) for a, b in spans]
    return text.encode("utf-8")


def _write(folder: Path, name: str, data: bytes) -> Path:
    """``data`` as the only file of ``folder`` (what an earlier example left is removed)."""
    for old in folder.iterdir():
        old.unlink()
    path = folder / name
    path.write_bytes(data)
    return path


def _check(result) -> None:
    """A result is footprints as :func:`read_footprints` promises them (the statistics count
    the outcomes: footprints, or an error line)."""
    event(
        "error line"
        if result is None
        else f"{min(len(result), 3)}{'+' * (len(result) >= 3)} footprints"
    )
    if result is not None:
        assert str(result.crs) == "EPSG:27700"
        assert list(result.columns[:1]) == ["id"] and result["id"].is_unique
        assert result.geometry.is_valid.all() and not result.geometry.is_empty.any()
        assert set(result.geom_type) <= {"Polygon", "MultiPolygon"}


def _edits(seed: bytes):
    """Byte-level mutations (a cut or damaged file) or XML-aware ones (odd values)."""
    return mutated(seed) | xml_edited(seed)


@given(data=st.data())
def test_mastermap_gml(data, mastermap_seed, folder, clean):
    path = _write(folder, "tile.gml", data.draw(_edits(mastermap_seed), label="gml"))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # repaired or dropped polygons are warnings, not errors
        _check(clean(read_footprints, path))
    assert sorted(p.name for p in folder.iterdir()) == ["tile.gml"]  # no .gfs sidecar


@given(data=st.data())
def test_mastermap_gml_gz(data, mastermap_seed, folder, clean):
    """Mutations of the compressed bytes (a cut download) and of the text inside."""
    if data.draw(st.booleans(), label="mutate compressed bytes"):
        raw = data.draw(mutated(gzip.compress(mastermap_seed, mtime=0)), label="gz")
    else:
        raw = gzip.compress(data.draw(_edits(mastermap_seed), label="gml"), mtime=0)
    path = _write(folder, "tile.gml.gz", raw)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        _check(clean(read_footprints, path))
    assert sorted(p.name for p in folder.iterdir()) == ["tile.gml.gz"]


def _geopackage_seed() -> bytes:
    """A tiny GeoPackage layer as geopandas writes it: two footprints in EPSG:27700."""
    with tempfile.TemporaryDirectory() as name:
        path = Path(name) / "seed.gpkg"
        gpd.GeoDataFrame(
            {"toid": ["a", "b"], "storeys": [2, 3]},
            geometry=[
                shapely.box(500100.0, 200300.0, 500140.0, 200330.0),
                shapely.box(500200.0, 200400.0, 500260.0, 200460.0),
            ],
            crs="EPSG:27700",
        ).to_file(path, layer="buildings")
        return path.read_bytes()


GEOPACKAGE_SEED = _geopackage_seed()


@settings(max_examples=max(10, settings.default.max_examples // 10))
@given(data=mutated(GEOPACKAGE_SEED))
def test_geopackage_bytes(data, folder, clean):
    path = _write(folder, "bytes.gpkg", data)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        _check(clean(read_footprints, path))


_SQUARE = shapely.box(500100.0, 200300.0, 500140.0, 200330.0)
#: Footprints a reader takes (the bow-tie after a repair) and ones it must refuse or drop.
GEOMETRIES = st.sampled_from(
    [
        _SQUARE,
        shapely.MultiPolygon([_SQUARE, shapely.box(500200.0, 200300.0, 500210.0, 200310.0)]),
        shapely.Polygon([(500100, 200300), (500140, 200340), (500140, 200300), (500100, 200340)]),
        shapely.Polygon([(500100, 200300, 5), (500140, 200300, 6), (500140, 200330, 7)]),  # 3D
        shapely.box(-0.1342, 51.5246, -0.1340, 51.5248),  # degrees (London)
    ]
) | st.sampled_from(
    [
        shapely.Polygon([(500100, 200300), (500120, 200300), (500140, 200300)]),  # no area
        shapely.Polygon(),
        shapely.Point(500100, 200300),
        shapely.LineString([(500100, 200300), (500140, 200300)]),
        shapely.GeometryCollection([_SQUARE]),
        shapely.box(1e300, 1e300, 2e300, 2e300),
        shapely.box(-4.49, 48.39, -4.48, 48.40),  # degrees, off the grids (Brest)
        None,
    ]
)
IDS = (
    st.none()
    | st.sampled_from(["a", "", " ", "\x01", "é" * 300])
    | st.integers(-(2**63), 2**63 - 1)
    | st.floats()
    | st.text(max_size=20)
)


@settings(max_examples=max(10, settings.default.max_examples // 10))
@given(
    rows=st.lists(st.tuples(IDS, GEOMETRIES), min_size=1, max_size=4),
    crs=st.sampled_from(["EPSG:27700", "EPSG:4326", "EPSG:23030", None]),
)
def test_geopackage_attributes(rows, crs, folder, clean, grid_dir):
    """Any ids (missing, repeated, huge; one type per column, as a layer has), any geometries
    and a few CRSs (EPSG:4326 through the grids; ED50, which has no grid path)."""
    ids, geometries = map(list, zip(*rows, strict=True))
    if len({type(i) for i in ids if i is not None}) > 1:
        ids = [None if i is None else str(i) for i in ids]
    frame = gpd.GeoDataFrame({"toid": ids, "n": np.arange(len(ids))}, geometry=geometries, crs=crs)
    path = folder / "attributes.gpkg"
    path.unlink(missing_ok=True)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        frame.to_file(path, layer="buildings", geometry_type="Unknown")
        _check(clean(read_footprints, path, grid_dir=grid_dir))

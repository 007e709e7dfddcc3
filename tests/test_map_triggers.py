"""A GeoPackage of the user's with triggers of its own is refused before anything writes to
it (``update``, ``estimate -o existing.gpkg``), whatever the trigger is named; a view given
as the layer, or a constraint that refuses the update, is one line and the map as it was
(issue 26). GeoPackage's and GDAL's own triggers are no reason to refuse."""

import contextlib
import hashlib
import shutil
import sqlite3
from pathlib import Path

import pyogrio
import pytest
from test_cli import run

CITY = Path(__file__).resolve().parents[1] / "examples" / "city"


def digest(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


@pytest.fixture
def city_map(tmp_path):
    """The city's footprints as a map, with a table of notes of the user's."""
    path = tmp_path / "map.gpkg"
    shutil.copy(CITY / "footprints.gpkg", path)
    sql(path, "CREATE TABLE notes (x)", "INSERT INTO notes VALUES (1)")
    return path


def sql(path: Path, *statements: str) -> None:
    with contextlib.closing(sqlite3.connect(path)) as db, db:
        for statement in statements:
            db.execute(statement)


def notes(path: Path) -> int:
    with contextlib.closing(sqlite3.connect(path)) as db:
        return db.execute("SELECT count(*) FROM notes").fetchone()[0]


def update(path: Path, grid_args, *extra) -> list[str]:
    return [
        "update", str(path), "--observations", str(CITY / "observations.parquet"), "--dem",
        str(CITY / "dem.tif"), *grid_args, "-q", *extra,
    ]  # fmt: skip


def estimate(output: Path, grid_args, *extra) -> list[str]:
    return [
        "estimate", str(CITY / "observations.parquet"), str(CITY / "footprints.gpkg"), "--dem",
        str(CITY / "dem.tif"), "-o", str(output), *grid_args, "-q", *extra,
    ]  # fmt: skip


def one_line(capsys, args, message: str) -> None:
    code, _, err = run(args, capsys)
    assert code == 2 and message in err, err
    lines = [line for line in err.strip().splitlines() if not line.startswith("warning: ")]
    assert len(lines) == 1 and "internal error" not in err  # (GDAL warns of columns it reads)


#: Triggers that would run on the writes: a user's, one named as an R-tree index's, one
#: named as GDAL's feature count, one that aborts.
TRIGGERS = {
    "audit": "CREATE TRIGGER audit AFTER UPDATE ON footprints BEGIN DELETE FROM notes; END",
    "rtree_footprints_geom_update9": "CREATE TRIGGER rtree_footprints_geom_update9 AFTER "
    'UPDATE ON footprints BEGIN DELETE FROM "notes"; END',
    "trigger_insert_feature_count_footprints2": "CREATE TRIGGER "
    "trigger_insert_feature_count_footprints2 AFTER INSERT ON gpkg_contents BEGIN "
    "UPDATE gpkg_ogr_contents SET feature_count = 0; DELETE FROM notes; END",
    "stop": "CREATE TRIGGER stop BEFORE UPDATE ON footprints BEGIN "
    "SELECT RAISE(ABORT, 'no updates here'); END",
    "contents": "CREATE TRIGGER contents AFTER INSERT ON gpkg_contents BEGIN "
    "DELETE FROM 'notes'; END",
    # an R-tree's name, its statement between comments holding quotes (read as one string)
    "rtree_footprints_geom_update8": "CREATE TRIGGER rtree_footprints_geom_update8 AFTER "
    "UPDATE ON footprints BEGIN /* ' */ DELETE FROM notes; /* ' */ END",
    "rtree_footprints_geom_update10": "CREATE TRIGGER rtree_footprints_geom_update10 AFTER "
    "UPDATE ON footprints BEGIN -- it's\n DELETE FROM notes; -- it's\n END",
}


@pytest.mark.parametrize("name", TRIGGERS)
def test_a_map_with_a_trigger_of_its_own_is_refused(name, city_map, grid_args, capsys):
    sql(city_map, TRIGGERS[name])
    before = digest(city_map)
    one_line(
        capsys, update(city_map, grid_args), f"the GeoPackage has triggers of its own ('{name}')"
    )
    one_line(capsys, estimate(city_map, grid_args), f"triggers of its own ('{name}')")
    assert digest(city_map) == before and notes(city_map) == 1
    assert sorted(p.name for p in city_map.parent.iterdir()) == ["map.gpkg"]


def test_geopackage_and_gdal_triggers_are_its_own(city_map, grid_args, capsys):
    """The sample's R-tree, feature-count and tile-matrix triggers (as GDAL writes them, the
    tile-matrix ones with 'update on table' in their messages): the map is updated."""
    code, _, err = run(update(city_map, grid_args), capsys)
    assert code == 0, err
    code, _, err = run(estimate(city_map, grid_args), capsys)
    assert code == 0, err
    assert notes(city_map) == 1


@pytest.mark.parametrize("layer", ["foot'prints", 'foot"prints', "foot`[prints]"])
def test_gdal_triggers_of_a_layer_named_with_quotes_are_its_own(layer, tmp_path, grid_args, capsys):
    """GDAL's R-tree triggers of a layer whose name holds a quote (in their double-quoted
    identifiers) are GeoPackage's own: the map is updated (was refused as triggers of its own
    when the name held an apostrophe)."""
    path = tmp_path / "map.gpkg"
    frame = pyogrio.read_dataframe(CITY / "footprints.gpkg")
    pyogrio.write_dataframe(frame, path, layer=layer)
    code, _, err = run(update(path, grid_args), capsys)
    assert code == 0, err
    assert pyogrio.list_layers(path)[0][0] == layer


def test_a_constraint_that_refuses_the_update_is_one_line(city_map, grid_args, capsys):
    """A unique index of the user's on a column the update writes (the same method for all)."""
    sql(
        city_map,
        "ALTER TABLE footprints ADD COLUMN method TEXT",
        "CREATE UNIQUE INDEX one_each ON footprints (method)",
    )
    before = digest(city_map)
    one_line(capsys, update(city_map, grid_args), "the GeoPackage refused the write: UNIQUE")
    assert digest(city_map) == before
    assert sorted(p.name for p in city_map.parent.iterdir()) == ["map.gpkg"]


def test_a_view_as_the_layer(city_map, grid_args, tmp_path, capsys):
    """A view registered as a layer: read as footprints it works; updated, one line."""
    sql(
        city_map,
        "CREATE VIEW seen AS SELECT * FROM footprints",
        "INSERT INTO gpkg_contents (table_name, data_type, identifier, srs_id) SELECT 'seen', "
        "'features', 'seen', srs_id FROM gpkg_contents WHERE table_name = 'footprints'",
        "INSERT INTO gpkg_geometry_columns SELECT 'seen', column_name, geometry_type_name, "
        "srs_id, z, m FROM gpkg_geometry_columns WHERE table_name = 'footprints'",
    )
    before = digest(city_map)
    one_line(capsys, update(city_map, grid_args, "--layer", "seen"), "'seen' is a view")
    assert digest(city_map) == before
    args = [*estimate(tmp_path / "h.gpkg", grid_args), "--layer", "seen"]
    args[2] = str(city_map)
    code, _, err = run(args, capsys)
    assert code == 0, err
    assert len(pyogrio.read_dataframe(tmp_path / "h.gpkg", layer="heights")) == 30


@pytest.mark.parametrize(
    ("content", "message"),
    [
        (b"not sqlite\n", "not a GeoPackage: the file is no SQLite database"),
        (b"PK\x03\x04" + bytes(100), "not a GeoPackage: the file is no SQLite database"),
        (b"", "not a GeoPackage: the file is empty"),
    ],
)
def test_a_map_that_is_no_sqlite_database_is_one_line(
    content, message, tmp_path, grid_args, capsys
):
    """update on a .gpkg that is text, a zip or empty; estimate -o into an existing one (with
    or without --overwrite): one line, the file as it was (were "internal error", or a lock
    held by another program)."""
    path = tmp_path / "map.gpkg"
    path.write_bytes(content)
    one_line(capsys, update(path, grid_args), message)
    if content:  # (an empty file is no GeoPackage to keep: estimate writes one in its place)
        one_line(capsys, estimate(path, grid_args), message)
        one_line(capsys, estimate(path, grid_args, "--overwrite"), message)
    assert path.read_bytes() == content
    assert sorted(p.name for p in tmp_path.iterdir()) == ["map.gpkg"]


#: Triggers on the tables a layer's write fills besides the layer (its provenance in
#: gpkg_metadata and gpkg_metadata_reference, its style in layer_styles) that abort the write,
#: drop the row silently or delete it: some named as the standard's checks of
#: gpkg_metadata_reference (RAISE allowed), one of them conditional on what is always true.
WRITE_TRIGGERS = {
    "abort on the reference": "CREATE TRIGGER gpkg_metadata_reference_stop BEFORE INSERT ON "
    "gpkg_metadata_reference BEGIN SELECT RAISE(ABORT, 'no'); END",
    "ignore the reference": "CREATE TRIGGER gpkg_metadata_reference_quiet BEFORE INSERT ON "
    "gpkg_metadata_reference BEGIN SELECT RAISE(IGNORE); END",
    "roll back the reference": "CREATE TRIGGER gpkg_metadata_reference_scope_insert BEFORE "
    "INSERT ON gpkg_metadata_reference FOR EACH ROW BEGIN SELECT RAISE(ROLLBACK, 'x') "
    "WHERE NEW.reference_scope NOT IN ('geopackage'); END",
    "abort when always true": "CREATE TRIGGER gpkg_metadata_reference_scope_insert BEFORE "
    "INSERT ON gpkg_metadata_reference FOR EACH ROW BEGIN SELECT RAISE(ABORT, 'insert on "
    "table gpkg_metadata_reference violates constraint') WHERE NEW.table_name NOT NULL; END",
    "delete the reference": "CREATE TRIGGER gpkg_metadata_reference_gone AFTER INSERT ON "
    "gpkg_metadata_reference BEGIN DELETE FROM gpkg_metadata_reference; END",
    "abort on the metadata": "CREATE TRIGGER gpkg_metadata_reference_m BEFORE INSERT ON "
    "gpkg_metadata BEGIN SELECT RAISE(ABORT, 'no'); END",
    "ignore the metadata": "CREATE TRIGGER gpkg_metadata_quiet BEFORE INSERT ON "
    "gpkg_metadata BEGIN SELECT RAISE(IGNORE); END",
    "delete the metadata": "CREATE TRIGGER gpkg_metadata_gone AFTER INSERT ON gpkg_metadata "
    "BEGIN DELETE FROM gpkg_metadata WHERE id = NEW.id; END",
    "abort on the style": "CREATE TRIGGER layer_styles_stop BEFORE INSERT ON layer_styles "
    "BEGIN SELECT RAISE(ABORT, 'no'); END",
    "ignore the style": "CREATE TRIGGER rtree_layer_styles_x BEFORE INSERT ON layer_styles "
    "BEGIN SELECT RAISE(IGNORE); END",
    "delete the style": "CREATE TRIGGER rtree_layer_styles_y AFTER INSERT ON layer_styles "
    "BEGIN DELETE FROM layer_styles; END",
}


@pytest.mark.parametrize("name", WRITE_TRIGGERS)
def test_a_trigger_on_the_provenance_or_style_tables_is_refused(name, tmp_path, grid_args, capsys):
    """estimate --overwrite into a map of heights (which has the metadata and style tables)
    with a trigger that would abort, drop or delete the provenance or the style: one line,
    the map as it was (was exit 0 and a map without its provenance)."""
    path = tmp_path / "map.gpkg"
    code, _, err = run(estimate(path, grid_args), capsys)
    assert code == 0, err
    sql(path, WRITE_TRIGGERS[name])
    before = digest(path)
    one_line(capsys, estimate(path, grid_args, "--overwrite", "--min-elevation", "15"), "trigger")
    assert digest(path) == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["map.gpkg"]

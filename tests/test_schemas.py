"""The project's contracts in schemas/: the JSON Schemas of the tables are the ones the readers
check (what the checks accept validates, their bounds and required columns are the schema's),
the CityJSON Extension types the heights table's columns, and the files are where the
repository and the package say they are."""

import json
import math
import os
import re
from pathlib import Path

import jsonschema
import numpy as np
import pandas as pd
import pytest

import gnss_citygml
from gnss_citygml.cli.demo import CITY
from gnss_citygml.contracts import EXTENSION, HEIGHTS, OBSERVATIONS, SCHEMA_FOLDER, load
from gnss_citygml.errors import InputError, MissingColumnError
from gnss_citygml.export import footprints_with_heights
from gnss_citygml.files.ids import with_id_field
from gnss_citygml.model.estimate import HEIGHTS_COLUMNS, estimate_heights
from gnss_citygml.observations import OBSERVATION_COLUMNS, check_observations

ROOT = Path(__file__).resolve().parents[1]
BASE = "https://gnss-citygml.org/schemas/1.1/"
OBS = load(OBSERVATIONS)
#: A row every check accepts, as JSON.
ROW = {
    "time_utc": "2020-02-11T08:50:00Z",
    "receiver": "s10",
    "lat": 51.5247,
    "lon": -0.1343,
    "h": 70.5,
    "constellation": "G",
    "svid": 5,
    "azimuth": 120.5,
    "elevation": 33.0,
    "cn0": 41.0,
}


def validator(schema):
    return jsonschema.Draft202012Validator(schema, format_checker=jsonschema.FormatChecker())


def json_rows(table: pd.DataFrame) -> list[dict]:
    """The rows of a table as JSON objects (NaN as null, times in ISO 8601)."""
    return json.loads(table.to_json(orient="records", date_format="iso", date_unit="ms"))


def accepted(row: dict) -> bool:
    """Whether check_observations takes a table of this one row."""
    try:
        check_observations(pd.DataFrame({k: [v] for k, v in row.items()}))
    except InputError:
        return False
    return True


# --- the files ----------------------------------------------------------------------------------


def test_the_top_level_folder_is_a_relative_link_to_the_package_folder():
    link = ROOT / "schemas"
    assert link.is_symlink() and not os.path.isabs(os.readlink(link))
    assert link.resolve() == SCHEMA_FOLDER == Path(gnss_citygml.__file__).parent / "schemas"


@pytest.mark.parametrize("name", [OBSERVATIONS, HEIGHTS])
def test_the_table_schemas_are_draft_2020_12_with_a_stable_id(name):
    schema = load(name)
    assert schema["$schema"] == "https://json-schema.org/draft/2020-12/schema"
    jsonschema.Draft202012Validator.check_schema(schema)
    assert schema["$id"] == BASE + name
    assert set(schema["required"]) <= set(schema["properties"])
    for column, spec in schema["properties"].items():
        assert spec["description"], column


def test_the_readme_names_every_file_with_its_id():
    readme = (SCHEMA_FOLDER / "README.md").read_text()
    files = sorted(p.name for p in SCHEMA_FOLDER.glob("*.json"))
    assert files == sorted([OBSERVATIONS, HEIGHTS, EXTENSION])
    for name in files:
        assert f"| `{name}` |" in readme and f"`{BASE}{name}`" in readme
    assert "version **1.1**" in readme and "are **names**, not addresses to fetch" in readme


# --- observations -------------------------------------------------------------------------------


def test_the_reader_takes_its_columns_from_the_schema():
    assert OBSERVATION_COLUMNS == list(OBS["properties"])
    assert OBSERVATION_COLUMNS[:4] == ["time_utc", "receiver", "lat", "lon"]
    assert set(OBSERVATION_COLUMNS) - set(OBS["required"]) == {"h", "position_sd"}


def test_rows_the_checks_accept_validate(tmp_path):
    """The sample city's observations and a CSV with gaps and lower-case letters, as the checks
    return them, validate row by row."""
    sample = pd.read_parquet(CITY / "observations.parquet")
    assert sample["cn0"].isna().any()  # blocked signals are there
    odd = pd.DataFrame([ROW, {**ROW, "constellation": " e ", "h": None, "cn0": None}])
    odd.to_csv(tmp_path / "odd.csv", index=False)
    check = validator(OBS)
    for table in (sample, pd.read_csv(tmp_path / "odd.csv")):
        rows = json_rows(check_observations(table))
        assert len(rows) == len(table)
        errors = [e.message for row in rows for e in check.iter_errors(row)]
        assert errors == []
    assert rows[1]["cn0"] is None and rows[1]["constellation"] == "E"
    assert rows[0]["time_utc"] == "2020-02-11T08:50:00.000Z"


def _edges(spec: dict) -> list:
    """Values at and just beyond a property's bounds, and values of no number type."""
    values = [None, "x"]
    for key, outward in (("minimum", -math.inf), ("maximum", math.inf)):
        if key in spec:
            values += [spec[key], np.nextafter(spec[key], outward), spec[key] + np.sign(outward)]
    if "exclusiveMaximum" in spec:
        edge = spec["exclusiveMaximum"]
        values += [np.nextafter(edge, -math.inf), edge, edge + 1]
    if "integer" in gnss_citygml.contracts.types(spec):
        values += [3.5, 7.0]
    return values


@pytest.mark.parametrize(
    ("column", "value"),
    [(c, v) for c, spec in OBS["properties"].items() for v in _edges(spec)]
    + [("constellation", letter) for letter in [*OBS["properties"]["constellation"]["enum"], "X"]],
)
def test_the_checks_enforce_the_schemas_bounds(column, value):
    """At each bound of the schema (and just beyond it), for empty cells and for values of no
    type the column has, the checks take a row exactly when the schema does."""
    row = {**ROW, column: float(value) if isinstance(value, np.floating) else value}
    assert accepted(row) == validator(OBS).is_valid(row), row


@pytest.mark.parametrize("column", OBSERVATION_COLUMNS)
def test_the_required_columns_are_the_schemas(column):
    row = {k: v for k, v in ROW.items() if k != column}
    assert validator(OBS).is_valid(row) == (column not in OBS["required"])
    if column in OBS["required"]:
        with pytest.raises(MissingColumnError, match=f"'{column}'"):
            check_observations(pd.DataFrame([row]))
    else:
        assert check_observations(pd.DataFrame([row]))[column].isna().all()


# --- heights ------------------------------------------------------------------------------------


def test_the_heights_schema_has_the_models_columns_in_order():
    heights = load(HEIGHTS)
    assert list(heights["properties"])[: len(HEIGHTS_COLUMNS)] == HEIGHTS_COLUMNS
    assert heights["required"] == ["id", "height"]
    assert "footprints' id field, `id` by default" in heights["properties"]["id"]["description"]


@pytest.fixture(scope="module")
def estimated():
    """The heights layer of the Python estimate on the sample city (its attributes)."""
    observations = gnss_citygml.read_observations(CITY / "observations.parquet")
    footprints = gnss_citygml.read_footprints(CITY / "footprints.gpkg")
    layer = gnss_citygml.estimate(observations, footprints, dem=str(CITY / "dem.tif"))
    return pd.DataFrame(layer.drop(columns="geometry"))


def test_heights_tables_the_toolkit_writes_validate(estimated, rng):
    from conftest import synthetic_intersections

    check = validator(load(HEIGHTS))
    assert set(estimated.columns) <= set(load(HEIGHTS)["properties"])
    assert not estimated["converged"].all()  # rows without an estimate are there too
    tables = [estimated]
    intersections = pd.concat(
        [synthetic_intersections(rng), synthetic_intersections(rng, building="few", n=5)]
    )
    for method in gnss_citygml.METHODS:
        tables.append(estimate_heights(intersections, gnss_citygml.Estimator(method=method)))
    for table in tables:
        assert table["height"].isna().any()
        errors = [e.message for row in json_rows(table) for e in check.iter_errors(row)]
        assert errors == []


@pytest.mark.parametrize("column", ["id", "height", "ground", "converged", "n_signals"])
def test_the_export_requires_the_schemas_required_columns(estimated, column):
    footprints = gnss_citygml.read_footprints(CITY / "footprints.gpkg")
    table = estimated.drop(columns=[column])
    if column in load(HEIGHTS)["required"]:
        with pytest.raises(MissingColumnError, match=f"'{column}'.*heights.csv"):
            footprints_with_heights(footprints, table, where="heights.csv")
    else:
        joined = footprints_with_heights(footprints, table)
        assert len(joined) == len(footprints)
        if column == "converged":  # read off the status, which says why not
            assert (joined["converged"] == (joined["status"] == "ok")).all()
        else:
            assert column not in joined


def test_a_table_without_converged_trusts_only_the_rows_its_status_says_ok(estimated):
    """The schema's status says why a building has no estimate to trust: a table without
    converged whose heights are filled in (99 m) where the status is not ok writes none of
    them (found at the command line: 30 buildings written where estimate trusted 24)."""
    from gnss_citygml.export import prepare_buildings

    footprints = gnss_citygml.read_footprints(CITY / "footprints.gpkg")
    table = estimated.drop(columns="converged")
    failed = table["status"] != "ok"
    table.loc[failed, "height"] = 99.0
    table.loc[table.index[0], "status"] = None  # no status: nothing said against it
    plan = prepare_buildings(footprints_with_heights(footprints, table.assign(ground=20.0)))
    skipped = {key for key, _ in plan.skipped}
    assert skipped == set(table["id"][failed & table["status"].notna()])
    assert failed.sum() > 0 and table["id"].iloc[0] not in skipped


def test_the_required_id_is_named_like_the_footprints_id_field(estimated):
    """With footprints whose ids come from a field ``toid``, the heights table's id column is
    ``toid`` (or ``id``): a table without it, or without a height, is refused naming them."""
    footprints = with_id_field(gnss_citygml.read_footprints(CITY / "footprints.gpkg"), "toid")
    table = estimated.rename(columns={"id": "toid"})
    assert len(footprints_with_heights(footprints, table)) == len(footprints)
    with pytest.raises(MissingColumnError, match=r"'height' .*has: toid, ground"):
        footprints_with_heights(footprints, table.drop(columns="height"))
    with pytest.raises(MissingColumnError, match=r"missing column\(s\) 'toid' "):
        footprints_with_heights(footprints, table.drop(columns="toid"))


# --- the CityJSON Extension ---------------------------------------------------------------------


def test_the_extension_types_the_heights_columns():
    """Each column of the heights table but the id is a Building attribute '+column' of the
    column's type (values are left out rather than null) and bounds."""
    extension = load(EXTENSION)
    attributes = extension["extraAttributes"]["Building"]
    columns = {k: v for k, v in load(HEIGHTS)["properties"].items() if k != "id"}
    assert list(attributes) == ["+" + name for name in columns]
    for name, spec in columns.items():
        typed = attributes["+" + name]
        assert {typed["type"], "null"} == set(spec["type"]), name
        assert typed.get("minimum") == spec.get("minimum") and typed["description"], name


def test_the_extension_file_follows_the_cityjson_2_extension_rules():
    """The rules of CityJSON 2.0's extension.schema.json and of a file's ``extensions``."""
    extension = load(EXTENSION)
    members = ("extraAttributes", "extraCityObjects", "extraRootProperties")
    assert extension["type"] == "CityJSONExtension" and all(m in extension for m in members)
    assert "extraSemanticSurfaces" in extension
    assert re.fullmatch(r"\w[a-zA-Z@#0-9._]*", extension["name"])
    assert re.fullmatch(r"(\d+\.)(\d+)", extension["version"])  # as a CityJSON file names it
    assert extension["versionCityJSON"] == "2.0"
    assert extension["url"] == BASE + EXTENSION
    assert all(re.fullmatch(r"\+\w+", name) for name in extension["extraAttributes"]["Building"])

"""The algorithms through QGIS's Processing framework, on simulated scenes and real GnssLogger
logs: the plugin's observations, heights and reports are the command line's, its city models
validate, its errors are the command line's one-line messages, Cancel stops it without an
output, its layer opens styled and its report page in the browser."""

import json
import shutil
from pathlib import Path

import geopandas as gpd
import numpy as np
import pandas as pd
import pytest
from conftest import ROOT, assert_same_heights, cli, estimate_with_the_cli
from qgis.core import (
    QgsApplication,
    QgsFillSymbol,
    QgsProcessingContext,
    QgsProcessingException,
    QgsProcessingFeatureSourceDefinition,
    QgsProcessingFeedback,
    QgsProject,
    QgsSingleSymbolRenderer,
    QgsVectorLayer,
)

from gnss_citygml.validate import validate_file

#: Options of `gnss-citygml estimate` and the plugin's parameters for them: the defaults,
#: and a set that changes every option the plugin maps.
OPTIONS = {
    "defaults": ([], {}),
    "changed": (
        [
            "--min-elevation",
            "15",
            "--max-elevation",
            "80",
            "--receiver-height",
            "dem",
            "--antenna-height",
            "1.2",
            "--init-threshold",
            "28",
            "--method",
            "4PL",
            "--max-range",
            "250",
            "--position-sd",
            "1",
        ],
        {
            "MIN_ELEVATION": 15,
            "MAX_ELEVATION": 80,
            "RECEIVER_HEIGHT": 0,
            "ANTENNA_HEIGHT": 1.2,
            "INIT_THRESHOLD": 28,
            "METHOD": 1,
            "MAX_RANGE": 250,
            "POSITION_SD": 1,
        },
    ),
    "mixture": (["--signal-model", "mixture"], {"SIGNAL_MODEL": 1}),
    # caps that cut the city scene's fits (19 heights, not 21) and still give heights
    "caps": (["--max-iter", "10", "--fit-max-iter", "40"], {"MAX_ITER": 10, "FIT_MAX_ITER": 40}),
}


def _inputs(scene, output, **extra):
    return {
        "OBSERVATIONS": str(scene["observations"]),
        "FOOTPRINTS": f"{scene['footprints']}|layername=footprints",
        "DEM": str(scene["dem"]),
        "OUTPUT": str(output),
        **extra,
    }


@pytest.mark.parametrize("options", sorted(OPTIONS))
def test_the_plugins_heights_are_the_clis(plugin, processing_framework, scene, options, tmp_path):
    flags, parameters = OPTIONS[options]
    theirs = estimate_with_the_cli(scene, tmp_path / "cli.gpkg", *flags)
    result = processing_framework.run(
        "gnsscitygml:estimate", _inputs(scene, tmp_path / "plugin.gpkg", **parameters)
    )
    assert result["OUTPUT"] == f"{tmp_path / 'plugin.gpkg'}|layername=heights"
    ours = gpd.read_file(tmp_path / "plugin.gpkg", layer="heights")
    assert result["BUILDINGS"] == len(ours) == len(theirs) > 0
    assert result["CONVERGED"] == int(ours["converged"].sum())
    assert_same_heights(ours, theirs)


@pytest.mark.parametrize("suffix", [".city.json", ".city.jsonl", ".gml"])
def test_convert_writes_what_validate_accepts(
    plugin, processing_framework, scene, suffix, tmp_path
):
    estimated = processing_framework.run(
        "gnsscitygml:estimate", _inputs(scene, tmp_path / "h.gpkg")
    )
    model = tmp_path / f"model{suffix}"
    converted = processing_framework.run(
        "gnsscitygml:convert", {"INPUT": estimated["OUTPUT"], "OUTPUT": str(model)}
    )
    assert converted["WRITTEN"] == estimated["CONVERGED"] > 0
    assert converted["SKIPPED"] == estimated["BUILDINGS"] - estimated["CONVERGED"]
    assert converted["VALIDATED"] and model.is_file()
    checked = processing_framework.run(
        "gnsscitygml:validate", {"INPUT": str(model), "ERRORS": "TEMPORARY_OUTPUT"}
    )
    assert checked["VALID"] and checked["N_ERRORS"] == 0
    assert checked["ERRORS"].featureCount() == 0
    assert cli("validate", model, check=False).returncode == 0  # and the command line agrees


def test_validate_lists_the_errors_of_a_broken_model(plugin, processing_framework, tmp_path):
    broken = tmp_path / "broken.city.json"
    broken.write_text(
        '{"type": "CityJSON", "version": "2.0", "transform": {"scale": [1, 1, 1], '
        '"translate": [0, 0, 0]}, "CityObjects": {"b1": {"type": "Building", "geometry": '
        '[{"type": "Solid", "lod": "1", "boundaries": [[[[0, 1, 9]]]]}]}}, "vertices": '
        "[[0, 0, 0], [1, 0, 0]]}"
    )
    checked = processing_framework.run(
        "gnsscitygml:validate", {"INPUT": str(broken), "ERRORS": "TEMPORARY_OUTPUT"}
    )
    assert not checked["VALID"] and checked["N_ERRORS"] > 0
    rows = [f.attributes()[1:] for f in checked["ERRORS"].getFeatures()]
    assert rows == [[i.rule, i.message] for i in validate_file(broken).errors]
    assert cli("validate", broken, check=False).returncode == 1


def test_validate_checks_a_tileset_as_one(plugin, processing_framework, tmp_path):
    """A tileset.json (here without content, so no GLB) is a tileset, not a bad CityJSON."""
    box = [0, 0, 0, 10, 0, 0, 0, 10, 0, 0, 0, 10]
    root = {"boundingVolume": {"box": box}, "geometricError": 0}
    good = {"asset": {"version": "1.1"}, "geometricError": 1, "root": root}
    bad = {"asset": {"version": "1.1"}, "root": {"boundingVolume": {"box": box}}}
    for name, doc in (("good", good), ("bad", bad)):
        (tmp_path / name).mkdir()
        (tmp_path / name / "tileset.json").write_text(json.dumps(doc))
    checked = processing_framework.run(
        "gnsscitygml:validate", {"INPUT": str(tmp_path / "good" / "tileset.json")}
    )
    assert checked["VALID"] and "3D Tiles 1.1" in checked["SUMMARY"]
    broken = tmp_path / "bad" / "tileset.json"
    checked = processing_framework.run(
        "gnsscitygml:validate", {"INPUT": str(broken), "ERRORS": "TEMPORARY_OUTPUT"}
    )
    assert not checked["VALID"] and "3D Tiles 1.1" in checked["SUMMARY"]
    rows = [f.attributes()[1:] for f in checked["ERRORS"].getFeatures()]
    assert rows == [[i.rule, i.message] for i in validate_file(broken).errors]
    assert {rule for rule, _ in rows} == {"json-schema"}


def test_errors_are_the_clis_one_line_messages(plugin, processing_framework, scene, tmp_path):
    observations = tmp_path / "observations.csv"
    table = (
        pd.read_parquet(scene["observations"])
        if scene["observations"].suffix == ".parquet"
        else pd.read_csv(scene["observations"])
    )
    table.drop(columns="elevation").to_csv(observations, index=False)
    bad = {**scene, "observations": observations}
    message = (
        cli(
            "estimate",
            observations,
            scene["footprints"],
            "--dem",
            scene["dem"],
            "-o",
            tmp_path / "cli.gpkg",
            check=False,
        )
        .stderr.strip()
        .splitlines()[-1]
    )
    assert message.startswith("error: ") and "elevation" in message
    with pytest.raises(QgsProcessingException) as raised:
        processing_framework.run("gnsscitygml:estimate", _inputs(bad, tmp_path / "p.gpkg"))
    assert str(raised.value) == message.removeprefix("error: ")
    assert not (tmp_path / "p.gpkg").exists()


@pytest.mark.parametrize("name", ["gnsscitygml:estimate", "gnsscitygml:update"])
def test_the_signal_model_reaches_the_library(plugin, processing_framework, scene, name, tmp_path):
    """The mixture signal model with a method that has no signal model: the library's own
    one-line refusal, so the choice reached its estimator; nothing written."""
    map_ = tmp_path / "map.gpkg"
    shutil.copy(scene["footprints"], map_)
    # the map as a project layer, given by id and removed after (as the update test does: a
    # layer object left to Python's collector crashes QGIS when it exits)
    layer = QgsVectorLayer(f"{map_}|layername=footprints", "map", "ogr")
    QgsProject.instance().addMapLayer(layer)
    inputs = {
        "gnsscitygml:estimate": _inputs(scene, tmp_path / "h.gpkg"),
        "gnsscitygml:update": {
            "MAP": layer.id(),
            "OBSERVATIONS": [str(scene["observations"])],
            "DEM": str(scene["dem"]),
        },
    }[name]
    try:
        with pytest.raises(QgsProcessingException) as raised:
            processing_framework.run(name, {**inputs, "METHOD": 2, "SIGNAL_MODEL": 1})
    finally:
        QgsProject.instance().removeMapLayer(layer.id())
    assert str(raised.value).startswith("signal model mixture needs method 4PL-B, not hinge")
    assert not (tmp_path / "h.gpkg").exists() and not (tmp_path / "map.bak.gpkg").exists()


class _CancelAfter(QgsProcessingFeedback):
    """Presses Cancel once the job reports its ``n``-th stage."""

    def __init__(self, n):
        super().__init__()
        self.n = n
        self.stages = []

    def setProgressText(self, text):  # noqa: N802 (QGIS's name)
        self.stages.append(text)
        if len(self.stages) == self.n:
            self.cancel()
        super().setProgressText(text)


def test_cancel_stops_the_job_and_writes_nothing(plugin, scene, tmp_path):
    """Cancel once the first stage has begun: the child stops (reading and casting are still
    ahead of it) and leaves nothing behind."""
    algorithm = QgsApplication.processingRegistry().createAlgorithmById("gnsscitygml:estimate")
    feedback = _CancelAfter(1)
    output = tmp_path / "cancelled.gpkg"
    with pytest.raises(QgsProcessingException, match="cancelled: nothing was written"):
        algorithm.run(_inputs(scene, output), QgsProcessingContext(), feedback, {}, False)
    assert len(feedback.stages) <= 2  # the child stops at once, or a stage later
    assert not output.exists() and not list(tmp_path.iterdir())


def test_a_cancel_too_late_leaves_the_whole_output(plugin, scene, tmp_path):
    """Cancel late in a small job may come after the child has finished: then the output is
    whole, never half of it."""
    algorithm = QgsApplication.processingRegistry().createAlgorithmById("gnsscitygml:estimate")
    output = tmp_path / "late.gpkg"
    try:
        algorithm.run(_inputs(scene, output), QgsProcessingContext(), _CancelAfter(5), {}, False)
    except QgsProcessingException as exc:
        assert str(exc) == "cancelled: nothing was written"
        assert not list(tmp_path.iterdir())
    else:
        assert len(gpd.read_file(output, layer="heights")) > 0
        assert [p.name for p in tmp_path.iterdir()] == ["late.gpkg"]


def test_the_layer_opens_styled(plugin, processing_framework, scene, tmp_path):
    """From the plugin (loaded into the project) and from the CLI's file (opened in QGIS)."""
    project = QgsProject.instance()
    project.clear()
    result = processing_framework.runAndLoadResults(
        "gnsscitygml:estimate", _inputs(scene, tmp_path / "h.gpkg")
    )
    (layer,) = project.mapLayers().values()
    assert layer.source() == result["OUTPUT"]
    assert layer.featureCount() == result["BUILDINGS"]
    _assert_styled(layer)
    # the user styles it their way and saves that as the layer's default in the file: a rerun
    # into the same file keeps theirs
    layer.setRenderer(QgsSingleSymbolRenderer(QgsFillSymbol.createSimple({"color": "red"})))
    assert layer.saveStyleToDatabase("mine", "", True, "") == ""
    project.clear()
    processing_framework.runAndLoadResults(
        "gnsscitygml:estimate", _inputs(scene, tmp_path / "h.gpkg")
    )
    (layer,) = project.mapLayers().values()
    assert layer.renderer().type() == "singleSymbol"
    assert layer.renderer().symbol().color().name() == "#ff0000"
    estimate_with_the_cli(scene, tmp_path / "cli.gpkg")
    _assert_styled(QgsVectorLayer(f"{tmp_path / 'cli.gpkg'}|layername=heights", "cli", "ogr"))
    project.clear()


def _assert_styled(layer):
    assert layer.isValid()
    renderer = layer.renderer()
    assert renderer.type() == "RuleRenderer"
    filters = [rule.filterExpression() for rule in renderer.rootRule().children()]
    assert any("relative_height" in f for f in filters) and 'NOT "converged"' in filters[-1]
    assert layer.renderer3D() is not None and layer.renderer3D().type() == "vector"
    assert not layer.labelsEnabled() and layer.labeling() is not None


def test_a_python_without_the_library_is_named_with_the_fix(
    plugin, processing_framework, scene, monkeypatch, tmp_path
):
    """$GNSS_CITYGML_PYTHON naming a Python that cannot import the library (Debian's own)."""
    monkeypatch.setenv("GNSS_CITYGML_PYTHON", "/usr/bin/python3")
    with pytest.raises(QgsProcessingException) as raised:
        processing_framework.run("gnsscitygml:estimate", _inputs(scene, tmp_path / "h.gpkg"))
    message = str(raised.value)
    assert message.startswith("/usr/bin/python3 cannot run gnss-citygml (")
    assert "No module named 'gnss_citygml'" in message
    assert '"/usr/bin/python3" -m pip install --user --upgrade gnss-citygml' in message
    monkeypatch.setenv("GNSS_CITYGML_PYTHON", str(tmp_path / "no-python"))
    with pytest.raises(QgsProcessingException, match="GNSS_CITYGML_PYTHON names .*no-python, wh"):
        processing_framework.run("gnsscitygml:estimate", _inputs(scene, tmp_path / "h.gpkg"))


def test_selected_features_only(plugin, processing_framework, scene, tmp_path):
    """A selection in QGIS is what the analyst means: the source is exported for the job."""
    footprints = QgsVectorLayer(f"{scene['footprints']}|layername=footprints", "fp", "ogr")
    QgsProject.instance().addMapLayer(footprints)
    try:
        chosen = [f.id() for f in footprints.getFeatures()][:2]
        footprints.selectByIds(chosen)
        wanted = sorted(f["id"] for f in footprints.getSelectedFeatures())
        source = QgsProcessingFeatureSourceDefinition(footprints.id(), True)
        result = processing_framework.run(
            "gnsscitygml:estimate", {**_inputs(scene, tmp_path / "h.gpkg"), "FOOTPRINTS": source}
        )
    finally:
        QgsProject.instance().removeMapLayer(footprints.id())
    heights = gpd.read_file(tmp_path / "h.gpkg", layer="heights")
    assert result["BUILDINGS"] == len(wanted) == 2 and sorted(heights["id"]) == wanted


def test_update_a_map_in_the_project_as_the_cli_does(plugin, processing_framework, scene, tmp_path):
    """The map layer open in QGIS is updated in place, then reloaded: it shows the new columns;
    the values are the command line's on a twin of the map."""

    ours, twin = tmp_path / "ours.gpkg", tmp_path / "twin.gpkg"
    shutil.copy(scene["footprints"], ours)
    shutil.copy(scene["footprints"], twin)
    layer = QgsVectorLayer(f"{ours}|layername=footprints", "map", "ogr")
    QgsProject.instance().addMapLayer(layer)
    try:
        result = processing_framework.run(
            "gnsscitygml:update",
            {
                "MAP": layer.id(),
                "OBSERVATIONS": [str(scene["observations"])],
                "DEM": str(scene["dem"]),
            },
        )
        assert result["WRITTEN"] and result["UPDATED"] > 0
        assert "height_gnss" in layer.fields().names()  # reloaded from the new file
        shown = {f["id"]: f["height_gnss"] for f in layer.getFeatures()}
    finally:
        QgsProject.instance().removeMapLayer(layer.id())
    cli("update", twin, "--observations", scene["observations"], "--dem", scene["dem"], "-q")
    theirs = gpd.read_file(twin, layer="footprints").set_index("id")["height_gnss"]
    mine = gpd.read_file(ours, layer="footprints").set_index("id")["height_gnss"]
    np.testing.assert_allclose(mine.loc[theirs.index], theirs, atol=1e-3, equal_nan=True)
    assert len(shown) == len(theirs)
    assert (tmp_path / "ours.bak.gpkg").is_file()


# --- observe: real GnssLogger logs and orbit files ---------------------------------------------

#: The shared data's logs and orbits that the repository keeps (tests/data, laid out as the
#: shared folder): two logs of two days, each with its own navigation file.
DATA = ROOT / "tests" / "data"
LOGS = [
    DATA / "gnss" / "google_demo_pseudoranges_log_2016_08_22_14_45_50.txt",
    DATA / "gnss" / "google_demo_pseudoranges_log_2016_06_30_21_26_07.txt",
]
ORBITS = [DATA / "orbits" / "hour2350.16n", DATA / "orbits" / "hour1820.16n"]

#: Options of `gnss-citygml observe` and the plugin's parameters for them ({positions}: a file
#: of surveyed positions the test writes), and the output's suffix.
OBSERVE_OPTIONS = {
    "defaults": ([], {}, ".parquet"),
    "changed": (
        ["--min-elevation", "15", "--max-elevation", "80", "--interpolate", "--lenient"],
        {"MIN_ELEVATION": 15, "MAX_ELEVATION": 80, "INTERPOLATE": True, "LENIENT": True},
        ".parquet",
    ),
    "surveyed": (["--positions", "{positions}"], {"POSITIONS": "{positions}"}, ".csv"),
}

SURVEYED = """receiver,start_utc,end_utc,lat,lon,h,sd
{0},2016-08-22T00:00:00Z,2016-08-23T00:00:00Z,37.422,-122.084,,0.5
{1},2016-06-30T00:00:00Z,2016-07-01T00:00:00Z,37.4221,-122.0841,10,0.2
"""


def _observe_inputs(output, **extra):
    return {
        "LOGS": [str(log) for log in LOGS],
        "ORBITS": [str(orbit) for orbit in ORBITS],
        "OUTPUT": str(output),
        **extra,
    }


@pytest.mark.parametrize("options", sorted(OBSERVE_OPTIONS))
def test_the_plugins_observations_are_the_clis(plugin, processing_framework, options, tmp_path):
    flags, parameters, suffix = OBSERVE_OPTIONS[options]
    positions = tmp_path / "positions.csv"
    positions.write_text(SURVEYED.format(*(log.stem for log in LOGS)))
    flags = [flag.format(positions=positions) for flag in flags]
    parameters = {k: str(v).format(positions=positions) if k == "POSITIONS" else v
                  for k, v in parameters.items()}  # fmt: skip
    theirs, ours = tmp_path / f"cli{suffix}", tmp_path / f"plugin{suffix}"
    orbits = [flag for orbit in ORBITS for flag in ("--orbits", orbit)]
    said = cli("observe", *LOGS, *orbits, *flags, "-o", theirs, "-q").stdout.strip()
    result = processing_framework.run("gnsscitygml:observe", _observe_inputs(ours, **parameters))
    assert result["OUTPUT"] == str(ours)
    if suffix == ".csv":
        assert ours.read_text() == theirs.read_text()
        table = pd.read_csv(ours)
    else:
        table = pd.read_parquet(ours)
        pd.testing.assert_frame_equal(table, pd.read_parquet(theirs))
    assert result["SIGNALS"] == len(table) > 0 and said.startswith(f"{len(table)} signals (")
    assert sorted(table["receiver"].unique()) == sorted(log.stem for log in LOGS)
    if options == "surveyed":
        assert set(table["position_sd"]) == {0.5, 0.2}


def test_observe_errors_are_the_clis(plugin, processing_framework, tmp_path):
    """A band the logs do not have (the choice reaches the library): the command line's
    one-line message, and nothing written."""
    orbits = [flag for orbit in ORBITS for flag in ("--orbits", orbit)]
    message = cli("observe", *LOGS, *orbits, "--band", "L5", "-o", tmp_path / "cli.parquet",
                  check=False).stderr.strip().splitlines()[-1]  # fmt: skip
    assert message.startswith("error: no L5 measurements in the log")
    with pytest.raises(QgsProcessingException) as raised:
        processing_framework.run(
            "gnsscitygml:observe", _observe_inputs(tmp_path / "p.parquet", BAND=1)
        )
    assert str(raised.value) == message.removeprefix("error: ")
    assert not list(tmp_path.iterdir())


# --- report ------------------------------------------------------------------------------------


def _buildings_tables(folder):
    """The report page's tables of the buildings: what depends neither on the time nor on how
    the figures were compressed."""
    page = (folder / "report.html").read_text(encoding="utf-8")
    return page.split("<h2>Buildings by status</h2>")[1]


class _Browser:
    """Stands in for QDesktopServices: the pages it was asked to open."""

    opened = []

    @classmethod
    def openUrl(cls, url):  # noqa: N802 (Qt's name)
        cls.opened.append(url.toLocalFile())
        return True


def test_the_plugins_report_is_the_clis(plugin, processing_framework, scene, monkeypatch, tmp_path):
    """The same tables of buildings (with the truth's heights and errors) and the same
    figures; the page opens in the browser (in QGIS's desktop, unless OPEN is unticked), never
    in a headless QGIS."""
    import gnss_citygml_qgis.report as report

    truth = scene["folder"] / "truth.csv"
    inputs = [scene["observations"], scene["footprints"], "--dem", scene["dem"]]
    cli("report", *inputs, "--truth", truth, "-o", tmp_path / "cli", "-q")
    assert not report.shows_pages()  # (pytest-qgis's QGIS is no desktop)
    monkeypatch.setattr(report, "shows_pages", lambda: True)
    monkeypatch.setattr(report, "QDesktopServices", _Browser)
    monkeypatch.setattr(_Browser, "opened", [])
    folder = tmp_path / "plugin"
    parameters = {**_inputs(scene, folder), "TRUTH": str(truth)}
    result = processing_framework.run("gnsscitygml:report", parameters)
    page = folder / "report.html"
    assert result["OUTPUT"] == str(folder) and result["PAGE"] == str(page)
    assert _Browser.opened == [str(page)]
    assert _buildings_tables(folder) == _buildings_tables(tmp_path / "cli")
    assert "<th>error</th>" in _buildings_tables(folder)
    figures = sorted(p.name for p in (tmp_path / "cli" / "figures").iterdir())
    assert sorted(p.name for p in (folder / "figures").iterdir()) == figures
    for figure in figures:
        assert (folder / "figures" / figure).read_bytes().startswith(b"\x89PNG")
    heights = estimate_with_the_cli(scene, tmp_path / "cli.gpkg")
    assert result["BUILDINGS"] == len(heights) and result["CONVERGED"] == heights["converged"].sum()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["cli", "cli.gpkg", "plugin"]
    # into a temporary folder (the dialog's default), OPEN unticked: not opened
    again = {**_inputs(scene, "TEMPORARY_OUTPUT"), "OPEN": False}
    result = processing_framework.run("gnsscitygml:report", again)
    assert result["PAGE"].startswith(result["OUTPUT"]) and result["PAGE"].endswith("report.html")
    assert Path(result["PAGE"]).is_file() and _Browser.opened == [str(page)]

"""End to end through QGIS's own command line, ``qgis_process``: the plugin enabled from
QGIS_PLUGINPATH in a throwaway profile, then each algorithm run as an analyst's script would.
(Debian's ``qgis_process`` wrapper fails with "--noversioncheck"; the binary is called.)"""

import json
import subprocess

import geopandas as gpd
from conftest import assert_same_heights, estimate_with_the_cli


def qgis_process(env, *args):
    process = subprocess.run(
        ["qgis_process.bin", *map(str, args)],
        capture_output=True,
        text=True,
        env=env,
        timeout=600,
    )
    assert process.returncode == 0, process.stdout[-2000:] + process.stderr[-2000:]
    return process.stdout


def run(env, algorithm, **parameters):
    out = qgis_process(
        env, "--json", "run", algorithm, "--", *(f"{k}={v}" for k, v in parameters.items())
    )
    return json.loads(out)["results"]


def test_enable_and_run_every_algorithm(qgis_env, scene, tmp_path):
    listed = qgis_process(qgis_env, "plugins", "enable", "gnss_citygml_qgis")
    assert "gnss_citygml_qgis" in listed
    assert "gnsscitygml:estimate" in qgis_process(qgis_env, "list")

    output = tmp_path / "heights.gpkg"
    estimated = run(
        qgis_env,
        "gnsscitygml:estimate",
        OBSERVATIONS=scene["observations"],
        FOOTPRINTS=scene["footprints"],
        DEM=scene["dem"],
        MIN_ELEVATION=12,
        OUTPUT=output,
    )
    assert estimated["OUTPUT"] == f"{output}|layername=heights"
    theirs = estimate_with_the_cli(scene, tmp_path / "cli.gpkg", "--min-elevation", "12")
    ours = gpd.read_file(output, layer="heights")
    assert estimated["CONVERGED"] == ours["converged"].sum() > 0
    assert_same_heights(ours, theirs)

    model = tmp_path / "city.gml"
    converted = run(qgis_env, "gnsscitygml:convert", INPUT=estimated["OUTPUT"], OUTPUT=model)
    assert converted["WRITTEN"] == estimated["CONVERGED"] and converted["VALIDATED"]
    checked = run(qgis_env, "gnsscitygml:validate", INPUT=model, ERRORS=tmp_path / "errors.gpkg")
    assert checked["VALID"] and checked["N_ERRORS"] == 0

    home = tmp_path / "home"
    assert not home.exists() or not any(home.rglob("*")), sorted(home.rglob("*"))

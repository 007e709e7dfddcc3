"""End to end through QGIS's own command line, ``qgis_process``: the plugin enabled from
QGIS_PLUGINPATH in a throwaway profile, then each algorithm run as an analyst's script would.
(Debian's ``qgis_process`` wrapper fails with "--noversioncheck"; the binary is called.)"""

import json
import subprocess

import geopandas as gpd
import pandas as pd
from conftest import ROOT, assert_same_heights, estimate_with_the_cli


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
    """Run ``algorithm``; a list is given as its parameter repeated (LOGS=a LOGS=b)."""
    values = [
        (k, v) for k, vs in parameters.items() for v in (vs if isinstance(vs, list) else [vs])
    ]
    out = qgis_process(env, "--json", "run", algorithm, "--", *(f"{k}={v}" for k, v in values))
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

    data = ROOT / "tests" / "data"
    logs = [
        data / "gnss" / "google_demo_pseudoranges_log_2016_08_22_14_45_50.txt",
        data / "gnss" / "google_demo_pseudoranges_log_2016_06_30_21_26_07.txt",
    ]
    orbits = [data / "orbits" / "hour2350.16n", data / "orbits" / "hour1820.16n"]
    observations = tmp_path / "observations.parquet"
    observed = run(qgis_env, "gnsscitygml:observe", LOGS=logs, ORBITS=orbits, OUTPUT=observations)
    table = pd.read_parquet(observations)
    assert observed["SIGNALS"] == len(table) > 0 and table["receiver"].nunique() == 2

    # the page is not opened by a QGIS without its desktop (OPEN is left ticked)
    reported = run(
        qgis_env,
        "gnsscitygml:report",
        OBSERVATIONS=scene["observations"],
        FOOTPRINTS=scene["footprints"],
        DEM=scene["dem"],
        MIN_ELEVATION=12,
        OUTPUT=tmp_path / "report",
    )
    assert reported["PAGE"] == str(tmp_path / "report" / "report.html")
    assert reported["CONVERGED"] == estimated["CONVERGED"]
    assert (tmp_path / "report" / "report.html").is_file()

    home = tmp_path / "home"
    assert not home.exists() or not any(home.rglob("*")), sorted(home.rglob("*"))

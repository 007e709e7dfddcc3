"""What the QGIS plugin's door costs: the sample city estimated by the command line, by the
plugin through Processing (a child Python runs the job) and by ``qgis_process``, best of three.

Run in the QGIS tests' environment (`make bench` does, when .venv-qgis exists):
    .venv-qgis/bin/python benchmarks/qgis_plugin.py
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import sysconfig
import tempfile
import time
from pathlib import Path

os.environ.setdefault("QT_QPA_PLATFORM", "offscreen")
ROOT = Path(__file__).resolve().parents[1]
CITY = ROOT / "gnss_citygml" / "data" / "city"
sys.path[:0] = [str(ROOT / "qgis_plugin"), "/usr/share/qgis/python/plugins"]


def best(run, repeats: int = 3) -> float:
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        run()
        times.append(time.perf_counter() - start)
    return min(times)


def main() -> None:
    folder = Path(tempfile.mkdtemp(prefix="gnss-citygml-bench-"))
    city = folder / "city"
    shutil.copytree(CITY, city)
    files = [city / "observations.parquet", city / "footprints.gpkg", "--dem", city / "dem.tif"]
    cli = [sys.executable, "-m", "gnss_citygml", "estimate", *map(str, files), "-q"]

    def command_line():
        subprocess.run(
            [*cli, "-o", str(folder / "cli.gpkg"), "--overwrite"],
            check=True,
            stdout=subprocess.DEVNULL,
        )

    from qgis.core import QgsApplication

    os.environ["QGIS_CUSTOM_CONFIG_PATH"] = str(folder / "profile")
    app = QgsApplication([], False)
    app.initQgis()
    from processing.core.Processing import Processing

    Processing.initialize()
    import gnss_citygml_qgis
    import processing

    plugin = gnss_citygml_qgis.classFactory(None)
    plugin.initProcessing()
    inputs = {
        "OBSERVATIONS": str(city / "observations.parquet"),
        "FOOTPRINTS": str(city / "footprints.gpkg"),
        "DEM": str(city / "dem.tif"),
    }

    def through_processing():
        processing.run("gnsscitygml:estimate", {**inputs, "OUTPUT": str(folder / "p.gpkg")})

    env = {
        **os.environ,
        "QGIS_PLUGINPATH": str(ROOT / "qgis_plugin"),
        "PYTHONPATH": os.pathsep.join([str(ROOT), sysconfig.get_paths()["purelib"]]),
        "XDG_CACHE_HOME": str(folder / "cache"),
        "XDG_CONFIG_HOME": str(folder / "config"),
    }
    process = ["qgis_process.bin"]
    subprocess.run([*process, "plugins", "enable", "gnss_citygml_qgis"], env=env, check=True,
                   capture_output=True)  # fmt: skip
    arguments = [f"{k}={v}" for k, v in inputs.items()] + [f"OUTPUT={folder / 'q.gpkg'}"]

    def through_qgis_process():
        subprocess.run([*process, "run", "gnsscitygml:estimate", "--", *arguments], env=env,
                       check=True, capture_output=True)  # fmt: skip

    print("sample city (30 buildings, 38,475 signals), estimate, best of 3:")
    for name, run in [
        ("gnss-citygml estimate (a new Python)", command_line),
        ("plugin, processing.run (child Python)", through_processing),
        ("qgis_process.bin run (QGIS + child)", through_qgis_process),
    ]:
        print(f"  {name:40s} {best(run):6.2f} s")
    plugin.unload()
    shutil.rmtree(folder, ignore_errors=True)


if __name__ == "__main__":
    main()

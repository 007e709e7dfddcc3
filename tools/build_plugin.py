"""Build the QGIS plugin's installable zip (`make plugin`): dist/gnss_citygml_qgis-VERSION.zip.

The zip holds the folder ``gnss_citygml_qgis/`` as QGIS's "Install from ZIP" and the plugin
repository expect it, with the project's LICENSE; the version is metadata.txt's, which a test
keeps equal to the library's.
"""

from __future__ import annotations

import configparser
import sys
import zipfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PLUGIN = ROOT / "qgis_plugin" / "gnss_citygml_qgis"


def build(dist: Path = ROOT / "dist") -> Path:
    meta = configparser.ConfigParser()
    meta.read(PLUGIN / "metadata.txt")
    version = meta["general"]["version"]
    dist.mkdir(exist_ok=True)
    target = dist / f"{PLUGIN.name}-{version}.zip"
    tmp = target.with_suffix(".zip.part")
    files = sorted(p for p in PLUGIN.rglob("*") if p.is_file() and "__pycache__" not in p.parts)
    with zipfile.ZipFile(tmp, "w", zipfile.ZIP_DEFLATED) as archive:
        for path in files:
            archive.write(path, path.relative_to(PLUGIN.parent).as_posix())
        archive.write(ROOT / "LICENSE", f"{PLUGIN.name}/LICENSE")
    tmp.replace(target)
    return target


if __name__ == "__main__":
    print(build(Path(sys.argv[1]) if len(sys.argv) > 1 else ROOT / "dist"))

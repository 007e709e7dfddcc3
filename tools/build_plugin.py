"""Build the QGIS plugin's installable zip (`make plugin`): dist/gnss_citygml_qgis-VERSION.zip.

The zip holds the folder ``gnss_citygml_qgis/`` as QGIS's "Install from ZIP" and the plugin
repository expect it, with the project's LICENSE and the library's own wheel in
``gnss_citygml_qgis/wheels/`` (what "Set up gnss-citygml" installs, with its requirements from
the package index); the version is metadata.txt's, which a test keeps equal to the library's.

The wheel is built from a copy of the library's files (nothing is written into the tree) by
``pip wheel --no-deps``: without build isolation when this Python has the build backend
(setuptools, as pyproject.toml asks: the development environment, offline), else with it (pip
fetches setuptools from the package index).
"""

from __future__ import annotations

import configparser
import os
import re
import shutil
import subprocess
import sys
import tempfile
import zipfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PLUGIN = ROOT / "qgis_plugin" / "gnss_citygml_qgis"

#: What the wheel is built from.
SOURCES = ("pyproject.toml", "README.md", "LICENSE", "gnss_citygml")


def build(dist: Path = ROOT / "dist", python: str = sys.executable) -> Path:
    meta = configparser.ConfigParser()
    meta.read(PLUGIN / "metadata.txt")
    version = meta["general"]["version"]
    dist.mkdir(parents=True, exist_ok=True)
    target = dist / f"{PLUGIN.name}-{version}.zip"
    tmp = target.with_suffix(".zip.part")
    files = sorted(
        p
        for p in PLUGIN.rglob("*")
        if p.is_file() and "__pycache__" not in p.parts and "wheels" not in p.parts
    )
    with tempfile.TemporaryDirectory() as folder:
        wheel = build_wheel(Path(folder), python)
        with zipfile.ZipFile(tmp, "w", zipfile.ZIP_DEFLATED) as archive:
            for path in files:
                archive.write(path, path.relative_to(PLUGIN.parent).as_posix())
            archive.write(ROOT / "LICENSE", f"{PLUGIN.name}/LICENSE")
            # stored: a wheel is a zip already
            archive.write(wheel, f"{PLUGIN.name}/wheels/{wheel.name}", zipfile.ZIP_STORED)
    tmp.replace(target)
    return target


def build_wheel(folder: Path, python: str = sys.executable) -> Path:
    """The library's wheel, built by ``python`` into ``folder``."""
    source = folder / "src"
    _copy_sources(source)
    command = [python, "-m", "pip", "wheel", "--no-deps", "--no-input", "--quiet"]
    if _has_backend(python):
        command.append("--no-build-isolation")
    command += ["--wheel-dir", str(folder / "wheel"), str(source)]
    env = {**os.environ, "PIP_DISABLE_PIP_VERSION_CHECK": "1"}
    done = subprocess.run(command, capture_output=True, text=True, env=env)
    if done.returncode != 0:
        raise RuntimeError(f"pip wheel failed:\n{done.stdout}{done.stderr}")
    (wheel,) = (folder / "wheel").glob("gnss_citygml-*.whl")
    return wheel


def _copy_sources(target: Path) -> None:
    """The library's files (tracked, or new and not ignored, in a git checkout) copied."""
    listed = subprocess.run(
        ["git", "ls-files", "-z", "--cached", "--others", "--exclude-standard", *SOURCES],
        cwd=ROOT,
        capture_output=True,
        text=True,
    )
    if listed.returncode != 0:  # not a git checkout: the files as they are
        for name in SOURCES:
            if (ROOT / name).is_dir():
                ignore = shutil.ignore_patterns("__pycache__", "*.pyc")
                shutil.copytree(ROOT / name, target / name, symlinks=True, ignore=ignore)
            else:
                target.mkdir(parents=True, exist_ok=True)
                shutil.copy2(ROOT / name, target / name)
        return
    for name in filter(None, listed.stdout.split("\0")):
        path = ROOT / name
        if not os.path.lexists(path):  # deleted in the tree, not yet in the index
            continue
        (target / name).parent.mkdir(parents=True, exist_ok=True)
        shutil.copy2(path, target / name, follow_symlinks=False)


def _has_backend(python: str) -> bool:
    """Whether ``python`` has the build backend pyproject.toml asks for (setuptools>=N)."""
    requires = (ROOT / "pyproject.toml").read_text(encoding="utf-8")
    minimum = re.search(r'requires\s*=\s*\["setuptools>=(\d+)', requires)
    needed = int(minimum.group(1)) if minimum else 0
    asked = subprocess.run(
        [python, "-c", "from importlib import metadata; print(metadata.version('setuptools'))"],
        capture_output=True,
        text=True,
    )
    found = re.match(r"\d+", asked.stdout.strip()) if asked.returncode == 0 else None
    return found is not None and int(found.group()) >= needed


if __name__ == "__main__":
    print(build(Path(sys.argv[1]) if len(sys.argv) > 1 else ROOT / "dist"))

"""Where the OSTN15/OSGM15 grids come from: discovery, the bundled copy and downloads.

:mod:`gnss_citygml.geodesy` needs two Ordnance Survey grids on PROJ's search path (:data:`GRIDS`).
This module finds them and nothing else: the transformation and its checks stay in geodesy.

The package ships both grids (:data:`BUNDLED_GRID_DIR`, with Ordnance Survey's 2-clause BSD
notice beside them), so that it works offline with nothing else installed. They are looked for,
in order (:func:`search_dirs`), in an explicit ``grid_dir`` (or ``$GNSS_CITYGML_GRID_DIR``),
pyproj's user data directory, PROJ's data directories and last the bundled copy: a copy the user
or PROJ keeps wins. Only if even the bundled copy is gone (a damaged install) are missing grids
downloaded from PROJ's CDN into the user data directory with ``network=True``
(:func:`fetch_grids`); a grid that cannot be found is a :class:`GridError`, never a fallback to
another transformation. :func:`grid_status` says which copy is used (``gnss-citygml grids``).
"""

from __future__ import annotations

import hashlib
import json
import os
import urllib.request
from pathlib import Path

import pandas as pd
from pyproj.datadir import append_data_dir, get_data_dir, get_user_data_dir
from pyproj.sync import get_proj_endpoint

from ..errors import GnssCityGMLError
from ..files.paths import StrPath

__all__ = [
    "BUNDLED_GRID_DIR",
    "GRIDS",
    "GRID_DIR_ENV",
    "HOW_TO_GET",
    "GridError",
    "add_to_proj_path",
    "fetch_grids",
    "grid_folders",
    "grid_status",
    "search_dirs",
]

#: Environment variable naming a folder that holds the grids.
GRID_DIR_ENV = "GNSS_CITYGML_GRID_DIR"
#: The PROJ grids the transformation needs, with what each is for.
GRIDS = {
    "uk_os_OSTN15_NTv2_OSGBtoETRS.tif": "OSTN15 horizontal shifts (OSGB36 to ETRS89 (2))",
    "uk_os_OSGM15_GB.tif": "OSGM15 geoid (ETRS89 to ODN height (2))",
}
#: The copy of the grids shipped inside the package (a real folder: PROJ opens grids by path),
#: searched last; its README names their source and checksums, its LICENSE their terms.
BUNDLED_GRID_DIR = Path(__file__).resolve().parents[1] / "data" / "grids"
#: How messages name the bundled copy (``source`` in :func:`grid_status`).
_BUNDLED = "bundled with gnss-citygml"

#: How to get the grids, for the fix of an error.
HOW_TO_GET = (
    "reinstall gnss-citygml (it ships them), run `gnss-citygml grids --fetch` (downloads "
    "them into pyproj's user data directory), or "
    + " and ".join(f"`projsync --file {name}`" for name in GRIDS)
    + f", or put them in a folder given by --grid-dir or ${GRID_DIR_ENV}"
)
#: Folders :func:`add_to_proj_path` added to PROJ's search path: not searched for another
#: grid_dir (they hold the grids of an earlier one).
_APPENDED: set[str] = set()


class GridError(GnssCityGMLError):
    """A PROJ grid is missing, cannot be downloaded, or PROJ would not use it."""


def grid_status(grid_dir: StrPath | None = None) -> pd.DataFrame:
    """Where each needed grid is found, for ``gnss-citygml grids``.

    Parameters
    ----------
    grid_dir
        A folder searched first (default ``$GNSS_CITYGML_GRID_DIR``).

    Returns
    -------
    pandas.DataFrame
        One row per grid: ``grid`` (file name), ``purpose``, ``found`` (bool), ``source``
        (which search location: ``"grid_dir"``, ``"$GNSS_CITYGML_GRID_DIR"``, ``"pyproj user
        data directory"``, ``"PROJ data directory"``, ``"bundled with gnss-citygml"``, or
        ``"missing"``) and ``path`` (the file, or ``""``).
    """
    rows = []
    for name, purpose in GRIDS.items():
        hit = _find(name, search_dirs(grid_dir))
        source, path = hit if hit else ("missing", "")
        rows.append((name, purpose, bool(hit), source, str(path)))
    return pd.DataFrame(rows, columns=["grid", "purpose", "found", "source", "path"])


def fetch_grids(
    target_dir: str | os.PathLike | None = None,
    *,
    endpoint: str | None = None,
    force: bool = False,
) -> list[Path]:
    """Download the grids from PROJ's CDN (as ``projsync`` does), checking their SHA-256.

    The checksums come from the CDN's catalogue ``files.geojson``. Each file is written to a
    ``.part`` file in the same folder and renamed into place once verified.

    Parameters
    ----------
    target_dir
        Destination folder (default: pyproj's user data directory, created if needed).
    endpoint
        Base URL of the CDN (default: PROJ's, :func:`pyproj.sync.get_proj_endpoint`).
    force
        Download grids that are already in ``target_dir`` again.

    Returns
    -------
    list of pathlib.Path
        The grid files in ``target_dir``.

    Raises
    ------
    GridError
        The CDN cannot be reached (e.g. offline) or a download does not match its checksum.
    """
    target = Path(target_dir) if target_dir is not None else Path(get_user_data_dir(True))
    target.mkdir(parents=True, exist_ok=True)
    paths = [target / name for name in GRIDS]
    todo = [p for p in paths if force or not p.is_file()]
    if not todo:
        return paths
    base = (endpoint or get_proj_endpoint()).rstrip("/")
    checksums = _catalogue(base)
    for path in todo:
        url = f"{base}/{path.name}"
        if path.name not in checksums:
            raise GridError(
                f"{path.name} is not in the grid catalogue", where=f"{base}/files.geojson"
            )
        _download(url, path, checksums[path.name])
    return paths


def search_dirs(grid_dir: StrPath | None) -> list[tuple[str, Path]]:
    """The folders searched for grids, in order, each with a label for messages."""
    dirs = []
    if grid_dir is None and os.environ.get(GRID_DIR_ENV):
        dirs.append((f"${GRID_DIR_ENV}", Path(os.environ[GRID_DIR_ENV])))
    elif grid_dir is not None:
        dirs.append(("grid_dir", Path(grid_dir)))
    if dirs and not dirs[0][1].is_dir():
        raise GridError(
            f"grid folder {dirs[0][1]} does not exist",
            where=dirs[0][0],
            fix=f"give an existing folder holding {', '.join(GRIDS)}",
        )
    dirs.append(("pyproj user data directory", Path(get_user_data_dir())))
    for folder in get_data_dir().split(os.pathsep):
        if folder not in _APPENDED:
            dirs.append(("PROJ data directory", Path(folder)))
    dirs.append((_BUNDLED, BUNDLED_GRID_DIR))
    return dirs


def _find(name, dirs):
    """(label, path) of the first folder holding ``name``, or None."""
    for label, folder in dirs:
        if (folder / name).is_file():
            return label, (folder / name).resolve()
    return None


def grid_folders(grid_dir: StrPath | None, network: bool) -> tuple[str, ...]:
    """The folders holding the grids, downloading them first if allowed; else GridError."""
    dirs = search_dirs(grid_dir)
    hits = {name: _find(name, dirs) for name in GRIDS}
    missing = [name for name, hit in hits.items() if hit is None]
    if missing and network:
        fetch_grids()
        hits = {name: _find(name, dirs) for name in GRIDS}
        missing = [name for name, hit in hits.items() if hit is None]
    if missing:
        raise GridError(
            "missing PROJ grid(s) " + ", ".join(missing),
            where="searched " + ", ".join(f"{folder} ({label})" for label, folder in dirs),
            fix=HOW_TO_GET,
        )
    return tuple(sorted({str(path.parent) for _, path in hits.values()}))


def add_to_proj_path(folders: tuple[str, ...]) -> None:
    """Put the grid folders (from :func:`grid_folders`) on PROJ's search path, once each.

    :func:`pyproj.datadir.append_data_dir` is used; ``PROJ_DATA`` is never touched."""
    searched = get_data_dir().split(os.pathsep) + [get_user_data_dir()]
    for folder in folders:
        if folder not in searched:
            append_data_dir(folder)
            _APPENDED.add(folder)


def _catalogue(base: str) -> dict[str, str]:
    """File name -> SHA-256 from the CDN's ``files.geojson``."""
    url = f"{base}/files.geojson"
    try:
        with urllib.request.urlopen(url, timeout=60) as response:
            features = json.load(response)["features"]
    except (OSError, ValueError, KeyError) as exc:
        raise GridError(
            f"cannot read PROJ's grid catalogue ({exc})",
            where=url,
            fix="connect to the internet, or copy " + ", ".join(GRIDS) + " from another "
            f"machine into a folder given by --grid-dir or ${GRID_DIR_ENV}",
        ) from exc
    return {
        f["properties"]["name"]: f["properties"].get("sha256", "")
        for f in features
        if f.get("properties", {}).get("name") in GRIDS
    }


def _download(url: str, path: Path, sha256: str) -> None:
    """Fetch ``url`` to ``path`` through a ``.part`` file, checking the SHA-256 if known."""
    part = path.with_name(path.name + ".part")
    digest = hashlib.sha256()
    try:
        with urllib.request.urlopen(url, timeout=60) as response, part.open("wb") as out:
            while chunk := response.read(1 << 20):
                digest.update(chunk)
                out.write(chunk)
        if sha256 and digest.hexdigest() != sha256:
            raise GridError(
                f"{path.name} does not match its SHA-256 checksum",
                where=url,
                fix="try again later; the download was incomplete or altered",
            )
        part.replace(path)
    except OSError as exc:
        raise GridError(
            f"cannot download {path.name} ({exc})",
            where=url,
            fix=f"check the internet connection, or copy the file into {path.parent}",
        ) from exc
    finally:
        part.unlink(missing_ok=True)

"""The DEM a partition was made on, recorded so that a run can tell it again.

A partition takes the receivers' heights (``--receiver-height dem``) and the buildings' ground
from its DEM; a run that grounds footprints on another DEM would mix two surveys silently.
The index records the DEM's name and its heights at a few points where it was used (the first
receiver and building of each tile, :func:`dem_probes`); a run given a DEM samples it there
again and refuses one that gives other heights (:func:`check_dem`, the check ``update`` makes of
the DEM its evidence was cast on: :func:`~gnss_citygml.terrain.check_same_ground`). A copy of
the DEM, or the same heights in another format, is the same DEM.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import geopandas as gpd
import numpy as np
import pandas as pd
from rasterio.io import DatasetReader

from ..errors import user_text
from ..terrain import Dem, DemCoverageError, check_same_ground, sample_ground

__all__ = ["PROBES", "check_dem", "dem_probes"]


#: The most tiles of receivers, and of buildings, whose DEM height the index records.
PROBES = 512


def dem_probes(
    tops: list[tuple[Path, dict[str, Any]]], dem: Dem, dem_crs: Any = None
) -> dict[str, Any]:
    """The index's record of ``dem``: its name, and its height (``probes``: e, n, height) at
    the first row of the first file of at most :data:`PROBES` tiles of each of ``tops`` (the
    folder of the receivers' tiles, then the buildings', with their index entries), spread
    over them: a receiver, a point inside a building. A point off the DEM or by a gap in it is
    left out."""
    (rx_top, rx_tiles), (b_top, b_tiles) = tops
    points = [_first_receiver(f) for f in _spread(rx_top, rx_tiles)]
    points += [_first_building(f) for f in _spread(b_top, b_tiles)]
    e, n = np.array(points, dtype=float).reshape(-1, 2).T
    keep = np.ones(e.size, dtype=bool)
    ground = np.empty(0)
    for _ in range(3):  # (the points off the DEM are named first, then those over its gaps)
        try:
            ground = sample_ground(dem, e[keep], n[keep], assume_crs=dem_crs)
            break
        except DemCoverageError as exc:
            keep[np.flatnonzero(keep)[np.asarray(exc.items, dtype=int)]] = False
    else:
        keep[:] = False
    return {"name": _name(dem), "probes": np.c_[e[keep], n[keep], ground].tolist()}


def check_dem(made: dict[str, Any], dem: Dem, dem_crs: Any = None) -> None:
    """Refuse a ``dem`` that is not the one the partition's record ``made``
    (:func:`dem_probes`) was taken from, naming both."""
    e, n, ground = np.array(made["probes"], dtype=float).reshape(-1, 3).T
    check_same_ground(
        e, n, ground, dem, assume_crs=dem_crs,
        what=f"{user_text(_name(dem))} is not the DEM the partition was made on "
        f"({user_text(made['name'])})",
        fix="give the partition's DEM, or partition again on this one",
    )  # fmt: skip


def _spread(top: Path, tiles: dict[str, Any]) -> list[Path]:
    """The first file of at most :data:`PROBES` of the ``tiles`` in ``top``, spread over them."""
    names = sorted(tiles)
    step = max(1, -(-len(names) // PROBES))
    return [top / f"tile={name}" / min(tiles[name]["files"]) for name in names[::step]]


def _name(dem: Dem) -> str:
    return Path(dem.name if isinstance(dem, DatasetReader) else os.fspath(dem)).name


def _first_receiver(file: Path) -> tuple[float, float]:
    first = pd.read_parquet(file, columns=["e", "n"]).iloc[0]
    return float(first["e"]), float(first["n"])


def _first_building(file: Path) -> tuple[float, float]:
    inside = gpd.read_parquet(file, columns=["geometry"]).geometry.iloc[0].representative_point()
    return inside.x, inside.y

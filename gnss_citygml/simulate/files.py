"""A simulated site as the files a user brings: observations, footprints, a DEM, and the truth.

The scene's local grid (metres east and north of the site's origin on the WGS84 ellipsoid) is
carried to British National Grid through WGS84 latitude and longitude and the OSTN15
transformation, exactly as the observations' positions will be by the pipeline, so the
footprints, the DEM and the receivers line up as real data do.
"""

from __future__ import annotations

from collections.abc import Iterable
from pathlib import Path

import geopandas as gpd
import numpy as np
import rasterio
import shapely
from rasterio.transform import from_origin

from ..files.paths import StrPath, atomic_path, check_output_folder, make_folder
from ..files.tables import write_layer, write_table
from ..geodesy import to_osgb
from ..observations import OBSERVATION_COLUMNS, write_observations
from . import Simulation, local_to_wgs84

__all__ = ["DEM_CELL", "check_site", "site_paths", "write_site"]

#: DEM cell size (m) and margin (m) around the site's buildings and receivers.
DEM_CELL = 5.0
DEM_MARGIN = 50.0


def site_paths(folder: StrPath, fmt: str = "parquet") -> dict[str, Path]:
    """The files of a site written by :func:`write_site`, by name."""
    folder = Path(folder)
    return {
        "observations": folder / f"observations.{fmt}",
        "footprints": folder / "footprints.gpkg",
        "dem": folder / "dem.tif",
        "truth": folder / "truth.csv",
    }


def check_site(
    folder: StrPath, fmt: str = "parquet", *, overwrite: bool, also: Iterable[StrPath] = ()
) -> dict[str, Path]:
    """The site's paths (:func:`site_paths`), checked before any work: without ``overwrite``
    none of them, nor of ``also`` (other files the caller writes there), may exist."""
    paths = site_paths(folder, fmt)
    files = [*paths.values(), *map(Path, also)]
    check_output_folder(folder, files, overwrite=overwrite, what="site folder")
    return paths


def write_site(
    sim: Simulation,
    folder: StrPath,
    *,
    grid_dir: StrPath | None = None,
    fmt: str = "parquet",
    overwrite: bool = True,
) -> dict[str, Path]:
    """Write ``observations.<fmt>``, ``footprints.gpkg``, ``dem.tif`` and ``truth.csv``.

    Returns the paths by name. The DEM is flat at the scene's ground height (ODN), in
    EPSG:27700, covering the buildings and receivers with a margin. Without ``overwrite``,
    any of the files already there is an error, raised before anything is written.
    """
    paths = check_site(folder, fmt, overwrite=overwrite)
    make_folder(folder)
    scene = sim.scene
    footprints = gpd.GeoDataFrame(
        {"id": [b.id for b in scene.buildings]},
        geometry=[_to_bng(b.footprint, scene, grid_dir) for b in scene.buildings],
        crs="EPSG:27700",
    )
    observations = sim.observations[OBSERVATION_COLUMNS]
    write_observations(observations, paths["observations"], overwrite=overwrite)
    write_layer(footprints, paths["footprints"], "footprints", overwrite=overwrite)
    e, n, _ = to_osgb(sim.observations["lat"], sim.observations["lon"], 0.0, grid_dir=grid_dir)
    _write_flat_dem(paths["dem"], footprints.total_bounds, e, n, scene.ground, overwrite)
    write_table(sim.truth, paths["truth"], overwrite=overwrite)
    return paths


def _to_bng(geometry, scene, grid_dir):
    def convert(xy):
        lon, lat = local_to_wgs84(scene, xy[:, 0], xy[:, 1])
        e, n, _ = to_osgb(lat, lon, 0.0, grid_dir=grid_dir)
        return np.column_stack([e, n])

    return shapely.transform(geometry, convert)


def _write_flat_dem(path, bounds, e, n, ground, overwrite):
    x0 = np.floor((min(bounds[0], e.min()) - DEM_MARGIN) / DEM_CELL) * DEM_CELL
    y0 = np.floor((min(bounds[1], n.min()) - DEM_MARGIN) / DEM_CELL) * DEM_CELL
    x1 = np.ceil((max(bounds[2], e.max()) + DEM_MARGIN) / DEM_CELL) * DEM_CELL
    y1 = np.ceil((max(bounds[3], n.max()) + DEM_MARGIN) / DEM_CELL) * DEM_CELL
    width, height = int((x1 - x0) / DEM_CELL), int((y1 - y0) / DEM_CELL)
    profile = {
        "driver": "GTiff",
        "width": width,
        "height": height,
        "count": 1,
        "dtype": "float32",
        "crs": "EPSG:27700",
        "transform": from_origin(x0, y1, DEM_CELL, DEM_CELL),
        "nodata": -9999.0,
        "compress": "deflate",
    }
    with atomic_path(path, overwrite=overwrite) as tmp, rasterio.open(tmp, "w", **profile) as ds:
        ds.write(np.full((1, height, width), ground, dtype="float32"))

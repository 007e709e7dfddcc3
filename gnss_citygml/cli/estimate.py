"""The ``estimate`` subcommand: observations + footprints + DEM -> building heights."""

from __future__ import annotations

from pathlib import Path

import click

from ..model import METHODS
from .observe import GRID_DIR
from .options import QUIET, THRESHOLD, output_file, progress


@click.command()
@click.argument("observations", type=click.Path(dir_okay=False, path_type=Path))
@click.argument("footprints", type=click.Path(path_type=Path))
@click.option(
    "--dem",
    type=click.Path(path_type=str),
    required=True,
    help="DEM raster in EPSG:27700 (GeoTIFF, ASCII grid, zip://...!/tile.asc).",
)
@output_file(
    "Output layer 'heights': a GeoPackage (.gpkg; other layers of an existing one are kept), "
    "FlatGeobuf (.fgb) or GeoParquet (.parquet)."
)
@click.option("--layer", help="Footprint layer (default: the only polygon layer).")
@click.option(
    "--id-field",
    help="Footprint id column (default: toid, id or fid); the output's id column keeps its name.",
)
@click.option("--min-elevation", type=float, default=10.0, show_default=True, help="Degrees.")
@click.option("--max-elevation", type=float, default=85.0, show_default=True, help="Degrees.")
@click.option(
    "--receiver-height",
    type=click.Choice(["dem", "log"]),
    default="dem",
    show_default=True,
    help="Antenna height from the DEM (+ --antenna-height) or from the observations' h.",
)
@click.option("--antenna-height", type=float, default=1.0, show_default=True, help="Metres.")
@THRESHOLD
@click.option("--method", type=click.Choice(list(METHODS)), default="4PL-B", show_default=True)
@click.option("--max-range", type=float, default=500.0, show_default=True, help="Ray length (m).")
@click.option(
    "--position-sd",
    type=click.FloatRange(min=0.0, min_open=True),
    help="How far the receiver positions may be off (m per axis; about 1 for points placed by "
    "hand): the fits model the height errors that follow and the ranges widen. Not for phone "
    "fixes, whose errors drift: use --calibration-sd. Default: positions taken as exact, as "
    "in the paper.",
)
@click.option(
    "--position-window",
    type=click.FloatRange(min=0.0, min_open=True),
    help="With --position-sd: one position error lasts this many seconds (e.g. 30 for a "
    "walker's traced path). Default: a whole recording, as a point placed by hand.",
)
@click.option(
    "--calibration-sd",
    type=click.FloatRange(min=0.0, min_open=True),
    help="Self-calibrate one position offset per recording with this prior (m per axis; "
    "about 1 for hand-placed points, 5 for phone fixes). Off by default.",
)
@click.option(
    "--calibration-window",
    type=click.FloatRange(min=0.0, min_open=True),
    help="With --calibration-sd: one offset per this many seconds of a recording (about 30 "
    "for phone fixes, whose errors drift) instead of one per recording.",
)
@click.option("--dem-crs", help="CRS of a DEM that has none, e.g. EPSG:27700.")
@GRID_DIR
@click.option(
    "--overwrite", is_flag=True, help="Replace an existing output (in a GeoPackage: the layer)."
)
@QUIET
def estimate(
    observations,
    footprints,
    dem,
    output,
    layer,
    id_field,
    min_elevation,
    max_elevation,
    receiver_height,
    antenna_height,
    init_threshold,
    method,
    max_range,
    position_sd,
    position_window,
    calibration_sd,
    calibration_window,
    dem_crs,
    grid_dir,
    overwrite,
    quiet,
):
    """Estimate the height of every footprint from GNSS OBSERVATIONS.

    OBSERVATIONS is the observations table (CSV or Parquet: time_utc, receiver, lat, lon, h,
    constellation, svid, azimuth, elevation, cn0 with empty = blocked). FOOTPRINTS is a
    GeoPackage or any polygon layer, or OS MasterMap Topography GML. The output holds each
    footprint with its estimate; buildings with too little data have empty heights.
    """
    from ..footprints import read_footprints
    from ..observations import read_observations
    from ..pipeline import STAGES
    from ..pipeline import estimate as run
    from ..tables import check_layer_output, write_layer

    check_layer_output(output, "heights", overwrite=overwrite)
    obs = read_observations(observations)
    fp = read_footprints(footprints, layer=layer, id_field=id_field, grid_dir=grid_dir)
    with progress(len(STAGES), "stages", quiet) as bar:

        def stage(name):
            bar.set_description(name)
            bar.update(1)

        heights = run(
            obs,
            fp,
            dem,
            min_elevation=min_elevation,
            max_elevation=max_elevation,
            receiver_height=receiver_height,
            antenna_height=antenna_height,
            init_threshold=init_threshold,
            method=method,
            max_range=max_range,
            grid_dir=grid_dir,
            dem_crs=dem_crs,
            position_sd=position_sd,
            position_window=position_window,
            calibration_sd=calibration_sd,
            calibration_window=calibration_window,
            progress=stage,
        )
    write_layer(heights, output, "heights", overwrite=overwrite)
    ok = int(heights["converged"].sum())
    click.echo(f"{ok} of {len(heights)} buildings have a height -> {output}")

"""The ``partition`` subcommand: observations as Parquet partitioned by tile, for a run in
tiles (``estimate FOLDER ... --scheduler``)."""

from __future__ import annotations

from pathlib import Path

import click

from ..settings import RunSettings
from .options import (
    ANTENNA_HEIGHT,
    DEM_CRS,
    GRID_DIR,
    ID_FIELD,
    LAYER,
    MAX_ELEVATION,
    MIN_ELEVATION,
    OVERWRITE,
    POSITION_DISTANCE,
    POSITION_WINDOW,
    QUIET,
    RECEIVER_HEIGHT,
    TILE_SIZE,
    chosen_settings,
    dem_file,
    footprints_file,
    output_dir,
    progress,
)


@click.command()
@click.argument(
    "observations", nargs=-1, required=True, type=click.Path(dir_okay=False, path_type=Path)
)
@output_dir("The partition folder (partition.json, receivers/tile=NAME/part-K.parquet).")
@dem_file(
    "DEM in EPSG:27700 (a raster or a folder of its tiles), for the receivers' heights "
    "(--receiver-height dem) and the ground under the --footprints."
)
@footprints_file(
    "Also partition these footprints (any layer GDAL reads, MasterMap GML, GeoParquet), read "
    "in batches, each building with its ground from --dem: the run then needs neither the "
    "footprints nor the DEM."
)
@LAYER
@ID_FIELD
@TILE_SIZE
@MIN_ELEVATION
@MAX_ELEVATION
@RECEIVER_HEIGHT
@ANTENNA_HEIGHT
@POSITION_DISTANCE
@POSITION_WINDOW
@DEM_CRS
@GRID_DIR
@OVERWRITE
@QUIET
def partition(
    observations,
    output_dir,
    dem,
    footprints,
    layer,
    id_field,
    tile_size,
    dem_crs,
    grid_dir,
    overwrite,
    quiet,
    **chosen,
):
    """Write observations as Parquet partitioned by tile, for a run in tiles.

    Each of the OBSERVATIONS files (CSV or Parquet, read one at a time) is masked by elevation
    and its receivers put in British National Grid + ODN with grid bearings; the rows go under
    the tile that holds their receiver. `estimate OUTPUT_DIR FOOTPRINTS --dem DEM --scheduler ...`
    then has each tile read only the partitions its rays can come from. A recording must lie
    in one file. With --footprints the buildings are partitioned too (buildings/tile=NAME/),
    and `estimate OUTPUT_DIR --scheduler ...` needs nothing else.
    """
    from ..tiling.buildings import Footprints
    from ..tiling.partition import partition_observations

    # the mask, receiver heights and position groups
    settings = RunSettings.of(**chosen_settings(chosen), grid_dir=grid_dir, dem_crs=dem_crs)

    with progress(len(observations), "files", quiet) as bar:

        def next_file(name):  # an observation file, or a batch of the footprints
            bar.set_description(Path(name).name)
            bar.update(0 if ": buildings " in name else 1)

        index = partition_observations(
            observations,
            output_dir,
            dem,
            settings,
            tile_size=tile_size,
            footprints=None if footprints is None else Footprints(footprints, layer, id_field),
            overwrite=overwrite,
            progress=next_file,
        )
    tiles, size = len(index["tiles"]), index["tile_size"]
    built = index.get("buildings")
    also = "" if built is None else f" and {built['rows']} buildings in {len(built['tiles'])} tiles"
    click.echo(f"{index['signals']} signals in {tiles} tiles of {size:g} m{also} -> {output_dir}")

"""Re-encode PROJ-data's OSTN15 and OSGM15 grids for the package: the same grids, smaller.

**The OSTN15 shifts.** PROJ-data's ``uk_os_OSTN15_NTv2_OSGBtoETRS.tif`` holds its shifts as
Float32 (3.0 MB): the noise in the low bits of each float does not compress, even losslessly
re-encoded with DEFLATE/ZSTD and a floating-point predictor (2.8-3.9 MB). PROJ's GeoTIFF grid
format takes integer bands with a scale (GDAL's band SCALE metadata), so :func:`pack` stores
each shift as Int32 in units of :data:`STEP` arc-seconds (horizontal differencing + DEFLATE:
1.7 MB). The rounding moves a node by at most STEP/2 = 5e-6 arc-seconds per component (0.15 mm
north, 0.10 mm east); measured through PROJ over a million points of the grid, the positions
move by at most 0.18 mm (RMS 0.07 mm): far below OSTN15's own millimetre rounding. The accuracy
bands are kept, in units of :data:`ACCURACY_STEP`. Everything else (extent, CRS, band names,
units, metadata) is copied; the description says what was done.

**The OSGM15 geoid.** :func:`pack_geoid` keeps every Float32 value bit for bit (the geoid's
values, resampled to latitude and longitude by PROJ-data, are not whole millimetres, so an
integer encoding would round them) and compresses them harder (DEFLATE level 9 with the
floating-point predictor: 1,540,925 -> 1,500,328 bytes); the metadata is copied.

Usage: ``python tools/pack_grids.py SOURCE_FOLDER gnss_citygml/data/grids/`` (SOURCE_FOLDER:
PROJ-data's ``uk_os`` files, e.g. ``../shared/data/geodesy``).
"""

import argparse
from pathlib import Path

import numpy as np
import rasterio

#: Arc-seconds per integer step of the latitude and longitude shifts.
STEP = 1e-5
#: Arc-seconds per integer step of the two accuracy bands (values 1e-6 to 3e-5).
ACCURACY_STEP = 1e-9
NAME = "uk_os_OSTN15_NTv2_OSGBtoETRS.tif"
GEOID = "uk_os_OSGM15_GB.tif"


def quantised(source: Path) -> tuple[np.ndarray, list[float]]:
    """The source's four bands as Int32 steps, and the scale of each band."""
    with rasterio.open(source) as ds:
        shifts = ds.read().astype(np.float64)
    scales = [STEP, STEP, ACCURACY_STEP, ACCURACY_STEP]
    steps = np.stack([np.round(band / s) for band, s in zip(shifts, scales, strict=True)])
    return steps.astype(np.int32), scales


def pack(source: Path, folder: Path) -> Path:
    """Write the re-encoded grid into ``folder`` under PROJ's name for it."""
    steps, scales = quantised(source)
    with rasterio.open(source) as ds:
        profile, tags = ds.profile, ds.tags()
        bands = [(ds.tags(k), ds.descriptions[k - 1], ds.units[k - 1]) for k in range(1, 5)]
    tags["TIFFTAG_IMAGEDESCRIPTION"] += (
        f"; re-encoded by gnss-citygml as Int32 in units of {STEP:g} arc-second "
        f"(accuracy bands {ACCURACY_STEP:g}), each shift within {STEP / 2:g} arc-second"
    )
    profile.update(
        dtype="int32", compress="deflate", zlevel=9, predictor=2, tiled=True, interleave="band"
    )
    target = folder / NAME
    with rasterio.open(target, "w", **profile) as out:
        out.write(steps)
        out.update_tags(**tags)
        for k, (band_tags, description, unit) in enumerate(bands, start=1):
            out.update_tags(k, **band_tags)
            out.set_band_description(k, description)
            out.set_band_unit(k, unit)
        out.scales = scales
        out.offsets = [0.0] * len(scales)
    return target


def pack_geoid(source: Path, folder: Path) -> Path:
    """Write the geoid into ``folder``: PROJ-data's values and metadata, compressed harder."""
    with rasterio.open(source) as ds:
        profile, tags, values = ds.profile, ds.tags(), ds.read()
        band = (ds.tags(1), ds.descriptions[0], ds.units[0])
    tags["TIFFTAG_IMAGEDESCRIPTION"] += "; re-compressed by gnss-citygml, values unchanged"
    profile.update(compress="deflate", zlevel=9, predictor=3, tiled=True, interleave="band")
    target = folder / GEOID
    with rasterio.open(target, "w", **profile) as out:
        out.write(values)
        out.update_tags(**tags)
        out.update_tags(1, **band[0])
        out.set_band_description(1, band[1])
        out.set_band_unit(1, band[2])
    return target


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("source", type=Path, help=f"the folder of PROJ-data's {NAME}, {GEOID}")
    parser.add_argument("folder", type=Path, help="Folder to write the re-encoded grids into")
    args = parser.parse_args()
    print(pack(args.source / NAME, args.folder))
    print(pack_geoid(args.source / GEOID, args.folder))

"""ETRS89 <-> British National Grid + ODN heights with the Ordnance Survey grids, and grid bearings.

The transformation is PROJ's EPSG:4937 (ETRS89 geographic 3D) <-> EPSG:7405 (OSGB36 / British
National Grid + ODN height), which PROJ carries out with two Ordnance Survey grids:

- ``uk_os_OSTN15_NTv2_OSGBtoETRS.tif`` (OSTN15, horizontal: "OSGB36 to ETRS89 (2)"),
- ``uk_os_OSGM15_GB.tif`` (OSGM15 geoid: "ETRS89 to ODN height (2)").

Smartphone WGS84 coordinates are taken as ETRS89 (PROJ's "ETRS89 to WGS 84 (1)" is a null
transformation too).

Coordinates in any other CRS (footprints) reach British National Grid only through this one
path, by :func:`to_bng`: a CRS on ETRS89 or WGS 84 is converted to its own latitude and
longitude and goes through :func:`to_osgb`; a CRS on OSGB36 is converted (no datum change).
Any other datum is a :class:`CrsError`: PROJ has only Helmert or ballpark transformations from
it (metres off, silently), so the user transforms the data with the transformation that made
it. PROJ's own choice is never taken: without the grids on its search path it picks "OSGB36 to
WGS 84 (6)", a Helmert transformation 2 m off, without a word.

The grids are found by :mod:`gnss_citygml.geodesy.grids` (an explicit ``grid_dir`` or
``$GNSS_CITYGML_GRID_DIR``, PROJ's folders, and last the copy shipped inside the package); a
grid that cannot be found is a :class:`~gnss_citygml.geodesy.grids.GridError`, never a fallback
to another transformation.

Two PROJ behaviours are guarded against:

- a transformer built without ``allow_ballpark=False`` silently uses a *ballpark* vertical step
  (ODN height = ellipsoidal height, about 50 m wrong) on the outlying islands; every transformer
  here is checked to be the single OSTN15 + OSGM15 pipeline and to reproduce an OS test point;
- PROJ returns ``inf`` without an error for a point outside the grids (or, with its network
  streaming on but unreachable, anywhere): any non-finite result is an
  :class:`OutsideExtentError` naming the points (by the labels the caller gives: an
  observation's receiver and time, a footprint's id).

PROJ's GeoTIFF block cache thrashes when points jump between distant parts of Great Britain
(about 1,000 points/s instead of millions): widely spread points are transformed in a
spatially sorted order and put back in their original order.
"""

from __future__ import annotations

import functools
import os
from collections.abc import Callable
from typing import Any, TypeAlias

import geopandas as gpd
import numpy as np
import numpy.typing as npt
import pyproj
from pyproj import Proj, Transformer
from pyproj.exceptions import ProjError

from ..errors import InputError, listing, user_text
from .grids import GRIDS, HOW_TO_GET, GridError, add_to_proj_path, grid_folders

__all__ = [
    "ETRS89",
    "OSGB_ODN",
    "CrsError",
    "CrsInput",
    "OutsideExtentError",
    "from_osgb",
    "grid_bearing",
    "check_bng",
    "is_bng",
    "meridian_convergence",
    "to_bng",
    "to_osgb",
]

#: ETRS89 geographic 3D (latitude, longitude, ellipsoidal height).
ETRS89 = "EPSG:4937"
#: OSGB36 / British National Grid + ODN height.
OSGB_ODN = "EPSG:7405"
#: A CRS as :meth:`pyproj.crs.CRS.from_user_input` takes it (a ``pyproj.CRS``, ``"EPSG:4326"``,
#: ``4326``, WKT, a PROJ string...), which pyproj types as Any.
CrsInput: TypeAlias = Any
#: OS test point TP09 (London), ETRS89 (lon, lat, h) and OSGB36 (E, N, ODN) from the OS test
#: files. Per direction: source CRS, target CRS, TP09 in, TP09 out, tolerance per coordinate.
_TP09_ETRS = (-0.11992557180, 51.48936564950, 66.057)
_TP09_OSGB = (530624.974, 178388.464, 20.544)
_DIRECTIONS = {
    "to_osgb": (ETRS89, OSGB_ODN, _TP09_ETRS, _TP09_OSGB, (0.01, 0.01, 0.005)),
    "from_osgb": (OSGB_ODN, ETRS89, _TP09_OSGB, _TP09_ETRS, (1e-7, 1e-7, 0.005)),
}
#: Datums (by PROJ's name: the EPSG ensembles, and as ESRI WKT and PROJ strings name them)
#: whose coordinates are taken as ETRS89, and OSGB36, the datum of British National Grid.
_ETRS89_DATUMS = frozenset(
    {
        "European Terrestrial Reference System 1989 ensemble",
        "European Terrestrial Reference System 1989",
        "World Geodetic System 1984 ensemble",
        "World Geodetic System 1984",
    }
)
_OSGB36_DATUM = "Ordnance Survey of Great Britain 1936"
#: Points listed by name in an error message.
_LIST_POINTS = 5


class OutsideExtentError(InputError):
    """Points lie outside the OSTN15 / OSGM15 grids (or their coordinates are not numbers)."""


class CrsError(InputError):
    """A CRS from which no exact (grid-based or datum-preserving) path to BNG exists."""


def to_osgb(
    lat: npt.ArrayLike,
    lon: npt.ArrayLike,
    h: npt.ArrayLike,
    *,
    grid_dir: str | os.PathLike | None = None,
    network: bool = False,
    labels: npt.ArrayLike | Callable | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """ETRS89 latitude, longitude, ellipsoidal height to British National Grid + ODN height.

    Parameters
    ----------
    lat, lon
        ETRS89 (or WGS84) latitude and longitude (deg); array_like, broadcast together with ``h``.
    h
        Ellipsoidal height (m). NaN where unknown: the point still gets its easting and
        northing, and its ODN height is NaN.
    grid_dir
        A folder holding the grids, searched first (default ``$GNSS_CITYGML_GRID_DIR``); then
        PROJ's folders, then the copy bundled with the package.
    network
        Download grids found nowhere, not even in the bundled copy, from PROJ's CDN into
        pyproj's user data directory.
    labels
        How an error names each point, as the user knows it (e.g. ``"receiver A at
        2020-06-01 10:00:00"``, ``"footprint osgb1000005430576"``), one per point of the
        broadcast shape, or a function from flat indices to those names (called only for the
        points an error names, so that no text is made for the millions that are fine);
        default ``"point <i>"`` with ``i`` its flat index in the arrays given.

    Returns
    -------
    (e, n, odn)
        Easting, northing (m, EPSG:27700) and ODN height (m, EPSG:5701) as float arrays of the
        broadcast shape.

    Raises
    ------
    GridError
        A grid is missing (the message names it and how to get it).
    OutsideExtentError
        Some points are outside the grids or have non-finite coordinates (the message names
        them).
    """
    return _run("to_osgb", lon, lat, h, grid_dir, network, labels)


def from_osgb(
    e: npt.ArrayLike,
    n: npt.ArrayLike,
    odn: npt.ArrayLike,
    *,
    grid_dir: str | os.PathLike | None = None,
    network: bool = False,
    labels: npt.ArrayLike | Callable | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """British National Grid + ODN height to ETRS89 latitude, longitude, ellipsoidal height.

    The inverse of :func:`to_osgb`, with the same parameters, grids and errors.

    Parameters
    ----------
    e, n
        Easting and northing (m, EPSG:27700); array_like, broadcast together with ``odn``.
    odn
        ODN height (m); NaN where unknown gives NaN ellipsoidal height.
    grid_dir, network, labels
        As for :func:`to_osgb`.

    Returns
    -------
    (lat, lon, h)
        ETRS89 latitude, longitude (deg) and ellipsoidal height (m).
    """
    lon, lat, h = _run("from_osgb", e, n, odn, grid_dir, network, labels)
    return lat, lon, h


def to_bng(
    x: npt.ArrayLike,
    y: npt.ArrayLike,
    crs: CrsInput,
    *,
    grid_dir: str | os.PathLike | None = None,
    network: bool = False,
    labels: npt.ArrayLike | Callable | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Horizontal coordinates in any CRS to British National Grid, by an exact path only.

    - British National Grid itself (also with a vertical CRS): unchanged.
    - A CRS on ETRS89 or WGS 84 (EPSG:4258, EPSG:4326, OGC:CRS84, UTM, Web Mercator...): its
      own latitude and longitude (a conversion, no datum change), then :func:`to_osgb`, the
      checked OSTN15 + OSGM15 transformation. WGS 84 is taken as ETRS89, as for the receivers.
    - A CRS on OSGB36 (EPSG:4277, another projection): converted (no datum change).
    - Anything else is a :class:`CrsError`: PROJ has only Helmert or ballpark
      transformations from other datums (metres off in Great Britain).

    A bound CRS (a PROJ string's ``+towgs84``, a WKT's ``TOWGS84``) is taken as its source CRS:
    its Helmert parameters are never used.

    Parameters
    ----------
    x, y
        Coordinates in ``crs``, in its traditional GIS order (longitude, latitude for a
        geographic CRS; easting, northing for a projected one), array_like.
    crs
        Anything :meth:`pyproj.crs.CRS.from_user_input` takes.
    grid_dir, network, labels
        As for :func:`to_osgb`.

    Returns
    -------
    (e, n)
        Easting and northing (m, EPSG:27700) as float arrays of the broadcast shape.

    Raises
    ------
    CrsError
        No exact path from ``crs`` (its datum is not ETRS89, WGS 84 or OSGB36).
    GridError, OutsideExtentError
        As for :func:`to_osgb`.
    """
    x, y = np.broadcast_arrays(np.asarray(x, dtype=float), np.asarray(y, dtype=float))
    crs = pyproj.CRS.from_user_input(crs)
    if is_bng(crs):
        return x.copy(), y.copy()
    crs = (crs.source_crs if crs.is_bound else crs).to_2d()  # type: ignore[union-attr]  # bound: has a source
    geodetic = crs.geodetic_crs
    frame = geodetic.datum if geodetic is not None and geodetic.is_geographic else None
    datum = frame.name if frame is not None else None
    if datum in _ETRS89_DATUMS:
        lon, lat = _conversion(crs, geodetic).transform(x, y)
        e, n, _ = to_osgb(lat, lon, np.nan, grid_dir=grid_dir, network=network, labels=labels)
        return e, n
    if datum == _OSGB36_DATUM:
        e, n = _conversion(crs, pyproj.CRS("EPSG:27700")).transform(x, y)
        _check_finite(e.ravel(), n.ravel(), np.zeros(e.size), False, labels)
        return e, n
    raise CrsError(
        f"no exact transformation from {crs.name} (datum {datum or 'unknown'}) to British "
        "National Grid",
        where=":".join(crs.to_authority() or ()) or None,
        fix="only coordinates on ETRS89 or WGS 84 (through OSTN15) and on OSGB36 are "
        "transformed, never with a Helmert or ballpark transformation (metres off): transform "
        "them to EPSG:4258, EPSG:4326 or EPSG:27700 with the transformation they were made "
        "with",
    )


def is_bng(crs: CrsInput) -> bool:
    """Whether a CRS is British National Grid (alone, with a vertical CRS, or bound to WGS 84).

    Parameters
    ----------
    crs
        Anything :meth:`pyproj.crs.CRS.from_user_input` takes.

    Examples
    --------
    >>> is_bng("EPSG:7405"), is_bng("EPSG:4326")
    (True, False)
    """
    crs = pyproj.CRS.from_user_input(crs)
    crs = crs.source_crs if crs.is_bound else crs
    return crs.to_2d().to_epsg(min_confidence=70) == 27700  # type: ignore[union-attr]  # bound: has a source


def check_bng(frame: object, what: str = "buildings") -> None:
    """Refuse a table that is not a GeoDataFrame in British National Grid, naming the CRS found.

    Every stage after the reader works in EPSG:27700 (rays, ground, city models), where
    footprints in another CRS lie far away or, after ``to_crs``, up to 2 m off (PROJ's Helmert
    path): only :func:`read_footprints` converts, through OSTN15. ``what`` names the table in
    the message (``footprints``, ``buildings``).
    """
    if not isinstance(frame, gpd.GeoDataFrame):
        raise InputError(
            f"the {what} must be a GeoDataFrame, not {type(frame).__name__}",
            where=what,
            fix="read them with read_footprints(path)",
        )
    crs = frame.crs
    if crs is None:
        raise InputError(
            f"the {what} have no CRS",
            where=what,
            fix="read the file with read_footprints(path), or set the CRS of the coordinates, "
            "e.g. gdf.set_crs('EPSG:27700') for British National Grid",
        )
    if not is_bng(crs):
        authority = crs.to_authority()
        found = crs.name + (f" ({':'.join(authority)})" if authority else "")
        raise InputError(
            f"the {what} are in {found}, not EPSG:27700 (British National Grid)",
            where=what,
            fix="read the file with read_footprints(path), which converts them with OSTN15 "
            "(gdf.to_file('footprints.gpkg') first for a GeoDataFrame); not gdf.to_crs, which "
            "may take PROJ's 2 m Helmert transformation",
        )


def meridian_convergence(lat: npt.ArrayLike, lon: npt.ArrayLike) -> np.ndarray:
    """The meridian convergence of British National Grid (deg): grid bearing = azimuth - this.

    Positive east of the central meridian (2 deg W), where true north points west of grid
    north. Computed by PROJ (:meth:`pyproj.Proj.get_factors`) on the Airy ellipsoid; taking
    ETRS89 coordinates for OSGB36 ones changes it by less than 0.002 deg.

    Parameters
    ----------
    lat, lon
        Latitude and longitude (deg), array_like.

    Returns
    -------
    numpy.ndarray
        Convergence (deg), of the broadcast shape.

    Examples
    --------
    >>> round(float(meridian_convergence(51.5246, -0.1340)), 3)  # Gower Street, London
    1.461
    """
    lat, lon = np.broadcast_arrays(np.asarray(lat, dtype=float), np.asarray(lon, dtype=float))
    factors = _bng().get_factors(lon.ravel(), lat.ravel())
    return np.asarray(factors.meridian_convergence, dtype=float).reshape(lat.shape)


def grid_bearing(lat: npt.ArrayLike, lon: npt.ArrayLike, azimuth: npt.ArrayLike) -> np.ndarray:
    """British National Grid bearing (deg in [0, 360)) of a true azimuth at a point.

    Parameters
    ----------
    lat, lon
        Latitude and longitude of the point (deg).
    azimuth
        Azimuth (deg clockwise from true north).

    Returns
    -------
    numpy.ndarray
        ``(azimuth - meridian_convergence(lat, lon)) % 360``.

    Examples
    --------
    >>> round(float(grid_bearing(51.5246, -0.1340, 0.0)), 3)
    358.539
    """
    return (np.asarray(azimuth, dtype=float) - meridian_convergence(lat, lon)) % 360.0


def _run(direction, x, y, z, grid_dir, network, labels):
    """Validate, locate grids, transform (spatially sorted if spread out), check the result."""
    x, y, z = np.broadcast_arrays(*(np.asarray(a, dtype=float) for a in (x, y, z)))
    shape = x.shape
    x, y, z = x.ravel(), y.ravel(), z.ravel()
    geographic = direction == "to_osgb"
    _check_finite(x, y, z, geographic, labels)
    transformer = _transformer(direction, grid_folders(grid_dir, network))
    no_z = np.isnan(z)
    z = np.where(no_z, 0.0, z)
    order = _spatial_order(x, y, 1.0 if geographic else 100_000.0)
    if order is not None:
        out = transformer.transform(x[order], y[order], z[order])
        result = [np.empty_like(x) for _ in range(3)]
        for dst, src in zip(result, out, strict=True):
            dst[order] = src
    else:
        result = list(transformer.transform(x, y, z))
    bad = ~(np.isfinite(result[0]) & np.isfinite(result[1]) & np.isfinite(result[2]))
    if bad.any():
        raise OutsideExtentError(
            f"{int(bad.sum())} point(s) outside the OSTN15/OSGM15 grids",
            where=_name_points(bad, x, y, geographic, labels),
            fix="the grids cover Great Britain and its islands (OSTN15 extent); check the "
            "coordinates, their order and their CRS",
        )
    result[2][no_z] = np.nan
    return tuple(r.reshape(shape) for r in result)


def _check_finite(x, y, z, geographic, labels):
    """Non-finite horizontal coordinates and infinite heights are input errors."""
    bad = ~(np.isfinite(x) & np.isfinite(y)) | np.isinf(z)
    if bad.any():
        raise OutsideExtentError(
            f"{int(bad.sum())} point(s) with non-finite coordinates",
            where=_name_points(bad, x, y, geographic, labels),
            fix="drop or fill these points (a missing height may be NaN)",
        )


def _name_points(bad, x, y, geographic, labels) -> str:
    """The first few bad points by label (one point per label) and coordinates."""
    index = np.flatnonzero(bad)
    if labels is None:
        names = np.array([f"point {i}" for i in index[:_LIST_POINTS]])
    elif callable(labels):
        names = np.asarray(labels(index), dtype=object).astype(str)
    else:
        given = np.asarray(labels, dtype=object).ravel()
        if given.size != bad.size:
            raise InputError(
                f"{given.size} labels for {bad.size} points",
                where="labels",
                fix="give one label per point, or none",
            )
        names = given[index].astype(str)
    if labels is not None:
        _, first = np.unique(names, return_index=True)  # a footprint's vertices: one label
        index, names = index[np.sort(first)], names[np.sort(first)]
    if geographic:
        coords = [f"lat {y[i]:.6f}, lon {x[i]:.6f}" for i in index[:_LIST_POINTS]]
    else:
        coords = [f"E {x[i]:.3f}, N {y[i]:.3f}" for i in index[:_LIST_POINTS]]
    shown = [
        f"{user_text(name)} ({c})" for name, c in zip(names[:_LIST_POINTS], coords, strict=True)
    ]
    return listing(shown, _LIST_POINTS, total=index.size)


def _spatial_order(x, y, cell):
    """A permutation grouping points by ``cell``-sized squares, or None if they are close."""
    if x.size < 2 or max(np.ptp(x), np.ptp(y)) <= cell:
        return None
    key = np.floor((y - y.min()) / cell) * (np.floor(np.ptp(x) / cell) + 1)
    key += np.floor((x - x.min()) / cell)
    return np.argsort(key, kind="stable")


@functools.cache
def _transformer(direction: str, folders: tuple[str, ...]) -> Transformer:
    """The checked OSTN15 + OSGM15 transformer, cached by direction and grid folders."""
    add_to_proj_path(folders)
    src, dst, start, expected, tolerance = _DIRECTIONS[direction]
    try:
        best = Transformer.from_crs(src, dst, always_xy=True, only_best=True, allow_ballpark=False)
    except ProjError as exc:
        raise GridError(
            f"PROJ cannot use the grids for {src} -> {dst}: {exc}",
            where=", ".join(folders),
            fix="replace the grid files: " + HOW_TO_GET,
        ) from exc
    _check_operation(best, start, expected, tolerance)
    return best


def _check_operation(transformer: Transformer, start, expected, tolerance) -> None:
    """Refuse anything but the single OSTN15 + OSGM15 pipeline reproducing OS point TP09."""
    uses_grids = all(f"grids={name}" in transformer.definition for name in GRIDS)
    if not uses_grids or "ballpark" in transformer.description.lower():
        raise GridError(
            f"PROJ chose {transformer.description!r} instead of the OSTN15/OSGM15 pipeline",
            where=f"pyproj {pyproj.__version__}, PROJ {pyproj.proj_version_str}",
            fix="report this with the PROJ version; check the grid files: " + HOW_TO_GET,
        )
    got = np.array(transformer.transform(*start))
    if not np.all(np.abs(got - np.array(expected)) <= np.array(tolerance)):
        raise GridError(
            f"the grids do not reproduce Ordnance Survey test point TP09 (got {got.tolist()}, "
            f"expected {list(expected)})",
            where=transformer.definition,
            fix="the grid files are damaged or not PROJ-data's: " + HOW_TO_GET,
        )


@functools.cache
def _conversion(src: pyproj.CRS, dst: pyproj.CRS) -> Transformer:
    """PROJ's operation between two CRSs on one datum: a conversion, exact (no datum change)."""
    return Transformer.from_crs(src, dst, always_xy=True, allow_ballpark=False)


@functools.cache
def _bng() -> Proj:
    """British National Grid as a projection, for its scale factors and convergence."""
    return Proj("EPSG:27700")

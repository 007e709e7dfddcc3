"""The stages of a run, each a function of tables: the observations inside the elevation mask
(:func:`in_mask`), the receivers in British National Grid + ODN (:func:`receivers`), which rows
share one position error (:func:`recordings`, :func:`position_sds`), the rays cast against the
footprints (:func:`intersections`, and the signals that enter none, :func:`open_sky`), and the
heights joined back onto the footprints (:func:`join_heights`).

A run in one process (:mod:`gnss_citygml.pipeline`) and a run in tiles (:mod:`gnss_citygml.tiling`)
compose them; this module imports neither (imports only downward).
"""

from __future__ import annotations

import geopandas as gpd
import numpy as np
import pandas as pd
import shapely
from scipy.special import ndtr

from .errors import InputError
from .files.ids import source_named, with_id_field
from .files.paths import StrPath
from .geodesy import CrsInput, grid_bearing, to_osgb
from .model.estimate import HEIGHTS_COLUMNS
from .observations import check_observations, satellites
from .raycast import footprint_entries
from .recordings import position_groups
from .settings import (
    DEFAULT_POSITION_SD,
    NEAR_SDS,
    PositionError,
    Rays,
    ReceiverHeights,
    RunSettings,
)
from .terrain import Dem, sample_ground

__all__ = [
    "EARTH_RADIUS",
    "MIN_INCIDENCE",
    "REFRACTION",
    "crossing_chance",
    "distance_sd",
    "entered",
    "in_mask",
    "intersections",
    "join_heights",
    "near_reach",
    "open_sky",
    "position_sds",
    "receivers",
    "run_receivers",
    "recordings",
]

#: Mean Earth radius (m) and the standard refraction coefficient of surveying.
EARTH_RADIUS = 6_371_000.0
REFRACTION = 0.13

#: Smallest cosine of the angle between a ray and the normal of the wall it enters through
#: that :func:`intersections` uses for the height error of a position error: closer to
#: grazing (beyond 84 deg) a metre of position moves the entry onto the neighbouring wall
#: rather than 10 m along this one.
MIN_INCIDENCE = 0.1
#: How far (in position sds) the rays are moved to each side to find how far a position error
#: moves each entry (:func:`distance_sd`, with ``PositionError.crossing``): two, a likely
#: error that finds a corner the ray passes.
SIDESTEP_SDS = 2.0


def in_mask(observations: pd.DataFrame, rays: Rays = Rays()) -> pd.DataFrame:
    """The observations (checked: :func:`~gnss_citygml.observations.check_observations`)
    inside the elevation mask of ``rays``, numbered from 0."""
    obs = check_observations(observations)
    obs = obs[obs["elevation"].between(rays.min_elevation, rays.max_elevation)]
    return obs.reset_index(drop=True)


def run_receivers(
    observations: pd.DataFrame, dem: Dem | None, settings: RunSettings
) -> pd.DataFrame:
    """:func:`receivers` as a run with ``settings`` finds them: its receiver heights, grids
    and DEM CRS."""
    return receivers(
        observations,
        dem,
        heights=settings.receiver_heights,
        grid_dir=settings.grid_dir,
        dem_crs=settings.dem_crs,
    )


def receivers(
    observations: pd.DataFrame,
    dem: Dem | None = None,
    *,
    heights: ReceiverHeights = ReceiverHeights(),
    grid_dir: StrPath | None = None,
    dem_crs: CrsInput | None = None,
) -> pd.DataFrame:
    """The observations with the receiver columns of DESIGN.md: ``e``, ``n`` (BNG, m), ``z``
    (ODN height of the antenna, m) and ``bearing`` (grid bearing of the ray, deg).

    Each distinct receiver position is transformed once. ``heights`` says where the antenna's
    height comes from (:class:`~gnss_citygml.settings.ReceiverHeights`): ``antenna_height``
    above the DEM (the paper's choice with phone fixes, whose heights are poor), or the
    observations' ellipsoidal ``h`` converted to ODN.
    """
    # the rows of an epoch share a position: transform each run of equal positions once
    coords = observations[["lat", "lon", "h"]].to_numpy(dtype=float)
    same = (coords[1:] == coords[:-1]) | (np.isnan(coords[1:]) & np.isnan(coords[:-1]))
    starts = np.r_[True, ~same.all(axis=1)]
    where = np.cumsum(starts) - 1
    lat, lon, h = coords[starts].T
    if heights.source == "log" and np.isnan(h).any():
        raise InputError(
            "observations without an ellipsoidal height 'h'",
            where=f"{int(np.isnan(h[where]).sum())} rows",
            fix="use --receiver-height dem (with a DEM), or give h for every row",
        )
    first = observations.iloc[np.flatnonzero(starts)]  # each position named by its first row

    def labels(index):  # made only for the positions an error names
        rows = first.iloc[index]
        return (
            "receiver " + rows["receiver"].astype(str) + " at " + rows["time_utc"].astype(str)
        ).to_numpy()

    e, n, odn = to_osgb(lat, lon, h, grid_dir=grid_dir, labels=labels)
    if heights.source == "dem":
        if dem is None:
            raise InputError("receiver heights from the DEM need a DEM", fix="give --dem")
        named = [f"receiver at lat {a:.6f} lon {b:.6f}" for a, b in zip(lat, lon, strict=True)]
        z = sample_ground(dem, e, n, assume_crs=dem_crs, labels=named) + heights.antenna_height
    else:
        z = odn
    out = observations.copy()
    out["e"], out["n"], out["z"] = e[where], n[where], z[where]
    out["bearing"] = grid_bearing(
        observations["lat"].to_numpy(), observations["lon"].to_numpy(), observations["azimuth"]
    )
    return out


def intersections(
    receivers: pd.DataFrame,
    buildings: gpd.GeoDataFrame,
    *,
    rays: Rays = Rays(),
    position_error: PositionError = PositionError(),
    recording: pd.Categorical | None = None,
) -> pd.DataFrame:
    """The intersections table of DESIGN.md: every signal x building its ray enters.

    ``height`` is the ODN height of the ray where it first enters the footprint: the antenna
    height ``z`` plus ``distance * tan(elevation)``, plus, with ``rays.earth_curvature``, the
    fall of the ground away from the ray's tangent plane (``d^2 (1 - k) / 2R`` with the
    standard refraction coefficient k = 0.13: 2 cm at 500 m). Rays reach ``rays.max_range``.

    Unless the positions are taken as exact (``position_error.sd`` 0), two more columns model
    how far the receiver positions may be off (:class:`~gnss_citygml.settings.PositionError`:
    by default each row's ``position_sd``, m per axis, and
    :data:`~gnss_citygml.settings.DEFAULT_POSITION_SD` where it is empty or missing):
    ``height_sd``, the standard deviation of each height that follows, ``sd * tan(elevation) /
    cos(incidence)`` (a position error across the entry wall moves the ray's way to it by
    itself over the cosine of incidence; along the wall nothing), with the cosine floored at
    :data:`MIN_INCIDENCE`; and ``recording``, which rows
    share one position error (:func:`~gnss_citygml.recordings.position_groups`: a receiver
    standing still shares one over its stay, a moving one over its recording, or over windows
    of ``position_error.window`` seconds; needs ``time_utc``): :func:`recordings`, unless
    given (``recording``, one per receiver row: a tile's rows, named over the whole run).
    With ``position_error.crossing``: ``crossing`` (:func:`crossing_chance`), rows of footprints
    passed within :data:`~gnss_citygml.settings.NEAR_SDS` sds (``order`` -1, where the moved
    ray touches them), ``height_sd`` from rays moved sideways (:func:`distance_sd`).
    """
    sd = None if position_error.exact else position_sds(receivers, position_error)
    reach = near_reach(receivers, position_error)
    ray, fp, dist, incidence, *across = footprint_entries(
        receivers["e"].to_numpy(),
        receivers["n"].to_numpy(),
        receivers["bearing"].to_numpy(),
        buildings.geometry.to_numpy(),
        rays.max_range,
        reach=reach,
        sidestep=None if reach is None else reach * (SIDESTEP_SDS / NEAR_SDS),
    )
    elevation = receivers["elevation"].to_numpy()[ray]
    slope = np.tan(np.radians(elevation))
    height = receivers["z"].to_numpy()[ray] + dist * slope
    if rays.earth_curvature:
        height += dist**2 * (1.0 - REFRACTION) / (2.0 * EARTH_RADIUS)
    extra: dict[str, object] = {}  # the position error's columns
    if sd is not None:
        extra["height_sd"] = _height_sd(sd[ray], slope, incidence, dist, across)
        named = recordings(receivers, position_error) if recording is None else recording
        extra["recording"] = named[ray]
    if {"constellation", "svid"} <= set(receivers.columns):
        extra["satellite"] = satellites(receivers)[ray]
    entered = np.ones(ray.size, dtype=bool)
    if across and sd is not None:
        extra["crossing"], entered = crossing_chance(across[0], sd[ray])
    # the columns are this function's own arrays: the table takes them as they are (no copy)
    return pd.DataFrame(
        {
            "signal": receivers.index.to_numpy()[ray],
            # categorical: the city's ids once, not one string per row
            # pandas-stubs takes only an Index for the categories; pandas, any array
            "building": pd.Categorical.from_codes(
                fp,
                categories=buildings["id"].astype(str),  # type: ignore[call-overload]
            ),
            "height": height,
            "distance": dist,
            "order": _order(ray, entered),
            "cn0": receivers["cn0"].to_numpy()[ray],
            "elevation": elevation,
            "receiver": receivers["receiver"].array.take(ray),  # its dtype, no Python strings
            **extra,
        },
        copy=False,
    )


def _height_sd(sd, slope, incidence, dist, across) -> np.ndarray:
    """Each row's height error, its receiver off by ``sd`` (m per axis): ``sd`` over the cosine
    of incidence (floored at :data:`MIN_INCIDENCE`) along the ray's ``slope``, or, with the
    moved rays' ``across`` (the crossing chance), the entry's distance error they found
    (:func:`distance_sd`)."""
    if not across:
        return sd * (slope / np.maximum(incidence, MIN_INCIDENCE))
    linear = sd / np.maximum(incidence, MIN_INCIDENCE)
    return slope * distance_sd(across[0], dist, sd, linear)


def near_reach(receivers: pd.DataFrame, position_error: PositionError) -> np.ndarray | None:
    """How far (m) across each receiver row's rays a footprint they pass gives a row
    (``position_error.crossing``: :data:`~gnss_citygml.settings.NEAR_SDS` of the row's position
    error); None without the crossing chance or with exact positions."""
    if not position_error.crossing or position_error.exact:
        return None
    return NEAR_SDS * position_sds(receivers, position_error)


def entered(intersections: pd.DataFrame) -> pd.DataFrame:
    """The intersections where a ray enters its footprint, without the footprints it only
    passes near (``order`` -1, :class:`~gnss_citygml.settings.PositionError`'s ``crossing``)."""
    if "order" not in intersections.columns:
        return intersections
    near = intersections["order"].to_numpy() < 0
    return intersections[~near] if near.any() else intersections


def distance_sd(
    across: np.ndarray, distance: np.ndarray, sd: np.ndarray, fallback: np.ndarray
) -> np.ndarray:
    """How far (m, one sd) each entry's distance along its ray may be off, its receiver off by
    ``sd`` (m per axis): ``sd`` along the ray, and across it what the rays moved
    :data:`SIDESTEP_SDS` sds to each side found (``across[:, 2:]``, the distances where the
    moved rays first cross the footprint): for a straight wall at incidence ``i`` each moves
    the entry by ``sd tan(i)`` a sd, so this is ``sd / cos(i)``; at a corner, where a ray
    moved a metre enters through another wall tens of metres on, it is that far. Where
    neither moved ray crosses, ``fallback``."""
    moved = (across[:, 2:] - distance[:, None]) / SIDESTEP_SDS
    sides = np.isfinite(moved)
    with np.errstate(invalid="ignore"):
        var = np.where(sides, moved, 0.0) ** 2
        across_var = var.sum(axis=1) / sides.sum(axis=1)
    return np.where(sides.any(axis=1), np.sqrt(sd**2 + across_var), fallback)


def crossing_chance(across: np.ndarray, sd: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Each row's chance that its ray crosses the footprint, the footprint reaching
    ``across[:, 0]`` (m, to the right: negative) to ``across[:, 1]`` (to the left) of it and the
    receiver's position off by ``sd`` (m) across the ray; and whether the ray as cast enters
    it. A ray through a footprint's middle crosses it almost surely, one through its corner
    half the time or less."""
    with np.errstate(divide="ignore", invalid="ignore"):
        chance = ndtr(across[:, 1] / sd) - ndtr(across[:, 0] / sd)
    entered = (across[:, 0] <= 0) & (across[:, 1] >= 0)
    return np.where(sd > 0, chance, entered.astype(float)), entered


def _order(ray: np.ndarray, entered: np.ndarray) -> np.ndarray:
    """Each row's place along its ray (rows sorted by ray and distance) among the footprints
    the ray ``entered`` (0 = the first); -1 for a footprint it passes near."""
    first = np.r_[True, ray[1:] != ray[:-1]]
    count = np.cumsum(entered)
    before = (count - entered)[np.maximum.accumulate(np.where(first, np.arange(ray.size), 0))]
    return np.where(entered, count - 1 - before, -1)


def open_sky(receivers: pd.DataFrame, intersections: pd.DataFrame) -> pd.DataFrame:
    """The receivers' rows (signals) whose rays enter no footprint within reach: open as far
    as the map knows, what the mixture signal model learns open signals from
    (:func:`~gnss_citygml.model.estimate.estimate_heights`). A ray that only passes near a
    footprint (``order`` -1) enters none."""
    return receivers[~receivers.index.isin(entered(intersections)["signal"].to_numpy())]


def recordings(
    receivers: pd.DataFrame, position_error: PositionError = PositionError()
) -> pd.Categorical:
    """Each row's position group (:func:`~gnss_citygml.recordings.position_groups`: stretches
    of ``position_error.distance`` metres, or windows of ``position_error.window`` seconds)
    named by its receiver and first epoch (``phone1
    2020-02-11T08:49:00Z``): a name that another run over more observations gives the same
    group (``update`` keeps it with its evidence)."""
    codes = position_groups(receivers, position_error.window, position_error.distance)
    first = receivers["time_utc"].groupby(codes).min()
    who = receivers["receiver"].groupby(codes).first()
    utc = pd.to_datetime(first, utc=True).dt.strftime("%Y-%m-%dT%H:%M:%S.%fZ")
    names = who.astype(str) + " " + utc
    return pd.Categorical.from_codes(codes, categories=pd.Index(names.to_numpy(), dtype=object))


def position_sds(receivers: pd.DataFrame, position_error: PositionError) -> np.ndarray:
    """Each row's position error (m per axis): ``position_error.sd`` if given, else the row's
    ``position_sd``, and :data:`~gnss_citygml.settings.DEFAULT_POSITION_SD` where that is empty
    or the table has no such column."""
    if position_error.sd is not None:
        return np.full(len(receivers), float(position_error.sd))
    if "position_sd" not in receivers.columns:
        return np.full(len(receivers), DEFAULT_POSITION_SD)
    sd = pd.to_numeric(receivers["position_sd"], errors="coerce").to_numpy(dtype=float)
    return np.where(np.isnan(sd), DEFAULT_POSITION_SD, sd)


def join_heights(
    buildings: gpd.GeoDataFrame, heights: pd.DataFrame, method: str, name: str
) -> gpd.GeoDataFrame:
    """Every footprint with its estimate; those no ray entered get an explicit status. The id
    goes out under ``name``, the footprints' source's id field (:mod:`gnss_citygml.files.ids`)."""
    est = heights.set_index("id").reindex(buildings["id"].astype(str))
    missing = est["method"].isna().to_numpy()
    est["method"] = est["method"].where(~missing, method)
    est["converged"] = est["converged"].where(~missing, False).astype(bool)
    est["status"] = est["status"].where(~missing, "no signal's ray enters the footprint")
    for column in ("n_signals", "iterations"):
        est[column] = est[column].fillna(0).astype(np.int64)
    out = buildings.drop(columns=[c for c in HEIGHTS_COLUMNS if c != "id"], errors="ignore")
    out = out.reset_index(drop=True)
    for column in est.columns:
        out[column] = est[column].to_numpy()
    out["relative_height"] = out["height"] - out["ground"]
    geometry = out.pop("geometry")
    out["geometry"] = shapely.force_2d(geometry.to_numpy())
    out = gpd.GeoDataFrame(out, geometry="geometry", crs=buildings.crs)
    return source_named(with_id_field(out, name))

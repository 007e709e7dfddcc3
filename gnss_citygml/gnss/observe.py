"""GnssLogger logs + orbits -> the observations table (one row per epoch x satellite in view).

For every epoch of a log, every satellite of the orbit files between the elevation masks is a
row: with the C/N0 the phone measured on it, or with C/N0 empty when the phone received
nothing, which is how 4PL-B learns where buildings block the sky. Only constellations the
phone reports at all are put in its sky (a phone without BeiDou does not see BeiDou blocked),
and only one band (L1/E1/B1/G1 by default), so that a satellite is one signal.

Azimuth and elevation are taken at the reception time: the ~0.07 s travel time moves a
satellite by less than 0.001 deg of arc as seen from the ground, far below what a building
edge resolves.
"""

from __future__ import annotations

import warnings
from collections.abc import Callable, Sequence

import numpy as np
import pandas as pd

from ..errors import InputError
from ..files.paths import StrPath
from ..observations import OBSERVATION_COLUMNS
from ..settings import check_elevation_mask
from .gnsslogger import GnssLog, read_gnsslogger
from .orbits import Orbits, load_orbits
from .positions import positions, read_surveyed_positions, surveyed_positions
from .sky import azimuth_elevation

__all__ = ["observe", "observe_log"]


def observe_log(
    log: GnssLog,
    orbits: Orbits,
    receiver_positions: pd.DataFrame,
    *,
    min_elevation: float = 10.0,
    max_elevation: float = 85.0,
    band: str = "L1",
) -> pd.DataFrame:
    """The observations of one log.

    Parameters
    ----------
    log
        A log from :func:`~gnss_citygml.gnss.gnsslogger.read_gnsslogger`.
    orbits
        Satellite orbits covering the log (:func:`~gnss_citygml.gnss.orbits.load_orbits`).
    receiver_positions
        ``time_utc``, ``lat``, ``lon``, ``h`` and optionally ``position_sd`` for every epoch of
        the log (e.g. from :func:`~gnss_citygml.gnss.positions.positions`); ``h`` may be NaN
        (the DEM gives the receiver height later; the sky is then seen from the ellipsoid, which
        moves no satellite by a measurable angle), and ``position_sd`` too (unknown: the
        estimator's default applies).
    min_elevation, max_elevation
        Elevation mask (deg): satellites outside it are left out.
    band
        The signal band kept (``L1`` by default; ``L5`` for the second frequency).

    Returns
    -------
    DataFrame
        The observations table (:data:`~gnss_citygml.observations.OBSERVATION_COLUMNS`).
    """
    check_elevation_mask(min_elevation, max_elevation)
    signals = log.raw[log.raw["band"] == band]
    systems = "".join(sorted(set(signals["constellation"])))
    epochs = log.epochs
    if not systems or len(epochs) == 0:
        raise InputError(
            f"no {band} measurements in the log",
            where=str(log.path),
            fix="check the log, or choose another --band",
        )
    sky = orbits.positions_all(epochs, constellations=systems)
    at = pd.DataFrame(receiver_positions).set_index("time_utc")
    rx = at.reindex(sky["time_utc"])
    h = np.nan_to_num(rx["h"].to_numpy(dtype=float))
    az, el = azimuth_elevation(
        rx["lat"].to_numpy(dtype=float),
        rx["lon"].to_numpy(dtype=float),
        h,
        sky[["x", "y", "z"]].to_numpy(),
    )
    in_view = (el >= min_elevation) & (el <= max_elevation)
    table = pd.DataFrame(
        {
            "time_utc": sky["time_utc"].to_numpy()[in_view],
            "receiver": log.receiver,
            "lat": rx["lat"].to_numpy()[in_view],
            "lon": rx["lon"].to_numpy()[in_view],
            "h": rx["h"].to_numpy()[in_view],
            "constellation": sky["constellation"].to_numpy()[in_view],
            "svid": sky["svid"].to_numpy()[in_view],
            "azimuth": az[in_view],
            "elevation": el[in_view],
            "position_sd": rx.get("position_sd", pd.Series(np.nan, rx.index)).to_numpy()[in_view],
        }
    )
    key = ["time_utc", "constellation", "svid"]
    cn0 = signals.groupby(key, as_index=False)["cn0"].max()  # one value per satellite
    cn0["time_utc"] = cn0["time_utc"].astype(table["time_utc"].dtype)
    out = table.merge(cn0, on=key, how="left", validate="one_to_one")
    _warn_unplaced(log, cn0, sky, key)  # type: ignore[arg-type]  # a DataFrame: as_index=False
    return out[OBSERVATION_COLUMNS]


def _warn_unplaced(log: GnssLog, cn0: pd.DataFrame, sky: pd.DataFrame, key) -> None:
    """Say how many received signals have no orbit (a system or satellite the files lack)."""
    known = sky[key].drop_duplicates()
    known["time_utc"] = known["time_utc"].astype(cn0["time_utc"].dtype)
    matched = cn0.merge(known, on=key, how="left", indicator=True)["_merge"] == "both"
    if not matched.all():
        missing = cn0.loc[~matched.to_numpy(), ["constellation", "svid"]].drop_duplicates()
        names = ", ".join(f"{c}{s:02d}" for c, s in missing.itertuples(index=False))
        warnings.warn(
            f"{log.path}: {int((~matched).sum())} received signals of satellites without orbit "
            f"data were left out ({names})",
            stacklevel=3,
        )


def observe(
    logs: Sequence[StrPath],
    orbit_files: Sequence[StrPath],
    *,
    surveyed: StrPath | None = None,
    provider: str = "gps",
    method: str = "nearest",
    min_elevation: float = 10.0,
    max_elevation: float = 85.0,
    band: str = "L1",
    lenient: bool = False,
    progress: Callable[[str], object] | None = None,
) -> pd.DataFrame:
    """Observations of several GnssLogger logs, one receiver per log (its file name).

    Parameters
    ----------
    logs, orbit_files
        Paths of GnssLogger logs and of SP3 / RINEX navigation files covering them.
    surveyed
        Optional path of a manually surveyed positions file (see
        :func:`~gnss_citygml.gnss.positions.read_surveyed_positions`); without it the
        positions come from each log's ``Fix`` rows of ``provider`` (``method`` ``nearest``
        or ``interpolate``).
    min_elevation, max_elevation, band
        See :func:`observe_log`.
    lenient
        Skip bad log lines (counted and reported) instead of stopping at the first.
    progress
        Optional callable told the name of each log when it is done.
    """
    check_elevation_mask(min_elevation, max_elevation)  # before reading anything
    orbits = load_orbits(orbit_files)
    survey = None if surveyed is None else read_surveyed_positions(surveyed)
    frames, names = [], set()
    for path in logs:
        log = read_gnsslogger(path, lenient=lenient)
        if log.receiver in names:
            raise InputError(
                f"two logs are named {log.receiver!r}",
                where=str(path),
                fix="give every recording its own file name: it names the receiver",
            )
        names.add(log.receiver)
        if survey is None:
            where = positions(log, provider=provider, method=method)
        else:
            where = surveyed_positions(survey, log.receiver, log.epochs)
        frames.append(
            observe_log(
                log,
                orbits,
                where,
                min_elevation=min_elevation,
                max_elevation=max_elevation,
                band=band,
            )
        )
        if progress is not None:
            progress(log.receiver)
    return pd.concat(frames, ignore_index=True)

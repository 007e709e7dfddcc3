"""Batch updates of a GeoPackage map as new GNSS data arrives, without ever risking the map.

:func:`update_map` adds or updates the estimate columns (:data:`COLUMNS`) of a footprint layer
of a GeoPackage, for the buildings with enough signals. Every other column, feature, layer and
style of the file is kept, and the layer's feature ids do not change: the columns are written
with SQL on the layer's own table, by building id.

- **Never a damaged map.** The work is done on a copy beside the map, which is renamed over it
  only when complete (:func:`gnss_citygml.files.paths.atomic_path`); the map as it was is kept as
  ``MAP.bak.gpkg`` (unless ``backup=False``). A crash, Ctrl-C or ``kill -9`` at any moment
  leaves the map byte-identical. A map that another program is writing to (a write lock, or
  a write-ahead log that is not empty: QGIS editing a layer) is refused.
- **Evidence kept.** Every intersection cast so far (signal, building, height, C/N0, the
  height error that its receiver's position error gives and which rows share that error, ...) is
  kept in the table ``gnss_evidence`` of the GeoPackage, keyed by its signal (receiver, time,
  satellite). A later update casts only the observations not in it yet, and refits the
  model on all of the evidence, so its result is that of one run over all the observations.
  The model is refitted whole, not only for the buildings the new signals touch: 4PL-B
  co-trains one signal classifier on every building's signals, so new signals anywhere move
  the labels, and with them the fits, everywhere. The evidence is the layer's as SQLite names
  it (in any letter case), and records what it was cast with: a later update with other
  settings (elevation mask, receiver heights) or a DEM that gives other antenna heights where
  signals were cast from is refused, never mixed in. A damaged evidence table is a one-line
  error. A map given as a symbolic link is the file it names (updated; the link stays).
- **Idempotent.** The same observations again add no evidence and change no value; a
  building's ``updated_utc`` changes only when one of its values does, and a run that
  changes nothing writes nothing.
"""

from __future__ import annotations

import contextlib
import os
import shutil
import sqlite3
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import pandas as pd

from ..errors import InputError
from ..files.geopackage import check_geopackage, check_no_triggers, check_table_layer, refused
from ..files.names import check_utf8_name
from ..files.paths import StrPath, atomic_path, check_not_input, input_file
from ..settings import PositionError, RunSettings
from ..tiling.output import INDEX as TILE_INDEX
from .evidence import (
    CAST,
    EVIDENCE,
    EVIDENCE_COLUMNS,
    INTERSECTIONS,
    SIGNAL_COLUMNS,
    append_evidence,
    cast_settings,
    check_cast_with,
    check_receiver_heights,
    read_evidence,
    signal_keys,
)
from .layer import (
    COLUMNS,
    current_values,
    key_column,
    layer_name,
    new_values,
    write_columns,
)

if TYPE_CHECKING:
    import geopandas as gpd

__all__ = ["COLUMNS", "EVIDENCE", "UpdateResult", "update_map"]


@dataclass
class UpdateResult:
    """What an update did (or, with ``dry_run``, would do)."""

    #: Observations cast this time (those not in the evidence yet), and the evidence rows
    #: they added.
    new_signals: int
    new_evidence: int
    #: Every building: ``id``, the height before and after (m ODN, NaN for none), whether
    #: its values changed, and why it was skipped (empty if it was not).
    buildings: pd.DataFrame
    #: The height change (m) above which a building is listed as changed.
    threshold: float
    #: The buildings the new signals' rays enter.
    touched: frozenset[str] = frozenset()
    #: Whether the map was written (False for a dry run or when nothing changed).
    written: bool = False
    backup: Path | None = None
    notes: list[str] = field(default_factory=list)

    @property
    def updated(self) -> pd.DataFrame:
        return self.buildings[self.buildings["changed"]]

    @property
    def skipped(self) -> pd.DataFrame:
        return self.buildings[self.buildings["skipped"] != ""]

    def lines(self) -> list[str]:
        """The change report: counts, the buildings that moved by more than the threshold,
        the skipped ones by reason."""
        table = self.buildings
        delta = (table["after"] - table["before"]).abs()
        moved = table[table["changed"] & (delta > self.threshold)]
        gained = table[table["changed"] & table["before"].isna() & table["after"].notna()]
        lost = table[table["changed"] & table["before"].notna() & table["after"].isna()]
        lines = [
            f"{self.new_signals} new signals cast, {self.new_evidence} new intersections in "
            f"{len(self.touched)} buildings; "
            f"{len(self.updated)} of {len(table)} buildings updated, {len(moved)} by more "
            f"than {self.threshold:g} m, {len(gained)} with a first height, {len(lost)} "
            "without one now"
        ]
        for row in moved.itertuples(index=False):
            lines.append(f"  {row.id}: {row.before:.2f} -> {row.after:.2f} m")
        for reason, n in self.skipped["skipped"].value_counts().items():
            lines.append(f"skipped {n}: {reason}")
        return lines + self.notes


def update_map(
    path: StrPath,
    observations: Sequence[StrPath],
    dem: StrPath,
    *,
    layer: str | None = None,
    id_field: str | None = None,
    min_signals: int = 1,
    threshold: float = 0.5,
    dry_run: bool = False,
    backup: bool = True,
    settings: RunSettings | None = None,
    report: StrPath | None = None,
    truth: StrPath | None = None,
    progress: Callable[[str, float], None] | None = None,
    **changes: Any,
) -> UpdateResult:
    """Update the estimate columns of ``layer`` of the GeoPackage ``path`` with new
    ``observations`` (observations tables, CSV or Parquet); see the module's notes.

    A building gets values when it has at least ``min_signals`` signals in the evidence;
    ``threshold`` (m) is the height change above which it is listed in the change report.
    ``report`` is a folder for the report of the fit over all the evidence
    (:mod:`gnss_citygml.report`; ``truth``, a simulator's truth table, adds the true heights).
    ``settings`` (and their parts by name in ``changes``) are a run's
    (:class:`~gnss_citygml.settings.RunSettings`): its rays, receiver heights, estimator, grids
    and DEM CRS; each observation's own position error, in one process, without
    self-calibration.
    """
    from ..pipeline import fit_heights

    settings = _update_settings(RunSettings.of(settings, **changes))
    rays, receiver_heights, estimator = settings.rays, settings.receiver_heights, settings.estimator
    grid_dir, dem_crs = settings.grid_dir, settings.dem_crs
    say = progress or (lambda what, done: None)
    path = _check_map(path)
    check_no_triggers(path)
    true = _check_request(path, observations, dem, truth, report, backup, min_signals, threshold)
    say("reading", 0.0)
    read_at = _stamp(path)
    here = _read_layer(path, layer, id_field, dem, dem_crs, grid_dir)
    name, buildings = here.name, here.buildings
    # the phones' levels and the mixture learn from every signal cast (the open sky)
    sky_needed = estimator.levels_phones or estimator.signal_model == "mixture"
    before = read_evidence(path, name, with_signals=report is not None or sky_needed)
    cast_with = cast_settings(rays, receiver_heights)
    check_cast_with(path, before, cast_with)
    check_receiver_heights(before.cast, dem, receiver_heights, dem_crs)
    cast = _cast_new(
        observations, before.cast, buildings, dem, rays, receiver_heights, grid_dir, dem_crs, say
    )
    evidence, gone = _evidence(path, before.intersections, buildings, cast.fresh)
    say("fitting", 0.5)
    everything = cast.signals.iloc[:0]  # every signal cast, where the sky or the report needs it
    if sky_needed or report is not None:
        everything = _every_signal(before.cast, cast.signals)
    model, sky = _fit_input(evidence, buildings, everything if sky_needed else None)
    estimate, classifier = fit_heights(model, buildings, estimator, open_sky=sky)
    values, table = new_values(estimate, here.current, min_signals)
    touched = frozenset(cast.fresh["building"].astype(str))
    result = UpdateResult(cast.n_new, len(cast.fresh), table, threshold, touched)
    unseen = bool(before.intersections.empty and here.current["converged"].notna().any())
    result.notes += _notes(gone, before.outlines, here.outlines, unseen)
    if report is not None:
        say("report", 0.6)
        _write_report(report, true, estimate, here, everything, model, evidence, classifier)
    if dry_run or (cast.signals.empty and not table["changed"].any()):
        if not dry_run:
            result.notes.append("nothing changed: the map is untouched")
        return result
    say("writing", 0.75)
    changed = values[table["changed"].to_numpy()]
    result.backup = _write_map(path, read_at, here, cast, changed, cast_with, backup)
    result.written = True
    say("done", 1.0)
    return result


def _update_settings(settings: RunSettings) -> RunSettings:
    """Refuse the settings an update has no use for, rather than ignore them."""
    for unused, what, fix in (
        (settings.calibration.on, "self-calibration", "--calibration-sd"),
        (settings.tiling.on, "a run on a Dask scheduler", "--scheduler"),
        (settings.position_error != PositionError(), "a position error", "--position-sd"),
    ):
        if unused:
            raise InputError(
                f"an update does not take {what}: it casts each observation with its own "
                "position error, in one process",
                fix=f"leave out {fix} (estimate the map again to use it)",
            )
    return settings


@dataclass(frozen=True)
class _Layer:
    """The footprint layer as read: its table's name (as the database names it: the evidence's
    key), the buildings grounded on the DEM, the source's id field, a digest of the outlines,
    the column of the table holding the ids with its values by id, and the estimate columns
    now."""

    name: str
    buildings: gpd.GeoDataFrame
    id_column: str
    outlines: str
    key: str
    stored_ids: pd.Series
    current: pd.DataFrame


def _read_layer(path, layer, id_field, dem, dem_crs, grid_dir) -> _Layer:
    """Read the map's footprint layer (:class:`_Layer`)."""
    from ..files.ids import id_field as source_id_field
    from ..jobs import read_buildings

    name = layer_name(path, layer)
    check_table_layer(path, name)
    buildings = read_buildings(
        path,
        layer=None if layer is None else name,
        id_field=id_field,
        dem=dem,
        dem_crs=dem_crs,
        grid_dir=grid_dir,
    )
    id_column = source_id_field(buildings)
    key, stored_ids = key_column(path, name, [id_column, id_field, "fid"], buildings["id"])
    current = current_values(path, name, key, buildings["id"])  # (checks our columns' types)
    return _Layer(name, buildings, id_column, _outlines(buildings), key, stored_ids, current)


def _write_map(path, read_at, here: _Layer, cast: _Cast, changed, settings, backup) -> Path | None:
    """Write the new evidence and the ``changed`` buildings' values through a copy of the map
    renamed over it, with the map as it was kept beside it (``backup``: its path, else None)."""
    if _stamp(path) != read_at:  # (from here on, atomic_path watches the file)
        raise InputError(
            "the map changed while this update ran (another update?)",
            where=str(path),
            fix="run again once the other program has finished with it",
        )
    with atomic_path(path, overwrite=True, update=True) as tmp, refused(path):
        if len(cast.fresh):
            append_evidence(tmp, here.name, INTERSECTIONS, cast.fresh, here.outlines, settings)
        if len(cast.signals):
            append_evidence(tmp, here.name, CAST, cast.signals, here.outlines, settings)
        ids = changed["id"].map(here.stored_ids)
        write_columns(tmp, here.name, here.key, changed.assign(id=ids))
        return _backup(path) if backup else None


def _check_request(path, observations, dem, truth, report, backup, min_signals, threshold):
    """The request's own checks, before anything is read: outputs that would overwrite an
    input, a truth table without a report, the counts and the threshold. Returns the truth
    table, read (None without one)."""
    inputs = [path, *observations, dem, truth]
    if backup:  # (the map itself is written through a copy: a new layer's columns, not a file)
        check_not_input(_backup_path(path), inputs, what="backup")
    from ..report import check_report_request

    true = check_report_request(report, truth, overwrite=True, inputs=inputs)
    if min_signals < 1:
        raise InputError(f"min_signals must be 1 or more, not {min_signals}", fix="give N >= 1")
    if not (np.isfinite(threshold) and threshold >= 0):
        raise InputError(
            f"the change threshold must be a number of metres, 0 or more, not {threshold}",
            fix="give --threshold in metres, e.g. 0.5",
        )
    return true


@dataclass(frozen=True)
class _Cast:
    """The observations not in the evidence yet, cast: how many, their intersections (the
    evidence's columns) and their signals (:data:`~.evidence.SIGNAL_COLUMNS`)."""

    n_new: int
    fresh: pd.DataFrame
    signals: pd.DataFrame


def _cast_new(
    observations, cast_before, buildings, dem, rays, receiver_heights, grid_dir, dem_crs, say
) -> _Cast:
    """Read the observation files and cast the signals the evidence has not seen yet."""
    from ..observations import read_observation_files
    from ..stages import in_mask, intersections, receivers

    obs = in_mask(read_observation_files(observations), rays)  # each signal once (it warns)
    unseen = ~signal_keys(obs).isin(cast_before["signal_key"]).to_numpy()
    new = obs[unseen].reset_index(drop=True)
    if not len(new):
        return _Cast(
            0, pd.DataFrame(columns=EVIDENCE_COLUMNS), pd.DataFrame(columns=SIGNAL_COLUMNS)
        )
    say("casting", 0.25)
    rx = receivers(new, dem, heights=receiver_heights, grid_dir=grid_dir, dem_crs=dem_crs)
    rx["signal_key"] = signal_keys(rx).to_numpy()
    cast = intersections(rx, buildings, rays=rays)
    fresh = cast.assign(
        signal_key=rx["signal_key"].to_numpy()[cast["signal"].to_numpy()],
        building=cast["building"].astype(str),
        satellite=cast["satellite"].astype(str),
        recording=cast["recording"].astype(str),
    )[EVIDENCE_COLUMNS]
    return _Cast(len(new), fresh, rx.drop_duplicates("signal_key")[SIGNAL_COLUMNS])


def _evidence(path, stored, buildings, fresh) -> tuple[pd.DataFrame, int]:
    """All the evidence to fit: what is stored for the layer's footprints and what was cast
    now; and how many stored rows were left out (footprints deleted since). None is an
    error."""
    gone = ~stored["building"].isin(buildings["id"].astype(str)).to_numpy()
    stored = stored[~gone].reset_index(drop=True)
    evidence = pd.concat([stored, fresh], ignore_index=True) if len(fresh) else stored
    if evidence.empty:
        raise InputError(
            "no evidence: no signal's ray enters a footprint of the map",
            where=str(path),
            fix="give observations made among the map's buildings",
        )
    return evidence, int(gone.sum())


def _every_signal(cast_before, signals) -> pd.DataFrame:
    """Every signal cast, once each (a damaged store's repeats would break the lookups)."""
    everything = pd.concat([cast_before, signals], ignore_index=True)
    return everything.drop_duplicates("signal_key", ignore_index=True)


def _fit_input(evidence, buildings, everything) -> tuple[pd.DataFrame, pd.DataFrame | None]:
    """The evidence as the height fits take it (signals coded, buildings the layer's), and,
    given ``everything`` (every signal cast), each row's elevation and the open sky: the
    signals whose rays entered no footprint."""
    model = evidence.assign(
        signal=pd.factorize(evidence["signal_key"])[0],
        building=pd.Categorical(evidence["building"], categories=buildings["id"].astype(str)),
    ).drop(columns="signal_key")
    if everything is None:
        return model, None
    signal_elevations = everything.set_index("signal_key")["elevation"]
    model["elevation"] = signal_elevations.reindex(evidence["signal_key"]).to_numpy()
    return model, everything[~everything["signal_key"].isin(evidence["signal_key"])]


def _notes(gone: int, outlines_before: str | None, outlines: str, unseen: bool) -> list[str]:
    """What the change report says of the evidence: some left out, outlines changed, none
    behind the layer's estimates (``unseen``: ``estimate``'s layer, whose observations an
    update has not seen)."""
    notes = []
    if unseen:
        notes.append(
            "the layer's estimates came with no evidence (estimate's output?): they are "
            "replaced by the fit of these observations alone (to keep what the earlier ones "
            "saw, give them too)"
        )
    if gone:
        notes.append(f"{gone} intersections with footprints no longer in the layer left out")
    if outlines_before not in (None, outlines):
        notes.append(
            "the footprints changed since the evidence was cast; signals cast before are "
            "not cast again against new or edited outlines (to cast everything again, delete "
            f"the table {EVIDENCE})"
        )
    return notes


def _write_report(report, true, estimate, here: _Layer, everything, model, evidence, classifier):
    """The report of the fit over all the evidence (:mod:`gnss_citygml.report`)."""
    from ..files.ids import with_id_field
    from ..pipeline import Run
    from ..report import write_report

    run = Run(
        heights=with_id_field(estimate, here.id_column),
        receivers=everything.drop(columns="z"),
        intersections=model.assign(
            signal=pd.Index(everything["signal_key"]).get_indexer(evidence["signal_key"]),
            building=evidence["building"].to_numpy(),
        ),
        buildings=here.buildings,
        classifier=classifier,
    )
    write_report(run, report, truth=true)


def _check_map(path: StrPath) -> Path:
    """The map: an existing GeoPackage that no other program is writing to; the file itself
    when ``path`` is a symbolic link (the update replaces the file, and the link stays)."""
    if (Path(path) / TILE_INDEX).is_file():
        raise InputError(
            "the map is a folder of tiles from a run in tiles: an update keeps its evidence and "
            "columns in one GeoPackage, and a tile's rays cross into its neighbours",
            where=str(path),
            fix="estimate the whole again, the same heights as one run: partition the old and "
            "new observations together, then estimate PARTITION -o FOLDER --scheduler ...",
        )
    path = Path(os.path.realpath(input_file(path, "map")))
    check_utf8_name(path, "map")  # (GDAL writes it)
    if path.suffix.lower() != ".gpkg":
        raise InputError(
            "the map must be a GeoPackage (.gpkg): only there can the evidence and the columns "
            "be added in place",
            where=str(path),
            fix="convert it first (ogr2ogr -f GPKG map.gpkg ...)",
        )
    check_geopackage(path, empty_ok=False)
    for suffix in ("-wal", "-shm"):
        side = path.with_name(path.name + suffix)
        if side.exists():
            raise InputError(
                f"the map is open in another program ({side.name} is beside it: SQLite's "
                "write-ahead log of an open connection, whose later writes would damage the "
                "updated file)",
                where=str(path),
                fix="close it there (QGIS: remove the layer from the project, or quit), then "
                "run again",
            )
    try:
        with contextlib.closing(sqlite3.connect(path, timeout=0.1)) as db:
            db.execute("BEGIN IMMEDIATE")  # a write lock: fails while another one holds it
            db.rollback()
    except sqlite3.DatabaseError as exc:
        raise InputError(
            f"the map cannot be locked for writing ({exc})",
            where=str(path),
            fix="another program is writing to it: let it finish or close it, then run again",
        ) from None
    return path


def _outlines(buildings: pd.DataFrame) -> str:
    """A digest of the footprints' ids and outlines, kept with the evidence cast against them."""
    import hashlib

    import shapely

    order = np.argsort(buildings["id"].astype(str).to_numpy(), kind="stable")
    digest = hashlib.sha256()
    for building, wkb in zip(
        buildings["id"].astype(str).to_numpy()[order],
        shapely.to_wkb(buildings.geometry.to_numpy()[order]),
        strict=True,
    ):
        digest.update(building.encode() + b"\0" + wkb)
    return digest.hexdigest()


def _stamp(path: Path) -> tuple[int, int, int]:
    """The file's inode, size and modification time: what changes when it is written."""
    info = path.stat()
    return info.st_ino, info.st_size, info.st_mtime_ns


def _backup_path(path: Path) -> Path:
    """Where the map as it was is kept: ``MAP.bak.gpkg``, a GeoPackage QGIS opens."""
    return path.with_name(path.stem + ".bak" + path.suffix)


def _backup(path: Path) -> Path:
    """``MAP.bak.gpkg``: the map as it was, written atomically beside it."""
    target = _backup_path(path)
    with atomic_path(target, overwrite=True) as tmp:
        shutil.copyfile(path, tmp)
    return target

"""The plan of an export: which buildings go out, and why the others do not.

The writers take the *buildings* table with heights: ``id``, ``geometry``, ``ground`` and
``height`` (the absolute roof height, m ODN), made by :mod:`.heights` from a heights table or
any footprint layer with a height attribute. :func:`prepare_buildings` checks
it and returns a :class:`Plan`, which hands the usable buildings out a chunk at a time, their
footprints snapped to the millimetre grid (:func:`~gnss_citygml.export.prisms.snap_footprints`),
and lists the others with their reason.

Rules
-----
- **Refused** (an error, nothing is written): not a GeoDataFrame in EPSG:27700, missing
  columns, missing or duplicate ids, non-polygon footprints, non-numeric heights, part ids
  (``<id>-1``, ...) that are building ids, or no building with a usable height.
- **Skipped buildings**: a building without a usable height is never written with a guessed
  one. No ground, no height, an estimate that did not converge, a roof not above the ground
  (after rounding to mm), heights that no building in Great Britain has (a roof more than
  :data:`MAX_HEIGHT_ABOVE_GROUND` above the ground, a ground outside :data:`GROUND_RANGE`), a
  footprint outside the British National Grid (:data:`GRID_EXTENT`) or one that vanishes at
  1 mm precision: the building is left out and listed with its reason (or, with
  ``strict=True``, the export stops with an error).
"""

from __future__ import annotations

import warnings
from collections.abc import Iterator, Sequence

import geopandas as gpd
import numpy as np
import pandas as pd
import shapely

from ..errors import InputError, MissingColumnError, listing, user_text
from ..files.ids import id_field, id_named, missing_ids
from ..files.paths import StrPath
from ..geodesy import check_bng
from ..validate import Report
from .output import ExportResult
from .prisms import part_ids, snap_footprints

__all__ = [
    "CHECK_CHUNK",
    "CHUNK",
    "GRID_EXTENT",
    "GROUND_RANGE",
    "MAX_HEIGHT_ABOVE_GROUND",
    "Plan",
    "booleans",
    "chunks",
    "hash_texts",
    "numeric",
    "prepare_buildings",
    "repeated_positions",
]

#: Buildings extruded and written at once by the streaming writers.
CHUNK = 2048
#: Rows of the buildings table checked at once by :func:`prepare_buildings`.
CHECK_CHUNK = 8 * CHUNK

#: Highest roof above the ground (m) that is written. The tallest structures in Great Britain
#: stand about 330 m (Emley Moor mast; The Shard 310 m); a higher "building" is an error in the
#: data (a height in millimetres or feet, a wrong field), not a building.
MAX_HEIGHT_ABOVE_GROUND = 400.0
#: Ground heights (m ODN) that exist in Great Britain, with a margin: Holme Fen is 2.75 m below
#: sea level, Ben Nevis 1,345 m above it.
GROUND_RANGE = (-10.0, 1400.0)
#: Where British National Grid coordinates exist (m: min E, min N, max E, max N), with a margin.
GRID_EXTENT = (-100_000.0, -100_000.0, 800_000.0, 1_400_000.0)
_TOO_TALL = (
    f"roof more than {MAX_HEIGHT_ABOVE_GROUND:.0f} m above the ground (no structure in Great "
    "Britain is; a height in mm or feet, or the wrong field?)"
)
_GROUND_OUTSIDE = (
    f"ground outside {GROUND_RANGE[0]:.0f}..{GROUND_RANGE[1]:.0f} m ODN (no ground in Great "
    "Britain is; a height in mm or feet, or the wrong field?)"
)
_TRUE = {"true", "t", "yes", "y", "1", "1.0"}
_FALSE = {"false", "f", "no", "n", "0", "0.0"}


def numeric(frame: pd.DataFrame, name: str) -> np.ndarray:
    """The column ``name`` as floats (NaN where empty); text is an error naming the buildings."""
    try:
        return pd.to_numeric(frame[name], errors="raise").to_numpy(dtype=float, na_value=np.nan)
    except (ValueError, TypeError):
        bad = pd.to_numeric(frame[name], errors="coerce").isna() & frame[name].notna()
        ids = frame["id"][bad] if "id" in frame.columns else frame.index[bad]
        raise InputError(
            f"column {name!r} is not numeric ({listing(list(ids))})",
            where="footprint layer",
            fix="give heights in metres as numbers",
        ) from None


class Plan:
    """The buildings to write, handed out a chunk at a time (from :func:`prepare_buildings`).

    The caller's table is not copied: each chunk is taken from it, its footprints snapped to
    the millimetre grid, so the writers' memory does not grow with the number of buildings.

    Attributes
    ----------
    frame
        The caller's buildings table.
    rows
        Positions (in ``frame``) of the buildings with a usable height.
    skipped
        ``(id, reason)`` of the buildings left out so far.
    written
        Buildings handed out so far.
    id_field
        The name of the source's id field (:mod:`gnss_citygml.files.ids`), for an id attribute.
    """

    def __init__(
        self,
        frame: gpd.GeoDataFrame,
        rows: np.ndarray,
        skipped: list,
        strict: bool,
        bounds: np.ndarray,
    ):
        self.frame = frame
        self.id_field = id_field(frame)
        self.rows = rows
        self.skipped = skipped
        self.strict = strict
        self.written = 0
        self._bounds = bounds

    def chunks(
        self, size: int = CHUNK, subset: np.ndarray | None = None
    ) -> Iterator[gpd.GeoDataFrame]:
        """The buildings, ``size`` at a time: text ``id``, snapped footprints, a fresh index;
        those at ``subset`` only (some of :attr:`rows`), if given."""
        positions = self.rows if subset is None else subset
        for part in chunks(len(positions), size):
            rows = self.frame.iloc[positions[part]].reset_index(drop=True)
            footprints = snap_footprints(rows.geometry.to_numpy())
            gone = shapely.is_empty(footprints)
            rows["id"] = rows["id"].astype(str)
            if gone.any():
                ids = rows["id"][gone].tolist()
                self.skipped.extend((i, "footprint vanishes at 1 mm precision") for i in ids)
                if self.strict:
                    raise InputError(
                        f"{len(ids)} footprint(s) vanish at 1 mm precision: {listing(ids)}",
                        where="buildings",
                        fix="drop them, or leave out --strict to skip them",
                    )
                rows, footprints = rows[~gone].reset_index(drop=True), footprints[~gone]
            if len(rows):
                self.written += len(rows)
                yield rows.set_geometry(footprints)

    def bounds_mm(self) -> np.ndarray:
        """(min e, min n, min ground, max e, max n, max roof) of the buildings, in mm."""
        return np.rint(self._bounds * 1000).astype(np.int64)

    def result(self, path: StrPath, report: Report | None) -> ExportResult:
        """What was written; an error if nothing was."""
        if not self.written:
            raise InputError(
                f"none of the {len(self.frame)} buildings can be modelled "
                f"({_reason_counts(self.skipped)})",
                where="buildings",
                fix="check their footprints and heights",
            )
        skipped = pd.DataFrame(self.skipped, columns=["id", "reason"], dtype=object)
        return ExportResult(str(path), self.written, skipped, report)


def prepare_buildings(buildings: gpd.GeoDataFrame, *, strict: bool = False) -> Plan:
    """Check the buildings table and set aside the buildings without a usable height.

    The table is read :data:`CHECK_CHUNK` rows at a time; across chunks only a hash of each id
    (8 bytes), the positions of the usable buildings and the bounds are kept, so the memory
    used does not grow with the table beyond a few bytes per building.

    Parameters
    ----------
    buildings
        GeoDataFrame in EPSG:27700 with ``id``, ``geometry`` (Polygon/MultiPolygon), ``ground``
        and ``height`` (absolute roof height, m ODN); ``converged`` (and ``status``, the reason)
        is honoured when present. The id may be under the name of its source's field
        (``attrs["id_field"]``, as :func:`~gnss_citygml.pipeline.estimate` returns it).
    strict
        Raise instead of skipping buildings without a usable height.

    Returns
    -------
    Plan
        The buildings to write, a chunk at a time, and the skipped ones with their reasons.

    Raises
    ------
    InputError
        Not a GeoDataFrame in EPSG:27700, missing columns, missing or duplicate ids, non-polygon
        footprints, non-numeric heights, part ids taken by buildings, no usable height, or
        (``strict``) skipped buildings.
    """
    check_bng(buildings)
    buildings = id_named(buildings)
    missing = [c for c in ("id", "ground", "height") if c not in buildings.columns]
    if missing:
        raise MissingColumnError(missing, where="buildings", have=list(buildings.columns))
    checks = _Checks(len(buildings))
    for part in chunks(len(buildings), CHECK_CHUNK):
        checks.add(buildings.iloc[part], part.start)
    checks.raise_errors(buildings)
    skipped = checks.skipped
    if strict and skipped:
        raise InputError(
            f"{len(skipped)} building(s) without a usable height: "
            + listing([f"{i} ({r})" for i, r in skipped]),
            where="buildings",
            fix="drop them, or leave out --strict to skip them",
        )
    if not checks.usable.any():
        raise InputError(
            f"none of the {len(buildings)} buildings has a usable height "
            f"({_reason_counts(skipped)})",
            where="buildings",
            fix="check the height and ground columns",
        )
    bounds = np.concatenate([checks.low, checks.high])
    rows = np.flatnonzero(checks.usable)
    _warn_not_finite(buildings, rows)
    return Plan(buildings, rows, skipped, strict, bounds)


def _warn_not_finite(buildings: gpd.GeoDataFrame, rows: np.ndarray) -> None:
    """Warn of each number column but the heights that is infinite for buildings to write:
    JSON has none (CityJSON, and 3D Tiles' properties hold one no-data value), so every
    format writes it as no value, which the warning says rather than leave it unsaid."""
    for name in buildings.columns:
        column = buildings[name]
        if name in ("id", "ground", "height") or not pd.api.types.is_float_dtype(column.dtype):
            continue
        values = column.iloc[rows].to_numpy(dtype=float, na_value=np.nan)
        bad = np.isinf(values)
        if bad.any():
            ids = buildings["id"].iloc[rows[bad]].astype(str).tolist()
            warnings.warn(
                f"column {user_text(str(name))} is not finite for buildings {listing(ids)}: "
                "written as no value, in every format alike (JSON has no infinity)",
                stacklevel=3,
            )


class _Checks:
    """What :func:`prepare_buildings` gathers over the chunks of a table of n buildings."""

    def __init__(self, n: int):
        self.hashes = np.zeros(n, dtype=np.int64)  # of each id
        self.usable = np.zeros(n, dtype=bool)
        self.low, self.high = np.full(3, np.inf), np.full(3, -np.inf)  # e, n, z
        self.skipped: list[tuple[str, str]] = []
        self.no_id: list[np.ndarray] = []  # positions
        self.not_polygon: list[str] = []  # ids
        self.part_hashes: list[np.ndarray] = []  # of each part id of a MultiPolygon
        self.part_rows: list[np.ndarray] = []  # position of the building of each part
        self.numeric = True

    def add(self, frame: gpd.GeoDataFrame, first: int) -> None:
        """Check the buildings ``frame``, which start at position ``first`` of the table."""
        self.no_id.append(np.flatnonzero(missing_ids(frame["id"])) + first)
        ids = frame["id"].astype(str).to_numpy(dtype=object)
        self.hashes[first : first + len(ids)] = hash_texts(ids)
        geoms = frame.geometry.to_numpy()
        kind = shapely.get_type_id(geoms)
        self.not_polygon.extend(ids[~np.isin(kind, [3, 6])].tolist())
        multi = kind == 6
        if multi.any():
            groups = part_ids(ids[multi], geoms[multi])
            self.part_hashes.append(hash_texts([p for group in groups for p in group]))
            sizes = [len(group) for group in groups]
            self.part_rows.append(np.repeat(np.flatnonzero(multi) + first, sizes))
        try:
            ground, height = numeric(frame, "ground"), numeric(frame, "height")
        except InputError:  # reported for the whole table by raise_errors
            self.numeric = False
            return
        reason = _reasons(frame, ground, height)
        skip = reason != None  # noqa: E711 - elementwise comparison of an object array
        self.skipped.extend(zip(ids[skip].tolist(), reason[skip].tolist(), strict=True))
        keep = ~skip
        self.usable[first : first + len(ids)] = keep
        if keep.any():
            e0, n0, e1, n1 = shapely.total_bounds(geoms[keep])
            self.low = np.minimum(self.low, [e0, n0, ground[keep].min()])
            self.high = np.maximum(self.high, [e1, n1, height[keep].max()])

    def raise_errors(self, buildings: gpd.GeoDataFrame) -> None:
        """Raise the first error found, in the order the checks are documented."""
        no_id = np.concatenate(self.no_id) if self.no_id else np.zeros(0, dtype=np.int64)
        if no_id.size:
            raise InputError(
                f"{no_id.size} building(s) without an id (missing, blank or with a NUL"
                f" character; rows {listing(no_id)})",
                where="buildings",
                fix="give every building an id",
            )
        ids = buildings["id"]
        suspects = repeated_positions(self.hashes)
        texts = ids.iloc[suspects].astype(str).to_numpy(dtype=object)
        repeated = pd.unique(texts[pd.Series(texts, dtype=object).duplicated().to_numpy()])
        if repeated.size:
            raise InputError(
                f"{repeated.size} duplicate building id(s): {listing(repeated)}",
                where="buildings",
                fix="give each building its own id",
            )
        if self.not_polygon:
            raise InputError(
                f"{len(self.not_polygon)} building(s) without a polygon footprint: "
                + listing(self.not_polygon),
                where="buildings",
                fix="give Polygon or MultiPolygon footprints (drop or repair the others)",
            )
        if self.part_hashes:
            parts = np.concatenate(self.part_hashes), np.concatenate(self.part_rows)
            _check_part_ids(buildings, self.hashes, *parts)
        if not self.numeric:
            numeric(buildings, "ground"), numeric(buildings, "height")  # raises


def _reasons(frame: gpd.GeoDataFrame, ground: np.ndarray, height: np.ndarray) -> np.ndarray:
    """Why each building cannot be modelled, or None."""
    reason = np.full(len(frame), None, dtype=object)
    with np.errstate(invalid="ignore", over="ignore"):
        above = height - ground
        rules = [
            (above > MAX_HEIGHT_ABOVE_GROUND, _TOO_TALL),
            (np.rint(height * 1000) <= np.rint(ground * 1000), "roof not above the ground"),
            ((ground < GROUND_RANGE[0]) | (ground > GROUND_RANGE[1]), _GROUND_OUTSIDE),
            (
                _outside_grid(frame.geometry.to_numpy()),
                "footprint outside the British National Grid",
            ),
            (~np.isfinite(ground), "no ground height"),
            (~np.isfinite(height), "no height"),
        ]
    for mask, text in rules:  # the last rule that applies wins: the most basic one
        reason[mask] = text
    if "converged" in frame.columns:
        converged = booleans(frame["converged"], "converged", frame)  # missing: no estimate
        failed = (~converged).fillna(False).to_numpy(dtype=bool)
        if "height_source" in frame.columns:  # another field's height is not the fit's
            failed &= frame["height_source"].astype(str).to_numpy() == "gnss"
        status = frame["status"].astype(str).to_numpy() if "status" in frame else None
        reason[failed] = [
            "height estimate did not converge" + (f" ({status[i]})" if status is not None else "")
            for i in np.flatnonzero(failed)
        ]
    return reason


def _outside_grid(geoms: np.ndarray) -> np.ndarray:
    e0, n0, e1, n1 = shapely.bounds(geoms).T
    with np.errstate(invalid="ignore"):
        return (
            (e0 < GRID_EXTENT[0])
            | (n0 < GRID_EXTENT[1])
            | (e1 > GRID_EXTENT[2])
            | (n1 > GRID_EXTENT[3])
        )


def booleans(column: pd.Series, name: str, frame: pd.DataFrame) -> pd.Series:
    """A column of flags as pandas' nullable booleans: True/False, 1/0 or their spellings in
    text (true/false, yes/no, t/f, y/n, any case); empty is missing. Anything else is an error
    naming the buildings, never a guess.

    Examples
    --------
    >>> frame = pd.DataFrame({"id": ["a", "b", "c"], "ok": ["Yes", "no", None]})
    >>> booleans(frame["ok"], "ok", frame).tolist()
    [True, False, <NA>]
    """
    if pd.api.types.is_bool_dtype(column):
        return column.astype("boolean")
    text = column.astype("string").str.strip().str.lower()
    out = pd.Series(pd.NA, index=column.index, dtype="boolean")
    out[text.isin(_TRUE).fillna(False)] = True
    out[text.isin(_FALSE).fillna(False)] = False
    bad = (out.isna() & text.notna() & (text != "")).to_numpy()
    if bad.any():
        ids = frame["id"][bad].astype(str) if "id" in frame.columns else frame.index[bad]
        values = pd.unique(column[bad].astype(str))
        raise InputError(
            f"column {name!r} is not true/false: {listing(map(repr, values))} "
            f"(buildings {listing(list(ids))})",
            where="buildings",
            fix="give true or false (yes/no, 1/0)",
        )
    return out


def hash_texts(texts: Sequence[str] | np.ndarray) -> np.ndarray:
    """A 64-bit hash of each of a sequence of texts (Python's: comparable within a process)."""
    return np.fromiter(map(hash, texts), dtype=np.int64, count=len(texts))


def repeated_positions(hashes: np.ndarray) -> np.ndarray:
    """Sorted positions of the hashes that occur more than once (texts that may repeat).

    Examples
    --------
    >>> repeated_positions(np.array([5, 3, 5, 7, 3, 9])).tolist()
    [0, 1, 2, 4]
    """
    order = np.argsort(hashes, kind="stable")
    ranked = hashes[order]
    same = ranked[1:] == ranked[:-1]
    twice = np.zeros(len(hashes), dtype=bool)
    twice[1:] = same
    twice[:-1] |= same
    return np.sort(order[twice])


def _reason_counts(skipped) -> str:
    """``"no height: 3 (a, b, c); ..."``: the skipped buildings by reason, most first."""
    by_reason: dict[str, list] = {}
    for building, reason in skipped:
        by_reason.setdefault(reason, []).append(building)
    ranked = sorted(by_reason.items(), key=lambda item: -len(item[1]))
    return "; ".join(f"{r}: {len(ids)} ({listing(ids[:3])})" for r, ids in ranked)


def chunks(n: int, size: int = CHUNK) -> list[slice]:
    """Slices of ``range(n)`` of at most ``size`` items."""
    return [slice(i, min(i + size, n)) for i in range(0, n, size)]


def _check_part_ids(buildings: gpd.GeoDataFrame, hashes, part_hashes, part_rows) -> None:
    """Refuse part ids (of MultiPolygon footprints) that are building ids.

    ``hashes`` are those of the building ids, ``part_hashes`` those of the part ids and
    ``part_rows`` the position of the building of each part; texts are compared only where
    hashes match.
    """
    suspects = np.flatnonzero(np.isin(hashes, part_hashes))
    if not suspects.size:
        return
    owners = np.unique(part_rows[np.isin(part_hashes, hashes[suspects])])
    rows = buildings.iloc[owners]
    ids = rows["id"].astype(str).to_numpy(dtype=object)
    parts = {p for group in part_ids(ids, rows.geometry.to_numpy()) for p in group}
    texts = buildings["id"].iloc[suspects].astype(str).to_numpy(dtype=object)
    taken = texts[pd.Index(texts, dtype=object).isin(parts)]
    if taken.size:
        raise InputError(
            f"building part ids clash with building ids: {listing(sorted(taken))}",
            where="buildings",
            fix="rename those buildings (the parts of building X are named X-1, X-2, ...)",
        )

"""``estimate_heights``: the intersections table in, the heights table out, by any method.

Also :func:`fourplb`, 4PL-B (or the one-shot 4PL) on coded arrays: a run of one part
(:mod:`.parts`) over the per-building maths of :mod:`.fourplb`.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np
import numpy.typing as npt
import pandas as pd

from ..errors import InputError, MissingColumnError, listing
from ..settings import Estimator
from .baselines import bayes_heights, hinge_heights
from .engine import run_parts
from .fourplb import BuildingFits, SignalModel
from .mixture import Cn0Moments, elevation_units
from .offsets import levelled, sky_counts
from .parts import Part
from .row_codes import compact

__all__ = [
    "HEIGHTS_COLUMNS",
    "estimate_heights",
    "fourplb",
    "heights_and_signal_model",
    "intersections_part",
    "no_heights",
    "phone_offsets",
    "open_sky_moments",
]

#: Columns of the heights table, in order (see DESIGN.md; ``status`` says why a building did
#: not converge, or ``ok``).
HEIGHTS_COLUMNS = [
    "id",
    "height",
    "height_lower",
    "height_upper",
    "height_paper",
    "a",
    "b",
    "c",
    "d",
    "n_signals",
    "iterations",
    "converged",
    "method",
    "status",
]

#: The heights table's columns that are not floats (or are set apart).
_NOT_FLOAT = ("id", "n_signals", "iterations", "converged", "method", "status")

_REQUIRED = ["building", "height", "cn0"]


def estimate_heights(
    intersections: pd.DataFrame,
    estimator: Estimator = Estimator(),
    open_sky: pd.DataFrame | None = None,
) -> pd.DataFrame:
    """Estimate every building's height from the signals that cross its footprint.

    Parameters
    ----------
    intersections
        The intersections table (DataFrame or mapping of equal-length columns) with at least
        ``building`` (id), ``height`` (ODN height of the ray where it enters the footprint, m)
        and ``cn0`` (dB-Hz, NaN = blocked); optionally ``signal`` (rows with the same value are
        one signal crossing several buildings), ``receiver``, ``distance``, ``order`` and
        ``height_sd`` (m: how far each height may be off owing to its receiver's position
        error, e.g. from :func:`gnss_citygml.pipeline.intersections` given a
        :class:`~gnss_citygml.settings.PositionError`). With ``height_sd``, 4PL-B and 4PL model
        that error (the slope ``b`` is then the roof line's own) and widen the range by the
        roof line's position uncertainty, each ``recording`` (default: each ``receiver``)
        counting as one shared error. With ``crossing`` (each row's chance that its ray crosses
        the building, given the position error; ``PositionError(crossing=True)``), each row
        weighs by it, and with whole-ray blame (``Estimator(blame="ray")``) a ray's chance of
        being blocked by each building it crosses or passes near (``order`` below 0) does. With
        ``elevation`` (deg), the mixture signal model learns how C/N0 changes with it.
    estimator
        The method and its settings (:class:`~gnss_citygml.settings.Estimator`; default: 4PL-B
        with the paper's settings), e.g. ``Estimator(method="hinge")`` or
        ``Estimator(init_threshold=25)``.
    open_sky
        Optional: the signals whose rays cross no footprint (``cn0``, optionally
        ``elevation``; e.g. :func:`gnss_citygml.pipeline.open_sky`), open as far as the map
        knows: each phone's C/N0 is levelled by them (``Estimator(level_phones=True)``, the
        default: with ``receiver`` and ``elevation`` here and in the intersections), and the
        mixture signal model (``Estimator(signal_model="mixture")``) learns from them what
        open signals look like.

    Returns
    -------
    pandas.DataFrame
        The heights table, one row per building in order of first appearance: ``id``,
        ``height`` (for the 4PL methods ``c``, or the paper's c + 1.5/b with
        ``height_rule="paper"``), ``height_lower`` and ``height_upper`` (the 3/b-wide
        transition centred on the height; 4PL-B stretches it over the 95 % likelihood-ratio
        interval of ``c``, :func:`~gnss_citygml.model.fourpl.c_interval`; with ``height_sd``
        both ends move out by twice the standard error of ``c`` from position errors, added to
        the interval in quadrature),
        ``height_paper`` (c + 1.5/b, whichever the rule), ``a``, ``b``, ``c``, ``d``,
        ``n_signals``, ``iterations``, ``converged``,
        ``method`` and ``status``. A building whose estimate is not to be trusted has
        ``converged = False``, empty heights and the reason in ``status``. The final signal
        model comes with it from :func:`heights_and_signal_model`.

    Raises
    ------
    InputError
        Missing columns, columns of different lengths, non-numeric or NaN heights.

    Examples
    --------
    >>> import pandas as pd
    >>> table = pd.DataFrame({"building": ["a", "a"], "height": [10.0, 30.0], "cn0": [None, 40]})
    >>> estimate_heights(table, Estimator(method="hinge"))[["id", "converged", "status"]]
      id  converged                 status
    0  a      False  fewer than 10 signals
    """
    return heights_and_signal_model(intersections, estimator, open_sky)[0]


def heights_and_signal_model(
    intersections: pd.DataFrame,
    estimator: Estimator = Estimator(),
    open_sky: pd.DataFrame | None = None,
) -> tuple[pd.DataFrame, SignalModel | None]:
    """:func:`estimate_heights`'s heights table, and the signal model its fits ended with (the
    4PL methods' C/N0 classifier or mixture; None for the hinge and Bayes baselines)."""
    if not estimator.fourpl:
        ids, columns = _baseline_columns(intersections, estimator)
        model = None
    else:
        ids, columns, model = _fourpl_columns(intersections, estimator, open_sky)
    table = pd.DataFrame({"id": ids, **columns, "method": estimator.method})[HEIGHTS_COLUMNS]
    return table, model


def _fourpl_columns(intersections, estimator: Estimator, open_sky):
    """4PL-B (or 4PL) in one process: the buildings' ids, the heights table's columns and the
    final signal model, the phones levelled by the open sky where the estimator says so."""
    ids, part = intersections_part(intersections, estimator, phones=estimator.levels_phones)
    offsets = phone_offsets(open_sky, estimator)
    if offsets is not None and open_sky is not None and part.phone is not None:
        part, open_sky = part.levelled(offsets), levelled(open_sky, offsets)
    moments = open_sky_moments(open_sky, estimator)
    (fits,), classifier = run_parts([part], [[0]], estimator, open_sky=moments)
    return ids, fits.columns(), classifier


def _baseline_columns(intersections, estimator: Estimator):
    """The hinge or Bayes baseline: the buildings' ids and the heights table's columns (no
    range, no 4PL parameters)."""
    table = _near_misses(_as_table(intersections), estimator)
    ids, codes, height, cn0, _, _ = _columns(table)
    n = len(ids)
    func = hinge_heights if estimator.method == "hinge" else bayes_heights
    h = func(codes, height, cn0, n, init_threshold=estimator.init_threshold)
    n_signals = np.bincount(codes, minlength=n)
    min_signals = estimator.acceptance.min_signals
    ok = n_signals >= min_signals
    nan = np.full(n, np.nan)
    return ids, {
        "height": np.where(ok, h, np.nan),
        **dict.fromkeys(["height_lower", "height_upper", "height_paper", "a", "b", "c", "d"], nan),
        "n_signals": n_signals,
        "iterations": np.where(ok, 1, 0),
        "converged": ok,
        "status": np.where(ok, "ok", f"fewer than {min_signals} signals").astype(object),
    }


def phone_offsets(open_sky: pd.DataFrame | None, estimator: Estimator) -> pd.Series | None:
    """Each phone's C/N0 offset learnt from ``open_sky`` (:mod:`.offsets`), as
    ``estimator.level_phones`` asks (None: not asked, no open sky, or one without each
    signal's ``receiver`` and ``elevation``). The rows are levelled by the run's parts
    (:meth:`~.parts.Part.levelled`), in one process as in tiles."""
    if not estimator.levels_phones or open_sky is None:
        return None
    if not {"receiver", "elevation"} <= set(open_sky.columns):
        return None
    return sky_counts(open_sky).offsets()


def intersections_part(
    intersections: pd.DataFrame | Mapping,
    estimator: Estimator,
    own: npt.ArrayLike | None = None,
    phones: bool = False,
) -> tuple[np.ndarray, Part]:
    """The 4PL-B :class:`~.parts.Part` of an intersections table (see
    :func:`estimate_heights`) and its buildings' ids, in order of first appearance: all of
    them owned, or, with ``own`` (ids), those first (a tile's, whose other rows are of the
    buildings its signals also cross). The part's buildings are known by their ids
    (``Part.building``), so that parts of a run can exchange their fits by id. With ``phones``
    (and ``receiver`` and ``elevation`` columns), the part knows each row's phone, to be
    levelled (:meth:`~.parts.Part.levelled`) once the run's open sky is known."""
    table = _near_misses(_as_table(intersections), estimator)
    ids, codes, height, cn0, signal, order = _columns(table)
    n_own = len(ids)
    if own is not None:  # the own buildings first
        mine = pd.Index(np.asarray(own, dtype=object)).get_indexer(ids) >= 0
        first = np.argsort(~mine, kind="stable")
        ids, codes, n_own = ids[first], np.argsort(first)[codes], int(mine.sum())
    height_sd = _height_sd(table)
    part = Part.of(
        codes,
        height,
        cn0,
        len(ids),
        estimator,
        n_own=n_own,
        building=ids,
        signal=signal,
        order=order,
        height_sd=height_sd,
        receiver=_recordings(table, height_sd),
        track=_tracks(table),
        elevation=_numeric(table, "elevation") if "elevation" in table.columns else None,
        phone=table["receiver"] if phones and "receiver" in table.columns else None,
        crossing=_crossing(table),
    )
    return ids, part


def fourplb(
    groups: npt.ArrayLike,
    height: npt.ArrayLike,
    cn0: npt.ArrayLike,
    n_groups: int,
    estimator: Estimator = Estimator(),
    *,
    signal: npt.ArrayLike | None = None,
    order: npt.ArrayLike | None = None,
    height_sd: npt.ArrayLike | None = None,
    receiver: npt.ArrayLike | None = None,
    track: npt.ArrayLike | None = None,
    elevation: npt.ArrayLike | None = None,
    open_sky: Cn0Moments | None = None,
) -> tuple[BuildingFits, SignalModel]:
    """Run 4PL-B (or, for method ``4PL``, the paper's one-shot 4PL) on coded arrays.

    Parameters
    ----------
    groups
        Building code of each row, in ``[0, n_groups)``.
    height, cn0
        Intersection height (m) and C/N0 (dB-Hz, NaN = blocked) of each row.
    n_groups
        Number of buildings.
    estimator
        The settings (:class:`~gnss_citygml.settings.Estimator`, method 4PL-B or 4PL): the
        initial threshold, the reweighting of the height fit (:func:`height_weights`), the
        visibility model, the iteration cap and what a converged estimate must satisfy. With
        ``visibility`` and ``signal``, a building leaves out the rows whose ray another building
        blocks (at the current estimates): such a signal says nothing about it; the first fit
        uses only the first building along each ray (needs ``order``). The loop stops after
        ``max_iter`` iterations or when fewer than ``acceptance.label_tol`` of every building's
        map labels change between two iterations. Method ``4PL`` runs a single pass (label by
        the initial classifier, fit, stop), which, as in the paper, always returns the fitted
        height when the optimiser converged on data of both classes; the plausibility checks of
        4PL-B are not applied to it.
    signal, order
        Optional signal code of each row (rows of one signal crossing several buildings) and
        the row's position along its ray (0 = first building crossed).
    height_sd, receiver
        Optional standard deviation (m) of each row's intersection height owing to its
        receiver's position error, and the row's recording (any hashable codes). With
        ``height_sd`` the height 4PLs model that error (errors in variables, see
        :mod:`.fourpl`), so ``b`` is the sharpness of the roof line itself, and the range is
        widened by :func:`position_margin` for the part of the error no fit averages away
        (``acceptance.max_uncertainty`` then bounds the widened range).
    track
        Optional look track of each row (one recording's view of one satellite,
        :func:`look_ids`).
    elevation, open_sky
        Optional elevation (deg) of each row's satellite, and the signals whose rays cross no
        footprint (:func:`~.estimate.open_sky_moments`): the mixture signal model
        (``estimator.signal_model = "mixture"``) learns how C/N0 changes with elevation, and
        what open signals look like.

    Returns
    -------
    (BuildingFits, SignalClassifier or Cn0Mixture)
        The per-building fits and the final signal model.
    """
    part = Part.of(
        groups,
        height,
        cn0,
        n_groups,
        estimator,
        signal=signal,
        order=order,
        height_sd=height_sd,
        receiver=receiver,
        track=track,
        elevation=elevation,
    )
    (fits,), model = run_parts([part], [[0]], estimator, open_sky=open_sky)
    return fits, model


def open_sky_moments(open_sky: pd.DataFrame | None, estimator: Estimator) -> Cn0Moments | None:
    """What the signals of ``open_sky`` (see :func:`estimate_heights`) teach the mixture
    signal model (None for another model, or without them)."""
    if open_sky is None or estimator.signal_model != "mixture":
        return None
    missing = [c for c in ("cn0",) if c not in open_sky.columns]
    if missing:
        raise MissingColumnError(missing, where="open-sky signals", have=list(open_sky.columns))
    cn0 = _cn0(open_sky, "open-sky signals")
    elevation = _numeric(open_sky, "elevation") if "elevation" in open_sky.columns else None
    e = 0.0 if elevation is None else elevation_units(elevation)
    return Cn0Moments.of(cn0, e, 1.0)


def _as_table(intersections) -> pd.DataFrame:
    if isinstance(intersections, pd.DataFrame):
        table = intersections
    elif isinstance(intersections, Mapping):
        lengths = {k: len(np.atleast_1d(v)) for k, v in intersections.items()}
        if len(set(lengths.values())) > 1:
            detail = ", ".join(f"{k}={v}" for k, v in lengths.items())
            raise InputError(
                "intersection columns have different lengths",
                where=detail,
                fix="give every column one value per row",
            )
        table = pd.DataFrame({k: np.atleast_1d(v) for k, v in intersections.items()})
    else:
        raise InputError(
            f"intersections must be a DataFrame or a mapping of columns, not "
            f"{type(intersections).__name__}",
            fix="pass the intersections table as a pandas DataFrame",
        )
    missing = [c for c in _REQUIRED if c not in table.columns]
    if missing:
        raise MissingColumnError(missing, where="intersections table", have=list(table.columns))
    return table


def _columns(table: pd.DataFrame):
    codes, ids = pd.factorize(table["building"], sort=False)
    if (codes < 0).any():
        raise InputError(
            "intersections have an empty building id",
            where=f"rows {_rows(codes < 0)}",
            fix="give every row the id of its building",
        )
    height = _numeric(table, "height")
    bad = ~np.isfinite(height)
    if bad.any():
        raise InputError(
            "intersection heights must be finite numbers",
            where=f"column 'height', rows {_rows(bad)}",
            fix="drop those rows or recompute their ray intersections",
        )
    cn0 = _cn0(table, "intersections")
    signal = compact(pd.factorize(table["signal"])[0]) if "signal" in table.columns else None
    order = None
    if "order" in table.columns:  # numpy's whole numbers as they are: a float copy is memory
        dtype = table["order"].dtype  # (pandas' nullable ones may hold a missing value: floats)
        whole = isinstance(dtype, np.dtype) and dtype.kind in "iu"
        order = table["order"].to_numpy() if whole else _numeric(table, "order")
    return np.asarray(ids, dtype=object), compact(codes), height, cn0, signal, order


def _cn0(table: pd.DataFrame, what: str) -> np.ndarray:
    """The ``cn0`` column of ``what``: numbers, NaN for a blocked signal, never infinite."""
    cn0 = _numeric(table, "cn0")
    if np.isinf(cn0).any():
        raise InputError(
            "C/N0 is infinite",
            where=f"{what}, column 'cn0', rows {_rows(np.isinf(cn0))}",
            fix="use NaN (empty) for blocked signals",
        )
    return cn0


def _recordings(table, height_sd) -> pd.Series | None:
    """Which position error each row shares (``recording``, else ``receiver``), which the
    position-error margin needs (only with ``height_sd``); the column as it is (a categorical
    is coded by its codes, not as one Python string a row)."""
    if height_sd is None:
        return None
    for column in ("recording", "receiver"):
        if column in table.columns:
            return table[column]
    return None


def _tracks(table) -> np.ndarray | None:
    """Which rows are one look along a satellite's track (one code each): one recording
    (``recording``, else ``receiver``) and one ``satellite``; None without a ``satellite``
    column. A missing value is a value like any other."""
    if "satellite" not in table.columns:
        return None
    satellite = pd.factorize(table["satellite"])[0].astype(np.int64) + 1  # 0: missing
    recording = next((c for c in ("recording", "receiver") if c in table.columns), None)
    if recording is None:
        return satellite
    # one int64 per (recording, satellite) pair: both codes are below the number of rows
    pair = (pd.factorize(table[recording])[0] + 1) * (int(satellite.max(initial=0)) + 1)
    return compact(pair + satellite)


def _near_misses(table: pd.DataFrame, estimator: Estimator) -> pd.DataFrame:
    """The rows of ``table`` the height model reads: those of footprints a ray passes near
    without entering (``order`` below 0) only with whole-ray blame, which weighs each by its
    chance of crossing; without it (the visibility model takes the first building along a ray
    for the one that may block it) they are left out."""
    if "order" not in table.columns:
        return table
    near = _numeric(table, "order") < 0
    if near.any() and "crossing" not in table.columns:
        raise InputError(
            "an order below 0 marks a footprint the ray passes near, which needs its chance of "
            "crossing, and the table has no column 'crossing'",
            where=f"column 'order', rows {_rows(near)}",
            fix="number each ray's footprints from 0, or cast with PositionError(crossing=True)",
        )
    return table if estimator.blame == "ray" or not near.any() else table[~near]


def _crossing(table) -> np.ndarray | None:
    """The ``crossing`` column (each row's chance that its ray crosses its building), if any:
    numbers from 0 to 1."""
    if "crossing" not in table.columns:
        return None
    crossing = _numeric(table, "crossing")
    bad = ~((crossing >= 0) & (crossing <= 1))
    if bad.any():
        raise InputError(
            "crossing must be a chance, 0 to 1",
            where=f"column 'crossing', rows {_rows(bad)}",
            fix="recompute the ray intersections (gnss_citygml.pipeline.intersections)",
        )
    return crossing


def _height_sd(table) -> np.ndarray | None:
    if "height_sd" not in table.columns:
        return None
    sd = _numeric(table, "height_sd")
    bad = ~(np.isfinite(sd) & (sd >= 0))
    if bad.any():
        raise InputError(
            "height_sd must be a finite number of metres, 0 or more",
            where=f"column 'height_sd', rows {_rows(bad)}",
            fix="give each row the standard deviation of its height, or drop the column",
        )
    return sd


def _numeric(table, column) -> np.ndarray:
    values = pd.to_numeric(table[column], errors="coerce").to_numpy(dtype=float)
    raw = table[column]
    garbage = np.isnan(values) & raw.notna().to_numpy()
    if garbage.any():
        raise InputError(
            f"column {column!r} holds values that are not numbers",
            where=f"rows {_rows(garbage)}",
            fix="give numbers in metres / dB-Hz",
        )
    return values


def _rows(mask) -> str:
    """The first few rows where ``mask`` holds, for a message."""
    return listing(np.flatnonzero(mask), shown=5)


def no_heights(ids: np.ndarray, method: str, status: str) -> pd.DataFrame:
    """The heights table's rows of buildings ``ids`` that have no estimate, and why
    (``status``), with the table's column types."""
    n = ids.size
    fits = {c: np.full(n, np.nan) for c in HEIGHTS_COLUMNS if c not in _NOT_FLOAT}
    return pd.DataFrame(
        {
            "id": ids,
            **fits,
            "n_signals": np.zeros(n, dtype=np.int64),
            "iterations": np.zeros(n, dtype=np.int64),
            "converged": np.zeros(n, dtype=bool),
            "method": method,
            "status": pd.Series([status] * n, dtype=object),
        }
    )[HEIGHTS_COLUMNS]

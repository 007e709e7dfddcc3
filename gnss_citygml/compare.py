"""Estimates against a truth table: what the demo prints and the report shows for simulated data.

A truth table (a simulator's ``truth.csv``) has one row per building: ``id``, ``height`` (the
true roof, m ODN) and ``ground`` (the true ground, m ODN), and may have the roof span
``roof_low``, ``roof_high`` (the roof's lowest and highest point, m ODN; issue 27). LOD1 height
references range over that span, so an estimate is judged by its distance to it (0 inside) and
a range is honest when it meets it; the error to ``height`` (the span's middle, or the part the
scene names, as UCL's main range) is kept beside it. A table without the span columns (or a
row with them empty) has the span [height, height]: the figures are then today's.
"""

from __future__ import annotations

import warnings

import numpy as np
import numpy.typing as npt
import pandas as pd

from .files.ids import id_named

__all__ = ["SPAN_COLUMNS", "check_truth", "compare", "roof_span", "span_distance", "summary"]

#: The truth table's roof span: the lowest and the highest roof point (m ODN).
SPAN_COLUMNS = ("roof_low", "roof_high")


def check_truth(truth: pd.DataFrame, where: str) -> pd.DataFrame:
    """The truth table, checked before any work: ``id``, ``height`` and ``ground`` there, the
    heights numbers, every id once; a roof span, if any, both its columns, numbers, its low
    end not above its high end."""
    from .errors import InputError, MissingColumnError, listing

    missing = [c for c in ("id", "height", "ground") if c not in truth.columns]
    if missing:
        raise MissingColumnError(missing, where=where, have=list(truth.columns))
    ids = truth["id"].astype(str)
    repeated = pd.unique(ids[ids.duplicated()])
    if repeated.size:
        raise InputError(
            f"{repeated.size} building id(s) more than once: {listing(repeated)}",
            where=where,
            fix="keep one row per building",
        )
    spans = [c for c in SPAN_COLUMNS if c in truth.columns]
    if len(spans) == 1:
        missing = [c for c in SPAN_COLUMNS if c not in spans]
        raise MissingColumnError(missing, where=where, have=list(truth.columns))
    for column in ("height", "ground", *spans):
        if not pd.api.types.is_numeric_dtype(truth[column]):
            raise InputError(
                f"the column {column!r} is not numbers", where=where, fix="give heights in m"
            )
    low, high = roof_span(truth)
    upside_down = ids[low > high]
    if upside_down.size:
        raise InputError(
            f"the roof span of {upside_down.size} building(s) has roof_low above roof_high: "
            f"{listing(upside_down)}",
            where=where,
            fix="give the lowest roof point as roof_low, the highest as roof_high",
        )
    return truth


def roof_span(truth: pd.DataFrame) -> tuple[np.ndarray, np.ndarray]:
    """The roof span (lowest, highest roof point, m ODN) of each row of a truth table:
    ``roof_low`` and ``roof_high``, or ``height`` where they are missing or empty.

    >>> roof_span(pd.DataFrame({"height": [10.0, 20.0], "roof_low": [9.0, np.nan],
    ...                         "roof_high": [11.0, np.nan]}))
    (array([ 9., 20.]), array([11., 20.]))
    """
    height = truth["height"].to_numpy(float)
    low, high = (
        np.where(np.isnan(v := truth[c].to_numpy(float)), height, v)
        if c in truth.columns
        else height
        for c in SPAN_COLUMNS
    )
    return low, high


def span_distance(estimate: npt.ArrayLike, low: npt.ArrayLike, high: npt.ArrayLike) -> np.ndarray:
    """How far each estimate lies outside its span [low, high] (m; 0 inside, NaN where there
    is no estimate).

    >>> span_distance(np.array([8.0, 10.0, 13.0, np.nan]), 9.0, 11.0)
    array([ 1.,  0.,  2., nan])
    """
    estimate = np.asarray(estimate, float)
    low, high = np.asarray(low, float), np.asarray(high, float)
    return np.maximum(low - estimate, 0.0) + np.maximum(estimate - high, 0.0)


def compare(heights: pd.DataFrame, truth: pd.DataFrame) -> pd.DataFrame:
    """One row per building of ``heights`` (a heights layer): ``id``, ``estimate`` (height
    above the estimated ground), ``lower``, ``upper`` (the range, likewise), ``truth`` (the
    true roof above the true ground), ``roof_low``, ``roof_high`` (the roof span, likewise),
    ``error`` (estimated minus true roof height, m ODN; NaN where there is no estimate),
    ``span_error`` (the estimate's distance to the roof span, m: 0 inside it), ``inside``
    (the range holds the true roof), ``meets`` (the range meets the roof span),
    ``converged`` and ``status``."""
    heights = id_named(heights)
    ids = heights["id"].astype(str)
    true = truth.assign(id=truth["id"].astype(str)).set_index("id").reindex(ids)
    if true["height"].isna().all():
        warnings.warn("the truth table's ids match none of the buildings", stacklevel=2)
    roof, ground = true["height"].to_numpy(float), heights["ground"].to_numpy(float)
    low, high = roof_span(true)
    true_ground = true["ground"].to_numpy(float)
    lower, upper = heights["height_lower"].to_numpy(float), heights["height_upper"].to_numpy(float)
    converged = heights["converged"].to_numpy(dtype=bool, na_value=False)
    estimate = np.where(converged, heights["height"].to_numpy(float), np.nan)
    return pd.DataFrame(
        {
            "id": ids.to_numpy(),
            "estimate": estimate - ground,
            "lower": np.where(converged, lower - ground, np.nan),
            "upper": np.where(converged, upper - ground, np.nan),
            "truth": roof - true_ground,
            "roof_low": low - true_ground,
            "roof_high": high - true_ground,
            "error": estimate - roof,
            "span_error": span_distance(estimate, low, high),
            "inside": converged & (lower <= roof) & (roof <= upper),
            "meets": converged & (lower <= high) & (low <= upper),
            "converged": converged,
            "status": heights["status"].astype(str).to_numpy(),
        }
    )


def summary(table: pd.DataFrame) -> str:
    """One line: how many converged, their RMSE to the roof span and to its middle (the
    truth's ``height``), and how many ranges meet the span. Where every span is one height
    (a truth without span columns) the two are one: the line is then the RMSE and how many
    ranges hold the truth, as before issue 27.

    >>> summary(pd.DataFrame({"error": [1.0, np.nan], "inside": [True, False],
    ...                       "converged": [True, False]}))
    '1 of 2 buildings converged, RMSE 1.00 m, truth inside the range for 1 of 1'
    >>> summary(pd.DataFrame({"error": [1.0, 2.0, np.nan], "span_error": [0.0, 1.0, np.nan],
    ...                       "roof_low": [9.0, 9.0, 9.0], "roof_high": [11.0, 11.0, 11.0],
    ...                       "meets": [True, True, False], "inside": [True, False, False],
    ...                       "converged": [True, True, False]}))
    '2 of 3 buildings converged, RMSE 0.71 m to the roof span, 1.58 m to its middle, range meeting the span for 2 of 2'
    """  # noqa: E501
    converged = table["converged"].to_numpy(bool)
    n = int(converged.sum())

    def rmse(column: str) -> str:
        errors = table[column].to_numpy(float)[converged]
        return f"{np.sqrt(np.mean(errors**2)):.2f} m" if n else "-"

    spanned = all(c in table.columns for c in SPAN_COLUMNS) and bool(
        (table["roof_low"] != table["roof_high"]).any()
    )
    if not spanned:
        inside = int(table["inside"].to_numpy(bool).sum())
        return (
            f"{n} of {len(table)} buildings converged, RMSE {rmse('error')}, truth inside the "
            f"range for {inside} of {n}"
        )
    meets = int(table["meets"].to_numpy(bool).sum())
    return (
        f"{n} of {len(table)} buildings converged, RMSE {rmse('span_error')} to the roof span, "
        f"{rmse('error')} to its middle, range meeting the span for {meets} of {n}"
    )

"""Estimates against a truth table: what the demo prints and the report shows for simulated data.

A truth table (a simulator's ``truth.csv``) has one row per building: ``id``, ``height`` (the
true roof, m ODN) and ``ground`` (the true ground, m ODN).
"""

from __future__ import annotations

import warnings

import numpy as np
import pandas as pd

from .ids import id_named

__all__ = ["check_truth", "compare", "summary"]


def check_truth(truth: pd.DataFrame, where: str) -> pd.DataFrame:
    """The truth table, checked before any work: ``id``, ``height`` and ``ground`` there, the
    heights numbers, every id once."""
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
    for column in ("height", "ground"):
        if not pd.api.types.is_numeric_dtype(truth[column]):
            raise InputError(
                f"the column {column!r} is not numbers", where=where, fix="give heights in m"
            )
    return truth


def compare(heights: pd.DataFrame, truth: pd.DataFrame) -> pd.DataFrame:
    """One row per building of ``heights`` (a heights layer): ``id``, ``estimate`` (height
    above the estimated ground), ``lower``, ``upper`` (the range, likewise), ``truth`` (the
    true roof above the true ground), ``error`` (estimated minus true roof height, m ODN; NaN
    where there is no estimate), ``inside`` (the range holds the true roof), ``converged`` and
    ``status``."""
    heights = id_named(heights)
    ids = heights["id"].astype(str)
    true = truth.assign(id=truth["id"].astype(str)).set_index("id").reindex(ids)
    if true["height"].isna().all():
        warnings.warn("the truth table's ids match none of the buildings", stacklevel=2)
    roof, ground = true["height"].to_numpy(float), heights["ground"].to_numpy(float)
    lower, upper = heights["height_lower"].to_numpy(float), heights["height_upper"].to_numpy(float)
    converged = heights["converged"].to_numpy(dtype=bool, na_value=False)
    estimate = np.where(converged, heights["height"].to_numpy(float), np.nan)
    return pd.DataFrame(
        {
            "id": ids.to_numpy(),
            "estimate": estimate - ground,
            "lower": np.where(converged, lower - ground, np.nan),
            "upper": np.where(converged, upper - ground, np.nan),
            "truth": roof - true["ground"].to_numpy(float),
            "error": estimate - roof,
            "inside": converged & (lower <= roof) & (roof <= upper),
            "converged": converged,
            "status": heights["status"].astype(str).to_numpy(),
        }
    )


def summary(table: pd.DataFrame) -> str:
    """One line: how many converged, their RMSE, and how many ranges hold the truth.

    >>> summary(pd.DataFrame({"error": [1.0, np.nan], "inside": [True, False],
    ...                       "converged": [True, False]}))
    '1 of 2 buildings converged, RMSE 1.00 m, truth inside the range for 1 of 1'
    """
    converged = table["converged"].to_numpy(bool)
    n = int(converged.sum())
    errors = table["error"].to_numpy(float)[converged]
    rmse = f"{np.sqrt(np.mean(errors**2)):.2f} m" if n else "-"
    inside = int(table["inside"].to_numpy(bool).sum())
    return (
        f"{n} of {len(table)} buildings converged, RMSE {rmse}, truth inside the range for "
        f"{inside} of {n}"
    )

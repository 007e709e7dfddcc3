"""The attributes a building carries in the city models, and their types.

Every column of the buildings table but ``id`` and the geometry is written under its own name,
as a boolean, integer, double or string (:func:`attribute_columns`, :func:`attribute_values`);
besides them each building has ``measuredHeight`` (roof - ground, from the millimetre vertices
of its prism: :func:`measured_heights`) and ``creationDate`` (:func:`creation_date`). The
CityJSON and CityGML writers spell these in their own formats.
"""

from __future__ import annotations

import datetime as dt
from collections.abc import Callable
from typing import Any

import numpy as np
import numpy.typing as npt
import pandas as pd

from ..errors import InputError

__all__ = ["attribute_columns", "attribute_values", "creation_date", "measured_heights"]


def attribute_columns(frame: pd.DataFrame) -> list[tuple[str, str]]:
    """(name, kind) of the columns written as attributes: every column but id and geometry.

    ``kind`` is ``"bool"``, ``"int"``, ``"double"`` or ``"string"`` (dates and anything else
    become ISO or plain text).
    """
    out = []
    for name in frame.columns:
        if name in ("id", frame.geometry.name):
            continue
        dtype = frame[name].dtype
        if pd.api.types.is_bool_dtype(dtype):
            kind = "bool"
        elif pd.api.types.is_integer_dtype(dtype):
            kind = "int"
        elif pd.api.types.is_float_dtype(dtype):
            kind = "double"
        else:
            kind = "string"
        out.append((str(name), kind))
    return out


def attribute_values(column: pd.Series, kind: str) -> list:
    """The column's values as Python objects of the given kind; None where missing.

    Text columns give ``str``, or a list of ``str`` for list-like values.
    """
    if kind == "double":
        values = column.to_numpy(dtype=float, na_value=np.nan)
        missing = ~np.isfinite(values)
        out = values.tolist()
    elif pd.api.types.is_datetime64_any_dtype(column.dtype):
        missing = column.isna().to_numpy()
        out = [None if m else v.isoformat() for v, m in zip(column, missing, strict=True)]
    else:
        missing = column.isna().to_numpy()  # elementwise: a list value is not missing
        converters: dict[str, Callable[[Any], object]] = {"int": int, "bool": bool, "string": _text}
        convert = converters[kind]
        objects = column.astype(object).tolist()
        return [None if m else convert(v) for v, m in zip(objects, missing.tolist(), strict=True)]
    if missing.any():
        out = [None if m else v for v, m in zip(out, missing, strict=True)]
    return out


def _text(value) -> str | list[str]:
    """Text, or a list of texts for a list-like value (e.g. MasterMap's descriptiveGroup)."""
    if isinstance(value, str):
        return value
    return [str(v) for v in value] if isinstance(value, list | tuple | np.ndarray) else str(value)


def creation_date(date: dt.date | str | None) -> str:
    """The ISO date written as creationDate/referenceDate (default: today, UTC)."""
    if date is None:
        return dt.datetime.now(dt.UTC).date().isoformat()
    if isinstance(date, str):
        try:
            return dt.date.fromisoformat(date).isoformat()
        except ValueError:
            raise InputError(f"not a date: {date!r}", where="date", fix="give YYYY-MM-DD") from None
    return date.isoformat() if isinstance(date, dt.date) else str(date)


def measured_heights(ground: npt.ArrayLike, roof: npt.ArrayLike) -> list[float]:
    """roof - ground in metres, from the millimetre values the geometry uses."""
    mm = np.rint(np.asarray(roof) * 1000).astype(np.int64) - np.rint(
        np.asarray(ground) * 1000
    ).astype(np.int64)
    return (mm / 1000).tolist()

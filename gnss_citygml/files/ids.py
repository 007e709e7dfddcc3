"""The building id: ``id`` between the stages, the source's own name at the edges.

Inside the toolkit every buildings and heights table names its id column ``id`` (DESIGN.md).
The footprints' source may call it otherwise (``toid``, ``TOID``, ``ref``): analysts join the
results back to the source by that field, so the outputs carry it under its own name.
:func:`~gnss_citygml.footprints.read_footprints` moves the id to ``id`` and records the name in
the table's ``attrs`` (:data:`ID_FIELD`; absent means ``id``). At the edges the name is put
back: :func:`~gnss_citygml.pipeline.estimate` returns its table with the id under the source's
name (:func:`source_named`), the layer writer writes it so, and a writer or join handed such a
table takes it back as ``id`` (:func:`id_named`), keeping the name for its own output (e.g.
CityGML's id attribute).

The name travels in ``attrs`` because the Python API hands the footprints from
``read_footprints`` to ``estimate`` itself: nothing else goes with the table. pandas keeps
``attrs`` through copies, slices, column changes, ``rename`` and ``concat`` of like tables,
not through ``merge``: a function that merges sets them again (:func:`with_id_field`). Each
path from a reader to an output is tested.
"""

from __future__ import annotations

from typing import TypeVar

import numpy as np
import pandas as pd

from ..errors import InputError

__all__ = [
    "ID_FIELD",
    "check_ids_given",
    "id_field",
    "id_named",
    "id_text",
    "missing_ids",
    "source_named",
    "with_id_field",
]

#: The key of ``DataFrame.attrs`` holding the name of the source's id field.
ID_FIELD = "id_field"

#: A table, or a GeoDataFrame: what goes in comes out.
Frame = TypeVar("Frame", bound=pd.DataFrame)


def missing_ids(ids: pd.Series) -> np.ndarray:
    """Where ``ids`` hold no usable id: missing (NULL, NaN), empty or only blanks (a blank id
    names nothing a user can find or join on), or with a NUL character (C libraries, GDAL
    among them, cut a text there: two ids would become one, or one become another).

    >>> missing_ids(pd.Series(["osgb1", None, "", "  ", "a" + chr(0) + "b"])).tolist()
    [False, True, True, True, True]
    """
    missing = np.array(ids.isna(), dtype=bool)
    text = ids[~missing].astype(str)
    missing[~missing] = (text.str.strip().eq("") | text.str.contains("\0", regex=False)).to_numpy()
    return missing


def check_ids_given(ids: pd.Series, where: str) -> None:
    """Refuse a table with rows without a usable id (:func:`missing_ids`), naming the first."""
    blank = np.flatnonzero(missing_ids(ids))
    if blank.size:
        raise InputError(
            f"{blank.size} row(s) without a building id (the first: data row {blank[0] + 1})",
            where=where,
            fix="give each row its building's id, or remove the row",
        )


def id_text(ids: pd.Series) -> pd.Series:
    """Building ids as text, as the source stores them: text kept as it is (``"001"``,
    ``"1.0"``), integers written out, whole numbers stored as REAL without their ``.0`` (a
    Shapefile's or a spreadsheet's numeric ids). The one rule for every reader of ids."""
    if pd.api.types.is_float_dtype(ids) and np.all(np.mod(ids.to_numpy(), 1) == 0):
        ids = ids.astype(np.int64)
    return ids.astype(str)


def id_field(frame: pd.DataFrame) -> str:
    """The name of the source's id field of a buildings or heights table (default ``id``)."""
    return str(frame.attrs.get(ID_FIELD) or "id")


def with_id_field(frame: Frame, name: str) -> Frame:
    """``frame`` itself, its ``attrs`` recording ``name`` as its source's id field."""
    frame.attrs[ID_FIELD] = name
    return frame


def source_named(frame: Frame) -> Frame:
    """The table with its ``id`` column under the source's name (unchanged if it has no ``id``
    or the source's field is ``id``).

    Examples
    --------
    >>> table = with_id_field(pd.DataFrame({"id": ["osgb1"], "height": [12.5]}), "toid")
    >>> source_named(table).columns.tolist()
    ['toid', 'height']
    """
    name = id_field(frame)
    if name == "id" or "id" not in frame.columns:
        return frame
    _check_single(frame, name, "buildings")
    return frame.rename(columns={"id": name})


def id_named(frame: Frame, name: str | None = None, *, where: str = "buildings") -> Frame:
    """The table with its id column named ``id``: a column ``name`` (default: the table's
    source's id field) is renamed to ``id``; the ``attrs`` keep the name. Unchanged if the
    table has no such column.

    Examples
    --------
    >>> table = with_id_field(pd.DataFrame({"toid": ["osgb1"], "height": [12.5]}), "toid")
    >>> back = id_named(table)
    >>> back.columns.tolist(), id_field(back)
    (['id', 'height'], 'toid')
    """
    name = id_field(frame) if name is None else name
    if name == "id" or name not in frame.columns:
        return frame
    _check_single(frame, name, where)
    return frame.rename(columns={name: "id"})


def _check_single(frame: pd.DataFrame, name: str, where: str) -> None:
    if "id" in frame.columns and name in frame.columns:
        raise InputError(
            f"the table has a column 'id' besides its id field {name!r}",
            where=where,
            fix="rename or drop one of them",
        )

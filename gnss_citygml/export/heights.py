"""The buildings table the writers take (:mod:`.plan`) from a layer of heights: a heights
table joined to its footprints (:func:`footprints_with_heights`), or any footprint layer's
height field (:func:`buildings_with_heights`), with a fallback field for the buildings without
a usable height.

Each field's reference is its own: a height field is absolute (m ODN) or above the ground, and
so, separately, is the fallback field. A heights layer says it of its own fields
(:func:`gnss_fields`: ``estimate``'s ``height`` is absolute and ``relative_height`` above the
ground, ``update``'s ``height_gnss`` absolute), and a field the layer says is absolute is never
taken as relative; the user says it of any other field. A field of a GNSS fit is a height only
where its fit converged: an unconverged fit is left out, whether its field is the height field
or the fallback's, and a fit does not judge the height of another field.
"""

from __future__ import annotations

import geopandas as gpd
import numpy as np
import pandas as pd

from ..contracts import HEIGHTS, load
from ..errors import InputError, MissingColumnError, listing, user_text
from ..files.ids import check_ids_given, id_field, id_named, id_text, with_id_field
from .plan import booleans, numeric

__all__ = ["buildings_with_heights", "footprints_with_heights", "gnss_fields"]

#: The fields of ``estimate``'s heights layer that are heights of its fit, each with whether
#: it is above the ground (else m ODN).
ESTIMATE_FIELDS = {
    "height": False,
    "height_lower": False,
    "height_upper": False,
    "height_paper": False,
    "c": False,
    "relative_height": True,
}
#: Likewise the fields ``update`` writes on a map (:data:`gnss_citygml.update.COLUMNS`).
UPDATE_FIELDS = {
    "height_gnss": False,
    "height_lower": False,
    "height_upper": False,
    "height_paper": False,
    "c_gnss": False,
}
#: What each switch is said of, for the messages.
_SWITCHES = "--relative is the height field's, --fallback-relative the fallback field's"


def footprints_with_heights(
    footprints: gpd.GeoDataFrame, heights: pd.DataFrame, *, where: str = "heights table"
) -> gpd.GeoDataFrame:
    """The footprints joined with a heights table (the ids and the heights columns), e.g. one
    written by ``gnss-citygml heights``. The table's ids are in ``id`` or in a column named
    like the footprints' id field (e.g. ``toid``, as ``estimate`` writes them; see
    :mod:`gnss_citygml.files.ids`), and the result keeps that name for the outputs. Footprints
    without a row keep empty heights (the writers skip and list them); in a table without
    ``converged``, a row whose ``status`` is not ``ok`` is not trusted. A column of the table
    that the footprints have too (their own ``ground``, say, or a DEM's) is an error, as are
    heights of ids that are not among the footprints and a table without the columns the
    heights schema requires (``schemas/heights.schema.json``: the id, ``height``)."""
    name, columns = id_field(footprints), list(heights.columns)
    footprints, heights = id_named(footprints), id_named(heights, name, where=where)
    required = load(HEIGHTS)["required"]
    missing = [name if c == "id" else c for c in required if c not in heights.columns]
    if missing:
        raise MissingColumnError(missing, where=where, have=columns)
    check_ids_given(heights["id"], where)
    table = heights.assign(id=id_text(heights["id"]))  # (a Parquet table's may be numbers)
    repeated = pd.unique(table["id"][table["id"].duplicated()])
    if repeated.size:
        raise InputError(
            f"{repeated.size} building id(s) with more than one height: {listing(repeated)}",
            where=where,
            fix="keep one row per building",
        )
    if "converged" not in table.columns and "status" in table.columns:
        # the schema's status says why a building has no estimate to trust: none but ok is
        status = table["status"]
        table["converged"] = status.isna() | (status.astype(str) == "ok")
    # a table with its own geometry (estimate's GeoParquet layer): the footprints' is the one
    table = pd.DataFrame(table).drop(
        columns=["geometry", footprints.geometry.name], errors="ignore"
    )
    both = [c for c in table.columns if c != "id" and c in footprints.columns]
    if both:
        raise InputError(
            "the footprints and the heights table both have the column(s) "
            + listing([repr(user_text(str(c))) for c in both]),
            where=where,
            fix="rename or drop them in the footprints (the heights stand on the table's "
            "ground; a DEM's is for a table without one)",
        )
    unknown = ~table["id"].isin(footprints["id"])
    if unknown.any():
        raise InputError(
            f"{int(unknown.sum())} height(s) for buildings not among the footprints: "
            + listing(table["id"][unknown]),
            where=where,
            fix="give the footprints the heights were estimated for",
        )
    return with_id_field(footprints.merge(table, on="id", how="left"), name)


def gnss_fields(columns: list) -> dict[str, bool]:
    """The fields among ``columns`` that are heights of a GNSS fit, each with whether it is
    above the ground (else m ODN): on a layer with ``converged``, ``update``'s
    (:data:`UPDATE_FIELDS`) if it has ``height_gnss``, and ``estimate``'s
    (:data:`ESTIMATE_FIELDS`) unless it is a map ``update`` wrote into (``height_gnss``
    without estimate's ``relative_height``: its other columns are the map's own).

    >>> gnss_fields(["relh2", "height_gnss", "converged", "c"])
    {'height_gnss': False}
    """
    have = set(columns)
    fields: dict[str, bool] = {}
    if "converged" not in have:
        return fields
    if "relative_height" in have or "height_gnss" not in have:
        fields.update(ESTIMATE_FIELDS)
    if "height_gnss" in have:
        fields.update(UPDATE_FIELDS)
    return {name: above for name, above in fields.items() if name in have}


def buildings_with_heights(
    frame: gpd.GeoDataFrame,
    height_field: str = "height",
    *,
    relative: bool = False,
    ground_field: str | None = None,
    fallback_field: str | None = None,
    fallback_relative: bool = False,
) -> gpd.GeoDataFrame:
    """Any footprint layer with a height attribute as the buildings table the writers take.

    Parameters
    ----------
    frame
        Footprints (``id``, ``geometry``) with a height attribute: ``estimate``'s heights
        layer, a map ``update`` wrote into, OS's ``abshmax`` or ``relh2``..., and a ``ground``
        column (e.g. :func:`gnss_citygml.terrain.building_ground`'s) or ``ground_field``.
    height_field
        The column with the roof height (m): absolute (ODN) unless ``relative``, or as the
        heights layer says (:func:`gnss_fields`).
    relative
        The height field is above the ground (the roof is ground + height); refused for a
        field the layer says is absolute.
    ground_field
        The column with the ground height (m ODN), moved to ``ground``.
    fallback_field
        A column whose height the buildings without a usable height get (none, or a GNSS fit
        that did not converge); ``height_source`` then says whose each height is: ``gnss``
        (a fit's field) or the field's name. A height not from the fit has no interval.
    fallback_relative
        The fallback field is above the ground: ``relative`` for the fallback field.

    Returns
    -------
    geopandas.GeoDataFrame
        A copy with ``ground``, ``height`` (absolute roof height, m ODN; the field is kept
        under its own name) and ``method`` saying where each height came from (the layer's
        for a fit's, else e.g. ``attribute relh2 + ground``); ``height_source`` with a
        fallback, or for a field that is not a fit's on a layer that has one.

    Raises
    ------
    MissingColumnError
        The height, ground or fallback field is missing.
    InputError
        A field is not numeric, or said relative where the layer says it is absolute; the
        fallback is the height field; other ``height``/``ground`` columns.

    Examples
    --------
    >>> import shapely
    >>> frame = gpd.GeoDataFrame({"id": ["a"], "relh2": [9.5], "base": [12.0]},
    ...                          geometry=[shapely.box(0, 0, 5, 5)], crs="EPSG:27700")
    >>> out = buildings_with_heights(frame, "relh2", relative=True, ground_field="base")
    >>> out[["ground", "height", "method"]].values.tolist()
    [[12.0, 21.5, 'attribute relh2 + ground']]
    """
    columns = list(frame.columns)
    _check_fields(columns, height_field, ground_field, fallback_field)
    fits = gnss_fields(columns)
    relative = _relative(fits, height_field, relative, "--relative")
    out = _absolute(frame, height_field, relative, ground_field)
    source = "gnss" if height_field in fits else height_field
    labels = {height_field: _attribute(height_field, relative)}
    # the fit does not judge a field beside it, which so gets a source of its own
    sourced = fallback_field is not None or (source != "gnss" and "converged" in columns)
    if not sourced:
        return out
    _check_not_the_users(columns)
    if fallback_field is not None:
        above = _relative(fits, fallback_field, fallback_relative, "--fallback-relative")
        labels[fallback_field] = _attribute(fallback_field, above)
        out = _fallback(out, fallback_field, above, source, fallback_field in fits)
    else:
        out["height_source"] = source
    _by_source(out, "gnss" if "height_lower" in fits else source, labels)
    return out


def _absolute(frame, height_field: str, relative: bool, ground_field: str | None):
    """A copy of ``frame`` with ``ground`` (from ``ground_field``, which is then dropped) and
    ``height``, the absolute roof (ground + the field if ``relative``), and ``method`` saying
    so for a field other than ``height`` where the layer has none."""
    out = frame.copy()
    ground = numeric(out, ground_field or "ground")
    height = numeric(out, height_field)
    out["ground"] = ground
    out["height"] = ground + height if relative else height
    if ground_field not in (None, "ground"):
        out = out.drop(columns=[ground_field])
    if "method" not in out.columns and height_field != "height":
        out["method"] = _attribute(height_field, relative)
    return out


def _check_not_the_users(columns: list) -> None:
    """Refuse a layer whose column ``height_source``, or ``method`` where no fit wrote it (no
    ``converged`` beside it), is the user's own: where each height came from is written
    there (:func:`_by_source`), over the user's values."""
    for column in ("height_source", "method"):
        if column in columns and (column == "height_source" or "converged" not in columns):
            raise InputError(
                f"the layer has a column {column!r} of its own, where the heights' "
                "source would be written",
                where="footprint layer",
                fix=f"rename or drop the column {column!r}",
            )


def _attribute(field: str, relative: bool) -> str:
    """The ``method`` of a height taken from the attribute ``field``."""
    return f"attribute {field}" + (" + ground" if relative else "")


def _by_source(out: gpd.GeoDataFrame, owner: str, labels: dict[str, str]) -> None:
    """Make ``method`` say where each height came from (a fit's method stays with its
    heights; a field's height gets its label, ``labels`` by field) and keep the interval
    (``height_lower``, ``height_upper``) only with the heights from its ``owner``."""
    source = out["height_source"].to_numpy()
    if "method" not in out.columns:
        out["method"] = None
    for field, label in labels.items():
        out.loc[source == field, "method"] = label
    for column in ("height_lower", "height_upper"):
        if column in out.columns:
            out.loc[source != owner, column] = np.nan


def _relative(fits: dict[str, bool], field: str, said: bool, switch: str) -> bool:
    """Whether ``field`` is above the ground: as the heights layer says (``fits``), else as
    the user ``said`` (with ``switch``); said of a field the layer says is absolute, refused."""
    if said and fits.get(field) is False:
        raise InputError(
            f"{field!r} holds absolute heights (m ODN), as the heights layer says",
            where="footprint layer",
            fix=f"leave out {switch} ({_SWITCHES})",
        )
    return fits.get(field, said)


def _check_fields(columns: list, height_field: str, ground_field, fallback_field) -> None:
    """Refuse fields the layer lacks, a layer without a ground, a fallback that is the height
    field, and a field that would be renamed over another column
    (:func:`buildings_with_heights`)."""
    for name in (height_field, ground_field, fallback_field):
        if name is not None and name not in columns:
            raise MissingColumnError([name], where="footprint layer", have=columns)
    if fallback_field == height_field:
        raise InputError(
            f"the fallback field is the height field ({user_text(height_field)}): it would "
            "give no building a height",
            where="footprint layer",
            fix="give another field as --fallback-field, or leave it out",
        )
    if ground_field is None and "ground" not in columns:
        raise MissingColumnError(
            ["ground"], where="footprint layer (give a ground field or a DEM)", have=columns
        )
    for target, name in (("ground", ground_field), ("height", height_field)):
        if name is not None and name != target and target in columns:
            raise InputError(
                f"the layer has a column {target!r} besides the {target} field {name!r}",
                where="footprint layer",
                fix=f"rename or drop the column {target!r}",
            )


def _fallback(frame: gpd.GeoDataFrame, field: str, relative: bool, source: str, fit: bool):
    """``frame`` whose buildings without a usable height take ``field``'s (above the ground
    if ``relative``; only where its fit converged, for a ``fit``'s field), with
    ``height_source``; a height from a GNSS fit (``source`` ``gnss``) is usable only where
    the fit converged (:func:`buildings_with_heights`)."""
    height = frame["height"].to_numpy(dtype=float)
    converged = np.ones(len(frame), dtype=bool)
    if "converged" in frame.columns:
        flags = booleans(frame["converged"], "converged", frame)
        converged = flags.fillna(False).to_numpy(bool)
    usable = np.isfinite(height) & (converged if source == "gnss" else True)
    other = numeric(frame, field) + (frame["ground"].to_numpy(dtype=float) if relative else 0.0)
    taken = ~usable & np.isfinite(other) & (converged if fit else True)
    out = frame.copy()
    out["height"] = np.where(taken, other, height)
    out["height_source"] = np.where(taken, field, source)
    return out

"""Real files of every kind `gnss-citygml info` reads, holding a provenance record given as the
JSON text the file stores (any text: a record of the wrong shape, JSON nested 100,000 deep,
text that is not JSON at all), for the tests and the fuzzers of the readers."""

from __future__ import annotations

import html
from pathlib import Path

#: The containers of a record, by the name of the file that holds it.
CONTAINERS = ["c.city.json", "c.city.jsonl", "tileset.json", "c.gml", "report.html", "h.gpkg"]


def holding(folder: Path, name: str, text: str) -> Path:
    """A file ``name`` (one of :data:`CONTAINERS`) in ``folder`` whose record is ``text``, stored
    where the toolkit's writers store it."""
    path = folder / name
    if name.endswith(".gpkg"):
        _geopackage(path, text)
    elif name.endswith(".gml"):
        path.write_text(
            '<CityModel xmlns="http://www.opengis.net/citygml/2.0" '
            'xmlns:gml="http://www.opengis.net/gml"><gml:description>made by a test\n'
            f"{html.escape(_xml_chars(text), quote=False)}</gml:description></CityModel>",
            encoding="utf-8",
        )
    elif name.endswith(".html"):
        script = text.replace("</", "<\\/")
        path.write_text(
            f'<html><head><script type="application/json" id="provenance">{script}</script>'
            "</head><body></body></html>",
            encoding="utf-8",
            errors="surrogatepass",
        )
    else:
        record = f'{{"provenance": {text}}}'
        if name == "tileset.json":
            head = f'{{"asset": {{"version": "1.1", "extras": {record}}}, "geometricError": 1}}'
        else:
            head = f'{{"type": "CityJSON", "version": "2.0", "metadata": {record}}}'
        if name.endswith(".jsonl"):
            head += '\n{"type": "CityJSONFeature", "id": "a", "CityObjects": {}, "vertices": []}\n'
        path.write_text(head, encoding="utf-8", errors="surrogatepass")
    return path


def _geopackage(path: Path, text: str) -> None:
    import geopandas as gpd
    import pyogrio
    import shapely

    frame = gpd.GeoDataFrame(
        {"id": ["a"], "height": [10.0]}, geometry=[shapely.box(0, 0, 1, 1)], crs="EPSG:27700"
    )
    pyogrio.write_dataframe(
        frame, path, layer="heights", layer_metadata={"provenance": _xml_chars(text)}
    )


def _xml_chars(text: str) -> str:
    """``text`` without the characters XML cannot hold (GDAL keeps a layer's metadata as XML)."""
    return "".join(
        c for c in text if c in "\t\n\r" or " " <= c <= "\ud7ff" or "\ue000" <= c <= "\ufffd"
    )

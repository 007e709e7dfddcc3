"""The toolkit's files: paths written atomically and checked (:mod:`.paths`), folder outputs
written whole (:mod:`.folders`), tables read and written whatever their format
(:mod:`.tables`), the id field of a layer (:mod:`.ids`), SQL on a GeoPackage's own tables
(:mod:`.geopackage`) and the heights layer's QGIS style (:mod:`.styles`). Everything above
reads and writes through them; they import nothing above.
"""

"""gnss-citygml in QGIS: a Processing provider (group "GNSS 3D mapping") that is a thin door
onto the gnss-citygml library, so that the plugin's heights are the command line's.

The plugin loads even when the library cannot be imported in QGIS's Python: it then says what
to install, and how (:mod:`.library`).
"""


def classFactory(iface):  # noqa: N802 (the name QGIS calls)
    """QGIS's entry point: the plugin object for the running QGIS interface."""
    from .plugin import GnssCityGMLPlugin

    return GnssCityGMLPlugin(iface)

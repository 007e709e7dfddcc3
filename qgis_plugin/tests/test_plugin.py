"""The plugin as QGIS sees it: metadata, loading and unloading, the provider and its algorithms,
and a QGIS whose Python has no gnss-citygml (the plugin loads and says what to install)."""

import configparser
import subprocess
import textwrap

from conftest import PLUGIN, PLUGINS
from qgis.core import QgsApplication
from qgis.PyQt.QtGui import QIcon

import gnss_citygml

ALGORITHMS = [
    "gnsscitygml:convert",
    "gnsscitygml:estimate",
    "gnsscitygml:update",
    "gnsscitygml:validate",
]


def test_metadata_has_what_the_plugin_repository_asks_for():
    meta = configparser.ConfigParser()
    meta.read(PLUGIN / "metadata.txt")
    general = meta["general"]
    for key in (
        "name",
        "description",
        "about",
        "version",
        "author",
        "email",
        "tracker",
        "repository",
        "icon",
    ):
        assert general.get(key), key
    assert general["qgisMinimumVersion"] == "3.22"
    assert general["hasProcessingProvider"] == "yes"
    assert general["version"] == gnss_citygml.__version__  # one release, one number
    assert not QIcon(str(PLUGIN / general["icon"])).isNull()


def test_load_and_unload_with_the_qgis_interface(qgis_iface, processing_framework):
    import gnss_citygml_qgis

    registry = QgsApplication.processingRegistry()
    plugin = gnss_citygml_qgis.classFactory(qgis_iface)
    plugin.initGui()
    try:
        provider = registry.providerById("gnsscitygml")
        assert provider is not None and not provider.icon().isNull()
        algorithms = sorted(a.id() for a in provider.algorithms())
        assert algorithms == ALGORITHMS
        for algorithm in provider.algorithms():
            assert algorithm.group() == "GNSS 3D mapping"
            assert algorithm.shortHelpString() and algorithm.displayName()
            assert algorithm.canExecute() == (True, "")
    finally:
        plugin.unload()
    assert registry.providerById("gnsscitygml") is None


def test_estimate_parameters_take_the_librarys_defaults(plugin):
    from gnss_citygml.settings import Estimator, Rays, ReceiverHeights

    algorithm = QgsApplication.processingRegistry().algorithmById("gnsscitygml:estimate")
    default = {p.name(): p.defaultValue() for p in algorithm.parameterDefinitions()}
    assert default["MIN_ELEVATION"] == Rays.min_elevation
    assert default["MAX_RANGE"] == Rays.max_range
    assert default["ANTENNA_HEIGHT"] == ReceiverHeights.antenna_height
    assert default["INIT_THRESHOLD"] == Estimator.init_threshold
    method = algorithm.parameterDefinition("METHOD")
    assert method.options()[default["METHOD"]] == Estimator.method


def test_without_the_library_the_plugin_loads_and_says_what_to_install(tmp_path):
    """QGIS's own Python with Debian's packages only (no site folders, so no gnss-citygml,
    however this machine's Python is set up): the plugin loads, and running an algorithm
    gives the message naming the library and the pip command for this Python."""
    script = textwrap.dedent(
        f"""
        import sys
        sys.path[:0] = ["/usr/lib/python3/dist-packages", "/usr/share/qgis/python/plugins",
                        {str(PLUGINS)!r}]
        from qgis.core import QgsApplication
        app = QgsApplication([], False)
        app.initQgis()
        messages = []
        QgsApplication.messageLog().messageReceived.connect(
            lambda text, tag, level: messages.append((tag, text)))
        from processing.core.Processing import Processing
        Processing.initialize()
        import processing
        import gnss_citygml_qgis
        plugin = gnss_citygml_qgis.classFactory(None)
        plugin.initGui()
        assert QgsApplication.processingRegistry().providerById("gnsscitygml") is not None
        for tag, text in messages:
            if tag == "gnss-citygml":
                print("LOG:", text)
        try:
            processing.run("gnsscitygml:estimate", {{}})
        except Exception as exc:
            print("RUN:", str(exc).replace(chr(10), " "))
        """
    )
    process = subprocess.run(
        ["/usr/bin/python3", "-I", "-S", "-c", script],
        capture_output=True,
        text=True,
        env={"QT_QPA_PLATFORM": "offscreen", "HOME": str(tmp_path), "PATH": "/usr/bin:/bin"},
        timeout=120,
    )
    assert process.returncode == 0, process.stderr
    lines = dict(line.split(": ", 1) for line in process.stdout.splitlines() if ": " in line)
    for key in ("LOG", "RUN"):
        message = lines[key]
        assert "the gnss-citygml library is missing from QGIS's Python" in message
        assert "-m pip install --user --upgrade gnss-citygml" in message

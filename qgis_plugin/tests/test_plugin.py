"""The plugin as QGIS sees it: metadata, loading and unloading, the provider and its algorithms,
and a QGIS whose Python has no gnss-citygml (the plugin loads and says what to install)."""

import configparser
import re

import pytest
from conftest import PLUGIN, PLUGINS, ROOT, debian_qgis
from qgis.core import QgsApplication, QgsProcessingException
from qgis.PyQt.QtGui import QIcon

import gnss_citygml

ALGORITHMS = [
    "gnsscitygml:convert",
    "gnsscitygml:estimate",
    "gnsscitygml:observe",
    "gnsscitygml:report",
    "gnsscitygml:setup",
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
            assert algorithm.helpUrl().startswith(REPOSITORY + "#")
    finally:
        plugin.unload()
    assert registry.providerById("gnsscitygml") is None


REPOSITORY = "https://github.com/gnss-citygml/gnss-citygml"


def github_anchor(heading):
    """The anchor GitHub gives a Markdown heading: lower case, spaces as hyphens, no
    punctuation but hyphens and underscores."""
    return re.sub(r"[^\w\- ]", "", heading.strip().lower()).replace(" ", "-")


def test_each_algorithms_help_is_its_readme_section(plugin):
    """The Help button opens the README's section on the algorithm's command (an anchor that
    is a heading of README.md), and each help text names that command."""
    headings = re.findall(r"^#+ (.+)$", (ROOT / "README.md").read_text(), re.M)
    anchors = {github_anchor(heading): heading for heading in headings}
    provider = QgsApplication.processingRegistry().providerById("gnsscitygml")
    for algorithm in provider.algorithms():
        url = algorithm.helpUrl()
        assert url.startswith(REPOSITORY + "#"), url
        heading = anchors.get(url.split("#")[1])
        assert heading is not None, f"{algorithm.id()}: no README section {url}"
        if algorithm.name() == "setup":  # not a command: the README says how to set up
            assert "set up" in heading, heading
            continue
        assert algorithm.name() in heading, (algorithm.id(), heading)
        assert f"gnss-citygml {algorithm.name()}</tt>" in algorithm.shortHelpString()


def test_the_metadata_and_the_readme_list_every_algorithm(plugin):
    """The plugin's description (metadata.txt's about) names every algorithm by what it does,
    and the README's QGIS section lists every algorithm: neither goes stale."""
    meta = configparser.ConfigParser()
    meta.read(PLUGIN / "metadata.txt")
    about = meta["general"]["about"].lower()
    readme = (ROOT / "README.md").read_text()
    section = readme.split("\n## QGIS\n")[1].split("\n## ")[0]
    provider = QgsApplication.processingRegistry().providerById("gnsscitygml")
    for algorithm in provider.algorithms():
        assert algorithm.displayName().lower() in about, algorithm.displayName()
        assert f"| `{algorithm.id()}` |" in section, algorithm.id()
    counted = r"\b(\d+|two|three|four|five|six|seven|eight|nine) (processing )?algorithms"
    assert not re.search(counted, about + section.lower())


def test_observe_parameters_take_the_librarys_defaults(plugin):
    """Those of gnss_citygml.jobs.observe_file, which the command line's defaults are too."""
    import inspect

    from gnss_citygml.jobs import observe_file
    from gnss_citygml.settings import Rays

    algorithm = QgsApplication.processingRegistry().algorithmById("gnsscitygml:observe")
    given = {p.name(): p for p in algorithm.parameterDefinitions()}
    library = {name: p.default for name, p in inspect.signature(observe_file).parameters.items()}
    assert library["min_elevation"] == given["MIN_ELEVATION"].defaultValue() == Rays.min_elevation
    assert library["max_elevation"] == given["MAX_ELEVATION"].defaultValue() == Rays.max_elevation
    for name in ("PROVIDER", "BAND"):
        parameter = given[name]
        assert parameter.options()[parameter.defaultValue()] == library[name.lower()]
    assert library["method"] == "nearest" and given["INTERPOLATE"].defaultValue() is False
    assert library["lenient"] is given["LENIENT"].defaultValue() is False
    positions = given["POSITIONS"]
    assert library["surveyed"] is None and positions.flags() & positions.FlagOptional


def test_report_has_the_parameters_of_estimate(plugin):
    """The same run's parameters, made once (RunAlgorithm); the report's own after them."""
    registry = QgsApplication.processingRegistry()

    def described(name):
        return [
            (p.name(), p.type(), p.description(), p.defaultValue(), int(p.flags()))
            for p in registry.algorithmById(name).parameterDefinitions()
        ]

    estimate, report = described("gnsscitygml:estimate"), described("gnsscitygml:report")
    assert report[: len(estimate) - 1] == estimate[:-1]  # all but the heights layer
    assert [p[0] for p in report[len(estimate) - 1 :]] == ["TRUTH", "OPEN", "OUTPUT"]
    opens = registry.algorithmById("gnsscitygml:report").parameterDefinition("OPEN")
    assert opens.defaultValue() is True


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


@pytest.mark.parametrize("name", ["gnsscitygml:estimate", "gnsscitygml:update"])
def test_qgis_and_the_command_line_cannot_disagree(plugin, name):
    """Each of the library's options in QGIS is its declaration in gnss_citygml.options:
    label, default, range, choices (the command line's options are checked against the same
    declarations by tests/test_options.py), so the two cannot disagree (issue 29)."""
    from gnss_citygml.options import OPTIONS

    algorithm = QgsApplication.processingRegistry().algorithmById(name)
    given = [p for p in algorithm.parameterDefinitions() if p.name() in OPTIONS]
    assert len(given) >= 5
    for parameter in given:
        spec = OPTIONS[parameter.name()]
        assert parameter.description() == spec.label
        if spec.kind == "choice":
            assert list(spec.choices)[parameter.defaultValue()] == spec.default
            assert parameter.options() == list(spec.words or spec.choices)
        elif spec.kind == "switch":
            assert parameter.defaultValue() is spec.default
        elif spec.kind == "field":
            assert parameter.parentLayerParameterName() == "FOOTPRINTS"
            assert parameter.flags() & parameter.FlagOptional
        else:
            assert parameter.defaultValue() == spec.default
            assert (parameter.minimum(), parameter.maximum()) == spec.bounds
            whole = parameter.dataType() == parameter.Integer
            assert whole == (spec.kind == "count"), parameter.name()
            assert bool(parameter.flags() & parameter.FlagOptional) == spec.optional


@pytest.mark.parametrize("name", ["gnsscitygml:estimate", "gnsscitygml:update"])
def test_the_signal_model_is_an_advanced_choice_with_the_librarys_default(plugin, name):
    from qgis.core import QgsProcessingParameterDefinition

    from gnss_citygml.settings import SIGNAL_MODELS, Estimator

    algorithm = QgsApplication.processingRegistry().algorithmById(name)
    parameter = algorithm.parameterDefinition("SIGNAL_MODEL")
    assert parameter.options() == list(SIGNAL_MODELS)
    assert parameter.options()[parameter.defaultValue()] == Estimator.signal_model
    assert parameter.flags() & QgsProcessingParameterDefinition.FlagAdvanced
    assert "signal model" in algorithm.shortHelpString()


@pytest.mark.parametrize("name", ["gnsscitygml:estimate", "gnsscitygml:update"])
def test_levelling_the_phones_is_an_advanced_switch_with_the_librarys_default(plugin, name):
    from qgis.core import QgsProcessingParameterDefinition

    from gnss_citygml.settings import Estimator

    algorithm = QgsApplication.processingRegistry().algorithmById(name)
    parameter = algorithm.parameterDefinition("LEVEL_PHONES")
    assert parameter.type() == "boolean"
    assert parameter.defaultValue() is Estimator.level_phones
    assert parameter.flags() & QgsProcessingParameterDefinition.FlagAdvanced
    assert "one level" in algorithm.shortHelpString()


#: A QGIS with its Python's Debian packages only (no site folders, so no gnss-citygml however
#: this machine's Python is set up), then ``SITE``'s folders: it loads the plugin as QGIS
#: does and runs an algorithm, printing the plugin's log (LOG), the algorithms (ALGORITHMS)
#: and the run's error (RUN).
SCRIPT = """
import sys
sys.path[:0] = ["/usr/lib/python3/dist-packages", "/usr/share/qgis/python/plugins", PLUGINS]
sys.path[3:3] = SITE
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
provider = QgsApplication.processingRegistry().providerById("gnsscitygml")
print("ALGORITHMS:", sorted(a.id() for a in provider.algorithms()))
for tag, text in messages:
    if tag == "gnss-citygml":
        print("LOG:", text)
try:
    processing.run("gnsscitygml:estimate", {})
except Exception as exc:
    print("RUN:", str(exc).replace(chr(10), " "))
"""


def plugin_in_qgis(tmp_path, site=()):
    """Load the plugin in a QGIS of Debian's packages and ``site``'s folders, run estimate:
    the plugin's messages by kind (LOG, RUN, ALGORITHMS); it must load without an error."""
    script = f"PLUGINS = {str(PLUGINS)!r}\nSITE = {[str(s) for s in site]!r}\n{SCRIPT}"
    process = debian_qgis(script, tmp_path)
    assert process.returncode == 0, process.stderr
    assert "Traceback" not in process.stderr, process.stderr
    lines = dict(line.split(": ", 1) for line in process.stdout.splitlines() if ": " in line)
    assert lines["ALGORITHMS"] == repr(ALGORITHMS)
    return lines


def test_without_the_library_the_plugin_loads_and_says_what_to_install(tmp_path):
    """No gnss-citygml: the plugin loads, and running an algorithm gives the message naming
    the library and the pip command for this Python."""
    lines = plugin_in_qgis(tmp_path)
    for key in ("LOG", "RUN"):
        message = lines[key]
        assert "the gnss-citygml library is missing from QGIS's Python: run Set up " in message
        assert "-m pip install --user --upgrade gnss-citygml" in message


def half_installed(folder, version=gnss_citygml.__version__, init=None):
    """A site folder with gnss-citygml's installed metadata (at ``version``) and, when
    ``init`` is given, a package gnss_citygml whose __init__.py is that."""
    info = folder / f"gnss_citygml-{version}.dist-info"
    info.mkdir(parents=True)
    (info / "METADATA").write_text(
        f"Metadata-Version: 2.1\nName: gnss-citygml\nVersion: {version}\n"
    )
    if init is not None:
        (folder / "gnss_citygml").mkdir()
        (folder / "gnss_citygml" / "__init__.py").write_text(init)
    return folder


@pytest.mark.parametrize(
    "init, why",
    [
        (None, "ModuleNotFoundError: No module named 'gnss_citygml'"),
        ("raise ImportError('libgeos_c.so.1: cannot open shared object file')", "ImportError"),
        ("import pyproj_gone", "ModuleNotFoundError: No module named 'pyproj_gone'"),
        ("def broken(:\n", "SyntaxError"),
        ("raise RuntimeError('numpy is broken')", "RuntimeError: numpy is broken"),
        ("", "No module named 'gnss_citygml.model'"),
    ],
)
def test_a_half_installed_library_is_said_and_the_plugin_loads(tmp_path, init, why):
    """The library's metadata installed, its module missing or failing to import (its own
    error, a missing or broken dependency, a syntax error, a part missing): the plugin loads
    with its algorithms, and says what is wrong and the command that reinstalls it."""
    lines = plugin_in_qgis(tmp_path, [half_installed(tmp_path / "site", init=init)])
    for key in ("LOG", "RUN"):
        message = lines[key]
        assert "the gnss-citygml library in QGIS's Python is broken: import gnss_citygml" in (
            message
        )
        assert why in message
        assert "-m pip install --user --upgrade --force-reinstall gnss-citygml" in message


def test_a_library_of_another_release_or_without_metadata_is_said(tmp_path):
    """The library's modules (this repository's, in a site folder of their own) with the
    metadata of another release, or with none (a copy, or what an uninstall left): the plugin
    loads and says so."""
    modules = tmp_path / "modules"
    modules.mkdir()
    (modules / "gnss_citygml").symlink_to(ROOT / "gnss_citygml")
    other = half_installed(tmp_path / "site", version="0.0.1")
    lines = plugin_in_qgis(tmp_path, [other, modules])
    for key in ("LOG", "RUN"):
        assert "QGIS's Python has gnss-citygml 0.0.1 and this plugin is " in lines[key]
        assert f'--upgrade "gnss-citygml=={gnss_citygml.__version__}"' in lines[key]
    lines = plugin_in_qgis(tmp_path, [modules])
    for key in ("LOG", "RUN"):
        message = lines[key]
        assert f"has gnss_citygml ({modules / 'gnss_citygml'}) without its installed" in message
        assert "-m pip install --user --upgrade gnss-citygml" in message


@pytest.mark.parametrize("kind", ["missing", "a folder", "not executable"])
def test_a_configured_python_that_cannot_run_is_said(
    plugin, processing_framework, tmp_path, monkeypatch, kind
):
    """``$GNSS_CITYGML_PYTHON`` naming no program: the algorithms show, and running one
    says what is wrong with the variable, not to install into a Python that is not there."""
    python = tmp_path / "bin" / "python"
    if kind == "a folder":
        python.mkdir(parents=True)
    elif kind == "not executable":
        python.parent.mkdir()
        python.write_text("#!/bin/sh\n")
    monkeypatch.setenv("GNSS_CITYGML_PYTHON", str(python))
    registry = QgsApplication.processingRegistry()
    assert sorted(a.id() for a in registry.providerById("gnsscitygml").algorithms()) == ALGORITHMS
    with pytest.raises(QgsProcessingException) as error:
        processing_framework.run("gnsscitygml:validate", {"INPUT": str(tmp_path / "city.gml")})
    message = str(error.value)
    assert f"GNSS_CITYGML_PYTHON names {python}, which " in message
    assert "unset it" in message and "pip install" not in message

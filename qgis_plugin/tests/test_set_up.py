""" "Set up gnss-citygml" (gnsscitygml:setup) in the real QGIS: it makes, upgrades and repairs
the jobs' own environment, Cancel leaves none half made, its failures are one line each; the
jobs then run with that environment's Python and QGIS imports only its gnss_citygml; and the
plugin offers it in the message bar when the library is missing.

These runs install a small stand-in wheel of the library (offline, from a folder of wheels);
test_set_up_qgis_process.py installs the real one, with its requirements, through
qgis_process."""

import base64
import hashlib
import os
import shutil
import sys
import zipfile

import pytest
from conftest import PLUGINS, ROOT, debian_qgis
from gnss_citygml_qgis import environment, library, set_up
from qgis.core import QgsApplication, QgsProcessingException, QgsProcessingFeedback

VERSION = library.plugin_version()


def fake_wheel(folder, version=VERSION, body="", requires=()):
    """A wheel named as the library's: gnss_citygml with ``body`` in its __init__.py and the
    modules set-up imports (jobs, worker), requiring ``requires``."""
    info = f"gnss_citygml-{version}.dist-info"
    metadata = f"Metadata-Version: 2.1\nName: gnss-citygml\nVersion: {version}\n"
    metadata += "".join(f"Requires-Dist: {r}\n" for r in requires)
    files = {
        "gnss_citygml/__init__.py": f"__version__ = {version!r}\n{body}",
        "gnss_citygml/jobs.py": "",
        "gnss_citygml/worker.py": "",
        "gnss_citygml/settings.py": "MARK = 'from the environment'\n",
        f"{info}/METADATA": metadata,
        f"{info}/WHEEL": "Wheel-Version: 1.0\nGenerator: test\nRoot-Is-Purelib: true\n"
        "Tag: py3-none-any\n",
    }
    record = ""
    for name, text in files.items():
        digest = hashlib.sha256(text.encode()).digest()
        encoded = base64.urlsafe_b64encode(digest).rstrip(b"=").decode()
        record += f"{name},sha256={encoded},{len(text.encode())}\n"
    files[f"{info}/RECORD"] = record + f"{info}/RECORD,,\n"
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / f"gnss_citygml-{version}-py3-none-any.whl"
    with zipfile.ZipFile(path, "w") as archive:
        for name, text in files.items():
            archive.writestr(name, text)
    return path


class Feedback(QgsProcessingFeedback):
    """Keeps what the algorithm said; cancels when a progress text starts with ``cancel_at``."""

    def __init__(self, cancel_at=None):
        super().__init__()
        self.cancel_at = cancel_at
        self.texts, self.infos, self.percents = [], [], []

    def setProgressText(self, text):  # noqa: N802 (the name QGIS calls)
        self.texts.append(text)
        if self.cancel_at and text.startswith(self.cancel_at):
            self.cancel()

    def pushInfo(self, info):  # noqa: N802 (the name QGIS calls)
        self.infos.append(info)

    def setProgress(self, percent):  # noqa: N802 (the name QGIS calls)
        self.percents.append(percent)
        super().setProgress(percent)


@pytest.fixture
def profile(tmp_path, monkeypatch):
    """The environment's place in a throwaway profile, the plugin's wheel a stand-in, an
    empty folder of wheels (offline), and Debian's Python the first on PATH."""
    folder = tmp_path / "profile" / "gnss-citygml" / "venv"
    monkeypatch.setattr(environment, "location", lambda: str(folder))
    wheel = fake_wheel(tmp_path / "plugin-wheels")
    monkeypatch.setattr(set_up, "shipped_wheel", lambda version: str(wheel))
    monkeypatch.setenv("PATH", "/usr/bin:/bin")
    monkeypatch.delenv("GNSS_CITYGML_PYTHON", raising=False)
    (tmp_path / "wheels").mkdir()
    yield {"folder": folder, "wheel": wheel, "wheels": tmp_path / "wheels", "tmp": tmp_path}
    library._Library.use(None)


def run_set_up(processing, profile, feedback=None, **parameters):
    parameters.setdefault("WHEELS", str(profile["wheels"]))
    return processing.run("gnsscitygml:setup", parameters, feedback=feedback or Feedback())


def test_set_up_can_always_run(plugin, monkeypatch):
    monkeypatch.setattr(library, "unavailable", lambda: "the library is missing")
    algorithm = QgsApplication.processingRegistry().algorithmById("gnsscitygml:setup")
    assert algorithm.canExecute() == (True, "")
    assert algorithm.displayName() == "Set up gnss-citygml"
    assert "Run it again to upgrade the environment in place" in algorithm.shortHelpString()


def test_set_up_makes_upgrades_and_repairs_the_environment(plugin, processing_framework, profile):
    folder = profile["folder"]
    feedback = Feedback()
    made = run_set_up(processing_framework, profile, feedback)
    python = str(folder / "bin" / "python")
    assert made == {
        "ACTION": "made",
        "BASE_PYTHON": "/usr/bin/python3",
        "FOLDER": str(folder),
        "PYTHON": python,
        "VERSION": VERSION,
    }
    # it says what it did: the Python used, the folder, the version installed
    assert feedback.infos[0].startswith("Python used: /usr/bin/python3 (Python 3.")
    assert f"made the environment {folder} with /usr/bin/python3: Python 3." in feedback.infos[1]
    assert feedback.infos[2] == (
        f"installed gnss-citygml {VERSION} from {profile['wheel'].name} and its 0 requirements "
        f"from the folder {profile['wheels']}"
    )
    assert feedback.infos[3] == f"the jobs now run with {python}"
    assert f"making a virtual environment in {folder}" in feedback.texts
    assert f"collecting gnss_citygml-{VERSION} (1 of about 30)" in feedback.texts
    assert feedback.percents == sorted(feedback.percents) and feedback.percents[-1] == 100
    marker = environment.read_marker(str(folder))
    assert marker["wheel"] == environment.wheel_digest(profile["wheel"])
    assert marker["python"] == "/usr/bin/python3" and marker["version"] == VERSION
    assert not (folder / environment.INCOMPLETE).exists()

    # the jobs now run there, isolated from QGIS's Python settings
    assert environment.state(str(folder), VERSION).status == "sound"
    assert library.interpreter() == python
    command, env = library.job_command()
    assert command == [python, "-I"] and "PYTHONPATH" not in env

    # again, with the library built anew at the same version: upgraded in place
    wheel = fake_wheel(profile["tmp"] / "plugin-wheels", body="NEW = True\n")
    feedback = Feedback()
    assert run_set_up(processing_framework, profile, feedback)["ACTION"] == "upgraded"
    assert f"upgrading the environment {folder} in place" in feedback.infos
    site = environment.state(str(folder), VERSION).site
    assert "NEW = True" in open(os.path.join(site, "gnss_citygml", "__init__.py")).read()
    assert environment.read_marker(str(folder))["wheel"] == environment.wheel_digest(wheel)
    assert environment.read_marker(str(folder))["made"] == marker["made"]

    # broken (the library's package gone): said, and made anew
    shutil.rmtree(os.path.join(site, "gnss_citygml"))
    broken = environment.state(str(folder), VERSION)
    assert broken.status == "broken" and "import gnss_citygml fails there" in broken.problem
    feedback = Feedback()
    assert run_set_up(processing_framework, profile, feedback)["ACTION"] == "remade"
    assert (
        feedback.infos[0] == f"the environment {folder} is broken ({broken.problem}): removing it"
    )
    assert environment.state(str(folder), VERSION).status == "sound"

    # and from scratch, when asked
    assert run_set_up(processing_framework, profile, RECREATE=True)["ACTION"] == "remade"


def test_cancel_leaves_no_half_environment(plugin, processing_framework, profile):
    folder = profile["folder"]
    feedback = Feedback(cancel_at="making a virtual environment")
    with pytest.raises(QgsProcessingException, match="^cancelled: no environment was made$"):
        run_set_up(processing_framework, profile, feedback)
    assert not folder.exists()

    # cancelled while pip upgrades it: as it was (pip had changed nothing yet)
    run_set_up(processing_framework, profile)
    feedback = Feedback(cancel_at="collecting")
    with pytest.raises(QgsProcessingException, match=r"^cancelled: the environment .* as it was$"):
        run_set_up(processing_framework, profile, feedback)
    assert environment.state(str(folder), VERSION).status == "sound"


def test_no_usable_python_is_one_line(plugin, processing_framework, profile, monkeypatch):
    bin = profile["tmp"] / "bin"
    bin.mkdir()
    old = bin / "python3"
    old.write_text('#!/bin/sh\necho \'{"version": [3, 9, 2], "missing": []}\'\n')
    old.chmod(0o755)
    monkeypatch.setenv("PATH", str(bin))
    monkeypatch.setattr(library, "qgis_python", lambda: str(old))
    with pytest.raises(QgsProcessingException) as raised:
        run_set_up(processing_framework, profile)
    message = str(raised.value)
    assert message.startswith("no usable Python to make gnss-citygml's environment from: ")
    assert "\n" not in message and "run Set up gnss-citygml again" in message
    assert not profile["folder"].exists()


def test_no_network_and_a_folder_without_the_requirements_are_one_line(
    plugin, processing_framework, profile, monkeypatch
):
    """pip's index unreachable (nothing listens there), no cache, no local wheels."""
    monkeypatch.setattr(
        set_up, "shipped_wheel", lambda version: str(fake_wheel(
            profile["tmp"] / "needs", requires=["gnss-citygml-test-requirement>=1"]
        ))
    )  # fmt: skip
    monkeypatch.setenv("PIP_CONFIG_FILE", os.devnull)
    monkeypatch.setenv("PIP_INDEX_URL", "http://127.0.0.1:9/simple")
    monkeypatch.setenv("PIP_CACHE_DIR", str(profile["tmp"] / "pip-cache"))
    for name in ("PIP_FIND_LINKS", "PIP_EXTRA_INDEX_URL", "PIP_NO_INDEX"):
        monkeypatch.delenv(name, raising=False)
    with pytest.raises(QgsProcessingException) as raised:
        run_set_up(processing_framework, profile, WHEELS="")
    message = str(raised.value)
    assert message.startswith("no network: pip could not reach the package index")
    assert "\n" not in message and 'pip download --dest wheels "' in message
    assert not profile["folder"].exists()

    with pytest.raises(QgsProcessingException) as raised:
        run_set_up(processing_framework, profile)
    assert str(raised.value).startswith(
        f"the folder of wheels {profile['wheels']} has no gnss-citygml-test-requirement>=1 for "
        "Python 3."
    )
    assert not profile["folder"].exists()


def test_the_message_bar_offers_set_up(qgis_iface, processing_framework, monkeypatch):
    """The library missing: the plugin's message has a "Set up" button that opens set-up's
    dialog; once set-up has made the library usable, the message goes."""
    import gnss_citygml_qgis
    import processing
    from gnss_citygml_qgis import plugin as plugin_module
    from qgis.PyQt.QtWidgets import QPushButton

    problem = ["the gnss-citygml library is missing: run Set up gnss-citygml"]
    monkeypatch.setattr(plugin_module, "unavailable", lambda: problem[0])
    opened = []
    monkeypatch.setattr(processing, "execAlgorithmDialog", lambda *a: opened.append(a))
    bar = qgis_iface.messageBar()
    loaded = gnss_citygml_qgis.classFactory(qgis_iface)
    loaded.initGui()
    try:
        item = bar.currentItem()
        assert item is not None and problem[0] in item.text()
        (button,) = [b for b in item.findChildren(QPushButton) if b.text() == "Set up"]
        button.click()
        assert opened == [("gnsscitygml:setup", {})]
        problem[0] = None
        for ready in list(set_up.READY):
            ready()
        assert bar.currentItem() is None
    finally:
        loaded.unload()
    assert set_up.READY == []


def test_a_broken_environment_is_offered_for_repair(qgis_iface, processing_framework, profile):
    """Broken, the environment is not used (the jobs run with QGIS's own library, which this
    QGIS has), and the message bar offers set-up to repair it."""
    import gnss_citygml_qgis
    from qgis.PyQt.QtWidgets import QPushButton

    profile["folder"].mkdir(parents=True)
    (profile["folder"] / environment.INCOMPLETE).write_text("")
    assert library.unavailable() is None
    assert library.interpreter() == library.qgis_python()
    loaded = gnss_citygml_qgis.classFactory(qgis_iface)
    loaded.initGui()
    try:
        item = qgis_iface.messageBar().currentItem()
        assert item.text() == (
            f"the environment of gnss-citygml in {profile['folder']} is broken (its set-up did "
            "not finish: it was cancelled or failed): run Set up gnss-citygml (Processing "
            "Toolbox, GNSS 3D mapping) to make it anew"
        )
        assert [b.text() for b in item.findChildren(QPushButton)] == ["Set up"]
    finally:
        loaded.unload()
    assert qgis_iface.messageBar().currentItem() is None


#: A QGIS whose Python has no gnss-citygml, with the jobs' environment at ``FOLDER`` (in its
#: profile): what it imports and from where.
SCRIPT = """
import sys
sys.path[:0] = ["/usr/lib/python3/dist-packages", "/usr/share/qgis/python/plugins", PLUGINS]
from qgis.core import QgsApplication
app = QgsApplication([], False)
app.initQgis()
messages = []
QgsApplication.messageLog().messageReceived.connect(
    lambda text, tag, level: messages.append((tag, text)))
from processing.core.Processing import Processing
Processing.initialize()
import gnss_citygml_qgis
from gnss_citygml_qgis import environment
environment.location = lambda: FOLDER
plugin = gnss_citygml_qgis.classFactory(None)
plugin.initGui()
registry = QgsApplication.processingRegistry()
print("PARAMETERS:", len(registry.algorithmById("gnsscitygml:estimate").parameterDefinitions()))
try:
    import gnss_citygml.settings
    print("LIBRARY:", gnss_citygml.__file__)
except ImportError as exc:
    print("LIBRARY:", exc)
try:
    import only_in_the_environment
    print("OTHER:", only_in_the_environment.__file__)
except ImportError as exc:
    print("OTHER:", exc)
for tag, text in messages:
    if tag == "gnss-citygml":
        print("LOG:", text)
"""


def qgis_with_environment(tmp_path, folder):
    script = f"PLUGINS = {str(PLUGINS)!r}\nFOLDER = {str(folder)!r}\n{SCRIPT}"
    process = debian_qgis(script, tmp_path)
    assert process.returncode == 0, process.stderr
    return dict(line.split(": ", 1) for line in process.stdout.splitlines() if ": " in line)


def test_qgis_imports_only_the_environments_gnss_citygml(
    plugin, processing_framework, profile, tmp_path
):
    """Made by set-up, the environment gives QGIS (whose Python has no library) its package
    gnss_citygml, and nothing else of its site-packages; broken, it is said how to repair."""
    run_set_up(processing_framework, profile)
    site = environment.state(str(profile["folder"]), VERSION).site
    # the library's own pure modules there (the stand-in has none), and a module of another
    shutil.rmtree(os.path.join(site, "gnss_citygml"))
    os.symlink(ROOT / "gnss_citygml", os.path.join(site, "gnss_citygml"))
    (open(os.path.join(site, "only_in_the_environment.py"), "w")).close()
    lines = qgis_with_environment(tmp_path, profile["folder"])
    assert "LOG" not in lines
    assert lines["LIBRARY"] == os.path.join(site, "gnss_citygml", "__init__.py")
    assert lines["OTHER"] == "No module named 'only_in_the_environment'"
    assert int(lines["PARAMETERS"]) > 10  # the estimate's, with the library's defaults

    (profile["folder"] / environment.INCOMPLETE).write_text("")
    lines = qgis_with_environment(tmp_path, profile["folder"])
    assert lines["LOG"] == (
        f"the environment of gnss-citygml in {profile['folder']} is broken (its set-up did not "
        "finish: it was cancelled or failed): run Set up gnss-citygml (Processing Toolbox, "
        "GNSS 3D mapping) to make it anew"
    )
    assert lines["PARAMETERS"] == "0"


def test_the_private_environment_decides_the_jobs_python_after_the_variable(
    plugin, processing_framework, profile, monkeypatch
):
    run_set_up(processing_framework, profile)
    monkeypatch.setenv("GNSS_CITYGML_PYTHON", sys.executable)
    assert library.interpreter() == sys.executable
    assert library.job_command() == ([sys.executable], None)
    monkeypatch.delenv("GNSS_CITYGML_PYTHON")
    assert library.interpreter() == str(profile["folder"] / "bin" / "python")
    shutil.rmtree(profile["folder"])
    assert library.interpreter() == library.qgis_python()
    assert library.job_command() == ([library.qgis_python()], None)

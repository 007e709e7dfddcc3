"""The jobs' own environment: a virtual environment in the QGIS profile's folder with the
gnss-citygml library, which "Set up gnss-citygml" makes (:mod:`.set_up`) and the jobs then
run in (:mod:`.library` decides).

Pure Python (QGIS only to know where the profile is), so that each part is tested alone: where
the environment is (:func:`location`), which Python to make it from (:func:`find_python`),
whether it is sound (:func:`state`), running a program with Cancel (:func:`follow`), pip's
output as progress (:class:`PipProgress`) and its failure in one line (:func:`pip_failure`).
Like library.py, it parses on Python 3.7.
"""

import glob
import hashlib
import json
import os
import queue
import re
import shutil
import signal
import subprocess
import sys
import threading
import zipfile
from collections import namedtuple

#: The oldest Python the library runs on.
PYTHON = (3, 11)

#: The folder of the environment, in the QGIS profile's folder.
FOLDER = os.path.join("gnss-citygml", "venv")

#: What set-up writes in the environment once it is done: the library's version and wheel,
#: and the Python it was made from.
MARKER = "gnss-citygml-setup.json"

#: There while set-up changes the environment: an environment with it did not finish.
INCOMPLETE = "gnss-citygml-setup.incomplete"

#: How many distributions the library brings with it (measured: 28 on Linux, Python 3.11):
#: how far pip's collecting is, until pip says.
EXPECTED_PACKAGES = 30

Environment = namedtuple("Environment", "folder python status problem version site")
Environment.__doc__ = """An environment's state: ``status`` "absent", "sound" or "broken" (then
``problem`` says why); a sound one's ``python``, library ``version`` and ``site`` (the folder
its ``gnss_citygml`` package is in)."""

Python = namedtuple("Python", "path version own")
Python.__doc__ = """A Python to make the environment from: its path, version ("3.11.2"), and
whether it is QGIS's own (which keeps QGIS's PYTHONHOME)."""


class NoPython(Exception):
    """No Python to make the environment from (the message says what was tried)."""


class Cancelled(Exception):
    """The user cancelled: the program was stopped."""


def location():
    """Where the environment is: the QGIS profile's folder, ``gnss-citygml/venv``; None outside
    QGIS."""
    try:
        from qgis.core import QgsApplication
    except ImportError:
        return None
    profile = QgsApplication.qgisSettingsDirPath()
    return os.path.join(profile, FOLDER) if profile else None


def python_of(folder):
    """The Python of the virtual environment ``folder``."""
    if os.name == "nt":
        return os.path.join(folder, "Scripts", "python.exe")
    return os.path.join(folder, "bin", "python")


def clean_environ(keep_home=False):
    """The environment variables for a Python other than QGIS's: without QGIS's PYTHONHOME and
    PYTHONPATH (that Python would load QGIS's Python's modules), the user's site folder or the
    current folder on its path, and unbuffered, so that its lines come as they are printed.
    ``keep_home``: for QGIS's own Python, which may need its PYTHONHOME (OSGeo4W)."""
    env = dict(os.environ)
    names = ["PYTHONPATH", "PYTHONSTARTUP", "PYTHONUSERBASE", "PYTHONEXECUTABLE", "VIRTUAL_ENV"]
    for name in names + ["__PYVENV_LAUNCHER__"] + ([] if keep_home else ["PYTHONHOME"]):
        env.pop(name, None)
    env.update(PYTHONNOUSERSITE="1", PYTHONUNBUFFERED="1", PYTHONSAFEPATH="1")
    return env


#: Prints the library's version and the folder it is imported from (in the environment's
#: Python: :func:`state`).
CHECK = """import json, os, sys
from importlib import metadata
import gnss_citygml
print(json.dumps({
    "version": metadata.version("gnss-citygml"),
    "site": os.path.dirname(os.path.dirname(os.path.abspath(gnss_citygml.__file__))),
}))"""

#: The last check of each environment: (its files' signature, what the check printed).
_CHECKED = {}


def state(folder, version):
    """The state of the environment ``folder``, for a plugin of ``version``: absent, sound, or
    broken (set-up did not finish, its Python is missing, ``import gnss_citygml`` fails there,
    or its library is another version). Its Python is asked only when its files changed."""
    if not folder or not os.path.isdir(folder):
        return Environment(folder, None, "absent", None, None, None)

    def broken(why):
        return Environment(folder, None, "broken", why, None, None)

    if os.path.exists(os.path.join(folder, INCOMPLETE)):
        return broken("its set-up did not finish: it was cancelled or failed")
    if not os.path.exists(os.path.join(folder, "pyvenv.cfg")):
        return broken("it is not a virtual environment: it has no pyvenv.cfg")
    python = python_of(folder)
    if not os.path.exists(python):
        base = home(folder)
        made = f" (the Python it was made from, in {base}, is gone or was upgraded)" * bool(base)
        return broken(f"its Python {python} is missing{made}")
    key = _signature(folder, python)
    checked = _CHECKED.get(folder)
    if checked is None or checked[0] != key:
        checked = _CHECKED[folder] = (key, _check(python))
    found = checked[1]
    if "error" in found:
        return broken(f"import gnss_citygml fails there ({found['error']})")
    if version and found["version"] != version:
        return broken(f"it has gnss-citygml {found['version']} and this plugin is {version}")
    return Environment(folder, python, "sound", None, found["version"], found["site"])


def home(folder):
    """The folder of the Python a virtual environment was made from (its pyvenv.cfg's home)."""
    try:
        with open(os.path.join(folder, "pyvenv.cfg"), encoding="utf-8") as config:
            for line in config:
                key, _, value = line.partition("=")
                if key.strip() == "home":
                    return value.strip()
    except OSError:
        pass
    return None


def _signature(folder, python):
    """What changes when the environment's Python or packages change: modification times."""
    paths = [python, os.path.join(folder, "pyvenv.cfg"), os.path.join(folder, MARKER)]
    for site in _sites(folder):
        paths += [site, os.path.join(site, "gnss_citygml", "__init__.py")]
    stamps = []
    for path in paths:
        try:
            stamps.append((path, os.stat(path).st_mtime_ns))
        except OSError:
            stamps.append((path, None))
    return tuple(stamps)


def _sites(folder):
    """The environment's site-packages folders."""
    patterns = ("lib/python3*/site-packages", "Lib/site-packages")
    return sorted(set(sum((glob.glob(os.path.join(folder, p)) for p in patterns), [])))


def _check(python):
    """Run :data:`CHECK` in ``python``: what it printed, or its error's last line."""
    answer = ask(python, CHECK)
    if "error" not in answer and not {"version", "site"} <= set(answer):
        answer = {"error": "it printed no version"}
    return answer


def ask(python, code, env=None, timeout=60):
    """Run ``code`` in ``python`` (isolated from QGIS's Python and the user's folders): the
    JSON object it printed last, or ``{"error": its last line}``."""
    try:
        done = subprocess.run(
            [python, "-I", "-c", code],
            capture_output=True,
            text=True,
            errors="replace",
            env=clean_environ() if env is None else env,
            timeout=timeout,
            stdin=subprocess.DEVNULL,
        )
    except (OSError, subprocess.SubprocessError) as exc:
        return {"error": f"{type(exc).__name__}: {exc}"}
    if done.returncode != 0:
        lines = (done.stderr + done.stdout).strip().splitlines()
        return {"error": lines[-1].strip() if lines else f"exit status {done.returncode}"}
    try:
        answer = json.loads(done.stdout.strip().splitlines()[-1])
    except (IndexError, ValueError):
        return {"error": f"it printed {done.stdout.strip()[-200:]!r}"}
    return answer if isinstance(answer, dict) else {"error": f"it printed {answer!r}"}


#: The names under which a Python is looked for on PATH, in order; then QGIS's own.
NAMES = ("python3", "python3.13", "python3.12", "python3.11", "python")

#: Prints a Python's version and whether it has what making an environment needs.
PROBE = """import json, sys
missing = []
for name in ("venv", "ensurepip"):
    try:
        __import__(name)
    except ImportError:
        missing.append(name)
print(json.dumps({"version": list(sys.version_info[:3]), "missing": missing}))"""


def find_python(qgis_python=None, names=NAMES, path=None):
    """The Python to make the environment from: the first of ``names`` on ``path`` (PATH), then
    ``qgis_python``, that runs, is 3.11 or newer and has its venv and ensurepip modules.
    Raises :class:`NoPython` saying what was tried."""
    tried, absent, seen = [], [], set()
    candidates = [(name, shutil.which(name, path=path), False) for name in names]
    if qgis_python:
        candidates.append(("QGIS's Python", qgis_python, True))
    for name, found, own in candidates:
        if not found or (own and not os.path.exists(found)):
            absent.append(name)
            continue
        real = os.path.realpath(found)
        if real in seen:
            continue
        seen.add(real)
        answer = ask(found, PROBE, env=clean_environ(keep_home=own), timeout=30)
        why = _unusable(answer)
        if why is None:
            return Python(found, ".".join(map(str, answer["version"])), own)
        tried.append(f"{name} ({found}): {why}")
    if absent:
        tried.append(", ".join(absent) + ": not found")
    raise NoPython(
        "no usable Python to make gnss-citygml's environment from: it needs Python {}.{} or "
        "newer with its venv module (tried {}): install one (python.org; Debian, Ubuntu: "
        "sudo apt install python3-venv) and run Set up gnss-citygml again".format(
            *PYTHON, "; ".join(tried)
        )
    )


def _unusable(answer):
    """Why a Python that answered :data:`PROBE` with ``answer`` cannot make the environment."""
    if "error" in answer:
        return f"does not run ({answer['error']})"
    version = tuple(answer.get("version") or ())
    if version[:2] < PYTHON:
        return "Python {}, too old".format(".".join(map(str, version)) or "?")
    if answer.get("missing"):
        return "no {} module (Debian, Ubuntu: sudo apt install python3-venv)".format(
            " or ".join(answer["missing"])
        )
    return None


def wheel_digest(wheel):
    """The SHA-256 of a wheel's RECORD (every file's own digest): the same for the same
    content, however often it is built."""
    with zipfile.ZipFile(wheel) as archive:
        records = [n for n in archive.namelist() if n.endswith(".dist-info/RECORD")]
        if len(records) != 1:
            raise ValueError(f"{wheel} is not a wheel (no single .dist-info/RECORD)")
        return hashlib.sha256(archive.read(records[0])).hexdigest()


def read_marker(folder):
    """What set-up wrote in the environment ``folder`` (:data:`MARKER`), or {}."""
    try:
        with open(os.path.join(folder, MARKER), encoding="utf-8") as marker:
            found = json.load(marker)
    except (OSError, ValueError):
        return {}
    return found if isinstance(found, dict) else {}


#: A new process group (POSIX: a session), so that Cancel stops the program's children too
#: (venv runs ensurepip in a child).
_GROUP = (
    {"creationflags": subprocess.CREATE_NEW_PROCESS_GROUP}
    if sys.platform == "win32"
    else {"start_new_session": True}
)


def follow(command, on_line, cancelled, env=None, poll=0.1):
    """Run ``command``, passing each line of its output (standard output and error together)
    to ``on_line`` as it comes, and polling ``cancelled()``: when it is true, the program and
    its children are stopped and :class:`Cancelled` is raised. Returns (exit status, lines)."""
    child = subprocess.Popen(
        command,
        stdin=subprocess.DEVNULL,
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
        encoding="utf-8",
        errors="replace",
        env=env,
        **_GROUP,
    )
    lines, output = queue.Queue(), []
    reader = threading.Thread(target=_read, args=(child.stdout, lines), daemon=True)
    reader.start()
    try:
        while True:
            try:
                line = lines.get(timeout=poll)
            except queue.Empty:
                line = ""
            if line is None:
                break
            if line.strip():
                output.append(line.rstrip())
                on_line(line.rstrip())
            if cancelled():
                raise Cancelled()
        child.wait()
    finally:
        if child.poll() is None:
            _stop(child)
        reader.join(5)
        child.stdout.close()
    return child.returncode, output


def _read(stream, lines):
    """Put each line of ``stream`` on the queue ``lines``, then None."""
    try:
        for line in stream:
            lines.put(line)
    except (OSError, ValueError):
        pass
    lines.put(None)


def _stop(child):
    """Stop ``child`` and its process group: asked (SIGTERM), then killed after 10 s."""
    try:
        if sys.platform == "win32":
            child.terminate()
        else:
            os.killpg(child.pid, signal.SIGTERM)
        child.wait(10)
    except subprocess.TimeoutExpired:
        if sys.platform == "win32":
            child.kill()
        else:
            os.killpg(child.pid, signal.SIGKILL)
        child.wait()
    except ProcessLookupError:
        child.wait()


class PipProgress:
    """pip's output (``pip install``, no progress bars) as progress: :meth:`feed` takes a line
    and gives (text or None, fraction of the install done or None)."""

    def __init__(self, expected=EXPECTED_PACKAGES):
        self.expected = expected
        self.collected = 0
        self.installing = None

    def feed(self, line):
        line = line.strip()
        found = re.match(r"(Collecting|Processing|Requirement already satisfied:)\s+(\S+)", line)
        if found:
            self.collected += 1
            name = _distribution(found.group(2))
            verb = "already there:" if found.group(1).startswith("Req") else "collecting"
            about = max(self.expected, self.collected)
            share = self.collected / (about + 1)
            return f"{verb} {name} ({self.collected} of about {about})", 0.7 * share
        found = re.match(r"(Downloading|Using cached)\s+(\S+)(?:\s+\(([^)]+)\))?", line)
        if found:
            size = f" ({found.group(3)})" if found.group(3) else ""
            return f"{found.group(1).lower()} {_distribution(found.group(2))}{size}", None
        found = re.match(r"Installing collected packages:\s*(.*)", line)
        if found:
            names = [n.strip() for n in found.group(1).split(",") if n.strip()]
            self.installing = len(names)
            shown = ", ".join(names[:4]) + (", ..." if len(names) > 4 else "")
            return f"installing {len(names)} packages: {shown}", 0.75
        if line.startswith("Successfully installed"):
            return "installed", 1.0
        if line.startswith("WARNING: Retrying"):
            return "the package index does not answer: trying again", None
        return None, None


def _distribution(text):
    """A distribution's name from pip's words: a requirement, a file or a URL."""
    name = text.rstrip("/").split("/")[-1].split("#")[0]
    if name.endswith((".whl", ".tar.gz", ".zip")):
        return "-".join(name.split("-")[:2])
    return name


#: Words of pip's output that mean the package index could not be reached.
_NETWORK = re.compile(
    r"NewConnectionError|Failed to establish a new connection|name resolution|"
    r"Name or service not known|nodename nor servname|getaddrinfo failed|Network is "
    r"unreachable|No route to host|Connection refused|ConnectTimeout|timed out|ProxyError|"
    r"SSLError|CERTIFICATE_VERIFY_FAILED|Connection reset|RemoteDisconnected"
)


def pip_failure(lines, requirement, wheels=None, python=None):
    """What went wrong, in one line, from pip's output ``lines``: no network (with what to do
    offline), a folder of ``wheels`` without a requirement, or pip's last error.
    ``requirement``: what set-up installs (the plugin's wheel, or the library's release);
    ``python``: the environment's Python version."""
    text = "\n".join(lines)
    missing = re.search(r"No matching distribution found for (\S+)", text)
    this = f"Python {python}" if python else "this Python"
    if os.path.isabs(requirement):
        requirement = f'"{requirement}"'
    offline = (
        "give Set up gnss-citygml a folder of wheels made where there is a network, for "
        f"{this} on this system, with: pip download --dest wheels {requirement}"
    )
    if wheels and missing:
        return (
            f"the folder of wheels {wheels} has no {missing.group(1)} for {this} on this "
            f"system: {offline}, and run Set up gnss-citygml again"
        )
    if not wheels and _NETWORK.search(text):
        return (
            "no network: pip could not reach the package index to download gnss-citygml's "
            "requirements (numpy, pandas, GDAL's and PROJ's wheels: about 200 MB): connect "
            "this computer to the internet (behind a proxy, set HTTPS_PROXY before starting "
            f"QGIS) and run Set up gnss-citygml again, or, offline, {offline}"
        )
    if missing:
        return (
            f"pip found no {missing.group(1)} for {this} on this system in the package "
            "index: run Set up gnss-citygml again with a Python it has wheels for, or give "
            f"it a folder of wheels ({offline})"
        )
    errors = [line[len("ERROR:") :].strip() for line in lines if line.startswith("ERROR:")]
    last = errors[-1] if errors else (lines[-1].strip() if lines else "no output")
    return f"pip failed: {last}"

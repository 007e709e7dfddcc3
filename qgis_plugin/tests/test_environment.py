"""The pure parts of the jobs' own environment (gnss_citygml_qgis/environment.py): which Python
it is made from, whether one is sound, pip's output as progress and its failures in one line,
and Cancel stopping a program with its children."""

import json
import os
import shutil
import stat
import sys
import time

import pytest
from gnss_citygml_qgis import environment
from gnss_citygml_qgis.environment import (
    INCOMPLETE,
    Cancelled,
    NoPython,
    PipProgress,
    find_python,
    follow,
    pip_failure,
    state,
)

#: The Python this QGIS runs (a virtual environment's python links to it).
BASE = os.path.realpath(sys.executable)


def fake_python(folder, name, answer=None, status=0, said=""):
    """A program ``name`` in ``folder`` that answers the probe with ``answer`` (a version, and
    the modules missing), or prints ``said`` and exits with ``status``."""
    folder.mkdir(exist_ok=True)
    path = folder / name
    if answer is not None:
        version, missing = answer
        said = json.dumps({"version": version, "missing": missing})
    path.write_text(f"#!/bin/sh\necho '{said}'\nexit {status}\n")
    path.chmod(path.stat().st_mode | stat.S_IXUSR)
    return path


def test_the_first_usable_python_on_path_is_taken(tmp_path):
    bin = tmp_path / "bin"
    fake_python(bin, "python3", ([3, 9, 2], []))
    fake_python(bin, "python3.13", status=127, said="pyenv: python3.13: command not found")
    fake_python(bin, "python3.12", ([3, 12, 1], ["ensurepip"]))
    good = fake_python(bin, "python3.11", ([3, 11, 4], []))
    found = find_python("/no/qgis/python", path=str(bin))
    assert found == (str(good), "3.11.4", False)


def test_qgis_python_is_taken_when_it_is_the_only_one(tmp_path):
    own = fake_python(tmp_path / "qgis", "python3", ([3, 11, 2], []))
    (tmp_path / "bin").mkdir()
    assert find_python(str(own), path=str(tmp_path / "bin")) == (str(own), "3.11.2", True)


def test_the_same_python_under_two_names_is_asked_once(tmp_path):
    bin = tmp_path / "bin"
    real = fake_python(bin, "python3.11", ([3, 10, 12], []))
    (bin / "python3").symlink_to(real)
    with pytest.raises(NoPython) as raised:
        find_python(None, path=str(bin))
    assert str(raised.value).count("Python 3.10.12, too old") == 1


def test_no_usable_python_is_one_line_saying_what_was_tried_and_what_to_do(tmp_path):
    bin = tmp_path / "bin"
    fake_python(bin, "python3", ([3, 9, 2], []))
    fake_python(bin, "python3.12", ([3, 12, 1], ["venv", "ensurepip"]))
    fake_python(bin, "python3.13", status=127, said="pyenv: python3.13: command not found")
    own = fake_python(tmp_path / "qgis", "python3.10", ([3, 10, 6], []))
    with pytest.raises(NoPython) as raised:
        find_python(str(own), path=str(bin))
    message = str(raised.value)
    assert "\n" not in message
    assert message.startswith("no usable Python to make gnss-citygml's environment from: it ")
    assert f"python3 ({bin / 'python3'}): Python 3.9.2, too old" in message
    assert "python3.12 (" in message and "no venv or ensurepip module" in message
    assert "does not run (pyenv: python3.13: command not found)" in message
    assert f"QGIS's Python ({own}): Python 3.10.6, too old" in message
    assert "python3.11, python: not found" in message
    assert "sudo apt install python3-venv" in message
    assert message.endswith("and run Set up gnss-citygml again")


def make_env(folder, version="0.1.0", init="__version__ = '0.1.0'\n"):
    """A virtual environment without pip (this Python, linked), with a package gnss_citygml
    whose __init__.py is ``init`` and installed metadata at ``version``."""
    (folder / "bin").mkdir(parents=True)
    (folder / "pyvenv.cfg").write_text(f"home = {os.path.dirname(BASE)}\n")
    (folder / "bin" / "python").symlink_to(BASE)
    site = folder / "lib" / "python{}.{}".format(*sys.version_info[:2]) / "site-packages"
    (site / "gnss_citygml").mkdir(parents=True)
    (site / "gnss_citygml" / "__init__.py").write_text(init)
    info = site / f"gnss_citygml-{version}.dist-info"
    info.mkdir()
    (info / "METADATA").write_text(
        f"Metadata-Version: 2.1\nName: gnss-citygml\nVersion: {version}\n"
    )
    return site


def test_a_sound_environment_and_each_way_it_breaks(tmp_path):
    folder = tmp_path / "venv"
    assert state(str(folder), "0.1.0").status == "absent"
    site = make_env(folder)
    found = state(str(folder), "0.1.0")
    assert found.status == "sound" and found.problem is None
    assert found.python == str(folder / "bin" / "python")
    assert (found.version, found.site) == ("0.1.0", str(site))

    # another version than the plugin's
    found = state(str(folder), "0.2.0")
    assert found.status == "broken"
    assert found.problem == "it has gnss-citygml 0.1.0 and this plugin is 0.2.0"

    # import gnss_citygml fails there (asked again: its files changed)
    (site / "gnss_citygml" / "__init__.py").write_text("raise ImportError('libgeos_c.so.1')\n")
    found = state(str(folder), "0.1.0")
    assert found.status == "broken"
    assert found.problem == "import gnss_citygml fails there (ImportError: libgeos_c.so.1)"
    shutil.rmtree(site / "gnss_citygml")
    assert "No module named 'gnss_citygml'" in state(str(folder), "0.1.0").problem

    # set-up did not finish
    (folder / INCOMPLETE).write_text("")
    assert state(str(folder), "0.1.0").problem == (
        "its set-up did not finish: it was cancelled or failed"
    )
    (folder / INCOMPLETE).unlink()

    # its Python is gone (the Python it was made from removed: the link dangles)
    (folder / "bin" / "python").unlink()
    (folder / "bin" / "python").symlink_to(tmp_path / "removed-python3")
    found = state(str(folder), "0.1.0")
    assert found.status == "broken"
    assert found.problem.startswith(f"its Python {folder / 'bin' / 'python'} is missing (the ")

    # not an environment at all
    (folder / "pyvenv.cfg").unlink()
    assert state(str(folder), "0.1.0").problem == (
        "it is not a virtual environment: it has no pyvenv.cfg"
    )


def test_a_sound_environment_is_asked_once(tmp_path, monkeypatch):
    folder = tmp_path / "venv"
    make_env(folder)
    assert state(str(folder), "0.1.0").status == "sound"
    asked = []
    monkeypatch.setattr(environment, "ask", lambda *a, **k: asked.append(a) or {"error": "x"})
    for _ in range(3):
        assert state(str(folder), "0.1.0").status == "sound"
    assert asked == []


#: pip's output (23.0.1, no progress bar) making an environment, shortened.
FRESH = """Looking in indexes: https://pypi.org/simple
Processing ./wheels/gnss_citygml-0.1.0-py3-none-any.whl
Collecting numpy>=1.26
  Downloading numpy-2.4.6-cp311-cp311-manylinux_2_27_x86_64.whl (16.9 MB)
Collecting pandas>=2.1
  Using cached pandas-3.1.1-cp311-cp311-manylinux_2_28_x86_64.whl (12.4 MB)
WARNING: Retrying (Retry(total=4, connect=None, read=None, redirect=None, status=None)) after \
connection broken by 'ReadTimeoutError(...)': /simple/scipy/
Collecting scipy>=1.11
  Downloading https://files.example/scipy-1.17.1-cp311-cp311-manylinux_2_28_x86_64.whl (35 MB)
Installing collected packages: numpy, pandas, scipy, tzdata, gnss-citygml
Successfully installed gnss-citygml-0.1.0 numpy-2.4.6 pandas-3.1.1 scipy-1.17.1 tzdata-2026.6
"""

#: ... and upgrading it in place.
UPGRADE = """Processing ./wheels/gnss_citygml-0.1.0-py3-none-any.whl
Requirement already satisfied: numpy>=1.26 in ./venv/lib/python3.11/site-packages (2.4.6)
Requirement already satisfied: tzdata in ./venv/lib/python3.11/site-packages (from pandas)
"""


def test_pips_output_as_progress():
    progress = PipProgress(expected=4)
    said = [progress.feed(line) for line in FRESH.splitlines()]
    texts = [text for text, _ in said if text]
    assert texts == [
        "collecting gnss_citygml-0.1.0 (1 of about 4)",
        "collecting numpy>=1.26 (2 of about 4)",
        "downloading numpy-2.4.6 (16.9 MB)",
        "collecting pandas>=2.1 (3 of about 4)",
        "using cached pandas-3.1.1 (12.4 MB)",
        "the package index does not answer: trying again",
        "collecting scipy>=1.11 (4 of about 4)",
        "downloading scipy-1.17.1 (35 MB)",
        "installing 5 packages: numpy, pandas, scipy, tzdata, ...",
        "installed",
    ]
    shares = [share for _, share in said if share is not None]
    assert shares == sorted(shares) and 0 < shares[0] and shares[-1] == 1.0
    assert shares[-2] == 0.75 and max(shares[:-2]) <= 0.7
    assert said[0] == (None, None)  # "Looking in indexes"
    progress = PipProgress()
    texts = [progress.feed(line)[0] for line in UPGRADE.splitlines()]
    assert texts[1:] == [
        "already there: numpy>=1.26 (2 of about 30)",
        "already there: tzdata (3 of about 30)",
    ]


#: pip's words when the package index cannot be reached (a name that does not resolve).
NO_NETWORK = """Looking in indexes: https://pypi.org/simple
Processing ./wheels/gnss_citygml-0.1.0-py3-none-any.whl
WARNING: Retrying (Retry(total=0, connect=None, read=None, redirect=None, status=None)) after \
connection broken by 'NewConnectionError('<pip._vendor.urllib3.connection.HTTPSConnection \
object at 0x7f66e11e8c90>: Failed to establish a new connection: [Errno -2] Name or service \
not known')': /simple/numpy/
ERROR: Could not find a version that satisfies the requirement numpy>=1.26 (from \
gnss-citygml==0.1.0) (from versions: none)
ERROR: No matching distribution found for numpy>=1.26
""".splitlines()


def test_pips_failures_in_one_line():
    wheel = "/plugins/gnss_citygml_qgis/wheels/gnss_citygml-0.1.0-py3-none-any.whl"
    message = pip_failure(NO_NETWORK, wheel, python="3.11")
    assert message.startswith("no network: pip could not reach the package index to download")
    assert "set HTTPS_PROXY" in message and "run Set up gnss-citygml again" in message
    assert "offline, give Set up gnss-citygml a folder of wheels" in message
    assert f'for Python 3.11 on this system, with: pip download --dest wheels "{wheel}"' in message
    assert "\n" not in message

    missing = [line for line in NO_NETWORK if line.startswith("ERROR")]
    message = pip_failure(missing, wheel, wheels="/media/usb/wheels", python="3.11")
    assert message.startswith(
        "the folder of wheels /media/usb/wheels has no numpy>=1.26 for Python 3.11 on this "
    )
    message = pip_failure(missing, "gnss-citygml==0.1.0", python="3.11")
    assert message.startswith("pip found no numpy>=1.26 for Python 3.11 on this system in ")
    assert message.endswith("with: pip download --dest wheels gnss-citygml==0.1.0)")

    other = ["Processing ./x.whl", "ERROR: Could not install packages due to an OSError: [Errno "
             "28] No space left on device"]  # fmt: skip
    assert pip_failure(other, wheel) == (
        "pip failed: Could not install packages due to an OSError: [Errno 28] No space left on "
        "device"
    )


def test_follow_passes_lines_and_cancel_stops_the_program_and_its_children(tmp_path):
    lines = []
    code, said = follow([sys.executable, "-c", "print('a'); print('b')"], lines.append, bool)
    assert code == 0 and said == lines == ["a", "b"]

    # a child that starts a grandchild, both printing: Cancel stops both
    pids = tmp_path / "pids"
    script = (
        "import os, subprocess, sys, time\n"
        "child = subprocess.Popen([sys.executable, '-c', 'import time; time.sleep(60)'])\n"
        f"open({str(pids)!r}, 'w').write(f'{{os.getpid()}} {{child.pid}}')\n"
        "print('started', flush=True)\n"
        "time.sleep(60)\n"
    )
    start = time.monotonic()
    with pytest.raises(Cancelled):
        follow([sys.executable, "-c", script], lines.append, lambda: "started" in lines)
    assert time.monotonic() - start < 20
    for pid in map(int, pids.read_text().split()):
        deadline = time.monotonic() + 10
        while _running(pid) and time.monotonic() < deadline:
            time.sleep(0.05)
        assert not _running(pid), pid


def _running(pid):
    """Whether the process ``pid`` is running (not gone, nor a zombie)."""
    try:
        with open(f"/proc/{pid}/stat") as status:
            return status.read().split(") ")[1][0] != "Z"
    except FileNotFoundError:
        return False

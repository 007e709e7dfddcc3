"""Khronos' glTF validator, run from Python: where it is installed, its install, its reports.

The official glTF 2.0 validator is a JavaScript library (the npm package ``gltf-validator``,
compiled from Dart), not a command. The package ships a small node script,
``gltf_validate.mjs``, which validates many files in one node process and prints one JSON
report per file; :func:`validate_gltf` runs it. The library is installed with npm into a cache
folder of its own (:func:`node_folder`: ``$GNSS_CITYGML_NODE_DIR``, by default
``~/.cache/gnss-citygml/node``), at the version pinned here (:data:`GLTF_VALIDATOR_VERSION`),
by :func:`install_gltf_validator`. :func:`khronos_results` runs it with what the machine
has: when node is found, installing the validator first if it is missing (npm, into that
folder), and otherwise says why it did not run, for the report.
"""

from __future__ import annotations

import contextlib
import json
import os
import shutil
import subprocess
import time
from collections.abc import Sequence
from pathlib import Path
from typing import NamedTuple

from ..errors import InputError, first_line, user_text
from ..files.paths import StrPath

__all__ = [
    "GLTF_VALIDATOR_VERSION",
    "NODE_DIR_ENV",
    "GltfMessage",
    "GltfResult",
    "gltf_validator",
    "install_gltf_validator",
    "khronos_results",
    "node_folder",
    "validate_gltf",
]

#: The version of the npm package ``gltf-validator`` installed and required.
GLTF_VALIDATOR_VERSION = "2.0.0-dev.3.10"
#: Environment variable naming the folder the validator is installed into (npm's ``--prefix``).
NODE_DIR_ENV = "GNSS_CITYGML_NODE_DIR"
#: The node script run (next to this module, shipped with the package).
SCRIPT = Path(__file__).with_name("gltf_validate.mjs")
#: Seconds an install on the fly (:func:`khronos_results`) may take: a machine with node and
#: no network falls back to the package's own checks soon.
AUTO_INSTALL_TIMEOUT = 120
#: Seconds after an install on the fly failed during which no other is tried (a machine with
#: node and no network would otherwise wait for npm at every run); the file that says when.
AUTO_INSTALL_RETRY = 24 * 3600
INSTALL_FAILED = ".install-failed"
#: Files per node process: keeps the command line well under the system's limit.
FILES_PER_RUN = 200
#: Messages kept per file (errors first); the counts are always whole.
MAX_MESSAGES = 100


class GltfMessage(NamedTuple):
    """One message of the validator: its code (``ACCESSOR_TOO_LONG``), severity (0 error,
    1 warning, 2 information, 3 hint), JSON pointer into the glTF and text."""

    code: str
    severity: int
    pointer: str
    message: str


class GltfResult(NamedTuple):
    """The validator's report on one file: counts by severity, the first messages (errors
    first, at most :data:`MAX_MESSAGES`), or why the file could not be validated at all
    (``failure``: unreadable, neither glTF nor GLB; then the counts are 0)."""

    path: Path
    n_errors: int
    n_warnings: int
    n_infos: int
    n_hints: int
    messages: list[GltfMessage]
    failure: str | None = None


def node_folder(node_dir: StrPath | None = None) -> Path:
    """The folder the validator is installed into: ``node_dir``, else ``$GNSS_CITYGML_NODE_DIR``,
    else ``gnss-citygml/node`` in the user's cache folder (``$XDG_CACHE_HOME`` or ``~/.cache``).

    >>> node_folder("/opt/validators")
    PosixPath('/opt/validators')
    """
    if node_dir is None:
        node_dir = os.environ.get(NODE_DIR_ENV) or None
    if node_dir is None:
        cache = os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache"
        return Path(cache) / "gnss-citygml" / "node"
    return Path(node_dir)


def _install_command(folder: Path) -> str:
    return f"npm install --prefix {folder} gltf-validator@{GLTF_VALIDATOR_VERSION}"


def _installed_version(folder: Path) -> str | None:
    try:
        manifest = folder / "node_modules" / "gltf-validator" / "package.json"
        return str(json.loads(manifest.read_text(encoding="utf-8")).get("version"))
    except (OSError, ValueError, AttributeError):
        return None


def gltf_validator(node_dir: StrPath | None = None) -> Path:
    """The folder holding the validator at the pinned version; an :class:`InputError` saying
    how to install it if it is not there."""
    folder = node_folder(node_dir)
    found = _installed_version(folder)
    if found == GLTF_VALIDATOR_VERSION:
        return folder
    state = "not installed" if found is None else f"installed at version {user_text(found)}"
    raise InputError(
        f"Khronos' glTF validator (npm package gltf-validator {GLTF_VALIDATOR_VERSION}) is {state}",
        where=str(folder),
        fix=f"run: {_install_command(folder)} (or call "
        "gnss_citygml.validate.install_gltf_validator(); needs Node.js and npm)",
    )


def install_gltf_validator(node_dir: StrPath | None = None, *, timeout: float = 600) -> Path:
    """Install Khronos' glTF validator with npm into :func:`node_folder` unless it is there.

    Runs ``npm install --prefix FOLDER gltf-validator@VERSION``, stopped after ``timeout``
    seconds (the npm registry must be
    reachable); returns the folder.

    Raises
    ------
    InputError
        node or npm is not found, or the install fails: the message gives the command to run.
    """
    folder = node_folder(node_dir)
    if _installed_version(folder) == GLTF_VALIDATOR_VERSION:
        return folder
    command = _install_command(folder)
    npm, node = shutil.which("npm"), shutil.which("node")
    if npm is None or node is None:
        raise InputError(
            f"{'npm' if npm is None else 'node'} not found: the glTF validator needs Node.js",
            where="PATH",
            fix=f"install Node.js (18 or later) with npm, then run: {command}",
        )
    try:
        folder.mkdir(parents=True, exist_ok=True)
        run = subprocess.run(
            [npm, "install", "--prefix", str(folder), "--no-audit", "--no-fund", "--save-exact"]
            + [f"gltf-validator@{GLTF_VALIDATOR_VERSION}"],
            capture_output=True,
            text=True,
            timeout=timeout,
        )
        reason = first_line(RuntimeError(run.stderr.strip())) if run.returncode else ""
    except (OSError, subprocess.TimeoutExpired) as exc:
        reason = first_line(exc)
    if not reason and _installed_version(folder) != GLTF_VALIDATOR_VERSION:
        reason = "npm succeeded but the package is not where expected"
    if reason:
        raise InputError(
            f"installing the glTF validator failed ({user_text(reason, 200)})",
            where=str(folder),
            fix=f"run: {command} (it needs the npm registry reachable)",
        )
    return folder


def validate_gltf(paths: Sequence[StrPath], *, node_dir: StrPath | None = None) -> list[GltfResult]:
    """Validate glTF and GLB files with Khronos' validator: one result per file, in order.

    External resources of a file (a ``.bin``, an image) are read relative to it; a URI with a
    scheme (``http:``) is refused, an error of the file (``IO_ERROR``): nothing is fetched.

    Raises
    ------
    InputError
        The validator is not installed (:func:`gltf_validator`), node is not found, or node
        fails (not a file's error: each file's own problems are in its result).
    """
    if not paths:
        return []
    folder = gltf_validator(node_dir)
    node = shutil.which("node")
    if node is None:
        raise InputError(
            "node not found: the glTF validator needs Node.js",
            where="PATH",
            fix="install Node.js (18 or later)",
        )
    results: list[GltfResult] = []
    for start in range(0, len(paths), FILES_PER_RUN):
        chunk = [Path(p) for p in paths[start : start + FILES_PER_RUN]]
        results.extend(_run(node, folder, chunk))
    return results


def khronos_results(
    paths: Sequence[StrPath], *, node_dir: StrPath | None = None, required: bool | None = None
) -> tuple[list[GltfResult] | None, str]:
    """Khronos' validator on ``paths`` if it can run, and the words a report names it by (its
    version), or None and why it did not run.

    ``required`` None: it runs when node is on the PATH, installed first into
    :func:`node_folder` if missing; an install or a node that fails is said, not raised.
    True: it must run (:func:`validate_gltf`'s errors are raised, nothing is installed).
    False: it does not run."""
    if required is False:
        return None, "not asked for"
    version = f"{GLTF_VALIDATOR_VERSION} (npm package gltf-validator, run by node)"
    if required:
        return validate_gltf(paths, node_dir=node_dir), version
    if shutil.which("node") is None:
        return None, "node not found"
    folder = node_folder(node_dir)
    if _installed_version(folder) != GLTF_VALIDATOR_VERSION:
        failed = folder / INSTALL_FAILED
        with contextlib.suppress(OSError):
            if time.time() - failed.stat().st_mtime < AUTO_INSTALL_RETRY:
                return None, (
                    f"installing it with npm failed in the last day ({user_text(failed)}); "
                    f"run: {_install_command(folder)}"
                )
        try:
            install_gltf_validator(folder, timeout=AUTO_INSTALL_TIMEOUT)
        except InputError as err:
            with contextlib.suppress(OSError):
                failed.parent.mkdir(parents=True, exist_ok=True)
                failed.write_text(f"{err.what}\n", encoding="utf-8")
            return None, f"installing it with npm failed: {err.what}; {err.fix}"
        failed.unlink(missing_ok=True)
        version += f", installed now into {folder}"
    try:
        return validate_gltf(paths, node_dir=folder), version
    except InputError as err:
        return None, f"{err.what}; {err.fix}"


def _run(node: str, folder: Path, paths: list[Path]) -> list[GltfResult]:
    """One node process validating ``paths``."""
    args = [node, str(SCRIPT), str(folder), str(MAX_MESSAGES), *map(str, paths)]
    try:
        run = subprocess.run(args, capture_output=True, text=True, check=False)
    except OSError as exc:
        run = None
        reason = first_line(exc)
    else:
        reason = first_line(RuntimeError(run.stderr.strip())) if run.returncode else ""
    lines = run.stdout.splitlines() if run is not None else []
    if not reason and len(lines) != len(paths):
        reason = f"{len(lines)} report(s) for {len(paths)} file(s)"
    if reason:
        raise InputError(
            f"the glTF validator failed ({user_text(reason, 200)})",
            where=str(SCRIPT),
            fix=f"check Node.js (18 or later) and the install in {folder} "
            f"(again: {_install_command(folder)})",
        )
    return [_result(path, json.loads(line)) for path, line in zip(paths, lines, strict=True)]


def _result(path: Path, report: dict) -> GltfResult:
    if "failure" in report:
        return GltfResult(path, 0, 0, 0, 0, [], str(report["failure"]))
    messages = [
        GltfMessage(str(m["code"]), int(m["severity"]), str(m.get("pointer") or ""), m["message"])
        for m in report["messages"]
    ]
    n = [int(report[k]) for k in ("numErrors", "numWarnings", "numInfos", "numHints")]
    return GltfResult(path, n[0], n[1], n[2], n[3], messages)

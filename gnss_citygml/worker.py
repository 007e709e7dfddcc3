"""Run one job of :mod:`gnss_citygml.jobs` for another program, in a process of its own.

The QGIS plugin runs its algorithms here rather than inside QGIS. On Linux, QGIS has its own
PROJ, GDAL and GEOS loaded into its process, and the compiled modules of the pyproj, rasterio,
pyogrio and shapely wheels would bind to those libraries instead of their own copies (the
dynamic linker looks in the process's global scope first): PROJ 9.1 refusing an option that
the wheel's PROJ knows, at best; a crash, at worst. A child Python has only the wheels' own.

``python -m gnss_citygml.worker`` reads one job as JSON on standard input::

    {"job": "observe" | "estimate" | "report" | "convert" | "validate" | "update", "args": {...}}

``args`` are the job's keyword arguments; the settings of ``estimate`` and ``report``
(``rays``, ``receiver_heights``, ``estimator``, ``position_error``, ``calibration``) are given
as dicts of their fields. It answers in JSON lines on standard output, one object each::

    {"progress": [what, done]}   {"warning": text}   {"result": {...}}   {"error": text}

An error is the command line's one-line message. SIGINT (the host's Cancel) stops the job
with ``{"error": "cancelled"}``, and like any failure leaves no output behind.
"""

from __future__ import annotations

import json
import signal
import sys
import warnings
from collections.abc import Callable, Iterable
from typing import IO, Any

from .errors import GnssCityGMLError, broken_install, escape_controls, internal_error
from .options import SETTINGS, settings_objects
from .settings import RunSettings

__all__ = ["CANCELLED", "JOBS", "main"]

#: The error of a job stopped by SIGINT.
CANCELLED = "cancelled"


Say = Callable[[dict[str, Any]], None]


def _run_settings(args: dict[str, Any], parts: Iterable[str]) -> RunSettings:
    """The run's settings, taken out of a job's ``args``: the ``parts``' arguments (as
    :func:`~gnss_citygml.options.settings_arguments` makes them), the grids and the DEM's CRS."""
    made = settings_objects({name: args.pop(name, {}) for name in parts})
    places = {name: args.pop(name) for name in ("grid_dir", "dem_crs") if name in args}
    return RunSettings.of(**made, **places)


def _observe(args: dict[str, Any], say: Say) -> dict[str, Any]:
    from .jobs import observe_file

    made = observe_file(**args, progress=_progress(say))
    return {"signals": len(made.table), "summary": made.summary()}


def _estimate(args: dict[str, Any], say: Say) -> dict[str, Any]:
    from .jobs import estimate_file

    settings = _run_settings(args, SETTINGS)
    made = estimate_file(**args, settings=settings, progress=_progress(say))
    return {"buildings": made.buildings, "converged": made.with_height}


def _report(args: dict[str, Any], say: Say) -> dict[str, Any]:
    """``estimate`` without a heights layer, into the report folder ``report`` (as
    ``gnss-citygml report``); the result names the page too."""
    from pathlib import Path

    from .report import REPORT

    made = _estimate({**args, "output": None}, say)
    return {**made, "page": str(Path(args["report"]).absolute() / REPORT)}


def _convert(args: dict[str, Any], say: Say) -> dict[str, Any]:
    from .jobs import convert_file

    result = convert_file(**args, progress=_progress(say))
    return {
        "written": result.written,
        "skipped": [[str(b), str(reason)] for b, reason in result.skipped.itertuples(index=False)],
        "validated": result.report is not None,
        "summary": result.summary(),
    }


def _validate(args: dict[str, Any], say: Say) -> dict[str, Any]:
    from .validate import validate_file

    report = validate_file(**args)
    return {
        "valid": report.valid,
        "exit_code": report.exit_code,
        "errors": [[i.object_id, i.rule, i.message, i.line()] for i in report.errors],
        "rule_counts": report.rule_counts(),
        "notes": [escape_controls(note) for note in report.notes],
        "summary": report.summary(),
    }


def _update(args: dict[str, Any], say: Say) -> dict[str, Any]:
    from .update import update_map

    settings = _run_settings(args, ("estimator",))
    result = update_map(**args, settings=settings, progress=_progress(say))
    return {
        "lines": result.lines(),
        "written": result.written,
        "backup": None if result.backup is None else str(result.backup),
        "updated": len(result.updated),
        "new_signals": result.new_signals,
    }


#: The jobs a host can ask for.
JOBS = {
    "observe": _observe,
    "estimate": _estimate,
    "report": _report,
    "convert": _convert,
    "validate": _validate,
    "update": _update,
}


def _progress(say: Say) -> Callable[[str, float], None]:
    return lambda what, done: say({"progress": [what, done]})


def run(request: dict[str, Any], say: Say) -> int:
    """Run the job ``request`` names, telling ``say`` its progress, warnings and outcome;
    return the exit status (0, or the command line's for the error)."""

    def warn(message, category, filename, lineno, file=None, line=None):
        say({"warning": escape_controls(str(message))})

    try:
        job = JOBS[request["job"]]
        with warnings.catch_warnings():
            warnings.showwarning = warn
            result = job(dict(request["args"]), say)
    except GnssCityGMLError as exc:
        say({"error": exc.one_line()})
        return exc.exit_code
    except KeyboardInterrupt:
        say({"error": CANCELLED})
        return 130
    except Exception as exc:
        broken = broken_install(exc)  # (the plugin's Python half installed: the user's side)
        say({"error": internal_error(exc) if broken is None else broken.one_line()})
        return 2
    say({"result": result})
    return 0


def main(stdin: IO[str] = sys.stdin, stdout: IO[str] = sys.stdout) -> int:
    """Read the job from ``stdin``, answer on ``stdout`` (anything else the libraries print
    goes to standard error, so that every line of ``stdout`` is one JSON object)."""
    answers = stdout
    sys.stdout = sys.stderr
    # the host's Cancel, even where the host ignores SIGINT (a process started in the
    # background, or by a desktop that ignores it, passes that on and Python then keeps it)
    signal.signal(signal.SIGINT, signal.default_int_handler)
    if hasattr(signal, "SIGBREAK"):  # Windows: the host's CTRL_BREAK stops the job as Ctrl-C
        signal.signal(signal.SIGBREAK, signal.default_int_handler)

    def say(message: dict[str, Any]) -> None:
        answers.write(json.dumps(message) + "\n")
        answers.flush()

    return run(json.load(stdin), say)


if __name__ == "__main__":
    sys.exit(main())

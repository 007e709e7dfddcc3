"""The ``gnss-citygml`` command: one click group, one thin subcommand per job.

Subcommands only parse options and compose the library's stages; each module of this package
holds the commands of one part of the pipeline. The group loads a subcommand's module only when
that subcommand is invoked (as cjio's and rio's groups do): ``--version`` and ``--help`` list
the commands from :data:`COMMANDS` and import no stage, so that they answer at once instead of
loading pandas, scipy, GDAL and PROJ first. Every
:class:`~gnss_citygml.errors.GnssCityGMLError` becomes one line on stderr
(``error: <what> (<where>): <how to fix>``) and exit code 2, never a traceback; warnings are
printed as one ``warning:`` line each. Anything else that escapes a command is a bug of the
toolkit, not a verdict on the user's data: it too ends as one ``error:`` line with exit code 2
(``GNSS_CITYGML_DEBUG=1`` shows its traceback), so that no crash reads as "invalid" (exit 1).
"""

from __future__ import annotations

import contextlib
import os
import sys
import warnings
from collections.abc import Sequence
from importlib import import_module
from typing import NoReturn

import click

from ..errors import (
    GnssCityGMLError,
    broken_install,
    escape_controls,
    internal_error,
    user_text,
)
from ..files.names import os_text

__all__ = ["COMMANDS", "LazyGroup", "cli", "main"]

#: Every subcommand: the module of this package that defines it (as a function of the same
#: name) and the first sentence of its help, which the group's ``--help`` shows without
#: importing the module (tests/test_package.py checks both against the commands themselves).
COMMANDS = {
    "convert": (
        "citymodel",
        "Turn footprints with a height attribute into CityJSON, CityJSONSeq, CityGML LOD1 or "
        "3D Tiles.",
    ),
    "demo": ("demo", "Run the main job on the bundled sample city and compare it with the truth."),
    "estimate": ("estimate", "Estimate the height of every footprint from GNSS OBSERVATIONS."),
    "export": (
        "citymodel",
        "Write the city model of a heights table (CSV or Parquet, from `heights`).",
    ),
    "grids": (
        "observe",
        "Show which copy of the OSTN15 / OSGM15 grids is used, and where it comes from.",
    ),
    "heights": (
        "heights",
        "Estimate building heights from an intersections table (CSV or Parquet).",
    ),
    "info": (
        "citymodel",
        "Print where an output came from: the version, command, settings and inputs (SHA-256).",
    ),
    "observe": (
        "observe",
        "Turn GnssLogger LOGS and satellite orbits into an observations table.",
    ),
    "partition": (
        "partition",
        "Write observations as Parquet partitioned by tile, for a run in tiles.",
    ),
    "report": (
        "estimate",
        "Estimate as `estimate` does and write the report of the run: an HTML page and PNGs.",
    ),
    "simulate": (
        "simulate",
        "Simulate a site and write the files a user brings to `estimate`: observations, "
        "footprints.gpkg and dem.tif (EPSG:27700), plus the intersections and the true heights.",
    ),
    "update": (
        "update",
        "Update a GeoPackage MAP's building heights with new GNSS observations, safely.",
    ),
    "validate": (
        "citymodel",
        "Check a CityGML 2.0, CityJSON, CityJSONSeq file or 3D Tiles tileset.json: exit 0 valid, "
        "1 invalid, 2 error.",
    ),
}


class Utf8Text(click.ParamType):
    """Text given on the command line that UTF-8 can hold. A byte of another encoding (a
    Latin-1 ``é`` typed in such a terminal), which Python holds as a surrogate escape, is an
    error naming the option: every text option ends in a UTF-8 file (a title, a layer or
    field name), where it cannot be written. Paths are not text: a file named in Latin-1 is
    read as it is."""

    name = "text"

    def convert(self, value, param, ctx):
        text = str(value)
        if os_text(text) != text:
            self.fail(
                f"'{user_text(os_text(text))}' is not UTF-8 text (a byte of another encoding, "
                "e.g. Latin-1): give it in UTF-8",
                param,
                ctx,
            )
        return text


#: The type of every text option.
UTF8_TEXT = Utf8Text()


class LazyGroup(click.Group):
    """A click group whose subcommands (:data:`COMMANDS`) are imported when first asked for."""

    def list_commands(self, ctx: click.Context | None) -> list[str]:
        return sorted(COMMANDS)

    def get_command(self, ctx: click.Context | None, cmd_name: str) -> click.Command | None:
        """The subcommand, its text options (not the paths) taking UTF-8 text only
        (:class:`Utf8Text`)."""
        if cmd_name not in COMMANDS:
            return None
        module = import_module(f".{COMMANDS[cmd_name][0]}", __name__)
        command: click.Command = getattr(module, cmd_name)
        for param in command.params:
            if type(param.type) is click.types.StringParamType:
                param.type = UTF8_TEXT
        return command

    def format_commands(self, ctx: click.Context, formatter: click.HelpFormatter) -> None:
        """The list of commands with their short help, as click writes it, from the table."""
        limit = formatter.width - 6 - max(map(len, COMMANDS))
        rows = [
            (name, click.Command(name, help=COMMANDS[name][1]).get_short_help_str(limit))
            for name in sorted(COMMANDS)
        ]
        with formatter.section("Commands"):
            formatter.write_dl(rows)


@click.group(cls=LazyGroup, context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(package_name="gnss-citygml", prog_name="gnss-citygml")
def cli() -> None:
    """3D city maps (CityGML LOD1 / CityJSON) from crowdsourced smartphone GNSS data."""


def _one_line_warning(message, category, filename, lineno, file=None, line=None):
    click.echo(f"warning: {escape_controls(str(message))}", err=True)


def _user_side(exc: Exception) -> None:
    """Exit with one line if ``exc`` is the user's side: a library that cannot be imported
    (:func:`~gnss_citygml.errors.broken_install`), or a write that failed (a full disk, a
    closed or full standard output...: :func:`gnss_citygml.files.paths.write_error`) that no writer
    turned into its own error; else return."""
    from ..files.paths import write_error

    where = getattr(exc, "filename", None) or "standard output"
    error = broken_install(exc) or write_error(exc, str(where))
    if error is None:
        return
    if where == "standard output":  # Python's flush of it at exit would fail again
        with contextlib.suppress(OSError, ValueError):
            os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
    click.echo(f"error: {error.one_line()}", err=True)
    sys.exit(error.exit_code)


def main(argv: Sequence[str] | None = None) -> NoReturn:
    """Entry point: run the click group, turning the toolkit's errors into one line."""
    warnings.showwarning = _one_line_warning
    try:
        cli.main(args=argv, prog_name="gnss-citygml", standalone_mode=False)
    except GnssCityGMLError as exc:
        click.echo(f"error: {exc.one_line()}", err=True)
        sys.exit(exc.exit_code)
    except click.exceptions.Abort:
        click.echo("aborted", err=True)
        sys.exit(1)
    except click.ClickException as exc:
        exc.show()
        sys.exit(exc.exit_code)
    except Exception as exc:
        if os.environ.get("GNSS_CITYGML_DEBUG"):
            raise
        _user_side(exc)
        click.echo(
            f"error: {internal_error(exc)} with the command that caused it "
            "(GNSS_CITYGML_DEBUG=1 shows the traceback)",
            err=True,
        )
        sys.exit(2)
    sys.exit(0)

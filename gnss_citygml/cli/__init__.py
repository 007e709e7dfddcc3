"""The ``gnss-citygml`` command: one click group, one thin subcommand per job.

Subcommands only parse options and compose the library's stages; each module of this package
holds the commands of one part of the pipeline. Every
:class:`~gnss_citygml.errors.GnssCityGMLError` becomes one line on stderr
(``error: <what> (<where>): <how to fix>``) and exit code 2, never a traceback; warnings are
printed as one ``warning:`` line each. Anything else that escapes a command is a bug of the
toolkit, not a verdict on the user's data: it too ends as one ``error:`` line with exit code 2
(``GNSS_CITYGML_DEBUG=1`` shows its traceback), so that no crash reads as "invalid" (exit 1).
"""

from __future__ import annotations

import os
import sys
import warnings

import click

from .. import __version__
from ..errors import GnssCityGMLError, escape_controls


@click.group(context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(__version__, prog_name="gnss-citygml")
def cli():
    """3D city maps (CityGML LOD1 / CityJSON) from crowdsourced smartphone GNSS data."""


from . import citymodel, estimate, models, observe  # noqa: E402  (subcommands register on cli)

__all__ = ["cli", "citymodel", "estimate", "main", "models", "observe"]


def _one_line_warning(message, category, filename, lineno, file=None, line=None):
    click.echo(f"warning: {escape_controls(str(message))}", err=True)


def main(argv=None):
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
        first = escape_controls(str(exc))[:200]
        click.echo(
            f"error: internal error, {type(exc).__name__}: {first}: please report it with the "
            "command that caused it (GNSS_CITYGML_DEBUG=1 shows the traceback)",
            err=True,
        )
        sys.exit(2)
    sys.exit(0)

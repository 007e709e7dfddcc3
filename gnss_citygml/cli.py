"""The ``gnss-citygml`` command: one click group, one thin subcommand per job.

Subcommands only parse options and compose the library's stages. Every
:class:`~gnss_citygml.errors.GnssCityGMLError` becomes one line on stderr
(``error: <what> (<where>): <how to fix>``) and exit code 2, never a traceback.
"""

from __future__ import annotations

import sys
from pathlib import Path

import click

from . import __version__
from .errors import GnssCityGMLError
from .model.estimate import METHODS
from .simulate.scenes import PRESETS

_SEED = click.option(
    "--seed",
    type=int,
    default=0,
    show_default=True,
    help="Seed of the simulation's random choices.",
)
_QUIET = click.option("--quiet", "-q", is_flag=True, help="No progress output.")
_THRESHOLD = click.option(
    "--init-threshold",
    type=float,
    default=30.0,
    show_default=True,
    help="C/N0 (dB-Hz) where the initial signal classifier gives 50 %.",
)


@click.group(context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(__version__, prog_name="gnss-citygml")
def cli():
    """3D city maps (CityGML LOD1 / CityJSON) from crowdsourced smartphone GNSS data."""


@cli.command()
@click.option(
    "--preset",
    "presets",
    multiple=True,
    type=click.Choice(list(PRESETS)),
    help="Sites to run (default: all four).",
)
@click.option(
    "--thresholds",
    default="20,25,30,35,40",
    show_default=True,
    help="Initial C/N0 thresholds, comma-separated (dB-Hz).",
)
@click.option(
    "--interval",
    type=float,
    default=5.0,
    show_default=True,
    help="Seconds between simulated epochs (1 = the paper's 1 Hz).",
)
@_SEED
@_QUIET
def demo(presets, thresholds, interval, seed, quiet):
    """Accuracy of 4PL-B and the paper's baselines on the simulated sites.

    Simulates the paper's three sites and a small city with manual and GNSS receiver
    positions, estimates the heights with every method and initial threshold, and prints the
    RMSE table of the paper ("Root Mean Square Error of mapping algorithms").
    """
    from .accuracy import markdown_table, run_accuracy, summarise

    values = _floats(thresholds, "--thresholds")
    presets = presets or tuple(PRESETS)
    n_runs = len(presets) * 2 * len(METHODS) * len(values)
    with _progress(n_runs, "fitting", quiet) as bar:
        results = run_accuracy(
            presets,
            thresholds=values,
            seed=seed,
            interval=interval,
            progress=lambda _: bar.update(1),
        )
    click.echo(markdown_table(summarise(results)))


@cli.command()
@click.argument("preset", type=click.Choice(list(PRESETS)))
@click.option(
    "--output-dir",
    "-o",
    type=click.Path(file_okay=False, path_type=Path),
    required=True,
    help="Folder for observations, intersections and truth tables.",
)
@click.option(
    "--locations",
    type=click.Choice(["manual", "gnss"]),
    default="manual",
    show_default=True,
    help="Receiver positions: hand-surveyed or the phone's fixes.",
)
@_SEED
@click.option(
    "--interval", type=float, default=1.0, show_default=True, help="Seconds between epochs."
)
@click.option(
    "--format", "fmt", type=click.Choice(["csv", "parquet"]), default="csv", show_default=True
)
def simulate(preset, output_dir, locations, seed, interval, fmt):
    """Simulate a site and write its observations, intersections and true heights."""
    from .simulate import simulate as run
    from .tables import write_table

    sim = run(preset, locations=locations, seed=seed, interval=interval)
    output_dir.mkdir(parents=True, exist_ok=True)
    for name in ("observations", "intersections", "truth"):
        write_table(getattr(sim, name), output_dir / f"{name}.{fmt}")
    click.echo(
        f"{len(sim.observations)} signals, {len(sim.intersections)} intersections, "
        f"{len(sim.truth)} buildings -> {output_dir}"
    )


@cli.command()
@click.argument("intersections", type=click.Path(path_type=Path))
@click.option(
    "--output",
    "-o",
    type=click.Path(dir_okay=False, path_type=Path),
    required=True,
    help="Heights table (.csv or .parquet).",
)
@click.option(
    "--method",
    type=click.Choice(list(METHODS)),
    default="4PL-B",
    show_default=True,
)
@_THRESHOLD
@click.option(
    "--weighting",
    type=click.Choice(["height", "balanced", "none"]),
    default=None,
    help="Reweighting of the 4PL height fit (4PL-B and 4PL; default: none).",
)
def heights(intersections, output, method, init_threshold, weighting):
    """Estimate building heights from an intersections table (CSV or Parquet)."""
    from .model.estimate import estimate_heights
    from .tables import read_table, write_table

    options = {} if weighting is None else {"weighting": weighting}
    out = estimate_heights(
        read_table(intersections), method=method, init_threshold=init_threshold, **options
    )
    write_table(out, output)
    ok = int(out["converged"].sum())
    click.echo(f"{ok} of {len(out)} buildings converged -> {output}")


def _floats(text, option):
    try:
        return [float(v) for v in text.split(",") if v.strip()]
    except ValueError:
        raise click.BadParameter(
            f"{text!r} is not a comma-separated list of numbers", param_hint=option
        ) from None


def _progress(total, label, quiet):
    from tqdm import tqdm

    return tqdm(total=total, desc=label, disable=quiet or None, file=sys.stderr, leave=False)


def main(argv=None):
    """Entry point: run the click group, turning the toolkit's errors into one line."""
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
    sys.exit(0)

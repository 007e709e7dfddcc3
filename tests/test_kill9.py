"""Kill -9 at random moments during every writer (issues 10, 45): nothing is lost or half-written.

Each writer (``estimate``, ``convert``, ``export``, ``observe`` and ``simulate``, which writes
a site of five files; and the folder outputs: a 3D Tiles ``tileset`` from ``convert``, a
``partition``, and a run's folder of ``tiles`` from ``estimate -o FOLDER``) first makes its
output completely (the *previous* output). Then the same command with other options (so that
its output differs) is run as a real process with ``--overwrite`` and killed with SIGKILL: at
the moment its output folder first changes (the start of writing, which a random delay seldom
hits) and after a delay drawn between 0 and the duration of a complete run. Afterwards every
output file must be byte-identical to the previous one or a complete, valid new one (the same
layers and features, objects or rows as a complete run of the new command), and the only
other files allowed are the hidden temporary files of the killed run (a folder output's:
``.NAME.part-…`` and ``.NAME.old-…`` folders). A folder output is compared whole: the
previous one byte for byte, or a new one holding every file its list
(:data:`~gnss_citygml.files.folders.MANIFEST`) names, each readable as a complete run's. The
rule holds per file: a site killed between two files is left mixed, some files previous and
some new (``benchmarks/kill9.py``, which runs many kills with this same machinery, counts
those).
"""

from __future__ import annotations

import contextlib
import io
import json
import os
import shutil
import signal
import subprocess
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

import geopandas as gpd
import numpy as np
import pandas as pd
import pyogrio
import pytest
import rasterio

from gnss_citygml.cli import cli, main
from gnss_citygml.files.folders import MANIFEST
from gnss_citygml.files.tables import read_table
from gnss_citygml.observations import read_observations
from gnss_citygml.validate import validate_file

EXAMPLE = Path(__file__).resolve().parents[1] / "examples" / "city"
#: Small public reference data in the repository (the Google demo log and its orbits).
DATA = Path(__file__).resolve().parent / "data"
DEMO_LOG = "google_demo_pseudoranges_log_2016_08_22_14_45_50.txt"
DEMO_ORBITS = "hour2350.16n"  # the broadcast orbits covering DEMO_LOG (tests/test_observe.py)


@dataclass(frozen=True)
class Writer:
    """A command that writes files, in two variants whose outputs differ.

    ``args`` is the command line, with ``{out}`` (the folder written to), ``{inputs}``,
    ``{example}``, ``{data}`` (tests/data: small public reference data) and ``{variant}``
    (``previous`` or ``new``) filled in; ``previous`` and ``new`` are the options that differ.
    ``outputs`` are the names of the files the command writes in ``{out}``."""

    name: str
    outputs: tuple[str, ...]
    args: tuple[str, ...]
    previous: tuple[str, ...] = ()
    new: tuple[str, ...] = ()

    def argv(self, variant: str, out: Path, places: dict) -> list[str]:
        """The command's arguments (after ``gnss-citygml``) for one variant, writing to ``out``.

        The new variant replaces the previous output: ``--overwrite`` when the command has it
        (``observe`` and ``simulate`` overwrite without it today)."""
        fill = {**places, "out": out, "variant": variant}
        args = [a.format(**fill) for a in self.args]
        extra = self.previous if variant == "previous" else self.new
        command = cli.get_command(None, self.args[0])
        has_overwrite = any(p.name == "overwrite" for p in command.params)
        overwrite = ["--overwrite"] if variant == "new" and has_overwrite else []
        return [*args, *extra, *overwrite]


#: ``estimate`` on the example city, quietly, up to its output.
ESTIMATE = (
    "estimate",
    "{example}/observations.parquet",
    "{example}/footprints.gpkg",
    "--dem",
    "{example}/dem.tif",
    "-q",
    "-o",
)

WRITERS = {
    w.name: w
    for w in [
        Writer(
            "estimate",
            ("heights.gpkg",),
            (*ESTIMATE, "{out}/heights.gpkg"),
            previous=("--min-elevation", "10"),
            new=("--min-elevation", "15"),
        ),
        Writer(
            "convert",
            ("city.gml",),
            ("convert", "{inputs}/heights_{variant}.gpkg", "-o", "{out}/city.gml", "-q"),
        ),
        Writer(
            "export",
            ("city.city.json",),
            (
                "export",
                "{inputs}/heights_{variant}.csv",
                "--footprints",
                "{example}/footprints.gpkg",
                "--dem",
                "{example}/dem.tif",
                "-o",
                "{out}/city.city.json",
                "-q",
            ),
        ),
        Writer(
            "observe",
            ("observations.parquet",),
            (
                "observe",
                f"{{data}}/gnss/{DEMO_LOG}",
                "--orbits",
                f"{{data}}/orbits/{DEMO_ORBITS}",
                "-o",
                "{out}/observations.parquet",
                "-q",
            ),
            previous=("--min-elevation", "10"),
            new=("--min-elevation", "15"),
        ),
        Writer(
            "simulate",
            ("observations.csv", "footprints.gpkg", "dem.tif", "truth.csv", "intersections.csv"),
            ("simulate", "goodchild", "-o", "{out}", "--interval", "20"),
            previous=("--seed", "0"),
            new=("--seed", "1"),
        ),
        Writer(
            "tileset",
            ("tiles",),
            ("convert", "{inputs}/heights_{variant}.gpkg", "-o", "{out}/tiles/tileset.json", "-q"),
            previous=("--no-validate",),
            new=("--no-validate",),
        ),
        Writer(
            "partition",
            ("part",),
            (
                "partition",
                "{example}/observations.parquet",
                "--dem",
                "{example}/dem.tif",
                "-q",
                "-o",
                "{out}/part",
            ),  # fmt: skip
            previous=("--min-elevation", "10"),
            new=("--min-elevation", "15"),
        ),
        Writer(
            "tiles",
            ("heights",),
            (*ESTIMATE, "{out}/heights", "--scheduler", "local", "--workers", "1"),
            previous=("--min-elevation", "10"),
            new=("--min-elevation", "15"),
        ),
    ]
}


def places(inputs: Path) -> dict:
    """The folders the writers' command lines refer to (the grids: the bundled copy)."""
    return {"example": EXAMPLE, "data": DATA, "inputs": inputs}


def run_in_process(argv: list[str]) -> None:
    """Run a command to completion in this process (no start-up cost), quietly."""
    out = io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(out):
        try:
            main(argv)
        except SystemExit as exc:
            if exc.code:
                raise RuntimeError(f"gnss-citygml {' '.join(argv)}: {out.getvalue()}") from None


def prepare_inputs(inputs: Path) -> None:
    """The inputs of ``convert`` and ``export`` in both variants: the example's footprints with
    their true heights (a GeoPackage) and the heights alone (a CSV table), as given and 2 m
    higher."""
    inputs.mkdir(parents=True, exist_ok=True)
    truth = pd.read_csv(EXAMPLE / "truth.csv")
    footprints = gpd.read_file(EXAMPLE / "footprints.gpkg")
    for variant, raise_by in (("previous", 0.0), ("new", 2.0)):
        heights = truth.assign(height=truth["height"] + raise_by)
        heights.to_csv(inputs / f"heights_{variant}.csv", index=False)
        footprints.merge(heights, on="id").to_file(inputs / f"heights_{variant}.gpkg")


def content(path: Path):
    """What a complete, valid output holds, to compare with a complete run's: the layers and
    their feature counts (GeoPackage), the objects (CityGML, CityJSON), the rows (tables),
    the cells (GeoTIFF), or a folder's files (:func:`folder_content`). Raises if the file is
    not readable or not valid."""
    name = path.name
    if path.is_dir():
        return folder_content(path)
    if name.endswith((".gml", ".city.json", ".city.jsonl")):
        report = validate_file(path)
        if not report.valid:
            raise ValueError(f"invalid: {report.errors[0]}")
        return report.format, report.n_objects  # a cut file can pass as valid with fewer
    if name.endswith(".gpkg"):
        layers = pyogrio.list_layers(path)[:, 0]
        for layer in layers:
            pyogrio.read_dataframe(path, layer=layer)  # every feature readable
        return [(layer, pyogrio.read_info(path, layer=layer)["features"]) for layer in layers]
    if name.endswith(".tif"):
        with rasterio.open(path) as dataset:
            cells = dataset.read()
        return dataset.crs.to_epsg(), cells.shape, float(np.nansum(cells))
    table = read_observations(path) if name.startswith("observations") else read_table(path)
    return list(table.columns), len(table)


def folder_content(folder: Path) -> list:
    """A folder output's files with what each holds (a table's rows, a GeoPackage's layers, a
    JSON file's keys; any other file: its size). Raises if a file its list names is missing."""
    listed = json.loads((folder / MANIFEST).read_text())["written"]
    missing = [n for n in listed if not n.endswith("/") and not (folder / n).is_file()]
    if missing:
        raise ValueError(f"missing {missing[:3]}")
    found = []
    for path in sorted(p for p in folder.rglob("*") if p.is_file() and p.name != MANIFEST):
        if path.suffix in (".parquet", ".gpkg"):
            held = content(path)
        elif path.suffix == ".json":
            held = sorted(json.loads(path.read_text()))
        else:
            held = path.stat().st_size
        found.append((path.relative_to(folder).as_posix(), held))
    return found


def read_output(path: Path) -> bytes | dict[str, bytes]:
    """A file's bytes, or a folder's files' bytes by relative path."""
    if not path.is_dir():
        return path.read_bytes()
    return {p.relative_to(path).as_posix(): p.read_bytes() for p in path.rglob("*") if p.is_file()}


def put_back(path: Path, data: bytes | dict[str, bytes]) -> None:
    """Write ``path`` (a file, or a folder whole) as :func:`read_output` read it."""
    remove(path)
    if isinstance(data, bytes):
        path.write_bytes(data)
        return
    for name, held in data.items():
        (path / name).parent.mkdir(parents=True, exist_ok=True)
        (path / name).write_bytes(held)


def remove(path: Path) -> None:
    """Remove a file or a folder, if there is one."""
    if path.is_dir() and not path.is_symlink():
        shutil.rmtree(path)
    elif os.path.lexists(path):
        os.unlink(path)


OK = ("previous", "new", "alike")  # the states an output may be left in


@dataclass
class Kill:
    """One killed run: its delay (s), whether it ended before the kill, what each output holds
    afterwards (``previous``, ``new``, ``alike`` for the bytes of both, or ``broken: why``) and
    the other files left."""

    delay: float
    ended: bool
    outputs: dict[str, str]
    left: list[str] = field(default_factory=list)

    def verdict(self) -> str:
        """``previous``, ``new``, ``mixed`` (some files previous, some new) or ``broken``."""
        states = {s if s in OK else "broken" for s in self.outputs.values()} - {"alike"}
        if "broken" in states or self.strays():
            return "broken"
        return states.pop() if len(states) == 1 else "mixed" if states else "previous"

    def temps(self) -> list[str]:
        """Files left that are the hidden temporary files of an output."""
        return [f for f in self.left if is_temp(f, self.outputs)]

    def strays(self) -> list[str]:
        """Files left that are neither an output nor a temporary file of one."""
        return [f for f in self.left if not is_temp(f, self.outputs)]


def is_temp(name: str, outputs) -> bool:
    """Whether ``name`` is a hidden temporary file of one of ``outputs``: ``.NAME.….part…``
    (``.NAME.part-HOST-PID-RANDOM.SUFFIX``, see :mod:`gnss_citygml.files.paths`), with the journal
    file SQLite may leave beside a GeoPackage, or a folder output's old folder renamed aside
    (``.NAME.old-HOST-PID-RANDOM``, :mod:`gnss_citygml.files.folders`)."""
    return any(name.startswith(f".{o}.") and (".part" in name or ".old-" in name) for o in outputs)


class Trials:
    """Kill runs of one writer in ``folder``: ``reference/`` holds a complete run of the new
    command (its duration is measured: the random kills' delays are drawn below it), ``run/``
    the previous output that every killed run tries to replace (made in this process)."""

    def __init__(self, writer: Writer, folder: Path, inputs: Path):
        self.writer = writer
        self.where = places(inputs)
        self.run, reference = folder / "run", folder / "reference"
        self.run.mkdir(parents=True)
        reference.mkdir(parents=True)
        start = time.perf_counter()
        subprocess.run(self.command("new", reference), check=True, capture_output=True)
        self.duration = time.perf_counter() - start
        self.expected = {name: content(reference / name) for name in writer.outputs}
        run_in_process(writer.argv("previous", self.run, self.where))
        self.previous = {name: read_output(self.run / name) for name in writer.outputs}
        # files both variants write alike (simulate's footprints, DEM and truth of one scene)
        self.alike = {n for n in writer.outputs if read_output(reference / n) == self.previous[n]}

    def command(self, variant: str, out: Path) -> list[str]:
        return [sys.executable, "-m", "gnss_citygml", *self.writer.argv(variant, out, self.where)]

    def restore(self, *, keep_temps: bool = False) -> None:
        """Put the previous output back and remove whatever a killed run left (but its hidden
        temporary files with ``keep_temps``)."""
        for name in os.listdir(self.run):
            if name not in self.previous and not (keep_temps and is_temp(name, self.previous)):
                remove(self.run / name)
        for name, data in self.previous.items():
            if not os.path.lexists(self.run / name) or read_output(self.run / name) != data:
                put_back(self.run / name, data)

    def start(self, *, keep_temps: bool = False) -> subprocess.Popen:
        """Restore the previous output and start the new command over it."""
        self.restore(keep_temps=keep_temps)
        return subprocess.Popen(
            self.command("new", self.run),
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
            start_new_session=True,  # (its group is killed: a cluster's workers too)
        )

    def kill(self, delay: float) -> Kill:
        """Start the new command over the previous output and SIGKILL it after ``delay`` s."""
        process = self.start()
        try:
            process.wait(timeout=delay)
            ended = True
        except subprocess.TimeoutExpired:
            ended = False
        stop(process)
        return self.inspect(delay, ended)

    def kill_when_writing(
        self, *, replaced: bool = False, keep_temps: bool = False, tries: int = 3
    ) -> Kill:
        """Start the new command and SIGKILL it as soon as its folder changes: a new file
        appears (whatever its name) or an output's inode, size or time changes. This is the
        moment that matters, which a random delay seldom hits: the writing itself. With
        ``replaced``, when the first output is replaced (its inode changes) instead. A run that
        ends before the change is seen (a busy machine) is tried again, up to ``tries`` runs."""
        for _ in range(tries):
            process = self.start(keep_temps=keep_temps)
            before = self.snapshot()
            started = time.perf_counter()
            while process.poll() is None and not self.changed(before, replaced):
                time.sleep(0.001)
            ended = process.poll() is not None
            stop(process)  # its group (nothing if it has ended)
            if not ended:
                break
        return self.inspect(time.perf_counter() - started, ended)

    def changed(self, before: dict, replaced: bool) -> bool:
        """Whether the run folder changed since ``before``, or with ``replaced`` an output."""
        now = self.snapshot()
        if not replaced:
            return now != before
        return any(now.get(o, (None,))[0] != before[o][0] for o in self.writer.outputs)

    def snapshot(self) -> dict:
        """Every file of the run folder with its inode, size and modification time."""
        files = {}
        with os.scandir(self.run) as entries:
            for entry in entries:
                with contextlib.suppress(FileNotFoundError):  # a journal file comes and goes
                    stat = entry.stat(follow_symlinks=False)
                    files[entry.name] = (stat.st_ino, stat.st_size, stat.st_mtime_ns)
        return files

    def complete_run(self) -> None:
        """Run the new command to its end over the previous output."""
        process = self.start(keep_temps=True)
        if process.wait():
            raise subprocess.CalledProcessError(process.returncode, process.args)

    def inspect(self, delay: float, ended: bool) -> Kill:
        outputs = {name: self.state(name) for name in self.writer.outputs}
        left = sorted(set(os.listdir(self.run)) - set(self.writer.outputs))
        return Kill(delay, ended, outputs, left)

    def state(self, name: str) -> str:
        path = self.run / name
        if not path.exists():
            return "broken: missing"
        if read_output(path) == self.previous[name]:
            return "alike" if name in self.alike else "previous"
        try:
            found = content(path)
        except Exception as exc:  # anything unreadable is what this test is looking for
            return f"broken: {type(exc).__name__}: {str(exc)[:200]}"
        if found != self.expected[name]:
            return f"broken: holds {found}, a complete run {self.expected[name]}"
        return "new"

    def delays(self, n: int, rng: np.random.Generator) -> np.ndarray:
        """``n`` delays between 0 and a complete run's duration, one in each of ``n`` equal
        slices (stratified: a few kills still cover the start, the work and the writing)."""
        return (np.arange(n) + rng.random(n)) * self.duration / n


def stop(process: subprocess.Popen) -> None:
    """SIGKILL a process started in a session of its own, with every process of its group
    (a local cluster's workers), and wait for it."""
    with contextlib.suppress(ProcessLookupError):
        os.killpg(process.pid, signal.SIGKILL)
    process.wait()


@pytest.fixture(scope="module")
def trials_of(tmp_path_factory):
    """The kill trials of a writer by name, set up once per module."""
    inputs = tmp_path_factory.mktemp("inputs")
    prepare_inputs(inputs)
    made = {}

    def get(name):
        if name not in made:
            made[name] = Trials(WRITERS[name], tmp_path_factory.mktemp(name), inputs)
        return made[name]

    return get


KILLS = 1  # random kills per writer in `make test` (and one while writing); the benchmark: 50


def check(kill: Kill, context: str) -> None:
    """Every output is the previous one or a complete new one, and nothing else is left under
    any name but a hidden temporary one of an output."""
    for output, state in kill.outputs.items():
        assert state in OK, f"{context}: {output} is {state}"
    assert not kill.strays(), f"{context}: left {kill.strays()}"


@pytest.mark.parametrize("name", list(WRITERS))
def test_kill9_keeps_the_previous_output_or_writes_a_complete_one(name, trials_of):
    trials = trials_of(name)
    kill = trials.kill_when_writing()
    assert not kill.ended, f"{name} ended before its output folder changed"
    check(kill, f"{name} killed as it started writing ({kill.delay:.2f} s)")
    rng = np.random.default_rng(sum(map(ord, name)))
    for delay in trials.delays(KILLS, rng):
        check(trials.kill(delay), f"{name} killed after {delay:.2f} s of {trials.duration:.2f} s")


@pytest.mark.parametrize("name", ["export", "tileset", "partition"])
def test_a_later_run_removes_the_temporary_files_of_killed_runs(name, trials_of):
    """Two runs killed while writing, then a complete run of the same command (a file, and
    folder outputs: their hidden folders of killed runs were left for ever)."""
    trials = trials_of(name)
    first = trials.kill_when_writing()
    second = trials.kill_when_writing(keep_temps=True)
    if first.ended or second.ended or not first.temps():
        pytest.fail(f"no run killed while writing: {first}, {second}")
    # After a kill, at most the temporary files of that killed run remain (gnss_citygml.files.paths
    # removes those of runs whose process is gone); after a complete run, none remain.
    assert not set(second.temps()) & set(first.temps()), "a killed run's files outlive the next"
    trials.complete_run()
    left = trials.inspect(0.0, True)
    if left.outputs != {output: "new" for output in trials.writer.outputs}:
        pytest.fail(f"a complete run did not write a complete output: {left.outputs}")
    assert not left.left, f"a complete run leaves the files of killed runs: {left.left}"

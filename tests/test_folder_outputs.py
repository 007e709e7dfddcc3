"""Folder outputs (a 3D Tiles tileset, a run's folder of tiles, a partition) from the user's
side (issue 45): an empty folder is no output that exists; ``--overwrite`` replaces what the
toolkit wrote and keeps the user's own files; a run killed at any moment of the swap leaves the
previous folder or the new one, never nothing, and its leftovers go at the next run."""

import os
import subprocess
import sys
from pathlib import Path

import pytest
from test_cli import run
from test_outputs import heights_gpkg

from gnss_citygml.errors import InputError
from gnss_citygml.files import folders
from gnss_citygml.files.folders import MANIFEST, atomic_folder, check_new_folder

CITY = Path(__file__).resolve().parents[1] / "examples" / "city"


def command(kind: str, tmp_path: Path, grid_args: list[str]) -> tuple[list[str], Path]:
    """The command line that writes a folder output of ``kind``, and the folder."""
    if kind == "tileset":
        source = heights_gpkg(tmp_path)
        return [
            "convert",
            str(source),
            "-o",
            str(tmp_path / "out" / "tileset.json"),
            "-q",
            "--no-validate",
        ], (tmp_path / "out")
    observed = [str(CITY / "observations.parquet")]
    dem = ["--dem", str(CITY / "dem.tif"), *grid_args, "-q", "-o", str(tmp_path / "out")]
    if kind == "partition":
        return ["partition", *observed, *dem], tmp_path / "out"
    tiled = ["--scheduler", "local"]
    return ["estimate", *observed, str(CITY / "footprints.gpkg"), *dem, *tiled], tmp_path / "out"


def user_files(folder: Path) -> dict[str, str]:
    """Put the user's own files in a folder output: a page and its images beside the output,
    a hidden file, a note in a folder the toolkit wrote, links to a folder and to a file."""
    outside = folder.parent / "elsewhere.txt"
    outside.write_text("outside")
    (folder / "img").mkdir()
    (folder / "img" / "logo.png").write_bytes(b"\x89PNG")
    (folder / "img" / "empty").mkdir()
    (folder / "index.html").write_text("<html>mine</html>")
    (folder / ".htaccess").write_text("Options +Indexes")
    inner = next(p for p in folder.iterdir() if p.is_dir() and p.name != "img")
    (inner / "NOTES.txt").write_text("mine too")
    os.symlink("img", folder / "pictures")
    os.symlink(outside, folder / "outside.txt")
    return {
        "img/logo.png": "\x89PNG",
        "index.html": "<html>mine</html>",
        ".htaccess": "Options +Indexes",
        f"{inner.name}/NOTES.txt": "mine too",
        "outside.txt": "outside",
    }


def kept(folder: Path, mine: dict[str, str]) -> None:
    for name, text in mine.items():
        assert (folder / name).read_bytes() == text.encode("latin-1"), name
    assert (folder / "img" / "empty").is_dir()
    assert os.readlink(folder / "pictures") == "img"
    assert (folder / "outside.txt").is_symlink()


@pytest.mark.parametrize("kind", ["tileset", "partition", "tiles"])
def test_an_empty_folder_is_new_and_overwrite_keeps_the_users_files(
    kind, tmp_path, grid_args, capsys
):
    """An existing empty folder takes the output without --overwrite (was "output exists");
    --overwrite then replaces what the toolkit wrote and keeps the user's own files, folders,
    hidden files and links (were deleted, exit 0)."""
    args, folder = command(kind, tmp_path, grid_args)
    folder.mkdir()
    code, _, err = run(args, capsys)
    assert code == 0, err
    ours = sorted(p.relative_to(folder) for p in folder.rglob("*"))
    mine = user_files(folder)
    code, _, err = run(args, capsys)
    assert code == 2 and "output exists" in err, err
    for _ in range(2):  # and again: the files kept are still the user's
        code, _, err = run([*args, "--overwrite"], capsys)
        assert code == 0, err
        kept(folder, mine)
    now = sorted(p.relative_to(folder) for p in folder.rglob("*"))
    assert set(ours) <= set(now)
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".out.")]


def test_overwrite_removes_what_the_old_output_wrote_only(tmp_path):
    """Files the old output wrote and the new one does not are gone; the user's stay."""
    out = tmp_path / "tiles"
    with atomic_folder(out, mark="index") as work:
        (work / "index").write_text("old")
        (work / "sub").mkdir()
        (work / "sub" / "old.bin").write_text("old")
    (out / "sub" / "mine.txt").write_text("mine")
    with atomic_folder(out, overwrite=True, mark="index") as work:
        (work / "index").write_text("new")
    assert sorted(p.relative_to(out).as_posix() for p in out.rglob("*")) == [
        MANIFEST,
        "index",
        "sub",
        "sub/mine.txt",
    ]
    assert (out / "index").read_text() == "new"


def test_a_users_file_the_new_output_would_replace_is_refused(tmp_path):
    out = tmp_path / "tiles"
    with atomic_folder(out, mark="index") as work:
        (work / "index").write_text("old")
    (out / "extra.bin").write_text("mine")
    with pytest.raises(InputError, match="extra.bin"):
        with atomic_folder(out, overwrite=True, mark="index") as work:
            (work / "index").write_text("new")
            (work / "extra.bin").write_text("the toolkit's now")
    assert (out / "extra.bin").read_text() == "mine" and (out / "index").read_text() == "old"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["tiles"]


def test_an_output_without_its_list_of_files_is_not_replaced(tmp_path):
    """A folder with the output's mark but no list of the files it wrote (another program's,
    or an older version's): what in it is the user's cannot be told."""
    out = tmp_path / "tiles"
    out.mkdir()
    (out / "index").write_text("old")
    (out / "index.html").write_text("mine")
    with pytest.raises(InputError, match="no list of the files"):
        check_new_folder(out, overwrite=True, mark="index")
    assert sorted(p.name for p in out.iterdir()) == ["index", "index.html"]


@pytest.mark.parametrize(
    "listing", ["[" * 100_000 + "]" * 100_000, '{"written": "tiles/"}', '{"written": [[1]]}']
)
def test_a_damaged_list_of_files_is_one_line(tmp_path, listing):
    """The folder's list of what its output wrote nested too deep for Python's JSON reader (an
    internal RecursionError before), or of another shape: one line, the folder kept."""
    out = tmp_path / "tiles"
    with atomic_folder(out, mark="index") as work:
        (work / "index").write_text("old")
    (out / MANIFEST).write_text(listing)
    with pytest.raises(InputError, match="cannot read the folder's list of the files"):
        with atomic_folder(out, overwrite=True, mark="index") as work:
            (work / "index").write_text("new")
    assert (out / "index").read_text() == "old"


def test_a_read_only_output_or_a_broken_link_is_refused(tmp_path):
    """--overwrite on a folder output made read-only (as a read-only file is refused), and a
    broken link named as the folder: one line, nothing changed (a read-only old folder could
    not be removed after the swap: left for ever)."""
    out = tmp_path / "tiles"
    with atomic_folder(out, mark="index") as work:
        (work / "index").write_text("old")
    out.chmod(0o555)
    try:
        with pytest.raises(InputError, match="read-only"):
            check_new_folder(out, overwrite=True, mark="index")
    finally:
        out.chmod(0o755)
    os.symlink(tmp_path / "gone", tmp_path / "link")
    with pytest.raises(InputError, match="broken link"):
        with atomic_folder(tmp_path / "link", mark="index"):
            pytest.fail("the block must not run")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["link", "tiles"]


#: A process that writes a folder output over an old one and dies (os._exit) at a moment of
#: the swap: ``between`` the renames (where no atomic exchange is), ``after`` the exchange.
DIE = """
import os, sys
from pathlib import Path
from gnss_citygml.files import folders
out, moment = Path(sys.argv[1]), sys.argv[2]
rename, exchange = os.rename, folders._exchange
def dying_rename(a, b):
    if Path(b) == out:
        os._exit(9)
    rename(a, b)
def dying_exchange(a, b):
    if not exchange(a, b):
        raise AssertionError("no atomic exchange here")
    os._exit(9)
if moment == "between":
    folders._exchange = lambda a, b: False
    folders.os.rename = dying_rename
else:
    folders._exchange = dying_exchange
with folders.atomic_folder(out, overwrite=True, mark="index") as work:
    (work / "index").write_text("new")
"""


@pytest.mark.parametrize("moment", ["between", "after"])
def test_a_run_killed_in_the_swap_leaves_a_folder_and_the_next_run_cleans_up(moment, tmp_path):
    out = tmp_path / "tiles"
    with atomic_folder(out, mark="index") as work:
        (work / "index").write_text("old")
    (out / "mine.txt").write_text("mine")
    env = {**os.environ, "PYTHONPATH": str(Path(folders.__file__).parents[2])}
    died = subprocess.run([sys.executable, "-c", DIE, str(out), moment], env=env)
    assert died.returncode == 9
    left = sorted(p.name for p in tmp_path.iterdir() if p.name != "tiles")
    assert left and all(n.startswith((".tiles.part-", ".tiles.old-")) for n in left), left
    if moment == "after":  # the exchange is atomic: the new folder is in place
        assert (out / "index").read_text() == "new" and (out / "mine.txt").read_text() == "mine"
    check_new_folder(out, overwrite=True, mark="index")  # the next run, as it starts
    assert sorted(p.name for p in tmp_path.iterdir()) == ["tiles"]
    assert (out / "index").read_text() == ("old" if moment == "between" else "new")
    assert (out / "mine.txt").read_text() == "mine"


def test_leftovers_of_a_live_run_or_of_another_machine_are_kept(tmp_path):
    out = tmp_path / "tiles"
    alive = tmp_path / f".tiles.part-{folders._HOST}-{os.getpid()}-0a1b2c3d"
    other = tmp_path / ".tiles.old-otherhost-1-0a1b2c3d"
    for folder in (alive, other):
        folder.mkdir()
        (folder / "index").write_text("theirs")
    check_new_folder(out, overwrite=False, mark="index")
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted([alive.name, other.name])

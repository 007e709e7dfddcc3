"""Folder outputs written whole: a 3D Tiles tileset, a run's folder of tiles, a partition.

A folder output is filled beside, under a hidden name (``.NAME.part-HOST-PID-RANDOM``), and
put in place only when complete (:func:`atomic_folder`). It lists the files it wrote in
:data:`MANIFEST`, so that ``--overwrite`` replaces those and keeps anything else the user put
in the folder (a web page beside a tileset, notes): those are hard-linked into the new folder
before the swap, so that no moment of it holds them in one place only. An empty folder is
no output yet: it takes one without ``--overwrite``.

The swap is one atomic exchange on Linux (``renameat2(RENAME_EXCHANGE)``); elsewhere the old
folder is renamed aside (``.NAME.old-HOST-PID-RANDOM``) and the new one into place. Whatever
a killed run leaves, the next run of that output puts right before it starts
(:func:`recover`): an old folder renamed aside with no folder in its place goes back, and the
hidden folders of dead processes of this machine go.
"""

from __future__ import annotations

import contextlib
import ctypes
import errno
import functools
import json
import os
import secrets
import shutil
import stat
from collections.abc import Callable, Iterator
from pathlib import Path

from ..errors import InputError, user_text
from .paths import _HOST, StrPath, _write_errors, stale_parts
from .userjson import parse_json

__all__ = ["MANIFEST", "atomic_folder", "check_new_folder", "recover", "written_files"]

#: The list of the files a folder output wrote, in the folder (hidden).
MANIFEST = ".gnss-citygml-files.json"


def check_new_folder(folder: StrPath, *, overwrite: bool, mark: str) -> Path:
    """Refuse, before any work, a folder output (written whole by :func:`atomic_folder`) that
    is a file, or exists (not empty) without ``overwrite``, or whose parent is missing; return
    it as an absolute path (a link to a folder: the folder). ``overwrite`` replaces only a
    folder an output of this kind wrote (it holds the file ``mark``, e.g. its index, and the
    list of its files): a folder name given by mistake (``-o Documents``) must not take the
    user's files with it. A killed run's leftovers are put right first (:func:`recover`)."""
    folder = Path(folder).absolute()
    if folder.is_symlink() and folder.is_dir():
        folder = Path(os.path.realpath(folder))
    recover(folder)
    if os.path.lexists(folder) and not folder.is_dir():
        raise InputError(
            "the output folder is a file (or a broken link)", where=str(folder), fix="give a folder"
        )
    if not folder.parent.is_dir():
        raise InputError(
            "output folder does not exist", where=str(folder.parent), fix="create it first"
        )
    if _empty(folder):
        return folder
    if not overwrite:
        raise InputError(
            "output exists", where=str(folder), fix="give another folder, or --overwrite"
        )
    refusal = _not_replaced(folder, mark)
    if refusal is not None:
        raise InputError(refusal[0], where=str(folder), fix=refusal[1])
    return folder


def _not_replaced(folder: Path, mark: str) -> tuple[str, str] | None:
    """Why ``--overwrite`` may not replace ``folder`` (no output of this kind, or one that
    does not list what it wrote), and the fix; None if it may."""
    if not (folder / mark).is_file():
        return (
            f"the folder holds files this output did not write (it has no {mark}), and "
            "--overwrite replaces only such an output",
            "give a new folder, or empty this one",
        )
    if not (folder / MANIFEST).is_file():
        return (
            f"the folder has no list of the files its output wrote ({MANIFEST}: another "
            "program's, or an older version's), so what in it is yours cannot be told",
            "move what you want to keep out of it and remove it, or give a new folder",
        )
    if not os.access(folder, os.W_OK) or not folder.stat().st_mode & 0o222:  # (root: the bits)
        return (
            "the output folder is read-only",
            "make it writable (chmod u+w) if it may be replaced, or give a new folder",
        )
    return None


def _empty(folder: Path) -> bool:
    """Whether ``folder`` is missing or an empty folder."""
    try:
        with os.scandir(folder) as entries:
            return next(entries, None) is None
    except FileNotFoundError:
        return True


@contextlib.contextmanager
def atomic_folder(folder: StrPath, *, overwrite: bool = False, mark: str) -> Iterator[Path]:
    """Yield a new folder beside ``folder`` to fill; put it in place of ``folder`` if the
    block succeeds, else remove it. An old ``folder`` is replaced (with ``overwrite``, and
    only an output of this kind: :func:`check_new_folder`) only once the new one is complete,
    keeping the files in it that the old output did not write (:func:`_keep_theirs`)."""
    folder = check_new_folder(folder, overwrite=overwrite, mark=mark)
    work = _hidden(folder, "part")
    try:
        work.mkdir()
    except OSError as exc:
        raise InputError(
            "cannot write to the output folder",
            where=str(folder.parent),
            fix=f"check its permissions and free space ({exc.strerror})",
        ) from None
    try:
        with _write_errors(folder, work):
            yield work
            _write_manifest(work, mark)
            _put_in_place(work, folder, overwrite, mark)
    finally:
        _remove(work)


def _put_in_place(work: Path, folder: Path, overwrite: bool, mark: str) -> None:
    """Put the complete ``work`` in place of ``folder``: a rename where there is none (or an
    empty one: a rename fails if another run filled it meanwhile), else the swap."""
    if _empty(folder):
        with contextlib.suppress(FileNotFoundError):
            os.chmod(work, stat.S_IMODE(folder.stat().st_mode))
        try:
            os.rename(work, folder)
            return
        except OSError as exc:
            if exc.errno not in (errno.ENOTEMPTY, errno.EEXIST):
                raise
    if not overwrite:
        raise InputError(
            "output exists (another run wrote it meanwhile)",
            where=str(folder),
            fix="give another folder, or --overwrite",
        )
    check_new_folder(folder, overwrite=True, mark=mark)  # (still an output of this kind?)
    _keep_theirs(folder, work, _written(folder))
    os.chmod(work, stat.S_IMODE(folder.stat().st_mode))
    _remove(_swap(work, folder))


def _write_manifest(work: Path, mark: str) -> None:
    """List every file and folder in ``work`` (its relative path; a folder's ends in ``/``)."""
    names = []
    for root, dirs, files in os.walk(work):
        here = Path(root).relative_to(work)
        names += [(here / d).as_posix() + "/" for d in dirs]
        names += [(here / f).as_posix() for f in files]
    record = {"format": "gnss-citygml folder", "mark": mark, "written": sorted(names)}
    (work / MANIFEST).write_text(json.dumps(record, indent=0))


def written_files(folder: StrPath) -> set[str] | None:
    """What the output in ``folder`` wrote, as its :data:`MANIFEST` lists it (None: the folder
    has no such list, an older version's output)."""
    folder = Path(folder)
    return _written(folder) if (folder / MANIFEST).is_file() else None


def _written(folder: Path) -> set[str]:
    """What the output in ``folder`` wrote, as its :data:`MANIFEST` lists it."""
    try:
        record = parse_json((folder / MANIFEST).read_bytes())
        names = record["written"] if isinstance(record, dict) else None
        if not isinstance(names, list) or not all(isinstance(n, str) for n in names):
            raise ValueError("not a list of names under 'written'")
        return set(names)
    except (OSError, ValueError, KeyError) as exc:  # (NotJSON is a ValueError)
        raise InputError(
            f"cannot read the folder's list of the files its output wrote ({exc})",
            where=str(folder / MANIFEST),
            fix="move what you want to keep out of the folder and remove it, or give a new one",
        ) from None


def _keep_theirs(
    old: Path, new: Path, ours: set[str], under: str = "", everything: bool = False
) -> None:
    """Hard-link (else copy) into ``new`` every file, link and folder of ``old`` that its
    output did not write (not in ``ours``; all that is in ``under`` with ``everything``): the
    user's own. A name the new output wrote too is refused: both cannot be kept."""
    for entry in sorted(os.scandir(old / under), key=lambda e: e.name):
        name = f"{under}{entry.name}"
        target = new / name
        if name == MANIFEST:
            continue
        if entry.is_dir(follow_symlinks=False):
            theirs = everything or f"{name}/" not in ours
            if theirs and not target.is_dir():
                _refuse_clash(target, name, old)
                target.mkdir()
                shutil.copystat(entry.path, target)
            _keep_theirs(old, new, ours, f"{name}/", theirs)
        elif everything or name not in ours:
            _refuse_clash(target, name, old)
            target.parent.mkdir(parents=True, exist_ok=True)  # (a folder only the old wrote)
            _link(Path(entry.path), target)


def _refuse_clash(target: Path, name: str, old: Path) -> None:
    if os.path.lexists(target):
        raise InputError(
            f"the new output writes {user_text(name)!r}, which is a file of yours in the "
            "folder (its output did not write it)",
            where=str(old),
            fix="move that file out of the folder, or give a new folder",
        )


def _link(source: Path, target: Path) -> None:
    """``source`` as ``target``: a link made again (to where it points), a file hard-linked
    (else, on a file system without hard links, copied)."""
    if source.is_symlink():
        os.symlink(os.readlink(source), target)
        return
    try:
        os.link(source, target)
    except OSError as exc:
        if exc.errno not in (errno.EXDEV, errno.EPERM, errno.ENOTSUP, errno.EMLINK):
            raise
        shutil.copy2(source, target)


def _swap(work: Path, folder: Path) -> Path:
    """Put ``work`` in place of ``folder``; return where the old folder went. An atomic
    exchange where the system has one; else the old is renamed aside first (a killed run
    leaves it there, and :func:`recover` puts it back)."""
    if _exchange(work, folder):
        return work
    aside = _hidden(folder, "old")
    os.rename(folder, aside)
    os.rename(work, folder)
    return aside


@functools.cache
def _renameat2() -> Callable[..., int] | None:
    """Linux's renameat2 from the C library, or None."""
    try:
        return ctypes.CDLL(None, use_errno=True).renameat2
    except (OSError, AttributeError, TypeError):
        return None


def _exchange(a: Path, b: Path) -> bool:
    """Exchange the folders ``a`` and ``b`` atomically; False where the system (or the file
    system) cannot."""
    call = _renameat2()
    if call is None:
        return False
    here, exchange = -100, 2  # AT_FDCWD, RENAME_EXCHANGE
    if call(here, os.fsencode(a), here, os.fsencode(b), exchange) == 0:
        return True
    code = ctypes.get_errno()
    if code in (errno.EINVAL, errno.ENOSYS, errno.ENOTSUP, errno.EOPNOTSUPP):
        return False
    raise OSError(code, os.strerror(code), str(b))


def recover(folder: StrPath) -> None:
    """Put right what killed runs of the output ``folder`` on this machine left: an old
    folder renamed aside with none in its place goes back (the newest, if several), and the
    other hidden folders of dead processes (``.NAME.part-*``, ``.NAME.old-*``) go: each is
    renamed as this process's first, so that a kill while it is removed leaves it to the next
    run again, not for ever."""
    folder = Path(folder)
    aside = sorted(stale_parts(folder, kind="old"), key=lambda p: p.lstat().st_ctime_ns)
    if aside and not os.path.lexists(folder):
        with contextlib.suppress(OSError):
            os.rename(aside.pop(), folder)
    for stale in [*aside, *stale_parts(folder)]:
        with contextlib.suppress(OSError):  # (taken over first: killed meanwhile, ours is left)
            os.rename(stale, taken := _hidden(folder, "part"))
            _remove(taken)


def _hidden(folder: Path, kind: str) -> Path:
    """A new hidden name beside ``folder`` that says which host and process made it, so that
    a later run can tell a dead process's (:func:`~gnss_citygml.files.paths.stale_parts`)."""
    return folder.with_name(f".{folder.name}.{kind}-{_HOST}-{os.getpid()}-{secrets.token_hex(4)}")


def _remove(path: Path) -> None:
    """Remove a folder with what it holds (links are not followed), or a file."""
    if path.is_dir() and not path.is_symlink():
        shutil.rmtree(path, ignore_errors=True)
    else:
        with contextlib.suppress(FileNotFoundError):
            path.unlink()

"""The files a user names: checks on inputs and outputs, and atomic writing.

A missing file, a folder where a file is meant, or a file that cannot be opened each get their
own one-line error, named the same way everywhere. Outputs are checked before any work starts
(:func:`check_output`) and written through :func:`atomic_path`: to a temporary file beside the
output, renamed into place only when complete, so that a failed or killed run never leaves a
half-written file under the output's name and never replaces what it must not.
"""

from __future__ import annotations

import contextlib
import errno
import gzip
import hashlib
import io
import os
import re
import secrets
import shutil
import socket
from collections.abc import Iterable, Iterator
from pathlib import Path
from typing import BinaryIO, TypeAlias

from ..errors import InputError

__all__ = [
    "StrPath",
    "atomic_path",
    "check_output",
    "check_output_folder",
    "file_digest",
    "gunzipped",
    "check_not_input",
    "input_file",
    "make_folder",
    "same_file",
    "stale_parts",
    "write_error",
]

#: A file or folder a caller names: a string or any path-like object (:class:`~pathlib.Path`).
StrPath: TypeAlias = str | os.PathLike[str]


def input_file(path: StrPath, what: str = "file") -> Path:
    """``path`` as a :class:`~pathlib.Path` if it is a readable file, else an :class:`InputError`.

    ``what`` names the file in the message (``"orbit file"``, ``"footprint file"``...).

    >>> input_file(".", "orbit file")
    Traceback (most recent call last):
    ...
    gnss_citygml.errors.InputError: orbit file is a folder, not a file (.): give the file's path
    """
    path = Path(path)
    if path.is_dir():
        raise InputError(
            f"{what} is a folder, not a file", where=str(path), fix="give the file's path"
        )
    if not path.exists():
        raise InputError(f"{what} not found", where=str(path), fix="check the path")
    if not os.access(path, os.R_OK):
        raise InputError(f"{what} is not readable", where=str(path), fix="check its permissions")
    return path


#: A gzipped input may expand to this many times its size: text and XML compress 5 to 30
#: times (an OS MasterMap tile about 15), a decompression bomb up to gzip's 1,032.
MAX_EXPANSION = 100
#: Bytes a gzipped input may always expand to, whatever its ratio (small, very regular files).
FREE_EXPANSION = 64 * 2**20


@contextlib.contextmanager
def gunzipped(path: StrPath, what: str = "file") -> Iterator[BinaryIO]:
    """A gzipped input opened for reading as a stream, which stops with an
    :class:`InputError` (naming the file, the ratio and the way round it) once it has given
    more than ``MAX_EXPANSION`` times the file's size (and more than ``FREE_EXPANSION``): a
    0.8 MB file that expands to 600 MB is a decompression bomb, not a map or an orbit file.
    Readers stream it (memory stays that of a buffer), so a large legitimate file costs
    nothing more than its reading."""
    path = Path(path)
    limit = max(FREE_EXPANSION, MAX_EXPANSION * path.stat().st_size)
    with gzip.open(path, "rb") as inner:
        yield io.BufferedReader(_Capped(inner, limit, path, what))


class _Capped(io.RawIOBase):
    """A binary stream that refuses to give more than ``limit`` bytes (:func:`gunzipped`)."""

    def __init__(self, inner: gzip.GzipFile, limit: int, path: Path, what: str):
        self.inner, self.limit, self.path, self.what, self.given = inner, limit, path, what, 0

    def readable(self) -> bool:
        return True

    def readinto(self, buffer) -> int:
        n = self.inner.readinto(buffer)
        self.given += n
        if self.given > self.limit:
            size = self.path.stat().st_size
            raise InputError(
                f"the gzipped {self.what} expands more than {MAX_EXPANSION} times its size"
                f" ({size} bytes to over {self.given}, past the limit of {self.limit}):"
                " a decompression bomb?",
                where=str(self.path),
                fix="if it is genuine, decompress it yourself (gzip -dk FILE) and give that",
            )
        return n


def file_digest(path: StrPath) -> tuple[int, str]:
    """The size and SHA-256 (hex) of a file, read in blocks."""
    digest = hashlib.sha256()
    size = 0
    with open(path, "rb") as file:
        while block := file.read(1 << 20):
            digest.update(block)
            size += len(block)
    return size, digest.hexdigest()


def same_file(a: object, b: object) -> bool:
    """Whether the paths ``a`` and ``b`` name one file (or folder) that exists: the same inode,
    reached by whatever spelling, symbolic link or hard link. Anything that is not a path
    (None, ``-``, a table in memory) names no file."""
    try:
        return os.path.samefile(a, b)  # type: ignore[arg-type]
    except (OSError, TypeError, ValueError):
        return False


def _spellings(path: StrPath) -> set[Path]:
    """``path`` as an absolute path, as given and with its links resolved."""
    return {Path(os.path.abspath(path)), Path(os.path.realpath(path))}


def _within(inner: StrPath, outer: StrPath) -> bool:
    """Whether ``inner`` is ``outer`` or lies in the folder ``outer`` (by any spelling)."""
    return any(
        a == b or b in a.parents for a in _spellings(inner) for b in _spellings(outer)
    ) or same_file(inner, outer)


def check_not_input(
    output: StrPath, inputs: Iterable[object], *, what: str = "output", folders: bool = True
) -> None:
    """Refuse, before any work, an output that would write over one of the command's
    ``inputs``: the same file by any spelling (``./x``, a relative path, a symbolic or hard
    link), a folder output that holds an input (it is replaced whole), or an output inside
    an input that is a folder (a partition, a folder of GeoParquet; ``folders=False``: the
    inputs are files, and their reader says when one is a folder). ``inputs`` may hold None
    and objects that are not paths (a DEM already open): they are no file."""
    if str(output) == "-":
        return
    for given in inputs:
        if not isinstance(given, str | os.PathLike) or str(given) in ("", "-"):
            continue
        if not os.path.exists(given):  # (a GDAL path such as zip://...!/x.asc: never written)
            continue
        if _within(given, output):
            if same_file(given, output):
                problem = f"would replace the input {given}"
            else:
                problem = f"is a folder that holds the input {given}, which it would replace"
        elif folders and os.path.isdir(given) and _within(output, given):
            problem = f"is inside the input folder {given}, which writing it would change"
        else:
            continue
        raise InputError(f"the {what} {problem}", where=str(output), fix="write to another name")


def check_output(
    path: StrPath,
    *,
    overwrite: bool,
    suffixes: tuple[str, ...] | None = None,
    exists_ok: bool = False,
) -> Path:
    """Check that ``path`` can be written, before the work that makes it starts.

    Parameters
    ----------
    path
        The output file.
    overwrite
        An existing output may be replaced (the user said ``--overwrite``).
    suffixes
        The endings the writer understands (e.g. ``(".gpkg", ".fgb")``); None: any.
    exists_ok
        An existing file is no error even without ``overwrite`` (a GeoPackage that gets a new
        layer; the caller checks the layer).

    Raises
    ------
    InputError
        An unknown suffix, a missing or read-only folder, a folder named as the output, an
        existing output without ``overwrite``, or a read-only existing output.
    """
    path = Path(path)
    name = path.name.lower()
    if suffixes is not None and not name.endswith(tuple(suffixes)):
        raise InputError(
            f"unknown output format {path.suffix or '(no suffix)'!r}",
            where=str(path),
            fix="name the output " + ", ".join(suffixes),
        )
    folder = path.parent
    if not folder.is_dir():
        raise InputError("output folder does not exist", where=str(folder), fix="create it first")
    if not os.access(folder, os.W_OK | os.X_OK):
        raise InputError(
            "cannot write to the output folder", where=str(folder), fix="check its permissions"
        )
    if path.is_dir():
        raise InputError("output is a folder", where=str(path), fix="give a file name")
    if path.exists():
        if not (overwrite or exists_ok):
            raise InputError(
                "output exists", where=str(path), fix="choose another name or --overwrite"
            )
        if not os.access(path, os.W_OK) or not path.stat().st_mode & 0o222:  # root ignores bits
            raise InputError(
                "output is read-only",
                where=str(path),
                fix="make it writable (chmod u+w) if it may be replaced, or choose another name",
            )
    return path


#: Why a write fails on the user's side, by errno: what happened and how to fix it.
_WRITE_ERRNOS = {
    errno.ENOSPC: ("no space left on the device", "free some space, or write to another disk"),
    errno.EDQUOT: ("the disk quota is used up", "free some space, or write to another disk"),
    errno.EFBIG: (
        "the file is too large for the file system or for the limit on file sizes (ulimit -f)",
        "write to another disk, or raise the limit",
    ),
    errno.EROFS: ("the file system is read-only", "write to another place"),
    errno.EACCES: ("permission denied", "check the permissions, or write to another place"),
    errno.EPERM: ("permission denied", "check the permissions, or write to another place"),
    errno.EIO: ("the disk could not be written (I/O error)", "check the disk, or write elsewhere"),
    errno.EPIPE: ("the reader closed the stream", "let the reader take all of it"),
}

#: The same causes as SQLite and GDAL word them in their own errors (which carry no errno).
_WRITE_MESSAGES = {
    "database or disk is full": errno.ENOSPC,
    "no space left on device": errno.ENOSPC,
    "disk quota exceeded": errno.EDQUOT,
    "file too large": errno.EFBIG,
    "read-only file system": errno.EROFS,
    "attempt to write a readonly database": errno.EROFS,
    "disk i/o error": errno.EIO,
}


def write_error(
    exc: BaseException, where: str, written: StrPath | None = None
) -> InputError | None:
    """The one-line error for a write that failed on the user's side (a full disk, a quota,
    a limit on file sizes, a read-only file system, a closed pipe...), or None when ``exc``
    is not one (a bug, to be reported as such). ``exc``, its causes and its context are
    looked at: Python's OSError by its errno, SQLite's and GDAL's errors by their message.
    GDAL may lose the cause on its way (a GeoPackage on a full disk fails later with "no
    such table"), and SQLite words a file size limit as an I/O error: with ``written``, the
    file being written when ``exc`` came, a failure on a disk with no room left, or of a file
    grown to the limit on file sizes, is taken as that."""
    code = _cause(exc)
    if code in (None, errno.EIO) and written is not None:  # (SQLite's word for EFBIG: EIO)
        code = _at_limit(Path(written)) or code
    if code is None:
        return None
    what, fix = _WRITE_ERRNOS[code]
    return InputError(f"cannot write: {what}", where=where, fix=fix)


def _cause(exc: BaseException | None) -> int | None:
    """The errno of :data:`_WRITE_ERRNOS` that ``exc`` or an exception behind it says."""
    seen: set[int] = set()
    while exc is not None and id(exc) not in seen:
        seen.add(id(exc))
        code = exc.errno if isinstance(exc, OSError) else None
        if code not in _WRITE_ERRNOS:
            text = str(exc).lower()
            code = next((n for m, n in _WRITE_MESSAGES.items() if m in text), None)
        if code is not None:
            return code
        exc = exc.__cause__ or exc.__context__
    return None


def _at_limit(written: Path) -> int | None:
    """ENOSPC if the disk of ``written`` has (almost) no room left, EFBIG if the file has
    grown to the process's limit on file sizes; else None."""
    import resource

    with contextlib.suppress(OSError):
        disk = os.statvfs(written.parent)
        if disk.f_bavail * disk.f_frsize < 1 << 20:
            return errno.ENOSPC
    limit = resource.getrlimit(resource.RLIMIT_FSIZE)[0]
    with contextlib.suppress(OSError):
        if limit != resource.RLIM_INFINITY and written.stat().st_size >= limit - (1 << 16):
            return errno.EFBIG
    return None


_HOST = re.sub(r"[^A-Za-z0-9-]", "-", socket.gethostname())[:32] or "host"


def _part_prefix(path: Path) -> str:
    return f".{path.name}.part-"


def stale_parts(path: StrPath, kind: str = "part") -> list[Path]:
    """Temporary files of ``path`` left by killed runs of this machine whose process is gone.

    A temporary file is named ``.NAME.part-HOST-PID-RANDOM.SUFFIX`` so that a later run can
    tell whether its writer still runs: files of another host are never touched (the folder
    may be shared), nor those of a live process. ``kind``: ``old`` for the old folders a
    folder output renames aside (:mod:`gnss_citygml.files.folders`)."""
    path = Path(path)
    prefix = f".{path.name}.{kind}-"
    pattern = re.compile(re.escape(prefix) + re.escape(_HOST) + r"-(\d+)-[0-9a-f]+")
    stale = []
    with contextlib.suppress(OSError):
        for entry in os.scandir(path.parent if str(path.parent) else "."):
            match = pattern.match(entry.name)
            if match and not _alive(int(match.group(1))):
                stale.append(Path(entry.path))
    return stale


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except OSError:  # e.g. another user's process: alive
        return True
    return True


def check_output_folder(
    folder: StrPath,
    files: list[Path],
    *,
    overwrite: bool,
    what: str = "output folder",
    inputs: Iterable[object] = (),
) -> None:
    """Check a folder that a command fills with ``files``, before the work: a file named as
    the folder is an error; in an existing folder each file is checked (:func:`check_output`,
    and none may be one of the command's ``inputs``: :func:`check_not_input`). A missing
    folder is fine: :func:`make_folder` creates it when the writing starts."""
    folder = Path(folder)
    if folder.exists() and not folder.is_dir():
        raise InputError(f"the {what} is a file", where=str(folder), fix="give a folder")
    for path in files:
        if folder.is_dir():
            check_output(path, overwrite=overwrite)
        check_not_input(path, inputs)


def make_folder(folder: StrPath) -> Path:
    """``folder``, created with its parents if missing, or a one-line error saying why not."""
    folder = Path(folder)
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise InputError(
            "cannot create the output folder",
            where=str(folder),
            fix=f"check the path and its permissions ({exc.strerror})",
        ) from None
    return folder


@contextlib.contextmanager
def atomic_path(path: StrPath, *, overwrite: bool = True, update: bool = False) -> Iterator[Path]:
    """Yield a temporary path beside ``path``; put it in place of ``path`` if the block succeeds.

    Parameters
    ----------
    path
        The output file.
    overwrite
        Replace an existing ``path``. Without it the result is put in place with a hard link,
        which fails if ``path`` appeared meanwhile (another run wrote it): the check holds at
        the moment of the rename, not only when writing starts.
    update
        Start from a copy of the existing ``path`` (a GeoPackage that gets a layer), and refuse
        to put it in place if ``path`` changed while the block ran.

    Notes
    -----
    The temporary file keeps the output's suffix (GDAL's drivers check it) and its name says
    which host and process write it; temporary files of this output left by killed runs are
    removed first (:func:`stale_parts`). A replaced file's permission bits are kept; a new one
    gets the usual ``0o666`` less the umask.
    """
    path = check_output(path, overwrite=overwrite, exists_ok=update)
    for stale in stale_parts(path):
        with contextlib.suppress(OSError):
            stale.unlink()
    folder = path.parent
    tmp = folder / f"{_part_prefix(path)}{_HOST}-{os.getpid()}-{secrets.token_hex(4)}{path.suffix}"
    before = _identity(path) if update else None
    try:
        if before is not None:
            shutil.copyfile(path, tmp)
        else:
            os.close(os.open(tmp, os.O_CREAT | os.O_EXCL | os.O_WRONLY, 0o600))
    except OSError as exc:
        _remove(tmp)
        raise InputError(
            "cannot write to the output folder",
            where=str(folder),
            fix=f"check its permissions and free space ({exc.strerror})",
        ) from None
    try:
        with _write_errors(path, tmp):
            yield tmp
            current = _identity(path)
            mode = current[3] if current is not None else 0o666 & ~_umask()
            os.chmod(tmp, mode & 0o7777)
            if before is not None and current != before:
                raise InputError(
                    "output changed while this run was writing it",
                    where=str(path),
                    fix="run again once the other program has finished with it",
                )
            if overwrite or before is not None:
                os.replace(tmp, path)
            else:
                _link_new(tmp, path)
    finally:
        _remove(tmp)


def _remove(tmp: Path) -> None:
    """Remove a temporary file and what SQLite may have left beside it (a journal that a
    failed write could not roll back)."""
    for name in (tmp, *(tmp.with_name(tmp.name + side) for side in ("-journal", "-wal", "-shm"))):
        with contextlib.suppress(FileNotFoundError):
            os.unlink(name)


@contextlib.contextmanager
def _write_errors(path: Path, written: Path) -> Iterator[None]:
    """Turn a write of ``path`` (into ``written``) that fails on the user's side
    (:func:`write_error`) into its one-line error; anything else goes on as it is."""
    try:
        yield
    except InputError:
        raise
    except Exception as exc:
        error = write_error(exc, str(path), written)
        if error is None:
            raise
        raise error from None


def _identity(path: Path) -> tuple[int, int, int, int, int] | None:
    """(device, inode, mtime, mode, size) of ``path``, or None if there is none."""
    try:
        st = os.stat(path)
    except FileNotFoundError:
        return None
    return st.st_dev, st.st_ino, st.st_mtime_ns, st.st_mode, st.st_size


def _link_new(tmp: Path, path: Path) -> None:
    """Put ``tmp`` at ``path`` only if nothing is there, atomically where links exist."""
    try:
        os.link(tmp, path)
    except FileExistsError:
        raise InputError(
            "output exists (another run wrote it meanwhile)",
            where=str(path),
            fix="choose another name or --overwrite",
        ) from None
    except OSError as exc:
        if exc.errno not in (errno.EPERM, errno.EOPNOTSUPP, errno.ENOTSUP, errno.EMLINK):
            raise
        # a file system without hard links (FAT, some network shares): check, then rename
        if path.exists():
            raise InputError(
                "output exists", where=str(path), fix="choose another name or --overwrite"
            ) from None
        os.replace(tmp, path)


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask

"""Reading and writing files the way a robot's executive must: never blocking on a FIFO,
never reading without a bound, never writing half a file or through a symbolic link.

* :func:`read_regular` reads a regular file (never blocking on a FIFO: see
  :func:`~executive.core.problems.open_regular`) and at most ``limit`` bytes of it: a
  larger file is refused after ``limit + 1`` bytes, whatever its size claims.
* :func:`write_atomic` writes a temporary file beside the target (created exclusively,
  never following a link) and renames it over the target: a reader sees the old file or
  the new one, never a torn one, and a symbolic link at the target is replaced, not
  followed. On any error (a full disk) the temporary file is removed and the target is
  left as it was.
* :func:`output_dir_problem` says, before any work, why a directory cannot take a
  report (an existing file, not writable, a pseudo file system).
"""

from __future__ import annotations

import contextlib
import errno
import os
import stat
import tempfile
from collections.abc import Callable
from pathlib import Path

from executive.core.problems import NotRegularFileError, open_regular

PSEUDO_FILESYSTEMS = ("/proc", "/sys", "/dev")
"""Trees whose entries are not files: never a place for a report."""


class UnusableFileError(Exception):
    """A file that cannot be used, with a message for the user (no traceback)."""


def describe_os_error(exc: OSError, path: Path | str, doing: str = "writing") -> str:
    """A one-line reason, naming a full disk as such."""
    if exc.errno in (errno.ENOSPC, errno.EDQUOT):
        return f"disk full while {doing} {path}"
    return f"cannot {doing.removesuffix('ing')} {path}: {exc.strerror or exc}"


def read_regular(path: Path | str, limit: int) -> bytes:
    """The content of the regular file at ``path``, at most ``limit`` bytes.

    Opened with :func:`~executive.core.problems.open_regular` (never blocking, checked
    on the open descriptor). Raises :class:`UnusableFileError` for a missing file, a
    directory, FIFO, device or socket, a file larger than ``limit``, or an OS error;
    returns at once in every case.
    """
    try:
        with open_regular(path) as handle:
            data = handle.read(limit + 1)
    except FileNotFoundError:
        raise UnusableFileError(f"{path}: file not found") from None
    except NotRegularFileError as exc:
        raise UnusableFileError(f"{path}: is {exc.strerror}, not a regular file") from None
    except OSError as exc:
        raise UnusableFileError(f"{path}: cannot read: {exc.strerror or exc}") from None
    if len(data) > limit:
        raise UnusableFileError(f"{path}: larger than the {limit} bytes allowed")
    return data


def write_atomic(path: Path, data: bytes) -> None:
    """Replace ``path`` with ``data`` in one rename (see the module docstring).

    Raises :class:`OSError` (the target untouched) when the data cannot be written; its
    ``filename`` is ``path`` (a full disk raises from ``write`` with no file name, and the
    temporary file's name would mean nothing to the user).
    """
    try:
        _write_atomic(path, data)
    except OSError as exc:
        exc.filename = str(path)
        raise


def _write_atomic(path: Path, data: bytes) -> None:
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    flags = os.O_WRONLY | os.O_CREAT | os.O_EXCL | getattr(os, "O_NOFOLLOW", 0)
    with contextlib.suppress(FileNotFoundError):
        os.unlink(tmp)  # left by a process of the same pid that was killed mid-write
    fd = os.open(tmp, flags, 0o644)
    try:
        view = memoryview(data)
        while view:
            written = os.write(fd, view)
            view = view[written:]
        os.fsync(fd)
    except BaseException:
        os.close(fd)
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        raise
    os.close(fd)
    try:
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        raise


def produce_atomic(path: Path, produce: Callable[[Path], object]) -> None:
    """Let ``produce`` write a file (a drawing library that wants a path) at a fresh
    temporary name beside ``path``, then rename it over ``path``: the same guarantees as
    :func:`write_atomic` (whole or nothing; a symbolic link at ``path`` is replaced, not
    followed)."""
    folder = tempfile.mkdtemp(prefix=f".{path.name}.", dir=path.parent)
    tmp = Path(folder) / path.name
    try:
        produce(tmp)
        os.replace(tmp, path)
    finally:
        with contextlib.suppress(OSError):
            tmp.unlink()
        with contextlib.suppress(OSError):
            os.rmdir(folder)


def remove_if_present(path: Path) -> None:
    """Remove a file or a symbolic link (never what it points to); a directory of that
    name is an error for the caller to report."""
    try:
        mode = os.lstat(path).st_mode
    except FileNotFoundError:
        return
    if stat.S_ISDIR(mode):
        raise UnusableFileError(f"{path}: is a directory where a report file belongs")
    os.unlink(path)


def output_dir_problem(out: Path) -> str | None:
    """Why ``out`` cannot be a report folder, or None when it can (created or not).

    Checked before any work: an existing non-directory, a path under a pseudo file
    system, a folder (or the nearest existing parent, when ``out`` does not exist yet)
    that this process cannot write into.
    """
    resolved = out.resolve()
    for root in PSEUDO_FILESYSTEMS:
        if resolved == Path(root) or resolved.is_relative_to(root):
            return f"{out}: under {root}, which is not a place for files"
    probe = resolved
    while not probe.exists():
        if probe.is_symlink():
            return f"{out}: {probe} is a dangling symbolic link"
        probe = probe.parent
    if probe != resolved and not probe.is_dir():
        return f"{out}: {probe} is not a directory"
    if probe == resolved and not resolved.is_dir():
        return f"{out}: exists and is not a directory"
    try:  # a real probe: permissions, a read-only mount, a full inode table
        fd, name = tempfile.mkstemp(prefix=".walkaround-probe-", dir=probe)
    except OSError as exc:
        return f"{out}: {probe} is not writable ({exc.strerror or exc})"
    os.close(fd)
    os.unlink(name)
    return None

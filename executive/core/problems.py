"""Problems found in input files, reported together with their location.

A :class:`Problem` is one mistake at ``file:line:column`` with a plain message. Loaders
collect every problem they can find and raise a single :class:`InvalidInputError` holding
all of them; they never return a partially built model.
"""

from __future__ import annotations

import os
import stat
from collections.abc import Iterable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import BinaryIO

MAX_FILE_BYTES = 4 * 1024 * 1024
"""Largest accepted input file; real missions are a few tens of kilobytes. Every read of
an input file (parsing, printing its offending line) stops after this many bytes."""

MAX_PROBLEMS = 100
"""Problems listed per file; further ones are counted, not listed."""

MAX_SHOWN_LINE = 200
"""Longest source line printed under a problem (characters)."""


@dataclass(frozen=True, slots=True, order=True)
class SourceLocation:
    """A place in a source file: 1-based line and column (0 when unknown)."""

    file: str
    line: int = 0
    column: int = 0

    def __str__(self) -> str:
        if self.line <= 0:
            return self.file
        if self.column <= 0:
            return f"{self.file}:{self.line}"
        return f"{self.file}:{self.line}:{self.column}"


@dataclass(frozen=True, slots=True, order=True)
class Problem:
    """One mistake in an input file.

    ``code`` is a short stable identifier (``xml-syntax``, ``schema``, ``duplicate-id``,
    ...) for tools and tests; ``message`` is written for the mission engineer.
    """

    where: SourceLocation
    code: str
    message: str

    def __str__(self) -> str:
        return f"{self.where}: {self.message} [{self.code}]"

    def as_dict(self) -> dict[str, object]:
        """A JSON-friendly form, as printed by ``walkaround validate --json``."""
        return {
            "file": self.where.file,
            "line": self.where.line,
            "column": self.where.column,
            "code": self.code,
            "message": self.message,
        }


class InvalidInputError(Exception):
    """Raised by loaders with every problem found; nothing was built."""

    def __init__(self, problems: Iterable[Problem]) -> None:
        self.problems: tuple[Problem, ...] = tuple(sorted(set(problems)))
        if not self.problems:
            raise ValueError("InvalidInputError needs at least one problem")
        super().__init__(self.summary())

    def summary(self) -> str:
        """All problems, one per line."""
        return "\n".join(str(p) for p in self.problems)

    def __iter__(self) -> Iterator[Problem]:
        return iter(self.problems)


class ProblemSink:
    """Collects problems for one file while a loader walks it."""

    def __init__(self, file: Path | str) -> None:
        self.file = str(file)
        self.problems: list[Problem] = []
        self.listed = 0  # problems of this file itself (not of files it refers to)
        self.dropped = 0

    def add(self, code: str, message: str, line: int = 0, column: int = 0) -> None:
        """Record a problem at ``line``/``column`` of this sink's file.

        After :data:`MAX_PROBLEMS` problems the rest are only counted: a hostile file
        with ten thousand mistakes gets a readable report, in bounded time.
        """
        if self.listed >= MAX_PROBLEMS:
            if not self.dropped:
                self.problems.append(
                    Problem(
                        SourceLocation(self.file, line, column),
                        "too-many-problems",
                        f"more than {MAX_PROBLEMS} problems: the rest are not listed",
                    )
                )
            self.dropped += 1
            return
        self.listed += 1
        self.problems.append(Problem(SourceLocation(self.file, line, column), code, message))

    def extend(self, problems: Iterable[Problem]) -> None:
        """Record problems found elsewhere (for instance in a referenced file)."""
        self.problems.extend(problems)

    def __bool__(self) -> bool:
        return bool(self.problems)

    def raise_if_any(self) -> None:
        """Raise :class:`InvalidInputError` when at least one problem was recorded."""
        if self.problems:
            raise InvalidInputError(self.problems)


class NotRegularFileError(OSError):
    """The path exists but is not a regular file (a directory, FIFO, device, socket)."""


def file_kind(mode: int) -> str:
    """What ``mode`` (from ``stat``) is, in words, for messages."""
    for test, words in (
        (stat.S_ISDIR, "a directory"),
        (stat.S_ISFIFO, "a FIFO (named pipe)"),
        (stat.S_ISCHR, "a character device"),
        (stat.S_ISBLK, "a block device"),
        (stat.S_ISSOCK, "a socket"),
    ):
        if test(mode):
            return words
    return "not a regular file"


def open_regular(path: Path | str) -> BinaryIO:
    """Open ``path`` for reading only if it is a regular file, without ever blocking.

    The file is opened with ``O_NONBLOCK`` (a FIFO with no writer would otherwise block
    ``open`` for ever) and checked with ``fstat`` on the open descriptor, so what is
    checked is what is read. Raises :class:`NotRegularFileError` for directories, FIFOs,
    devices and sockets, ``OSError`` for the rest.
    """
    flags = os.O_RDONLY | getattr(os, "O_NONBLOCK", 0) | getattr(os, "O_NOCTTY", 0)
    try:
        fd = os.open(path, flags)
    except IsADirectoryError as exc:
        raise NotRegularFileError(exc.errno, "a directory", str(path)) from None
    try:
        mode = os.fstat(fd).st_mode
        if not stat.S_ISREG(mode):
            raise NotRegularFileError(0, file_kind(mode), str(path))
        if hasattr(os, "set_blocking"):
            os.set_blocking(fd, True)
        return os.fdopen(fd, "rb")
    except BaseException:
        os.close(fd)
        raise


def source_line(problem: Problem, budget: int = MAX_FILE_BYTES) -> str | None:
    """The offending line of ``problem`` with a caret under the column, or None.

    Only a regular file is read, and at most ``budget`` bytes of it: lines before the
    wanted one are skipped in bounded chunks, and the wanted line itself is read no
    further than :data:`MAX_SHOWN_LINE` characters would need (longer lines are not shown).
    """
    if problem.where.line <= 0:
        return None
    limit = 4 * MAX_SHOWN_LINE + 2  # UTF-8: at most 4 bytes a character, plus CR LF
    try:
        with open_regular(problem.where.file) as handle:
            line, used = 1, 0
            while line < problem.where.line:
                chunk = handle.readline(min(65536, budget - used))
                used += len(chunk)
                if not chunk or used >= budget:
                    return None
                line += chunk.endswith(b"\n")
            raw = handle.readline(min(limit, max(budget - used, 0)))
        if not raw or (len(raw) >= limit and not raw.endswith(b"\n")):
            return None
        text = raw.decode("utf-8").rstrip("\r\n").expandtabs(1)
    except (OSError, UnicodeDecodeError):
        return None
    if not text.isprintable() or len(text) > MAX_SHOWN_LINE:
        return None
    out = f"    | {text}"
    if 0 < problem.where.column <= len(text) + 1:
        out += "\n    | " + " " * (problem.where.column - 1) + "^"
    return out


def internal_error(path: Path | str, exc: BaseException) -> Problem:
    """A problem standing for an unexpected exception while checking ``path``.

    Batch commands report it with the file instead of a traceback, so one file's crash
    never hides another file's result.
    """
    detail = " ".join(str(exc).split())[:200]
    return Problem(
        SourceLocation(str(path)),
        "internal-error",
        f"internal error while checking this file ({type(exc).__name__}"
        + (f": {detail}" if detail else "")
        + "); please report it",
    )

"""Problems found in input files, reported together with their location.

A :class:`Problem` is one mistake at ``file:line:column`` with a plain message. Loaders
collect every problem they can find and raise a single :class:`InvalidInputError` holding
all of them; they never return a partially built model.
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator
from dataclasses import dataclass
from pathlib import Path


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

    def add(self, code: str, message: str, line: int = 0, column: int = 0) -> None:
        """Record a problem at ``line``/``column`` of this sink's file."""
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

"""What every wire of the robot has in common: it owns a thread or a socket, and it is
closed (once, promptly) by :meth:`Wire.close`; a ``with`` block closes it too."""

from __future__ import annotations

from abc import ABC, abstractmethod
from types import TracebackType
from typing import Self


class Wire(ABC):
    """A client or server of one of the robot's wires (CAN, SCIP, NMEA, detections)."""

    @abstractmethod
    def close(self) -> None:
        """Stop the wire's thread and release what it holds; idempotent."""

    def __enter__(self) -> Self:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()

"""The base of every walkaround behaviour: declared, typed blackboard access.

Like py_trees' own behaviours, a :class:`Node` keeps the lifecycle (``initialise``,
``update``, ``terminate``); in addition it declares the keys it ``reads`` and ``writes``
(:mod:`behaviours.keys`), registers them with a py_trees blackboard client, and checks the
record type on every write. The compiler uses the declarations to prove the wiring.

The executive ticks the whole tree at 50 Hz, so the per-node machinery is on the hot
path: with py_trees' logging above DEBUG and no blackboard activity stream, a node ticks,
stops, reads and writes without py_trees' debug-string formatting and per-access
permission lookups (the permissions are the declared ones, checked once at construction
and proved by the compiler). With either switched on, py_trees' own code runs, so its
debug log and activity stream stay complete.
"""

from __future__ import annotations

from collections.abc import Iterator
from typing import Any, TypeVar

import py_trees
from py_trees.blackboard import Blackboard
from py_trees.common import Access, Status

from behaviours.keys import Key

T = TypeVar("T")

_STATUSES = frozenset(Status)


def unobserved() -> bool:
    """True when nobody listens to py_trees' debug log or blackboard activity."""
    return py_trees.logging.level > py_trees.logging.Level.DEBUG and (
        Blackboard.activity_stream is None
    )


class Node(py_trees.behaviour.Behaviour):
    """A behaviour with declared blackboard reads and writes."""

    reads: tuple[Key, ...] = ()
    writes: tuple[Key, ...] = ()
    reads_previous: tuple[Key, ...] = ()
    """Keys read as the *previous* tick left them: feedback from later nodes (the mission's
    progress read by sensing). The compiler checks only that something writes them."""

    def __init__(self, name: str) -> None:
        super().__init__(name=name)
        self.bb = self.attach_blackboard_client(name=name)
        for key in (*self.reads, *self.reads_previous):
            self.bb.register_key(key=key.name, access=Access.READ)
        for key in self.writes:
            self.bb.register_key(key=key.name, access=Access.WRITE)
        namespace = self.bb.namespace
        self._readable = {
            key.name: Blackboard.absolute_name(namespace, key.name)
            for key in (*self.reads, *self.reads_previous, *self.writes)
        }
        self._writable = {
            key.name: Blackboard.absolute_name(namespace, key.name) for key in self.writes
        }

    def tick(self) -> Iterator[py_trees.behaviour.Behaviour]:
        """py_trees' leaf tick (initialise, update, stop on a final status), without its
        debug-string formatting unless its log is at DEBUG."""
        if not unobserved():
            yield from super().tick()
            return
        if self.status != Status.RUNNING:
            self.initialise()
        new_status = self.update()
        if new_status not in _STATUSES:
            self.logger.error(
                f"A behaviour returned an invalid status, setting to INVALID "
                f"[{new_status}][{self.name}]"
            )
            new_status = Status.INVALID
        if new_status != Status.RUNNING:
            self.stop(new_status)
        self.status = new_status
        yield self

    def stop(self, new_status: Status) -> None:
        """py_trees' stop (terminate, then the new status), without its debug string."""
        if not unobserved():
            super().stop(new_status)
            return
        self.terminate(new_status)
        self.status = new_status
        self.iterator = self.tick()

    def read(self, key: Key, default: Any = None) -> Any:
        """The record under ``key``, or ``default`` when nothing was written yet."""
        name = self._readable.get(key.name)
        if name is None or not unobserved():
            try:
                return self.bb.get(key.name)
            except KeyError:
                return default
        return Blackboard.storage.get(name, default)

    def write(self, key: Key, value: object) -> None:
        """Store ``value`` under ``key``; it must be of the key's record type."""
        if not isinstance(value, key.type):
            raise TypeError(f"{self.name}: {key} takes {key.type.__name__}, not {type(value)}")
        name = self._writable.get(key.name)
        if name is None or not unobserved():
            self.bb.set(key.name, value, overwrite=True)
        else:
            Blackboard.storage[name] = value


class Guard(Node):
    """A condition: SUCCESS when its controller should run, FAILURE otherwise.

    ``feedback_message`` says why (which value against which threshold): the runtime
    logs it as the reason of a controller switch.
    """


class Controller(Node):
    """An action that writes exactly one :class:`VelocityCommand` each tick it runs."""

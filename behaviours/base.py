"""The base of every walkaround behaviour: declared, typed blackboard access.

Like py_trees' own behaviours, a :class:`Node` keeps the lifecycle (``initialise``,
``update``, ``terminate``); in addition it declares the keys it ``reads`` and ``writes``
(:mod:`behaviours.keys`), registers them with a py_trees blackboard client, and checks the
record type on every write. The compiler uses the declarations to prove the wiring.
"""

from __future__ import annotations

from typing import Any, TypeVar

import py_trees
from py_trees.common import Access

from behaviours.keys import Key

T = TypeVar("T")


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

    def read(self, key: Key, default: Any = None) -> Any:
        """The record under ``key``, or ``default`` when nothing was written yet."""
        try:
            return self.bb.get(key.name)
        except KeyError:
            return default

    def write(self, key: Key, value: object) -> None:
        """Store ``value`` under ``key``; it must be of the key's record type."""
        if not isinstance(value, key.type):
            raise TypeError(f"{self.name}: {key} takes {key.type.__name__}, not {type(value)}")
        self.bb.set(key.name, value, overwrite=True)


class Guard(Node):
    """A condition: SUCCESS when its controller should run, FAILURE otherwise.

    ``feedback_message`` says why (which value against which threshold): the runtime
    logs it as the reason of a controller switch.
    """


class Controller(Node):
    """An action that writes exactly one :class:`VelocityCommand` each tick it runs."""

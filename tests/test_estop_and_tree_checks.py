"""The e-stop latch law, and the compiler's own checks of a tree's wiring."""

import math

import py_trees
from hypothesis import given
from hypothesis import strategies as st

from behaviours.base import Controller, Guard, Node
from behaviours.keys import COMMAND, OBSTACLES, POSE
from behaviours.laws.estop import EStopLatch
from executive.compiler import GuardedBranch, GuardSelector, check_tree


def test_obstacle_latch_releases_after_hold():
    latch = EStopLatch(r_es=0.6, hold=1.0)
    assert latch.update(0.0, 0.4, bumper=False)
    assert latch.cause == "obstacle" and "0.40 m" in latch.reason
    assert latch.update(0.5, 2.0, bumper=False)  # clear, but not for long enough
    assert latch.update(1.4, 2.0, bumper=False)
    assert not latch.update(1.6, 2.0, bumper=False)


def test_obstacle_back_during_hold_restarts_it():
    latch = EStopLatch(r_es=0.6, hold=1.0)
    latch.update(0.0, 0.4, False)
    latch.update(0.9, 2.0, False)
    latch.update(1.0, 0.5, False)  # back again
    assert latch.update(1.9, 2.0, False)
    assert not latch.update(3.0, 2.0, False)


def test_bumper_latch_needs_an_operator_reset_after_release():
    latch = EStopLatch(r_es=0.6, hold=1.0)
    latch.update(0.0, math.inf, bumper=True)
    assert latch.update(100.0, math.inf, bumper=False)  # clear for ages: still latched
    assert latch.update(101.0, math.inf, bumper=True, reset=True)  # pressed: no reset
    assert not latch.update(102.0, math.inf, bumper=False, reset=True)


@given(st.lists(st.tuples(st.floats(0, 5), st.booleans(), st.booleans()), min_size=1, max_size=60))
def test_a_bumper_latch_survives_anything_but_a_reset(steps):
    latch = EStopLatch(r_es=0.6, hold=0.5)
    latch.update(0.0, math.inf, bumper=True)
    for i, (r_c, bumper, _) in enumerate(steps):
        assert latch.update(0.1 * (i + 1), r_c, bumper, reset=False)


# -- tree checks -------------------------------------------------------------------------------
class Writes(Controller):
    writes = (COMMAND,)

    def update(self):
        return py_trees.common.Status.RUNNING


class ReadsPose(Guard):
    reads = (POSE,)

    def update(self):
        return py_trees.common.Status.FAILURE


class WritesPose(Node):
    writes = (POSE,)

    def update(self):
        return py_trees.common.Status.SUCCESS


class ReadsObstacles(Controller):
    reads = (OBSTACLES,)
    writes = (COMMAND,)

    def update(self):
        return py_trees.common.Status.RUNNING


def _seq(*children):
    return py_trees.composites.Sequence("s", memory=False, children=list(children))


def test_sound_tree_passes():
    tree = _seq(
        WritesPose("pose"),
        GuardSelector("g", [GuardedBranch("b", ReadsPose("guard"), Writes("c1")), Writes("c2")]),
    )
    assert check_tree(tree) == []


def test_read_before_any_writer_is_reported():
    tree = _seq(ReadsPose("guard"), WritesPose("pose"))
    [problem] = check_tree(tree)
    assert "'guard' reads /state/pose but nothing writes it before it runs" in problem


def test_key_nobody_writes_is_reported():
    tree = GuardSelector("g", [ReadsObstacles("avoid")])
    assert any("/state/obstacles" in p for p in check_tree(tree))


def test_unguarded_controller_in_a_guard_selector_is_reported():
    tree = _seq(WritesPose("pose"), GuardSelector("g", [Writes("rogue"), Writes("default")]))
    problems = check_tree(tree)
    assert any("controller 'rogue' in 'g' has no guard" in p for p in problems)
    assert any("'rogue' is not a guarded branch" in p for p in problems)


def test_guard_selector_must_end_with_a_controller():
    tree = _seq(WritesPose("pose"), GuardSelector("g", [ReadsPose("lonely")]))
    assert any("must end with a default controller" in p for p in check_tree(tree))


def test_guarded_branch_must_be_guard_then_controller():
    bad = GuardedBranch("b", ReadsPose("guard"), Writes("c"))
    bad.children.reverse()
    tree = _seq(WritesPose("pose"), GuardSelector("g", [bad, Writes("d")]))
    assert any("'b' must be [guard] -> controller" in p for p in check_tree(tree))

"""sim2d: the pymunk world that stands in for the robot in tests and dry-runs.

It reads the mission model from ``executive.core`` and implements the robot interface;
nothing in ``behaviours`` imports it.
"""

"""Behaviour-tree nodes of walkaround (sensing, guards, controllers) and pure control laws.

Behaviours depend only on ``executive.core``; the mathematics lives in
``behaviours.laws`` and has no py_trees import.
"""

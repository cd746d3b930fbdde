"""Pure control laws and estimators: numpy only, no py_trees import.

Each law cites the seed equation it implements, so it can be tested against the thesis
without a behaviour tree.
"""

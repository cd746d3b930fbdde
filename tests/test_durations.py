"""The recorded test durations that order the suite (tests/durations.py)."""

import json

from tests import durations
from tests.conftest import REPO

REPORT = """\
============================= slowest durations ==============================
428.90s call     tests/test_readme.py::test_main_job
65.46s setup    tests/test_servo_e2e.py::test_lab[a-b]
59.21s call     tests/test_servo_e2e.py::test_lab[a-b]
3.10s call     tests/test_quick.py::test_short
0.50s teardown tests/test_servo_e2e.py::test_lab[a-b]
1 failed, 1964 passed in 2660.11s (0:44:20)
"""


def test_a_test_counts_its_setup_call_and_teardown_and_short_ones_are_left_out():
    parsed = durations.parse(REPORT.splitlines())
    assert parsed == {
        "tests/test_readme.py::test_main_job": 428.9,
        "tests/test_servo_e2e.py::test_lab[a-b]": 125.2,
    }
    assert list(parsed) == sorted(parsed, key=lambda k: -parsed[k])


def test_a_grouped_test_is_found_under_its_own_id():
    assert durations.test_id("tests/test_hil.py::test_x[1]@hil") == "tests/test_hil.py::test_x[1]"


def test_the_recorded_file_names_tests_that_exist():
    """Every recorded id names a test function of this suite: a renamed test would lose
    its place."""
    recorded = durations.load()
    assert recorded
    for test in recorded:
        path, name = test.split("::", 1)
        source = (REPO / path).read_text()
        assert f"def {name.split('[', 1)[0]}(" in source, test


def test_a_missing_file_orders_nothing(tmp_path):
    assert durations.load(tmp_path / "none.json") == {}
    (tmp_path / "d.json").write_text(json.dumps({"a::b": 3}))
    assert durations.load(tmp_path / "d.json") == {"a::b": 3.0}

"""tests/timeline.py reads what conftest.py writes with DAQ_TEST_TIMELINE: a worker's consecutive tests of one file
are one span, from the suite's first start; another file, or the same file later, starts a new span."""

from __future__ import annotations

from timeline import spans


def test_a_workers_consecutive_tests_of_a_file_are_one_span():
    lines = ["gw0\t100.0\t101.0\ttests/test_a.py::t1\n", "gw1\t100.5\t103.0\ttests/test_b.py::t1\n",
             "gw0\t101.0\t104.0\ttests/test_a.py::t2[x]\n", "gw0\t104.0\t105.0\ttests/test_c.py::t1\n",
             "gw0\t105.0\t106.5\ttests/test_a.py::t3\n"]
    got = spans(lines)
    assert got["gw0"] == [("test_a.py", 0.0, 4.0), ("test_c.py", 4.0, 5.0), ("test_a.py", 5.0, 6.5)]
    assert got["gw1"] == [("test_b.py", 0.5, 3.0)]

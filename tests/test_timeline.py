"""tests/timeline.py reads what conftest.py writes with DAQ_TEST_TIMELINE: a worker's consecutive tests of one file
are one span, from the suite's first start; another file, or the same file later, starts a new span."""

from __future__ import annotations

from timeline import cpu_by_file, cpu_table, spans


def test_a_workers_consecutive_tests_of_a_file_are_one_span():
    lines = ["gw0\t100.0\t101.0\ttests/test_a.py::t1\n", "gw1\t100.5\t103.0\ttests/test_b.py::t1\n",
             "gw0\t101.0\t104.0\ttests/test_a.py::t2[x]\n", "gw0\t104.0\t105.0\ttests/test_c.py::t1\n",
             "gw0\t105.0\t106.5\ttests/test_a.py::t3\n"]
    got = spans(lines)
    assert got["gw0"] == [("test_a.py", 0.0, 4.0), ("test_c.py", 4.0, 5.0), ("test_a.py", 5.0, 6.5)]
    assert got["gw1"] == [("test_b.py", 0.5, 3.0)]


def test_the_cpu_is_summed_by_file_and_compared_with_a_baseline_line_by_line():
    """A test's CPU is its worker's own plus its reaped children's; lines from before the CPU columns count nothing;
    against a baseline each file and the total carry their ratio."""
    now = ["gw0\t100.0\t101.0\ttests/test_a.py::t1\t2.00\t1.00\n",
           "gw1\t100.5\t103.0\ttests/test_b.py::t1\t0.50\t0.00\n",
           "gw0\t101.0\t104.0\ttests/test_a.py::t2[x]\t1.00\t0.00\n", "gw0\t104.0\t105.0\ttests/test_c.py::t1\n"]
    before = ["gw0\t0.0\t1.0\ttests/test_a.py::t1\t4.00\t4.00\n", "gw1\t0.0\t1.0\ttests/test_b.py::t1\t0.25\t0.25\n"]
    assert cpu_by_file(now) == {"test_a.py": 4.0, "test_b.py": 0.5}
    assert spans(now)["gw0"][-1] == ("test_c.py", 4.0, 5.0)  # the old four-column lines still make their spans
    table = cpu_table(cpu_by_file(now), cpu_by_file(before))
    assert table[0].split() == ["4.0", "s", "0.50x", "test_a.py"]
    assert table[1].split() == ["0.5", "s", "1.00x", "test_b.py"]
    assert table[-1].split() == ["4.5", "s", "0.53x", "all", "2", "files"]

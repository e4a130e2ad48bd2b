"""Stress-suite hooks: print how many cases ran and the largest errors at the end of the session."""

from __future__ import annotations

from tests.stress.record import summary_lines


def pytest_terminal_summary(terminalreporter, exitstatus, config):
    lines = summary_lines()
    if not lines:
        return
    terminalreporter.section("illum stress summary")
    for line in lines:
        terminalreporter.write_line(line)

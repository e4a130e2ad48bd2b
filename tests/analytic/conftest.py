"""Print the error summary of the analytic-integral accuracy tests after the run."""

from __future__ import annotations

from tests.analytic import harness


def pytest_terminal_summary(terminalreporter, exitstatus, config):
    lines = harness.summary_lines()
    if not lines:
        return
    terminalreporter.write_sep("-", "analytic light integrals vs quadrature (tests/analytic)")
    for line in lines:
        terminalreporter.write_line(line)
    terminalreporter.write_line(
        f"acceptance: |err| <= {harness.REL_TOL:g}*G_ref + {harness.FLOOR:g}*Omega + "
        f"{harness.POS:g}*eps*X*B (see tests/analytic/harness.py)")

"""What the benchmark scripts share: a run that a signal stopped ends the benchmark.

run_case catches SIGTERM/SIGINT/SIGHUP and returns the run so far with status
"interrupted" (so that nothing written is lost); a benchmark that took that for a
result would write a partial run as a row of its table. Imported after each script
has applied the thread policy.
"""

from __future__ import annotations

from capsim.runs.runner import run_case


def run_or_stop(case):
    """run_case(case), except that an interrupted run ends the script without a table."""
    result = run_case(case)
    if result["status"] == "interrupted":
        raise SystemExit(f"benchmark run {case.name!r} {result.get('status_reason') or 'interrupted'}: "
                         "no table written (a partial run is never a row)")
    return result

"""One run, end to end: the time loop and its run file (runner), every rule that ends a run
(stopping), the ladder of a measured accuracy target (ladder) and the speed benchmarks (benchmark).

Sits above the solve and the run store; never imports a campaign or the CLI. One public
surface: ``capsim.runs.<name>`` for every name of ``__all__`` (``run_case``, ``RunResult``,
``stop_reason``, ``bench_case`` ...), each loaded from its module on first access (the runner's, the
stopping rules' and the benchmark's names apply the thread policy first); ``import capsim.runs`` loads
no numba. The library's own modules import each other by their full name.
"""

from capsim._surface import lazy_surface

#: module -> the names it gives the package's surface
_SURFACE = {
    "runner": "run_case run_ladder RunResult",
    "stopping": "stop_reason guard_violation step_collapse LoopState MAX_CENTROID_COORDINATE",
    "ladder": "run_measured",
    "benchmark": "bench_case bench_velocity split_lines SPLIT_STAGES",
}
#: the modules that load numba on import (their names apply the thread policy first)
__all__, __getattr__, __dir__ = lazy_surface(__name__, _SURFACE, {'benchmark', 'runner', 'stopping'})

"""One run, end to end: the time loop and its run file (runner), every rule that ends a run
(stopping), the ladder of a measured accuracy target (ladder) and the speed benchmarks (benchmark).

Sits above the solve and the run store; never imports a campaign or the CLI. Modules are
imported by their full name; this ``__init__`` loads nothing (no numba on import).
"""

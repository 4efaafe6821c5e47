"""One run, end to end: the time loop and its run file (runner), every rule that ends a run
(stopping), the ladder of a measured accuracy target (ladder) and the speed benchmarks (benchmark).

Sits above the solve and the run store; never imports a campaign or the CLI. One public
surface: ``capsim.runs.<name>`` for every name of ``__all__`` (``run_case``, ``RunResult``,
``stop_reason``, ``bench_case`` ...), each loaded from its module on first access (the runner's, the
stopping rules' and the benchmark's names apply the thread policy first); ``import capsim.runs`` loads
no numba. The library's own modules import each other by their full name.
"""


#: module -> the names it gives the package's surface
_SURFACE = {
    "runner": "run_case run_ladder RunResult",
    "stopping": "stop_reason guard_violation step_collapse LoopState MAX_CENTROID_COORDINATE",
    "ladder": "run_measured",
    "benchmark": "bench_case bench_velocity split_lines SPLIT_STAGES",
}
# name -> module that defines it; imported on first access (PEP 562)
_LAZY = {name: f"{__name__}.{module}" for module, names in _SURFACE.items() for name in names.split()}
__all__ = list(_LAZY)
#: the modules that load numba on import
_NUMBA = {f"{__name__}.benchmark", f"{__name__}.runner", f"{__name__}.stopping"}


def __getattr__(name: str):
    module = _LAZY.get(name)
    if module is None:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    import importlib
    if module in _NUMBA:  # the module loads numba: the thread policy first (as capsim.RunResult)
        importlib.import_module("capsim.numerics.threads").apply_policy()
    value = getattr(importlib.import_module(module), name)
    globals()[name] = value
    return value


def __dir__():
    return sorted(set(globals()) | set(__all__))

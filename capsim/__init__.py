"""capsim: boundary-integral simulation of elastic capsules in simple shear flow.

The library face (every name is loaded on first use; ``import capsim`` loads neither
numba nor HDF5)::

    import capsim
    case = capsim.load_case("configs/sphere.yaml", mesh__level=1)   # a Case
    result = capsim.run(case, overwrite=True, progress=True)        # a RunResult
    tree = capsim.open_run(result.path)                             # an xarray.DataTree

``sweep``, ``summarize`` and ``study`` do what the CLI commands of the same names do;
see :mod:`capsim.api`.
"""

from capsim._version import __version__

__all__ = ["__version__", "load_case", "load_campaign", "run", "sweep", "summarize", "study", "fit", "open_run",
           "warm_up", "Case", "RunResult"]

# name -> module that defines it; imported on first access (PEP 562)
_LAZY = {
    "load_case": "capsim.api",
    "load_campaign": "capsim.api",
    "run": "capsim.api",
    "sweep": "capsim.api",
    "summarize": "capsim.api",
    "study": "capsim.api",
    "fit": "capsim.api",
    "open_run": "capsim.api",
    "warm_up": "capsim.api",
    "Case": "capsim.config",
    "RunResult": "capsim.runs.runner",
}


def __getattr__(name: str):
    module = _LAZY.get(name)
    if module is None:
        raise AttributeError(f"module 'capsim' has no attribute {name!r}")
    import importlib

    if name == "RunResult":  # capsim.runs.runner loads numba: the thread policy first
        importlib.import_module("capsim.numerics.threads").apply_policy()
    value = getattr(importlib.import_module(module), name)
    globals()[name] = value
    return value


def __dir__():
    return sorted(set(globals()) | set(__all__))

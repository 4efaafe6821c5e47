"""The lazy public surface of a package (PEP 562): its names loaded from their modules on first
access, so that importing the package loads nothing (no numba, h5py or matplotlib).

Every sub-package (and ``capsim`` itself) declares a table module → names; :func:`lazy_surface`
turns it into the package's ``__all__``, ``__getattr__`` and ``__dir__``. A name of a module that
loads numba applies the thread policy first (capsim.numerics.threads: numba's thread count is
fixed when it loads). Imports nothing of capsim at import time.
"""

from __future__ import annotations

import importlib
import sys
from typing import Callable


def lazy_surface(package: str, surface: dict[str, str],
                 numba_modules: frozenset[str] | set[str] = frozenset()) -> tuple[list[str], Callable, Callable]:
    """(``__all__``, ``__getattr__``, ``__dir__``) of ``package`` from ``surface`` (module name
    relative to the package → its names, space-separated); ``numba_modules``: those (relative
    names) that load numba."""
    lazy = {name: module for module, names in surface.items() for name in names.split()}

    def __getattr__(name: str):
        module = lazy.get(name)
        if module is None:
            raise AttributeError(f"module {package!r} has no attribute {name!r}")
        if module in numba_modules:  # the module loads numba: the thread policy first
            importlib.import_module("capsim.numerics.threads").apply_policy()
        value = getattr(importlib.import_module(f"{package}.{module}" if module else package), name)
        vars(sys.modules[package])[name] = value
        return value

    def __dir__():
        return sorted(set(vars(sys.modules[package])) | set(lazy))

    return list(lazy), __getattr__, __dir__

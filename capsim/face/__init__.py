"""What a person sees: the command line (cli, cli_errors), the terminal display, figures (plot)
and exports to other tools (export).

The top layer with ``capsim.api``: nothing below imports it. One public surface:
``capsim.face.<name>`` for every name of ``__all__`` (``app``, ``RunProgress``, ``export_run``,
``write_figure``, ``contour_figure`` ...), each loaded from its module on first access;
``import capsim.face`` loads nothing (no matplotlib), so ``capsim --help`` stays fast. (``plot.plot``
is reached as ``capsim.face.plot.plot``: the name is its module's.) The library's own modules import
each other by their full name.
"""


#: module -> the names it gives the package's surface
_SURFACE = {
    "cli": "app",
    "display": "RunProgress SweepProgress summary_table summary_rows",
    "plot": ("write_figure contour_figure conduit_figure deformation_figure inclination_figure orbit_map_figure "
             "rheology_figure trajectory_figure KINDS SCENE_KINDS SUMMARY_KINDS CLASS_COLOURS DPI FIGSIZE"),
    "export": "export_run export_to_dir snapshot_fields membrane_fields model_for",
}
# name -> module that defines it; imported on first access (PEP 562)
_LAZY = {name: f"{__name__}.{module}" for module, names in _SURFACE.items() for name in names.split()}
__all__ = list(_LAZY)


def __getattr__(name: str):
    module = _LAZY.get(name)
    if module is None:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    import importlib
    value = getattr(importlib.import_module(module), name)
    globals()[name] = value
    return value


def __dir__():
    return sorted(set(globals()) | set(__all__))

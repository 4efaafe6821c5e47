"""What a person sees: the command line (cli, cli_errors), the terminal display, figures (plot)
and exports to other tools (export).

The top layer with ``capsim.api``: nothing below imports it. One public surface:
``capsim.face.<name>`` for every name of ``__all__`` (``app``, ``RunProgress``, ``export_run``,
``write_figure``, ``contour_figure`` ...), each loaded from its module on first access;
``import capsim.face`` loads nothing (no matplotlib), so ``capsim --help`` stays fast. (``plot.plot``
is reached as ``capsim.face.plot.plot``: the name is its module's.) The library's own modules import
each other by their full name.
"""

from capsim._surface import lazy_surface

#: module -> the names it gives the package's surface
_SURFACE = {
    "cli": "app",
    "display": "RunProgress SweepProgress summary_table summary_rows",
    "plot": ("write_figure contour_figure conduit_figure deformation_figure inclination_figure orbit_map_figure "
             "rheology_figure trajectory_figure KINDS SCENE_KINDS SUMMARY_KINDS CLASS_COLOURS DPI FIGSIZE"),
    "export": "export_run export_to_dir snapshot_fields membrane_fields model_for",
}
__all__, __getattr__, __dir__ = lazy_surface(__name__, _SURFACE)

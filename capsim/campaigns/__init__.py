"""Many runs: campaigns (sweeps) and their executor (processes, dask), the summary of a campaign,
and convergence studies.

Imports runs, the run store and below; never the CLI or plots. One public surface:
``capsim.campaigns.<name>`` for every name of ``__all__`` (``load_campaign``, ``run_campaign``,
``summarize_campaign``, ``run_study``, ``format_study_table`` ...), each loaded from its module on
first access; ``import capsim.campaigns`` loads no h5py, xarray or numba. (A convergence study itself is
``capsim.study``: here the name ``study`` is its module's.) The library's own modules
import each other by their full name.
"""

from capsim._surface import lazy_surface

#: module -> the names it gives the package's surface
_SURFACE = {
    "campaign": ("Campaign load_campaign load_campaign_with campaign_from_dict expand_campaign count_runs plan_lines "
                 "run_campaign execute_run check_scheduler campaign_digest MAX_RUNS FOREIGN"),
    "executor": ("run_batch warm_up check_workers distinct_kinds refuse_in_spawned_import_of_main path_arg path_list "
                 "text_list"),
    "summary": "summarize_campaign summarize_to_file write_summary read_run SUMMARY_ATTRS",
    "study": ("run_study analyse_study write_study format_study_table format_error_estimate error_estimate "
              "final_values richardson own_errors verdict check_run plot_pareto QUANTITIES"),
}
__all__, __getattr__, __dir__ = lazy_surface(__name__, _SURFACE)

"""The library face of capsim: what `import capsim` offers, and what every CLI command calls.

Each function does what its CLI command does, with the same checks and the same
one-line errors, but returns Python objects instead of printing:

| function | CLI command | returns |
|---|---|---|
| [`load_case`][capsim.api.load_case] | `capsim validate CASE` | a [`Case`][capsim.config.Case] |
| [`run`][capsim.api.run] | `capsim run` | a [`RunResult`][capsim.runs.runner.RunResult] |
| [`sweep`][capsim.api.sweep] | `capsim sweep` | a dict of counts and one record per run |
| [`summarize`][capsim.api.summarize] | `capsim summarize` | an `xarray.Dataset` (also written as netCDF) |
| [`study`][capsim.api.study] | `capsim study` | an `xarray.Dataset` (written when `output` is given) |
| [`open_run`][capsim.api.open_run] | (none) | an `xarray.DataTree` of a run file |
| [`warm_up`][capsim.api.warm_up] | `capsim warm-up [CASE]` | the seconds spent compiling or loading kernels |
| [`fit`][capsim.api.fit] | `capsim fit FIT` | a `capsim.campaigns.fit.FitResult` (also written as fit.json) |

Nothing here imports numba at import time: `run`, `sweep` and `study` first apply
the thread policy (`capsim.numerics.threads.apply_policy`, the same one the CLI applies), then
load the kernels.

An argument that takes a list (`sets`, `inputs`, `levels`, `rtols`, `quad`, the cases
of `warm_up`) also takes a single value, as a list of one: `sets="mesh.level=1"` is
`sets=["mesh.level=1"]`. `levels` and `rtols` take numbers, not texts.

`sweep`, and `study` with `workers` > 1, run in worker processes started by spawn. The
workers do not import the calling script again, so a plain script works as it is, with
or without an `if __name__ == "__main__":` guard. Called while a process of the
script's own (a `multiprocessing` pool started by spawn) imports the script again, they
refuse: put the call under that guard.

A mistake in what is asked (an argument, a case, a campaign, a path) and a file in the way
raise one of these exceptions, its message one line (the line the CLI prints after
`error:`). A run that goes unstable or is stopped (a limit, Ctrl-C) returns, its `status`
saying so; in a sweep, so does each run that fails.

| exception | when |
|---|---|
| [`capsim.config.ConfigError`][capsim.config.ConfigError] | a bad case, campaign or argument (`workers=0`, `units="bogus"`, `levels=[]`, `overwrite` with `resume`, a directory that holds no campaign) |
| [`capsim.storage.files.OutputError`][capsim.storage.files.OutputError] | an output that must not be written (an existing run file without `overwrite`) |
| [`capsim.storage.files.LockedError`][capsim.storage.files.LockedError] | another process writes the same file or directory |
| [`capsim.storage.files.StorageError`][capsim.storage.files.StorageError] | writing fails (a full disk, a file-size limit) |
| [`capsim.storage.checkpoint.ResumeError`][capsim.storage.checkpoint.ResumeError] | a run cannot resume or be extended (no or a damaged checkpoint, another case) |
| [`capsim.storage.store.TrajectoryError`][capsim.storage.store.TrajectoryError] | a run file cannot be read: missing, not a capsim run file, damaged, or being written (`open_run`) |
| [`capsim.units.UnitsError`][capsim.units.UnitsError] | physical units asked of a case or campaign without a `physical:` block |
"""

from __future__ import annotations

import os
import sys
from collections.abc import Callable, Iterable, Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:  # pragma: no cover - types only
    import xarray as xr

    from capsim.campaigns.campaign import Campaign
    from capsim.config import Case
    from capsim.runs.runner import RunResult

__all__ = ["load_case", "load_campaign", "run", "sweep", "summarize", "study", "open_run", "warm_up", "fit"]

PathLike = str | os.PathLike
#: `progress=` of `run`, `sweep`, `study`: False (silent), True (the CLI's display on
#: stderr), or a callable given each progress state
Progress = bool | Callable[[Any], None]


def load_case(source: "PathLike | Mapping[str, Any] | Case", sets: "str | Sequence[str] | None" = None,
              **overrides: Any) -> "Case":
    """A case from a YAML file, a dict of the same sections, or an existing
    [`Case`][capsim.config.Case].

    `sets` are `--set` texts (`"mesh.level=1"`, the value read as YAML; one text or a
    list); `overrides` are fields by dotted name, written with `**{"time.t_end": 2.0}`
    or with a double underscore for the dot, `time__t_end=2.0` (None leaves a field as
    it is). Every value is checked against the schema (the case file reference of the
    docs); a mistake raises `capsim.config.ConfigError` with one line naming the
    field, the value and what is allowed.

    ```python
    import capsim
    case = capsim.load_case("configs/sphere.yaml", mesh__level=1)
    case.mesh.level  # 1
    ```
    """
    from capsim.config import resolve_case
    from capsim.campaigns.executor import text_list

    return resolve_case(dict(source) if isinstance(source, Mapping) else source, text_list(sets, "sets"),
                        **overrides)


def load_campaign(source: PathLike, sets: "str | Sequence[str] | None" = None, *,
                  max_runs: int | None = None) -> "Campaign":
    """A campaign file (a `base` case, a `sweep` grid and/or `zip` lists, an `output.dir`),
    with `--set` texts (one text or a list) written into its base; a mistake raises a
    one-line `capsim.config.ConfigError`."""
    from capsim.campaigns.campaign import MAX_RUNS, load_campaign_with
    from capsim.campaigns.executor import check_workers, path_arg, text_list

    limit = MAX_RUNS if max_runs is None else check_workers(max_runs, "max_runs", default=None)
    return load_campaign_with(path_arg(source, "campaign"), text_list(sets, "sets"), max_runs=limit)


def _apply_thread_policy(workers: int = 1) -> None:
    """The CLI's thread policy (a no-op after the first call, or once numba is loaded)."""
    from capsim.numerics.threads import apply_policy

    apply_policy(workers=workers)


def _progress(progress: Progress, make: Callable[[], Any]):
    if progress is True:
        return make()
    if progress is False or progress is None:
        return None
    if not callable(progress):
        from capsim.config import ConfigError
        from capsim.errors import bounded_repr

        raise ConfigError(f"progress = {bounded_repr(progress)}: must be True, False or a callable")
    return progress


def _finish(display: Any) -> None:
    finish = getattr(display, "finish", None)
    if callable(finish):
        finish()


def run(case: "PathLike | Mapping[str, Any] | Case", *, output: PathLike | None = None, overwrite: bool = False,
        resume: bool = False, progress: Progress = False, sets: "str | Sequence[str] | None" = None,
        inputs: "PathLike | Sequence[PathLike]" = (), **overrides: Any) -> "RunResult":
    """Run one case and write its run file (HDF5); what `capsim run` does.

    `case` is a case file, a dict or a [`Case`][capsim.config.Case]; `sets` and
    `overrides` change fields as in [`load_case`][capsim.api.load_case]; `output`
    replaces `output.path`. Before anything is computed the output is checked exactly
    as the CLI checks it: an existing file is refused (`capsim.storage.files.OutputError`, the
    CLI's one-line message) unless `overwrite` (start again) or `resume` (continue an
    interrupted run from its checkpoint, or extend a completed one to a later
    `time.t_end`); the two exclude each other (`capsim.config.ConfigError`). The thread
    policy is applied before numba loads. `progress=True` shows the CLI's progress line
    on stderr; a callable receives `{t, dt, D_xy, step, t_end}` after each step.
    `inputs`: more files the run must never write over (the case file is one when
    `case` is a path).

    Returns a [`RunResult`][capsim.runs.runner.RunResult]: `status` (`"completed"` when the
    run reached its end), the path, cost, and the summary of the motion
    (`result["D_xy"]`, `result["theta"]`: means over the last window). A case whose
    accuracy target is measured (`accuracy.method`) runs the ladder of levels and returns
    the kept level's run, `result.accuracy` its verdict (met or NOT met, the error estimate).

    ```python
    result = capsim.run("configs/sphere.yaml", overwrite=True)
    result.status, round(result["D_xy"], 4)  # ('completed', 0.3899)
    ```
    """
    from capsim.campaigns.executor import path_arg, path_list

    if overwrite and resume:
        from capsim.config import ConfigError

        raise ConfigError("overwrite and resume exclude each other: overwrite starts the run again from kt = 0, "
                          "resume continues the one in the file; give one")
    inputs = path_list(inputs, "inputs") + ([Path(case)] if isinstance(case, (str, os.PathLike)) else [])
    if output is not None:
        overrides["output.path"] = os.fspath(path_arg(output, "output"))
    case = load_case(case, sets, **overrides)
    from capsim.storage.store import guard_run_output

    guard_run_output(case.output.path, inputs, overwrite=overwrite, resume=resume)
    _apply_thread_policy()
    if progress is True and not kernels_cached():
        # the first run after an install compiles every kernel it uses: said before, timed, and
        # done before the run starts, so that its wall time is the computation's
        print("capsim: compiling the numba kernels (the first run after an install; about half a minute "
              "on 2 cores, cached for every later run)", file=sys.stderr, flush=True)
        seconds = warm_up([case])
        print(f"capsim: compiled in {seconds:.0f} s", file=sys.stderr, flush=True)
    from capsim.face.display import RunProgress
    from capsim.runs.runner import run_case

    display = _progress(progress, RunProgress)
    try:
        return run_case(case, progress=display, resume=resume, overwrite=overwrite)
    finally:
        _finish(display)


def sweep(campaign: "PathLike | Campaign", *, workers: int | None = None, scheduler: str | None = None,
          resume: bool = True, overwrite: bool = False, progress: Progress = False,
          sets: "str | Sequence[str] | None" = None, max_runs: int | None = None) -> dict[str, Any]:
    """Run every case of a campaign into its `output.dir`; what `capsim sweep` does.

    Completed runs are skipped unless `resume=False`; a directory that holds another
    campaign is refused unless `overwrite`. `workers` local processes (a whole number
    >= 1, default one per core) or a Dask `scheduler` address. Works from a plain script
    (the worker processes do not run the script again). Returns `{"total", "skipped",
    "completed", "failed", "interrupted", "records"}` (one record per run, with its
    `run_id`, `status` and `status_reason`); [`summarize`][capsim.api.summarize] then
    collects the directory into one Dataset.
    """
    from capsim.campaigns.campaign import Campaign, expand_campaign, run_campaign
    from capsim.campaigns.executor import check_workers, refuse_in_spawned_import_of_main

    refuse_in_spawned_import_of_main("capsim.sweep")
    workers = check_workers(workers)
    if not isinstance(campaign, Campaign):
        if not isinstance(campaign, (str, os.PathLike)):
            from capsim.config import ConfigError
            from capsim.errors import bounded_repr

            raise ConfigError(f"campaign = {bounded_repr(campaign)}: a campaign file or a Campaign is expected")
        campaign = load_campaign(campaign, sets, max_runs=max_runs)
    _apply_thread_policy()
    display = None
    if progress is True:
        from capsim.face.display import SweepProgress

        display = SweepProgress({spec.run_id: spec.case().time.t_end for spec in expand_campaign(campaign)})
    else:
        display = _progress(progress, lambda: None)
    try:
        return run_campaign(campaign, workers=workers, scheduler=scheduler, resume=resume, progress=display,
                            overwrite=overwrite)
    finally:
        _finish(display)


def summary_path(directory: PathLike, output: PathLike | None = None) -> Path:
    """Where [`summarize`][capsim.api.summarize] writes: `output`, else `DIR/summary.nc`."""
    return Path(output) if output is not None else Path(directory) / "summary.nc"


def summarize(directory: PathLike, output: PathLike | None = None, *, overwrite: bool = False,
              units: str = "capsim") -> "xr.Dataset":
    """Collect a campaign directory's runs into one `xarray.Dataset` and write it as netCDF
    (to `output`, default [`summary_path`][capsim.api.summary_path]); what
    `capsim summarize` does.

    `directory` is a campaign's `output.dir` (with the `campaign.yaml` and `runs.json`
    that `sweep` writes); another directory or a file is refused
    (`capsim.config.ConfigError`). The Dataset has one dimension per swept field, named
    by the field's last part (`flow.shear_rate_G` gives `shear_rate_G`,
    `flow.viscosity_ratio` gives `viscosity_ratio`; a `run` dimension for a campaign that
    is not a full grid), and one variable per quantity of the quantity table (`D_xy`,
    `theta`, ..., with units and meaning in their attributes) plus `status`. An existing
    file that is not a summary is replaced only with `overwrite`
    (`capsim.storage.files.OutputError`). `units="physical"` (or `"capsim"`, the default): the
    variables with a capsim scale in physical units from each run's `physical:` block
    (`capsim.units.UnitsError` for a campaign without one).
    """
    from capsim.campaigns.executor import path_arg
    from capsim.campaigns.summary import summarize_to_file

    directory, output = path_arg(directory, "directory"), path_arg(output, "output")
    _, ds = summarize_to_file(directory, summary_path(directory, output), overwrite=overwrite, units=units)
    return ds


def study(case: "PathLike | Mapping[str, Any] | Case", levels: "int | Sequence[int]" = (2, 3, 4),
          rtols: "float | Sequence[float]" = (1e-3, 1e-4, 1e-5), **options: Any) -> "xr.Dataset":
    """Accuracy against cost; see [`capsim.campaigns.study.study`][capsim.campaigns.study.study]
    (`capsim.study(...)` calls it too)."""
    from capsim.campaigns.study import study as _study

    return _study(case, levels, rtols, **options)


def fit(spec: "PathLike | Mapping[str, Any]", *, workers: int | None = 1, progress: bool = False) -> Any:
    """Infer case fields from measured run outputs; what `capsim fit` does (docs/fit.md).

    `spec` is a fit file (its `data` CSV relative to the file) or a dict of the same
    fields (`data` relative to the working directory). Weighted least squares, one run per
    distinct data row per evaluation through the campaign runner in `<output.dir>/runs`
    (runs that exist are reused); `workers` local processes. `progress=True` prints the
    plan (the runs it costs), one line per evaluation and the closing table on stderr.
    Returns a `capsim.campaigns.fit.FitResult` (estimates, intervals,
    correlations, residuals, `n_runs`), also written to `<output.dir>/fit.json`. A bad
    spec or data file raises a one-line `capsim.config.ConfigError` before any run;
    a run that does not complete raises `capsim.campaigns.fit.FitError`.
    """
    from capsim.campaigns.executor import check_workers, refuse_in_spawned_import_of_main
    from capsim.campaigns.fit import fit_from_dict, load_fit, run_fit

    refuse_in_spawned_import_of_main("capsim.fit")
    workers = check_workers(workers)
    if isinstance(spec, Mapping):
        loaded = fit_from_dict(dict(spec), source="<fit>")
    elif isinstance(spec, (str, os.PathLike)):
        loaded = load_fit(spec)
    else:
        from capsim.config import ConfigError
        from capsim.errors import bounded_repr

        raise ConfigError(f"spec = {bounded_repr(spec)}: a fit file or a mapping of its fields is expected")
    _apply_thread_policy()
    return run_fit(loaded, workers=workers, log=None if not progress else _stderr_line)


def _stderr_line(line: str) -> None:
    print(line, file=sys.stderr, flush=True)


def open_run(path: PathLike):
    """A run file as an `xarray.DataTree`: one node per group, read into memory.

    `/timeseries` holds `D_xy`, `theta`, ... over `t` (one row per step); `/mesh` the
    surface: `elements`, `rest_positions`, and the node `positions` of each snapshot over
    `snapshot_t`; `/summary` the motion and its window means; `/run` the state at the end
    and the cost; `/membrane_law`, `/rest_shape` and, after `--error-estimate`,
    `/error_estimate`; the root's attributes hold the status and the resolved case
    (`config_yaml`). A path that is not a capsim run file (missing, empty, another
    program's HDF5 file, a summary), a damaged file, or one that a running capsim process
    writes and that cannot be read consistently just then, raises
    `capsim.storage.store.TrajectoryError` with one line saying which.
    """
    from capsim.campaigns.executor import path_arg
    from capsim.storage.store import open_run as _open_run  # h5py and xarray only when asked for

    return _open_run(path_arg(path, "path"))


def warm_up(cases: "PathLike | Mapping[str, Any] | Case | Sequence[PathLike | Mapping[str, Any] | Case]" = ()
            ) -> float:
    """Compile every numba kernel the cases use into numba's on-disk cache (or load it from
    there), so that their runs start computing at once; what `capsim warm-up` (and
    `make venv`, at install) does.

    `cases`: one case (a file, a dict or a [`Case`][capsim.config.Case]) or a list of
    them; none: the default case's kernels (the demo's). Returns the seconds it took.
    Each kind of case (law, traction, λ ≠ 1, bending, symmetry, scheme, preconditioner,
    membrane viscosity: `capsim.campaigns.executor.kernel_kind`) is run once at level 0 for two
    steps.
    """
    import time

    from capsim.config import Case

    if isinstance(cases, (str, os.PathLike, Mapping, Case)):
        cases = [cases]
    elif isinstance(cases, Iterable) and not isinstance(cases, bytes):
        cases = list(cases)
    else:
        from capsim.config import ConfigError
        from capsim.errors import bounded_repr

        raise ConfigError(f"cases = {bounded_repr(cases)}: a case (a path, a dict or a Case) or a list of them "
                          "is expected")
    loaded = [load_case(c) for c in cases] or [load_case({"name": "warm-up"})]
    _apply_thread_policy()
    from capsim.campaigns.executor import warm_up as _warm_up

    t0 = time.perf_counter()
    _warm_up(loaded)
    return time.perf_counter() - t0


def kernels_cached() -> bool:
    """Whether numba's on-disk cache holds capsim's kernels: ``NUMBA_CACHE_DIR`` when set
    (numba then looks nowhere else), else the ``__pycache__`` beside capsim/numerics/kernels.py."""
    cache_dir = os.environ.get("NUMBA_CACHE_DIR", "").strip()
    where = Path(cache_dir) if cache_dir else Path(__file__).parent / "numerics" / "__pycache__"
    try:
        return where.is_dir() and next(where.rglob("kernels.*.nbi"), None) is not None
    except OSError:
        return False

"""Command-line interface: each command loads its inputs and calls one library function.

Exit codes: 0 success, 1 the run ended unstable/failed/interrupted, 2 user error
(bad case file, bad option, unwritable output).
"""

from __future__ import annotations

import atexit
import enum
import gc
import json
from pathlib import Path
from typing import Any, Optional

import typer

from capsim.face.cli_errors import OneLineErrors
from capsim.storage.files import FIGURE_MAGIC

# A command's last ~0.2 s went to the interpreter's teardown collecting the whole heap (numba's,
# pydantic's, scipy's objects) several times. Frozen at exit, it is left to the OS: objects are
# still freed by reference counting, and only cycles alive at exit skip finalizers, which Python
# does not promise to run at exit anyway (capsim closes every file it writes before it returns).
atexit.register(gc.freeze)


app = typer.Typer(
    help="Boundary-integral simulation of elastic capsules in Stokes flow (shear, extension, Poiseuille, any linear flow, in time; near a wall, in a tube, duct or constriction; one capsule or several); runs that meet accuracy targets; campaigns with summaries and figures; membrane parameters fitted to measurements.",
    no_args_is_help=True,
    add_completion=True,
    pretty_exceptions_show_locals=False,
    context_settings={"help_option_names": ["-h", "--help"]},
    cls=OneLineErrors,
)

# Choices, as enums so that --help lists them. Written out here (the CLI must not import
# matplotlib or HDF5 for --help); tests/test_registries.py checks them against the registries:
# plot kinds capsim.face.plot.KINDS, export formats capsim.face.export.FORMATS, study references
# capsim.campaigns.study.REFERENCES, figure formats capsim.face.plot.FIGURE_FORMATS.
_PLOT_KINDS = ("deformation", "inclination", "contour", "trajectory", "separation", "tensions", "rheology", "steady",
               "orbit", "orbit_map", "conduit", "lift", "migration")
_EXPORT_FORMATS = ("xdmf", "vtu")
_STUDY_REFERENCES = ("finest", "richardson")
_FIGURE_FORMATS = ("png", "pdf", "svg")
# capsim.quantities.UNIT_SYSTEMS, copied: importing that table costs ~60 ms of every command's
# start-up (tests/face/test_physical_output.py keeps the two equal)
_UNIT_SYSTEMS = ("capsim", "physical")
_FIGURE_MAGIC = FIGURE_MAGIC
PlotKind = enum.Enum("PlotKind", {k: k for k in _PLOT_KINDS}, type=str)
ExportFormat = enum.Enum("ExportFormat", {k: k for k in _EXPORT_FORMATS}, type=str)
StudyReference = enum.Enum("StudyReference", {k: k for k in _STUDY_REFERENCES}, type=str)
UnitSystem = enum.Enum("UnitSystem", {k: k for k in _UNIT_SYSTEMS}, type=str)
#: --units, on run, summarize, plot and export
_UNITS_HELP = ("capsim: capsim's scales (kt, x/a, E_s ...); physical: s, um, uN/m, Hz, pN*um from the case's "
               "physical: block (capsim.quantities.SCALE_UNITS)")

#: --set FIELD=VALUE, repeatable (run, validate, sweep, study)
_SET_HELP = ("set a case field, dotted path = YAML value, repeatable: --set mesh.level=1 "
             "--set time.scheme=rkc (a campaign: a field of its base)")
def _user_error(message: str) -> typer.Exit:
    typer.echo(f"error: {message}", err=True)
    return typer.Exit(code=2)


def _load(case_path: Path, sets: list[str] | None = None, **overrides: Any):
    """The case at `case_path` (a case file, or a run file: the case it ran, written back to it)
    with --set fields and the command's own options; user errors exit 2."""
    from capsim.config import ConfigError, load_case_with
    from capsim.storage.files import is_hdf5

    source: Any = case_path
    if is_hdf5(case_path):  # capsim run RUN.h5 --resume --t-end 60
        from capsim.storage.store import TrajectoryError, read_case

        try:
            source, overrides["output.path"] = read_case(case_path), overrides.get("output.path") or str(case_path)
        except TrajectoryError as exc:
            raise _user_error(str(exc)) from None
    try:
        return load_case_with(source, sets, **overrides)
    except ConfigError as exc:
        raise _user_error(str(exc)) from None


def _factors(case, what: str) -> dict:
    """--units physical: the factors of the case's physical block; none is a one-line error."""
    from capsim.units import UnitsError, factors_for

    try:
        return factors_for(case, what)
    except UnitsError as exc:
        raise _user_error(str(exc)) from None


def _files_call(fn, *args, **kwargs):
    """A library call: its user errors (a bad case or campaign, a file it may not write or take) one line, exit 2."""
    from capsim.config import ConfigError
    from capsim.storage.files import LockedError, OutputError, StorageError

    try:
        return fn(*args, **kwargs)
    except (ConfigError, OutputError, StorageError, LockedError) as exc:
        raise _user_error(str(exc)) from None


@app.command()
def run(
    case_path: Path = typer.Argument(..., metavar="CASE.yaml|RUN.h5", help="case file, or a run file: its case"),
    output: Optional[Path] = typer.Option(None, "-o", "--output", help="output HDF5 path"),
    error_estimate: bool = typer.Option(
        False, "--error-estimate", help="also run one level coarser and rtol x 10; store the differences"
    ),
    t_end: Optional[float] = typer.Option(None, "--t-end", help="override time.t_end"),
    level: Optional[int] = typer.Option(None, "--level", help="override mesh.level"),
    accuracy: Optional[str] = typer.Option(None, "--accuracy", metavar="QUANTITY=TARGET",
                                           help="an accuracy target, e.g. D_xy=1e-3: capsim picks the level and rtol"),
    verify: bool = typer.Option(False, "--verify", help="afterwards, the error estimate against the accuracy target"),
    quiet: bool = typer.Option(False, "--quiet", "-q", help="no progress line"),
    resume: bool = typer.Option(
        False, "--resume", help="continue an interrupted run from the checkpoint beside its output, "
        "or extend a completed one to a later --t-end (appended to the same file)"),
    overwrite: bool = typer.Option(False, "--overwrite", help="replace an existing file at the output path"),
    sets: Optional[list[str]] = typer.Option(None, "--set", metavar="FIELD=VALUE", help=_SET_HELP),
    units: UnitSystem = typer.Option("capsim", "--units", help="the closing table's units: " + _UNITS_HELP),
) -> None:
    """Run one case and write its trajectory (or, with --resume, finish an interrupted one).

    Examples:

    capsim run configs/sphere.yaml

    capsim run configs/sphere.yaml --set mesh.level=2 --set time.scheme=rkc -o runs/s.h5

    capsim run configs/sphere.yaml --resume   (after an interruption)

    capsim run runs/sphere-G0.1.h5 --resume --t-end 12   (a completed run, extended to kt = 12)
    """
    from capsim import api
    from capsim.storage.checkpoint import ResumeError
    from capsim.storage.files import is_hdf5

    quantity, target = _accuracy_option(accuracy)
    case = _load(case_path, sets, **{"output.path": str(output) if output is not None else None,
                                     "time.t_end": t_end, "mesh.level": level, "accuracy.quantity": quantity,
                                     "accuracy.target": target})
    if case.accuracy is not None and not (resume and t_end is not None):  # the prediction, before the run
        typer.echo(case.accuracy.choice, err=True)  # (an extension's was for the t_end the run had then)
    factors = _factors(case, str(case_path)) if units.value == "physical" else None  # refused before the run
    try:
        summary = _files_call(api.run, case, inputs=[] if is_hdf5(case_path) else [case_path], overwrite=overwrite,
                              resume=resume, progress=not quiet)
    except ResumeError as exc:
        raise _user_error(f"cannot resume: {exc}") from None
    except OSError as exc:
        raise _user_error(f"cannot write {case.output.path}: {exc.strerror or exc}") from None
    except KeyboardInterrupt:
        typer.echo("\ninterrupted", err=True)
        raise typer.Exit(code=1) from None
    from capsim.face.display import print_summary

    print_summary({**summary, "shear_rate_G": case.flow.shear_rate_G}, title=case.name, factors=factors)
    from capsim.campaigns.study import check_run

    if summary.get("accuracy"):  # a measured target's ladder: its verdict is the verification
        typer.echo(summary["accuracy"])
    text, verified = _files_call(check_run, case, summary, error_estimate=error_estimate, verify=verify)
    if text:
        typer.echo(text)
    # NOT met, by a ladder or by --verify (docs/data_safety.md, "How a ladder ends"): 3
    completed = summary.get("status") == "completed"
    not_met = summary.get("accuracy_met") is False or verified is False
    raise typer.Exit(code=(3 if not_met else 0) if completed else 1)


@app.command()
def bench(
    level: int = typer.Option(..., "--level", help="mesh subdivision level"),
    viscosity_ratio: float = typer.Option(1.0, "--viscosity-ratio", help="lambda"),
    repeat: int = typer.Option(3, "--repeat", help="timed repetitions (1 to 1000)"),
    as_json: bool = typer.Option(False, "--json", help="print JSON"),
) -> None:
    """Time one velocity evaluation on a sphere mesh (options checked like a case's) and
    print its split per stage: membrane (geometry, strain, mass-matrix assembly and solve),
    single layer (Stokeslet sum, singular correction), velocity (normals, volume correction,
    the λ ≠ 1 solve), each in ms per evaluation and against the Stokeslet sum.

    Example:

    capsim bench --level 3 --viscosity-ratio 5 --repeat 5 --json
    """
    from capsim.runs.benchmark import bench_case, bench_velocity, split_lines
    from capsim.config import ConfigError

    try:
        bench_case(level, viscosity_ratio, repeat=repeat)
    except ConfigError as exc:
        raise _user_error(str(exc)) from None
    result = bench_velocity(level=level, viscosity_ratio=viscosity_ratio, repeat=repeat)
    if as_json:
        typer.echo(json.dumps(result, indent=2, default=str))
        return
    from capsim.face.display import key_value_lines

    typer.echo(key_value_lines({k: v for k, v in result.items() if k != "split_s"}))
    typer.echo(split_lines(result))


@app.command()
def fit(fit_path: Path = typer.Argument(..., metavar="FIT.yaml", help="fit file (docs/fit.md)"),
        workers: int = typer.Option(1, "--workers", min=1, help="local worker processes per evaluation"),
        quiet: bool = typer.Option(False, "--quiet", "-q", help="only the closing table")) -> None:
    """Infer case fields from measured run outputs: least squares over cached runs (a refit or a
    resumed fit reuses them); writes fit.json, summary.nc and fit.png in the fit's output dir.

    Examples:

    capsim fit fits/fit-modulus-shear.yaml
    """
    from capsim import api
    from capsim.campaigns.fit import FitError

    try:
        result = _files_call(api.fit, fit_path, workers=workers, progress=not quiet)
    except (FitError, KeyboardInterrupt) as exc:  # finished runs are kept: capsim fit again resumes
        typer.echo(f"error: {exc or 'interrupted'}; finished runs are kept, capsim fit again resumes", err=True)
        raise typer.Exit(code=1) from None
    if quiet:
        typer.echo(result.table())
    raise typer.Exit(code=0 if result.success else 1)


@app.command("warm-up")
def warm_up(
    case_paths: Optional[list[Path]] = typer.Argument(None, metavar="[CASE.yaml]...", help="case files"),
) -> None:
    """Compile the numba kernels these cases use (default: the default case's) into numba's cache,
    so that their first run computes at once (make venv does this for the demo).

    Examples:

    capsim warm-up configs/sphere.yaml

    capsim warm-up configs/rbc.yaml configs/rbc-viscous.yaml
    """
    from capsim import api

    cases = [_load(path) for path in case_paths or []]
    typer.echo(f"kernels ready in {api.warm_up(cases):.1f} s (compiled, or loaded from numba's cache)")


@app.command()
def validate(
    case_path: Path = typer.Argument(..., metavar="CASE.yaml|CAMPAIGN.yaml|FIT.yaml", help="case, campaign or fit file"),
    sets: Optional[list[str]] = typer.Option(None, "--set", metavar="FIELD=VALUE", help=_SET_HELP),
    max_runs: int = typer.Option(10_000, "--max-runs", help="a campaign: refuse more runs than this"),
) -> None:
    """Check a case file (print it resolved), dry-run a campaign (list its runs) or a fit (its plan).

    A case is printed with every default filled in; a campaign run by run: its id, what a sweep
    would do (run, skip it completed, extend it to a later t_end), its path and swept values.

    Examples:

    capsim validate configs/sphere.yaml --set mesh.level=2

    capsim validate campaigns/smoke.yaml

    capsim validate fits/fit-modulus-shear.yaml
    """
    from capsim.campaigns.inputs import describe

    typer.echo(_files_call(describe, case_path, sets, max_runs=max_runs), nl=False)


def _load_campaign(path: Path, sets: list[str] | None, max_runs: int, data: Any = None):
    """The campaign at `path` with --set fields written into its base; user errors exit 2."""
    from capsim.campaigns.campaign import load_campaign_with
    from capsim.config import ConfigError

    try:
        return load_campaign_with(path, sets, max_runs=max_runs, data=data)
    except ConfigError as exc:
        raise _user_error(str(exc)) from None


@app.command()
def units(
    shear_rate: Optional[str] = typer.Option(None, "--shear-rate", help="shear rate k, e.g. '100 1/s'"),
    viscosity: Optional[str] = typer.Option(None, "--viscosity", help="outer viscosity μ, e.g. '1.2 mPa*s'"),
    radius: Optional[str] = typer.Option(None, "--radius", help="equal-volume radius a, e.g. '2.8 um'"),
    surface_modulus: Optional[str] = typer.Option(
        None, "--surface-modulus", help="membrane elastic modulus E_s (a drop: surface tension), e.g. '18 uN/m'"),
    shear_modulus: Optional[str] = typer.Option(
        None, "--shear-modulus", help="surface shear modulus G_s = E_s/3 instead of E_s, e.g. '6 uN/m'"),
    membrane_viscosity: Optional[str] = typer.Option(
        None, "--membrane-viscosity", help="membrane surface shear viscosity μ_s, e.g. '2.5e-7 N*s/m' (gives Bq)"),
    capillary_number: Optional[float] = typer.Option(
        None, "--capillary-number", help="Ca = μka/G_s (flow.capillary_number): alone, gives G = Ca/3; with three "
        "of shear rate, viscosity, radius and modulus, solves for the fourth"),
    as_json: bool = typer.Option(False, "--json", help="print a JSON object (G, Ca, time_unit_s, ...)"),
) -> None:
    """Physical values to capsim's numbers: G = μka/E_s, Ca = μka/G_s = 3G and the time unit 1/k.

    Examples:

    capsim units --shear-rate '100 1/s' --viscosity '1.2 mPa*s' --radius '2.8 um' --shear-modulus '6 uN/m'

    capsim units --capillary-number 0.1 --viscosity '1.2 mPa*s' --radius '2.8 um' --shear-modulus '6 uN/m'
    """
    from capsim.units import check_given, conversion, describe_capillary, describe_conversion, from_capillary_number

    given = {"shear_rate": shear_rate, "viscosity": viscosity, "radius": radius,
             "surface_modulus": surface_modulus, "shear_modulus": shear_modulus,
             "membrane_viscosity": membrane_viscosity}
    if capillary_number is not None:
        out = _units_call(from_capillary_number, capillary_number, given)
        typer.echo(json.dumps(out) if as_json else describe_capillary(out))
        return
    _units_call(check_given, given)  # every value needed, each in its own units
    # values that overflow together (G = inf): one line, never Infinity in the JSON
    out = _units_call(conversion, shear_rate, viscosity, radius, surface_modulus, shear_modulus, membrane_viscosity)
    typer.echo(json.dumps(out) if as_json else describe_conversion(out))


def _units_call(fn, *args):
    from capsim.units import UnitsError

    try:
        return fn(*args)
    except UnitsError as exc:
        raise _user_error(f"units: {exc}") from None


def _version(value: bool) -> None:
    if value:
        from capsim._version import __version__

        typer.echo(f"capsim {__version__}")
        raise typer.Exit()


# Commands that run numba kernels: they report a thread setting taken from the user's environment.
_COMPUTING = ("run", "sweep", "study", "bench")


@app.callback()
def main(
    ctx: typer.Context,
    version: bool = typer.Option(
        False, "--version", callback=_version, is_eager=True, help="print the version"
    ),
) -> None:
    """Boundary-integral simulation of elastic capsules in simple shear flow."""
    # Before any command imports numba: threading layer, wait policy and thread count
    # (capsim.numerics.threads; NUMBA_NUM_THREADS, NUMBA_THREADING_LAYER, OMP_WAIT_POLICY of the user win).
    from capsim.numerics.threads import ThreadsError, apply_policy

    try:
        policy = apply_policy()
    except ThreadsError as exc:
        raise _user_error(str(exc)) from None
    if policy.user and ctx.invoked_subcommand in _COMPUTING:
        typer.echo(f"threads: {policy.describe()}", err=True)


@app.command()
def sweep(
    campaign_path: Path = typer.Argument(..., metavar="CAMPAIGN.yaml", help="campaign file"),
    workers: Optional[int] = typer.Option(
        None, "--workers", min=1,
        help="local worker processes, each with cores // workers numba threads (default: one per core)",
    ),
    scheduler: Optional[str] = typer.Option(None, "--scheduler", help="Dask scheduler address, tcp://host:port"),
    no_resume: bool = typer.Option(False, "--no-resume", help="redo runs that already completed"),
    overwrite: bool = typer.Option(
        False, "--overwrite", help="take over an output directory that holds another campaign"
    ),
    quiet: bool = typer.Option(False, "--quiet", "-q", help="no progress line"),
    max_runs: int = typer.Option(
        10_000, "--max-runs", help="refuse a campaign of more runs than this (checked before any case is built)"
    ),
    sets: Optional[list[str]] = typer.Option(None, "--set", metavar="FIELD=VALUE", help=_SET_HELP),
) -> None:
    """Run every case of a campaign (skipping completed runs) into its output directory.

    `capsim validate CAMPAIGN.yaml` lists the runs first (a dry run).

    Examples:

    capsim sweep campaigns/smoke.yaml --workers 2

    capsim sweep campaigns/fig4-spheres-lambda1.0.yaml --set time.scheme=rkc --set mesh.level=2
    """
    from capsim import api

    campaign = _load_campaign(campaign_path, sets, max_runs)
    try:
        result = _files_call(api.sweep, campaign, workers=workers, scheduler=scheduler, resume=not no_resume,
                             overwrite=overwrite, progress=not quiet)
    except KeyboardInterrupt:  # outside the batch (its stop is its own): before the runs, or as the index is written
        typer.echo("\ninterrupted: the run files keep each run's status; capsim sweep again resumes", err=True)
        raise typer.Exit(code=1) from None
    from capsim.face.display import print_sweep_result  # it names every run that did not complete, once

    print_sweep_result(result, campaign, table=not quiet)
    raise typer.Exit(code=0 if result["failed"] == 0 and not result["interrupted"] else 1)


@app.command()
def summarize(
    directory: Path = typer.Argument(..., metavar="DIR", help="campaign output directory"),
    output: Optional[Path] = typer.Option(None, "-o", "--output", help="netCDF path (default DIR/summary.nc)"),
    overwrite: bool = typer.Option(False, "--overwrite", help="replace an existing file that is not a summary"),
    units: UnitSystem = typer.Option("capsim", "--units", help="the variables' units: " + _UNITS_HELP),
) -> None:
    """Collect a campaign's runs into one xarray Dataset written as netCDF.

    Example:

    capsim summarize runs/fig9-11-13-spheres-level2 -o s.nc   (then: capsim plot s.nc --kind steady)
    """
    from capsim import api
    from capsim.config import ConfigError
    from capsim.units import UnitsError

    try:
        ds = _files_call(api.summarize, directory, output, overwrite=overwrite, units=units.value)
    except (FileNotFoundError, ConfigError, UnitsError) as exc:
        raise _user_error(str(exc)) from None
    path = api.summary_path(directory, output)
    counts = {s: int((ds["status"] == s).sum()) for s in sorted(set(ds["status"].values.ravel()))}
    typer.echo(f"{path}: dims {dict(ds.sizes)}, status {counts}")


@app.command()
def plot(
    paths: list[Path] = typer.Argument(
        ..., metavar="PATH...",
        help="run file (.h5), several for deformation, inclination, separation, migration and lift (overlaid), or "
             "campaign summary (.nc) or a campaign's output directory for --kind steady, orbit_map, conduit and lift",
    ),
    kind: PlotKind = typer.Option(..., "--kind", "-k", help="what to draw"),
    output: Optional[Path] = typer.Option(
        None, "-o", "--output", help="figure path; its suffix gives the format: .png, .pdf, .svg (default PATH_<kind>.png)"),
    dpi: Optional[float] = typer.Option(None, "--dpi", help="resolution of a PNG (default 100: 640 x 480 pixels)"),
    times: Optional[list[float]] = typer.Option(None, "--time", "-t", help="snapshot time kt (contour: repeatable; tensions: one)"),
    node: Optional[int] = typer.Option(None, "--node", help="trajectory: node index (default: the rest node at +x in z = 0)"),
    no_theory: bool = typer.Option(False, "--no-theory", help="leave out the first-order theory"),
    unwrap: bool = typer.Option(False, "--unwrap", help="inclination: continue θ through ±π/2 (default: break the line there)"),
    overwrite: bool = typer.Option(False, "--overwrite", help="replace an existing file that is not a figure of this format"),
    x: Optional[str] = typer.Option(None, "--x", help="steady, orbit_map, conduit: the swept field on the axis (default shear_rate_G, else the first numeric one)"),
    y: Optional[str] = typer.Option(None, "--y", help="orbit_map: the second swept field (default viscosity_ratio, else the next one)"),
    size: Optional[str] = typer.Option(None, "--size", metavar="W,H", help="figure size in inches, e.g. 3.3,2.5 (default 6.4,4.8)"),
    labels: Optional[list[str]] = typer.Option(None, "--label", help="legend label of each overlaid run, once per PATH in order (lift: per G)"),
    units: UnitSystem = typer.Option("capsim", "--units", help="the axes' units (--time stays kt): " + _UNITS_HELP),
) -> None:
    """Write a figure (PNG, PDF or SVG) of a run, or of a campaign summary for --kind steady, orbit_map, conduit, lift.

    Examples:

    capsim plot runs/sphere-G0.1.h5 --kind deformation -o fig.pdf

    capsim plot runs/fig4/*.h5 --kind inclination --dpi 200 -o fig4.png

    capsim plot runs/sphere-G0.1.h5 --kind contour -t 0 -t 2 -t 5

    capsim summarize runs/fig9 -o s.nc; capsim plot s.nc --kind steady -o steady.svg

    capsim plot s.nc --kind orbit_map --x shear_rate --y viscosity_ratio -o classes.png
    """
    from capsim.face.plot import FigureError, write_figure

    try:
        out = _files_call(write_figure, paths, kind.value, output, overwrite=overwrite, dpi=dpi,
                          theory=not no_theory, unwrap=unwrap, times=times, node=node, x=x, size=size, labels=labels,
                          units=units.value, y=y)
    except FigureError as exc:
        raise _user_error(str(exc)) from None
    typer.echo(str(out))


@app.command()
def export(
    path: Path = typer.Argument(..., metavar="RUN.h5", help="run file"),
    fmt: ExportFormat = typer.Option(
        "xdmf", "--format", "-f", help="xdmf (one .xdmf + .h5) or vtu (.vtu per snapshot + .pvd)"),
    output: Optional[Path] = typer.Option(None, "-o", "--output", help="output directory (default RUN_<format>/)"),
    no_fields: bool = typer.Option(False, "--no-fields", help="geometry and displacement only (no recomputed fields)"),
    overwrite: bool = typer.Option(False, "--overwrite", help="replace run files or checkpoints in the output directory"),
    units: UnitSystem = typer.Option("capsim", "--units", help="times, positions and fields in: " + _UNITS_HELP),
) -> None:
    """Write the surface mesh over time with membrane fields for ParaView.

    ParaView draws each quadratic element as flat sub-triangles (areas about 1 % low at level 2).

    Examples:

    capsim export runs/sphere-G0.1.h5   (then open runs/sphere-G0.1_xdmf/sphere-G0.1.xdmf)

    capsim export runs/sphere-G0.1.h5 --format vtu -o vtu/
    """
    from capsim.face.export import ExportError, export_to_dir

    try:
        files = _files_call(export_to_dir, path, output, fmt.value, fields=not no_fields, overwrite=overwrite,
                            units=units.value)
    except ExportError as exc:
        raise _user_error(str(exc)) from None
    typer.echo(f"{files[0]} ({len(files)} files)")


def _accuracy_option(text: str | None) -> tuple[str | None, float | None]:
    """--accuracy QUANTITY=TARGET as (quantity, target); a malformed one exits 2."""
    if text is None:
        return None, None
    quantity, _, target = text.partition("=")
    try:
        return quantity.strip(), float(target)
    except ValueError:
        raise _user_error(f"--accuracy {text!r}: give QUANTITY=TARGET, e.g. --accuracy D_xy=1e-3") from None


def _number_list(text: str, kind: type, option: str) -> list:
    try:
        values = [kind(v) for v in "".join(text.split()).split(",") if v]
    except ValueError:
        values = []
    if not values:
        raise _user_error(f"{option} must be a non-empty comma-separated list of {kind.__name__}s, got {text!r}")
    return values


@app.command()
def study(
    case_path: Path = typer.Argument(..., metavar="CASE.yaml", help="case file"),
    levels: str = typer.Option("2,3,4", "--levels", help="mesh levels, comma-separated"),
    rtols: str = typer.Option("1e-3,1e-4,1e-5", "--rtols", help="time.rtol values of the case's time.scheme, comma-separated"),
    quad: Optional[str] = typer.Option(None, "--quad", help="regular Gauss orders (points per element), comma-separated"),
    reference: StudyReference = typer.Option(
        "finest", "--reference", help="finest (run) or richardson (extrapolated in the level)"),
    quantity: str = typer.Option("shape", "--quantity", help="shape (D_xy, θ, TTF, S*xy at t_end) or orbit "
                                 "(the orbit period, orbit constant and body rotation of each run's summary)"),
    t_end: Optional[float] = typer.Option(None, "--t-end", help="override time.t_end"),
    workers: int = typer.Option(
        1, "--workers", min=1, help="runs side by side, in worker processes with cores // workers numba threads each"
    ),
    output: Path = typer.Option(Path("study.nc"), "-o", "--output", help="netCDF path; the Pareto plot goes next to it (.png)"),
    runs_dir: Optional[Path] = typer.Option(None, "--runs-dir", help="keep the run files here (default: discarded)"),
    overwrite: bool = typer.Option(
        False, "--overwrite", help="replace an existing output file, figure or run files in --runs-dir"),
    quiet: bool = typer.Option(False, "--quiet", "-q", help="no line per finished run"),
    sets: Optional[list[str]] = typer.Option(None, "--set", metavar="FIELD=VALUE", help=_SET_HELP),
) -> None:
    """Accuracy against cost: run a ladder of settings, print errors, wall time and observed order.

    Examples:

    capsim study configs/sphere.yaml --levels 1,2,3 --rtols 1e-3,1e-4 --t-end 2 --workers 2

    capsim study configs/sphere.yaml --levels 1,2,3 --reference richardson --set time.scheme=rkc
    """
    from capsim import api
    from capsim.campaigns.study import format_study_table

    level_list = _number_list(levels, int, "--levels")
    rtol_list = _number_list(rtols, float, "--rtols")
    quad_list = _number_list(quad, int, "--quad") if quad is not None else None
    if reference.value == "richardson" and len(set(level_list)) < 2:
        raise _user_error("--reference richardson needs at least two levels")
    if runs_dir is not None and runs_dir.exists() and not runs_dir.is_dir():
        raise _user_error(f"--runs-dir {runs_dir} is not a directory")
    case = _load(case_path, sets, **{"time.t_end": t_end})
    report = None if quiet else (lambda line: typer.echo(line, err=True))
    try:
        ds = _files_call(api.study, case, level_list, rtol_list, quad=quad_list, reference=reference.value,
                         workers=workers, output=output, runs_dir=runs_dir, overwrite=overwrite, progress=report,
                         quantity=quantity, inputs=[case_path])
    except KeyboardInterrupt:
        typer.echo("\ninterrupted", err=True)
        raise typer.Exit(code=1) from None
    typer.echo(format_study_table(ds))
    typer.echo(f"{output}, {output.with_suffix('.png')}")
    raise typer.Exit(code=0 if bool((ds["status"] == "completed").all()) else 1)


if __name__ == "__main__":
    app()

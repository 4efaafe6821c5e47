"""Command-line interface: each command loads its inputs and calls one library function.

Exit codes: 0 success, 1 the run ended unstable/failed/interrupted, 2 user error
(bad case file, bad option, unwritable output).
"""

from __future__ import annotations

import enum
import json
import math
import os
import sys
from pathlib import Path
from typing import Any, Optional

import typer
from typer.core import TyperGroup

try:  # typer >= 0.2x carries its own copy of click
    from typer import _click as click
except ImportError:  # pragma: no cover - older typer on the real click
    import click


class _OneLineErrors(TyperGroup):
    """Usage errors (a bad option value, an unknown option, a missing argument) as one
    line on stderr, exit 2, like every other user error of capsim."""

    def main(self, args=None, prog_name=None, complete_var=None, standalone_mode=True, **extra):
        if not standalone_mode:
            return super().main(args, prog_name, complete_var, standalone_mode=False, **extra)
        try:
            code = super().main(args, prog_name, complete_var, standalone_mode=False, **extra)
        except click.exceptions.UsageError as exc:
            if type(exc).__name__ == "NoArgsIsHelpError":  # the help was printed
                sys.exit(exc.exit_code)
            from capsim.errors import first_line

            where = exc.ctx.command_path if exc.ctx is not None else "capsim"
            text = first_line(Exception(exc.format_message()), type(exc).__name__).replace("Value error, ", "")
            typer.echo(f"error: {text.rstrip('.')}; see '{where} -h'", err=True)
            sys.exit(2)
        except click.exceptions.ClickException as exc:
            from capsim.errors import first_line

            typer.echo(f"error: {first_line(Exception(exc.format_message()), type(exc).__name__)}", err=True)
            sys.exit(exc.exit_code)
        except typer.Abort:
            typer.echo("aborted", err=True)
            sys.exit(1)
        sys.exit(code if isinstance(code, int) else 0)


app = typer.Typer(
    help="Boundary-integral simulation of elastic capsules in simple shear flow.",
    no_args_is_help=True,
    add_completion=True,
    pretty_exceptions_show_locals=False,
    context_settings={"help_option_names": ["-h", "--help"]},
    cls=_OneLineErrors,
)

# Choices, as enums so that --help lists them. Written out here (the CLI must not import
# matplotlib or h5py for --help); tests/test_registries.py checks them against the registries:
# plot kinds capsim.plot.KINDS, export formats capsim.export.FORMATS, study references
# capsim.study.REFERENCES, figure formats capsim.plot.FIGURE_FORMATS.
_PLOT_KINDS = ("deformation", "inclination", "contour", "trajectory", "tensions", "rheology", "steady")
_EXPORT_FORMATS = ("xdmf", "vtu")
_STUDY_REFERENCES = ("finest", "richardson")
_FIGURE_FORMATS = ("png", "pdf", "svg")
PlotKind = enum.Enum("PlotKind", {k: k for k in _PLOT_KINDS}, type=str)
ExportFormat = enum.Enum("ExportFormat", {k: k for k in _EXPORT_FORMATS}, type=str)
StudyReference = enum.Enum("StudyReference", {k: k for k in _STUDY_REFERENCES}, type=str)

#: --set FIELD=VALUE, repeatable (run, validate, sweep, study)
_SET_HELP = ("set a case field, dotted path = YAML value, repeatable: --set mesh.level=1 "
             "--set time.scheme=rkc (a campaign: a field of its base)")
#: longest --set text: a field path and a value, not a document
_SET_MAX = 1000


def _user_error(message: str) -> typer.Exit:
    typer.echo(f"error: {message}", err=True)
    return typer.Exit(code=2)


def _parse_sets(sets: list[str] | None) -> dict[str, Any]:
    """--set FIELD=VALUE options as {dotted field: value}; a bad one is a one-line user error."""
    from capsim.errors import bounded_repr

    out: dict[str, Any] = {}
    for text in sets or ():
        shown = bounded_repr(text)
        if len(text) > _SET_MAX:
            raise _user_error(f"--set {shown}: at most {_SET_MAX} characters")
        key, sep, raw = text.partition("=")
        key = key.strip()
        if not sep or not key or any(not part.isidentifier() for part in key.split(".")):
            raise _user_error(f"--set {shown}: give FIELD=VALUE with a dotted case field, e.g. --set mesh.level=2")
        import yaml

        try:
            value = yaml.safe_load(raw) if raw.strip() else None
        except yaml.YAMLError as exc:
            from capsim.errors import first_line

            raise _user_error(f"--set {shown}: the value is not YAML ({first_line(exc)})") from None
        if value is None:
            raise _user_error(f"--set {shown}: no value after '='")
        if key in out:
            raise _user_error(f"--set {key} is given twice")
        out[key] = value
    return out


def _load(case_path: Path, sets: list[str] | None = None, **overrides: Any):
    # Imported here so that `capsim --help` does not pay for pydantic.
    from capsim.config import ConfigError, apply_overrides, load_case

    dotted = _parse_sets(sets)
    for key, value in overrides.items():
        if value is not None:
            if key in dotted:
                raise _user_error(f"--set {key} and its own option both given; give one")
            dotted[key] = value
    try:
        case = load_case(case_path)
    except ConfigError as exc:
        raise _user_error(str(exc)) from None
    try:
        return apply_overrides(case, **dotted) if dotted else case
    except ConfigError as exc:
        text = str(exc)
        prefix = "<overrides>: "
        raise _user_error(f"{case_path}: --set/options: {text[len(prefix):] if text.startswith(prefix) else text}") from None


def _check_writable(path: Path) -> None:
    """Refuse an output path we cannot write before spending time on a run."""
    if path.is_dir():
        raise _user_error(f"output path {path} is a directory")
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise _user_error(f"output path {path}: cannot create its directory {path.parent}: {exc.strerror}") from None
    if not os.access(path.parent, os.W_OK) or (path.exists() and not os.access(path, os.W_OK)):
        raise _user_error(f"output path {path} is not writable")


def _same_file(a: Path, b: Path) -> bool:
    try:
        return a.exists() and b.exists() and os.path.samefile(a, b)
    except OSError:
        return False


def _protected(path: Path) -> str | None:
    """What an existing file is that no command replaces unless told to (--overwrite); None if not one."""
    from capsim.campaign import CAMPAIGN_FILE, INDEX_FILE
    from capsim.store import is_run_file

    if path.name in (CAMPAIGN_FILE, INDEX_FILE):
        return "a campaign's own file"
    if path.name.endswith(".ckpt.npz"):
        return "a restart checkpoint"
    if is_run_file(path):
        return "a capsim run file"
    return None


def _guard_output(out: Path, inputs: list[Path], overwrite: bool, *, ours=lambda p: False,
                  option: str = "--overwrite") -> None:
    """Refuse (exit 2, one line) to write over one of the command's inputs (never), or
    over an existing file it does not write itself (``ours``) or that is a run file,
    a checkpoint or a campaign file, unless `overwrite`."""
    for source in inputs:
        if _same_file(out, source):
            raise _user_error(f"output path {out} is this command's input {source}; choose another output")
    if out.exists() and not out.is_dir() and not overwrite:
        kind = _protected(out)
        if kind is not None or not ours(out):
            raise _user_error(f"output path {out} exists ({kind or 'a file this command did not write'}); "
                              f"nothing was changed: choose another output, or pass {option} to replace it")


def _starts_with(magic: bytes):
    def check(path: Path) -> bool:
        try:
            with open(path, "rb") as fh:
                return fh.read(len(magic)) == magic
        except OSError:
            return False
    return check


def _is_summary(path: Path) -> bool:
    """A netCDF file written by `capsim summarize` (its campaign_yaml attribute)."""
    import h5py

    try:
        with h5py.File(path, "r", locking=False) as f:
            return "campaign_yaml" in f.attrs and "config_yaml" not in f.attrs
    except (OSError, ValueError):
        return False


def _replace_atomically(out: Path, write) -> None:
    """``write(tmp)`` to a temporary name next to `out`, then move it into place:
    a failure (a full disk) leaves `out` as it was; exit 2 with one line."""
    tmp = out.with_name(f".{out.stem}.tmp-{os.getpid()}{out.suffix}")
    try:
        write(tmp)
        os.replace(tmp, out)
    except (OSError, RuntimeError) as exc:
        tmp.unlink(missing_ok=True)
        from capsim.errors import first_line

        raise _user_error(f"cannot write {out}: {getattr(exc, 'strerror', None) or first_line(exc)}; "
                          "nothing was changed") from None
    finally:
        tmp.unlink(missing_ok=True)


def _run_progress():
    """rich.progress in a terminal, plain periodic lines otherwise (capsim.display)."""
    from capsim.display import RunProgress

    return RunProgress()


def _fmt(value: Any, spec: str) -> str:
    if isinstance(value, (int, float)) and not isinstance(value, bool):
        return format(value, spec)
    return "n/a" if value is None else str(value)


def _mean_std(summary: dict[str, Any], name: str, scale: float = 1.0) -> str | None:
    """'mean ± std' over the averaging window, or None when the run has no summary."""
    mean, std = summary.get(name), summary.get(f"{name}_std")
    if not isinstance(mean, (int, float)):
        return None
    shown = f"{mean / scale:.6f}"
    return shown + (f" ± {std / scale:.2e}" if isinstance(std, (int, float)) else "")


def _compression(summary: dict[str, Any]) -> str | None:
    """Share of the membrane under compression at the end, with a warning when large.

    A membrane without bending stiffness cannot carry compression: where the smaller
    principal tension is negative a real capsule wrinkles, and where the compression
    persists the computed solution comes to depend on the mesh (README, "Compressed
    membranes and bending stiffness").
    """
    frac, low = summary.get("compressed_fraction"), summary.get("min_tension")
    if not isinstance(frac, float):
        return None
    text = f"{100 * frac:.0f} % (smallest tension {low:.3g} μka)"
    if frac > 0.05:
        if summary.get("bending_modulus", 0.0) > 0:
            text += f": held by the bending modulus {summary['bending_modulus']:g}; check mesh convergence"
        else:
            text += (": would wrinkle without bending; rerun with --set membrane.bending_modulus=1e-4 "
                     "(README, \"Compressed membranes and bending stiffness\")")
    return text


def _summary_rows(summary: dict[str, Any]) -> list[tuple[str, str]]:
    """The closing table of a run: (quantity, value) rows, those without a value left out."""
    period = summary.get("period")
    window = (summary.get("averaging_t_from"), summary.get("averaging_t_to"))
    rows = [
        ("status", summary.get("status")),
        ("reason", summary.get("status_reason") or None),
        ("t", _fmt(summary.get("t"), "g")),
        ("motion", summary.get("motion")),
        ("averaged over kt", f"[{window[0]:.4g}, {window[1]:.4g}]" if None not in window else None),
        ("period kT", _fmt(period, ".4g") if isinstance(period, float) and math.isfinite(period) else None),
        ("D_xy", _mean_std(summary, "D_xy")),
        ("theta/pi", _mean_std(summary, "theta", math.pi)),
        ("TTF/f_s", _mean_std(summary, "ttf_ratio")),
        ("S*_xy", _mean_std(summary, "Sxy_star")),
        ("N1*", _mean_std(summary, "N1_star")),
        ("N2*", _mean_std(summary, "N2_star")),
        ("scheme", summary.get("scheme")),
        ("steps", _fmt(summary.get("steps"), "d")),
        ("velocity evaluations", _fmt(summary.get("velocity_evaluations"), "d")),
        ("layer applications", _fmt(summary.get("layer_applications"), "d")),
        # only the linearly implicit scheme solves stage equations
        ("stage-solve iterations", _fmt(summary.get("linear_iterations"), "d") if summary.get("linear_iterations") else None),
        ("layer matrices", _fmt(summary.get("layer_matrices"), "d") if summary.get("layer_matrices") else None),
        ("wall time (s)", _fmt(summary.get("wall_time_s"), ".1f")),
        ("volume drift", _fmt(summary.get("volume_drift"), ".3e")),
        ("compressed vertices", _compression(summary)),
        ("output", summary.get("path")),
    ]
    return [(key, str(value)) for key, value in rows if value is not None]


def _summary_table(summary: dict[str, Any]) -> str:
    """The closing table as plain aligned text."""
    rows = _summary_rows(summary)
    width = max(len(key) for key, _ in rows)
    return "\n".join(f"{key:<{width}}  {value}" for key, value in rows)


def _print_summary(summary: dict[str, Any], title: str | None = None) -> None:
    from capsim.display import print_table

    print_table(_summary_rows(summary), title=title)


@app.command()
def run(
    case_path: Path = typer.Argument(..., metavar="CASE.yaml", help="case file"),
    output: Optional[Path] = typer.Option(None, "-o", "--output", help="output HDF5 path"),
    error_estimate: bool = typer.Option(
        False, "--error-estimate", help="also run one level coarser and rtol x 10; store the differences"
    ),
    t_end: Optional[float] = typer.Option(None, "--t-end", help="override time.t_end"),
    level: Optional[int] = typer.Option(None, "--level", help="override mesh.level"),
    quiet: bool = typer.Option(False, "--quiet", "-q", help="no progress line"),
    resume: bool = typer.Option(
        False, "--resume", help="continue an interrupted run from its checkpoint <output>.ckpt.npz"
    ),
    overwrite: bool = typer.Option(False, "--overwrite", help="replace an existing file at the output path"),
    sets: Optional[list[str]] = typer.Option(None, "--set", metavar="FIELD=VALUE", help=_SET_HELP),
) -> None:
    """Run one case and write its trajectory (or, with --resume, finish an interrupted one).

    Examples:

    capsim run configs/sphere.yaml

    capsim run configs/sphere.yaml --set mesh.level=2 --set time.scheme=rkc -o runs/s.h5

    capsim run configs/sphere.yaml --resume   (after an interruption)
    """
    case = _load(
        case_path,
        sets,
        **{
            "output.path": str(output) if output is not None else None,
            "time.t_end": t_end,
            "mesh.level": level,
        },
    )
    out = Path(case.output.path)
    _check_writable(out)
    _guard_output(out, [case_path], overwrite or resume, option="--overwrite (or --resume to continue it)")
    for derived in (Path(f"{out}.ckpt.npz"), Path(f"{out}.lock")):
        _guard_output(derived, [case_path], True)

    from capsim.runner import ResumeError, run_case
    from capsim.store import LockedError, StorageError

    progress = None if quiet else _run_progress()
    try:
        summary = run_case(case, progress=progress, resume=resume)
    except ResumeError as exc:
        raise _user_error(f"cannot resume: {exc}") from None
    except (LockedError, StorageError) as exc:
        raise _user_error(str(exc)) from None
    except OSError as exc:
        raise _user_error(f"cannot write {case.output.path}: {exc.strerror or exc}") from None
    except KeyboardInterrupt:
        typer.echo("\ninterrupted", err=True)
        raise typer.Exit(code=1) from None
    finally:
        if progress is not None:
            progress.finish()
    _print_summary(summary, title=case.name)
    if error_estimate and summary.get("status") == "completed":
        from capsim.study import run_error_estimate

        typer.echo(run_error_estimate(case, summary))
    raise typer.Exit(code=0 if summary.get("status") == "completed" else 1)


@app.command()
def bench(
    level: int = typer.Option(..., "--level", help="mesh subdivision level"),
    viscosity_ratio: float = typer.Option(1.0, "--viscosity-ratio", help="lambda"),
    repeat: int = typer.Option(3, "--repeat", help="timed repetitions (1 to 1000)"),
    as_json: bool = typer.Option(False, "--json", help="print JSON"),
) -> None:
    """Time one velocity evaluation on a sphere mesh (options checked like a case's).

    Example:

    capsim bench --level 3 --viscosity-ratio 5 --repeat 5 --json
    """
    from capsim.benchmark import bench_case, bench_velocity
    from capsim.config import ConfigError

    try:
        bench_case(level, viscosity_ratio, repeat=repeat)
    except ConfigError as exc:
        raise _user_error(str(exc)) from None
    result = bench_velocity(level=level, viscosity_ratio=viscosity_ratio, repeat=repeat)
    if as_json:
        typer.echo(json.dumps(result, indent=2, default=str))
        return
    width = max((len(key) for key in result), default=0)
    for key, value in result.items():
        if isinstance(value, float):
            shown = f"{value:.6g}"
        elif isinstance(value, (str, int)):
            shown = str(value)
        else:
            shown = json.dumps(value, default=str)
        typer.echo(f"{key:<{width}}  {shown}")


@app.command()
def validate(
    case_path: Path = typer.Argument(..., metavar="CASE.yaml|CAMPAIGN.yaml", help="case or campaign file"),
    sets: Optional[list[str]] = typer.Option(None, "--set", metavar="FIELD=VALUE", help=_SET_HELP),
    max_runs: int = typer.Option(10_000, "--max-runs", help="a campaign: refuse more runs than this"),
) -> None:
    """Check a case file (print it resolved) or dry-run a campaign (list its runs).

    A case is printed with every default filled in. A campaign is listed run by run:
    its run id, whether `capsim sweep` would run it or skip it (completed), its output
    path and swept values.

    Examples:

    capsim validate configs/sphere.yaml --set mesh.level=2

    capsim validate campaigns/smoke.yaml
    """
    from capsim.config import ConfigError, read_yaml

    try:
        data = read_yaml(case_path)
    except ConfigError as exc:
        raise _user_error(str(exc)) from None
    if not _is_campaign(data):
        typer.echo(_load(case_path, sets).to_yaml(), nl=False)
        return
    campaign = _load_campaign(case_path, sets, max_runs, data=data)
    from capsim.campaign import expand_campaign
    from capsim.store import read_run_status

    specs = expand_campaign(campaign, source=str(case_path))
    actions = ["skip (completed)" if read_run_status(spec.path) == "completed" else "run" for spec in specs]
    typer.echo(f"{campaign.name}: {len(specs)} runs, {actions.count('run')} to run -> {campaign.output.dir}")
    width = max(len(spec.run_id) for spec in specs)
    for spec, action in zip(specs, actions):
        swept = ", ".join(f"{k}={v}" for k, v in spec.params.items())
        typer.echo(f"{spec.run_id:<{width}}  {action:<16}  {spec.path}" + (f"  {swept}" if swept else ""))


def _is_campaign(data: Any) -> bool:
    """A campaign file's top level (base, sweep or zip); a case has none of them."""
    return isinstance(data, dict) and any(key in data for key in ("base", "sweep", "zip"))


def _load_campaign(path: Path, sets: list[str] | None, max_runs: int, data: Any = None):
    """The campaign at `path` with --set fields written into its base; user errors exit 2."""
    from capsim.campaign import campaign_from_dict
    from capsim.config import ConfigError, read_yaml

    if max_runs < 1:
        raise _user_error(f"--max-runs = {max_runs}: must be >= 1")
    dotted = _parse_sets(sets)
    try:
        data = read_yaml(path) if data is None else data
        if dotted and isinstance(data, dict):
            data = dict(data)
            base = json.loads(json.dumps(data.get("base") or {}, default=str)) if isinstance(
                data.get("base") or {}, dict) else data.get("base")
            for key, value in dotted.items():
                if key in (data.get("sweep") or {}) or key in (data.get("zip") or {}):
                    raise _user_error(f"--set {key}: the campaign sweeps this field; change its sweep instead")
                node = base
                parts = key.split(".")
                for part in parts[:-1]:
                    if not isinstance(node, dict):
                        break
                    node = node.setdefault(part, {})
                if not isinstance(node, dict):
                    raise _user_error(f"--set {key}: '{'.'.join(parts[:-1])}' is not a section of the case")
                node[parts[-1]] = value
            data["base"] = base
        return campaign_from_dict(data, source=str(path), max_runs=max_runs)
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
    as_json: bool = typer.Option(False, "--json", help="print a JSON object (G, Ca, time_unit_s, ...)"),
) -> None:
    """Physical values to capsim's numbers: G = μka/E_s, Ca = μka/G_s = 3G and the time unit 1/k.

    Example:

    capsim units --shear-rate '100 1/s' --viscosity '1.2 mPa*s' --radius '2.8 um' --shear-modulus '6 uN/m'
    """
    from capsim.units import UnitsError, conversion, parse

    given = {"shear_rate": shear_rate, "viscosity": viscosity, "radius": radius,
             "surface_modulus": surface_modulus, "shear_modulus": shear_modulus,
             "membrane_viscosity": membrane_viscosity}
    missing = [f"--{k.replace('_', '-')}" for k in ("shear_rate", "viscosity", "radius") if given[k] is None]
    if (surface_modulus is None) == (shear_modulus is None):
        missing.append("--surface-modulus or --shear-modulus (one of the two)" if surface_modulus is None
                       else "only one of --surface-modulus and --shear-modulus")
    if missing:
        raise _user_error(f"units: give {', '.join(missing)} (quantities with units, e.g. --radius '2.8 um')")
    for kind, value in given.items():
        if value is not None:
            try:
                parse(value, kind)
            except UnitsError as exc:
                raise _user_error(f"units: --{kind.replace('_', '-')}: {exc}") from None
    out = conversion(shear_rate, viscosity, radius, surface_modulus, shear_modulus, membrane_viscosity)
    if as_json:
        typer.echo(json.dumps(out))
        return
    typer.echo(f"G  = mu k a / E_s  = {out['G']:.6g}   (flow.shear_rate_G)")
    typer.echo(f"Ca = mu k a / G_s  = {out['Ca']:.6g}   (= 3 G: G_s = E_s / 3 for every elastic law)")
    typer.echo(f"time unit 1/k      = {out['time_unit_s']:.6g} s   (kt = 1)")
    typer.echo(f"E_s = {out['E_s_N_per_m']:.6g} N/m, G_s = {out['G_s_N_per_m']:.6g} N/m, "
               f"velocity unit ka = {out['velocity_m_per_s']:.6g} m/s, tension unit mu k a = "
               f"{out['tension_N_per_m']:.6g} N/m")
    if "Bq" in out:
        typer.echo(f"Bq = mu_s / (mu a) = {out['Bq']:.6g}   (membrane.viscosity.shear); membrane time "
                   f"mu_s / G_s = {out['membrane_time_s']:.6g} s (k tau = Bq Ca = {out['Bq'] * out['Ca']:.6g})")


def _version(value: bool) -> None:
    if value:
        from capsim import __version__

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
    # (capsim.threads; NUMBA_NUM_THREADS, NUMBA_THREADING_LAYER, OMP_WAIT_POLICY of the user win).
    from capsim.threads import apply_policy

    policy = apply_policy()
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
    from capsim.campaign import run_campaign
    from capsim.config import ConfigError
    from capsim.store import LockedError, StorageError

    campaign = _load_campaign(campaign_path, sets, max_runs)
    progress = None
    if not quiet:
        from capsim.campaign import expand_campaign
        from capsim.display import SweepProgress

        t_end = {spec.run_id: spec.case().time.t_end for spec in expand_campaign(campaign)}
        progress = SweepProgress(t_end)
    try:
        result = run_campaign(campaign, workers=workers, scheduler=scheduler, resume=not no_resume, progress=progress,
                              overwrite=overwrite)
    except (ConfigError, LockedError, StorageError) as exc:
        raise _user_error(str(exc)) from None
    finally:
        if progress is not None:
            progress.finish()
    for record in result["records"]:
        if record["status"] != "completed":
            typer.echo(f"{record['run_id']}: {record['status']}: {record['status_reason']}", err=True)
    if result["records"] and not quiet:
        from capsim.display import print_table

        def cell(record: dict, key: str, spec: str) -> str:
            summary = record.get("summary") or {}
            return _fmt(summary.get(key), spec) if key in summary else ""

        print_table([(r["run_id"], r["status"], cell(r, "t", ".4g"), cell(r, "D_xy", ".5f"),
                      cell(r, "wall_time_s", ".1f"), r.get("status_reason") or "")
                     for r in result["records"]],
                    columns=("run", "status", "kt", "D_xy", "wall (s)", "reason"), title=campaign.name)
    not_started = result["total"] - result["skipped"] - result["completed"] - result["failed"]
    typer.echo(
        f"{campaign.name}: {result['total']} runs, {result['skipped']} skipped, {result['completed']} completed, "
        f"{result['failed']} not completed{' (interrupted)' if result['interrupted'] else ''}"
        + (f", {not_started} not started" if not_started > 0 else "")
        + f" -> {campaign.output.dir}"
    )
    raise typer.Exit(code=0 if result["failed"] == 0 and not result["interrupted"] else 1)


@app.command()
def summarize(
    directory: Path = typer.Argument(..., metavar="DIR", help="campaign output directory"),
    output: Optional[Path] = typer.Option(None, "-o", "--output", help="netCDF path (default DIR/summary.nc)"),
    overwrite: bool = typer.Option(False, "--overwrite", help="replace an existing file that is not a summary"),
) -> None:
    """Collect a campaign's runs into one xarray Dataset written as netCDF.

    Example:

    capsim summarize runs/fig9-11-13-spheres-level2 -o s.nc   (then: capsim plot s.nc --kind steady)
    """
    from capsim.config import ConfigError
    from capsim.summary import summarize_campaign, write_summary

    try:
        ds = summarize_campaign(directory)
    except (FileNotFoundError, ConfigError) as exc:
        raise _user_error(str(exc)) from None
    path = output if output is not None else directory / "summary.nc"
    _check_writable(path)
    from capsim.campaign import CAMPAIGN_FILE, INDEX_FILE
    from capsim.store import is_run_file

    inputs = [directory / CAMPAIGN_FILE, directory / INDEX_FILE]
    if path.exists() and path.resolve().parent == directory.resolve() and is_run_file(path):
        inputs.append(path)  # one of the campaign's runs
    _guard_output(path, inputs, overwrite, ours=_is_summary)
    _replace_atomically(path, lambda tmp: write_summary(ds, tmp))
    counts = {s: int((ds["status"] == s).sum()) for s in sorted(set(ds["status"].values.ravel()))}
    typer.echo(f"{path}: dims {dict(ds.sizes)}, status {counts}")


_FIGURE_MAGIC = {"png": b"\x89PNG\r\n\x1a\n", "pdf": b"%PDF-", "svg": b"<?xml"}


@app.command()
def plot(
    paths: list[Path] = typer.Argument(
        ..., metavar="PATH...",
        help="run file (.h5), several for deformation/inclination (overlaid), or campaign summary (.nc) for --kind steady",
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
) -> None:
    """Write a figure (PNG, PDF or SVG) of a run, or of a campaign summary for --kind steady.

    Examples:

    capsim plot runs/sphere-G0.1.h5 --kind deformation -o fig.pdf

    capsim plot runs/fig4/*.h5 --kind inclination --dpi 200 -o fig4.png

    capsim plot runs/sphere-G0.1.h5 --kind contour -t 0 -t 2 -t 5

    capsim summarize runs/fig9 -o s.nc; capsim plot s.nc --kind steady -o steady.svg
    """
    from capsim import plot as plotting
    from capsim.config import ConfigError
    from capsim.errors import first_line
    from capsim.store import TrajectoryError

    kind = kind.value
    if len(paths) > 1 and kind not in plotting.OVERLAY_KINDS:
        raise _user_error(
            f"--kind {kind} takes one PATH, got {len(paths)}; "
            f"several runs overlay only for {', '.join(plotting.OVERLAY_KINDS)}"
        )
    for path in paths:
        if not path.exists():
            raise _user_error(f"{path}: no such file")
        if path.is_dir():
            raise _user_error(f"{path}: is a directory; give a run file (.h5) or a summary (.nc)")
    if dpi is not None and not (math.isfinite(dpi) and 10 <= dpi <= 2400):
        raise _user_error(f"--dpi {dpi:g}: must be in [10, 2400]")
    path = paths[0]
    out = output if output is not None else plotting.default_output(path, kind)
    try:
        fmt = plotting.figure_format(out)
    except ValueError as exc:
        _guard_output(out, list(paths), overwrite)  # an input or a run file named as output: say that first
        raise _user_error(str(exc)) from None
    _check_writable(out)
    _guard_output(out, list(paths), overwrite, ours=_starts_with(_FIGURE_MAGIC[fmt]))
    options: dict[str, Any] = {}
    if kind in ("deformation", "inclination", "rheology", "steady"):
        options["theory"] = not no_theory
    if kind == "inclination" and unwrap:
        options["unwrap"] = True
    if kind == "contour" and times:
        options["times"] = times
    if kind == "tensions" and times:
        options["t"] = times[-1]
    if kind == "trajectory" and node is not None:
        options["node"] = node

    source: Any = [str(p) for p in paths] if len(paths) > 1 else path
    try:
        _replace_atomically(out, lambda tmp: plotting.plot(source, kind, tmp, dpi=dpi, fmt=fmt, **options))
    except (TrajectoryError, ConfigError, ValueError, KeyError) as exc:
        raise _user_error(first_line(exc)) from None
    except OSError as exc:
        raise _user_error(f"{path}: {exc.strerror or first_line(exc)}") from None
    except Exception as exc:  # noqa: BLE001 - a file that is not what --kind needs: one line, not a traceback
        raise _user_error(f"cannot plot {path} as --kind {kind}: {type(exc).__name__}: {first_line(exc)}") from None
    typer.echo(str(out))


@app.command()
def export(
    path: Path = typer.Argument(..., metavar="RUN.h5", help="run file"),
    fmt: ExportFormat = typer.Option(
        "xdmf", "--format", "-f", help="xdmf (one .xdmf + .h5) or vtu (.vtu per snapshot + .pvd)"),
    output: Optional[Path] = typer.Option(None, "-o", "--output", help="output directory (default RUN_<format>/)"),
    no_fields: bool = typer.Option(False, "--no-fields", help="geometry and displacement only (no recomputed fields)"),
    overwrite: bool = typer.Option(False, "--overwrite", help="replace run files or checkpoints in the output directory"),
) -> None:
    """Write the surface mesh over time with membrane fields for ParaView.

    ParaView draws each quadratic element as flat sub-triangles (areas about 1 % low at level 2).

    Examples:

    capsim export runs/sphere-G0.1.h5   (then open runs/sphere-G0.1_xdmf/sphere-G0.1.xdmf)

    capsim export runs/sphere-G0.1.h5 --format vtu -o vtu/
    """
    from capsim.config import ConfigError
    from capsim.errors import first_line
    from capsim.export import export_run
    from capsim.store import TrajectoryError, is_run_file

    fmt = fmt.value
    if not path.exists():
        raise _user_error(f"{path}: no such file")
    if not is_run_file(path):
        raise _user_error(f"{path}: not a capsim run file (an HDF5 file written by capsim run or sweep)")
    out_dir = output if output is not None else path.with_name(f"{path.stem}_{fmt}")
    if out_dir.exists() and not out_dir.is_dir():
        raise _user_error(f"output path {out_dir} is not a directory")
    if out_dir.is_dir():  # the files it will write: <stem>.xdmf, <stem>_data.h5 | <stem>_NNNN.vtu, <stem>.pvd
        planned = [out_dir / f"{path.stem}.xdmf", out_dir / f"{path.stem}_data.h5", out_dir / f"{path.stem}.pvd"]
        planned += sorted(out_dir.glob(f"{path.stem}_[0-9][0-9][0-9][0-9].vtu"))
        for target in planned:
            _guard_output(target, [path], overwrite, ours=lambda p: _protected(p) is None)
    try:
        files = export_run(path, out_dir, fmt, fields=not no_fields)
    except (TrajectoryError, ConfigError, ValueError) as exc:
        raise _user_error(first_line(exc)) from None
    except OSError as exc:
        raise _user_error(f"cannot write {out_dir}: {exc.strerror or first_line(exc)}") from None
    except Exception as exc:  # noqa: BLE001 - one line, not a traceback
        raise _user_error(f"cannot export {path}: {type(exc).__name__}: {first_line(exc)}") from None
    typer.echo(f"{files[0]} ({len(files)} files)")


def _number_list(text: str, kind: type, option: str) -> list:
    try:
        values = [kind(v) for v in text.replace(" ", "").split(",") if v]
    except ValueError:
        raise _user_error(f"{option} must be a comma-separated list of {kind.__name__}s, got {text!r}") from None
    if not values:
        raise _user_error(f"{option} is empty")
    return values


@app.command()
def study(
    case_path: Path = typer.Argument(..., metavar="CASE.yaml", help="case file"),
    levels: str = typer.Option("2,3,4", "--levels", help="mesh levels, comma-separated"),
    rtols: str = typer.Option("1e-3,1e-4,1e-5", "--rtols", help="RKF23 tolerances, comma-separated"),
    quad: Optional[str] = typer.Option(None, "--quad", help="regular Gauss orders (points per element), comma-separated"),
    reference: StudyReference = typer.Option(
        "finest", "--reference", help="finest (run) or richardson (extrapolated in the level)"),
    t_end: Optional[float] = typer.Option(None, "--t-end", help="override time.t_end"),
    workers: int = typer.Option(
        1, "--workers", min=1, help="runs side by side, in worker processes with cores // workers numba threads each"
    ),
    output: Path = typer.Option(Path("study.nc"), "-o", "--output", help="netCDF path; the Pareto plot goes next to it (.png)"),
    runs_dir: Optional[Path] = typer.Option(None, "--runs-dir", help="keep the run files here (default: discarded)"),
    quiet: bool = typer.Option(False, "--quiet", "-q", help="no line per finished run"),
    sets: Optional[list[str]] = typer.Option(None, "--set", metavar="FIELD=VALUE", help=_SET_HELP),
) -> None:
    """Accuracy against cost: run a ladder of settings, print errors, wall time and observed order.

    Examples:

    capsim study configs/sphere.yaml --levels 1,2,3 --rtols 1e-3,1e-4 --t-end 2 --workers 2

    capsim study configs/sphere.yaml --levels 1,2,3 --reference richardson --set time.scheme=rkc
    """
    from capsim.config import ConfigError
    from capsim.study import format_study_table, plot_pareto, run_study, write_study

    reference = reference.value
    level_list = _number_list(levels, int, "--levels")
    rtol_list = _number_list(rtols, float, "--rtols")
    quad_list = _number_list(quad, int, "--quad") if quad is not None else None
    if reference == "richardson" and len(set(level_list)) < 2:
        raise _user_error("--reference richardson needs at least two levels")
    case = _load(case_path, sets, **{"time.t_end": t_end})
    _check_writable(output)
    report = None if quiet else (lambda line: typer.echo(line, err=True))
    try:
        ds = run_study(case, level_list, rtol_list, regular_orders=quad_list, reference=reference,
                       workers=workers, out_dir=runs_dir, progress=report)
    except ConfigError as exc:
        raise _user_error(str(exc)) from None
    except KeyboardInterrupt:
        typer.echo("\ninterrupted", err=True)
        raise typer.Exit(code=1) from None
    typer.echo(format_study_table(ds))
    write_study(ds, output)
    png = plot_pareto(ds, output.with_suffix(".png"))
    typer.echo(f"{output}, {png}")
    raise typer.Exit(code=0 if bool((ds["status"] == "completed").all()) else 1)


if __name__ == "__main__":
    app()

"""Accuracy against cost: a ladder of settings, errors against a reference, wall time.

:func:`run_study` runs one case over a ladder of mesh levels × time tolerances (of the case's time.scheme)
(× regular Gauss orders, optionally), in a process pool, and returns an xarray
Dataset with, for every setting, the raw values of the observables at ``t_end``,
their errors against the reference, the wall time, the number of steps and the
volume drift. The reference is the finest run (highest level, smallest rtol,
highest Gauss order) or a Richardson extrapolation in the mesh level of the
finest-tolerance runs.

Errors are taken at the same instant ``t = t_end`` for every setting (the last
row of each trajectory; every run ends exactly at ``t_end``), so that a run still
in its start-up transient is compared like for like; ``ttf_ratio`` is the
instantaneous tank-treading ratio of the time series at ``t_end``.

Observed order in the mesh level, per quantity, at each tolerance:

- ``<q>_order``: ``log2(|e_l| / |e_{l+1}|)`` with ``e`` the error against the
  reference (NaN where ``e_{l+1} = 0``, i.e. the reference itself);
- ``<q>_order3``: the classic three-level estimate
  ``log2(|f_l − f_{l+1}| / |f_{l+1} − f_{l+2}|)``, independent of the reference.

The mesh spacing halves with every level, so ``p`` is the order in ``h``.

:func:`run_error_estimate` is ``capsim run --error-estimate``: it reruns a case
one level coarser and with a ten times looser tolerance and stores
``|Δ_mesh| + |Δ_time|`` for each summary value in the run file's
``error_estimate`` group.
"""

from __future__ import annotations

import math
import os
import shutil
import sys
import tempfile
from collections.abc import Mapping
from datetime import datetime, timezone
from pathlib import Path
from typing import Any, Callable, Sequence

import numpy as np

from capsim.solve.accuracy import observed_order
from capsim.config import Case, apply_overrides
from capsim.quantities import attrs_for, global_attrs

__all__ = [
    "QUANTITIES",
    "REFERENCES",
    "analyse_study",
    "error_estimate",
    "format_error_estimate",
    "format_study_table",
    "plot_pareto",
    "run_error_estimate",
    "run_verification",
    "check_run",
    "run_study",
    "write_error_estimate",
    "write_study",
]

#: Observables whose error the study reports (quantity "shape": values at t_end).
QUANTITIES = ("D_xy", "theta", "ttf_ratio", "Sxy_star")
#: quantity "orbit" (issue 39): the orbit's numbers of the run summary, window values over its
#: last whole orbits (compare like with like only where every setting completes two orbits)
ORBIT_QUANTITIES = ("orbit_period", "orbit_constant", "body_rotation_ratio")
#: study(quantity=...) → the observables it compares
QUANTITY_SETS = {"shape": QUANTITIES, "orbit": ORBIT_QUANTITIES}


def _studied(ds) -> tuple[str, ...]:
    """The observables a study Dataset compares (its ``quantity`` attribute; older files: shape)."""
    return QUANTITY_SETS.get(str(ds.attrs.get("quantity", "shape")), QUANTITIES)
#: what errors are measured against: the finest run, or the Richardson extrapolation in the level
REFERENCES = ("finest", "richardson")


def _attrs(name: str, **extra: Any) -> dict[str, Any]:
    """Attributes of a study variable, from the one table (capsim.quantities)."""
    return dict(attrs_for(name, "study"), **extra)


# ---------------------------------------------------------------- one run


def _window_mean(t: np.ndarray, s: np.ndarray, t0: float, t1: float) -> float:
    """Trapezoidal time mean of s over [t0, t1] (linear interpolation at the ends)."""
    if not (math.isfinite(t0) and math.isfinite(t1)) or t1 <= t0 or t.size < 2:
        return float("nan")
    inner = (t > t0) & (t < t1)
    tt = np.concatenate([[t0], t[inner], [t1]])
    ss = np.concatenate([[np.interp(t0, t, s)], s[inner], [np.interp(t1, t, s)]])
    return float(np.trapezoid(ss, tt) / (t1 - t0)) if hasattr(np, "trapezoid") else float(
        np.trapz(ss, tt) / (t1 - t0)
    )


def final_values(ts: dict[str, np.ndarray], window: tuple[float, float] | None = None) -> dict[str, float]:
    """Each of QUANTITIES at the last row of a time series (θ unwrapped modulo π)
    and, with `window` = (t0, t1), its time mean over the window as ``<q>_mean``. A run of
    several capsules (columns (t, capsule)): the mean over the capsules, as the run's summary
    gives beside each capsule's own (each capsule's θ unwrapped first)."""
    t = np.asarray(ts["t"], float)
    out: dict[str, float] = {}
    from capsim.solve.observables import capsule_mean

    for q in QUANTITIES:
        # θ: NaN where the shape has no long axis (kt = 0 of a sphere), skipped by the unwrapping
        s = capsule_mean(ts[q], angle=q == "theta")
        out[q] = float(s[-1])
        if window is not None:
            out[f"{q}_mean"] = _window_mean(t, s, *window)
    return out


def _failed_record(reason: str) -> dict[str, Any]:
    record: dict[str, Any] = {"status": "failed", "status_reason": reason, "wall_time_s": float("nan"),
                              "steps": -1, "volume_drift": float("nan"), "n_nodes": -1, "t": float("nan")}
    for q in QUANTITIES:
        record[q] = float("nan")
        record[f"{q}_mean"] = float("nan")
    for q in ORBIT_QUANTITIES:
        record[q] = float("nan")
    record["settled"] = float("nan")
    return record


def _run_one(case: Case, window: tuple[float, float] | None = None) -> dict[str, Any]:
    """Run `case` and return its record: values at t_end, cost, status.

    With `window` = (t0, t1), also the time means of the quantities over it
    (``<q>_mean``), so that runs can be compared over one averaging window.
    """
    from capsim.runs.runner import run_case
    from capsim.storage.store import read_trajectory

    record = _failed_record("")
    try:
        summary = run_case(case)
    except Exception as exc:  # one failed setting must not sink the study
        record["status_reason"] = f"{type(exc).__name__}: {exc}"
        return record
    record.update(
        status=summary.get("status", "failed"),
        status_reason=summary.get("status_reason", ""),
        wall_time_s=float(summary["wall_time_s"]),
        steps=int(summary["steps"]),
        volume_drift=float(summary["volume_drift"]),
        t=float(summary["t"]),
    )
    traj = read_trajectory(case.output.path)
    ts = traj["timeseries"]
    record["n_nodes"] = int(traj["attrs"].get("n_nodes", traj["rest_positions"].shape[0]))
    record.update(final_values(ts, window))
    motion = summary.summary if hasattr(summary, "summary") else {}
    for q in (*ORBIT_QUANTITIES, "settled"):
        value = motion.get(q, float("nan"))
        record[q] = float(value) if isinstance(value, (int, float)) else float("nan")
    if record["status"] == "completed" and abs(record["t"] - case.time.t_end) > 1e-9 * max(1.0, case.time.t_end):
        record["status_reason"] = f"stopped at kt = {record['t']:.6g} before t_end"
    return record


def _job(job: tuple[Case, tuple[float, float] | None], progress: Any = None) -> dict[str, Any]:
    """The executor's task: one setting of the ladder (looked up at call time, so tests can replace _run_one)."""
    case, window = job
    return _run_one(case, window)


def _run_jobs(jobs: list[tuple[Case, Any]], workers: int, progress: Callable[[str], None] | None,
              window: tuple[float, float] | None = None) -> list[dict[str, Any]]:
    """Run the cases (on the batch executor's process pool when workers > 1); records in job order.

    The kernels of every kind of case are warmed up first (in each worker), so that
    wall times measure the runs; an interrupted run (Ctrl-C, SIGTERM) stops the
    ladder with KeyboardInterrupt.
    """
    from capsim.campaigns.executor import run_batch

    cases = [case for case, _ in jobs]
    # Biggest first, so that the pool is not left waiting on one long run at the end.
    order = sorted(range(len(jobs)), key=lambda i: (-cases[i].mesh.level, cases[i].time.rtol))

    def done(i: int, record: dict[str, Any]) -> None:
        if progress is not None:
            progress(_describe_done(cases[i], record))

    def failure(i: int, status: str, reason: str) -> dict[str, Any]:
        return dict(_failed_record(reason), status=status)

    outcome = run_batch(
        [(case, window) for case in cases], _job, keys=[case.output.path for case in cases],
        failure=failure, workers=workers, warm=cases, in_process=workers <= 1 or len(jobs) == 1,
        order=order, on_done=done, stop_on_interrupted=True, name="study",
    )
    if outcome.interrupted:
        reasons = [r["status_reason"] for r in outcome.records if r is not None and r["status"] == "interrupted"]
        raise KeyboardInterrupt(reasons[0] if reasons else "study stopped")
    return outcome.records  # type: ignore[return-value]


def _describe_done(case: Case, record: dict[str, Any]) -> str:
    return (f"level {case.mesh.level} rtol {case.time.rtol:g} q{case.quadrature.regular_order}: "
            f"{record['status']}, {record['wall_time_s']:.1f} s, {record['steps']} steps, "
            f"D_xy = {record['D_xy']:.6f}")


# ---------------------------------------------------------------- the study


def _order_from_errors(e: np.ndarray) -> np.ndarray:
    """log2(|e_l| / |e_{l+1}|) along the last axis (NaN past the end or where undefined)."""
    e = np.abs(np.asarray(e, float))
    out = np.full(e.shape, np.nan)
    with np.errstate(divide="ignore", invalid="ignore"):
        r = np.log2(e[..., :-1] / e[..., 1:])
    out[..., :-1] = np.where(np.isfinite(r), r, np.nan)
    return out


def _order_three_level(f: np.ndarray) -> np.ndarray:
    """log2(|f_l − f_{l+1}| / |f_{l+1} − f_{l+2}|) along the last axis."""
    f = np.asarray(f, float)
    out = np.full(f.shape, np.nan)
    if f.shape[-1] >= 3:
        d = np.abs(np.diff(f, axis=-1))
        with np.errstate(divide="ignore", invalid="ignore"):
            r = np.log2(d[..., :-1] / d[..., 1:])
        out[..., :-2] = np.where(np.isfinite(r), r, np.nan)
    return out


def richardson(f: np.ndarray, levels: np.ndarray) -> tuple[float, float]:
    """Extrapolated value and the order used, from values f over consecutive levels."""
    ok = np.isfinite(f)
    f, levels = f[ok], levels[ok]
    if f.size == 0:
        return float("nan"), float("nan")
    if f.size == 1 or np.any(np.diff(levels) != 1):
        return float(f[-1]), float("nan")
    p = 2.0
    if f.size >= 3:
        # levels that overshoot and come back show no order (the biconcave cell of benchmarks/accuracy_target.md)
        p_obs = observed_order(f[-2] - f[-3], f[-1] - f[-2])
        if p_obs is not None and 0.5 <= p_obs <= 8.0:
            p = p_obs
    return float(f[-1] + (f[-1] - f[-2]) / (2.0**p - 1.0)), p


def run_study(
    case: Case,
    levels: Sequence[int],
    rtols: Sequence[float],
    regular_orders: Sequence[int] | None = None,
    reference: str = "finest",
    workers: int = 1,
    out_dir: str | os.PathLike | None = None,
    progress: Callable[[str], None] | None = None,
    overwrite: bool = False,
    inputs: Sequence[str | os.PathLike] = (),
    quantity: str = "shape",
):
    """Run the ladder levels × rtols (× regular_orders) and compare with the reference.

    `quantity`: "shape" compares D_xy, θ, TTF and S*_xy at t_end; "orbit" the orbit's numbers
    of each run's summary (orbit period, orbit constant, the body's rotation rate), window
    values over its last whole orbits, with each setting's ``settled`` flag beside them.

    `reference` is ``"finest"`` (the run at the highest level, smallest rtol and
    highest Gauss order) or ``"richardson"`` (extrapolation in the level of the
    finest-tolerance runs, with the observed order when three levels give one
    between 0.5 and 8 (their two differences of one sign), else 2). The run files go to `out_dir` (a temporary
    directory, removed afterwards, when None); a run file already there (a
    file of an earlier study, or any other) is not replaced unless `overwrite`
    (:class:`capsim.storage.files.OutputError`), nor ever one of `inputs`. Returns an
    xarray Dataset.
    """
    import xarray as xr

    if reference not in REFERENCES:
        raise ValueError(f"reference must be 'finest' or 'richardson', got {reference!r}")
    if quantity not in QUANTITY_SETS:
        raise ValueError(f"quantity must be one of {', '.join(QUANTITY_SETS)}, got {quantity!r}")
    levels = sorted({int(v) for v in levels})
    rtols = sorted({float(v) for v in rtols}, reverse=True)  # loosest first: error falls along the axis
    quads = sorted({int(v) for v in regular_orders}) if regular_orders else [case.quadrature.regular_order]
    if not levels or not rtols:
        raise ValueError("the study needs at least one level and one rtol")
    if reference == "richardson" and len(levels) < 2:
        raise ValueError("a Richardson reference needs at least two levels")

    tmp = None
    if out_dir is None:
        tmp = tempfile.mkdtemp(prefix="capsim-study-")
        run_dir = Path(tmp)
    else:
        run_dir = Path(out_dir)
        run_dir.mkdir(parents=True, exist_ok=True)

    base = apply_overrides(case, **{"time.stop_when_steady": False, "time.stop_when_settled": False,
                                    "accuracy": None})  # the ladder sets the level and rtol itself
    jobs: list[tuple[Case, tuple[int, int, int]]] = []
    for iq, q in enumerate(quads):
        for ir, rtol in enumerate(rtols):
            for il, level in enumerate(levels):
                name = f"{case.name}_L{level}_rtol{rtol:g}_q{q}"
                c = apply_overrides(base, **{
                    "mesh.level": level, "time.rtol": rtol, "quadrature.regular_order": q,
                    "output.path": str(run_dir / f"{name}.h5"),
                })
                jobs.append((c, (iq, ir, il)))
    if tmp is None:
        from capsim.storage.files import guard_output

        for c, _ in jobs:  # before any run: nothing of an earlier study is replaced unasked
            guard_output(Path(c.output.path), list(inputs), overwrite,
                         option="--overwrite (or another --runs-dir)")
    try:
        records = _run_jobs(jobs, workers, progress)
    finally:
        if tmp is not None:
            shutil.rmtree(tmp, ignore_errors=True)

    shape = (len(quads), len(rtols), len(levels))

    def grid(key: str, dtype=float, fill=np.nan) -> np.ndarray:
        a = np.full(shape, fill, dtype=dtype)
        for (c, idx), rec in zip(jobs, records):
            a[idx] = rec[key]
        return a

    dims = ("regular_order", "rtol", "level")
    status = grid("status", dtype=object, fill="")
    completed = status == "completed"
    data_vars: dict[str, Any] = {}
    for q in QUANTITY_SETS[quantity]:
        data_vars[q] = (dims, np.where(completed, grid(q), np.nan), _attrs(q))
    if quantity == "orbit":
        data_vars["settled"] = (dims, np.where(completed, grid("settled"), np.nan), _attrs("settled"))
    data_vars["wall_time_s"] = (dims, grid("wall_time_s"), _attrs("wall_time_s"))
    data_vars["steps"] = (dims, grid("steps", dtype=np.int64, fill=-1), _attrs("steps"))
    data_vars["volume_drift"] = (dims, grid("volume_drift"), _attrs("volume_drift"))
    data_vars["n_nodes"] = (dims, grid("n_nodes", dtype=np.int64, fill=-1), _attrs("n_nodes"))
    data_vars["status"] = (dims, status.astype(str), _attrs("status"))
    data_vars["status_reason"] = (dims, grid("status_reason", dtype=object, fill="").astype(str),
                                  _attrs("status_reason"))

    from capsim._version import __version__

    ds = xr.Dataset(
        data_vars,
        coords={name: (name, values, _attrs(name))
                for name, values in (("regular_order", quads), ("rtol", rtols), ("level", levels))},
        attrs={
            **global_attrs(f"capsim accuracy study of case {case.name}"),  # CF-1.10 (issue 16)
            "case_yaml": base.to_yaml(),
            "quantity": quantity,
            "t_end": float(case.time.t_end),
            "created": datetime.now(timezone.utc).isoformat(timespec="seconds"),
            "workers": int(workers),
            "capsim_version": __version__,
        },
    )
    ds = analyse_study(ds, reference)
    if len(quads) == 1:
        ds = ds.squeeze("regular_order")
    return ds


def analyse_study(ds, reference: str = "finest"):
    """Errors, relative errors, observed orders and cost exponents of a study Dataset.

    `ds` holds the raw values (``D_xy`` …, ``wall_time_s``, ``steps``,
    ``n_nodes``) on dimensions (``regular_order``,) ``rtol`` (loosest first),
    ``level``; returns a copy with the ``*_error``, ``*_relative_error``,
    ``*_order``, ``*_order3`` and ``*_reference`` variables (re)computed against
    `reference` (``"finest"`` or ``"richardson"``).
    """
    if reference not in REFERENCES:
        raise ValueError(f"reference must be 'finest' or 'richardson', got {reference!r}")
    squeezed = "regular_order" not in ds.dims
    if squeezed:
        ds = ds.expand_dims("regular_order")
    ds = ds.transpose("regular_order", "rtol", "level")
    levels = np.asarray(ds["level"].values, int)
    if reference == "richardson" and levels.size < 2:
        raise ValueError("a Richardson reference needs at least two levels")
    dims = ("regular_order", "rtol", "level")
    shape = tuple(ds.sizes[d] for d in dims)
    out = ds.copy()
    for q in _studied(ds):
        raw = np.asarray(ds[q].values, float)
        if reference == "finest":
            ref, ref_order = float(raw[-1, -1, -1]), float("nan")
        else:
            ref, ref_order = richardson(raw[-1, -1, :], levels)
        err = raw - ref
        out[f"{q}_error"] = (dims, err, _attrs(f"{q}_error", reference=reference))
        rel = np.abs(err) / abs(ref) if ref else np.full(shape, np.nan)
        out[f"{q}_relative_error"] = (dims, rel, _attrs(f"{q}_relative_error"))
        out[f"{q}_order"] = (dims, _order_from_errors(err), _attrs(f"{q}_order"))
        out[f"{q}_order3"] = (dims, _order_three_level(raw), _attrs(f"{q}_order3"))
        out[f"{q}_reference"] = ((), ref, _attrs(f"{q}_reference", reference=reference,
                                                 richardson_order=ref_order))
    out.attrs["reference"] = reference
    out.attrs["error_definition"] = "value at t_end minus the reference value"
    # Wall time against the number of nodes at the finest tolerance: measured exponents.
    n = np.asarray(ds["n_nodes"].values[-1, -1, :], float)
    for name, y in (("wall_time_exponent", ds["wall_time_s"].values),
                    ("wall_time_per_step_exponent", ds["wall_time_s"].values / ds["steps"].values)):
        w = np.asarray(y[-1, -1, :], float)
        ok = (n > 0) & np.isfinite(w) & (w > 0)
        out.attrs[name] = float(np.polyfit(np.log(n[ok]), np.log(w[ok]), 1)[0]) if ok.sum() >= 2 else float("nan")
    if squeezed:
        out = out.squeeze("regular_order")
    return out


def write_study(ds, path: str | os.PathLike) -> Path:
    """Write the study Dataset as netCDF (text variables as char arrays, as CF checkers read them)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    out = ds.copy()
    for name in ("status", "status_reason"):
        out[name] = out[name].astype(str)
    out.to_netcdf(path, encoding={name: {"dtype": "S1"} for name, var in out.variables.items()
                                  if var.dtype.kind in "OU"})
    return path


# ---------------------------------------------------------------- reporting


def _settings(ds):
    """(label, index dict) for every setting, loosest first."""
    import itertools

    dims = [d for d in ("regular_order", "rtol", "level") if d in ds.dims]
    for combo in itertools.product(*(range(ds.sizes[d]) for d in dims)):
        idx = dict(zip(dims, combo))
        yield idx


def _error_cell(ds, sel, q: str) -> str:
    """One error, in the convention of accuracy targets, --verify and the error block: relative
    to |reference| with the absolute beside it; θ in rad (its target's unit)."""
    error = float(sel[f"{q}_error"])
    if q == "theta":
        return f"{error:+.2e}"
    reference = abs(float(ds[f"{q}_reference"]))
    relative = error / reference if reference > 0 else float("nan")
    return f"{relative:+.2e} ({error:+.1e})"


def format_study_table(ds) -> str:
    """The study as a text table: one row per setting, then the observed orders."""
    studied = _studied(ds)
    short = {"D_xy": "D_xy", "theta": "θ", "ttf_ratio": "ttf", "Sxy_star": "S*xy", "orbit_period": "T_orbit",
             "orbit_constant": "C", "body_rotation_ratio": "body"}
    head = ["level", "rtol"] + (["quad"] if "regular_order" in ds.dims else []) + [
        "nodes", "steps", "wall s", studied[0],
        *(f"err {short.get(q, q)}" + (" rad" if q == "theta" else " rel (abs)") for q in studied)] + (
        ["settled"] if "settled" in ds else []) + ["vol drift", "status"]
    rows = []
    for idx in _settings(ds):
        sel = ds.isel(idx)
        row = [str(int(sel["level"])), f"{float(sel['rtol']):.0e}"]
        if "regular_order" in ds.dims:
            row.append(str(int(sel["regular_order"])))
        row += [
            str(int(sel["n_nodes"])), str(int(sel["steps"])), f"{float(sel['wall_time_s']):.1f}",
            f"{float(sel[studied[0]]):.6f}",
            *(_error_cell(ds, sel, q) for q in studied),
            *([f"{float(sel['settled']):.0f}"] if "settled" in ds else []),
            f"{float(sel['volume_drift']):.1e}", str(sel["status"].values),
        ]
        rows.append(row)
    widths = [max(len(h), *(len(r[i]) for r in rows)) for i, h in enumerate(head)]
    lines = ["  ".join(h.rjust(w) for h, w in zip(head, widths))]
    lines += ["  ".join(c.rjust(w) for c, w in zip(r, widths)) for r in rows]
    lines.append(f"reference ({ds.attrs['reference']}): " + ", ".join(
        f"{q} = {float(ds[f'{q}_reference']):.6f}" for q in studied))
    # Observed orders at the finest tolerance (and Gauss order).
    fine = ds.isel(rtol=-1, **({"regular_order": -1} if "regular_order" in ds.dims else {}))
    levels = [int(v) for v in ds["level"].values]
    for q in studied[:2]:
        parts = []
        for i, level in enumerate(levels):
            p, p3 = float(fine[f"{q}_order"][i]), float(fine[f"{q}_order3"][i])
            if math.isfinite(p):
                parts.append(f"p(L{level}→L{levels[i + 1]}) = {p:.2f}")
            if math.isfinite(p3):
                parts.append(f"p3(L{level},L{levels[i + 1]},L{levels[i + 2]}) = {p3:.2f}")
        if parts:
            lines.append(f"observed order of {q} at rtol {float(fine['rtol']):.0e}: " + ", ".join(parts))
    lines.append(
        f"wall time ∝ N^{ds.attrs['wall_time_exponent']:.2f}, wall time per step ∝ "
        f"N^{ds.attrs['wall_time_per_step_exponent']:.2f} (N nodes, finest tolerance)")
    return "\n".join(lines)


def plot_pareto(ds, path: str | os.PathLike, quantities: Sequence[str] = ("D_xy", "theta")) -> Path:
    """PNG of |error| against wall time for every setting, with the Pareto front."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig, axes = plt.subplots(1, len(quantities), figsize=(5.5 * len(quantities), 4.5), squeeze=False)
    rtols = [float(v) for v in ds["rtol"].values]
    markers = "osD^v<>"
    for ax, q in zip(axes[0], quantities):
        pts = []
        for idx in _settings(ds):
            sel = ds.isel(idx)
            w, e = float(sel["wall_time_s"]), abs(float(sel[f"{q}_error"]))
            if not (math.isfinite(w) and math.isfinite(e)) or e == 0.0:
                continue  # the reference itself has no error to show
            r = float(sel["rtol"])
            label = f"L{int(sel['level'])}"
            ax.loglog(w, e, markers[rtols.index(r) % len(markers)], color=f"C{rtols.index(r)}",
                      label=f"rtol {r:.0e}")
            ax.annotate(label, (w, e), textcoords="offset points", xytext=(4, 3), fontsize=8)
            pts.append((w, e))
        pts.sort()
        front, best = [], math.inf
        for w, e in pts:
            if e < best:
                front.append((w, e))
                best = e
        if front:
            ax.loglog(*zip(*front), "k--", lw=1, label="Pareto front")
        handles, labels = ax.get_legend_handles_labels()
        uniq = dict(zip(labels, handles))
        ax.legend(uniq.values(), uniq.keys(), fontsize=8)
        ax.set_xlabel("wall time (s)")
        ax.set_ylabel(f"|error of {q}| at kt = {ds.attrs['t_end']:g}")
        ax.grid(True, which="both", alpha=0.3)
    fig.suptitle(f"{ds.attrs['title']} (reference: {ds.attrs['reference']})", fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path


# ---------------------------------------------------------------- run --error-estimate


def error_estimate(case: Case, summary: dict[str, Any], workers: int = 2,
                   rtol_factor: float = 10.0) -> dict[str, Any]:
    """Error estimate of a finished run: rerun one level coarser and with a looser tolerance.

    Returns, for each quantity q of :data:`QUANTITIES`, ``q`` (estimate of the
    error of the value at t_end: ``|Δ_mesh| + |Δ_time|``), ``q_mesh`` and
    ``q_time`` (the two signed differences, run minus coarser/looser run), and
    the same for the time mean over the run's averaging window as ``q_mean*``.
    The estimate needs both parts: at level 0 (no coarser mesh, ``coarse_level`` -1) the
    mesh part is NaN and so is ``q``, the time part alone being no bound of the error (it
    is kept as ``q_time``); the same when a rerun did not complete.
    """
    from capsim.storage.store import read_trajectory

    traj = read_trajectory(case.output.path)
    ts = traj["timeseries"]
    t = np.asarray(ts["t"], float)
    t0 = float(summary.get("averaging_t_from", float("nan")))
    t1 = float(summary.get("averaging_t_to", t[-1] if t.size else float("nan")))
    window = (t0, t1)
    main = final_values(ts, window)

    tmp = tempfile.mkdtemp(prefix="capsim-errest-")
    try:
        # the reruns at a given level and rtol: not the accuracy target's choice, nor rtol auto's again
        base = apply_overrides(case, **{"time.stop_when_steady": False, "time.stop_when_settled": False,
                                        "accuracy": None})
        loose_rtol = min(case.time.rtol * rtol_factor, 0.5)
        jobs: list[tuple[Case, str]] = [(apply_overrides(base, **{
            "time.rtol": loose_rtol, "output.path": str(Path(tmp) / "time.h5")}), "time")]
        if case.mesh.level > 0:
            jobs.append((apply_overrides(base, **{
                "mesh.level": case.mesh.level - 1, "time.rtol": case.time.rtol,
                "output.path": str(Path(tmp) / "mesh.h5")}), "mesh"))
        if case.mesh.level > 1:  # a third level measures the Richardson order (4x cheaper than level − 1)
            jobs.append((apply_overrides(base, **{
                "mesh.level": case.mesh.level - 2, "time.rtol": case.time.rtol,
                "output.path": str(Path(tmp) / "mesh2.h5")}), "mesh2"))
        records = _run_jobs(jobs, workers, None, window=window)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    by_kind = {kind: rec for (_, kind), rec in zip(jobs, records)}

    out: dict[str, Any] = {
        "coarse_level": case.mesh.level - 1 if case.mesh.level > 0 else -1,
        "loose_rtol": loose_rtol,
        "wall_time_s": float(sum(r["wall_time_s"] for r in records)),
    }
    for q in QUANTITIES:
        for suffix in ("", "_mean"):
            key = f"{q}{suffix}"
            d_time = main[key] - by_kind["time"][key] if by_kind["time"]["status"] == "completed" else float("nan")
            d_mesh = (main[key] - by_kind["mesh"][key]
                      if "mesh" in by_kind and by_kind["mesh"]["status"] == "completed" else float("nan"))
            out[f"{key}_value"] = main[key]
            out[f"{key}_time"] = float(d_time)
            out[f"{key}_mesh"] = float(d_mesh)
            out[f"{key}_mesh2"] = float(main[key] - by_kind["mesh2"][key]
                                        if "mesh2" in by_kind and by_kind["mesh2"]["status"] == "completed"
                                        else float("nan"))
            # one part alone would be read as the error (at level 0 the time part is ~1e-6,
            # the mesh's error ~1e-2): no total without both
            out[key] = float(abs(d_time) + abs(d_mesh))
    return out


def write_error_estimate(path: str | os.PathLike, estimate: dict[str, Any]) -> None:
    """Store the estimate as the run file's ``error_estimate`` group (replacing any)."""
    from capsim.storage import store

    store.write_error_estimate(path, estimate)


#: the band of an estimate whose order three levels measured: Roache's factor of safety 1.25 for a
#: grid-convergence index with an observed order (P. J. Roache, Verification and Validation in
#: Computational Science and Engineering, 1998), taken both ways
MEASURED_ORDER_BAND = 1.25


def _finite(*xs: Any) -> bool:
    return all(isinstance(x, (int, float)) and math.isfinite(x) for x in xs)


def own_error(estimate: dict[str, Any], q: str, key: str, model_order: float,
              level: int | None = None) -> dict[str, Any] | None:
    """The run's own error of `key` (``q`` or ``q_mean``) by Richardson from the reruns: the one
    error statement of the error block and of ``--verify``. Relative to |value| (θ: in rad, as its
    target), the absolute beside it, with its band {"lo", "hi"}.

    The order: measured from three levels (:func:`capsim.solve.accuracy.measured_error`) where they
    converge and the coarsest is level 1 or finer; level 0 is short of the asymptotic range
    (sphere G 0.1 at kt 2, levels 0-3: D_xy 0.3515, 0.3726, 0.3814, 0.3823: the order of levels
    0-2 is 1.3, of 1-3 3.2), so there, from two levels or from levels that do not converge,
    the error model's `model_order`. The band: with a measured order, its estimate and the model
    order's, widened ÷/× MEASURED_ORDER_BAND; else the orders LADDER_MAX_ORDER to
    LADDER_TWO_LEVEL_ORDER (and up to the larger difference where three levels do not converge).
    The time part is the 10× looser tolerance's difference over 9 (time error ∝ rtol), in all
    three. None where the mesh part is unknown (level 0). `level`: the run's (the estimate's
    coarse_level + 1 when not given)."""
    from capsim.solve import accuracy as am

    value, d_mesh, d_time, d_mesh2 = (estimate.get(f"{key}{k}") for k in ("_value", "_mesh", "_time", "_mesh2"))
    if not _finite(value, d_mesh, d_time):
        return None
    level = int(estimate.get("coarse_level", -1)) + 1 if level is None else level
    relative = q != "theta"
    scale = max(abs(float(value)), 1e-300) if relative else 1.0
    time = abs(d_time) / 9.0
    d = abs(d_mesh)
    by_model = d / (2.0**model_order - 1.0)
    order, mesh = float(model_order), by_model
    lo, hi = d / (2.0**am.LADDER_MAX_ORDER - 1.0), d / (2.0**am.LADDER_TWO_LEVEL_ORDER - 1.0)
    how = f"order {order:.2g} of the error model"
    if _finite(d_mesh2):
        m = am.measured_error([value - d_mesh2, value - d_mesh, value], relative=False,
                              period=math.pi if q == "theta" else None)
        if m["converging"] and level - 2 >= 1:
            order, mesh = float(m["order"]), float(m["error"])
            lo = min(mesh, by_model) / MEASURED_ORDER_BAND
            hi = max(mesh, by_model) * MEASURED_ORDER_BAND
            how = f"order {order:.2g} measured from levels {level - 2}-{level}"
        elif not m["converging"]:
            hi = max(hi, float(m["error"]))
            how += f", levels {level - 2}-{level} not converging"
        else:
            how += f" (levels {level - 2}-{level}: level 0 short of the asymptotic range)"
    else:
        how += ", two levels"
    lo, hi = min(lo, mesh), max(hi, mesh)
    return {"abs": mesh + time, "rel": (mesh + time) / scale, "lo": (lo + time) / scale,
            "hi": (hi + time) / scale, "order": order, "how": how, "relative": relative}


def own_errors(case: Case, estimate: dict[str, Any]) -> dict[str, dict[str, Any]]:
    """:func:`own_error` of every quantity the estimate holds (orders from the case's error model)."""
    from capsim.solve import accuracy as error_model

    orders = error_model.entry(case.error_model_features())[0]["order"]
    out = {}
    for q in QUANTITIES:
        for key in (q, f"{q}_mean"):
            e = own_error(estimate, q, key, float(orders.get(q, error_model.LADDER_TWO_LEVEL_ORDER)),
                          case.mesh.level)
            if e is not None:
                out[key] = e
    return out


def format_error_estimate(summary: dict[str, Any], estimate: dict[str, Any],
                          errors: dict[str, dict[str, Any]] | None = None) -> str:
    """Lines 'q  value ± estimate (mesh …, time …)' for the summary values; a part that could
    not be had (level 0 has no coarser mesh) is said to be unknown, and so is the ±. With `errors`
    (:func:`own_errors`) the ± is the run's own error by Richardson, relative beside it: the same
    statement ``--verify`` judges."""
    coarse = int(estimate["coarse_level"])
    errors = errors or {}
    if coarse >= 0:
        what = ("the Richardson estimate of the run's own error (absolute; relative beside it, θ in rad)"
                if errors else "error estimate |mesh| + |time| (not a window spread)")
        lines = [f"error estimate (level {coarse} and rtol {estimate['loose_rtol']:g} reruns, "
                 f"{estimate['wall_time_s']:.1f} s); value ± {what}, "
                 "θ in units of π as in the table above:"]
    else:
        lines = [f"error estimate: the rtol {estimate['loose_rtol']:g} rerun only ({estimate['wall_time_s']:.1f} s): "
                 "level 0 has no coarser mesh, so the mesh part, and with it the error estimate, is unknown "
                 "(run at level >= 1 for one); the time part alone, θ in units of π as in the table above:"]
    names = {"D_xy": "D_xy", "theta": "theta/pi", "ttf_ratio": "TTF/f_s", "Sxy_star": "S*_xy"}
    scales = {"theta": math.pi}
    width = max(len(v) for v in names.values()) + len(" (t_end)")

    def shown(x: Any, c: float, form: str) -> str:
        return format(x / c, form) if isinstance(x, (int, float)) and math.isfinite(x) else "unknown"

    for q, label in names.items():
        for suffix, where in (("_mean", ""), ("", " (t_end)")):
            key = f"{q}{suffix}"
            value = summary.get(q) if suffix == "_mean" else estimate.get(f"{key}_value")
            if not isinstance(value, (int, float)) or not math.isfinite(value):
                continue
            c = scales.get(q, 1.0)
            own = errors.get(key)
            bar = shown(own["abs"] if own else estimate.get(key), c, ".2e")
            rel = (f"{own['rel']:.1e} {'relative' if own['relative'] else 'rad'}, " if own else "")
            lines.append(f"  {label + where:<{width}}  {value / c:.6f} ± {bar}"
                         f"  ({rel}mesh {shown(estimate.get(f'{key}_mesh'), c, '+.1e')}, "
                         f"time {shown(estimate.get(f'{key}_time'), c, '+.1e')})")
    return "\n".join(lines)


def run_error_estimate(case: Case, summary: dict[str, Any], workers: int = 2, verify: bool = False) -> str:
    """`capsim run --error-estimate`: estimate, store in the run file, return the lines to print;
    with `verify` (``--verify``) the last line says whether the case's accuracy target was met."""
    estimate = error_estimate(case, summary, workers=workers)
    write_error_estimate(case.output.path, estimate)  # the run's result itself is read-only (RunResult)
    text = format_error_estimate(summary, estimate, own_errors(case, estimate))
    return text + "\n" + verification(case, estimate) if verify else text


def check_run(case: Case, summary: dict[str, Any], error_estimate: bool = False,
              verify: bool = False) -> tuple[str, bool | None]:
    """What `capsim run` prints after a completed run, and whether its target was verified met
    (None: not verified): ``--verify`` (:func:`run_verification`) or ``--error-estimate``
    (:func:`run_error_estimate`, of the level kept); a measured target's ladder is its own check."""
    measured = bool(summary.get("accuracy"))
    if not (error_estimate or (verify and not measured)) or summary.get("status") != "completed":
        return "", None
    from capsim.storage.store import read_case

    kept = read_case(case.output.path) if measured else case  # the level the ladder kept
    if verify and not measured:
        return run_verification(kept, summary)
    return run_error_estimate(kept, summary), None


def run_verification(case: Case, summary: dict[str, Any], workers: int = 2) -> tuple[str, bool | None]:
    """`capsim run --verify`: :func:`run_error_estimate`'s lines with the verdict, and whether the
    target was met (None: unchecked or undecided); a target NOT met exits 3, as a ladder's does."""
    estimate = error_estimate(case, summary, workers=workers)
    write_error_estimate(case.output.path, estimate)
    line, met = _verified(case, estimate)
    return format_error_estimate(summary, estimate, own_errors(case, estimate)) + "\n" + line, met


def verification(case: Case, estimate: dict[str, Any]) -> str:
    """Whether the run met its accuracy target: the error estimate of the target's quantity at
    t_end (relative for D_xy and S*_xy, rad for θ) against the target and the prediction."""
    return _verified(case, estimate)[0]


def verdict(error: float, lo: float, hi: float, target: float) -> tuple[str, bool | None]:
    """The verdict of an error estimate with its band [lo, hi] against a target: met where the band
    is below it, met within the estimate's uncertainty where the estimate is, undecided where only
    the band's lower end is, NOT met where the whole band is above: no flat NOT met that the
    estimate's own uncertainty does not carry."""
    if hi <= target:
        return "target met", True
    if error <= target:
        return "target met within the estimate's uncertainty", True
    if lo <= target:
        return "undecided: the estimate's uncertainty straddles the target", None
    return "target NOT met", False


def _verified(case: Case, estimate: dict[str, Any]) -> tuple[str, bool | None]:
    target = case.accuracy
    if target is None:
        return "verify: the case has no accuracy target (give accuracy: {quantity, target} or --accuracy)", None
    q = target.quantity
    own = own_errors(case, estimate).get(q)
    if own is None:
        return f"verify: no error estimate of {q} (level 0 has no coarser mesh): the target is unchecked", None
    said, met = verdict(own["rel"], own["lo"], own["hi"], target.target)
    unit = "relative" if own["relative"] else "rad"
    return (f"verify: {q} error {own['rel']:.2g} {unit} ({own['abs']:.2g} absolute; Richardson from the reruns, "
            f"{own['how']}; uncertainty {own['lo']:.2g} to {own['hi']:.2g}) "
            f"{'<=' if own['rel'] <= target.target else '>'} target {target.target:g}: {said} ({target.choice})",
            met)


PathLike = str | os.PathLike


def study(case: "PathLike | Mapping[str, Any] | Case", levels: "int | Sequence[int]" = (2, 3, 4),
          rtols: "float | Sequence[float]" = (1e-3, 1e-4, 1e-5), *, quad: "int | Sequence[int] | None" = None,
          reference: str = "finest", workers: int = 1, output: PathLike | None = None,
          runs_dir: PathLike | None = None, overwrite: bool = False, progress: bool | Callable[[str], None] = False,
          sets: "str | Sequence[str] | None" = None, inputs: "PathLike | Sequence[PathLike]" = (),
          quantity: str = "shape", **overrides: Any) -> "xr.Dataset":
    """Accuracy against cost: run the ladder `levels` × `rtols` (× `quad` Gauss orders)
    and compare each run with the `reference` (`"finest"` or `"richardson"`);
    what `capsim study` does. `quantity`: `"shape"` (D_xy, θ, TTF, S*_xy at t_end) or `"orbit"`
    (the orbit period, orbit constant and body rotation rate of each run's summary, with its
    `settled` flag: run each setting for at least two whole orbits).

    `levels`, `rtols` and `quad` are numbers or lists of numbers (a single one is a list
    of one; not texts); `workers` a whole number >= 1 (worker processes when > 1, which
    do not run the calling script again: a plain script works). A bad argument raises a
    one-line `capsim.config.ConfigError`.

    Returns an `xarray.Dataset` of errors, wall times and observed orders
    (`capsim.campaigns.study.format_study_table` prints it as the CLI does). With
    `output` the Dataset is written there as netCDF and the Pareto plot beside it
    (`.png`), through the same guards as the CLI. `progress=True` prints a line
    per finished run on stderr; a callable receives that line. `inputs`: more
    files never to write over.
    """
    from capsim.config import ConfigError, resolve_case
    from capsim.errors import bounded_repr
    from capsim.campaigns.executor import (
        check_workers, number_list, path_arg, path_list, refuse_in_spawned_import_of_main, text_list,
    )
    from capsim.storage.files import FIGURE_MAGIC, check_writable, guard_output, is_study_file, replace_atomically, starts_with
    from capsim.numerics.threads import apply_policy

    refuse_in_spawned_import_of_main("capsim.study")
    levels = number_list(levels, "levels", whole=True)
    rtols = number_list(rtols, "rtols")
    quad = number_list(quad, "quad", whole=True) if quad is not None else None
    workers = check_workers(workers, default=None)
    if not isinstance(reference, str) or reference not in REFERENCES:
        raise ConfigError(f"reference = {bounded_repr(reference)}: allowed: {', '.join(REFERENCES)}")
    if not isinstance(quantity, str) or quantity not in QUANTITY_SETS:
        raise ConfigError(f"quantity = {bounded_repr(quantity)}: allowed: {', '.join(QUANTITY_SETS)}")
    if reference == "richardson" and len(set(levels)) < 2:
        raise ConfigError("reference = 'richardson' needs at least two levels")
    if not (progress is True or progress is False or progress is None or callable(progress)):
        raise ConfigError(f"progress = {bounded_repr(progress)}: must be True, False or a callable")
    inputs = path_list(inputs, "inputs") + ([Path(case)] if isinstance(case, (str, os.PathLike)) else [])
    output, runs_dir = path_arg(output, "output"), path_arg(runs_dir, "runs_dir")
    case = resolve_case(dict(case) if isinstance(case, Mapping) else case, text_list(sets, "sets"), **overrides)
    targets = []
    if output is not None:
        output = Path(output)
        png = output.with_suffix(".png")
        targets = [(output, is_study_file), (png, starts_with(FIGURE_MAGIC["png"]))]
        for path, ours in targets:
            check_writable(path)
            guard_output(path, inputs, overwrite, ours=ours)
        inputs += [output, png]
    if runs_dir is not None and Path(runs_dir).exists() and not Path(runs_dir).is_dir():
        raise ConfigError(f"runs_dir {runs_dir} is not a directory")
    if progress is True:
        report = lambda line: print(line, file=sys.stderr)  # noqa: E731
    else:
        report = progress or None
    apply_policy(workers=workers)

    ds = run_study(case, levels, rtols, regular_orders=quad, reference=reference,
                   workers=workers, out_dir=runs_dir, progress=report, overwrite=overwrite, inputs=inputs,
                   quantity=quantity)
    if output is not None:
        replace_atomically(output, lambda tmp: write_study(ds, tmp))
        replace_atomically(png, lambda tmp: plot_pareto(ds, tmp, _studied(ds)[:2]))
    return ds

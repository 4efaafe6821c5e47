"""`make bench-rtol-auto`: what ``time.rtol: auto`` saves and what it moves (issue 44).

For each case of benchmarks/stepping.py at mesh level ≤ 3 (a, c, d, e, f, g, i), with the
default scheme (``time.scheme: auto``), three runs, one each (no median), after a warm-up run
(kt 0.05) at each tolerance that loads numba's cached kernels outside the wall times:

1. ``time.rtol: auto`` (the rtol it chose read back from the run: ``time_rtol``/``time_rtol_choice``);
2. ``time.rtol: 1e-4``;
3. ``time.rtol: 1e-4`` one mesh level coarser, for the case's own mesh error at its level by
   Richardson with order 2 (the smallest order benchmarks/error_model.md observed):
   e_mesh(q) = |q_L − q_{L−1}| / 3, absolute for D_xy and θ (rad).

Reported per case: the chosen rtol, the velocity evaluations and wall time of runs 1 and 2 and
the ratio of evaluations; the move |q_auto − q_1e-4| of D_xy and θ at t_end and as the max over
the trajectory, at the ten snapshot times t_end/10, 2 t_end/10, ..., t_end (the steps are clipped
to them, so every run has a row there: no interpolation, whose own error at auto's long steps
would be counted as a move; θ modulo π, only where the shape has a long axis, D_xy > 1e-3 as
stepping.errors); the mesh error at t_end and its max over the same times. The
issue's criterion holds on a case when the ratio is ≥ 1.5 and both moves are below a tenth of
the mesh error (at t_end against e_mesh at t_end; over the trajectory max move against max e_mesh).

    python benchmarks/rtol_auto.py          # every case (about a minute on one core)
    python benchmarks/rtol_auto.py c g      # some of them (the others' rows kept)

writes benchmarks/rtol_auto.md (included by docs/benchmarks.md) and benchmarks/rtol_auto.json.
"""

from __future__ import annotations

# the CLI's thread policy, before numpy (OpenBLAS) and numba load: capsim.numerics.threads
from capsim.numerics.threads import apply_policy

apply_policy()

import json  # noqa: E402
import platform  # noqa: E402
import subprocess  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402
from datetime import datetime, timezone  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

from capsim import __version__  # noqa: E402
from capsim.config import case_from_dict  # noqa: E402
from capsim.storage.store import read_trajectory  # noqa: E402
from _common import run_or_stop  # noqa: E402
from stepping import CASES, theta_difference  # noqa: E402

HERE = Path(__file__).resolve().parent
MD, JSON = HERE / "rtol_auto.md", HERE / "rtol_auto.json"
#: the cases of stepping.CASES at mesh level ≤ 3 (b, h, h5 are at level 4 and 5)
KEYS = tuple(k for k, (_, spec) in CASES.items() if spec["mesh"]["level"] <= 3)
FIXED_RTOL = 1e-4
#: the move auto may make: this fraction of the mesh error (the issue's criterion)
FRACTION = 0.1
#: auto's evaluations at least this many times fewer than at FIXED_RTOL (the issue's criterion)
RATIO = 1.5
#: Richardson's order for the mesh error (the smallest benchmarks/error_model.md observed)
ORDER = 2
#: snapshots a run (t_end / SNAPSHOTS apart): the times the trajectories are compared at
SNAPSHOTS = 10
#: where the shape has a long axis (θ defined), as stepping.errors
LONG_AXIS = 1e-3
#: the warm-up runs' kt (each case, both tolerances, before the runs that count)
WARM_UP = 0.05
RUN = datetime.now(timezone.utc).isoformat(timespec="seconds")


def _commit() -> str | None:
    """The commit capsim was measured at ("+local changes" where capsim/ differs from it)."""
    try:
        git = ["git", "-C", str(HERE.parent)]
        head = subprocess.run([*git, "rev-parse", "--short", "HEAD"], capture_output=True, text=True, check=True)
        dirty = subprocess.run([*git, "status", "--porcelain", "capsim"], capture_output=True, text=True, check=True)
    except (OSError, subprocess.CalledProcessError):
        return None
    return head.stdout.strip() + (" + local changes" if dirty.stdout.strip() else "")


def _run(key: str, rtol, tmp: Path, coarser: bool = False, t_end: float | None = None) -> tuple[dict, dict]:
    spec = json.loads(json.dumps(CASES[key][1]))
    if coarser:
        spec["mesh"]["level"] -= 1
    if t_end is not None:
        spec["time"]["t_end"] = t_end
    spec["name"] = f"{key}-L{spec['mesh']['level']}-{rtol if isinstance(rtol, str) else f'{rtol:g}'}"
    spec.setdefault("time", {})["rtol"] = rtol
    spec["output"] = {"path": str(tmp / f"{spec['name']}.h5"),
                      "snapshot_every": CASES[key][1]["time"]["t_end"] / SNAPSHOTS}
    result = run_or_stop(case_from_dict(spec))
    return dict(result), read_trajectory(result["path"])["timeseries"]


def _at_snapshots(series: dict, times: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """D_xy and θ at the snapshot times (the steps are clipped to them: rows of every run)."""
    i = np.searchsorted(series["t"], times - 1e-9)
    if not np.allclose(series["t"][i], times, rtol=0.0, atol=1e-9):
        raise SystemExit("a run has no row at a snapshot time")
    return series["D_xy"][i], series["theta"][i]


def compare(run: dict, other: dict, times: np.ndarray) -> dict:
    """|run − other| for D_xy and θ at t_end and as the max over the snapshot times (rows of both,
    no interpolation); θ modulo π, where both have a long axis (D_xy > LONG_AXIS)."""
    (d1, th1), (d2, th2) = _at_snapshots(run, times), _at_snapshots(other, times)
    d, theta = np.abs(d1 - d2), np.abs(theta_difference(th1, th2))
    defined = (np.minimum(d1, d2) > LONG_AXIS) & np.isfinite(theta)
    return {"D_xy_end": float(d[-1]), "theta_end": float(theta[-1]),
            "D_xy_max": float(d.max()), "theta_max": float(theta[defined].max(initial=0.0))}


def _cost(result: dict) -> dict:
    keys = ("status", "steps", "rejected_steps", "velocity_evaluations", "layer_applications", "wall_time_s",
            "rtol", "rtol_choice", "scheme")
    return {k: result.get(k) for k in keys}


def bench_case(key: str, tmp: Path) -> dict:
    label = CASES[key][0]
    print(f"({key}) {label}", flush=True)
    for rtol in ("auto", FIXED_RTOL):  # warm-up (numba's cached kernels load): not counted in the wall times
        _run(key, rtol, tmp, t_end=WARM_UP)
    auto, s_auto = _run(key, "auto", tmp)
    print(f"    auto: rtol {auto['rtol']:g}, {auto['scheme']}, {auto['velocity_evaluations']} evaluations, "
          f"{auto['wall_time_s']:.1f} s", flush=True)
    fixed, s_fixed = _run(key, FIXED_RTOL, tmp)
    print(f"    {FIXED_RTOL:g}: {fixed['scheme']}, {fixed['velocity_evaluations']} evaluations, "
          f"{fixed['wall_time_s']:.1f} s", flush=True)
    coarse, s_coarse = _run(key, FIXED_RTOL, tmp, coarser=True)
    print(f"    level {CASES[key][1]['mesh']['level'] - 1}, {FIXED_RTOL:g}: {coarse['scheme']}, "
          f"{coarse['velocity_evaluations']} evaluations, {coarse['wall_time_s']:.1f} s", flush=True)
    for r in (auto, fixed, coarse):
        if r["status"] != "completed":
            raise SystemExit(f"({key}) a run ended {r['status']}: {r.get('status_reason')}; no table written")
    t_end = CASES[key][1]["time"]["t_end"]
    times = t_end * np.arange(1, SNAPSHOTS + 1) / SNAPSHOTS
    move = compare(s_auto, s_fixed, times)
    mesh = {k: v / (2**ORDER - 1) for k, v in compare(s_fixed, s_coarse, times).items()}
    ratio = fixed["velocity_evaluations"] / auto["velocity_evaluations"]
    within = {k: move[k] < FRACTION * mesh[k] for k in move}
    row = {"case": key, "label": label, "level": CASES[key][1]["mesh"]["level"], "run": RUN,
           "auto": _cost(auto), "fixed": _cost(fixed), "coarser": _cost(coarse),
           "evaluation_ratio": ratio, "wall_ratio": fixed["wall_time_s"] / auto["wall_time_s"],
           "move": move, "mesh_error": mesh, "within": within,
           "met_end": bool(ratio >= RATIO and within["D_xy_end"] and within["theta_end"]),
           "met_trajectory": bool(ratio >= RATIO and within["D_xy_max"] and within["theta_max"])}
    print(f"    ratio {ratio:.2f}; move {move}; mesh error {mesh}", flush=True)
    return row


def _yes(ok: bool) -> str:
    return "yes" if ok else "**no**"


def markdown(rows: list[dict]) -> str:
    commits = sorted({r["commit"] for r in rows if r.get("commit")})
    at = f" (capsim at {', '.join(commits)})" if commits else ""
    lines = [
        f"`time.rtol: auto`{at} against `time.rtol: {FIXED_RTOL:g}` on the cases of benchmarks/stepping.py at mesh "
        "level ≤ 3, default scheme (`auto`), one run each (`make bench-rtol-auto`, "
        "benchmarks/rtol_auto.py, one process on one thread, the machine's two cores shared with other work, "
        "so wall times are indicative). The move is |q_auto − q_1e-4|, at t_end and as the max over the "
        f"trajectory at the {SNAPSHOTS} snapshot times t_end/{SNAPSHOTS}, ..., t_end (rows of every run: the steps "
        "are clipped to them; θ modulo π, where D_xy > 1e-3). The "
        f"mesh error is the case's own at its level, by Richardson with order {ORDER} (the smallest order of "
        "benchmarks/error_model.md) from the same case one level coarser at rtol 1e-4: "
        f"|q_L − q_(L−1)| / {2**ORDER - 1}, absolute (D_xy and θ in rad), at t_end and its max over the "
        f"trajectory. The criterion (issue 44): evaluations at 1e-4 / at auto ≥ {RATIO:g} and both moves "
        f"< {FRACTION:g} × the mesh error (\"end\": at t_end; \"traj.\": max move against max mesh error).",
        "",
        "| case | auto rtol (scheme) | evals auto | evals 1e-4 (scheme) | ratio | steps auto / 1e-4 | "
        "wall s auto / 1e-4 | "
        "move D_xy end / max | mesh err D_xy end / max | move θ end / max | mesh err θ end / max | "
        "met end | met traj. |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        a, f, m, e = r["auto"], r["fixed"], r["move"], r["mesh_error"]
        lines.append(
            f"| ({r['case']}) {r['label']} | {a['rtol']:g} ({a['scheme']}) | {a['velocity_evaluations']} | "
            f"{f['velocity_evaluations']} ({f['scheme']}) | {r['evaluation_ratio']:.2f} | "
            f"{a['steps']} / {f['steps']} | {a['wall_time_s']:.1f} / {f['wall_time_s']:.1f} | "
            f"{m['D_xy_end']:.1e} / {m['D_xy_max']:.1e} | {e['D_xy_end']:.1e} / {e['D_xy_max']:.1e} | "
            f"{m['theta_end']:.1e} / {m['theta_max']:.1e} | {e['theta_end']:.1e} / {e['theta_max']:.1e} | "
            f"{_yes(r['met_end'])} | {_yes(r['met_trajectory'])} |")
    return "\n".join(lines) + "\n"


def main(args: list[str]) -> None:
    if "-h" in args or "--help" in args:
        print(__doc__)
        return
    keys = args or list(KEYS)
    unknown = sorted(set(keys) - set(KEYS))
    if unknown:
        raise SystemExit(f"benchmarks/rtol_auto.py: unknown cases {unknown}; allowed: {list(KEYS)}")
    commit = _commit()
    old = {r["case"]: r for r in json.loads(JSON.read_text())["results"]} if JSON.exists() else {}
    with tempfile.TemporaryDirectory(prefix="capsim-rtol-auto-") as tmp:
        for key in keys:
            old[key] = {**bench_case(key, Path(tmp)), "commit": commit}
            rows = [old[k] for k in KEYS if k in old]
            out = {"capsim_version": __version__, "created": RUN, "machine": platform.platform(),
                   "python": sys.version.split()[0], "fixed_rtol": FIXED_RTOL, "fraction": FRACTION,
                   "ratio": RATIO, "richardson_order": ORDER, "results": rows}
            JSON.write_text(json.dumps(out, indent=2) + "\n")  # kept as it goes
    MD.write_text(markdown(rows))
    print(MD.read_text())


if __name__ == "__main__":
    main(sys.argv[1:])

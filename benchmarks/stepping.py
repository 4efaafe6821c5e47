"""`make bench-stepping`: time schemes compared at equal accuracy.

For each case: a reference (``rkf23`` at rtol 1e-6 on the same mesh), then each
scheme at the loosest tolerance of a ladder that keeps
max over t of |D_xy − D_ref| ≤ 1e-4 and |θ − θ_ref| ≤ 1e-3 rad (θ compared
where the shape has a long axis, D_xy > 1e-3, modulo π). The reference is
interpolated at the run's own times (its steps are far shorter). Reported per
scheme: rtol, steps, velocity evaluations (stages, rejected attempts and
spectral-radius probes included), layer applications (each GMRES iteration
included), wall time, the two errors; and the ratios rkf23 / rkc of evaluations
and of wall time, measured in one run. Writes benchmarks/time_schemes.md and .json.

    python benchmarks/stepping.py            # every case (about an hour on 2 cores)
    python benchmarks/stepping.py a c f      # some of them
"""

from __future__ import annotations

import json
import platform
import sys
import tempfile
from datetime import datetime, timezone
from pathlib import Path

import numpy as np

from capsim import __version__
from capsim.config import case_from_dict
from capsim.runner import run_case
from capsim.store import read_trajectory

D_TOL, THETA_TOL = 1e-4, 1e-3
REFERENCE_RTOL = 1e-6
LADDER = {"rkf23": (1e-3, 1e-4, 1e-5), "rkc": (1e-2, 3e-3, 1e-3, 3e-4, 1e-4, 3e-5, 1e-5)}

CASES = {
    "a": ("sphere, G = 0.1, level 3, kt 10", {"mesh": {"level": 3}, "flow": {"shear_rate_G": 0.1},
                                              "time": {"t_end": 10.0}}),
    "b": ("sphere, G = 0.1, level 4, kt 4", {"mesh": {"level": 4}, "flow": {"shear_rate_G": 0.1},
                                             "time": {"t_end": 4.0}}),
    "c": ("sphere, G = 0.0125, level 3, kt 4", {"mesh": {"level": 3}, "flow": {"shear_rate_G": 0.0125},
                                                "time": {"t_end": 4.0}}),
    "d": ("sphere, lambda = 5, G = 0.1, level 3, kt 6",
          {"mesh": {"level": 3}, "flow": {"shear_rate_G": 0.1, "viscosity_ratio": 5.0}, "time": {"t_end": 6.0}}),
    "e": ("oblate b/a = 0.5, lambda = 10, G = 0.2, kappa = 1e-3, level 3, kt 20",
          {"shape": {"kind": "oblate", "aspect_ratio": 0.5}, "mesh": {"level": 3},
           "membrane": {"bending_modulus": 1e-3},
           "flow": {"shear_rate_G": 0.2, "viscosity_ratio": 10.0}, "time": {"t_end": 20.0}}),
    "f": ("biconcave, G = 0.2, level 2, kt 20", {"shape": {"kind": "biconcave"}, "mesh": {"level": 2},
                                                 "flow": {"shear_rate_G": 0.2}, "time": {"t_end": 20.0}}),
}


def _run(key: str, scheme: str, rtol: float, tmp: Path) -> tuple[dict, dict]:
    spec = json.loads(json.dumps(CASES[key][1]))
    spec["name"] = f"{key}-{scheme}-{rtol:g}"
    spec.setdefault("time", {}).update(scheme=scheme, rtol=rtol)
    spec["output"] = {"path": str(tmp / f"{spec['name']}.h5"), "snapshot_every": 1.0}
    result = run_case(case_from_dict(spec))
    return dict(result), read_trajectory(result["path"])["timeseries"]


def errors(run: dict, ref: dict) -> tuple[float, float]:
    """max |ΔD_xy| and max |Δθ| (mod π, where D_xy > 1e-3) against the reference at the run's times."""
    t = run["t"]
    d_ref = np.interp(t, ref["t"], ref["D_xy"])
    theta_ref = np.interp(t, ref["t"], np.unwrap(ref["theta"], period=np.pi))
    dtheta = (run["theta"] - theta_ref + np.pi / 2) % np.pi - np.pi / 2
    defined = np.minimum(run["D_xy"], d_ref) > 1e-3
    return float(np.abs(run["D_xy"] - d_ref).max()), float(np.abs(dtheta[defined]).max(initial=0.0))


def bench_case(key: str, tmp: Path) -> dict:
    label = CASES[key][0]
    ref_result, ref = _run(key, "rkf23", REFERENCE_RTOL, tmp)
    row: dict = {"case": key, "label": label, "reference": _cost(ref_result)}
    print(f"({key}) {label}: reference {_line(row['reference'])}", flush=True)
    for scheme, ladder in LADDER.items():
        for rtol in ladder:
            result, series = _run(key, scheme, rtol, tmp)
            d_err, theta_err = errors(series, ref) if result["status"] == "completed" else (np.inf, np.inf)
            entry = {**_cost(result), "rtol": rtol, "D_xy_error": d_err, "theta_error": theta_err}
            print(f"    {scheme} rtol {rtol:g}: {_line(entry)}  |dD| {d_err:.2e}  |dtheta| {theta_err:.2e}", flush=True)
            if d_err <= D_TOL and theta_err <= THETA_TOL:
                row[scheme] = entry
                break
        else:
            row[scheme] = {**entry, "note": "no tolerance of the ladder met the accuracy target"}
    if "rkf23" in row and "rkc" in row:
        row["evaluation_ratio"] = row["rkf23"]["velocity_evaluations"] / row["rkc"]["velocity_evaluations"]
        row["layer_ratio"] = row["rkf23"]["layer_applications"] / row["rkc"]["layer_applications"]
        row["wall_ratio"] = row["rkf23"]["wall_time_s"] / row["rkc"]["wall_time_s"]
    return row


def _cost(result: dict) -> dict:
    keys = ("status", "steps", "rejected_steps", "velocity_evaluations", "layer_applications", "wall_time_s")
    return {k: result.get(k) for k in keys}


def _line(c: dict) -> str:
    return (f"{c['status']}, {c['steps']} steps, {c['velocity_evaluations']} evaluations, "
            f"{c['layer_applications']} layer applications, {c['wall_time_s']:.1f} s")


def markdown(rows: list[dict]) -> str:
    head = ("| case | scheme | rtol | steps | velocity evals | layer apps | wall s | max abs dD_xy | max abs dtheta |\n"
            "|---|---|---|---|---|---|---|---|---|")
    lines = [head]
    for r in rows:
        for scheme in LADDER:
            e = r[scheme]
            lines.append(f"| ({r['case']}) {r['label']} | {scheme} | {e['rtol']:g} | {e['steps']} | "
                         f"{e['velocity_evaluations']} | {e['layer_applications']} | {e['wall_time_s']:.1f} | "
                         f"{e['D_xy_error']:.1e} | {e['theta_error']:.1e} |")
    lines += ["", "| case | evaluations rkf23/rkc | layer applications rkf23/rkc | wall time rkf23/rkc |",
              "|---|---|---|---|"]
    for r in rows:
        if "evaluation_ratio" in r:
            lines.append(f"| ({r['case']}) | {r['evaluation_ratio']:.2f} | {r['layer_ratio']:.2f} | "
                         f"{r['wall_ratio']:.2f} |")
    return "\n".join(lines) + "\n"


def main(keys: list[str]) -> None:
    keys = keys or list(CASES)
    unknown = sorted(set(keys) - set(CASES))
    if unknown:
        sys.exit(f"unknown cases {unknown}; allowed: {sorted(CASES)}")
    with tempfile.TemporaryDirectory(prefix="capsim-stepping-") as tmp:
        rows = [bench_case(key, Path(tmp)) for key in keys]
    here = Path(__file__).parent
    previous = here / "time_schemes.json"
    if previous.exists():  # a run of some cases keeps the others' rows
        kept = [r for r in json.loads(previous.read_text())["results"] if r["case"] not in keys]
        rows = sorted(kept + rows, key=lambda r: r["case"])
    out = {"capsim_version": __version__, "created": datetime.now(timezone.utc).isoformat(timespec="seconds"),
           "machine": platform.platform(), "python": sys.version.split()[0],
           "targets": {"D_xy": D_TOL, "theta_rad": THETA_TOL, "reference_rtol": REFERENCE_RTOL}, "results": rows}
    (here / "time_schemes.json").write_text(json.dumps(out, indent=2))
    (here / "time_schemes.md").write_text(markdown(rows))
    print(markdown(rows))


if __name__ == "__main__":
    main(sys.argv[1:])

"""Stability map (issue 8): how far each extreme case runs, its wall time and why
it stopped. Writes one benchmarks/stability_map/row<i>.json per case. Level 2 (130 nodes
per octant... 514 nodes) to keep the whole map within an hour on 2 cores."""

import json
import sys
import time
from pathlib import Path

from capsim.config import case_from_dict
from _common import run_or_stop

LEVEL = int(sys.argv[1]) if len(sys.argv) > 1 else 2
OUT = Path(__file__).with_name("stability_map")

CASES = [
    ("sphere λ=1 G=0.45", {"flow": {"shear_rate_G": 0.45}}, 20.0),
    ("sphere λ=1 G=1.0", {"flow": {"shear_rate_G": 1.0}}, 20.0),
    ("sphere λ=0.01 G=0.2", {"flow": {"shear_rate_G": 0.2, "viscosity_ratio": 0.01}}, 20.0),
    ("sphere λ=100 G=0.2", {"flow": {"shear_rate_G": 0.2, "viscosity_ratio": 100.0}}, 20.0),
    ("sphere λ=1 G=0.001", {"flow": {"shear_rate_G": 0.001}}, 2.0),
]
for lam in (1.0, 5.0, 10.0):
    CASES.append((f"oblate b/a=0.3 λ={lam:g} G=0.2", {"shape": {"kind": "oblate", "aspect_ratio": 0.3},
                  "initial_tilt_deg": 45.0, "flow": {"shear_rate_G": 0.2, "viscosity_ratio": lam}}, 40.0))
    CASES.append((f"biconcave λ={lam:g} G=0.2", {"shape": {"kind": "biconcave"}, "initial_tilt_deg": 45.0,
                  "flow": {"shear_rate_G": 0.2, "viscosity_ratio": lam}}, 40.0))


def main() -> None:
    OUT.mkdir(exist_ok=True)
    rows = []
    only = set(sys.argv[2:])
    for i, (label, spec, t_end) in enumerate(CASES):
        if only and str(i) not in only:
            continue
        case = case_from_dict({
            "name": f"map{i}", "mesh": {"level": LEVEL}, "time": {"t_end": t_end},
            "solver": {"tol": 1e-6}, "output": {"path": str(OUT / f"map{i}.h5"), "snapshot_every": 1.0},
            **spec,
        })
        t0 = time.perf_counter()
        try:
            s = run_or_stop(case)
        except Exception as exc:  # recorded, never fatal for the map
            s = {"status": "failed", "status_reason": f"{type(exc).__name__}: {exc}", "t": float("nan")}
        s["wall_time_s"] = time.perf_counter() - t0
        row = {"case": label, "t_end": t_end, "level": LEVEL, **{k: s.get(k) for k in (
            "status", "status_reason", "t", "steps", "wall_time_s", "D_xy", "theta", "motion", "volume_drift")}}
        rows.append(row)
        print(json.dumps(row, default=str), flush=True)
        (OUT / f"row{i}.json").write_text(json.dumps(row, default=str))


if __name__ == "__main__":
    main()

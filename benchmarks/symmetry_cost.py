"""Cost of the half symmetry (point inversion, any orientation) against the quarter
(mirror z and rotation by π about z, axis in the shear plane) at the same level and
tolerance (issue 26: at most 2.2×). The same in-plane case (oblate b/a = 0.6 tilted
30°, G = 0.1, kt 1, rkf23 rtol 1e-4) is run with mesh.symmetry quarter, half and none;
quarter and half give the same trajectory to 1e-10 (tests/solve/test_orientation.py), so
the runs take the same steps and the wall times compare the layer work alone.
Medians of ``--repeat`` runs, interleaved (the machine is shared).

    PYTHONPATH=. NUMBA_NUM_THREADS=1 python benchmarks/symmetry_cost.py [--levels 2 3] [--repeat 3]
"""

from __future__ import annotations

import argparse
import json
import tempfile

import numpy as np

from capsim.config import case_from_dict
from _common import run_or_stop

MODES = ("quarter", "half", "none")


def _case(tmp: str, level: int, lam: float, mode: str, t_end: float):
    return case_from_dict({
        "name": f"sym-{level}-{lam:g}-{mode}",
        "shape": {"kind": "oblate", "aspect_ratio": 0.6}, "initial_tilt_deg": 30.0,
        "flow": {"shear_rate_G": 0.1, "viscosity_ratio": lam},
        "mesh": {"level": level, "symmetry": mode},
        "time": {"t_end": t_end},
        "output": {"path": f"{tmp}/{level}-{lam:g}-{mode}.h5", "snapshot_every": t_end},
    })


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--levels", type=int, nargs="+", default=[2, 3])
    ap.add_argument("--lams", type=float, nargs="+", default=[1.0, 5.0])
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--t-end", type=float, default=1.0)
    ap.add_argument("--out", default="benchmarks/symmetry_cost.json")
    args = ap.parse_args()
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        run_or_stop(_case(tmp, 0, 5.0, "half", 0.05))  # JIT warm-up
        for level in args.levels:
            for lam in args.lams:
                walls = {m: [] for m in MODES}
                steps = {}
                for _ in range(args.repeat):
                    for mode in MODES:
                        s = run_or_stop(_case(tmp, level, lam, mode, args.t_end))
                        walls[mode].append(s["wall_time_s"])
                        steps[mode] = s["steps"]
                med = {m: float(np.median(w)) for m, w in walls.items()}
                row = {"level": level, "viscosity_ratio": lam, "steps": steps, "wall_s": med,
                       "half_over_quarter": med["half"] / med["quarter"], "none_over_quarter": med["none"] / med["quarter"]}
                rows.append(row)
                print(f"level {level} λ {lam:g}: steps {steps['quarter']}/{steps['half']}/{steps['none']}  "
                      f"wall quarter {med['quarter']:.2f} s, half {med['half']:.2f} s, none {med['none']:.2f} s  "
                      f"half/quarter {row['half_over_quarter']:.2f}, none/quarter {row['none_over_quarter']:.2f}",
                      flush=True)
    with open(args.out, "w") as fh:
        json.dump(rows, fh, indent=1)


if __name__ == "__main__":
    main()

"""The calibration of capsim.solve.scheme_cost.COSTS (issue 44, item 3): short runs of every time scheme
at mesh levels 1-3, interleaved, the seconds per operation fitted to their median wall times by
non-negative least squares (wall = Σ count × cost, the counts of capsim.solve.scheme_cost.run_counts).

    python benchmarks/scheme_cost.py [rounds]      # prints a new COSTS table (make bench-scheme-cost)
"""

from __future__ import annotations

from typing import Any

from capsim.solve.scheme_cost import OPERATIONS, run_counts

# ---------------------------------------------------------------- the calibration

#: (name, scheme, preconditioner, G, λ, kt per level) of the calibration runs
DESIGNS = (
    ("rkf23", "rkf23", None, 0.1, 1.0, {1: 2.0, 2: 1.0, 3: 0.3}),
    ("rkc", "rkc", None, 0.1, 1.0, {1: 4.0, 2: 2.0, 3: 0.6}),
    ("rkc-stiff", "rkc", None, 0.001, 1.0, {1: 1.0, 2: 0.5, 3: 0.1}),
    ("rkc-lambda5", "rkc", None, 0.1, 5.0, {1: 2.0, 2: 1.0, 3: 0.3}),
    ("li-local", "linearly_implicit", "local", 0.001, 1.0, {1: 2.0, 2: 1.0, 3: 0.3}),
    ("li-local-lambda5", "linearly_implicit", "local", 0.1, 5.0, {1: 2.0, 2: 1.0, 3: 0.3}),
    ("li-dense", "linearly_implicit", "dense", 0.001, 1.0, {1: 2.0, 2: 1.0, 3: 0.3}),
    ("li-dense-G0.1", "linearly_implicit", "dense", 0.1, 1.0, {1: 4.0, 2: 2.0, 3: 0.6}),
)


def calibrate(levels: tuple[int, ...] = (1, 2, 3), rounds: int = 3, rtol: float = 1e-4,
              verbose: bool = True) -> dict[int, dict[str, Any]]:
    """Run DESIGNS at each level ``rounds`` times (interleaved) and fit the costs per level:
    {n_nodes: {"level", "costs", "runs": [(name, counts, median wall, predicted wall)]}}."""
    import statistics
    import tempfile
    from pathlib import Path

    import numpy as np
    from scipy.optimize import nnls

    from capsim.config import case_from_dict
    from capsim.runs.runner import run_case

    out: dict[int, dict[str, Any]] = {}
    with tempfile.TemporaryDirectory() as d:
        tmp = Path(d)

        def case(name, scheme, pre, g, lam, kt, level, rnd):
            time = {"scheme": scheme, "rtol": rtol, "t_end": kt}
            if pre is not None:
                time["preconditioner"] = pre
            return case_from_dict({"name": f"{name}-{level}-{rnd}", "mesh": {"level": level},
                                   "flow": {"shear_rate_G": g, "viscosity_ratio": lam}, "time": time,
                                   "output": {"path": str(tmp / f"{name}-{level}-{rnd}.h5"), "snapshot_every": 1.0}})

        for name, scheme, pre, g, lam, kts in DESIGNS:  # kernels compiled or loaded before timing
            run_case(case(name, scheme, pre, g, lam, 0.02, 1, "warm"))
        for level in levels:
            walls: dict[str, list[float]] = {name: [] for name, *_ in DESIGNS}
            counts: dict[str, dict[str, float]] = {}
            n_nodes = None
            for rnd in range(rounds):
                for name, scheme, pre, g, lam, kts in DESIGNS:
                    c = case(name, scheme, pre, g, lam, kts[level], level, rnd)
                    n_nodes = c.mesh.n_nodes
                    result = run_case(c)
                    walls[name].append(float(result["wall_time_s"]))
                    counts[name] = run_counts(result)
                    if verbose:
                        print(f"level {level} round {rnd} {name}: {result['wall_time_s']:.3f} s {counts[name]}",
                              flush=True)
            names = [n for n, *_ in DESIGNS]
            a = np.array([[counts[n][op] for op in OPERATIONS] for n in names])
            b = np.array([statistics.median(walls[n]) for n in names])
            # relative residuals: weight each run by its own wall time
            x, _ = nnls(a / b[:, None], np.ones_like(b))
            fitted = dict(zip(OPERATIONS, (float(v) for v in x)))
            out[n_nodes] = {"level": level, "costs": fitted,
                            "runs": [(n, counts[n], float(w), float(a[i] @ x)) for i, (n, w) in
                                     enumerate(zip(names, b))]}
            if verbose:
                print(f"level {level} ({n_nodes} nodes): " + ", ".join(f"{k} {v:.3g}" for k, v in fitted.items()))
                for n, _, w, p in out[n_nodes]["runs"]:
                    print(f"    {n}: measured {w:.3f} s, fitted {p:.3f} s")
    return out


if __name__ == "__main__":  # python benchmarks/scheme_cost.py [rounds]
    import sys

    from capsim.numerics.threads import apply_policy

    apply_policy()
    table = calibrate(rounds=int(sys.argv[1]) if len(sys.argv) > 1 else 3)
    print("COSTS = {")
    for n, entry in table.items():
        print(f"    {n}: {{" + ", ".join(f'"{k}": {v:.2g}' for k, v in entry["costs"].items()) + "},")
    print("}")

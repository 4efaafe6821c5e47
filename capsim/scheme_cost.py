"""What one operation of a time scheme costs in wall time, per mesh (issue 44, item 3).

``time.scheme: auto`` (``capsim.timestepping.Automatic``) predicts each candidate's wall time
per unit time as counts × costs: the counts (accepted steps, velocity evaluations, layer
applications beyond one per evaluation, GMRES iterations of the stage solves, dense layer
matrices) from its measurement of ρ and the tolerance; the costs, seconds per operation, from
:data:`COSTS`, a table measured by :func:`calibrate` on the octahedron at levels 1-3 (the
sphere in shear, quarter symmetry, λ = 1 and 5, one thread per the CLI's policy) and
interpolated in the number of nodes. No timing happens in a run: the table is data, so the
choice stays deterministic (a resumed run makes it again).

The operations (each run's counters, :class:`capsim.runner.RunResult`):

- ``step``: what an accepted step costs beyond its evaluations (the error norm, the
  observables, the row written): the runner's own overhead, large against an evaluation on
  coarse meshes;
- ``evaluation``: one velocity evaluation at λ = 1 (the membrane, one single layer, the far
  field and the volume correction);
- ``layer``: each further layer application (a double-layer GMRES iteration at λ ≠ 1, a stage
  solve's Jacobian-vector product);
- ``iteration_local``, ``iteration_dense``: a stage solve's GMRES iteration beyond its layer
  applications (the membrane Hessian's product, the preconditioner: the local one's sparse
  solve, the dense one's LU solves with (3N)² matrices);
- ``matrix``: one dense layer matrix (the dense preconditioner, every
  time.jacobian_refresh_steps steps) with what is built from it: the product with the Hessian,
  the LU factorisations of the (3N)² stage operators (∝ N³) until the next rebuild.

:func:`calibrate` runs short runs of every scheme (DESIGNS) at each level, ``rounds`` times
interleaved, and fits the costs to their median wall times by non-negative least squares
(wall = Σ count × cost), per level. ``python -m capsim.scheme_cost`` prints a new table.
"""

from __future__ import annotations

import math
from typing import Any

#: the operations, in the order of a cost vector
OPERATIONS = ("step", "evaluation", "layer", "iteration_local", "iteration_dense", "matrix")

#: seconds per operation at the octahedron's levels 1, 2, 3 (n_nodes: costs), quarter symmetry
#: (targets = a quarter of the nodes or so). Measured by calibrate() on this project's 2-core
#: development machine (x86_64, shared, capsim 0.1.0 at issue 44), rounds 3:
COSTS: dict[int, dict[str, float]] = {
    66: {"step": 1.2e-3, "evaluation": 4.0e-5, "layer": 9.2e-5, "iteration_local": 1.0e-4, "iteration_dense": 0.0,
         "matrix": 0.025},
    258: {"step": 1.3e-3, "evaluation": 8.9e-5, "layer": 1.7e-4, "iteration_local": 3.0e-4, "iteration_dense": 0.0,
          "matrix": 0.13},
    1026: {"step": 3.2e-3, "evaluation": 4.4e-4, "layer": 7.7e-4, "iteration_local": 1.9e-3, "iteration_dense": 0.0,
           "matrix": 3.4},
}
#: the nodes' exponent beyond the table (the dense sums and matrices go like N², the LU like N³)
EXTRAPOLATION = {"step": 1.0, "evaluation": 2.0, "layer": 2.0, "iteration_local": 2.0, "iteration_dense": 2.0,
                 "matrix": 3.0}


def costs_for(n_nodes: int, target_fraction: float = 0.25) -> dict[str, float]:
    """Seconds per operation on a mesh of ``n_nodes`` nodes: COSTS interpolated log-log in the
    nodes (beyond the table: its last entry × (n / n_last)^EXTRAPOLATION). ``target_fraction``:
    the symmetry's target nodes over the nodes; the evaluation, layer and iteration costs go
    with the targets (COSTS were measured at about a quarter)."""
    sizes = sorted(COSTS)
    out = {}
    for op in OPERATIONS:
        if n_nodes <= sizes[0]:
            value = COSTS[sizes[0]][op] * (n_nodes / sizes[0]) ** EXTRAPOLATION[op]
        elif n_nodes >= sizes[-1]:
            value = COSTS[sizes[-1]][op] * (n_nodes / sizes[-1]) ** EXTRAPOLATION[op]
        else:
            hi = next(i for i, n in enumerate(sizes) if n >= n_nodes)
            n0, n1 = sizes[hi - 1], sizes[hi]
            w = math.log(n_nodes / n0) / math.log(n1 / n0)
            a, b = COSTS[n0][op], COSTS[n1][op]
            value = math.exp((1 - w) * math.log(a) + w * math.log(b)) if a > 0 and b > 0 else (1 - w) * a + w * b
        if op in ("evaluation", "layer", "iteration_local", "iteration_dense"):
            value *= max(target_fraction, 1e-3) / 0.25
        out[op] = value
    return out


def seconds(counts: dict[str, float], costs: dict[str, float]) -> float:
    """Σ count × cost over OPERATIONS (missing counts are 0)."""
    return float(sum(counts.get(op, 0.0) * costs[op] for op in OPERATIONS))


def run_counts(result: Any) -> dict[str, float]:
    """A run's counts in the terms of OPERATIONS (a RunResult or its mapping)."""
    evals = float(result["velocity_evaluations"])
    its = float(result.get("linear_iterations") or 0)
    mats = float(result.get("layer_matrices") or 0)
    dense = mats > 0
    return {"step": float(result["steps"]) + float(result.get("rejected_steps") or 0), "evaluation": evals,
            "layer": max(float(result["layer_applications"]) - evals, 0.0),
            "iteration_local": 0.0 if dense else its, "iteration_dense": its if dense else 0.0, "matrix": mats}


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
    from capsim.runner import run_case

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


if __name__ == "__main__":  # python -m capsim.scheme_cost [rounds]
    import sys

    from capsim.threads import apply_policy

    apply_policy()
    table = calibrate(rounds=int(sys.argv[1]) if len(sys.argv) > 1 else 3)
    print("COSTS = {")
    for n, entry in table.items():
        print(f"    {n}: {{" + ", ".join(f'"{k}": {v:.2g}' for k, v in entry["costs"].items()) + "},")
    print("}")

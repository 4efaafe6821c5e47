"""What one operation of a time scheme costs in wall time, per mesh.

``time.scheme: auto`` (``capsim.solve.timestepping.Automatic``) predicts each candidate's wall time
per unit time as counts × costs: the counts (accepted steps, velocity evaluations, layer
applications beyond one per evaluation, GMRES iterations of the stage solves, dense layer
matrices) from its measurement of ρ and the tolerance; the costs, seconds per operation, from
:data:`COSTS`, a table measured by ``benchmarks/scheme_cost.py`` on the octahedron at levels 1-3 (the
sphere in shear, quarter symmetry, λ = 1 and 5, one thread per the CLI's policy) and
interpolated in the number of nodes. No timing happens in a run: the table is data, so the
choice stays deterministic (a resumed run makes it again).

The operations (each run's counters, :class:`capsim.runs.runner.RunResult`):

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

``benchmarks/scheme_cost.py`` (its ``calibrate``) runs short runs of every scheme at each level,
interleaved, and fits the costs to their median wall times by non-negative least squares
(wall = Σ count × cost), per level, and prints a new table (``make bench-scheme-cost``).
"""

from __future__ import annotations

import math
from typing import Any

#: the operations, in the order of a cost vector
OPERATIONS = ("step", "evaluation", "layer", "iteration_local", "iteration_dense", "matrix")

#: seconds per operation at the octahedron's levels 1, 2, 3 (n_nodes: costs), quarter symmetry
#: (targets = a quarter of the nodes or so). Measured by benchmarks/scheme_cost.py on this project's 2-core
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

"""Speed benchmarks (not tests): one velocity evaluation against a bare dense
Stokeslet sum of the same size, with a per-stage breakdown.

Timings are medians over ``repeat`` runs with a warm JIT cache; the bare sum and
the full evaluation are interleaved so that load from other processes on a
shared machine affects both alike.
"""

from __future__ import annotations

import os
import time

import numpy as np

from capsim import kernels
from capsim.membrane import get_law
from capsim.mesh import unit_sphere_mesh
from capsim.solver import CapsuleModel, Discretization


def bench_velocity(
    level: int = 3, viscosity_ratio: float = 1.0, repeat: int = 7, base: str = "octahedron", symmetry: bool = True
) -> dict:
    """``symmetry`` as the case setting mesh.symmetry (default on): integrals at
    the z ≥ 0 nodes only. The bare sum is always the full N_p × N_sources sum."""
    mesh = unit_sphere_mesh(base, level)
    disc = Discretization(mesh.elements, mesh.n_vertices)
    X = mesh.positions
    if symmetry:
        X = disc.enable_mirror_symmetry(X)
    model = CapsuleModel(disc, X, 0.1, viscosity_ratio, get_law("thin_shell"), {})
    # a deformed, tilted configuration: a realistic membrane state
    c, s = np.cos(0.6), np.sin(0.6)
    Q = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])
    x = X @ np.diag([1.15, 0.88, 1.0 / (1.15 * 0.88)]) @ Q.T
    model.velocity(x)  # JIT warm-up (and solver warm start, as in a run)
    geo = disc.geometry(x)
    sources = geo.points.reshape(-1, 3)
    strengths = np.ones_like(sources)
    kernels.stokeslet_sum(x, sources, strengths)

    bare, full, stages, iters = [], [], [], []
    for _ in range(repeat):
        t0 = time.perf_counter()
        kernels.stokeslet_sum(x, sources, strengths)
        bare.append(time.perf_counter() - t0)
        for k in model.stage_times:
            model.stage_times[k] = 0.0
        xp = x * (1.0 + 1e-4 * np.random.default_rng(0).standard_normal(x.shape))
        t0 = time.perf_counter()
        model.velocity(xp)
        full.append(time.perf_counter() - t0)
        stages.append(dict(model.stage_times))
        iters.append(model.last_solve_info["iterations"])
    med_stage = {k: float(np.median([s[k] for s in stages])) for k in stages[0]}
    bare_s = float(np.median(bare))
    full_s = float(np.median(full))
    return {
        "level": level,
        "base": base,
        "symmetry": symmetry,
        "viscosity_ratio": viscosity_ratio,
        "n_nodes": int(X.shape[0]),
        "n_elements": int(mesh.elements.shape[0]),
        "n_sources": int(sources.shape[0]),
        "repeat": repeat,
        "threads": int(os.environ.get("NUMBA_NUM_THREADS", os.cpu_count() or 1)),
        "velocity_eval_s": full_s,
        "bare_stokeslet_sum_s": bare_s,
        "ratio_to_bare": full_s / bare_s,
        "stages_s": med_stage,
        "solver_iterations_median": float(np.median(iters)),
    }

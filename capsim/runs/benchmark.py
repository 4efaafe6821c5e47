"""Speed benchmarks (not tests): one velocity evaluation against a bare dense
Stokeslet sum of the same size, with a per-stage breakdown, and the layer time
(single layer + λ ≠ 1 solve) under each symmetry the mesh has.

Timings are medians over ``repeat`` runs with a warm JIT cache. The evaluations run
back to back, as a run makes them, and the bare sums after them: on this project's
machines (AMD EPYC, AVX-512) a burst of vectorised sums slows the scalar code that
follows for milliseconds (level 3, quarter symmetry: after ten bare full-size sums the
next evaluations' singular correction took 170, 129, 114, 84, 77 µs, then ~60, against
45 µs without; the work outside the sum against it 1.48 falling to 0.65, against
0.55), so interleaving them, once meant to share the load of other processes alike,
measured the bare sums' after-effect instead of the evaluation.
"""

from __future__ import annotations

import os
import time

import numpy as np

from capsim.numerics import kernels
from capsim.config import Case, ConfigError, case_from_dict
from capsim.solve.solver import CapsuleModel, build_model

# symmetry settings of the benchmark (group found → setting): "quarter" is what a run with
# mesh.symmetry auto uses in the plane, "half" (the point inversion) what it uses off the plane
SYMMETRY_SETTINGS = {"none": "none", "mirror_z": "mirror_z", "mirror_z+rotation_z": "quarter", "inversion": "half"}
#: the old boolean settings, still taken
_FROM_BOOL = {True: "auto", False: "none"}


def _model(case: Case, symmetry: bool | str) -> tuple[CapsuleModel, np.ndarray]:
    """The run's model of the case (``build_model``) with the benchmark's symmetry setting,
    which may be the mirror only (not a case setting)."""
    mode = _FROM_BOOL[symmetry] if isinstance(symmetry, bool) else symmetry
    return build_model(case, symmetry=mode)


#: most timed repetitions (each is one velocity evaluation: up to minutes at level 6)
MAX_REPEAT = 1000


def bench_case(
    level: int, viscosity_ratio: float = 1.0, base: str = "octahedron", symmetry: bool | str = True, repeat: int = 1
) -> Case:
    """The benchmark's options checked by the case schema, as `capsim run` checks a case's.

    Raises a one-line ConfigError naming the option, its value and what is allowed.
    """
    if isinstance(repeat, bool) or not isinstance(repeat, int) or not 1 <= repeat <= MAX_REPEAT:
        raise ConfigError(f"bench options: --repeat = {repeat!r}: must be an integer in [1, {MAX_REPEAT}]")
    allowed = ("auto", *SYMMETRY_SETTINGS.values())
    if isinstance(symmetry, str) and symmetry not in allowed:
        raise ConfigError(f"bench options: symmetry = {symmetry!r}: must be true, false or one of {', '.join(allowed)}")
    mode = symmetry if isinstance(symmetry, bool) or symmetry != "mirror_z" else "auto"
    # G = 0.1 (the demo's) and the λ ≠ 1 solve to 1e-8, as the benchmark always measured
    return case_from_dict(
        {"name": "bench", "flow": {"viscosity_ratio": viscosity_ratio, "shear_rate_G": 0.1},
         "mesh": {"level": level, "base": base, "symmetry": mode}, "solver": {"tol": 1e-8}},
        source="bench options",
    )


def bench_velocity(
    level: int = 3, viscosity_ratio: float = 1.0, repeat: int = 7, base: str = "octahedron",
    symmetry: bool | str = True, compare_symmetry: bool = True,
) -> dict:
    """``symmetry`` as the case setting mesh.symmetry (default auto: the mirror in z
    and the rotation by π about z, integrals at a quarter of the nodes; "half" the
    point inversion, half of the nodes, as a run off the shear plane uses);
    "mirror_z" for the mirror only. The bare sum is always the full
    N_p × N_sources sum. ``compare_symmetry`` adds ``layer_s_by_symmetry``: the
    median layer time (single layer + solve) without symmetry, with the mirror,
    with the inversion and with the group of four, measured interleaved, their
    ratios to no symmetry, and ``layer_ratio_half_to_quarter`` (issue 26: at most 2.2).

    The options are checked first by :func:`bench_case` (one-line ConfigError)."""
    case = bench_case(level, viscosity_ratio, base, symmetry, repeat)
    level, base, viscosity_ratio = case.mesh.level, case.mesh.base, case.flow.viscosity_ratio
    variants = {"main": symmetry}
    if compare_symmetry:
        variants.update(SYMMETRY_SETTINGS)
    models = {k: _model(case, s) for k, s in variants.items()}
    model, X = models["main"]
    # a deformed, tilted configuration: a realistic membrane state
    c, s = np.cos(0.6), np.sin(0.6)
    Q = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])
    F = np.diag([1.15, 0.88, 1.0 / (1.15 * 0.88)]) @ Q.T
    configs = {k: Xk @ F for k, (_, Xk) in models.items()}
    for k, (m, _) in models.items():
        m.velocity(configs[k])  # JIT warm-up (and solver warm start, as in a run)
    x = configs["main"]
    geo = model.disc.geometry(x)
    sources = geo.points.reshape(-1, 3)
    strengths = np.ones_like(sources)
    kernels.stokeslet_sum(x, sources, strengths)

    bare, full, stages, splits, iters = [], [], [], [], []
    layer: dict[str, list[float]] = {k: [] for k in models}
    noise = np.random.default_rng(0).standard_normal(x.shape)
    # each repeat a step further along a smooth in-plane strain (it keeps every symmetry), as
    # successive evaluations of a run are: the warm starts (GMRES) work as in a run
    step = np.eye(3) + 1e-3 * np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 0.0]])

    def evaluate(k: str) -> tuple[float, dict]:
        m = models[k][0]
        m.reset_stage_times()
        # a perturbation with the configuration's symmetry (expand makes it exact)
        configs[k] = configs[k] @ step
        xp = configs[k] + 1e-4 * m.disc.expand(noise[m.disc.targets])
        t0 = time.perf_counter()
        m.velocity(xp)
        elapsed = time.perf_counter() - t0
        times = m.stage_times
        layer[k].append(times["single_layer"] + times["solve"])
        return elapsed, times

    # the main model alone, its evaluations back to back as a run makes them (the split and the
    # evaluation time; another model's evaluation in between, the "none" one's full-size sum
    # above all, slows the stages after it as the bare sums do: module docstring)
    for _ in range(repeat):
        elapsed, times = evaluate("main")
        full.append(elapsed)
        stages.append(times)
        splits.append(model.split_times)
        iters.append(model.last_solve_info["iterations"])
    for _ in range(repeat):
        t0 = time.perf_counter()
        kernels.stokeslet_sum(x, sources, strengths)
        bare.append(time.perf_counter() - t0)
    # then the symmetry settings' layer times, interleaved with each other
    if compare_symmetry:
        for _ in range(repeat):
            for k in SYMMETRY_SETTINGS:
                evaluate(k)
    med_stage = {k: float(np.median([s[k] for s in stages])) for k in stages[0]}
    med_split = {k: float(np.median([s.get(k, 0.0) for s in splits])) for k in splits[0]}
    # everything an evaluation does besides its Stokeslet sum (at the targets), against that sum,
    # from the medians per stage: on a shared machine a descheduling of a few ms hits one stage of
    # some evaluations, which a stage's median ignores and an evaluation's median may not
    outside = sum(v for k, v in med_split.items() if k != "stokeslet_sum") / med_split["stokeslet_sum"]
    bare_s = float(np.median(bare))
    full_s = float(np.median(full))
    out = {
        "level": level,
        "base": base,
        "symmetry": model.disc.symmetry,
        "viscosity_ratio": viscosity_ratio,
        "n_nodes": int(X.shape[0]),
        "n_targets": int(model.disc.targets.size),
        "n_elements": int(model.disc.elements.shape[0]),
        "n_sources": int(sources.shape[0]),
        "repeat": repeat,
        "threads": int(os.environ.get("NUMBA_NUM_THREADS", os.cpu_count() or 1)),
        "velocity_eval_s": full_s,
        "bare_stokeslet_sum_s": bare_s,
        "ratio_to_bare": full_s / bare_s,
        "stages_s": med_stage,
        "split_s": med_split,
        "split_total_s": float(sum(med_split.values())),
        "outside_sum_ratio": float(outside),
        "layer_s": float(np.median(layer["main"])),
        "solver_iterations_median": float(np.median(iters)),
    }
    if compare_symmetry:
        by = {models[k][0].disc.symmetry: float(np.median(layer[k])) for k in SYMMETRY_SETTINGS}
        out["layer_s_by_symmetry"] = by
        out["layer_ratio_to_none"] = {k: v / by["none"] for k, v in by.items()}
        out["layer_ratio_half_to_quarter"] = by["inversion"] / by["mirror_z+rotation_z"]
    return out


#: the stages of the split in the order an evaluation runs them, each with its group
SPLIT_STAGES = {
    "geometry": "membrane", "strain": "membrane", "mass_assembly": "membrane", "mass_solve": "membrane",
    "gather": "membrane", "contour_traction": "membrane",
    "interpolation": "single layer", "stokeslet_sum": "single layer", "singular_correction": "single layer",
    "near_correction": "single layer", "expand": "single layer",
    "far_field": "velocity", "normals": "velocity", "double_layer_solve": "velocity", "viscous_solve": "velocity",
    "volume_correction": "velocity",
}


def split_lines(result: dict) -> str:
    """The per-stage split of ``bench_velocity``'s result as lines: stage, group, ms per
    evaluation and share of the Stokeslet sum (medians over the repeats), then the work
    outside the sum against the sum."""
    split = result["split_s"]
    order = [k for k in SPLIT_STAGES if k in split] + sorted(set(split) - set(SPLIT_STAGES))
    total_sum = split["stokeslet_sum"]
    lines = [f"per-stage split (ms per evaluation, median of {result['repeat']}; x sum = against the Stokeslet sum):"]
    for k in order:
        lines.append(f"  {k:<20} {SPLIT_STAGES.get(k, ''):<13} {1e3 * split[k]:8.3f} ms  {split[k] / total_sum:6.2f} x sum")
    lines.append(f"  {'all stages':<20} {'':<13} {1e3 * result['split_total_s']:8.3f} ms"
                 f"  (whole evaluation: {1e3 * result['velocity_eval_s']:.3f} ms)")
    lines.append(f"work outside the Stokeslet sum: {result['outside_sum_ratio']:.2f} x the sum")
    return "\n".join(lines)

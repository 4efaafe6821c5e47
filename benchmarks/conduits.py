"""The cost of a conduit's wall (issue 53, "Cost, measured"): `make bench-conduits`.

1. Against the wall's nodes M (a tube of radius 2 a, a/R = 0.5, 8.6 a long, round caps,
   ``tube_mesh(..., caps="round")`` with one element size along its whole length, chosen to give
   M ≈ 1k, 2k, 4k and 8k nodes): the single layer's assembly, its LU factorisation (both inside
   ``WallOperator.__init__``, timed by wrapping the two calls it makes), the matrix's memory, one
   back-solve (``WallOperator.density``), one wall→capsule sum at the 258 nodes of a level-2
   capsule at the origin (``rigid_surface.single_layer_at``), one capsule→wall sum
   (``kernels.stokeslet_sum`` from the capsule's 128×7 rule points to the M nodes) and, for the
   iterative alternative to the factorisation, one matrix-free application of W as the dense
   Stokeslet sum from every wall rule point to every wall node (a lower bound: no singular
   corrections) with the GMRES iterations (scipy, on the dense matrix, rtol 1e-8, restart 300:
   never reached) that a unit point force at FORCE_AT needs. One numba thread (the policy
   capsules.py applies, then ``numba.set_num_threads(1)``) and one BLAS thread (the LU, the
   back-solve: ``OPENBLAS_NUM_THREADS=1`` unless set; on 2 threads scipy's OpenBLAS segfaulted
   factorising the 8k matrix, 4.8 GB). The cheap operations: medians over ``--rounds`` rounds, the sizes
   interleaved within a round, after a warm-up (numba's compilation excluded); the assembly and the
   LU: medians of ``--build-rounds`` builds up to 4k nodes, one build at 8k.
2. Whole runs (``run_case`` through ``run_or_stop``, each in its own subprocess so that its peak
   memory is its own, a fresh output path each): configs/tube.yaml (level 2, Ca = G = 0.1,
   neo-Hookean) with t_end 6.0 (10 radii at about 1.70 U), and the same at level 3 (1.5 min here;
   ``--skip-level3`` leaves it out). The wall's operator is built first and timed (the one-time
   wall work; the run finds it in the operator cache), then the run.

Writes benchmarks/conduits.md (the tables the docs include) and benchmarks/conduits.json.

    PYTHONPATH=. python benchmarks/conduits.py [--rounds 5] [--build-rounds 3] [--skip-level3]
"""

from __future__ import annotations

import argparse
import json
import math
import os
import platform
import subprocess
import sys
import tempfile
import time
from datetime import datetime, timezone
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
OUT = ROOT / "benchmarks" / "conduits"
CONFIG = ROOT / "configs" / "tube.yaml"

#: the tube (units of a): radius 2 (a/R = 0.5) and the length conduit_dimensions gives it (8.6 a)
RADIUS, LENGTH = 2.0, 8.6
#: the wall's node counts aimed at (the mesh comes in steps: the nearest is taken)
TARGETS = (1000, 2000, 4000, 8000)
#: the size not run: its dense matrix would not fit this machine's memory
NOT_RUN = 16000
#: the point force whose wall velocity is GMRES's right-hand side (units of a; unit force along x)
FORCE_AT = (0.3, 0.4, 0.1)
GMRES_RTOL, GMRES_RESTART = 1e-8, 300
#: the variable that sets scipy's OpenBLAS threads (one in part 1: see main)
BLAS_THREADS = "OPENBLAS_NUM_THREADS"
#: the whole runs: (level, t_end)
RUNS = ((2, 6.0), (3, 6.0))


# ------------------------------------------------------------------------ 1. against M

def tube(h: float):
    from capsim.numerics.conduit_mesh import tube_mesh

    return tube_mesh(RADIUS, LENGTH, h, h, 0.5 * LENGTH, caps="round")


def size_for(target: int) -> tuple[float, int]:
    """(element size, M) of the tube whose M is nearest `target` (M falls in steps as h grows)."""
    lo, hi = 0.05, 3.0  # M(lo) > target >= M(hi)
    for _ in range(40):
        mid = math.sqrt(lo * hi)
        if tube(mid).n_nodes > target:
            lo = mid
        else:
            hi = mid
    m_lo, m_hi = tube(lo).n_nodes, tube(hi).n_nodes
    return (lo, m_lo) if m_lo - target < target - m_hi else (hi, m_hi)


def capsule():
    """The level-2 capsule at the origin: its 258 nodes, and its 128×7 rule points with strengths."""
    import numpy as np

    from capsim.numerics import rigid_surface
    from capsim.numerics.mesh import unit_sphere_mesh

    m = unit_sphere_mesh("octahedron", 2)
    q = np.random.default_rng(1).standard_normal(m.positions.shape)
    points, strengths = rigid_surface.point_strengths_of(m.positions, m.elements, q)
    return np.ascontiguousarray(m.positions), np.ascontiguousarray(points), np.ascontiguousarray(strengths)


class _Timed:
    """WallOperator.__init__ with its assembly and factorisation timed (the module attributes it
    calls wrapped for the duration); `before_lu(W)` sees the assembled matrix (rank-one term
    included) before the factorisation overwrites it."""

    def __init__(self, before_lu=None):
        self.before_lu, self.times = before_lu, {}

    def build(self, mesh):
        import scipy.linalg

        from capsim.numerics import rigid_surface
        from capsim.scene.conduit import WallOperator

        assemble, factor = rigid_surface.single_layer_matrix, scipy.linalg.lu_factor

        def timed_assemble(*a, **k):
            t0 = time.perf_counter()
            out = assemble(*a, **k)
            self.times["assembly_s"] = time.perf_counter() - t0
            return out

        def timed_factor(a, **k):
            if self.before_lu is not None:
                self.before_lu(a.T)  # WallOperator factorises the transpose view of W
            t0 = time.perf_counter()
            out = factor(a, **k)
            self.times["lu_s"] = time.perf_counter() - t0
            return out

        rigid_surface.single_layer_matrix, scipy.linalg.lu_factor = timed_assemble, timed_factor
        try:
            t0 = time.perf_counter()
            op = WallOperator(mesh)
            total = time.perf_counter() - t0
        finally:
            rigid_surface.single_layer_matrix, scipy.linalg.lu_factor = assemble, factor
        gmres_s = self.times.get("gmres_s", 0.0)
        self.times["operator_s"] = total - gmres_s
        self.times["other_s"] = self.times["operator_s"] - self.times["assembly_s"] - self.times["lu_s"]
        return op


def point_force_rhs(nodes):
    import numpy as np

    from capsim.numerics.kernels import stokeslet_sum

    return stokeslet_sum(nodes, np.array([FORCE_AT]), np.array([[1.0, 0.0, 0.0]])).reshape(-1)


def gmres_probe(store: dict):
    """The GMRES solve of W q = b on the dense matrix (before the LU overwrites it)."""
    import numpy as np
    import scipy.sparse.linalg as spla

    def probe(W):
        b = store["rhs"]
        count = [0]
        t0 = time.perf_counter()
        q, info = spla.gmres(W, b, rtol=GMRES_RTOL, restart=GMRES_RESTART, maxiter=20,
                             callback=lambda _: count.__setitem__(0, count[0] + 1), callback_type="pr_norm")
        store.update(gmres_s=time.perf_counter() - t0, gmres_iterations=count[0], gmres_info=int(info),
                     gmres_residual=float(np.linalg.norm(W @ q - b) / np.linalg.norm(b)), gmres_q=q)
    return probe


def wall_costs(rounds: int, build_rounds: int) -> dict:
    import numba
    import numpy as np

    from capsim.numerics import rigid_surface
    from capsim.numerics.kernels import stokeslet_sum

    numba.set_num_threads(1)
    targets, cap_points, cap_strengths = capsule()
    sizes = {t: size_for(t) for t in TARGETS}
    # warm-up: every kernel compiled (or loaded from numba's cache) on a coarse tube
    warm = _Timed().build(tube(1.5))
    q = warm.density(point_force_rhs(warm.positions))
    rigid_surface.single_layer_at(targets, warm.positions, warm.elements, q)
    stokeslet_sum(np.ascontiguousarray(warm.positions), cap_points, cap_strengths)
    del warm

    rows, ops = {}, {}
    for target, (h, m) in sizes.items():  # builds: smaller sizes repeated, the largest built once
        mesh = tube(h)
        n_builds = build_rounds if m <= 5000 else 1
        builds = []
        for k in range(n_builds):
            store = {"rhs": point_force_rhs(np.ascontiguousarray(mesh.positions))}
            timed = _Timed(gmres_probe(store) if k == n_builds - 1 else None)
            timed.times = store
            op = timed.build(mesh)
            builds.append({key: store[key] for key in ("assembly_s", "lu_s", "other_s", "operator_s")})
        q_lu = op.density(store["rhs"])
        rows[target] = {
            "element_size": h, "nodes": int(m), "elements": int(mesh.n_elements), "builds": n_builds,
            "matrix_gb": op.matrix_bytes / 1e9,
            **{key: float(np.median([b[key] for b in builds])) for key in builds[0]},
            "build_rounds_s": builds,
            "gmres_iterations": store["gmres_iterations"], "gmres_info": store["gmres_info"],
            "gmres_s": store["gmres_s"], "gmres_residual": store["gmres_residual"],
            "gmres_vs_lu": float(np.linalg.norm(store["gmres_q"] - q_lu.reshape(-1)) / np.linalg.norm(q_lu)),
            "wall_points": int(7 * mesh.n_elements)}
        pts, strengths = rigid_surface.point_strengths_of(op.positions, op.elements, q_lu)
        ops[target] = (op, store["rhs"], q_lu, np.ascontiguousarray(op.positions), pts, strengths)
        print(f"  M = {m}: assembly {rows[target]['assembly_s']:.1f} s, LU {rows[target]['lu_s']:.1f} s, "
              f"GMRES {store['gmres_iterations']} iterations", file=sys.stderr, flush=True)

    ops_timed = ("back_solve", "wall_to_capsule", "capsule_to_wall", "matrix_free")
    times = {t: {k: [] for k in ops_timed} for t in sizes}
    for _ in range(rounds):
        for target, (op, rhs, q, nodes, pts, strengths) in ops.items():
            for key, call in (("back_solve", lambda: op.density(rhs)),
                              ("wall_to_capsule", lambda: rigid_surface.single_layer_at(targets, op.positions,
                                                                                         op.elements, q)),
                              ("capsule_to_wall", lambda: stokeslet_sum(nodes, cap_points, cap_strengths)),
                              ("matrix_free", lambda: stokeslet_sum(nodes, pts, strengths))):
                t0 = time.perf_counter()
                call()
                times[target][key].append(1e3 * (time.perf_counter() - t0))
    for target, row in rows.items():
        for key in ops_timed:
            row[f"{key}_ms"] = float(np.median(times[target][key]))
            row[f"{key}_rounds_ms"] = times[target][key]
        row["iterative_ms"] = row["gmres_iterations"] * row["matrix_free_ms"]
    ops.clear()
    h16, m16 = size_for(NOT_RUN)
    return {"sizes": {str(t): r for t, r in rows.items()},
            "not_run": {"target": NOT_RUN, "element_size": h16, "nodes": int(m16), "matrix_gb": (3 * m16) ** 2 * 8 / 1e9},
            "capsule_nodes": int(targets.shape[0]), "capsule_points": int(cap_points.shape[0])}


# ------------------------------------------------------------------------ 2. whole runs

def run_worker(level: int, t_end: float, path: str) -> None:
    """In a subprocess: the wall's operator built and timed, then the run; prints JSON."""
    import resource

    from capsim.numerics.threads import apply_policy

    policy = apply_policy()
    t_start = time.perf_counter()
    sys.path.insert(0, str(Path(__file__).parent))
    from _common import run_or_stop

    from capsim.config import load_case_with
    from capsim.scene.conduit import RigidConduit, _wall_operator

    case = load_case_with(CONFIG, [f"mesh.level={level}", f"time.t_end={t_end}", f"output.path={path}"])
    t0 = time.perf_counter()
    op = RigidConduit.from_case(case).wall_operator()
    wall_s = time.perf_counter() - t0
    t0 = time.perf_counter()
    result = run_or_stop(case)
    run_s = time.perf_counter() - t0
    import numba

    out = {"level": level, "t_end": t_end, "status": result.status, "t": result.t, "steps": result.steps,
           "scheme": result.scheme, "rtol": result.rtol, "velocity_evaluations": result.velocity_evaluations,
           "layer_applications": result.layer_applications, "wall_nodes": int(op.n_nodes),
           "wall_matrix_gb": op.matrix_bytes / 1e9, "back_solves": int(op.solves),
           "operator_cache_hits": _wall_operator.cache_info().hits,
           "wall_operator_s": wall_s, "run_case_s": run_s, "run_wall_time_s": result.wall_time_s,
           "process_s": time.perf_counter() - t_start,
           "peak_rss_gb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024 / 1e9,
           "vm_hwm_gb": vm_hwm_gb(),
           "numba_threads": int(numba.get_num_threads()), "policy_threads": policy.num_threads,
           **travelled(path)}
    print(json.dumps(out, default=float))


def vm_hwm_gb() -> float | None:
    """This process image's peak resident size (/proc/self/status VmHWM; a check on ru_maxrss)."""
    try:
        for line in Path("/proc/self/status").read_text().splitlines():
            if line.startswith("VmHWM:"):
                return int(line.split()[1]) * 1024 / 1e9
    except OSError:
        pass
    return None


def travelled(path: str) -> dict:
    """The capsule's distance along the axis (units of a) and its last axial speed (units of U)."""
    import h5py

    with h5py.File(path, "r") as f:
        x, u = f["timeseries/centroid_x"][()], f["timeseries/centroid_velocity_x"][()]
    return {"distance": float(x[-1] - x[0]), "speed_end": float(u[-1])}


def whole_runs(levels, blas_threads: str | None) -> dict:
    out = {}
    with tempfile.TemporaryDirectory() as tmp:
        for level, t_end in RUNS:
            if level not in levels:
                continue
            print(f"run: level {level}, t_end {t_end} ...", file=sys.stderr, flush=True)
            env = {**os.environ, "PYTHONPATH": str(ROOT)}
            env.pop(BLAS_THREADS, None)
            if blas_threads is not None:
                env[BLAS_THREADS] = blas_threads
            proc = subprocess.run([sys.executable, __file__, "--run-worker", str(level), str(t_end),
                                   f"{tmp}/tube-level{level}.h5"], env=env, capture_output=True, text=True)
            if proc.returncode != 0:
                raise SystemExit(f"the level-{level} run failed:\n{proc.stderr[-3000:]}")
            out[str(level)] = json.loads(proc.stdout.strip().splitlines()[-1])
    return out


# ------------------------------------------------------------------------ the tables

def table(result: dict) -> str:
    w = result["wall"]
    rows = list(w["sizes"].values())
    lines = [
        f"The wall of a tube (radius 2 a, a/R = 0.5, 8.6 a long, round caps; one element size along it) against its "
        f"nodes M (`make bench-conduits`, {result['created'][:10]}, {result['cores']} cores shared with other work; "
        f"numba and BLAS one thread each). Assembly and LU: medians of {result['build_rounds']} builds "
        f"(one above 5000 nodes); the rest medians of {result['rounds']} interleaved rounds, numba's compilation excluded. "
        f"Wall→capsule: `single_layer_at` at the {w['capsule_nodes']} nodes of a level-2 capsule at the origin; "
        f"capsule→wall: `stokeslet_sum` from its {w['capsule_points']} rule points to the M nodes.",
        "",
        "| M (nodes) | element size (a) | matrix (GB) | assembly (s) | LU (s) | back-solve (ms) | wall→capsule (ms) | "
        "capsule→wall (ms) |",
        "|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for r in rows:
        lines.append(f"| {r['nodes']} | {r['element_size']:.3f} | {r['matrix_gb']:.2f} | {r['assembly_s']:.1f} | "
                     f"{r['lu_s']:.1f} | {r['back_solve_ms']:.2f} | {r['wall_to_capsule_ms']:.2f} | "
                     f"{r['capsule_to_wall_ms']:.2f} |")
    nr = w["not_run"]
    lines += [
        f"| {nr['nodes']} | {nr['element_size']:.3f} | {nr['matrix_gb']:.1f} | not run | not run | — | — | — |",
        "",
        f"M = {nr['nodes']} (≈ 16k) was not run: its dense matrix alone, (3M)² × 8 B = {nr['matrix_gb']:.1f} GB, "
        f"would take most of this machine's {result['memory_gb']:.1f} GB, which other work shares. The wall→capsule "
        "sum grows slowly with M: the coarse elements within 3 element sizes of a capsule node are integrated on "
        "subdivided rules (the gap is 1 a), the fine ones of 8k by the regular rule alone.",
        "",
        "The iterative alternative to the back-solve: one matrix-free application of W as the dense Stokeslet sum from "
        "every wall rule point (7 per element) to every wall node (`stokeslet_sum`; a lower bound, without the "
        f"singular corrections), and the GMRES iterations on the dense matrix (rtol {GMRES_RTOL:g}, restart "
        f"{GMRES_RESTART}, never reached) for the wall velocity of a unit point force along x at {FORCE_AT}; "
        "iterative = iterations × application.",
        "",
        "| M (nodes) | wall points | application (ms) | GMRES iterations | iterative (ms) | back-solve (ms) | "
        "iterative / back-solve | ‖q_GMRES − q_LU‖ / ‖q_LU‖ |",
        "|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for r in rows:
        lines.append(f"| {r['nodes']} | {r['wall_points']} | {r['matrix_free_ms']:.1f} | {r['gmres_iterations']} | "
                     f"{r['iterative_ms']:.0f} | {r['back_solve_ms']:.2f} | "
                     f"{r['iterative_ms'] / r['back_solve_ms']:.0f}× | {r['gmres_vs_lu']:.1e} |")
    runs = result.get("runs") or {}
    lines += ["", "Whole runs of configs/tube.yaml (Ca = G = 0.1, neo-Hookean, λ = 1, rtol and scheme auto), t_end "
              "6.0 (the capsule travels about 10 radii at 1.70 U), each in its own process (peak memory: its "
              "`ru_maxrss`), the thread policy's threads; the one-time wall work (mesh, assembly, LU) timed before the "
              "run, which then finds the operator built; the run's time is its set-up without the wall and the time "
              "loop; threads: numba's (BLAS as OpenBLAS finds it).", "",
              "| level | distance (a) | speed at the end (U) | wall nodes | velocity evaluations | back-solves | one-time wall work (s) | run (s) | "
              "total (s) | wall work share | run per evaluation (ms) | peak memory (GB) | threads |",
              "|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|"]
    for level in ("2", "3"):
        r = runs.get(level)
        if r is None:
            lines.append(f"| {level} | not run | | | | | | | | | | | |")
            continue
        total = r["wall_operator_s"] + r["run_case_s"]
        lines.append(f"| {level} | {r['distance']:.2f} | {r['speed_end']:.3f} | {r['wall_nodes']} | {r['velocity_evaluations']} | {r['back_solves']} | "
                     f"{r['wall_operator_s']:.1f} | {r['run_case_s']:.1f} | {total:.1f} | "
                     f"{100 * r['wall_operator_s'] / total:.0f} % | "
                     f"{1e3 * r['run_case_s'] / r['velocity_evaluations']:.0f} | {r['peak_rss_gb']:.2f} | "
                     f"{r['numba_threads']} |")
    if runs.get("3", {}).get("carried_over"):
        lines += ["", f"(level 3 kept from the run of {runs['3']['measured'][:10]}: this one was given --skip-level3.)"]
    return "\n".join(lines) + "\n"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--rounds", type=int, default=5)
    ap.add_argument("--build-rounds", type=int, default=3, help="builds (assembly, LU) per size up to 4k nodes")
    ap.add_argument("--skip-level3", action="store_true", help="leave out the level-3 run (1.5 min here)")
    ap.add_argument("--skip-runs", action="store_true", help=argparse.SUPPRESS)
    ap.add_argument("--run-worker", nargs=3, help=argparse.SUPPRESS)
    ap.add_argument("--out", default=str(OUT))
    ap.add_argument("--replot", action="store_true", help="rewrite the .md from the .json")
    args = ap.parse_args()
    if args.run_worker:
        run_worker(int(args.run_worker[0]), float(args.run_worker[1]), args.run_worker[2])
        return
    from capsim.numerics.threads import apply_policy

    apply_policy()
    # BLAS on one thread too, before numpy loads it; the runs' subprocesses get the caller's setting.
    # (scipy's OpenBLAS 0.3.31 getrf on 2 threads segfaults on a matrix over 4 GB, M ≈ 7.7k and above.)
    user_blas = os.environ.get(BLAS_THREADS)
    os.environ.setdefault(BLAS_THREADS, "1")
    out = Path(args.out)
    if args.replot:
        result = json.loads(out.with_suffix(".json").read_text())
    else:
        import numba
        import numpy as np
        import scipy

        result = {"created": datetime.now(timezone.utc).isoformat(timespec="seconds"), "rounds": args.rounds,
                  "build_rounds": args.build_rounds, "machine": platform.platform(), "processor": platform.processor(),
                  "python": sys.version.split()[0], "numpy": np.__version__, "scipy": scipy.__version__,
                  "numba": numba.__version__, "cores": os.cpu_count(),
                  "memory_gb": os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES") / 1e9,
                  "load_average_start": list(os.getloadavg()), "blas_threads": os.environ[BLAS_THREADS],
                  "blas_threads_runs": user_blas or "OpenBLAS's default (every core)"}
        # the runs first: a child forked from a parent that holds the 8k matrix would inherit its
        # resident size as the start of its own ru_maxrss
        levels = () if args.skip_runs else (2,) if args.skip_level3 else (2, 3)
        result["runs"] = whole_runs(levels, user_blas)
        print("the wall against M ...", file=sys.stderr, flush=True)
        result["wall"] = wall_costs(args.rounds, args.build_rounds)
        old = out.with_suffix(".json")
        if 3 not in levels and old.exists() and "3" in (json.loads(old.read_text()).get("runs") or {}):
            previous = json.loads(old.read_text())
            result["runs"]["3"] = {**previous["runs"]["3"], "carried_over": True,
                                   "measured": previous["runs"]["3"].get("measured", previous["created"])}
        for r in result["runs"].values():
            r.setdefault("measured", result["created"])
        result["load_average_end"] = list(os.getloadavg())
        out.with_suffix(".json").write_text(json.dumps(result, indent=1))
    text = table(result)
    out.with_suffix(".md").write_text(text)
    print(text)


if __name__ == "__main__":
    main()

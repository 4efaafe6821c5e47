"""The cost of one velocity evaluation against the number of capsules (issue 43, "Cost,
measured"): `make bench-capsules`.

1. One evaluation, ``model.velocity(x)`` (the membrane and the single layer; λ = 1, one numba
   thread) at level 2 with 1, 2, 4, 8 and 16 capsules on a lattice 4 a apart (a gap of 2 a: no
   near-field correction between capsules; a row along x, 2×2 in the shear plane, 2×2×2 and
   4×2×2 across it, all centred on the origin so that the whole scene keeps the quarter
   group), and at level 3 one capsule at the origin against the pair ±(4, 0.25, 0)·a, each with
   ``mesh.symmetry: auto`` (both the quarter) and with none. Medians over ``--rounds`` rounds of
   each round's median of ``--evals`` evaluations, the cases interleaved within a round (the
   machine is shared), after a warm-up evaluation (numba's compilation excluded). Counted beside
   the times: target nodes, source points (the regular rule's points of every element) and the
   Stokeslet pairs of the dense sum, targets × points. The issue's criterion: two capsules at
   level 3 at most 4.5× one capsule with the same symmetry group.
2. The dense Stokeslet sum (``capsim.numerics.kernels.stokeslet_sum``) against fmm3dpy's Stokes FMM
   (``stfmm3d``) at eps 1e-6 and 1e-9, one thread each, at the sizes of the cases above (and
   32 and 64 capsules at level 2, the sum alone): the same targets, points and strengths (those
   of one evaluation), timed in one process in alternating order, the FMM's error against the
   dense sum. fmm3dpy is no dependency of capsim: it runs in a throwaway virtual environment
   given by ``--fmm-python`` (or ``FMM_PYTHON=...`` for make), which imports this checkout's
   ``capsim.numerics.kernels`` by path (it needs numba and numpy there)::

       python3 -m venv /tmp/fmmvenv && /tmp/fmmvenv/bin/pip install fmm3dpy numpy numba scipy
       make bench-capsules FMM_PYTHON=/tmp/fmmvenv/bin/python

   Without it the FMM numbers of the previous benchmarks/capsules.json are kept (and said to be).
3. Threads: the 4-, 8- and 16-capsule scenes at level 2 and both level-3 scenes with 1 and 2
   numba threads, interleaved, beside what ``capsim.numerics.threads.threads_for_work`` gives a run.

Writes benchmarks/capsules.md (the tables the docs include) and benchmarks/capsules.json.

    PYTHONPATH=. python benchmarks/capsules.py [--rounds 7] [--evals 10] [--fmm-python PATH]
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import sys
import tempfile
import time
from datetime import datetime, timezone
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
OUT = ROOT / "benchmarks" / "capsules"

#: centre to centre on the lattices (units of a): a gap of 2 a, beyond the reach of the
#: near-field correction between capsules (capsule_near_field_factor × an element's size)
SPACING = 4.0
#: the level-3 pair (issue 43): point-symmetric about the origin in the shear plane
PAIR_L3 = (4.0, 0.25, 0.0)
#: the deformed shape every capsule takes about its own centre (as benchmarks/scenes.py's)
STRETCH = (1.1, 0.93, 0.98)
#: the FMM's requested precisions
EPS = (1e-6, 1e-9)


def lattice(counts: tuple[int, int, int]) -> list[tuple[float, float, float]]:
    """counts[k] centres along axis k, SPACING apart, centred on the origin."""
    axes = [[SPACING * (i - (n - 1) / 2) for i in range(n)] for n in counts]
    return [(x, y, z) for x in axes[0] for y in axes[1] for z in axes[2]]


#: level 2: capsules -> (placement in words, lattice counts along x, y, z)
LEVEL2 = {
    1: ("at the origin", (1, 1, 1)),
    2: ("a row along x", (2, 1, 1)),
    4: ("2×2 in the shear plane (x–y)", (2, 2, 1)),
    8: ("2×2×2 (across the shear plane)", (2, 2, 2)),
    16: ("4×2×2", (4, 2, 2)),
}
#: more capsules for the Stokeslet sum against the FMM alone (no evaluation timed)
LEVEL2_SUM_ONLY = {32: ("4×4×2", (4, 4, 2)), 64: ("4×4×4", (4, 4, 4))}

#: placements and the group `mesh.symmetry: auto` finds for them (built, not timed)
PLACEMENTS = {
    "one capsule at the origin": [(0.0, 0.0, 0.0)],
    "any lattice above (centred on the origin)": lattice((2, 2, 2)),
    "pair ±(4, 0.25, 0)": [PAIR_L3, tuple(-c for c in PAIR_L3)],
    "pair ±(2, 0, 2): off the shear plane, point-symmetric": [(2.0, 0.0, 2.0), (-2.0, 0.0, -2.0)],
    "pair (0, 0, ±2): on the z axis": [(0.0, 0.0, 2.0), (0.0, 0.0, -2.0)],
    "pair (0, 0, 0) and (4, 0, 0): not centred": [(0.0, 0.0, 0.0), (4.0, 0.0, 0.0)],
    "pair (0, 0, 0) and (3, 3, 3)": [(0.0, 0.0, 0.0), (3.0, 3.0, 3.0)],
}


def cases() -> dict[str, dict]:
    """name -> level, centres, mesh.symmetry, placement in words, the one-capsule case it is
    compared with (same level and symmetry setting)."""
    out = {}
    for n, (words, counts) in LEVEL2.items():
        out[f"level 2, {n}"] = {"level": 2, "centers": lattice(counts), "symmetry": "auto", "placement": words,
                                "capsules": n, "base": "level 2, 1"}
    pair = [PAIR_L3, tuple(-c for c in PAIR_L3)]
    for sym in ("auto", "none"):
        suffix = "" if sym == "auto" else ", none"
        out[f"level 3, 1{suffix}"] = {"level": 3, "centers": [(0.0, 0.0, 0.0)], "symmetry": sym,
                                      "placement": "at the origin", "capsules": 1, "base": f"level 3, 1{suffix}"}
        out[f"level 3, 2{suffix}"] = {"level": 3, "centers": pair, "symmetry": sym, "placement": "±(4, 0.25, 0)",
                                      "capsules": 2, "base": f"level 3, 1{suffix}"}
    return out


def build(level: int, centers, symmetry: str = "auto"):
    """(model, deformed configuration): every capsule stretched by STRETCH about its centre
    (a map that keeps every symmetry the placement has)."""
    import numpy as np

    from capsim.config import case_from_dict
    from capsim.solve.solver import build_model

    d = {"name": "capsules", "mesh": {"level": level, "symmetry": symmetry}, "flow": {"shear_rate_G": 0.1}}
    if len(centers) > 1 or any(centers[0]):
        d["capsules"] = [{"center": list(c)} for c in centers]
    model, X = build_model(case_from_dict(d))
    x = X.copy()
    for i, c in enumerate(centers):
        idx = model.bodies.nodes(i)
        x[idx] = np.asarray(c) + (X[idx] - np.asarray(c)) * np.asarray(STRETCH)
    return model, x


def sum_arrays(model, x):
    """The dense sum's targets, points and strengths in an evaluation at x (as
    Discretization.single_layer forms them)."""
    import numpy as np

    from capsim.numerics import kernels

    state = model.membrane(x)
    geo, disc = state.geometry, model.disc
    weights = geo.weights if state.measure is None else state.measure.reg_weights
    density = state.density
    if density.ndim == 2:
        strengths = (np.repeat(density[:, None, :], weights.shape[1], axis=1) * weights[..., None]).reshape(-1, 3)
    else:
        _, strengths = kernels.point_strengths(disc.reg_phi, np.ascontiguousarray(density), weights)
    return (np.ascontiguousarray(x[disc.targets]), np.ascontiguousarray(geo.points.reshape(-1, 3)),
            np.ascontiguousarray(strengths), np.ascontiguousarray(x))


def counts(model, x) -> dict:
    geo = model.disc.geometry(x)
    near = model.disc.near_pairs(x, geo)
    targets, points = len(model.disc.targets), int(geo.points.reshape(-1, 3).shape[0])
    return {"symmetry": model.disc.symmetry, "nodes": int(model.disc.n_nodes), "targets": int(targets),
            "points": points, "pairs": int(targets) * points,
            "near_pairs_between_capsules": 0 if near is None else int(len(near[1]))}


def time_evaluations(models: dict, rounds: int, evals: int, threads: dict[str, int]) -> dict[str, list[float]]:
    """Per (key -> threads) the median ms of `evals` evaluations in each round; keys interleaved."""
    import numba
    import numpy as np

    times: dict[str, list[float]] = {k: [] for k in threads}
    for _ in range(rounds):
        for key, n in threads.items():
            model, x = models[key.split(" @")[0]]
            numba.set_num_threads(n)
            one = []
            for _ in range(evals):
                t0 = time.perf_counter()
                model.velocity(x)
                one.append(time.perf_counter() - t0)
            times[key].append(1e3 * float(np.median(one)))
    numba.set_num_threads(1)
    return times


def evaluation_costs(rounds: int, evals: int) -> tuple[dict, dict]:
    import numba
    import numpy as np

    from capsim.numerics.threads import threads_for_work

    start_load = list(os.getloadavg())
    spec = cases()
    models = {name: build(c["level"], c["centers"], c["symmetry"]) for name, c in spec.items()}
    numba.set_num_threads(1)
    for model, x in models.values():  # compile and warm
        model.velocity(x)
    times = time_evaluations(models, rounds, evals, {name: 1 for name in models})
    out = {}
    for name, c in spec.items():
        model, x = models[name]
        out[name] = {**{k: c[k] for k in ("level", "capsules", "placement", "base")},
                     "centers": [list(p) for p in c["centers"]], "symmetry_setting": c["symmetry"],
                     **counts(model, x), "ms": float(np.median(times[name])), "ms_rounds": times[name]}
    for row in out.values():
        base = out[row["base"]]
        row["ratio"] = row["ms"] / base["ms"]
        row["pairs_ratio"] = row["pairs"] / base["pairs"]
    # threads: the larger scenes with 1 and 2 threads, interleaved
    available = numba.config.NUMBA_NUM_THREADS
    thread_cases = [k for k in ("level 2, 4", "level 2, 8", "level 2, 16", "level 3, 1", "level 3, 2") if k in models]
    counts_to_try = sorted({1, min(2, available)})
    keys = {f"{k} @{n}": n for k in thread_cases for n in counts_to_try}
    for key, n in keys.items():  # warm each thread count's pool
        numba.set_num_threads(n)
        models[key.split(" @")[0]][0].velocity(models[key.split(" @")[0]][1])
    ttimes = time_evaluations(models, rounds, evals, keys)
    threads = {"available": int(available), "load_average_start": start_load, "load_average": list(os.getloadavg()),
               "cases": {}}
    for k in thread_cases:
        row = {str(n): float(np.median(ttimes[f"{k} @{n}"])) for n in counts_to_try}
        threads["cases"][k] = {"nodes": out[k]["nodes"], "targets": out[k]["targets"], "ms": row,
                               "ms_rounds": {str(n): ttimes[f"{k} @{n}"] for n in counts_to_try},
                               "policy_threads": threads_for_work(out[k]["nodes"], available)}
    return out, threads


def placements() -> dict[str, str]:
    return {words: build(2, centers)[0].disc.symmetry for words, centers in PLACEMENTS.items()}


# ------------------------------------------------------------------------ the FMM (another venv)

def fmm_worker(path: str, rounds: int) -> None:
    """In the FMM's environment: per size the dense sum and stfmm3d at each eps, one thread,
    alternating within a round; prints JSON."""
    sys.path.insert(0, str(ROOT))
    import fmm3dpy
    import numba
    import numpy as np

    from capsim.numerics.kernels import stokeslet_sum

    numba.set_num_threads(1)
    data = np.load(path)
    names = sorted({k.rsplit("/", 1)[0] for k in data.files})

    def fmm(targets, points, strengths, eps):
        o = fmm3dpy.stfmm3d(eps=eps, sources=np.ascontiguousarray(points.T), stoklet=np.ascontiguousarray(strengths.T),
                            targets=np.ascontiguousarray(targets.T), ifppreg=0, ifppregtarg=1)
        return 8.0 * np.pi * o.pottarg.reshape(3, -1).T  # fmm3d's Stokeslet is capsim's / (8π)

    out = {"fmm3dpy": getattr(fmm3dpy, "__version__", "?"), "numba": numba.__version__, "numpy": np.__version__,
           "omp_num_threads": os.environ.get("OMP_NUM_THREADS"), "sizes": {}}
    libs = Path(fmm3dpy.__file__).resolve().parents[1] / "fmm3dpy.libs"  # the wheel's bundled libraries
    out["openmp"] = any("gomp" in f.name for f in libs.iterdir()) if libs.is_dir() else None
    for name in names:
        points, strengths = data[f"{name}/points"], data[f"{name}/strengths"]
        for which in ("targets", "nodes"):
            targets = data[f"{name}/{which}"]
            dense = stokeslet_sum(targets, points, strengths)
            row = {"targets": int(targets.shape[0]), "points": int(points.shape[0]), "error": {}}
            for eps in EPS:
                u = fmm(targets, points, strengths, eps)
                row["error"][str(eps)] = float(np.linalg.norm(u - dense) / np.linalg.norm(dense))
            t = {"dense": [], **{str(eps): [] for eps in EPS}}
            for r in range(rounds):
                order = ["dense", *map(str, EPS)]
                for key in (order if r % 2 == 0 else order[::-1]):
                    t0 = time.perf_counter()
                    if key == "dense":
                        stokeslet_sum(targets, points, strengths)
                    else:
                        fmm(targets, points, strengths, float(key))
                    t[key].append(1e3 * (time.perf_counter() - t0))
            row["ms"] = {k: float(np.median(v)) for k, v in t.items()}
            out["sizes"][f"{name}/{which}"] = row
            print(f"  {name} {which}: " + ", ".join(f"{k} {v:.2f} ms" for k, v in row["ms"].items()), file=sys.stderr,
                  flush=True)
    print(json.dumps(out))


def fmm_costs(python: str, rounds: int) -> dict:
    import numpy as np

    sizes = {f"level 2, {n}": (2, lattice(c)) for n, (_, c) in {**LEVEL2, **LEVEL2_SUM_ONLY}.items()}
    sizes["level 3, 1"] = (3, [(0.0, 0.0, 0.0)])
    sizes["level 3, 2"] = (3, [PAIR_L3, tuple(-c for c in PAIR_L3)])
    arrays = {}
    for name, (level, centers) in sizes.items():
        model, x = build(level, centers)
        targets, points, strengths, nodes = sum_arrays(model, x)
        arrays.update({f"{name}/targets": targets, f"{name}/points": points, f"{name}/strengths": strengths,
                       f"{name}/nodes": nodes})
    with tempfile.TemporaryDirectory() as tmp:
        path = f"{tmp}/sums.npz"
        np.savez(path, **arrays)
        env = {**os.environ, "NUMBA_NUM_THREADS": "1", "OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1",
               "PYTHONPATH": ""}
        proc = subprocess.run([python, __file__, "--fmm-worker", path, "--rounds", str(rounds)], env=env,
                              cwd=tmp, capture_output=True, text=True)
    if proc.returncode != 0:
        raise SystemExit(f"the FMM worker ({python}) failed:\n{proc.stderr[-3000:]}")
    result = json.loads(proc.stdout.strip().splitlines()[-1])
    result["python"] = python
    result["rounds"] = rounds
    result["measured"] = datetime.now(timezone.utc).isoformat(timespec="seconds")
    for key, row in result["sizes"].items():
        row["capsules"] = int(key.split(", ")[1].split("/")[0])
        row["level"] = int(key.split(",")[0].split()[1])
    return result


def crossover(fmm: dict, level: int, which: str, eps: float) -> str:
    rows = sorted(((r["capsules"], r) for k, r in fmm["sizes"].items()
                   if r["level"] == level and k.endswith("/" + which)), key=lambda nr: nr[0])
    for n, r in rows:
        if r["ms"][str(eps)] < r["ms"]["dense"]:
            return f"{n} capsules"
    if not rows:
        return "not measured"
    n, r = rows[-1]
    if n < 16:  # too few sizes to extrapolate: the FMM's fixed cost still dominates
        return f"none at {' and '.join(str(m) for m, _ in rows)} capsules"
    # beyond: the dense sum grows as N², the FMM as N (as measured from 16 to 64 capsules at level 2)
    return f"none up to {n} capsules (≈ {n * r['ms'][str(eps)] / r['ms']['dense']:.0f} extrapolated)"


# ------------------------------------------------------------------------ the table

def table(result: dict) -> str:
    from capsim.scene import MAX_CAPSULES, MAX_SCENE_NODES

    ev = result["evaluation"]
    lines = [
        f"One velocity evaluation (`model.velocity(x)`: membrane and single layer, λ = 1, one numba thread; "
        f"each capsule stretched by {STRETCH} about its centre) against the number of capsules: medians of "
        f"{result['rounds']} interleaved rounds of each round's median of {result['evals']} evaluations "
        f"(`make bench-capsules`, {result['created'][:10]}, 2 cores shared with other work). Level-2 lattices are "
        f"{SPACING:g} a apart (a gap of {SPACING - 2:g} a: no near-field correction between capsules); pairs = "
        "target nodes × source points of the dense Stokeslet sum.",
        "",
        "| case | placement | symmetry | target nodes of nodes | source points | pairs (M) | ms per evaluation | "
        "× one capsule, same group | pairs × one capsule |",
        "|---|---|---|---:|---:|---:|---:|---:|---:|",
    ]
    for name, r in ev.items():
        lines.append(f"| {name} | {r['placement']} | {r['symmetry']} | {r['targets']} of {r['nodes']} | "
                     f"{r['points']} | {r['pairs'] / 1e6:.2f} | {r['ms']:.2f} | {r['ratio']:.2f}× | "
                     f"{r['pairs_ratio']:.2f}× |")
    pair, none = ev["level 3, 2"], ev["level 3, 2, none"]
    holds = pair["ratio"] <= 4.5
    lines += [
        "",
        f"**Criterion (two capsules at level 3 at most 4.5× one capsule with the same symmetry group): "
        f"{'holds' if holds else 'fails'}**: {pair['ratio']:.2f}× with the quarter group "
        f"({pair['symmetry']} for both: {pair['targets']} against {ev['level 3, 1']['targets']} targets), "
        f"{4.5 / pair['ratio']:.2f}× under the bound, the pair interactions {pair['pairs_ratio']:.2f}×; "
        f"without symmetry {none['ratio']:.2f}× (pairs {none['pairs_ratio']:.2f}×).",
        "",
        "The group `mesh.symmetry: auto` finds for a placement (level 2, simple shear):",
        "",
        "| placement | group |",
        "|---|---|",
    ]
    lines += [f"| {words} | {group} |" for words, group in result["placements"].items()]
    th = result["threads"]
    lines += [
        "",
        f"Threads ({result['rounds']} rounds, 1 and 2 numba threads interleaved; the 1-minute load average "
        f"{th['load_average_start'][0]:.1f} before the evaluations and {th['load_average'][0]:.1f} after, on "
        f"{result['cores']} cores): what `capsim.numerics.threads.threads_for_work` gives a run "
        "(by the full mesh's nodes, 2000 and more: every core).",
        "",
        "| case | nodes | targets | 1 thread (ms) | 2 threads (ms) | 1 / 2 threads | a run's policy |",
        "|---|---:|---:|---:|---:|---:|---:|",
    ]
    for name, r in th["cases"].items():
        one, two = r["ms"]["1"], r["ms"].get("2")
        two_text, speed = (f"{two:.2f}", f"{one / two:.2f}×") if two else ("—", "—")
        policy = f"{r['policy_threads']} thread{'s' if r['policy_threads'] > 1 else ''}"
        lines.append(f"| {name} | {r['nodes']} | {r['targets']} | {one:.2f} | {two_text} | {speed} | {policy} |")
    fmm = result.get("fmm")
    lines += ["", "The dense Stokeslet sum against fmm3dpy's Stokes FMM (`stfmm3d`), one thread each, the same "
              "targets, points and strengths (one evaluation's); **measured outside the project's environment** "
              "(fmm3dpy in a throwaway venv importing this checkout's `capsim.numerics.kernels`), the dense sum and the FMM "
              "alternating in one process. Error: ‖u_FMM − u_dense‖/‖u_dense‖ over the targets."]
    if not fmm:
        lines += ["", f"Not measured: {result.get('fmm_reason', 'no FMM environment given (--fmm-python)')}."]
        return "\n".join(lines) + "\n"
    if fmm.get("carried_over"):
        lines += ["", f"(kept from the run of {fmm['measured'][:10]}: this run had no FMM environment.)"]
    omp = {True: "with OpenMP", False: "built without OpenMP: one thread whatever OMP_NUM_THREADS", None: "?"}
    lines += ["", f"fmm3dpy {fmm['fmm3dpy']} (the PyPI wheel, {omp[fmm.get('openmp')]}), numba {fmm['numba']}, "
              f"numpy {fmm['numpy']}; medians of {fmm.get('rounds', '?')} alternating rounds.", "",
              "| scene | targets | source points | dense (ms) | FMM 1e-6 (ms) | FMM 1e-9 (ms) | FMM / dense (1e-6) | "
              "error 1e-6 | error 1e-9 |",
              "|---|---:|---:|---:|---:|---:|---:|---:|---:|"]
    order = sorted(fmm["sizes"].items(), key=lambda kv: (kv[1]["level"], not kv[0].endswith("/targets"),
                                                         kv[1]["capsules"]))
    for key, r in order:
        name, which = key.split("/")
        label = f"{name}{'' if which == 'targets' else ', every node'}"
        ms = r["ms"]
        lines.append(f"| {label} | {r['targets']} | {r['points']} | {ms['dense']:.2f} | {ms['1e-06']:.2f} | "
                     f"{ms['1e-09']:.2f} | {ms['1e-06'] / ms['dense']:.2f} | {r['error']['1e-06']:.1e} | "
                     f"{r['error']['1e-09']:.1e} |")
    lines += ["", "Crossover (the fewest capsules at which the FMM is faster than the dense sum; extrapolated from "
              "the largest size, the dense sum growing as N² and the FMM as N): "
              f"level 2 at the quarter group's targets: {crossover(fmm, 2, 'targets', 1e-6)} at eps 1e-6, "
              f"{crossover(fmm, 2, 'targets', 1e-9)} at 1e-9; at every node (no symmetry): "
              f"{crossover(fmm, 2, 'nodes', 1e-6)} at 1e-6, {crossover(fmm, 2, 'nodes', 1e-9)} at 1e-9; "
              f"level 3, quarter targets: {crossover(fmm, 3, 'targets', 1e-6)} at 1e-6, "
              f"every node: {crossover(fmm, 3, 'nodes', 1e-6)} at 1e-6. Capsim's scenes stop at "
              f"{MAX_CAPSULES} capsules and {MAX_SCENE_NODES:,} nodes ({MAX_SCENE_NODES // 258} capsules at level 2). "
              "The FMM's times are the PyPI wheel's (a generic build); one's own build (gfortran, "
              "-march=native, OpenMP) may be several times faster, which would not bring the crossover "
              "within the scenes capsim takes under the quarter group."]
    return "\n".join(lines) + "\n"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--rounds", type=int, default=7)
    ap.add_argument("--evals", type=int, default=10)
    ap.add_argument("--fmm-python", default=os.environ.get("FMM_PYTHON") or None,
                    help="a Python with fmm3dpy, numba and numpy (not the project's venv)")
    ap.add_argument("--fmm-rounds", type=int, default=3, help="alternating rounds of the dense sum and the FMM")
    ap.add_argument("--fmm-worker", help=argparse.SUPPRESS)
    ap.add_argument("--out", default=str(OUT))
    ap.add_argument("--replot", action="store_true", help="rewrite the .md from the .json")
    args = ap.parse_args()
    if args.fmm_worker:
        fmm_worker(args.fmm_worker, args.rounds)  # fmm_costs passes --fmm-rounds as --rounds
        return
    from capsim.numerics.threads import apply_policy

    apply_policy()
    out = Path(args.out)
    if args.replot:
        result = json.loads(out.with_suffix(".json").read_text())
    else:
        result = {"created": datetime.now(timezone.utc).isoformat(timespec="seconds"), "rounds": args.rounds,
                  "evals": args.evals, "machine": platform.platform(), "python": sys.version.split()[0],
                  "cores": os.cpu_count()}
        if args.fmm_python:
            print("FMM against the dense sum ...", file=sys.stderr, flush=True)
            result["fmm"] = fmm_costs(args.fmm_python, args.fmm_rounds)
        elif out.with_suffix(".json").exists() and json.loads(out.with_suffix(".json").read_text()).get("fmm"):
            result["fmm"] = {**json.loads(out.with_suffix(".json").read_text())["fmm"], "carried_over": True}
        else:
            result["fmm_reason"] = "no FMM environment given (--fmm-python)"
        print("evaluations ...", file=sys.stderr, flush=True)
        result["evaluation"], result["threads"] = evaluation_costs(args.rounds, args.evals)
        result["placements"] = placements()
        out.with_suffix(".json").write_text(json.dumps(result, indent=1))
    text = table(result)
    out.with_suffix(".md").write_text(text)
    print(text)


if __name__ == "__main__":
    main()

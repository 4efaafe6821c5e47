"""The per-stage split of one velocity evaluation, before and after (issue 29, item 3).

The case of ``capsim bench --level 3``: a sphere, λ = 1, quarter symmetry, one numba
thread, each timed evaluation a small step further along a smooth strain (so that the
warm starts work as in a run), the evaluations back to back. The same measurement
(``worker``) runs on two source trees in one invocation: this checkout ("after") and a baseline
commit exported with ``git archive`` ("before"), each in a fresh interpreter, in
alternating rounds so that load from other processes affects both alike. Per stage the
table gives the median over the rounds of each round's median, in ms per evaluation and
against the Stokeslet sum, and the work outside the sum against the sum (the item asks
for at most 0.6).

Usage::

    python benchmarks/evaluation_split.py                  # 4 rounds of 40 evaluations (a few minutes)
    python benchmarks/evaluation_split.py --rounds 1 --repeat 5 --out /tmp/split   # quick check

Writes ``<out>.md`` (the table) and ``<out>.json`` (every round), default
``benchmarks/evaluation_split.{md,json}``.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import sys
import tempfile
from datetime import datetime, timezone
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
#: the commit that added the split to `capsim bench`, before the evaluation was made cheaper
BASELINE = "b504b1217f401d289b1b4c60d0e186cab1923eaf"


def worker(level: int, repeat: int) -> None:
    """One round in the tree on sys.path: ``repeat`` evaluations back to back, as a run makes
    them (the case and path of ``capsim bench``), with this script's loop for both trees (a
    tree's own ``bench_velocity`` may interleave other work: the baseline's ran a bare
    full-size sum before every evaluation, which slows the stages after it)."""
    import time

    from capsim.runs.benchmark import _model, bench_case

    model, X = _model(bench_case(level, 1.0, "octahedron", "quarter", repeat), "quarter")
    c, s = np.cos(0.6), np.sin(0.6)
    x = X @ (np.diag([1.15, 0.88, 1.0 / (1.15 * 0.88)]) @ np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]]).T)
    model.velocity(x)  # JIT and warm starts
    noise = np.random.default_rng(0).standard_normal(x.shape)
    step = np.eye(3) + 1e-3 * np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 0.0]])
    full, splits, mass_iterations = [], [], []
    for _ in range(repeat):
        x = x @ step
        xp = x + 1e-4 * model.disc.expand(noise[model.disc.targets])
        model.reset_stage_times()
        t0 = time.perf_counter()
        model.velocity(xp)
        full.append(time.perf_counter() - t0)
        splits.append(model.split_times)
        mass_iterations.append(getattr(model.membrane, "last_mass_iterations", 0))
    split = {k: float(np.median([t.get(k, 0.0) for t in splits])) for k in splits[0]}
    outside = sum(v for k, v in split.items() if k != "stokeslet_sum") / split["stokeslet_sum"]
    print(json.dumps({
        "n_nodes": int(X.shape[0]), "n_targets": int(model.disc.targets.size), "velocity_eval_s": float(np.median(full)),
        "split_s": split, "split_total_s": float(sum(split.values())), "outside_sum_ratio": float(outside),
        "mass_iterations_median": float(np.median(mass_iterations)),
    }))


def measure(tree: Path, level: int, repeat: int) -> dict:
    env = {**os.environ, "PYTHONPATH": str(tree), "NUMBA_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1"}
    out = subprocess.run(
        [sys.executable, __file__, "--worker", "--level", str(level), "--repeat", str(repeat)],
        env=env, cwd=tree, capture_output=True, text=True, check=True,
    )
    return json.loads(out.stdout.strip().splitlines()[-1])


def export(rev: str, into: Path) -> str:
    sha = subprocess.run(["git", "rev-parse", rev], cwd=ROOT, capture_output=True, text=True, check=True).stdout.strip()
    archive = subprocess.run(["git", "archive", sha, "capsim"], cwd=ROOT, capture_output=True, check=True).stdout
    subprocess.run(["tar", "-x", "-C", str(into)], input=archive, check=True)
    return sha


def summarize(rounds: list[dict]) -> dict:
    stages = sorted({k for r in rounds for k in r["split_s"]})
    return {
        "split_ms": {k: 1e3 * float(np.median([r["split_s"].get(k, 0.0) for r in rounds])) for k in stages},
        "evaluation_ms": 1e3 * float(np.median([r["velocity_eval_s"] for r in rounds])),
        "stages_total_ms": 1e3 * float(np.median([r["split_total_s"] for r in rounds])),
        "outside_sum_ratio": float(np.median([r["outside_sum_ratio"] for r in rounds])),
        "mass_iterations": float(np.median([r["mass_iterations_median"] for r in rounds])),
    }


def table(result: dict) -> str:
    from capsim.runs.benchmark import SPLIT_STAGES

    before, after = result["before"], result["after"]
    stages = [k for k in SPLIT_STAGES if k in before["split_ms"] or k in after["split_ms"]]
    sb, sa = before["split_ms"]["stokeslet_sum"], after["split_ms"]["stokeslet_sum"]
    lines = [
        f"Level {result['level']}, λ = 1, quarter symmetry ({result['n_targets']} of {result['n_nodes']} nodes), "
        f"one thread; medians of {result['rounds']} alternating rounds of {result['repeat']} evaluations each "
        f"(`make bench-split`, {result['created'][:10]}). Before: {result['baseline'][:10]}.",
        "",
        "| stage | group | before (ms) | after (ms) | before (× sum) | after (× sum) |",
        "|---|---|---:|---:|---:|---:|",
    ]
    def cells(split: dict, k: str, total: float) -> tuple[str, str]:  # "—": the tree has no such stage
        return (f"{split[k]:.3f}", f"{split[k] / total:.2f}") if k in split else ("—", "—")

    for k in stages:
        (b, b_sum), (a, a_sum) = cells(before["split_ms"], k, sb), cells(after["split_ms"], k, sa)
        lines.append(f"| {k} | {SPLIT_STAGES[k]} | {b} | {a} | {b_sum} | {a_sum} |")
    lines += [
        f"| all stages | | {before['stages_total_ms']:.3f} | {after['stages_total_ms']:.3f} | "
        f"{before['stages_total_ms'] / sb:.2f} | {after['stages_total_ms'] / sa:.2f} |",
        f"| whole evaluation (its own median) | | {before['evaluation_ms']:.3f} | {after['evaluation_ms']:.3f} | "
        f"{before['evaluation_ms'] / sb:.2f} | {after['evaluation_ms'] / sa:.2f} |",
        "",
        f"Work outside the Stokeslet sum against the sum: **{before['outside_sum_ratio']:.2f} before, "
        f"{after['outside_sum_ratio']:.2f} after** (the other stages' medians against the sum's; the "
        f"item asks for at most 0.6). A stage's median ignores the few-ms descheduling that a shared "
        f"machine gives some evaluations; the whole evaluation's median may not. "
        f"Mass-matrix solve: {before['mass_iterations']:.0f} conjugate-gradient iterations per evaluation "
        f"before (M(x)·Δf = ∂E/∂x, assembled at every evaluation), after: one exact solve of M0·F = ∂E/∂x "
        f"by the rest shape's factor (F per unit rest area; docs/method.md, \"Numerical method\").",
    ]
    return "\n".join(lines) + "\n"


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--worker", action="store_true", help=argparse.SUPPRESS)
    p.add_argument("--level", type=int, default=3)
    p.add_argument("--repeat", type=int, default=40)
    p.add_argument("--rounds", type=int, default=4)
    p.add_argument("--baseline", default=BASELINE, help="the 'before' commit")
    p.add_argument("--out", default=str(ROOT / "benchmarks" / "evaluation_split"))
    a = p.parse_args()
    if a.worker:
        worker(a.level, a.repeat)
        return
    sys.path.insert(0, str(ROOT))  # this checkout's capsim for the table, whatever is installed
    runs: dict[str, list[dict]] = {"before": [], "after": []}
    with tempfile.TemporaryDirectory() as tmp:
        baseline = export(a.baseline, Path(tmp))
        trees = {"before": Path(tmp), "after": ROOT}
        for i in range(a.rounds):
            for label, tree in trees.items():
                runs[label].append(measure(tree, a.level, a.repeat))
                s = runs[label][-1]
                print(f"round {i + 1} {label:6}: eval {1e3 * s['velocity_eval_s']:.3f} ms, "
                      f"outside/sum {s['outside_sum_ratio']:.2f}", flush=True)
    first = runs["after"][0]
    result = {
        "level": a.level, "n_nodes": first["n_nodes"], "n_targets": first["n_targets"],
        "rounds": a.rounds, "repeat": a.repeat, "baseline": baseline,
        "created": datetime.now(timezone.utc).isoformat(timespec="seconds"),
        "machine": platform.platform(), "python": sys.version.split()[0],
        "before": summarize(runs["before"]), "after": summarize(runs["after"]), "runs": runs,
    }
    out = Path(a.out)
    out.with_suffix(".json").write_text(json.dumps(result, indent=2))
    out.with_suffix(".md").write_text(table(result))
    print(table(result))
    print(f"wrote {out}.md and {out}.json")


if __name__ == "__main__":
    main()

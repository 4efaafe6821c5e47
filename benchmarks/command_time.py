"""What a command spends around its evaluations (issue 57): the demo's command, before and after.

Two source trees in one invocation, in alternating rounds so that other processes' load affects
both alike: this checkout ("after") and a baseline commit exported with ``git archive``
("before"), each in fresh interpreters with the byte-code cache on (``PYTHONDONTWRITEBYTECODE``
unset: an installed package has its .pyc; without them every command compiles capsim's sources
again, ~0.1 s), one thread, after a warm-up round (numba's cache and the .pyc written). Per tree:

- ``command``: the whole ``capsim run configs/sphere.yaml`` (the demo) as a subprocess, wall time;
- ``validate``: the whole ``capsim validate configs/sphere.yaml``;
- ``interpreter``: ``python -c pass``; ``numba``: ``python -c "import numba"``;
- in one more fresh interpreter (``worker``): the imports of the run's modules, then ``capsim.run``
  of the same case with its parts timed by wrapping them: the velocity evaluations (``_Run._rhs``:
  the membrane's forces and the velocity, what ``capsim bench`` calls one evaluation; until
  2026-12-06 this wrapped the model's ``velocity`` alone and counted the membrane's forces, ~0.4 of
  an evaluation at level 3, outside), ``observe`` (the step's row), the run file's row writes;
  ``outside`` is the run's wall time less its evaluations; then the same run again in that process
  (``warm_*``: numba's start-up and the kernels' loading already paid, as in the issue's profile).

The table gives medians over the rounds; ``around the run`` is the command's wall time less the
worker's run wall time (the same case). Usage::

    python benchmarks/command_time.py                # 5 rounds (about 2 min)
    python benchmarks/command_time.py --rounds 2 --out /tmp/ct

Writes ``<out>.md`` and ``<out>.json``, default ``benchmarks/command_time.{md,json}``.
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

import numpy as np

from _common import ROOT, TIMED_SOURCE, export_commit, fresh_env
#: the last commit before this session's issue-57 changes (the run file's writes); the session before
#: compared with 697d7fa (the version literal, numba observables: docs/performance.md quotes it)
BASELINE = "8e7b114"
CASE = "configs/sphere.yaml"

WORKER = r"""
import json, sys, tempfile, time
t0 = time.perf_counter()
from capsim.numerics.threads import apply_policy
apply_policy(1)
import capsim
from capsim.runs import runner
from capsim.solve import observables
from capsim.storage import store
imports = time.perf_counter() - t0
""" + TIMED_SOURCE + r"""
timed(runner._Run, "_rhs", "evaluations")  # an evaluation: the membrane's forces and the velocity
timed(observables.StepObserver, "observe", "observe")
timed(store.TrajectoryWriter, "append_step", "writes")
case = capsim.load_case(sys.argv[1])
with tempfile.TemporaryDirectory() as d:
    case = case.model_copy(update={"output": case.output.model_copy(update={"path": d + "/run.h5"})})
    s = time.perf_counter()
    result = capsim.run(case, overwrite=True)
    run = time.perf_counter() - s
    first = dict(clock)
    # the same run again in this (now warm) process: numba's start-up and the kernels' loading paid
    # (the issue's own profile was of a warm run)
    for key in clock:
        clock[key] = 0.0
    s = time.perf_counter()
    capsim.run(case, overwrite=True)
    warm = time.perf_counter() - s
print(json.dumps({"imports": imports, "run": run, **first, "velocity_evaluations": int(result["velocity_evaluations"]),
                  "D_xy": float(result["D_xy"]), "warm_run": warm, "warm_evaluations": clock["evaluations"],
                  "warm_observe": clock["observe"]}))
"""


def _wall(args: list[str], tree: Path, cwd: Path) -> float:
    s = time.perf_counter()
    subprocess.run(args, env=fresh_env(tree), cwd=cwd, check=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    return time.perf_counter() - s


def _cli(tree: Path, *args: str) -> list[str]:
    return [sys.executable, "-c", "import sys; from capsim.face.cli import app; sys.argv[0] = 'capsim'; app()", *args]


def measure(tree: Path, work: Path) -> dict:
    case = str(tree / CASE)
    out = {"command": _wall(_cli(tree, "run", case, "--overwrite", "--quiet"), tree, work),
           "validate": _wall(_cli(tree, "validate", case), tree, work),
           "interpreter": _wall([sys.executable, "-c", "pass"], tree, work),
           "numba": _wall([sys.executable, "-c", "import numba"], tree, work)}
    return with_worker(out, [sys.executable, "-c", WORKER, case], tree, work)


def with_worker(out: dict, args: list[str], tree: Path, work: Path) -> dict:
    """``out`` (the whole command's wall time) with the worker's split of the same run and what follows
    from the two: the time outside the evaluations, fresh and warm, and around the run."""
    res = subprocess.run(args, env=fresh_env(tree), cwd=work, check=True, capture_output=True, text=True)
    out.update(json.loads(res.stdout.strip().splitlines()[-1]))
    out["outside"] = out["run"] - out["evaluations"]
    out["warm_outside"] = out["warm_run"] - out["warm_evaluations"]
    out["around_the_run"] = out["command"] - out["run"]
    return out


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--rounds", type=int, default=5)
    ap.add_argument("--baseline", default=BASELINE)
    ap.add_argument("--out", default=str(ROOT / "benchmarks" / "command_time"))
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        trees = {"before": export_commit(args.baseline, Path(tmp) / "before"), "after": ROOT}
        work = Path(tmp) / "work"
        work.mkdir()
        for tree in trees.values():  # warm-up: numba's cache, the .pyc
            measure(tree, work)
        rounds = {name: [] for name in trees}
        for r in range(args.rounds):
            for name, tree in trees.items():
                rounds[name].append(measure(tree, work))
                print(f"round {r + 1} {name}: " + ", ".join(f"{k} {v:.3f}" for k, v in rounds[name][-1].items()
                                                           if isinstance(v, float)), flush=True)
    med = {name: {k: float(np.median([x[k] for x in rs])) for k in rs[0]} for name, rs in rounds.items()}
    rows = [("the whole command (`capsim run configs/sphere.yaml`)", "command"),
            ("its time around the run (command less the run)", "around_the_run"),
            ("the run (`capsim.run`, in-process)", "run"),
            ("the run's velocity evaluations", "evaluations"),
            ("the run outside its evaluations", "outside"),
            ("… of which the rows (`observe`)", "observe"),
            ("… of which the run file's row writes", "writes"),
            ("the run again in the same process (warm)", "warm_run"),
            ("… its velocity evaluations", "warm_evaluations"),
            ("… outside its evaluations", "warm_outside"),
            ("… of which the rows (`observe`)", "warm_observe"),
            ("imports of the run's modules (fresh interpreter)", "imports"),
            ("`capsim validate configs/sphere.yaml`", "validate"),
            ("`python -c pass`", "interpreter"),
            ("`python -c \"import numba\"`", "numba")]
    lines = [f"The demo's command and its split (issue 57), medians of {args.rounds} alternating rounds, one thread, "
             f"byte-code cache on; before: commit {args.baseline}, after: this tree. `make bench-command`. "
             f"{platform.processor() or platform.machine()}, load when run: {os.getloadavg()[0]:.1f}.", "",
             "| seconds | before | after | after / before |", "|---|---|---|---|"]
    for label, key in rows:
        b, a = med["before"][key], med["after"][key]
        lines.append(f"| {label} | {b:.3f} | {a:.3f} | {a / b:.2f} |")
    for name in trees:
        m = med[name]
        lines.append("")
        lines.append(f"{name}: outside the evaluations {100 * m['outside'] / m['run']:.0f} % of the run in a fresh "
                     f"interpreter, {100 * m['warm_outside'] / m['warm_run']:.0f} % warm; "
                     f"{int(m['velocity_evaluations'])} evaluations, D_xy {m['D_xy']:.6f}")
    Path(args.out + ".md").write_text("\n".join(lines) + "\n")
    Path(args.out + ".json").write_text(json.dumps({"date": datetime.now(timezone.utc).isoformat(timespec="seconds"),
                                                    "baseline": args.baseline, "rounds": rounds, "medians": med},
                                                   indent=1) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()

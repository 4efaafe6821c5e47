"""A campaign's time outside its velocity evaluations (issue 57): 16 short runs at level 2 on one worker.

The campaign: a sphere (thin shell) at level 2, G = 0.0125 … 0.4 (eight values) × λ = 1 and 5, to
kt = 4 (`stop_when_steady` off: every run its full length), expanded as `capsim sweep` expands it and
run one after another in one fresh interpreter by the function a sweep's worker runs
(`capsim.campaigns.campaign.execute_run`), one thread, byte-code cache on (as an installed package),
after one warm-up run of each kind (numba's cache loaded, as a worker that has run a case). Timed by
wrapping the run's parts:

- ``evaluations``: the velocity evaluations, each the membrane's forces and the velocity
  (``_Run._rhs``: what ``capsim bench`` calls one evaluation);
- ``rows``: the accepted steps' observables (``StepObserver.observe``); ``writes``: the run file's
  rows, snapshots and groups (``TrajectoryWriter.append_step``, ``append_snapshot``, ``flush``);
- ``set-up``: the run's construction (mesh, model, the scheme's probe: its evaluations excluded);
- ``outside``: each run's wall time less its evaluations, summed.

Counts are given beside the times (steps, evaluations): they do not drift with the machine's load.
Usage::

    python benchmarks/campaign_overhead.py              # 3 rounds, medians (about 2 min)
    python benchmarks/campaign_overhead.py --rounds 1 --out /tmp/co

Writes ``<out>.md`` and ``<out>.json`` (default ``benchmarks/campaign_overhead.{md,json}``).
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

from _common import ROOT, TIMED_SOURCE, export_commit, fresh_env
G_VALUES = (0.0125, 0.025, 0.05, 0.075, 0.1, 0.15, 0.2, 0.4)
LAMBDAS = (1.0, 5.0)
T_END = 4.0
LEVEL = 2
#: the commit before issue 57's changes of this session (the campaign's writes and rows)
BASELINE = "8a86e1e"

WORKER = r"""
import json, sys, tempfile, time
t0 = time.perf_counter()
from capsim.numerics.threads import apply_policy
apply_policy(1)
from capsim.campaigns.campaign import campaign_from_dict, expand_campaign, execute_run
from capsim.runs import runner
from capsim.solve import observables
from capsim.storage import store
imports = time.perf_counter() - t0
""" + TIMED_SOURCE + r"""
spec = json.loads(sys.argv[1])
with tempfile.TemporaryDirectory() as tmp:
    spec["output"] = {"dir": tmp + "/campaign"}
    specs = expand_campaign(campaign_from_dict(spec))
    for warm in (specs[0], specs[-1]):  # numba's cache for both kinds (λ = 1, λ ≠ 1) loaded, as a worker's
        warm = warm.model_copy(update={"path": tmp + "/warm.h5"})
        execute_run(warm)
    timed(runner._Run, "_rhs", "evaluations")
    timed(runner._Run, "__init__", "setup")
    timed(observables.StepObserver, "observe", "rows")
    for name in ("append_step", "append_snapshot", "flush", "write_summary", "write_run_record"):
        timed(store.TrajectoryWriter, name, "writes")
    s = time.perf_counter()
    steps = evaluations = 0
    statuses = []
    for one in specs:
        r = execute_run(one)
        statuses.append(r.get("status"))
        summary = r.get("summary") or {}
        steps += int(summary.get("steps", 0))
        evaluations += int(summary.get("velocity_evaluations", 0))
    wall = time.perf_counter() - s
print(json.dumps({"imports": imports, "campaign": wall, **clock, "steps": steps,
                  "velocity_evaluations": evaluations, "runs": len(specs), "statuses": statuses}))
"""


def campaign_spec() -> dict:
    return {"name": "overhead", "base": {"shape": {"kind": "sphere"}, "membrane": {"law": "thin_shell"},
                                          "mesh": {"level": LEVEL}, "time": {"t_end": T_END}},
            "sweep": {"flow.shear_rate_G": list(G_VALUES), "flow.viscosity_ratio": list(LAMBDAS)}, "zip": {}}


def measure(tree: Path) -> dict:
    res = subprocess.run([sys.executable, "-c", WORKER, json.dumps(campaign_spec())], env=fresh_env(tree), cwd=tree,
                         check=True,
                         capture_output=True, text=True)
    out = json.loads(res.stdout.strip().splitlines()[-1])
    out["outside"] = out["campaign"] - out["evaluations"]
    return out


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--baseline", default=BASELINE, help="the commit to compare with (git archive), '' for none")
    ap.add_argument("--out", default=str(ROOT / "benchmarks" / "campaign_overhead"))
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        trees = {"after": ROOT}
        if args.baseline:
            trees = {"before": export_commit(args.baseline, Path(tmp) / "before"), "after": ROOT}
        rounds: dict[str, list[dict]] = {name: [] for name in trees}
        for r in range(args.rounds):  # alternating: the machine's load falls on both alike
            for name, tree in trees.items():
                rounds[name].append(measure(tree))
                print(f"round {r + 1} {name}: " + ", ".join(f"{k} {v:.3f}" for k, v in rounds[name][-1].items()
                                                           if isinstance(v, float)), flush=True)
    keys = [k for k, v in rounds["after"][0].items() if isinstance(v, (int, float))]
    meds = {name: {k: float(np.median([x[k] for x in rs])) for k in keys} for name, rs in rounds.items()}
    med = meds["after"]
    rows = [("the campaign (16 runs, one worker)", "campaign"), ("its velocity evaluations", "evaluations"),
            ("outside the evaluations", "outside"), ("… the runs' set-up (mesh, model, scheme's probe)", "setup"),
            ("… the rows (`observe`)", "rows"), ("… the run files' writes", "writes")]
    names = list(meds)
    lines = [f"A campaign of {med['runs']:.0f} short runs on one worker (issue 57): a sphere at level {LEVEL}, "
             f"G = {G_VALUES[0]:g} … {G_VALUES[-1]:g} × λ = {', '.join(f'{x:g}' for x in LAMBDAS)}, to kt = {T_END:g}, "
             f"one thread; medians of {args.rounds} rounds in fresh interpreters"
             + (f", alternating with commit {args.baseline} (before)" if "before" in meds else "")
             + ". `make bench-campaign`. "
             f"{platform.processor() or platform.machine()}, load when run: {os.getloadavg()[0]:.1f}.", "",
             "| | " + " | ".join(f"{n}: seconds | {n}: share | {n}: ms a step" for n in names) + " |",
             "|---|" + "---|---|---|" * len(names)]
    for label, key in rows:
        cells = [f"{m[key]:.3f} | {100 * m[key] / m['campaign']:.0f} % | {1e3 * m[key] / m['steps']:.3f}"
                 for m in meds.values()]
        lines.append(f"| {label} | " + " | ".join(cells) + " |")
    lines += ["", f"Work: {med['steps']:.0f} accepted steps, {med['velocity_evaluations']:.0f} velocity evaluations "
              f"({med['velocity_evaluations'] / med['steps']:.2f} a step; "
              f"{1e3 * med['evaluations'] / med['velocity_evaluations']:.3f} ms an evaluation). "
              f"The set-up's evaluations (the scheme's probe) are counted with the evaluations."]
    Path(args.out + ".md").write_text("\n".join(lines) + "\n")
    Path(args.out + ".json").write_text(json.dumps({"date": datetime.now(timezone.utc).isoformat(timespec="seconds"),
                                                    "baseline": args.baseline, "campaign": campaign_spec(),
                                                    "rounds": rounds, "medians": meds},
                                                   indent=1) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()

"""Thread policy benchmark (issue 20): numba threading layers and OpenMP wait policies.

The case: a sphere, level 3, G = 0.1, kt = 2 (``capsim run -q`` of that case,
run in-process in a fresh interpreter per setting so that numba reads the
setting at import). Each setting runs with 1 and 2 numba threads, on the machine
as it is ("quiet") and with one competing busy process that this script starts
and stops itself ("busy"). Every child warms the kernels up (a level-0 copy) and
then times ``--repeat`` runs; the table gives the medians of wall time and user
CPU time and the 2-thread / 1-thread ratio of the medians.

Settings:

- ``default``: numba's and libgomp's defaults (no NUMBA_THREADING_LAYER, no
  OMP_WAIT_POLICY): what capsim did before its thread policy;
- ``omp-passive``: NUMBA_THREADING_LAYER=omp, OMP_WAIT_POLICY=PASSIVE;
- ``workqueue``: NUMBA_THREADING_LAYER=workqueue;
- ``tbb``: NUMBA_THREADING_LAYER=tbb (only when the TBB library is installed);
- ``capsim``: no variable set; the child applies capsim.numerics.threads.apply_policy
  (what ``capsim run`` does), and records the settings it got.

Usage::

    python benchmarks/threads.py                       # full: repeat 5, kt 2 (several minutes)
    python benchmarks/threads.py --repeat 1 --t-end 0.2 --out /tmp/threads   # quick check

Writes ``<out>.md`` (the table) and ``<out>.json`` (every measurement), default
``benchmarks/threads.{md,json}``.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import subprocess
import sys
import time
from datetime import datetime, timezone
from pathlib import Path

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
VARIABLES = ("NUMBA_NUM_THREADS", "NUMBA_THREADING_LAYER", "OMP_WAIT_POLICY", "GOMP_SPINCOUNT",
             "CAPSIM_THREAD_POLICY")
#: bounded spin counts measured against PASSIVE (0) and libgomp's default (300000)
SPIN_COUNTS = (1000, 10000, 100000)


def _settings() -> dict[str, dict[str, str] | None]:
    sys.path.insert(0, str(ROOT))
    from capsim.numerics.threads import available_layers  # numba-free

    settings: dict[str, dict[str, str] | None] = {
        "default": {},
        "omp-passive": {"NUMBA_THREADING_LAYER": "omp", "OMP_WAIT_POLICY": "PASSIVE"},
        "workqueue": {"NUMBA_THREADING_LAYER": "workqueue"},
    }
    # libgomp with its default wait policy but a bounded spin: GOMP_SPINCOUNT busy-wait
    # iterations at a barrier, then sleep (libgomp's own default is 300000).
    for count in SPIN_COUNTS:
        settings[f"omp-spin{count // 1000}k"] = {"NUMBA_THREADING_LAYER": "omp", "GOMP_SPINCOUNT": str(count)}
    if "tbb" in available_layers():
        settings["tbb"] = {"NUMBA_THREADING_LAYER": "tbb"}
    settings["capsim"] = None  # the policy, applied in the child
    return settings


# ---------------------------------------------------------------- child


def child(spec: dict) -> dict:
    """Runs in a fresh interpreter: warm up, then time `repeat` runs of the case."""
    import resource
    import tempfile

    sys.path.insert(0, str(ROOT))
    from capsim.numerics import threads

    if spec["policy"]:
        threads.apply_policy(spec["threads"])
    from capsim.config import apply_overrides, case_from_dict
    from _common import run_or_stop

    with tempfile.TemporaryDirectory(prefix="capsim-bench-threads-") as tmp:
        case = case_from_dict({
            "name": "bench-threads", "shape": {"kind": "sphere"}, "flow": {"shear_rate_G": 0.1},
            "mesh": {"level": spec["level"]}, "time": {"t_end": spec["t_end"]},
            "output": {"path": os.path.join(tmp, "run.h5"), "snapshot_every": spec["t_end"]},
        })
        warm = apply_overrides(case, **{"mesh.level": 0, "time.t_end": 0.01,
                                        "output.path": os.path.join(tmp, "warm.h5")})
        run_or_stop(warm)
        runs = []
        for _ in range(spec["repeat"]):
            cpu0, wall0 = resource.getrusage(resource.RUSAGE_SELF).ru_utime, time.perf_counter()
            summary = run_or_stop(case)
            wall = time.perf_counter() - wall0
            cpu = resource.getrusage(resource.RUSAGE_SELF).ru_utime - cpu0
            runs.append({"wall_s": wall, "user_cpu_s": cpu, "steps": int(summary["steps"]),
                         "status": summary["status"]})
    return {"runs": runs, "in_effect": threads.policy_attrs()}


# ---------------------------------------------------------------- parent


def _busy() -> subprocess.Popen:
    """One CPU-bound competitor (a Python spin loop)."""
    return subprocess.Popen([sys.executable, "-c", "while True: pass"])


def _measure(name: str, env_vars: dict | None, n_threads: int, args) -> dict:
    env = {k: v for k, v in os.environ.items() if k not in VARIABLES}
    if env_vars is not None:
        env.update(env_vars)
        env["NUMBA_NUM_THREADS"] = str(n_threads)
    spec = {"threads": n_threads, "policy": env_vars is None, "level": args.level, "t_end": args.t_end,
            "repeat": args.repeat}
    out = subprocess.run([sys.executable, __file__, "--child", json.dumps(spec)], env=env,
                         capture_output=True, text=True, timeout=args.timeout)
    if out.returncode != 0:
        tail = (out.stderr.strip().splitlines() or ["?"])[-1]
        return {"error": tail}
    return json.loads(out.stdout.strip().splitlines()[-1])


def _row(result: dict) -> dict:
    runs = result.get("runs", [])
    return {
        "wall_median_s": statistics.median(r["wall_s"] for r in runs) if runs else float("nan"),
        "user_cpu_median_s": statistics.median(r["user_cpu_s"] for r in runs) if runs else float("nan"),
    }


def _table(results: list[dict], meta: dict) -> str:
    lines = [
        f"Sphere, level {meta['level']}, G = 0.1, kt = {meta['t_end']:g}; medians of {meta['repeat']} runs per "
        f"row; {meta['cores']} usable cores; numba {meta['numba']}; {meta['when']}.",
        f"Load: {meta['load_note']}",
        "",
        "| setting | load | threads | wall (s) | user CPU (s) | 2 threads / 1 thread (wall) | layer, wait policy in effect |",
        "|---|---|---|---|---|---|---|",
    ]
    by_key = {(r["setting"], r["load"], r["threads"]): r for r in results}
    for r in results:
        if "error" in r:
            lines.append(f"| {r['setting']} | {r['load']} | {r['threads']} | failed: {r['error']} | | | |")
            continue
        one = by_key.get((r["setting"], r["load"], 1))
        ratio = ""
        if r["threads"] == 2 and one is not None and "error" not in one:
            ratio = f"{r['wall_median_s'] / one['wall_median_s']:.2f}"
        eff = r["in_effect"]
        lines.append(
            f"| {r['setting']} | {r['load']} | {r['threads']} | {r['wall_median_s']:.2f} | "
            f"{r['user_cpu_median_s']:.2f} | {ratio} | {eff['numba_threading_layer']}, {eff['omp_wait_policy']} |"
        )
    quiet_default = by_key.get(("default", "quiet", 2))
    quiet_capsim = by_key.get(("capsim", "quiet", 2))
    if quiet_default and quiet_capsim and "error" not in quiet_default and "error" not in quiet_capsim:
        lines += ["", f"Quiet, 2 threads: capsim's policy / numba's default = "
                      f"{quiet_capsim['wall_median_s'] / quiet_default['wall_median_s']:.2f} (wall)."]
    return "\n".join(lines) + "\n"


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--repeat", type=int, default=5, help="timed runs per setting (median)")
    p.add_argument("--t-end", type=float, default=2.0, help="kt of each run")
    p.add_argument("--level", type=int, default=3, help="mesh level")
    p.add_argument("--threads", default="1,2", help="thread counts, comma-separated")
    p.add_argument("--settings", default=None, help="comma-separated subset of the settings")
    p.add_argument("--loads", default="quiet,busy", help="quiet, busy or both")
    p.add_argument("--timeout", type=float, default=1800.0, help="seconds per child")
    p.add_argument("--load-note", default="", help="what else ran on the machine (goes into the table)")
    p.add_argument("--out", default=str(HERE / "threads"), help="output prefix (.md and .json)")
    p.add_argument("--child", help=argparse.SUPPRESS)
    args = p.parse_args(argv)
    if args.child:
        print(json.dumps(child(json.loads(args.child))))
        return 0

    settings = _settings()
    if args.settings:
        settings = {k: v for k, v in settings.items() if k in args.settings.split(",")}
    thread_counts = [int(v) for v in args.threads.split(",")]
    results = []
    for load in args.loads.split(","):
        busy = _busy() if load == "busy" else None
        try:
            for name, env_vars in settings.items():
                for n in thread_counts:
                    t0 = time.perf_counter()
                    result = _measure(name, env_vars, n, args)
                    row = {"setting": name, "load": load, "threads": n, **result}
                    if "error" not in result:
                        row.update(_row(result))
                        print(f"{load:5s} {name:12s} {n} threads: wall {row['wall_median_s']:.2f} s, "
                              f"user CPU {row['user_cpu_median_s']:.2f} s ({time.perf_counter() - t0:.0f} s)",
                              flush=True)
                    else:
                        print(f"{load:5s} {name:12s} {n} threads: failed: {result['error']}", flush=True)
                    results.append(row)
        finally:
            if busy is not None:
                busy.terminate()
                busy.wait()
    import numba  # only for the version shown; the children measured

    sys.path.insert(0, str(ROOT))
    from capsim.numerics.threads import usable_cores

    meta = {
        "level": args.level, "t_end": args.t_end, "repeat": args.repeat, "cores": usable_cores(),
        "numba": numba.__version__, "python": platform.python_version(),
        "when": datetime.now(timezone.utc).strftime("%Y-%m-%d %H:%M UTC"),
        "load_note": ("'busy' adds one CPU-bound process started by the benchmark. " + args.load_note).strip(),
    }
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.with_suffix(".json").write_text(json.dumps({"meta": meta, "results": results}, indent=1))
    table = _table(results, meta)
    out.with_suffix(".md").write_text(table)
    print(table)
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""Warm-up knows every kernel (issue 27, item 4): after warm_up(cases), running the cases
compiles (or loads) no numba signature, for every time scheme and preconditioner.

Run in a fresh interpreter: in the test process, kernels other tests compiled are already
loaded and would hide a kind that the warm-up missed.
"""

from __future__ import annotations

import json
import subprocess
import sys
import textwrap

SCRIPT = textwrap.dedent('''
    import json, sys, tempfile, os
    from capsim.config import case_from_dict
    from capsim.campaigns.executor import warm_up, kernel_kind

    tmp = tempfile.mkdtemp()
    def case(name, **time):
        return case_from_dict({"name": name, "flow": {"shear_rate_G": 0.1}, "mesh": {"level": 1},
                               "membrane": {"traction": "galerkin"},
                               "time": {"t_end": 0.02, "dt_initial": 0.005, **time},
                               "output": {"path": os.path.join(tmp, name + ".h5")}})
    cases = [case("rkf23"), case("rkc", scheme="rkc"),
             case("li_local", scheme="linearly_implicit", preconditioner="local"),
             case("li_dense", scheme="linearly_implicit", preconditioner="dense"),
             case("li_none", scheme="linearly_implicit", preconditioner="none")]
    warm_up(cases)
    import numba
    from numba.core.registry import CPUDispatcher
    import capsim.numerics.kernels as k
    def signatures():
        return {name: len(obj.signatures) for name, obj in vars(k).items() if isinstance(obj, CPUDispatcher)}
    before = signatures()
    from capsim.runs.runner import run_case
    compiled = {}
    for c in cases:
        run_case(c)
        after = signatures()
        compiled[c.name] = sorted(n for n in after if after[n] != before.get(n))
        before = after
    print(json.dumps({"kinds": len({kernel_kind(c) for c in cases}), "compiled": compiled}))
''')


def test_a_run_after_warm_up_compiles_nothing_for_any_scheme_or_preconditioner():
    proc = subprocess.run([sys.executable, "-c", SCRIPT], capture_output=True, text=True, timeout=900)
    assert proc.returncode == 0, proc.stderr[-3000:]
    result = json.loads(proc.stdout.strip().splitlines()[-1])
    assert result["kinds"] == 5  # each scheme and preconditioner is a kind of its own
    assert result["compiled"] == {name: [] for name in ("rkf23", "rkc", "li_local", "li_dense", "li_none")}


RUN_AND_COUNT = textwrap.dedent('''
    import json, sys
    from numba.core.registry import CPUDispatcher
    import capsim
    result = capsim.run(sys.argv[1], output=sys.argv[2])
    import capsim.numerics.kernels as k
    stats = [obj.stats for obj in vars(k).values() if isinstance(obj, CPUDispatcher)]
    print(json.dumps({"status": result.status, "hits": sum(sum(s.cache_hits.values()) for s in stats),
                      "misses": sum(sum(s.cache_misses.values()) for s in stats)}))
''')


def test_capsim_warm_up_fills_the_cache_so_the_first_run_compiles_nothing(tmp_path):
    """`capsim warm-up CASE` (what `make venv` runs for the demo, issue 29 item 5) leaves numba's
    cache holding every kernel the case's run uses: a run in a new process then loads each
    signature from the cache (hits) and compiles none (misses = 0), and says nothing of compiling."""
    import os

    import yaml

    case = tmp_path / "c.yaml"
    case.write_text(yaml.safe_dump({"name": "c", "mesh": {"level": 1}, "time": {"t_end": 0.05}}))
    env = {**os.environ, "NUMBA_CACHE_DIR": str(tmp_path / "cache")}
    env.pop("NUMBA_NUM_THREADS", None)
    warm = subprocess.run([sys.executable, "-m", "capsim.face.cli", "warm-up", str(case)], env=env,
                          capture_output=True, text=True, timeout=900)
    assert warm.returncode == 0, warm.stderr[-2000:]
    assert warm.stdout.startswith("kernels ready in ")
    run = subprocess.run([sys.executable, "-c", RUN_AND_COUNT, str(case), str(tmp_path / "run.h5")], env=env,
                         capture_output=True, text=True, timeout=900)
    assert run.returncode == 0, run.stderr[-2000:]
    counts = json.loads(run.stdout.strip().splitlines()[-1])
    assert counts["status"] == "completed"
    assert counts["hits"] > 0 and counts["misses"] == 0, counts
    cli = subprocess.run([sys.executable, "-m", "capsim.face.cli", "run", str(case), "-o", str(tmp_path / "cli.h5")],
                         env=env, capture_output=True, text=True, timeout=600)
    assert cli.returncode == 0 and "compiling" not in cli.stderr, cli.stderr[-2000:]


def test_warm_up_of_a_bad_case_file_is_one_line(tmp_path):
    import os

    case = tmp_path / "bad.yaml"
    case.write_text("name: b\nmesh: {level: -1}\n")
    env = {k: v for k, v in os.environ.items() if k != "NUMBA_NUM_THREADS"}
    proc = subprocess.run([sys.executable, "-m", "capsim.face.cli", "warm-up", str(case)], env=env,
                          capture_output=True, text=True, timeout=300)
    assert proc.returncode == 2
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: ") and "mesh.level" in lines[0], proc.stderr

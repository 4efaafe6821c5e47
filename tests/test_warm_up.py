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
    from capsim.executor import warm_up, kernel_kind

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
    import capsim.kernels as k
    def signatures():
        return {name: len(obj.signatures) for name, obj in vars(k).items() if isinstance(obj, CPUDispatcher)}
    before = signatures()
    from capsim.runner import run_case
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

"""The whole command and its split for the three cases of the side-by-side comparison with the Fortran
peer (issue 57, item 3): the demo's sphere at level 3 (λ 1, G 0.1, kt 10: the demo itself), at λ 5
(G 0.1, kt 6) and at small G (λ 1, G 0.0125, kt 2), this checkout, one thread, byte-code cache on.

Per case and round, in fresh interpreters (as ``command_time.py``, whose worker this reuses):

- ``command``: the whole ``capsim run configs/sphere.yaml --set ...`` as a subprocess, wall time;
- in one more fresh interpreter: ``capsim.run`` of the same case with its velocity evaluations
  (``_Run._rhs``: the membrane's forces and the velocity) and its rows (``observe``) timed by
  wrapping them, then the same run again in that process (``warm_*``: numba's start-up and the
  kernels' loading already paid).

``around the run`` is the command less the fresh in-process run; ``outside`` the run less its
evaluations. Counts (evaluations) beside the times. Usage::

    python benchmarks/peer_command_time.py            # 3 rounds (about 2 min)
    python benchmarks/peer_command_time.py --rounds 1 --out /tmp/pct

Writes ``<out>.md`` and ``<out>.json``, default ``benchmarks/peer_command_time.{md,json}``.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import tempfile
from datetime import datetime, timezone
from pathlib import Path

import numpy as np

from _common import ROOT
from command_time import WORKER, _cli, _wall, with_worker

CASE = "configs/sphere.yaml"
#: the peer's three cases (the tranche's side-by-side comparison): label, --set overrides
CASES = (
    ("λ 1, G 0.1, kt 10 (the demo)", ()),
    ("λ 5, G 0.1, kt 6", ("flow.viscosity_ratio=5", "time.t_end=6")),
    ("λ 1, G 0.0125, kt 2", ("flow.shear_rate_G=0.0125", "time.t_end=2")),
)

#: command_time's worker reads the case file alone: here the overrides are applied first
PEER_WORKER = WORKER.replace("case = capsim.load_case(sys.argv[1])",
                             "case = capsim.load_case(sys.argv[1], sets=json.loads(sys.argv[2]))")


def measure(sets: tuple[str, ...], work: Path) -> dict:
    case = str(ROOT / CASE)
    options = [arg for s in sets for arg in ("--set", s)]
    out = {"command": _wall(_cli(ROOT, "run", case, *options, "-o", str(work / "cmd.h5"), "--overwrite", "--quiet"),
                            ROOT, work)}
    return with_worker(out, [sys.executable, "-c", PEER_WORKER, case, json.dumps(list(sets))], ROOT, work)


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--out", default=str(ROOT / "benchmarks" / "peer_command_time"))
    args = ap.parse_args()
    rounds: dict[str, list[dict]] = {label: [] for label, _ in CASES}
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        measure((), work)  # warm-up: numba's cache, the .pyc
        for r in range(args.rounds):
            for label, sets in CASES:
                rounds[label].append(measure(sets, work))
                print(f"round {r + 1} {label}: " + ", ".join(f"{k} {v:.3f}" for k, v in rounds[label][-1].items()
                                                            if isinstance(v, float)), flush=True)
    med = {label: {k: float(np.median([x[k] for x in rs])) for k in rs[0]} for label, rs in rounds.items()}
    rows = [("the whole command", "command", "{:.2f}"),
            ("its time around the run", "around_the_run", "{:.2f}"),
            ("the run (fresh interpreter)", "run", "{:.2f}"),
            ("… its velocity evaluations", "evaluations", "{:.2f}"),
            ("… outside them", "outside", "{:.2f}"),
            ("… of which the rows", "observe", "{:.2f}"),
            ("the run again (warm)", "warm_run", "{:.2f}"),
            ("… outside its evaluations", "warm_outside", "{:.2f}"),
            ("… of which the rows", "warm_observe", "{:.2f}")]
    labels = [label for label, _ in CASES]
    lines = [f"The peer's three cases (issue 57, item 3): `capsim run configs/sphere.yaml` at level 3, one thread, "
             f"byte-code cache on, this tree; seconds, medians of {args.rounds} rounds in fresh interpreters. "
             f"`make bench-peer-command`. {platform.processor() or platform.machine()}, load when run: "
             f"{os.getloadavg()[0]:.1f}.", "",
             "| seconds | " + " | ".join(labels) + " |", "|---" * (len(labels) + 1) + "|"]
    for text, key, fmt in rows:
        lines.append(f"| {text} | " + " | ".join(fmt.format(med[label][key]) for label in labels) + " |")
    lines.append("| share outside the evaluations, fresh / warm | " + " | ".join(
        f"{100 * med[label]['outside'] / med[label]['run']:.0f} % / "
        f"{100 * med[label]['warm_outside'] / med[label]['warm_run']:.0f} %" for label in labels) + " |")
    lines.append("| velocity evaluations | " + " | ".join(f"{int(med[label]['velocity_evaluations'])}"
                                                       for label in labels) + " |")
    Path(args.out + ".md").write_text("\n".join(lines) + "\n")
    Path(args.out + ".json").write_text(json.dumps({"date": datetime.now(timezone.utc).isoformat(timespec="seconds"),
                                                    "cases": dict(CASES), "rounds": rounds, "medians": med},
                                                   indent=1) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()

"""`make bench`: velocity-evaluation benchmark for levels 2-4 (λ = 1 and 5),
written to benchmarks/results.json and printed as a table."""

import json
import platform
import sys
from datetime import datetime, timezone
from pathlib import Path

from capsim import __version__
from capsim.runs.benchmark import bench_velocity


def main() -> None:
    rows = []
    for lam in (1.0, 5.0):
        for level in (2, 3, 4):
            for sym in ("quarter", "half", "none"):
                rows.append(bench_velocity(level=level, viscosity_ratio=lam, repeat=5 if level < 4 else 3, symmetry=sym))
                r = rows[-1]
                print(
                    f"λ={lam:<4g} level {level} symmetry {sym:7}: {r['n_nodes']:5d} nodes"
                    f"  eval {1e3 * r['velocity_eval_s']:8.2f} ms"
                    f"  bare {1e3 * r['bare_stokeslet_sum_s']:7.2f} ms  ratio {r['ratio_to_bare']:5.2f}"
                    f"  iters {r['solver_iterations_median']:.0f}",
                    flush=True,
                )
    out = {
        "capsim_version": __version__,
        "created": datetime.now(timezone.utc).isoformat(timespec="seconds"),
        "machine": platform.platform(),
        "python": sys.version.split()[0],
        "results": rows,
    }
    path = Path(__file__).with_name("results.json")
    path.write_text(json.dumps(out, indent=2))
    print(f"wrote {path}")


if __name__ == "__main__":
    main()

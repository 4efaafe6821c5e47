"""Rigid limit of off-plane orbits (issue 26): prolate (r = 2) and oblate (r = 0.5)
capsules with a stiff membrane, started with the director at 30°, 60° and 90° from the
vorticity axis (azimuth 0: in the yz-plane), against Jeffery's orbit of the rigid
spheroid: period T = 2π(r + 1/r)/k and orbit constant C (docs/known_answers.md).

    PYTHONPATH=. python benchmarks/jeffery_orbits.py [--level 2] [--G 0.001 0.0005] [--out benchmarks/jeffery_orbits.json]

Writes a JSON list of records and prints a table (docs/known_answers.md holds
the committed one). r is measured on the discretised rest shape (jeffery_aspect_ratio).
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
from jeffery_cases import POLAR_DEG, SHAPES, jeffery_record  # noqa: E402

def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--level", type=int, default=2)
    ap.add_argument("--G", type=float, nargs="+", default=[0.001, 0.0005])
    ap.add_argument("--kinds", nargs="+", default=list(SHAPES))
    ap.add_argument("--polar", type=float, nargs="+", default=list(POLAR_DEG))
    ap.add_argument("--out", default="benchmarks/jeffery_orbits.json")
    args = ap.parse_args()
    records = []
    with tempfile.TemporaryDirectory() as tmp:
        for G in args.G:
            for kind in args.kinds:
                for polar in args.polar:
                    rec = jeffery_record(kind, polar, G, args.level, tmp)
                    records.append(rec)
                    print(f"{kind:8s} θ0 {polar:4.0f}°  G {G:<7g} r {rec['r']:.4f}  T {rec['period']:.4f} "
                          f"(Jeffery {rec['jeffery_period']:.4f}, {100 * rec['period_error']:+.2f} %)  "
                          + (f"C {rec['C_first']:.4f} ({100 * rec['C_error']:+.2f} %)  " if rec["C_error"] is not None
                             else f"C {rec['C_first']}  ")
                          + f"final θ {rec['final_polar_deg']:.2f}°  "
                          f"{rec['motion']}  {rec['steps']} steps  {rec['wall_s']:.1f} s", flush=True)
    with open(args.out, "w") as fh:
        json.dump(records, fh, indent=1)


if __name__ == "__main__":
    main()

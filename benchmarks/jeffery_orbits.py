"""Rigid limit of off-plane orbits (issue 26): prolate (r = 2) and oblate (r = 0.5)
capsules with a stiff membrane, started with the director at 30°, 60° and 90° from the
vorticity axis (azimuth 0: in the yz-plane), against Jeffery's orbit of the rigid
spheroid: period T = 2π(r + 1/r)/k and orbit constant C (docs/known_answers.md).

    PYTHONPATH=. python benchmarks/jeffery_orbits.py [--level 1] [--G 0.005 0.0025] [--out benchmarks/jeffery_orbits.json]

Writes a JSON list of records and prints a table (benchmarks/jeffery_orbits.md holds
the committed one). r is measured on the discretised rest shape (jeffery_aspect_ratio).
"""

from __future__ import annotations

import argparse
import json
import math
import tempfile
import time

from capsim.config import case_from_dict
from capsim.runner import run_case

SHAPES = {"prolate": 2.0, "oblate": 0.5}
POLAR_DEG = (30.0, 60.0, 90.0)


def orbit_case(kind: str, polar_deg: float, G: float, level: int, path: str, periods: float = 1.05,
               scheme: str = "rkc", rtol: float = 1e-4) -> dict:
    r = SHAPES[kind]
    p = math.radians(polar_deg)
    return {
        "name": f"jeffery-{kind}-{polar_deg:g}-G{G:g}-L{level}",
        "shape": {"kind": kind, "aspect_ratio": r},
        "initial_axis": [0.0, math.sin(p), math.cos(p)],
        "flow": {"shear_rate_G": G},
        "membrane": {"law": "neo_hookean"},
        "mesh": {"level": level},
        "time": {"t_end": periods * 2 * math.pi * (r + 1 / r), "scheme": scheme, "rtol": rtol},
        "output": {"path": path, "snapshot_every": 1.0},
    }


def jeffery_record(kind: str, polar_deg: float, G: float, level: int, tmp: str, **options) -> dict:
    case = case_from_dict(orbit_case(kind, polar_deg, G, level, f"{tmp}/{kind}-{polar_deg:g}-{G:g}.h5", **options))
    t0 = time.perf_counter()
    s = run_case(case)
    wall = time.perf_counter() - t0
    r = s["jeffery_aspect_ratio"]
    C_exact = math.tan(math.radians(polar_deg))  # at azimuth 0: C = tan θ0 · r / r
    rec = {"kind": kind, "polar_deg": polar_deg, "G": G, "level": level, "r": r,
           "period": s["orbit_period"], "jeffery_period": s["jeffery_period"],
           "period_error": s["orbit_period"] / s["jeffery_period"] - 1.0,
           "C_first": s["orbit_constant_first"], "C_exact": C_exact if polar_deg != 90 else float("inf"),
           "final_polar_deg": math.degrees(s["final_polar_angle"]), "motion": s["motion"],
           "steps": s["steps"], "wall_s": wall}
    rec["C_error"] = rec["C_first"] / C_exact - 1.0 if polar_deg != 90 else float("nan")
    return rec


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--level", type=int, default=1)
    ap.add_argument("--G", type=float, nargs="+", default=[0.005, 0.0025])
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
                          f"C {rec['C_first']:.4f} ({100 * rec['C_error']:+.2f} %)  final θ {rec['final_polar_deg']:.2f}°  "
                          f"{rec['motion']}  {rec['steps']} steps  {rec['wall_s']:.1f} s", flush=True)
    with open(args.out, "w") as fh:
        json.dump(records, fh, indent=1)


if __name__ == "__main__":
    main()

"""Jeffery's rigid limit as capsim cases (issue 26): shared by tests/solve/test_orientation.py and
benchmarks/jeffery_orbits.py. A prolate (r = 2) or oblate (r = 0.5) capsule with a stiff
neo-Hookean membrane, started with the director at a polar angle from the vorticity axis
and azimuth 0 (in the yz-plane), run for ``periods`` of Jeffery's period 2π(r + 1/r)."""

from __future__ import annotations

import math
import time

from capsim.config import case_from_dict
from capsim.runs.runner import run_case

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
           "C_first": s["orbit_constant_first"], "C_exact": C_exact if polar_deg != 90 else None,
           "final_polar_deg": math.degrees(s["final_polar_angle"]), "motion": s["motion"],
           "steps": s["steps"], "wall_s": wall}
    # in the shear plane C is ∞ (Jeffery), and so is capsim's
    rec["C_error"] = rec["C_first"] / C_exact - 1.0 if polar_deg != 90 else None
    if polar_deg == 90:
        rec["C_first"] = None if s["orbit_constant_first"] == float("inf") else s["orbit_constant_first"]
    return rec

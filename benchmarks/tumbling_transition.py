"""The red cell's tumbling-tank-treading transition against the measured threshold stress (issue 55).

Fischer & Korzeniewski (J. Fluid Mech. 736, 2013) measured the shear stress τ = μk above which
discocytes tank-tread rather than tumble, at three viscosities of the suspending medium (10.7, 23.9
and 104 mPa s; benchmarks/data/fischer2013_tt_tb_threshold.csv, with Abkarian, Faivre & Viallat
2007's at 31 mPa s). The cell's shape memory, its stress-free shape, sets that threshold (Fischer
2004; Cordasco, Yazdani & Bagchi 2014; Peng, Mashayekh & Zhu 2014): this runs the Tran-Son-Tay case's
cell (campaigns/tran-son-tay-1984.yaml: Evans-Fung disk of a = 2.98 um, Skalak C = 10, G_s 2.5 uN/m,
κ 1.8e-19 J, cytoplasm 10 mPa s, μ_s the mean of their Table III) over the shear rate at each
viscosity, for two stress-free shapes (its own disk, and a nearly spherical oblate spheroid of
aspect 0.9), and classifies each run's motion (capsim's orbit classifier: tumbling, swinging =
tank-treading with an oscillating shape). The threshold is bracketed by the fastest rate that
tumbles and the slowest that tank-treads.

Mesh level 1 (the TTS case's frequency moved 0.1 % from level 1 to 2), t_end kt 60 (two to three
tumbling periods), rtol 1e-4: a first look, not a converged threshold.

    python benchmarks/tumbling_transition.py run [VISCOSITY ...]   # resumable; rows in the JSON
    python benchmarks/tumbling_transition.py finer 2 23.9 [K ...] [--oblate] [--auto]  # the disk (or the
                          # oblate state) at level 2 (or 3; LEVEL2_RATES); --auto: membrane.skalak_c auto
    python benchmarks/tumbling_transition.py report                # the table
"""

from __future__ import annotations

import json
import math
import os
import sys
import tempfile
from pathlib import Path

for _name in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_name, "1")

ROOT = Path(__file__).resolve().parents[1]
JSON = ROOT / "benchmarks" / "tumbling_transition.json"
TABLE = ROOT / "benchmarks" / "tumbling_transition.md"
DATA = ROOT / "benchmarks" / "data"
#: the medium's viscosity (mPa s) and the shear rates (1/s) run there: around the measured thresholds
RATES = {23.9: (1.0, 2.0, 3.0, 5.0, 8.0, 12.0, 20.0), 10.7: (10.0, 20.0, 40.0, 60.0, 90.0, 130.0),
         104.0: (0.15, 0.3, 0.5, 0.8, 1.2, 2.0)}
STRESS_FREE = (("disk", None), ("oblate 0.9", {"kind": "oblate", "aspect_ratio": 0.9}))
LEVEL, T_END = 1, 60.0
#: the tag's suffix of the rows run with membrane.skalak_c auto (`finer ... --auto`)
AUTO_TAG = ", skalak_c auto"


def base_case() -> dict:
    import yaml

    base = yaml.safe_load((ROOT / "campaigns" / "tran-son-tay-1984.yaml").read_text())["base"]
    base["physical"]["membrane_viscosity"] = "0.662e-7 N*s/m"  # Tran-Son-Tay's Table III, mean
    base["mesh"]["level"] = LEVEL
    base["time"] = {"t_end": T_END, "rtol": 1.0e-4}
    return base


#: the disk's bracket at level 1 checked at level 2 (the motion near the threshold is the mesh's too: at
#: 28.9 mPa s, 8.2 1/s, the cell of fits/fit-fischer-2015-mu-s-g-s.yaml tumbled at level 1 and tank-treaded
#: at level 2): viscosity -> shear rates, the disk only
LEVEL2_RATES = {23.9: (5.0, 8.0, 12.0)}


def run_one(eta: float, k: float, tag: str, reference, level: int = LEVEL, area_auto: bool = False) -> dict:
    from capsim.config import case_from_dict
    from _common import run_or_stop  # an interrupted run ends the benchmark, never a row

    case = json.loads(json.dumps(base_case()))
    case["physical"].update(viscosity=f"{eta:g} mPa*s", shear_rate=f"{k:g} 1/s")
    case["mesh"]["level"] = level
    if reference is not None:
        case["membrane"]["reference_shape"] = reference
    if area_auto:  # the membrane nearly area-incompressible (its C chosen for the case's G) instead of C = 10
        case["membrane"]["skalak_c"] = "auto"
    with tempfile.TemporaryDirectory() as tmp:
        case["name"] = "tt-tb"
        case["output"] = {"path": f"{tmp}/run.h5", "snapshot_every": T_END}
        c = case_from_dict(case)
        result = run_or_stop(c)
    s = dict(result.summary)
    return {"eta_mPa_s": eta, "shear_rate": k, "stress_Pa": eta * 1e-3 * k, "stress_free": tag,
            "G": c.flow.shear_rate_G, "viscosity_ratio": c.flow.viscosity_ratio, "status": result.status,
            "motion": s.get("motion"), "settled": s.get("settled"), "ttf_ratio": s.get("ttf_ratio"),
            "body_rotation_ratio": s.get("body_rotation_ratio"), "wall_time_s": result.wall_time_s,
            "level": level, "skalak_c": c.membrane.skalak_c}


def run_finer(level: int, eta: float, rates: list[float], tag: str = "disk", area_auto: bool = False) -> None:
    """A stress-free shape of STRESS_FREE (the disk by default) at a finer level at the given rates
    (LEVEL2_RATES), each row added to the JSON under a lock (two of these may run side by side, one per core);
    ``area_auto``: with membrane.skalak_c auto (its row's shape tagged ", skalak_c auto")."""
    reference = dict(STRESS_FREE)[tag]
    tag = tag + (AUTO_TAG if area_auto else "")
    import fcntl

    from capsim.numerics.threads import apply_policy

    apply_policy(1)
    for k in rates:
        row = run_one(eta, k, tag, reference, level=level, area_auto=area_auto)
        with open(JSON.with_suffix(".lock"), "w") as lock:
            fcntl.flock(lock, fcntl.LOCK_EX)
            rows = [r for r in load() if not (r.get("level", LEVEL) == level and r["eta_mPa_s"] == eta
                                              and r["shear_rate"] == k and r["stress_free"] == tag)]
            JSON.write_text(json.dumps(rows + [row], indent=1) + "\n")
        print(f"level {level}: η {eta:g} k {k:g} ({row['stress_Pa']:.3g} Pa) {tag}: {row['motion']} {row['status']} "
              f"{row['wall_time_s']:.0f} s", flush=True)


def load() -> list[dict]:
    return json.loads(JSON.read_text()) if JSON.exists() else []


def run(viscosities: list[float]) -> None:
    from capsim.numerics.threads import apply_policy

    apply_policy(1)
    rows = load()
    done = {(r["eta_mPa_s"], r["shear_rate"], r["stress_free"]) for r in rows if r.get("level", LEVEL) == LEVEL}
    for eta in viscosities:
        for tag, reference in STRESS_FREE:
            for k in RATES[eta]:
                if (eta, k, tag) in done:
                    continue
                rows.append(run_one(eta, k, tag, reference))
                JSON.write_text(json.dumps(rows, indent=1) + "\n")
                r = rows[-1]
                print(f"η {eta:g} k {k:g} ({r['stress_Pa']:.3g} Pa, G {r['G']:.3g}) {tag}: {r['motion']} "
                      f"{r['status']} {r['wall_time_s']:.0f} s", flush=True)
    report()


def _measured(eta: float) -> str:
    import numpy as np

    out = []
    for name in ("fischer2013_tt_tb_threshold.csv", "abkarian2007_tt_tb_threshold.csv"):
        d = np.genfromtxt(DATA / name, delimiter=",", names=True)
        tau = d["tau_threshold_Pa"][np.isclose(d["eta_mPa_s"], eta)]
        if tau.size:
            out.append(", ".join(f"{t:.3g}" for t in sorted(tau)))
    return "; ".join(out) or "—"


def report() -> None:
    everything = load()
    rows = [r for r in everything if r.get("level", LEVEL) == LEVEL]
    lines = [__doc__.split("\n\n")[0].replace("\n", " ") + " `make bench-transition` (level 1, kt 60).", "",
             "| η (mPa s) | measured threshold τ (Pa) | stress-free shape | tumbles at τ (Pa) | tank-treads at τ (Pa) | "
             "threshold bracket (Pa) |", "|---|---|---|---|---|---|"]
    for eta in sorted({r["eta_mPa_s"] for r in rows}):
        for tag, _ in STRESS_FREE:
            mine = sorted((r for r in rows if r["eta_mPa_s"] == eta and r["stress_free"] == tag),
                          key=lambda r: r["stress_Pa"])
            if not mine:
                continue
            tumbles = [r["stress_Pa"] for r in mine if r["motion"] == "tumbling"]
            treads = [r["stress_Pa"] for r in mine if r["motion"] in ("swinging", "steady")]
            lo = max(tumbles) if tumbles else None
            hi = min((t for t in treads if lo is None or t > lo), default=None)
            bracket = (f"({lo:.3g}, {hi:.3g})" if lo is not None and hi is not None else
                       f"below {hi:.3g}" if hi is not None else f"above {lo:.3g}" if lo is not None else "—")
            lines.append(f"| {eta:g} | {_measured(eta)} | {tag} | {', '.join(f'{t:.3g}' for t in tumbles) or '—'} | "
                         f"{', '.join(f'{t:.3g}' for t in treads) or '—'} | {bracket} |")
    others = [r for r in rows if r["motion"] not in ("tumbling", "swinging", "steady")]
    if others:
        lines += ["", "Runs classified otherwise: " + "; ".join(
            f"η {r['eta_mPa_s']:g}, {r['stress_Pa']:.3g} Pa, {r['stress_free']}: {r['motion']} ({r['status']})"
            for r in others)]
    finer = [r for r in everything if r.get("level", LEVEL) > LEVEL]
    if finer:
        by = {(r.get("level", LEVEL), r["eta_mPa_s"], r["shear_rate"], r["stress_free"]): r for r in everything}
        lines += ["", "Finer meshes near the level-1 brackets (the motion near the threshold depends on the mesh; "
                  "`python benchmarks/tumbling_transition.py finer LEVEL ETA K ... [--oblate]`):", "",
                  "| η (mPa s) | stress-free shape | τ (Pa) | G | level 1 | level 2 | level 3 |",
                  "|---|---|---|---|---|---|---|"]
        for eta, tag, k in sorted({(r["eta_mPa_s"], r["stress_free"], r["shear_rate"]) for r in finer}):
            r0 = next(r for (lv, e, kk, t), r in by.items() if e == eta and kk == k and t == tag)
            cells = [by[(lv, eta, k, tag)]["motion"] if (lv, eta, k, tag) in by else "not run" for lv in (1, 2, 3)]
            lines.append(f"| {eta:g} | {tag} | {r0['stress_Pa']:.3g} | {r0['G']:.3g} | " + " | ".join(cells) + " |")
    TABLE.write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    if len(sys.argv) > 1 and sys.argv[1] == "run":
        run([float(v) for v in sys.argv[2:]] or sorted(RATES))
    elif len(sys.argv) > 3 and sys.argv[1] == "finer":
        eta, args = float(sys.argv[3]), [a for a in sys.argv[4:] if a not in ("--oblate", "--auto")]
        run_finer(int(sys.argv[2]), eta, [float(v) for v in args] or list(LEVEL2_RATES[eta]),
                  "oblate 0.9" if "--oblate" in sys.argv else "disk", area_auto="--auto" in sys.argv)
    else:
        report()

"""Red cells against measurement (issue 40): the tank-treading frequency of young red cells in
a 35 cP dextran solution measured by Tran-Son-Tay, Sutera & Rao, Biophys. J. 46 (1984) 65-72,
at their five shear rates, against capsim's cell with the membrane viscosity they infer
(campaigns/tran-son-tay-1984.yaml) and with none (campaigns/tran-son-tay-1984-elastic.yaml),
and the sensitivity of the computed frequency to the shear modulus, the membrane viscosity
(±30 %) and the mesh level at one shear rate.

The paper's numbers below are their Tables I-III as digitised in the public repository
github.com/slitvinov/uDeviceX, tools/tran_son_tay/data/tab1.txt, tab2.txt, tab3.txt (commit
50278c63500989a0a3757ac05defc6516f970aad), checked against the paper's own text (its scanned
copy tools/tran_son_tay/papers/tran-son-tay84.pdf at that commit). Young cells only (the
digitised tables hold the young fraction; the paper's old-cell columns are not used).

    python benchmarks/tran_son_tay.py run [GROUP ...]   # the runs (all groups but level3), resumable
    python benchmarks/tran_son_tay.py report            # table and figure

GROUP: main (their mu_s), elastic (none), sensitivity (mu_s x0.7, x1.3, G_s x2, level 1),
extra (mu_s x1.7, the same shape at their area), shape (their reduced volume, G_s x0.5),
hardening (Skalak C = 100 at every rate), soft (G_s 1.25 uN/m and C = 100 at every rate),
level3 (level 3 at 28.6 1/s: ~6 min; not run for the docs), stressfree (issue 55: the case with a
stress-free oblate spheroid of aspect 0.9, and a sphere, at 28.6, 57.1 and 171.4 1/s), fischer (issue 55:
the case in Fischer & Korzeniewski 2015's 28.9 mPa s at the six shear rates of their 225 cells,
benchmarks/data/fischer2015_ttf_eta28.9.csv, with the mean of Table III's μ_s), fischersoft (the same with
G_s 1.25 uN/m and C = 100), fischermu (the same with the μ_s fitted to Fischer's frequencies, issue 55),
fischerauto (fischermu with the membrane nearly area-incompressible: membrane.skalak_c auto),
twosided (issue 55: μ_s x0.7, x1.3, G_s x0.5, x2, the cytoplasm at 5 and
20 mPa s, at 28.6 and 171.4 1/s; their reduced volume at 171.4), fischerfit (Fischer's rates with the μ_s
and G_s fitted to Table I, benchmarks/fit_tran_son_tay_mu_s_g_s.json, level 1), outline (issue 55: the case
at every rate, their reduced volume, C = 100 and G_s 1.25 uN/m with C = 100 at 28.6 and 171.4 1/s, with
snapshots: the outline seen along the gradient and Table II's ellipsoid made from it). `make bench-tts`
runs every group but level3.

`run` appends each finished run to benchmarks/tran_son_tay.json (a run already there is not
repeated; one run at level 2 takes 1-3 min on one core); `report` writes
benchmarks/tran_son_tay.md (included by docs/validation.md), docs/figures/tran_son_tay.png and
docs/figures/fischer_2015_ttf.png.
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

import numpy as np  # noqa: E402 - after the thread counts above

from _common import save_figure, silhouette  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
JSON = ROOT / "benchmarks" / "tran_son_tay.json"
TABLE = ROOT / "benchmarks" / "tran_son_tay.md"
FIGURE = ROOT / "docs" / "figures" / "tran_son_tay.png"
FISCHER_FIGURE = ROOT / "docs" / "figures" / "fischer_2015_ttf.png"
CAMPAIGN = ROOT / "campaigns" / "tran-son-tay-1984.yaml"
ELASTIC = ROOT / "campaigns" / "tran-son-tay-1984-elastic.yaml"

# Table I, young cells (data/tab1.txt): shear rate (1/s); projected half-length a cos(theta)
# and half-width c (um, uncorrected: scaled by an 8.0 um reference diameter) with their
# standard deviations; tank-treading frequency f (rad/s) and its standard deviation (N = 30).
TABLE_I = [
    (28.6, 5.5, 0.5, 3.2, 0.2, 6.22, 0.31),
    (42.9, 5.9, 0.7, 3.0, 0.5, 9.42, 0.57),
    (57.1, 6.5, 0.8, 2.5, 0.3, 12.7, 0.57),
    (114.3, 7.3, 0.4, 2.3, 0.5, 24.6, 1.07),
    (171.4, 7.6, 0.4, 2.1, 0.3, 37.4, 1.45),
]
# Table II, young cells (data/tab2.txt): the ellipsoid's semi-axes a (long, in the shear
# plane), b (short, in the plane), c (along the vorticity) in um and its inclination theta in
# degrees, which they COMPUTED from Table I with Keller & Skalak's model (their eq. 10 for
# theta), the cells' area and volume assigned (S = 141 um^2, V = 111 um^3): not measured.
TABLE_II = [
    (28.6, 5.6, 1.5, 3.2, 12.8),
    (42.9, 6.0, 1.5, 3.0, 13.0),
    (57.1, 6.7, 1.6, 2.5, 13.2),
    (114.3, 7.1, 1.7, 2.2, 12.5),
    (171.4, 7.3, 1.9, 2.0, 12.7),
]
# Table III, young cells, cytoplasm 10 cP (data/tab3.txt): the surface-averaged membrane
# viscosity they infer, in 1e-4 dyn s/cm = 1e-7 N s/m.
TABLE_III_MU = [0.96, 0.72, 0.53, 0.53, 0.57]

RADIUS_UM = 2.98          # (3 V / 4 pi)^(1/3) for V = 111 um^3
SENSITIVITY_RATE = 28.6   # the shear rate of the sensitivity table and of tests/campaigns/test_tran_son_tay.py
MAIN_LEVEL = 2
#: the Evans-Fung coefficients times 1.3215: the sphericity of their young cells, 0.792
THICK = (0.2736, 2.647, -1.4841)
#: issue 55: the stress-free shapes tried (membrane.reference_shape) and at which of Table I's rates
STRESS_FREE_SHAPES = (("oblate 0.9", {"kind": "oblate", "aspect_ratio": 0.9}), ("sphere", {"kind": "sphere"}))
STRESS_FREE_RATES = (28.6, 57.1, 171.4)
#: issue 55: the membrane viscosity (N s/m) of the best point of the level-1 fit to Fischer & Korzeniewski 2015's
#: frequencies (fits/fit-fischer-2015-mu-s-g-s.yaml, G_s 2.5 uN/m; docs/validation.md says how it ended)
FISCHER_FIT_MU_S = 3.265452361e-07
#: Fischer & Korzeniewski 2015 (Biophys. J., Fig. S11): f/k of 225 cells in 28.9 mPa s (benchmarks/data/README.md)
FISCHER_DATA = ROOT / "benchmarks" / "data" / "fischer2015_ttf_eta28.9.csv"
FISCHER_VISCOSITY_MPAS = 28.9
#: issue 55: the sensitivity's second rate (the highest of Table I), and the changes made at both rates
TWO_SIDED_RATE = 171.4
TWO_SIDED_CHANGES = (
    ("mu_s x0.7", {"membrane_viscosity": lambda mu: f"{0.7 * mu:.4g} N*s/m"}),
    ("mu_s x1.3", {"membrane_viscosity": lambda mu: f"{1.3 * mu:.4g} N*s/m"}),
    ("G_s 1.25 uN/m", {"shear_modulus": "1.25 uN/m"}),
    ("G_s 5 uN/m", {"shear_modulus": "5 uN/m"}),
    ("cytoplasm 5 mPa s", {"inner_viscosity": "5 mPa*s"}),
    ("cytoplasm 20 mPa s", {"inner_viscosity": "20 mPa*s"}),
)
#: the changes the sensitivity group already ran at the lowest rate (same labels)
ALREADY_AT_LOW_RATE = ("mu_s x0.7", "mu_s x1.3", "G_s 1.25 uN/m", "G_s 5 uN/m")


def load_base(path: Path) -> tuple[dict, dict]:
    import yaml

    data = yaml.safe_load(path.read_text())
    return data["base"], data.get("zip") or {}


def case_dicts(path: Path) -> list[dict]:
    """The campaign's runs as case dicts (its zip lists, in order)."""
    base, zipped = load_base(path)
    n = len(next(iter(zipped.values())))
    out = []
    for i in range(n):
        d = json.loads(json.dumps(base))
        for key, values in zipped.items():
            node = d
            *head, last = key.split(".")
            for part in head:
                node = node.setdefault(part, {})
            node[last] = values[i]
        out.append(d)
    return out


def rate_of(case: dict) -> float:
    return float(str(case["physical"]["shear_rate"]).split()[0])


def ellipsoid_of_width(c: float, volume: float, area: float) -> tuple[float, float]:
    """Tran-Son-Tay et al.'s Table II ellipsoid: the semi-axes a ≥ b of the ellipsoid of semi-axis c
    (the measured half-width), the given volume and the given area (Knud Thomsen's area, p = 1.6,
    within ~1 %). Its a and b follow from c, V and S alone; their Table II is this of Table I's c
    with V = 111 µm³, S = 141 µm² (a/b within 3 % at 28.6-114.3 1/s; their θ comes from f, eq. 10)."""
    from scipy.optimize import brentq

    p = 1.6

    def thomsen(a: float, b: float) -> float:
        return 4 * math.pi * (((a * b) ** p + (b * c) ** p + (c * a) ** p) / 3) ** (1 / p)

    ab = 3 * volume / (4 * math.pi * c)
    b = brentq(lambda b: thomsen(ab / b, b) - area, 1e-6 * math.sqrt(ab), math.sqrt(ab))
    return ab / b, b


def run_one(case: dict, label: str, level: int | None = None, t_end: float | None = None,
            outline: bool = False) -> dict:
    """Run a case (dict) to its end and return the summary's numbers, with the frequency in rad/s;
    with ``outline`` also the cell's outline seen along the gradient (:func:`silhouette`, in µm, the
    mean over the snapshots, one per unit kt, in the summary's averaging window), its volume and area."""
    import numpy as np

    from capsim.config import case_from_dict
    from capsim.runs.runner import run_case
    from capsim.storage.store import read_trajectory

    case = json.loads(json.dumps(case))
    if level is not None:
        case["mesh"]["level"] = level
    if t_end is not None:
        case["time"]["t_end"] = t_end
    with tempfile.TemporaryDirectory() as tmp:
        case["name"] = "tts"
        case["output"] = {"path": f"{tmp}/tts.h5", "snapshot_every": 1.0 if outline else case["time"]["t_end"]}
        c = case_from_dict(case)
        result = run_case(c)
        if result.status != "completed":
            raise SystemExit(f"run {label} ended {result.status}: no row written")
        data = read_trajectory(c.output.path)
        ts = data["timeseries"]
    s = dict(result.summary)
    k = rate_of(case)
    t = np.asarray(ts["t"], float)
    sel = (t >= s["averaging_t_from"]) & (t <= s["averaging_t_to"])
    mean = {name: float(np.mean(np.asarray(ts[name], float)[sel])) for name in
            ("ellipsoid_a", "ellipsoid_b", "ellipsoid_c")}
    tt = np.asarray(ts["tt_angle"], float)
    half = t >= 0.5 * t[-1]
    row = {
        "label": label, "shear_rate": k, "level": c.mesh.level, "t_end": c.time.t_end,
        "G": c.flow.shear_rate_G, "viscosity_ratio": c.flow.viscosity_ratio,
        "Bq": (c.membrane.viscosity.shear if c.membrane.viscosity is not None else 0.0),
        "bending": c.membrane.bending_modulus,
        "shear_modulus": case["physical"]["shear_modulus"],
        "membrane_viscosity": case["physical"].get("membrane_viscosity", "0"),
        "motion": s["motion"], "settled": s.get("settled", float("nan")),
        "ttf_ratio": s["ttf_ratio"], "ttf_ratio_std": s["ttf_ratio_std"],
        "tank_treading_ratio": s.get("tank_treading_ratio", float("nan")),
        "body_rotation_ratio": s.get("body_rotation_ratio", float("nan")),
        "shape_period": s.get("shape_period", float("nan")),
        # whole revolutions of the tracked nodes in the second half: ttf_ratio counts them
        "revolutions_second_half": float(abs(tt[half][-1] - tt[half][0]) / (2 * math.pi)),
        "averaging": [s["averaging_t_from"], s["averaging_t_to"]],
        "D_xy": s["D_xy"], "theta_deg": math.degrees(s["theta"]),
        "axes_um": [mean[n] * RADIUS_UM for n in ("ellipsoid_a", "ellipsoid_b", "ellipsoid_c")],
        # the membrane's area at the end over its rest area, less 1 (Skalak C = 10 lets it grow)
        "area_change": result.area_change,
        "wall_time_s": result.wall_time_s,
    }
    row["f_rad_s"] = row["ttf_ratio"] * k / 2.0   # ttf_ratio = omega / (k/2)
    if outline:
        snap_t = np.asarray(data["snapshot_t"], float)
        pick = np.flatnonzero((snap_t >= s["averaging_t_from"]) & (snap_t <= s["averaging_t_to"]))
        extents = np.array([silhouette(np.asarray(data["positions"][i], float), np.asarray(data["elements"]))
                            for i in pick])
        row["outline_um"] = [float(x) * RADIUS_UM for x in extents.mean(axis=0)]
        row["outline_sd_um"] = [float(x) * RADIUS_UM for x in extents.std(axis=0)]
        row["outline_snapshots"] = int(pick.size)
        row["volume_um3"] = float(np.mean(np.asarray(ts["volume"], float)[sel])) * RADIUS_UM ** 3
        row["area_um2"] = float(np.mean(np.asarray(ts["area"], float)[sel])) * RADIUS_UM ** 2
    return row


def load_rows() -> dict:
    return json.loads(JSON.read_text()) if JSON.exists() else {}


def save_row(row: dict) -> None:
    rows = load_rows()
    rows[row["label"]] = row
    JSON.write_text(json.dumps(rows, indent=1, sort_keys=True) + "\n")


def jobs() -> dict[str, list[tuple[str, dict, dict]]]:
    main = case_dicts(CAMPAIGN)
    elastic = case_dicts(ELASTIC)
    out: dict[str, list] = {"main": [], "elastic": [], "sensitivity": [], "level3": []}
    for c in main:
        out["main"].append((f"viscous k={rate_of(c)} L{MAIN_LEVEL}", c, {}))
    for c in elastic:
        out["elastic"].append((f"elastic k={rate_of(c)} L{MAIN_LEVEL}", c, {}))
    base = next(c for c in main if rate_of(c) == SENSITIVITY_RATE)
    mu = float(base["physical"]["membrane_viscosity"].split()[0])

    def variant(**physical):
        d = json.loads(json.dumps(base))
        d["physical"].update(physical)
        return d

    out["sensitivity"] = [
        (f"sens mu_s x0.7 k={SENSITIVITY_RATE} L{MAIN_LEVEL}", variant(membrane_viscosity=f"{0.7 * mu:.4g} N*s/m"), {}),
        (f"sens mu_s x1.3 k={SENSITIVITY_RATE} L{MAIN_LEVEL}", variant(membrane_viscosity=f"{1.3 * mu:.4g} N*s/m"), {}),
        (f"sens G_s 5 uN/m k={SENSITIVITY_RATE} L{MAIN_LEVEL}", variant(shear_modulus="5 uN/m"), {}),
        (f"viscous k={SENSITIVITY_RATE} L1", base, {"level": 1}),
    ]
    out["extra"] = [
        # the paper's own estimate: an area-conserving membrane velocity field (Secomb & Skalak)
        # dissipates 60-70 % of the K-S field's, so their mu_s would be ~40-70 % greater
        (f"sens mu_s x1.7 k={SENSITIVITY_RATE} L{MAIN_LEVEL}", variant(membrane_viscosity=f"{1.7 * mu:.4g} N*s/m"), {}),
        # the cell of their area (141 um^2) instead of their volume: a = sqrt(0.746 S / 4 pi)
        (f"sens a 2.89 um k={SENSITIVITY_RATE} L{MAIN_LEVEL}", variant(radius="2.89 um"), {}),
    ]
    # their cells' reduced volume: the Evans-Fung thickness times 1.3215 (c0, c2, c4 scaled
    # alike) has sphericity 0.792 (level 3; 0.7927 at level 2) = (36 pi V^2)^(1/3)/S for
    # V = 111 um^3, S = 141 um^2: at a = 2.98 um its area is 141 um^2
    thick = variant()
    thick["shape"] = {"kind": "biconcave", "c0": THICK[0], "c2": THICK[1], "c4": THICK[2]}
    out["shape"] = [(f"sens thick k={SENSITIVITY_RATE} L{MAIN_LEVEL}", thick, {}),
                    (f"sens G_s 1.25 uN/m k={SENSITIVITY_RATE} L{MAIN_LEVEL}", variant(shear_modulus="1.25 uN/m"), {})]
    # a membrane nearer area-incompressible at the highest rate, where Skalak's C = 10 lets
    # the area grow 7 % (C = 100: K_s/G_s = 201)
    out["hardening"] = []
    for c in main:
        stiff = json.loads(json.dumps(c))
        stiff["membrane"]["skalak_c"] = 100.0
        out["hardening"].append((f"sens C 100 k={rate_of(stiff)} L{MAIN_LEVEL}", stiff, {}))
    # softer at small strain, nearly area-incompressible: G_s = 1.25 uN/m, C = 100
    out["soft"] = []
    for c in main:
        soft = json.loads(json.dumps(c))
        soft["membrane"]["skalak_c"] = 100.0
        soft["physical"]["shear_modulus"] = "1.25 uN/m"
        out["soft"].append((f"sens G_s 1.25 C 100 k={rate_of(soft)} L{MAIN_LEVEL}", soft, {}))
    out["level3"] = [(f"viscous k={SENSITIVITY_RATE} L3", base, {"level": 3})]
    # issue 55: which parameter moves the frequency at the lowest rate and not at the highest (the
    # measured f/k is flat, capsim's falls): the same changes at 28.6 and 171.4 1/s, the cytoplasm too
    out["twosided"] = []
    for c in main:
        if rate_of(c) not in (SENSITIVITY_RATE, TWO_SIDED_RATE):
            continue
        k, mu_k = rate_of(c), float(c["physical"]["membrane_viscosity"].split()[0])
        for tag, physical in TWO_SIDED_CHANGES:
            if rate_of(c) == SENSITIVITY_RATE and tag in ALREADY_AT_LOW_RATE:
                continue
            d = json.loads(json.dumps(c))
            d["physical"].update({key: (value(mu_k) if callable(value) else value) for key, value in physical.items()})
            out["twosided"].append((f"sens {tag} k={k} L{MAIN_LEVEL}", d, {}))
        if rate_of(c) == TWO_SIDED_RATE:  # their cells' reduced volume (group shape ran it at the lowest rate)
            d = json.loads(json.dumps(c))
            d["shape"] = {"kind": "biconcave", "c0": THICK[0], "c2": THICK[1], "c4": THICK[2]}
            out["twosided"].append((f"sens thick k={TWO_SIDED_RATE} L{MAIN_LEVEL}", d, {}))
    # issue 55: the stress-free shape (membrane.reference_shape) other than the cell's own disk
    out["stressfree"] = []
    for c in main:
        if rate_of(c) not in STRESS_FREE_RATES:
            continue
        for tag, reference in STRESS_FREE_SHAPES:
            d = json.loads(json.dumps(c))
            d["membrane"]["reference_shape"] = reference
            out["stressfree"].append((f"stress-free {tag} k={rate_of(c)} L{MAIN_LEVEL}", d, {}))
    # issue 55: Fischer & Korzeniewski 2015's cells at 28.9 mPa s, their six shear rates
    out["fischer"] = []
    for k, _, _, _ in fischer_groups():
        d = json.loads(json.dumps(base))
        d["physical"].update(shear_rate=f"{k:.4g} 1/s", viscosity=f"{FISCHER_VISCOSITY_MPAS} mPa*s",
                             membrane_viscosity=f"{sum(TABLE_III_MU) / len(TABLE_III_MU):.3g}e-7 N*s/m")
        out["fischer"].append((f"fischer k={k:.4g} L{MAIN_LEVEL}", d, {}))
    # the softer, nearly area-incompressible membrane that brings Table I within 25 % (group soft)
    out["fischersoft"] = []
    for label, d, opts in out["fischer"]:
        soft = json.loads(json.dumps(d))
        soft["membrane"]["skalak_c"] = 100.0
        soft["physical"]["shear_modulus"] = "1.25 uN/m"
        out["fischersoft"].append((label.replace("fischer ", "fischer G_s 1.25 C 100 "), soft, opts))
    # issue 55: the (μ_s, G_s) fitted to Tran-Son-Tay et al.'s five rates (fits/fit-tran-son-tay-mu-s-g-s.yaml,
    # benchmarks/fit_tran_son_tay_mu_s_g_s.json) at Fischer & Korzeniewski's rates, level 1 as the fit
    out["fischerfit"] = []
    fitted = json.loads((ROOT / "benchmarks" / "fit_tran_son_tay_mu_s_g_s.json").read_text())["estimates"]
    for label, d, opts in out["fischer"]:
        e = json.loads(json.dumps(d))
        e["physical"]["membrane_viscosity"] = f"{fitted['physical.membrane_viscosity']:.4g} N*s/m"
        e["physical"]["shear_modulus"] = f"{fitted['physical.shear_modulus']:.4g} uN/m"
        out["fischerfit"].append((label.replace("fischer ", "fischer TTS-fit ").replace(f"L{MAIN_LEVEL}", "L1"), e,
                                  {"level": 1}))
    # issue 55: Fischer & Korzeniewski's own parameter set: the smallest χ² of the level-1 fit to their six rate groups
    # (fits/fit-fischer-2015-mu-s-g-s.yaml; χ² 1.84, evaluation 2 of 5 before a run at 258 1/s stopped it
    # unstable), checked at level 2, where the lowest rate's motion is resolved (level 1 tumbles there)
    out["fischermu"] = []
    for label, d, opts in out["fischer"]:
        e = json.loads(json.dumps(d))
        e["physical"]["membrane_viscosity"] = f"{FISCHER_FIT_MU_S:.4g} N*s/m"
        out["fischermu"].append((label.replace("fischer ", "fischer mu_s 3.27e-7 "), e, opts))
    # the same set with the membrane nearly area-incompressible (membrane.skalak_c auto, the area within 2 %; C = 10's
    # grew 7-8 % at the highest rates): what holding the area does to the frequencies
    out["fischerauto"] = []
    for label, d, opts in out["fischermu"]:
        e = json.loads(json.dumps(d))
        e["membrane"]["skalak_c"] = "auto"
        out["fischerauto"].append((label.replace("fischer mu_s 3.27e-7 ", "fischer auto mu_s 3.27e-7 "), e, opts))
    # issue 55: the cell's outline seen along the gradient (Table I's measured a cos θ and c) and Table II's
    # ellipsoid made of it as they made theirs; the case at every rate, three changes at the two ends
    out["outline"] = [(label.replace("viscous ", "outline viscous "), d, {"outline": True}) for label, d, _ in out["main"]]
    for group, prefix in (("shape", "sens thick"), ("hardening", "sens C 100"), ("soft", "sens G_s 1.25 C 100"),
                          ("twosided", "sens thick")):
        for label, d, opts in out[group]:
            if label.startswith(prefix + " ") and rate_of(d) in (SENSITIVITY_RATE, TWO_SIDED_RATE):
                out["outline"].append(("outline " + label, d, {**opts, "outline": True}))
    return out


def fischer_groups() -> list[tuple[float, float, float, int]]:
    """Fischer & Korzeniewski 2015's 225 cells in their six groups of shear rate (k within a
    factor 1.3 of each other): (mean k in 1/s, mean f/k, its SD over the cells, the count); their
    f/k is the frequency in revolutions per second over k, so ω/k = 2π f/k (ω/k ≤ 1/2, the
    vorticity's, for any tank-treading cell; 4π f/k would pass it at their lowest rates)."""
    import numpy as np

    data = np.genfromtxt(FISCHER_DATA, delimiter=",", names=True)
    k, ratio = data["shear_rate_1_per_s"], data["ttf_over_shear_rate"]
    order = np.argsort(k)
    groups, start = [], 0
    for i in range(1, len(order) + 1):
        if i == len(order) or k[order[i]] > 1.3 * k[order[start]]:
            idx = order[start:i]
            groups.append((float(k[idx].mean()), float(ratio[idx].mean()), float(ratio[idx].std(ddof=1)), len(idx)))
            start = i
    return groups


def run(groups: list[str]) -> None:
    from capsim.numerics.threads import apply_policy

    apply_policy(1)
    done = load_rows()
    todo = jobs()
    for group in groups:
        for label, case, opts in todo[group]:
            if label in done:
                continue
            row = run_one(case, label, **opts)
            save_row(row)
            print(f"{label}: f = {row['f_rad_s']:.2f} rad/s, ttf_ratio {row['ttf_ratio']:.4f}, "
                  f"{row['motion']}, settled {row['settled']}, {row['wall_time_s']:.0f} s", flush=True)


def _fmt(x: float, digits: int = 3) -> str:
    return "—" if x is None or not math.isfinite(x) else f"{x:.{digits}g}"


def report() -> None:
    rows = load_rows()
    lines = [
        "| k (1/s) | μ_s (1e-7 N s/m) | G | Bq_s | f measured (rad/s) | f capsim, their μ_s | error | "
        "f capsim, μ_s = 0 | error | motion (their μ_s) | revolutions averaged |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for (k, _, _, _, _, f, sd), mu in zip(TABLE_I, TABLE_III_MU):
        v = rows.get(f"viscous k={k} L{MAIN_LEVEL}")
        e = rows.get(f"elastic k={k} L{MAIN_LEVEL}")
        cells = [f"{k:g}", f"{mu:.2f}", _fmt(v["G"]) if v else "—", _fmt(v["Bq"]) if v else "—",
                 f"{f:.3g} ± {sd:.2g}"]
        for r in (v, e):
            if r is None:
                cells += ["not run", "—"]
            else:
                cells += [f"{r['f_rad_s']:.3g}", f"{100 * (r['f_rad_s'] / f - 1):+.0f} %"]
        cells += [f"{v['motion']}{'' if v['settled'] == 1 else ' (not settled)'}" if v else "—",
                  f"{math.floor(v['revolutions_second_half'])}" if v else "—"]
        lines.append("| " + " | ".join(cells) + " |")
    lines += ["", "The membrane law at every rate, their μ_s (f in rad/s, error against the measured f):", "",
              "| k (1/s) | f measured | G_s 2.5 µN/m, C = 10 (the case) | G_s 2.5 µN/m, C = 100 | "
              "G_s 1.25 µN/m, C = 100 |", "|---|---|---|---|---|"]
    for (k, _, _, _, _, f, sd) in TABLE_I:
        cells = [f"{k:g}", f"{f:.3g} ± {sd:.2g}"]
        for label in (f"viscous k={k} L{MAIN_LEVEL}", f"sens C 100 k={k} L{MAIN_LEVEL}",
                      f"sens G_s 1.25 C 100 k={k} L{MAIN_LEVEL}"):
            r = rows.get(label)
            cells.append("not run" if r is None else f"{r['f_rad_s']:.3g} ({100 * (r['f_rad_s'] / f - 1):+.0f} %)")
        lines.append("| " + " | ".join(cells) + " |")
    lines += ["", "Shape with their μ_s: capsim's equal-moment ellipsoid (semi-axes in µm: a long, c along the "
              "vorticity, b short; θ the long axis's inclination) against Table I (measured: the projected "
              "half-length a cos θ and half-width c seen along the shear gradient, lengths scaled by a reference "
              "diameter of 8.0 µm, mean ± SD) and Table II (computed by them from Table I with Keller & Skalak's "
              "ellipsoid model, area 141 µm² and volume 111 µm³ assigned, θ from the measured f: not measured); "
              "the membrane's area change at the end (Skalak, C = 10):", "",
              "| k (1/s) | a cos θ: capsim / Table I | c: capsim / Table I | a: capsim / Table II | "
              "b: capsim / Table II | θ (deg): capsim / Table II | area change |", "|---|---|---|---|---|---|---|"]
    for (k, lp, lp_sd, w, w_sd, _, _), (_, a, b, c, th) in zip(TABLE_I, TABLE_II):
        v = rows.get(f"viscous k={k} L{MAIN_LEVEL}")
        if v is None:
            continue
        A, M, S = v["axes_um"]
        proj = A * math.cos(math.radians(v["theta_deg"]))
        area = f"{100 * v['area_change']:+.1f} %" if v.get("area_change") is not None else "—"
        lines.append(f"| {k:g} | {proj:.2f} / {lp} ± {lp_sd} | {M:.2f} / {w} ± {w_sd} | {A:.2f} / {a} | "
                     f"{S:.2f} / {b} | {v['theta_deg']:.1f} / {th} | {area} |")
    base = rows.get(f"viscous k={SENSITIVITY_RATE} L{MAIN_LEVEL}")
    f_meas = next(r[5] for r in TABLE_I if r[0] == SENSITIVITY_RATE)
    lines += ["", f"Sensitivity at k = {SENSITIVITY_RATE} 1/s (measured f = {f_meas} rad/s):", "",
              "| change from the case | f capsim (rad/s) | against the case | against measured | motion |",
              "|---|---|---|---|---|"]
    sens = [("the case (level 2, G_s 2.5 µN/m, their μ_s)", base),
            ("μ_s × 0.7", rows.get(f"sens mu_s x0.7 k={SENSITIVITY_RATE} L{MAIN_LEVEL}")),
            ("μ_s × 1.3", rows.get(f"sens mu_s x1.3 k={SENSITIVITY_RATE} L{MAIN_LEVEL}")),
            ("μ_s = 0", rows.get(f"elastic k={SENSITIVITY_RATE} L{MAIN_LEVEL}")),
            ("μ_s × 1.7 (their area-conserving estimate: up to +70 %)",
             rows.get(f"sens mu_s x1.7 k={SENSITIVITY_RATE} L{MAIN_LEVEL}")),
            ("G_s = 1.25 µN/m (× 0.5)", rows.get(f"sens G_s 1.25 uN/m k={SENSITIVITY_RATE} L{MAIN_LEVEL}")),
            ("G_s = 5 µN/m (× 2)", rows.get(f"sens G_s 5 uN/m k={SENSITIVITY_RATE} L{MAIN_LEVEL}")),
            ("the same shape at their area: a = 2.89 µm (area 141 µm², volume 101 µm³)",
             rows.get(f"sens a 2.89 um k={SENSITIVITY_RATE} L{MAIN_LEVEL}")),
            ("their reduced volume: Evans–Fung thickness × 1.32 (sphericity 0.792, area 141 µm²)",
             rows.get(f"sens thick k={SENSITIVITY_RATE} L{MAIN_LEVEL}")),
            ("mesh level 1", rows.get(f"viscous k={SENSITIVITY_RATE} L1")),
            ("mesh level 3 (not run: about 6 min a run on the shared machine)",
             rows.get(f"viscous k={SENSITIVITY_RATE} L3"))]
    for name, r in sens:
        if r is None:
            lines.append(f"| {name} | not run | — | — | — |")
            continue
        rel = f"{100 * (r['f_rad_s'] / base['f_rad_s'] - 1):+.1f} %" if base else "—"
        lines.append(f"| {name} | {r['f_rad_s']:.3g} | {rel} | {100 * (r['f_rad_s'] / f_meas - 1):+.0f} % | "
                     f"{r['motion']} |")
    lines += two_sided_lines(rows) + outline_lines(rows) + stress_free_lines(rows) + fischer_lines(rows)
    TABLE.write_text("\n".join(lines) + "\n")
    figure(rows)


def two_sided_lines(rows: dict) -> list[str]:
    """Issue 55: each change at the lowest and the highest of Table I's rates, and what it does to the
    ratio of the two frequencies (measured 6.01, the rates' ratio 5.99: f proportional to k) and to the
    measured shape (Table I's a cos θ and c)."""
    lo, hi = SENSITIVITY_RATE, TWO_SIDED_RATE
    meas = {r[0]: r for r in TABLE_I}
    table2 = {r[0]: r for r in TABLE_II}
    changes = [("the case (G_s 2.5 µN/m, C = 10, their μ_s, cytoplasm 10 mPa s, the disk)", "viscous"),
               ("μ_s × 0.7", "sens mu_s x0.7"), ("μ_s × 1.3", "sens mu_s x1.3"), ("μ_s = 0", "elastic"),
               ("G_s × 0.5 (1.25 µN/m)", "sens G_s 1.25 uN/m"), ("G_s × 2 (5 µN/m)", "sens G_s 5 uN/m"),
               ("cytoplasm 5 mPa s (λ 0.14)", "sens cytoplasm 5 mPa s"),
               ("cytoplasm 20 mPa s (λ 0.57)", "sens cytoplasm 20 mPa s"),
               ("Skalak C = 100", "sens C 100"), ("G_s × 0.5 and C = 100", "sens G_s 1.25 C 100"),
               ("their reduced volume (sphericity 0.792)", "sens thick"),
               *((f"stress-free {t}", f"stress-free {t}") for t, _ in STRESS_FREE_SHAPES)]
    base = {k: rows.get(f"viscous k={k} L{MAIN_LEVEL}") for k in (lo, hi)}
    lines = ["", f"What moves what, at the lowest and the highest rate ({lo:g} and {hi:g} 1/s; level {MAIN_LEVEL}): the "
             "frequency against the case's, the ratio of the two frequencies (measured "
             f"{meas[hi][5] / meas[lo][5]:.2f}: the rates' ratio is {hi / lo:.2f}, f proportional to k), the "
             "measured shape, Table I's projected half-length a cos θ and half-width c (µm), and the ellipsoid's a/b "
             "against Table II's (computed by them from Table I with their cells' area and volume assigned):", "",
             f"| change | f at {lo:g}: rad/s (against the case) | f at {hi:g} | f({hi:g}) / f({lo:g}) | "
             f"a cos θ at {lo:g} / {hi:g} | c at {lo:g} / {hi:g} | θ (deg) at {lo:g} / {hi:g} | a/b at {lo:g} / {hi:g} |",
             "|---|---|---|---|---|---|---|---|",
             f"| measured (Tables I, II) | {meas[lo][5]:.3g} | {meas[hi][5]:.3g} | {meas[hi][5] / meas[lo][5]:.2f} | "
             f"{meas[lo][1]} / {meas[hi][1]} | {meas[lo][3]} / {meas[hi][3]} | 12.8 / 12.7 (computed) | "
             f"{table2[lo][1] / table2[lo][2]:.2f} / {table2[hi][1] / table2[hi][2]:.2f} (computed) |"]
    for name, prefix in changes:
        r = {k: rows.get(f"{prefix} k={k} L{MAIN_LEVEL}") for k in (lo, hi)}
        if any(v is None for v in r.values()):
            lines.append(f"| {name} | not run | — | — | — | — | — | — |")
            continue
        f = {k: r[k]["f_rad_s"] for k in (lo, hi)}
        rel = {k: "" if prefix == "viscous" else f" ({100 * (f[k] / base[k]['f_rad_s'] - 1):+.1f} %)" for k in (lo, hi)}
        proj = {k: r[k]["axes_um"][0] * math.cos(math.radians(r[k]["theta_deg"])) for k in (lo, hi)}
        lines.append(f"| {name} | {f[lo]:.3g}{rel[lo]} | {f[hi]:.3g}{rel[hi]} | {f[hi] / f[lo]:.2f} | "
                     f"{proj[lo]:.2f} / {proj[hi]:.2f} | {r[lo]['axes_um'][1]:.2f} / {r[hi]['axes_um'][1]:.2f} | "
                     f"{r[lo]['theta_deg']:.1f} / {r[hi]['theta_deg']:.1f} | "
                     f"{r[lo]['axes_um'][0] / r[lo]['axes_um'][2]:.2f} / {r[hi]['axes_um'][0] / r[hi]['axes_um'][2]:.2f} |")
    return lines


#: Table II's assigned cell (Tran-Son-Tay et al., after Nash & Wyard 1980): volume (µm³) and area (µm²)
TABLE_II_VOLUME, TABLE_II_AREA = 111.0, 141.0


def outline_lines(rows: dict) -> list[str]:
    """Issue 55: the cell as the rheoscope sees it (its outline along the gradient: Table I's measured
    a cos θ and c) and Table II's ellipsoid made of it as they made theirs (:func:`ellipsoid_of_width`
    with their V and S), or with the cell's own volume and area."""
    meas = {r[0]: r for r in TABLE_I}
    table2 = {r[0]: r for r in TABLE_II}
    lines = ["", "The outline seen along the gradient (as in the rheoscope; mean over the snapshots of the averaging "
             "window, one a unit kt) against Table I's measured projected half-length a cos θ and half-width c (µm, "
             "mean ± SD), and Table II's a/b made from it as they made theirs: the ellipsoid of that half-width c with "
             f"their assigned volume {TABLE_II_VOLUME:g} µm³ and area {TABLE_II_AREA:g} µm² (Table II's own a/b is this "
             "of Table I's c within 3 % at 28.6–114.3 1/s), or with the cell's own volume and area "
             "(what capsim's equal-moment ellipsoid gives):", "",
             "| run | k (1/s) | half-length: capsim / Table I | half-width c: capsim / Table I | "
             "a/b, their V and S: capsim / Table II | a/b, the cell's own V and S (area µm²) | "
             "equal-moment a/b |", "|---|---|---|---|---|---|---|"]
    for tag, prefix in (("the case", "outline viscous"), ("their reduced volume", "outline sens thick"),
                        ("C = 100", "outline sens C 100"), ("G_s 1.25 µN/m, C = 100", "outline sens G_s 1.25 C 100")):
        for k, *_ in TABLE_I:
            r = rows.get(f"{prefix} k={k} L{MAIN_LEVEL}")
            if r is None:
                continue
            half_length, half_width = r["outline_um"]
            a, b = ellipsoid_of_width(half_width, TABLE_II_VOLUME, TABLE_II_AREA)
            own_a, own_b = ellipsoid_of_width(half_width, r["volume_um3"], r["area_um2"])
            ab2 = table2[k][1] / table2[k][2]
            lines.append(f"| {tag} | {k:g} | {half_length:.2f} / {meas[k][1]} ± {meas[k][2]} | "
                         f"{half_width:.2f} / {meas[k][3]} ± {meas[k][4]} | {a / b:.2f} / {ab2:.2f} "
                         f"({100 * (a / b / ab2 - 1):+.0f} %) | {own_a / own_b:.2f} ({r['area_um2']:.0f}) | "
                         f"{r['axes_um'][0] / r['axes_um'][2]:.2f} |")
    return lines


def stress_free_lines(rows: dict) -> list[str]:
    """Issue 55: the frequency and the shape with another stress-free shape, against Tables I and II."""
    lines = ["", "The stress-free shape (`membrane.reference_shape`; the case's is the cell's own disk): f (rad/s) "
             "and the ellipsoid's a, b (µm) and θ (deg) against Table I's f and Table II's a, b, θ (their μ_s):", "",
             "| k (1/s) | stress-free shape | f capsim / measured | a: capsim / Table II | b: capsim / Table II | "
             "θ: capsim / Table II | motion |", "|---|---|---|---|---|---|---|"]
    for (k, _, _, _, _, f, sd), (_, a, b, c, th) in zip(TABLE_I, TABLE_II):
        if k not in STRESS_FREE_RATES:
            continue
        for tag, label in (("the disk (the case)", f"viscous k={k} L{MAIN_LEVEL}"),
                           *((t, f"stress-free {t} k={k} L{MAIN_LEVEL}") for t, _ in STRESS_FREE_SHAPES)):
            r = rows.get(label)
            if r is None:
                lines.append(f"| {k:g} | {tag} | not run | — | — | — | — |")
                continue
            A, _, S = r["axes_um"]
            lines.append(f"| {k:g} | {tag} | {r['f_rad_s']:.3g} / {f:.3g} ({100 * (r['f_rad_s'] / f - 1):+.0f} %) | "
                         f"{A:.2f} / {a} | {S:.2f} / {b} | {r['theta_deg']:.1f} / {th} | {r['motion']} |")
    return lines


def fischer_lines(rows: dict) -> list[str]:
    """Issue 55: Fischer & Korzeniewski 2015's frequencies against the rate (28.9 mPa s)."""
    lines = ["", f"Fischer & Korzeniewski (2015), {FISCHER_VISCOSITY_MPAS} mPa s, the case's cell (G_s 2.5 µN/m, "
             "C = 10, cytoplasm 10 mPa s as in the case, μ_s the mean of Table III, 0.66e-7 N s/m): ω/k, the "
             "membrane's angular frequency over the shear rate (theirs: 2π × their f/k, mean ± SD over the cells "
             "of each group of rates):", "",
             "| k (1/s) | cells | ω/k measured | ω/k capsim | error | G | motion | ω/k capsim, G_s 1.25 µN/m, C = 100 | "
             "error | ω/k capsim, Tran-Son-Tay's fitted μ_s and G_s (level 1) | error | "
             f"ω/k capsim, μ_s {FISCHER_FIT_MU_S:.3g} N s/m fitted to these (G_s 2.5 µN/m) | error | motion | "
             "the same, skalak_c auto (the area within 2 %) | error | motion |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for k, ratio, sd, n in fischer_groups():
        measured = 2 * math.pi * ratio
        r = rows.get(f"fischer k={k:.4g} L{MAIN_LEVEL}")
        soft = rows.get(f"fischer G_s 1.25 C 100 k={k:.4g} L{MAIN_LEVEL}")
        cells = [f"{k:.3g}", f"{n}", f"{measured:.3f} ± {2 * math.pi * sd:.3f}"]
        cells += (["not run", "—", "—", "—"] if r is None else
                  [f"{r['f_rad_s'] / k:.3f}", f"{100 * (r['f_rad_s'] / k / measured - 1):+.0f} %", f"{r['G']:.3g}",
                   r["motion"]])
        cells += (["not run", "—"] if soft is None else
                  [f"{soft['f_rad_s'] / k:.3f}", f"{100 * (soft['f_rad_s'] / k / measured - 1):+.0f} %"])
        fitted = rows.get(f"fischer TTS-fit k={k:.4g} L1")
        turning = fitted is not None and fitted["motion"] not in ("swinging", "steady", "transient")
        cells += (["not run", "—"] if fitted is None else
                  [f"{fitted['f_rad_s'] / k:.3f}" + (f" ({fitted['motion']}: the body's turn)" if turning else ""),
                   "—" if turning else f"{100 * (fitted['f_rad_s'] / k / measured - 1):+.0f} %"])
        for tag in ("fischer mu_s 3.27e-7", "fischer auto mu_s 3.27e-7"):
            own = rows.get(f"{tag} k={k:.4g} L{MAIN_LEVEL}")
            cells += (["not run", "—", "—"] if own is None else
                      [f"{own['f_rad_s'] / k:.3f}", f"{100 * (own['f_rad_s'] / k / measured - 1):+.0f} %",
                       own["motion"] + ("" if own["settled"] == 1 else " (not settled)")])
        lines.append("| " + " | ".join(cells) + " |")
    return lines


def figure(rows: dict) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    k = [r[0] for r in TABLE_I]
    fig, ax = plt.subplots(figsize=(5.2, 3.8))
    f = [r[5] for r in TABLE_I]
    ax.fill_between(k, [0.75 * x for x in f], [1.25 * x for x in f], color="0.85", lw=0,
                    label="measured ± 25 % (the issue's criterion)")
    ax.errorbar(k, [r[5] for r in TABLE_I], yerr=[r[6] for r in TABLE_I], fmt="ko", capsize=3,
                label="measured, young cells (Tran-Son-Tay et al. 1984, mean ± SD)")
    for kind, style, name in (("viscous", "s-", "capsim, their membrane viscosity"),
                              ("sens C 100", "d:", "capsim, their membrane viscosity, Skalak C = 100"),
                              ("sens G_s 1.25 C 100", "v-.", "capsim, their membrane viscosity, C = 100, G_s/2"),
                              ("elastic", "^--", "capsim, no membrane viscosity")):
        pts = [(r[0], rows[f"{kind} k={r[0]} L{MAIN_LEVEL}"]["f_rad_s"]) for r in TABLE_I
               if f"{kind} k={r[0]} L{MAIN_LEVEL}" in rows]
        if pts:
            ax.plot(*zip(*pts), style, mfc="none", label=name)
    ax.set_xlabel("shear rate k (1/s)")
    ax.set_ylabel("tank-treading frequency f (rad/s)")
    ax.set_xlim(0, 185)
    ax.set_ylim(0, 64)  # room for the legend above the curves
    ax.legend(fontsize=6.5, loc="upper left")
    ax.set_title("Red cells in 35 cP dextran, λ = 0.29 (level 2)", fontsize=9)
    save_figure(fig, FIGURE)
    fischer_figure(rows)


def fischer_figure(rows: dict) -> None:
    """Issue 55: Fischer & Korzeniewski 2015's ω/k against the rate, with capsim's sets (the Fischer table)."""
    import matplotlib.pyplot as plt

    groups = fischer_groups()
    k = [g[0] for g in groups]
    fig, ax = plt.subplots(figsize=(5.2, 3.8))
    measured = [2 * math.pi * g[1] for g in groups]
    ax.fill_between(k, [0.85 * x for x in measured], [1.15 * x for x in measured], color="0.85", lw=0,
                    label="measured ± 15 % (the issue's criterion)")
    ax.errorbar(k, measured, yerr=[2 * math.pi * g[2] for g in groups], fmt="ko", capsize=3,
                label="measured (Fischer & Korzeniewski 2015, mean ± SD of the cells)")
    for prefix, level, style, name in (
            ("fischer", MAIN_LEVEL, "s-", "capsim, G_s 2.5 µN/m, Tran-Son-Tay's mean μ_s 0.66e-7 N s/m"),
            ("fischer G_s 1.25 C 100", MAIN_LEVEL, "v-.", "capsim, G_s 1.25 µN/m, C = 100, μ_s 0.66e-7"),
            ("fischer mu_s 3.27e-7", MAIN_LEVEL, "D-", f"capsim, G_s 2.5 µN/m, μ_s {FISCHER_FIT_MU_S:.3g} (fitted here)"),
            ("fischer TTS-fit", 1, "^--", "capsim, μ_s and G_s fitted to Tran-Son-Tay (level 1)")):
        pts = [(g[0], rows[key]["f_rad_s"] / g[0], rows[key]["motion"]) for g in groups
               if (key := f"{prefix} k={g[0]:.4g} L{level}") in rows]
        if not pts:
            continue
        line, = ax.plot([p[0] for p in pts], [p[1] for p in pts], style, mfc="none", label=name)
        turning = [(x, y) for x, y, motion in pts if motion not in ("swinging", "steady", "transient")]
        if turning:
            ax.plot(*zip(*turning), "x", color=line.get_color(), ms=9, label="… tumbling there (no tank-treading)")
    ax.set_xscale("log")
    ax.set_xlabel("shear rate k (1/s)")
    ax.set_ylabel("ω/k (membrane's angular frequency / shear rate)")
    ax.set_ylim(0.1, 0.5)  # room for the legend above the points
    ax.legend(fontsize=6.2, loc="upper right")
    ax.set_title(f"Red cells in {FISCHER_VISCOSITY_MPAS} mPa s (level 2 unless marked)", fontsize=9)
    save_figure(fig, FISCHER_FIGURE)


if __name__ == "__main__":
    if len(sys.argv) >= 2 and sys.argv[1] == "run":
        run(sys.argv[2:] or ["main", "elastic", "sensitivity", "extra", "shape", "hardening", "soft", "stressfree",
                             "fischer", "fischersoft", "twosided", "fischerfit", "outline", "fischermu",
                             "fischerauto"])
    elif len(sys.argv) == 2 and sys.argv[1] == "report":
        report()
    else:
        raise SystemExit(__doc__)

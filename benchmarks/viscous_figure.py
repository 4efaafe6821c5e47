"""The sphere over Bq_s (issue 28): D_xy, θ and the tank-treading frequency against the
membrane's Boussinesq number at λ = 1 and 5, capsim beside the first-order theory
(capsim.scene.small_deformation). The runs are campaigns/viscous-membrane-sphere.yaml at level 2
with a weak bending modulus (κ = 1e-4, against the low-G creep; docs/viscous_membrane.md),
each ended 8 slow relaxation times after the start.

    python benchmarks/viscous_figure.py      # docs/figures/viscous-membrane-sphere.{png,json} (~2 min)
"""

from __future__ import annotations

import json
import os
import tempfile
from pathlib import Path

for _name in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_name, "1")

from capsim.numerics.threads import apply_policy  # noqa: E402

apply_policy(1)

import numpy as np  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
G, KAPPA, LEVEL = 0.01, 1e-4, 2
BQ = (0.0, 1.0, 3.0, 10.0, 30.0)
LAMBDAS = (1.0, 5.0)


def run(lam: float, bq: float) -> dict:
    from capsim.config import case_from_dict
    from _common import run_or_stop
    from capsim.scene.small_deformation import LinearCapsule
    from capsim.storage.store import read_trajectory

    t_end = 8.0 * LinearCapsule.from_G(G, viscosity_ratio=lam, Bq_shear=bq).relaxation_times()[0]
    with tempfile.TemporaryDirectory() as tmp:
        case = case_from_dict({
            "name": "v", "mesh": {"level": LEVEL}, "flow": {"shear_rate_G": G, "viscosity_ratio": lam},
            "membrane": {"viscosity": {"shear": bq}, "bending_modulus": KAPPA},
            "time": {"t_end": t_end, "scheme": "rkc", "rtol": 1e-5},
            "output": {"path": f"{tmp}/v.h5", "snapshot_every": t_end}})
        run_or_stop(case)
        ts = read_trajectory(case.output.path)["timeseries"]
        return {"lam": lam, "Bq": bq, "D_xy": float(ts["D_xy"][-1]), "theta": float(ts["theta"][-1]),
                "ttf_ratio": float(ts["ttf_ratio"][-1]), "Sxy_star": float(ts["Sxy_star"][-1])}


def main() -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from capsim.scene.small_deformation import LinearCapsule

    rows = [run(lam, bq) for lam in LAMBDAS for bq in BQ]
    out = ROOT / "docs" / "figures" / "viscous-membrane-sphere"
    out.with_suffix(".json").write_text(json.dumps({"G": G, "level": LEVEL, "bending_modulus": KAPPA, "rows": rows},
                                                   indent=1))
    grid = np.linspace(0.0, 32.0, 161)
    fig, axes = plt.subplots(1, 3, figsize=(12, 3.6))
    for lam, colour in zip(LAMBDAS, ("C0", "C1")):
        theory = [LinearCapsule.from_G(G, viscosity_ratio=lam, Bq_shear=b).steady_shear() for b in grid]
        mine = [r for r in rows if r["lam"] == lam]
        bq = [r["Bq"] for r in mine]
        axes[0].plot(grid, [d / G for d, _ in theory], color=colour, label=f"first order, λ = {lam:g}")
        axes[0].plot(bq, [r["D_xy"] / G for r in mine], "o", color=colour, label=f"capsim, λ = {lam:g}")
        axes[1].plot(grid, [np.degrees(t) for _, t in theory], color=colour)
        axes[1].plot(bq, [np.degrees(r["theta"]) for r in mine], "o", color=colour)
        axes[2].axhline(1.0, color="grey", lw=0.8)
        axes[2].plot(bq, [r["ttf_ratio"] for r in mine], "o-", color=colour)
    axes[0].set_ylabel("D_xy / G")
    axes[1].set_ylabel("θ (degrees)")
    axes[2].set_ylabel("TTF / f_s (first order: 1)")
    for ax in axes:
        ax.set_xlabel("Bq_s = μ_s / (μ a)")
    axes[0].legend(fontsize=7)
    fig.suptitle(f"sphere, thin shell, G = {G:g}, level {LEVEL}, κ = {KAPPA:g}: steady shear against membrane viscosity")
    fig.tight_layout()
    fig.savefig(out.with_suffix(".png"), dpi=110)
    for r in rows:
        print(r)


if __name__ == "__main__":
    main()

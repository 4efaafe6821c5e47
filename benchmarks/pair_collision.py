"""Two capsules colliding in simple shear (issue 43) against Lac, Morel & Barthès-Biesel,
J. Fluid Mech. 573 (2007) 149-169: two neo-Hookean capsules, λ = 1, pre-inflated 5 %
(shape.inflation 0.05), starting 8 a apart along the flow and 0.5 a across it, at their
Ca = μ k a / G_s = 0.45. capsim's G = μ k a / E_s with E_s = 3 G_s for every elastic law
(capsim.units.SHEAR_OVER_ELASTIC_MODULUS), so Ca 0.45 is G = 0.15; G = 0.45 (Ca read as
μ k a / E_s) is run beside it to show which reading their curve is.

Their figure 4(b), the cross-stream separation against the streamwise one, as digitised in
the public repository github.com/comphy-lab/basilisk-C (a mirror of the Basilisk wiki),
basilisk-wiki/sandbox/huet/tests/lagrangian_caps/data/caps_interception/lac_fig4b.csv (commit
96c53ce7610255a9a74006b7a8bb3b31a6134332; D. Huet's test case caps_interception.c plots it as
"Lac et al. (2007)" in units of 2a): LAC_FIG4B below, in units of a.

    python benchmarks/pair_collision.py            # the runs (levels 2 and 3), table and figure

writes benchmarks/pair_collision.md (included by docs/validation.md), benchmarks/pair_collision.json
and docs/figures/pair_collision.png (the trajectories, and the final offset against the initial
one of campaigns/pair-collision.yaml when its runs are in runs/pair-collision: `capsim sweep
campaigns/pair-collision.yaml` first). Level 2: ~2 s a run; level 3: ~10 s.
"""

from __future__ import annotations

import json
import os
import sys
import tempfile
from pathlib import Path

for _name in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_name, "1")

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
MD, JSON = ROOT / "benchmarks" / "pair_collision.md", ROOT / "benchmarks" / "pair_collision.json"
FIGURE = ROOT / "docs" / "figures" / "pair_collision.png"

#: Lac et al. (2007), fig. 4(b), Ca = 0.45: (separation_x, separation_y) in units of a (the
#: digitisation's Δx1/2a, Δx2/2a times 2; source in the module docstring)
LAC_FIG4B = np.array([
    (-7.98195, 0.50403), (-6.03308, 0.49597), (-4.40902, 0.48790), (-2.85714, 0.50403),
    (-1.81053, 0.66532), (-1.01654, 0.96371), (-0.22256, 1.25000), (0.86015, 1.43952),
    (2.10526, 1.36694), (3.09774, 1.22581), (4.25263, 1.14113), (5.84060, 1.10887),
    (7.28421, 1.09274), (8.58346, 1.09274), (9.88271, 1.09274), (11.36241, 1.09274),
])
#: the digitisation's own resolution: its start, 0.504 a, against the paper's 0.5 a
DIGITISATION = 0.004


def lac_case(path: str, G: float = 0.15, level: int = 2, t_end: float = 30.0) -> dict:
    """The collision of LAC_FIG4B as a capsim case (capsule 1 less capsule 0 starts at (−8, 0.5, 0))."""
    return {"name": Path(path).stem, "membrane": {"law": "neo_hookean"}, "shape": {"inflation": 0.05},
            "flow": {"shear_rate_G": G}, "mesh": {"level": level}, "time": {"t_end": t_end, "rtol": 1e-3},
            "capsules": [{"center": [4.0, -0.25, 0.0]}, {"center": [-4.0, 0.25, 0.0]}],
            "output": {"path": path, "snapshot_every": 5.0}}


def trajectory(path: str | Path) -> tuple[np.ndarray, np.ndarray]:
    import h5py

    with h5py.File(path, "r") as f:
        return f["timeseries/separation_x"][()], f["timeseries/separation_y"][()]


def compare(path: str | Path) -> dict:
    """The run's separation_y at the digitised separation_x (interpolated) against the figure's:
    the largest and rms deviation, the peak and the plateau (the last digitised point)."""
    sx, sy = trajectory(path)
    at = np.interp(LAC_FIG4B[:, 0], sx, sy)
    deviation = at - LAC_FIG4B[:, 1]
    k = int(np.argmax(sy))
    return {"max_deviation": float(np.abs(deviation).max()), "rms_deviation": float(np.sqrt(np.mean(deviation**2))),
            "peak": float(sy[k]), "peak_at": float(sx[k]), "plateau": float(at[-1]),
            "figure_peak": float(LAC_FIG4B[:, 1].max()), "figure_plateau": float(LAC_FIG4B[-1, 1])}


def _campaign_points(directory: Path) -> dict[float, list[tuple[float, float]]]:
    """{G: [(initial offset, final offset)]} of the campaign's completed runs."""
    from capsim.campaigns.summary import read_run

    out: dict[float, list[tuple[float, float]]] = {}
    for path in sorted(directory.glob("*.h5")):
        record = read_run(path)
        if record is None or record["status"] != "completed":
            continue
        import yaml

        import h5py

        with h5py.File(path, "r") as f:
            G = float(yaml.safe_load(f.attrs["config_yaml"])["flow"]["shear_rate_G"])
        out.setdefault(G, []).append((record["separation_y_initial"], record["separation_y_final"]))
    return {G: sorted(v) for G, v in sorted(out.items())}


def main() -> None:
    from capsim.config import case_from_dict
    from capsim.runs.runner import run_case

    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        paths = {}
        for label, G, level in (("G 0.15 (Ca 0.45 on G_s), level 2", 0.15, 2),
                                ("G 0.15 (Ca 0.45 on G_s), level 3", 0.15, 3),
                                ("G 0.45 (Ca 0.45 read on E_s), level 2", 0.45, 2)):
            path = str(Path(tmp) / f"lac_{G}_{level}.h5")
            result = run_case(case_from_dict(lac_case(path, G, level)))
            paths[label] = path
            rows.append({"run": label, "G": G, "level": level, "status": result.status,
                         "wall_time_s": result.wall_time_s, "velocity_evaluations": result.velocity_evaluations,
                         **compare(path)})
        figure(paths)
    JSON.write_text(json.dumps(rows, indent=1) + "\n")
    lines = ["| run | peak separation_y (a) at separation_x | at separation_x 11.36 (a) | largest / rms deviation "
             "from the figure (a) | velocity evaluations |", "|---|---|---|---|---|"]
    first = rows[0]
    lines.append(f"| Lac et al. 2007, fig. 4(b) | {first['figure_peak']:.3f} at 0.86 | {first['figure_plateau']:.3f} | "
                 f"(digitisation ±{DIGITISATION:g}) | |")
    for r in rows:
        lines.append(f"| {r['run']} | {r['peak']:.3f} at {r['peak_at']:.2f} | {r['plateau']:.3f} | "
                     f"{r['max_deviation']:.3f} / {r['rms_deviation']:.3f} | {r['velocity_evaluations']} |")
    MD.write_text("\n".join(lines) + "\n")
    print(MD.read_text())


def figure(paths: dict[str, str]) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    campaign = ROOT / "runs" / "pair-collision"
    points = _campaign_points(campaign) if campaign.is_dir() else {}
    fig, axes = plt.subplots(1, 2 if points else 1, figsize=(11 if points else 6, 4), squeeze=False)
    ax = axes[0, 0]
    for label, path in paths.items():
        sx, sy = trajectory(path)
        ax.plot(sx, sy, label=f"capsim, {label}")
    ax.plot(LAC_FIG4B[:, 0], LAC_FIG4B[:, 1], "ko", ms=4, label="Lac et al. 2007, fig. 4(b)")
    ax.set_xlim(-8.5, 14)
    ax.set_xlabel("separation_x (a)")
    ax.set_ylabel("separation_y (a)")
    ax.legend(fontsize=7)
    ax.set_title("pair collision in shear, Ca = 0.45, α = 0.05")
    if points:
        ax = axes[0, 1]
        for G, values in points.items():
            a = np.array(values)
            ax.plot(a[:, 0], a[:, 1], "o-", label=f"G {G:g} (Ca {3 * G:g})")
        ax.plot([0, 1.6], [0, 1.6], "k:", lw=0.8, label="no net displacement")
        ax.set_xlabel("initial separation_y (a)")
        ax.set_ylabel("final separation_y (a)")
        ax.legend(fontsize=7)
        ax.set_title("campaigns/pair-collision.yaml, level 2")
    fig.tight_layout()
    fig.savefig(FIGURE, dpi=120)


if __name__ == "__main__":
    sys.exit(main())

"""The scene's cost and its two figures (issues 41 and 42): `make bench-scenes`.

1. Cost of one velocity evaluation at level 3 for each flow and with a wall, against simple
   shear with the same symmetry (an evaluation is the same work whatever the far field: the
   far field is one vector op) and against the unbounded shear run (which uses the quarter):
   medians of ``--repeat`` rounds of ``--evals`` evaluations, the cases interleaved within a
   round (the machine is shared). Counted beside the times: the symmetry each case uses and
   its target nodes.
2. The wall's image kernel per pair against the free-space Stokeslet sum: the same targets and
   sources (level 3's targets, its regular points), medians.
3. Figure: D_xy against G in planar extension (level 2, bending 1e-3, kt 3) with the
   first-order line 25/2 G·(the level's shear factor) and the shear runs beside it.
4. Figure: the lift of a capsule (G = 0.05, level 1, kt 3) against the wall distance h,
   log-log, with the far-field law −(9/64π) S_yy/h² of its unbounded stresslet.

Writes benchmarks/scenes.md (the table the docs include), benchmarks/scenes.json and
docs/figures/planar_extension_D.png, docs/figures/wall_lift.png.

    PYTHONPATH=. python benchmarks/scenes.py [--repeat 5] [--evals 20]
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

from capsim.numerics.threads import apply_policy

apply_policy()

import numpy as np  # noqa: E402

from capsim.config import case_from_dict  # noqa: E402
from capsim.numerics.kernels import stokeslet_sum, wall_image_sum  # noqa: E402
from capsim.solve.solver import build_model  # noqa: E402

sys.path.insert(0, str(Path(__file__).parent))
from _common import run_or_stop  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
SCENES = {
    "simple shear (quarter)": {},
    "simple shear (mirror_z)": {"mesh": {"symmetry": "mirror_z"}},
    "planar extension": {"flow": {"kind": "planar_extension"}},
    "uniaxial extension": {"flow": {"kind": "uniaxial_extension"}},
    "Poiseuille, R = 5": {"flow": {"kind": "poiseuille", "poiseuille_radius": 5.0}},
    "wall, h = 4": {"wall": {"distance": 4.0}},
}


def _model(level: int, extra: dict):
    d = {"name": "b", "mesh": {"level": level}, "flow": {"shear_rate_G": 0.1, **extra.get("flow", {})}}
    if "wall" in extra:
        d["wall"] = extra["wall"]
    # mirror_z alone is no case setting; build_model takes it (as benchmarks/symmetry_cost.py does)
    model, X = build_model(case_from_dict(d), symmetry=extra.get("mesh", {}).get("symmetry"))
    x = X * np.array([1.1, 0.93, 0.98])  # a deformed shape, the same for every scene
    x = x - x.mean(axis=0) + X.mean(axis=0)
    return model, x


def evaluation_costs(level: int, repeat: int, evals: int) -> dict:
    models = {name: _model(level, extra) for name, extra in SCENES.items()}
    for model, x in models.values():  # compile and warm
        model.velocity(x, model.membrane(x))
    times: dict[str, list[float]] = {name: [] for name in models}
    for _ in range(repeat):
        for name, (model, x) in models.items():
            state = model.membrane(x)
            t0 = time.perf_counter()
            for _ in range(evals):
                model.velocity(x, state)
            times[name].append((time.perf_counter() - t0) / evals * 1e3)
    out = {}
    for name, (model, _) in models.items():
        out[name] = {"ms": float(np.median(times[name])), "symmetry": model.disc.symmetry,
                     "targets": int(len(model.disc.targets)), "nodes": int(model.disc.n_nodes)}
    return out


def kernel_costs(level: int, repeat: int) -> dict:
    model, x = _model(level, {})
    geo = model.disc.geometry(x)
    targets, sources = x, geo.points.reshape(-1, 3)
    strengths = np.random.default_rng(0).standard_normal(sources.shape)
    stokeslet_sum(targets, sources, strengths)
    wall_image_sum(targets, sources, strengths, -4.0)
    free, image = [], []
    for _ in range(repeat):
        t0 = time.perf_counter()
        stokeslet_sum(targets, sources, strengths)
        free.append(time.perf_counter() - t0)
        t0 = time.perf_counter()
        wall_image_sum(targets, sources, strengths, -4.0)
        image.append(time.perf_counter() - t0)
    pairs = targets.shape[0] * sources.shape[0]
    return {"pairs": pairs, "free_ns_per_pair": float(np.median(free)) / pairs * 1e9,
            "image_ns_per_pair": float(np.median(image)) / pairs * 1e9}


def planar_extension_figure(tmp: str) -> dict:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    Gs = [0.0025, 0.005, 0.01, 0.02, 0.04, 0.06, 0.08]
    out = {"G": Gs, "planar": [], "shear": []}
    for G in Gs:
        for kind, key in (("planar_extension", "planar"), ("simple_shear", "shear")):
            r = run_or_stop(case_from_dict({
                "name": f"{kind}-{G}", "flow": {"kind": kind, "shear_rate_G": G},
                "membrane": {"bending_modulus": 1e-3}, "mesh": {"level": 2}, "time": {"t_end": 3.0},
                "output": {"path": f"{tmp}/{kind}-{G}.h5", "snapshot_every": 3.0}}))
            out[key].append(float(r.final_D_xy) if r.status == "completed" else float("nan"))
    fig, ax = plt.subplots(figsize=(5, 3.6))
    g = np.array(Gs)
    ax.plot(g, out["planar"], "o-", label="planar extension (capsim)")
    ax.plot(g, out["shear"], "s-", label="simple shear (capsim)")
    slope = out["shear"][0] / Gs[0]  # the level's own first-order factor (25/4 less bending's share)
    ax.plot(g, 2 * slope * g, "k--", lw=1, label="first order: twice shear's slope")
    ax.plot(g, slope * g, "k:", lw=1, label="first order, shear")
    ax.set_xlabel("G = μ·rate·a/E_s")
    ax.set_ylabel("D_xy")
    ax.legend(frameon=False, fontsize=8)
    ax.set_title("thin shell, bending 1e-3, level 2, kt 3", fontsize=9)
    fig.tight_layout()
    fig.savefig(ROOT / "docs" / "figures" / "planar_extension_D.png", dpi=120)
    return out


def wall_lift_figure(tmp: str) -> dict:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    G = 0.05
    hs = [2.0, 3.0, 4.0, 6.0, 8.0, 12.0, 16.0, 32.0]
    free = run_or_stop(case_from_dict({"name": "free", "flow": {"shear_rate_G": G}, "mesh": {"level": 1},
                                       "time": {"t_end": 3.0}, "output": {"path": f"{tmp}/free.h5"}}))
    S_yy = (free.summary["N2_star"] - free.summary["N1_star"]) / 3 * 2.5 * (4 * np.pi / 3)
    law = -9 / (64 * np.pi) * S_yy
    import h5py

    lift = []
    for h in hs:
        path = f"{tmp}/wall-{h}.h5"
        run_or_stop(case_from_dict({"name": f"w{h}", "flow": {"shear_rate_G": G}, "wall": {"distance": h},
                                    "mesh": {"level": 1}, "time": {"t_end": 3.0}, "output": {"path": path}}))
        with h5py.File(path, "r") as f:
            lift.append(float(f["timeseries/centroid_velocity_y"][-1]) if f.attrs["status"] == "completed"
                        else float("nan"))
    data = {"h": hs, "lift": lift, "far_field_law_h2": law}
    draw_wall_lift(data)
    return data


def draw_wall_lift(data: dict) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.ticker import NullFormatter, ScalarFormatter

    fig, ax = plt.subplots(figsize=(5, 3.6))
    h = np.array(data["h"])
    ax.loglog(h, data["lift"], "o-", label="capsim (G = 0.05, level 1, kt 3)")
    ax.loglog(h, data["far_field_law_h2"] / h**2, "k--", lw=1,
              label="far field −(9/64π) S_yy/h² (unbounded S, window mean)")
    ax.set_xticks(h)
    ax.xaxis.set_major_formatter(ScalarFormatter())
    ax.xaxis.set_minor_formatter(NullFormatter())
    ax.set_xlabel("h/a (wall to the capsule's initial centre)")
    ax.set_ylabel("lift velocity / (k a)")
    ax.legend(frameon=False, fontsize=8)
    fig.tight_layout()
    fig.savefig(ROOT / "docs" / "figures" / "wall_lift.png", dpi=120)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--level", type=int, default=3)
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--evals", type=int, default=20)
    ap.add_argument("--no-figures", action="store_true")
    ap.add_argument("--replot", action="store_true", help="redraw the lift figure from benchmarks/scenes.json")
    args = ap.parse_args()
    if args.replot:
        draw_wall_lift(json.loads((ROOT / "benchmarks" / "scenes.json").read_text())["wall_lift"])
        return
    result = {"level": args.level, "evaluation": evaluation_costs(args.level, args.repeat, args.evals),
              "kernel": kernel_costs(args.level, args.repeat)}
    if not args.no_figures:
        with tempfile.TemporaryDirectory() as tmp:
            result["planar_extension"] = planar_extension_figure(tmp)
            result["wall_lift"] = wall_lift_figure(tmp)
    (ROOT / "benchmarks" / "scenes.json").write_text(json.dumps(result, indent=1))
    ev, base = result["evaluation"], result["evaluation"]["simple shear (quarter)"]["ms"]
    mirror = ev["simple shear (mirror_z)"]["ms"]
    lines = [f"One velocity evaluation at level {args.level} (λ = 1, one thread; medians of {args.repeat} rounds of "
             f"{args.evals}, interleaved; `make bench-scenes`):", "",
             "| scene | symmetry | target nodes | ms per evaluation | against shear, same symmetry | against unbounded shear |",
             "|---|---|---|---|---|---|"]
    for name, row in ev.items():
        same = base if row["symmetry"] == "mirror_z+rotation_z" else mirror if row["symmetry"] == "mirror_z" else float("nan")
        lines.append(f"| {name} | {row['symmetry']} | {row['targets']} of {row['nodes']} | {row['ms']:.3f} | "
                     f"{row['ms'] / same:.2f}× | {row['ms'] / base:.2f}× |")
    k = result["kernel"]
    lines += ["", f"The wall's image kernel: {k['image_ns_per_pair']:.2f} ns per pair against the free-space "
              f"Stokeslet's {k['free_ns_per_pair']:.2f} ns ({k['image_ns_per_pair'] / k['free_ns_per_pair']:.2f}×; "
              f"{k['pairs']:,} pairs, medians)."]
    (ROOT / "benchmarks" / "scenes.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()

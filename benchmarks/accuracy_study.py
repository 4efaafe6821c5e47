"""Accuracy against cost for the docs/validation.md ("Accuracy and cost").

Runs `capsim.campaigns.study.run_study` on an initially spherical capsule (thin-shell law,
G = 0.1) at λ = 1 and λ = 5, mesh levels 2-4 × rtol 1e-3, 1e-4, 1e-5, to
kt = 4, and writes for each case benchmarks/accuracy_<case>.nc and .png, then
the markdown section benchmarks/accuracy.md (the measured tables, the cheapest
settings reaching 1 % and 0.1 % in D_xy, observed orders, cost exponents).

    .venv/bin/python benchmarks/accuracy_study.py [--levels 2,3,4] [--rtols 1e-3,1e-4,1e-5]
        [--t-end 4] [--lambdas 1,5] [--workers 1]

Runs sequentially by default: the kernels are numba-parallel over all cores, so
two runs side by side would only distort each other's wall time.
"""

from __future__ import annotations

import argparse
import math
import os
import platform
import sys
from datetime import datetime, timezone
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent))

from capsim import __version__  # noqa: E402
from capsim.config import case_from_dict  # noqa: E402
from capsim.campaigns.study import QUANTITIES, analyse_study, format_study_table, plot_pareto, run_study, write_study  # noqa: E402


def sphere_case(lam: float, t_end: float):
    return case_from_dict({
        "name": f"sphere-G0.1-lam{lam:g}",
        "shape": {"kind": "sphere"},
        "membrane": {"law": "thin_shell"},
        "flow": {"shear_rate_G": 0.1, "viscosity_ratio": lam},
        "mesh": {"base": "octahedron"},
        "time": {"t_end": t_end},
        "output": {"snapshot_every": t_end},
    })


def _sel(ds, rtol_i, level_i):
    return ds.isel(rtol=rtol_i, level=level_i)


def markdown_table(ds_f, ds_r) -> str:
    """Table of one study: errors of D_xy against the finest run and Richardson, others against Richardson."""
    head = ("| level | nodes | rtol | steps | wall (s) | D_xy(t_end) | D_xy err (finest) | D_xy rel. err (Richardson) "
            "| θ err (rad) | TTF/f_s err | S*_xy err | volume drift |")
    lines = [head, "|" + "|".join(["---:"] * 12) + "|"]
    for ir in range(ds_f.sizes["rtol"]):
        for il in range(ds_f.sizes["level"]):
            f, r = _sel(ds_f, ir, il), _sel(ds_r, ir, il)
            lines.append(
                f"| {int(f['level'])} | {int(f['n_nodes'])} | {float(f['rtol']):.0e} | {int(f['steps'])} "
                f"| {float(f['wall_time_s']):.1f} | {float(f['D_xy']):.5f} | {float(f['D_xy_error']):+.1e} "
                f"| {float(r['D_xy_relative_error']):.1e} | {float(r['theta_error']):+.1e} "
                f"| {float(r['ttf_ratio_error']):+.1e} | {float(r['Sxy_star_error']):+.1e} "
                f"| {float(f['volume_drift']):+.1e} |"
            )
    return "\n".join(lines)


def cheapest(ds_r, threshold: float) -> str:
    best = None
    for ir in range(ds_r.sizes["rtol"]):
        for il in range(ds_r.sizes["level"]):
            s = _sel(ds_r, ir, il)
            e, w = float(s["D_xy_relative_error"]), float(s["wall_time_s"])
            if math.isfinite(e) and e <= threshold and (best is None or w < best[0]):
                best = (w, int(s["level"]), float(s["rtol"]), e)
    if best is None:
        return f"no setting of the ladder reaches {100 * threshold:g} %"
    w, level, rtol, e = best
    return f"level {level}, rtol {rtol:.0e}: {100 * e:.2g} % in {w:.1f} s"


def orders(ds_f) -> str:
    fine = ds_f.isel(rtol=-1)
    levels = [int(v) for v in ds_f["level"].values]
    out = []
    for q in ("D_xy", "theta", "Sxy_star"):
        p3 = [float(v) for v in fine[f"{q}_order3"].values]
        p = [float(v) for v in fine[f"{q}_order"].values]
        bits = []
        if len(levels) >= 3 and math.isfinite(p3[0]):
            bits.append(f"three-level p = {p3[0]:.2f}")
        if math.isfinite(p[0]):
            bits.append(f"log2(e_L{levels[0]}/e_L{levels[1]}) vs finest = {p[0]:.2f}")
        if bits:
            out.append(f"{q}: " + ", ".join(bits))
    return "; ".join(out)


def section(ds_f, lam: float) -> str:
    """Markdown of one study (the finest-reference Dataset as written by this script)."""
    ds_r = analyse_study(ds_f, "richardson")
    levels = [int(v) for v in ds_f["level"].values]
    rtol_min = float(ds_f["rtol"].values.min())
    t_end = float(ds_f.attrs["t_end"])
    tag = f"lam{lam:g}"
    ref_f = ", ".join(f"{q} = {float(ds_f[f'{q}_reference']):.5f}" for q in QUANTITIES)
    ref_r = ", ".join(f"{q} = {float(ds_r[f'{q}_reference']):.5f}" for q in QUANTITIES)
    p_used = float(ds_r["D_xy_reference"].attrs.get("richardson_order", float("nan")))
    total = float(np.nansum(ds_f["wall_time_s"].values))
    return (
        f"### Sphere, λ = {lam:g}, G = 0.1, thin-shell law, kt = {t_end:g}\n\n"
        f"{markdown_table(ds_f, ds_r)}\n\n"
        f"- Finest run (level {levels[-1]}, rtol {rtol_min:.0e}): {ref_f}.\n"
        f"- Richardson reference (in the level, at rtol {rtol_min:.0e}, D_xy order {p_used:.2f}): {ref_r}.\n"
        f"- Observed order in h at rtol {rtol_min:.0e}: {orders(ds_f)}.\n"
        f"- Cheapest setting reaching 1 % in D_xy (against Richardson): {cheapest(ds_r, 1e-2)}; "
        f"0.1 %: {cheapest(ds_r, 1e-3)}.\n"
        f"- Wall time ∝ N^{ds_f.attrs['wall_time_exponent']:.2f} over the levels at rtol {rtol_min:.0e} "
        f"(per step: N^{ds_f.attrs['wall_time_per_step_exponent']:.2f}); the ladder's runs took {total:.0f} s "
        f"in all.\n"
        f"- Files: `benchmarks/accuracy_{tag}.nc` (errors against the finest run), "
        f"`benchmarks/accuracy_{tag}_richardson.nc`, Pareto plot `benchmarks/accuracy_{tag}.png`.\n"
    )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--levels", default="2,3,4")
    ap.add_argument("--rtols", default="1e-3,1e-4,1e-5")
    ap.add_argument("--t-end", type=float, default=4.0)
    ap.add_argument("--lambdas", default="1,5")
    ap.add_argument("--workers", type=int, default=1)
    ap.add_argument("--report-only", action="store_true", help="rebuild accuracy.md from the .nc files present")
    args = ap.parse_args()
    levels = [int(v) for v in args.levels.split(",")]
    rtols = [float(v) for v in args.rtols.split(",")]
    if not args.report_only:
        for lam in (float(v) for v in args.lambdas.split(",")):
            case = sphere_case(lam, args.t_end)
            tag = f"lam{lam:g}"
            ds_f = run_study(case, levels, rtols, reference="finest", workers=args.workers,
                             out_dir=HERE.parent / "runs" / "accuracy" / tag,
                             progress=lambda msg: print(f"  λ={lam:g} {msg}", flush=True))
            ds_r = analyse_study(ds_f, "richardson")
            write_study(ds_f, HERE / f"accuracy_{tag}.nc")
            write_study(ds_r, HERE / f"accuracy_{tag}_richardson.nc")
            plot_pareto(ds_r, HERE / f"accuracy_{tag}.png")
            print(format_study_table(ds_f), flush=True)
            print(format_study_table(ds_r), flush=True)
            write_markdown()
    write_markdown()


def write_markdown() -> None:
    """benchmarks/accuracy.md from every benchmarks/accuracy_lam*.nc present."""
    import xarray as xr

    sections = []
    for path in sorted(HERE.glob("accuracy_lam*.nc")):
        if path.stem.endswith("_richardson"):
            continue
        lam = float(path.stem.removeprefix("accuracy_lam"))
        with xr.open_dataset(path) as ds:
            sections.append((lam, section(ds.load(), lam), float(ds.attrs["t_end"])))
    if not sections:
        return
    sections.sort()
    text = (
        "## Accuracy and cost\n\n"
        "Measured with `benchmarks/accuracy_study.py` (`capsim study` underneath) on "
        f"{platform.machine()} with {os.cpu_count()} cores (numba threads: all cores; runs one after another), "
        f"capsim {__version__}, {datetime.now(timezone.utc):%Y-%m-%d}. Every value is taken at the same "
        f"instant kt = {sections[0][2]:g}. "
        "Errors are value minus reference: `D_xy err (finest)` against the finest run of the ladder, the other "
        "columns against the Richardson extrapolation in the mesh level of the finest-tolerance runs.\n\n"
        + "\n".join(text for _, text, _ in sections)
    )
    (HERE / "accuracy.md").write_text(text, encoding="utf-8")


if __name__ == "__main__":
    main()

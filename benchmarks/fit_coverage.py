"""Do capsim fit's intervals cover the truth at their stated rate? (issue 56; a benchmark, not a test)

Synthetic data from capsim itself at a known truth, N independent noise draws (seeded), each
fitted with :func:`capsim.campaigns.fit.run_fit`; counted: how often the 68.3 % (±1 standard
error) and the 95 % intervals contain the truth, with the binomial standard error of each rate,
and the mean reported standard error against the standard deviation of the estimates over the
draws. Two fits:

- ``G``: flow.G (log) from D_xy at λ = 0.5, 1, 2, truth G = 0.01, noise 1 % of D_xy (the fit of
  tests/campaigns/test_fit.py);
- ``Gs-lambda``: physical.shear_modulus (log) and flow.viscosity_ratio (log) from D_xy and theta
  at shear rates 1-4 1/s (radius 50 µm, 1 mPa·s), truth 5 µN/m and λ = 2, noise 1 % of D_xy
  and 0.005 rad on theta.

The truth is the fit's own model (its evaluator, the runs the fit itself makes) at the true
parameters, so the model is exact at the truth and only the noise and the method are tested;
the sd columns carry the noise's true sd (known errors: normal quantiles). Every draw's fit has
its own output directory in a temporary directory (the runs of one draw are reused within it:
a parameter point met twice is run once); across draws the points differ, except the first
iteration's (the initial value and its forward-difference steps, the same for every draw): those
runs are made once and linked into each draw's runs/ (the campaign runner skips a completed
run), the rest are run anew. (The committed table's run reused only the initial point's runs, 3
of about 36 a draw: the step was then taken as absolute in u; see _first_iteration_runs.)

Writes benchmarks/fit_coverage.md (the table docs/fit.md includes) and benchmarks/fit_coverage.json.

    PYTHONPATH=. python benchmarks/fit_coverage.py [--fits G Gs-lambda] [--draws 20 8] [--level 1]

The cost, measured on 2 shared cores (load about 3), one process: a draw of G is one fit of about
12 evaluations of 3 runs, about 40 s; a draw of Gs-lambda about 18 evaluations of 4 runs, about
100 s. The default (G, 20 draws) is about 15 minutes.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import tempfile
import time
from pathlib import Path

from capsim.numerics.threads import apply_policy

apply_policy()

import numpy as np  # noqa: E402

from capsim.campaigns.campaign import expand_campaign  # noqa: E402
from capsim.campaigns.fit import (  # noqa: E402
    _campaign, _Evaluator, _from_unit, _point, _to_unit, fit_from_dict, run_fit,
)

ROOT = Path(__file__).resolve().parent.parent
OUT = ROOT / "benchmarks" / "fit_coverage"
SEED = 56
Z68 = 1.0  # the ±1 SE interval: 68.27 %
NOMINAL68 = math.erf(1 / math.sqrt(2))

FITS = {
    "G": {
        "title": "flow.G from D_xy at λ = 0.5, 1, 2",
        "base": {"shape": {"kind": "sphere"}, "time": {"t_end": 2.0}},
        "parameters": {"flow.G": {"bounds": [0.002, 0.05], "initial": 0.02, "log": True}},
        "truth": {"flow.G": 0.01},
        "conditions": {"flow.viscosity_ratio": [0.5, 1.0, 2.0]},
        "noise": {"D_xy": ("rel", 0.01)},
    },
    "Gs-lambda": {
        "title": "physical.shear_modulus and flow.viscosity_ratio from D_xy and theta at 1-4 1/s",
        "base": {"shape": {"kind": "sphere"}, "time": {"t_end": 2.0},
                 "physical": {"viscosity": "1 mPa*s", "radius": "50 um"}},
        "parameters": {"physical.shear_modulus": {"bounds": [1, 50], "initial": 10, "log": True, "unit": "uN/m"},
                       "flow.viscosity_ratio": {"bounds": [0.2, 10], "initial": 1, "log": True}},
        "truth": {"physical.shear_modulus": 5.0, "flow.viscosity_ratio": 2.0},
        "conditions": {"physical.shear_rate": ["1 1/s", "2 1/s", "3 1/s", "4 1/s"]},
        "noise": {"D_xy": ("rel", 0.01), "theta": ("abs", 0.005)},
    },
}


def _csv(path: Path, conds: dict, values: dict, sds: dict) -> None:
    keys, obs = list(conds), list(values)
    lines = [",".join(keys + obs + [o + "_sd" for o in obs])]
    for i in range(len(conds[keys[0]])):
        lines.append(",".join([str(conds[k][i]) for k in keys] + [repr(float(values[o][i])) for o in obs]
                              + [repr(float(sds[o][i])) for o in obs]))
    path.write_text("\n".join(lines) + "\n")


def _fit(name: str, cfg: dict, level: int, work: Path, values: dict, sds: dict):
    work.mkdir(parents=True, exist_ok=True)
    _csv(work / "data.csv", cfg["conditions"], values, sds)
    base = json.loads(json.dumps(cfg["base"]))
    base["mesh"] = {"level": level}
    return fit_from_dict({"name": f"coverage-{name}", "base": base, "parameters": cfg["parameters"],
                          "data": str(work / "data.csv"), "output": {"dir": str(work / "out"), "figure": False}},
                         source=f"fit_coverage-{name}")


def _first_iteration_runs(fit) -> list[Path]:
    """The run files of the initial point and its first steps (trf's forward differences, dfols' first
    interpolation points), the same for every draw.

    scipy's 2-point step with ``diff_step`` is relative to the variable, h = diff_step · |u| (scipy
    1.17; measured: u0 = 0.715 is stepped to 0.72215), not an absolute step in u; both candidates are
    listed (a point never run is simply not linked), − where + leaves [0, 1]."""
    pars = list(fit.spec.parameters.values())
    u0 = np.array([_to_unit(p, p.initial) for p in pars])
    rel = fit.spec.method.diff_step
    points = [u0]
    for j in range(len(pars)):
        # trf's forward differences (relative and absolute steps), dfols' first model (radius_start along each axis)
        for h in (rel * abs(u0[j]) or rel, rel, fit.spec.method.radius_start):
            u = u0.copy()
            u[j] = u0[j] + h if u0[j] + h <= 1.0 else u0[j] - h
            points.append(u)
    xs = [[_from_unit(p, ui) for p, ui in zip(pars, u)] for u in points]
    specs = expand_campaign(_campaign(fit, [_point(fit, x) for x in xs]))
    return [Path(s.path) for s in specs]


def run_one(name: str, draws: int, level: int, tmp: Path) -> dict:
    cfg = FITS[name]
    names = list(cfg["parameters"])
    n_rows = len(next(iter(cfg["conditions"].values())))
    # the truth: the fit's own model at the true parameters
    dummy = {o: np.ones(n_rows) for o in cfg["noise"]}
    truth_fit = _fit(name, cfg, level, tmp / f"{name}-truth", dummy, dummy)
    t0 = time.perf_counter()
    model, _, _ = _Evaluator(truth_fit, 1, lambda line: None)([cfg["truth"][k] for k in names])
    truth_s = time.perf_counter() - t0
    obs_list = truth_fit.data.observable
    truth_values = {o: np.array([v for v, ob in zip(model, obs_list) if ob == o]) for o in cfg["noise"]}
    sds = {o: (s * np.abs(truth_values[o]) if kind == "rel" else np.full(n_rows, s))
           for o, (kind, s) in cfg["noise"].items()}
    shared: dict[str, Path] = {}
    rows = []
    for k in range(draws + 1):  # draw 0: no noise (the optimiser's own error); 1..N: noise draws
        rng = np.random.default_rng([SEED, k])
        values = {o: truth_values[o] + (rng.normal(0.0, sds[o]) if k else 0.0) for o in cfg["noise"]}
        work = tmp / f"{name}-{k}"
        fit = _fit(name, cfg, level, work, values, sds)
        first = _first_iteration_runs(fit)
        fit.runs_dir.mkdir(parents=True, exist_ok=True)
        for path in first:  # the first iteration's runs, made by an earlier draw
            if path.name in shared:
                os.link(shared[path.name], path)
        t0 = time.perf_counter()
        res = run_fit(fit, workers=1, log=None)
        wall = time.perf_counter() - t0
        for path in first:
            if path.exists() and path.name not in shared:
                shared[path.name] = path
        row = {"draw": k, "wall_s": wall, "n_runs": res.n_runs, "n_runs_executed": res.n_runs_executed,
               "n_evaluations": res.n_evaluations, "chi2": res.chi2, "dof": res.dof, "success": res.success,
               "at_bound": any(res.at_bound.values()), "parameters": {}}
        for i, p in enumerate(names):
            par = cfg["parameters"][p]
            lo, hi = res.intervals[p]
            est, truth = res.estimates[p], cfg["truth"][p]
            f = math.log10 if par.get("log") else (lambda v: v)
            q95 = (f(hi) - f(lo)) / 2  # the interval's half-width in the fitted scale (log10 for log)
            se_z = q95 / 1.959963984540054
            z, zt = f(est), f(truth)
            row["parameters"][p] = {"estimate": est, "std_error": res.std_errors[p], "interval95": [lo, hi],
                                    "se_fitted_scale": se_z, "z_score": (z - zt) / se_z if se_z > 0 else math.nan,
                                    "covered68": bool(abs(z - zt) <= Z68 * se_z),
                                    "covered95": bool(lo <= truth <= hi)}
        rows.append(row)
        print(f"{name} draw {k}: " + ", ".join(f"{p} {row['parameters'][p]['estimate']:.6g} ± "
                                               f"{row['parameters'][p]['std_error']:.3g}" for p in names)
              + f", chi2 {res.chi2:.3g}, {res.n_evaluations} evaluations, {res.n_runs_executed}/{res.n_runs} runs "
              f"made, {wall:.1f} s", flush=True)
    return {"fit": name, "title": cfg["title"], "level": level, "draws": draws, "seed": SEED,
            "truth": cfg["truth"], "parameters": cfg["parameters"], "conditions": cfg["conditions"],
            "noise": {o: list(v) for o, v in cfg["noise"].items()},
            "truth_values": {o: v.tolist() for o, v in truth_values.items()}, "truth_runs_s": truth_s,
            "rows": rows, "stats": stats(rows[1:], names, cfg["truth"], {p: cfg["parameters"][p].get("log", False)
                                                                          for p in names}),
            "noise_free": rows[0]["parameters"]}


def stats(rows: list[dict], names: list[str], truth: dict, log: dict) -> dict:
    n = len(rows)
    out = {"draws": n, "mean_wall_s": float(np.mean([r["wall_s"] for r in rows])),
           "mean_runs": float(np.mean([r["n_runs"] for r in rows])),
           "mean_runs_made": float(np.mean([r["n_runs_executed"] for r in rows])),
           "mean_evaluations": float(np.mean([r["n_evaluations"] for r in rows])),
           "mean_chi2": float(np.mean([r["chi2"] for r in rows])), "dof": rows[0]["dof"],
           "failed": sum(not r["success"] for r in rows), "at_bound": sum(r["at_bound"] for r in rows)}
    for p in names:
        ps = [r["parameters"][p] for r in rows]
        est = np.array([q["estimate"] for q in ps])
        se = np.array([q["std_error"] for q in ps])
        f = np.log10 if log[p] else (lambda v: v)
        z = f(est)
        se_z = np.array([q["se_fitted_scale"] for q in ps])
        c68 = float(np.mean([q["covered68"] for q in ps]))
        c95 = float(np.mean([q["covered95"] for q in ps]))
        sd_z = float(np.std(z, ddof=1))
        out[p] = {"coverage68": c68, "coverage68_se": math.sqrt(NOMINAL68 * (1 - NOMINAL68) / n),
                  "coverage95": c95, "coverage95_se": math.sqrt(0.95 * 0.05 / n),
                  "mean_estimate": float(np.mean(est)), "bias": float(np.mean(est) - truth[p]),
                  "bias_se": float(np.std(est, ddof=1) / math.sqrt(n)),
                  "mean_std_error": float(np.mean(se)), "sd_estimates": float(np.std(est, ddof=1)),
                  "mean_se_fitted_scale": float(np.mean(se_z)), "sd_fitted_scale": sd_z,
                  "sd_over_se": sd_z / float(np.mean(se_z)), "sd_over_se_rel_error": 1 / math.sqrt(2 * (n - 1)),
                  "mean_abs_z": float(np.mean(np.abs([q["z_score"] for q in ps])))}
    return out


def _verdict(res: dict) -> str:
    """Each parameter's rates against their nominal within twice the binomial error, said in words."""
    s, out = res["stats"], []
    for p in res["truth"]:
        q = s[p]
        ok68 = abs(q["coverage68"] - NOMINAL68) <= 2 * q["coverage68_se"]
        ok95 = abs(q["coverage95"] - 0.95) <= 2 * q["coverage95_se"]
        ok_sd = abs(q["sd_over_se"] - 1) <= 2 * q["sd_over_se"] * q["sd_over_se_rel_error"]
        words = "within" if ok68 and ok95 and ok_sd else "NOT within"
        out.append(f"{res['fit']}, `{p}`: both rates and SD/SE are {words} twice their errors of the nominal "
                   f"(with {s['draws']} draws that resolves a 95 % rate to ±{200 * q['coverage95_se']:.0f} points "
                   "only: a coarse check, not a proof).")
    return " ".join(out)


def _method_text() -> str:
    from capsim.campaigns.fit import FitMethod

    m = FitMethod()
    return (f"{m.optimizer}, radius_start {m.radius_start:g}, radius_end {m.radius_end:g}" if m.optimizer == "dfols"
            else f"{m.optimizer}, diff_step {m.diff_step:g}, xtol {m.xtol:g}")


def table(results: list[dict]) -> str:
    head = results[0]
    text = (f"How often `capsim fit`'s intervals contain the truth over repeated noise draws (issue 56): synthetic "
            f"data made by capsim itself (the fit's own model at the true parameters, mesh level {head['level']}, "
            "sphere, neo-Hookean, kt = 2; "
            + "; ".join(f"{res['fit']}: {res['title']}, from the start "
                        + ", ".join(f"{k} = {v['initial']:g}" for k, v in res["parameters"].items())
                        for res in results)
            + ") plus Gaussian noise of known sd (given in the sd columns), "
            f"each draw fitted by `run_fit` with the default method ({_method_text()}). The 68.3 % interval "
            "is ±1 reported standard error in the fitted scale (log10 for `log: true`), the 95 % one is the fit's "
            "own; the rate's error is the binomial standard error at the nominal rate. SD/SE: the standard "
            "deviation of the estimates over the draws against the mean reported standard error, in the fitted "
            f"scale (1 when the covariance is right; its own relative error 1/sqrt(2(N−1))). Seed {head['seed']}, "
            "draw k seeded [56, k]; draw 0 without noise returns "
            + ", ".join(f"{k} = {v['estimate']:.6g}" for res in results for k, v in res["noise_free"].items())
            + ". " + " ".join(_verdict(res) for res in results) + " `make bench-fit`.")
    lines = [text, "", "| fit | noise | draws | parameter | truth | mean estimate | 68.3 % coverage | 95 % coverage "
             "| mean SE | SD of estimates | SD/SE | mean χ² (dof) | runs made / used per fit |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for res in results:
        s = res["stats"]
        noise = ", ".join(f"{o} {100 * v:g} %" if kind == "rel" else f"{o} {v:g}"
                          for o, (kind, v) in res["noise"].items())
        for p in res["truth"]:
            q = s[p]
            lines.append(f"| {res['fit']} | {noise} | {s['draws']} | `{p}` | {res['truth'][p]:g} | "
                         f"{q['mean_estimate']:.5g} ± {q['bias_se']:.2g} | "
                         f"{100 * q['coverage68']:.1f} ± {100 * q['coverage68_se']:.1f} % | "
                         f"{100 * q['coverage95']:.1f} ± {100 * q['coverage95_se']:.1f} % | {q['mean_std_error']:.3g} | "
                         f"{q['sd_estimates']:.3g} | {q['sd_over_se']:.3f} ± {q['sd_over_se'] * q['sd_over_se_rel_error']:.3f} | "
                         f"{s['mean_chi2']:.2f} ({s['dof']}) | {s['mean_runs_made']:.1f} / {s['mean_runs']:.1f} |")
    return "\n".join(lines) + "\n"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--fits", nargs="+", default=["G"], choices=list(FITS))
    ap.add_argument("--draws", type=int, nargs="+", default=[20], help="noise draws per fit (one per fit, or one for all)")
    ap.add_argument("--level", type=int, default=1)
    ap.add_argument("--out", default=str(OUT), help="path of the .md and .json without suffix")
    ap.add_argument("--report", action="store_true", help="rewrite the table from the .json")
    args = ap.parse_args()
    out = Path(args.out)
    if args.report:
        results = json.loads(out.with_suffix(".json").read_text())["fits"]
    else:
        draws = args.draws if len(args.draws) == len(args.fits) else [args.draws[0]] * len(args.fits)
        results = []
        with tempfile.TemporaryDirectory(prefix="fit-coverage-") as tmp:
            for name, n in zip(args.fits, draws):
                results.append(run_one(name, n, args.level, Path(tmp)))
        out.with_suffix(".json").write_text(json.dumps({"fits": results}, indent=1) + "\n")
    out.with_suffix(".md").write_text(table(results))
    print(table(results))


if __name__ == "__main__":
    main()

"""Do the reported error bars bound the error? (issue 18, item 3; docs/validation.md "Accuracy and cost")

For each case: the run itself (mesh level L, ``time.rtol`` 1e-4), its reported
bar (:func:`capsim.campaigns.study.error_estimate`, what ``capsim run --error-estimate``
prints: reruns at level L − 1 and at 10× the tolerance), and a reference one
level finer (L + 1) at rtol 1e-5. The true error is value − reference; the
ratio bar / |true error| should lie in [1, 20]. The reference carries its own
error: for a quantity of order p it is 2^−p of the run's, so against the exact
answer the ratio is 1 − 2^−p times the one printed (×3/4 for a second-order θ,
×7/8 for a third-order D_xy).

    .venv/bin/python benchmarks/error_bars.py [--cases NAME,...] [--level 2] [--scheme rkc]

Results go to benchmarks/error_bars.json (one record per case, kept between
invocations: a case already there is not rerun) and the table to
benchmarks/error_bars.md. Runs one simulation at a time (the kernels use all
cores).
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import tempfile
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent))

from capsim.config import apply_overrides, case_from_dict  # noqa: E402
from _common import run_or_stop  # noqa: E402
from capsim.campaigns.study import error_estimate, final_values  # noqa: E402
from capsim.storage.store import read_trajectory  # noqa: E402


#: name: (shape, G, λ, t_end)
CASES = {
    "sphere-G0.1-lam1": ({"kind": "sphere"}, 0.1, 1.0, 7.0),
    "sphere-G0.45-lam1": ({"kind": "sphere"}, 0.45, 1.0, 6.0),
    "sphere-G0.1-lam5": ({"kind": "sphere"}, 0.1, 5.0, 4.0),
    "sphere-G0.0125-lam0.2": ({"kind": "sphere"}, 0.0125, 0.2, 2.0),
    "prolate2-G0.05-lam1": ({"kind": "prolate", "aspect_ratio": 2.0}, 0.05, 1.0, 4.0),
    "oblate0.5-G0.2-lam1": ({"kind": "oblate", "aspect_ratio": 0.5}, 0.2, 1.0, 5.0),
    "biconcave-G0.2-lam5": ({"kind": "biconcave"}, 0.2, 5.0, 3.0),
}


def make_case(name: str, level: int, rtol: float, scheme: str, path: str):
    shape, G, lam, t_end = CASES[name]
    return case_from_dict({
        "name": name, "shape": shape, "membrane": {"law": "thin_shell"},
        "flow": {"shear_rate_G": G, "viscosity_ratio": lam},
        "mesh": {"level": level}, "time": {"t_end": t_end, "rtol": rtol, "scheme": scheme},
        "output": {"path": path, "snapshot_every": t_end},
    })


def values(path: str, window: tuple[float, float]) -> dict[str, float]:
    return final_values(read_trajectory(path)["timeseries"], window)


def run_one(name: str, level: int, scheme: str, reference: str | None = None) -> dict:
    rec: dict = {"case": name, "level": level, "scheme": scheme}
    with tempfile.TemporaryDirectory(prefix="capsim-errbars-") as tmp:
        main = make_case(name, level, 1e-4, scheme, f"{tmp}/main.h5")
        t0 = time.perf_counter()
        summary = run_or_stop(main)
        rec["wall_main_s"] = time.perf_counter() - t0
        rec["status"] = summary["status"]
        window = (float(summary["averaging_t_from"]), float(summary["averaging_t_to"]))
        rec["window"] = window
        t0 = time.perf_counter()
        est = error_estimate(main, summary, workers=1)
        rec["wall_estimate_s"] = time.perf_counter() - t0
        ref = apply_overrides(main, **{"mesh.level": level + 1, "time.rtol": 1e-5,
                                       "output.path": reference or f"{tmp}/ref.h5"})
        t0 = time.perf_counter()
        if reference is None:
            rec["reference_status"] = run_or_stop(ref)["status"]
        else:  # the same case run before (e.g. the level-4 reference, minutes here)
            rec["reference_status"] = f"reused {Path(reference).name}"
        rec["wall_reference_s"] = time.perf_counter() - t0
        got, want = values(main.output.path, window), values(ref.output.path, window)
    for key in got:
        rec[key] = {"value": got[key], "reference": want[key], "bar": est[key],
                    "mesh": est[f"{key}_mesh"], "time": est[f"{key}_time"],
                    "true_error": got[key] - want[key]}
    return rec


def table(records: list[dict]) -> str:
    lines = ["| case | level | quantity | value | reported bar | true error (vs level + 1) | ratio |",
             "|---|---:|---|---:|---:|---:|---:|"]
    for rec in records:
        for key in ("D_xy_mean", "theta_mean", "ttf_ratio_mean", "Sxy_star_mean", "D_xy", "theta"):
            r = rec[key]
            err = abs(r["true_error"])
            ratio = r["bar"] / err if err > 0 else math.inf
            flag = "" if 1.0 <= ratio <= 20.0 else " **✗**"
            label = key.replace("_mean", " (mean)") if key.endswith("_mean") else f"{key} (t_end)"
            lines.append(f"| {rec['case']} | {rec['level']} | {label} | {r['value']:.5f} | {r['bar']:.1e} "
                         f"| {r['true_error']:+.1e} | {ratio:.1f}{flag} |")
    return "\n".join(lines)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--cases", default=",".join(CASES))
    p.add_argument("--level", type=int, default=2)
    p.add_argument("--scheme", default="rkc", choices=["rkc", "rkf23"])
    p.add_argument("--reference", default=None,
                   help="run file of the reference case (level + 1, rtol 1e-5) made before; one case only")
    args = p.parse_args(argv)
    out_json = HERE / "error_bars.json"
    records = json.loads(out_json.read_text()) if out_json.exists() else []
    done = {(r["case"], r["level"], r["scheme"]) for r in records}
    for name in args.cases.split(","):
        if (name, args.level, args.scheme) in done:
            continue
        t0 = time.perf_counter()
        rec = run_one(name, args.level, args.scheme, args.reference)
        print(f"{name}: {time.perf_counter() - t0:.0f} s", flush=True)
        records.append(rec)
        out_json.write_text(json.dumps(records, indent=1))
    (HERE / "error_bars.md").write_text(table(records) + "\n")
    print(table(records))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

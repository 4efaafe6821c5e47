"""`make bench-auto`: does ``time.scheme: auto`` pick the fastest scheme in wall time (issue 44, item 3)?

For each case of benchmarks/stepping.py at mesh levels 2 and 3 (made cheaper: shorter kt, as
each label says; (g) at level 2 keeps the issue's kt 2), at one rtol (1e-4, the default's
neighbour the issue measured), every fixed entry — rkf23, rkc, linearly_implicit (local
preconditioner), linearly_implicit/dense — and auto, in ``--rounds`` rounds (3), the entries
interleaved within a round (the machine is shared: a round's entries run under one load). Per
entry: the median wall time and the counts of its last run (velocity evaluations, layer
applications, GMRES iterations, layer matrices); auto's pick; auto / best, the medians' ratio
to the fastest fixed entry. The issue's bound: auto within 1.25x of the best fixed choice.

Entries hopeless in wall time are not run to the end: from the second entry of a round on, a
run stops at ``time.max_wall_s`` = CAP x the fastest entry so far of the case (interrupted:
the table says "> t"), and an entry interrupted once is not run again; such an entry cannot be
the fastest (its time is at least CAP x another's). Entries are compared at the same rtol, not
at equal accuracy: time.rtol's one promise (docs/time_stepping.md) bounds every scheme's error
by the same rtol, and a user who asks for an rtol gets that rtol from auto.

Writes benchmarks/auto_choice.md and benchmarks/auto_choice.json.

    python benchmarks/auto_choice.py                 # every case (about 25 min on 2 shared cores)
    python benchmarks/auto_choice.py g2 a3 --rounds 3  # some of them (cases <key><level>)
"""

from __future__ import annotations

# the CLI's thread policy, before numpy (OpenBLAS) and numba load: capsim.numerics.threads
from capsim.numerics.threads import apply_policy

apply_policy()

import argparse  # noqa: E402
import json  # noqa: E402
import platform  # noqa: E402
import statistics  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402
from datetime import datetime, timezone  # noqa: E402
from pathlib import Path  # noqa: E402

from capsim import __version__  # noqa: E402
from capsim.config import ConfigError, case_from_dict  # noqa: E402
from capsim.runs.runner import run_case  # noqa: E402

OUT = Path(__file__).resolve().parent / "auto_choice"
#: this invocation (a row's entries all ran in one invocation, interleaved)
RUN = datetime.now(timezone.utc).isoformat(timespec="seconds")
RTOL = 1e-4
#: the auto bound of issue 44 (wall time, auto over the fastest fixed entry)
BOUND = 1.25
#: a run stops at this many times the fastest entry so far (it cannot be the fastest)
CAP = 3.0
ENTRIES = ("rkf23", "rkc", "linearly_implicit", "linearly_implicit/dense", "auto")
FIXED = ENTRIES[:-1]
#: the order the entries run in within a round: rkc first (never hopeless, so that the others
#: have a cap from the first round on)
ORDER = ("rkc", "rkf23", "linearly_implicit", "linearly_implicit/dense", "auto")
VARIANTS = {"linearly_implicit/dense": {"scheme": "linearly_implicit", "preconditioner": "dense"}}

#: (label, case) of benchmarks/stepping.py's CASES with the level and kt of this table
_BASE = {
    "a": ("sphere, G = 0.1", {"flow": {"shear_rate_G": 0.1}}, {2: 4.0, 3: 2.0}),
    "c": ("sphere, G = 0.0125", {"flow": {"shear_rate_G": 0.0125}}, {2: 2.0, 3: 1.0}),
    "d": ("sphere, lambda = 5, G = 0.1", {"flow": {"shear_rate_G": 0.1, "viscosity_ratio": 5.0}}, {2: 3.0, 3: 1.5}),
    "e": ("oblate b/a = 0.5, lambda = 10, G = 0.2, kappa = 1e-3",
          {"shape": {"kind": "oblate", "aspect_ratio": 0.5}, "membrane": {"bending_modulus": 1e-3},
           "flow": {"shear_rate_G": 0.2, "viscosity_ratio": 10.0}}, {2: 4.0, 3: 2.0}),
    "f": ("biconcave, G = 0.2", {"shape": {"kind": "biconcave"}, "flow": {"shear_rate_G": 0.2}}, {2: 5.0, 3: 2.0}),
    "g": ("sphere, G = 0.001", {"flow": {"shear_rate_G": 0.001}}, {2: 2.0, 3: 0.5}),
    "i": ("sphere, G = 0.001, kappa = 0.01", {"flow": {"shear_rate_G": 0.001}, "membrane": {"bending_modulus": 0.01}},
          {2: 0.5, 3: 0.25}),
}
#: the stepping benchmark's own level and kt of each case (the labels say what changed)
_STEPPING = {"a": (3, 10.0), "c": (3, 4.0), "d": (3, 6.0), "e": (3, 20.0), "f": (2, 20.0), "g": (2, 2.0),
             "i": (3, 1.0)}


def _cases() -> dict[str, tuple[str, dict]]:
    out = {}
    for key, (label, spec, kts) in _BASE.items():
        level0, kt0 = _STEPPING[key]
        for level, kt in kts.items():
            changed = [f"level {level}" + ("" if level == level0 else f" (not {level0})"),
                       f"kt {kt:g}" + ("" if kt == kt0 else f" (not {kt0:g})")]
            out[f"{key}{level}"] = (f"({key}) {label}, {', '.join(changed)}",
                                    {**json.loads(json.dumps(spec)), "mesh": {"level": level}, "time": {"t_end": kt}})
    return out


CASES = _cases()


def _case(key: str, entry: str, tmp: Path, max_wall: float | None, rnd: int):
    spec = json.loads(json.dumps(CASES[key][1]))
    spec["name"] = f"{key}-{entry.replace('/', '-')}-{rnd}"
    spec["time"].update(VARIANTS.get(entry, {"scheme": entry}), rtol=RTOL, max_wall_s=max_wall)
    spec["output"] = {"path": str(tmp / f"{spec['name']}.h5"), "snapshot_every": 1.0}
    return case_from_dict(spec)


def _applies(key: str, entry: str, tmp: Path) -> bool:
    try:
        _case(key, entry, tmp, None, 0)
    except ConfigError:
        return False
    return True


def _picked(result: dict) -> str:
    name = result.get("scheme") or "?"
    if name == "linearly_implicit" and result.get("layer_matrices"):
        name += "/dense"
    return name


def bench_case(key: str, rounds: int, tmp: Path) -> dict:
    label = CASES[key][0]
    entries = [e for e in ORDER if _applies(key, e, tmp)]
    runs: dict[str, list[dict]] = {e: [] for e in entries}
    stopped: dict[str, float] = {}
    for rnd in range(rounds):
        for entry in entries:
            if entry in stopped:
                continue
            done = [statistics.median(r["wall_time_s"] for r in runs[e]) for e in entries
                    if runs[e] and e not in stopped]
            cap = CAP * min(done) if done else None
            result = dict(run_case(_case(key, entry, tmp, cap, rnd)))
            (tmp / f"{key}-{entry.replace('/', '-')}-{rnd}.h5").unlink(missing_ok=True)
            if result["status"] == "interrupted" and "max_wall_s" in (result.get("status_reason") or ""):
                stopped[entry] = result["wall_time_s"]
                print(f"  ({key}) round {rnd}: {entry} stopped at {result['wall_time_s']:.2f} s", flush=True)
                continue
            if result["status"] != "completed":  # a signal, an unstable run: no table
                raise SystemExit(f"({key}) {entry}: {result['status']} ({result.get('status_reason')})")
            runs[entry].append({k: result.get(k) for k in (
                "wall_time_s", "steps", "rejected_steps", "velocity_evaluations", "layer_applications",
                "linear_iterations", "layer_matrices", "scheme", "scheme_choice")})
            print(f"  ({key}) round {rnd}: {entry} {result['wall_time_s']:.2f} s, "
                  f"{result['velocity_evaluations']} evals, {result['layer_applications']} layer apps"
                  + (f" -> {_picked(result)}" if entry == "auto" else ""), flush=True)
    row: dict = {"case": key, "label": label, "rtol": RTOL, "run": RUN, "entries": {}}
    for entry in entries:
        if entry in stopped:
            row["entries"][entry] = {"stopped_at_s": stopped[entry], "wall_s": None}
        else:
            last = runs[entry][-1]
            row["entries"][entry] = {**last, "wall_s": statistics.median(r["wall_time_s"] for r in runs[entry]),
                                     "walls": [r["wall_time_s"] for r in runs[entry]]}
    fixed = {e: row["entries"][e]["wall_s"] for e in FIXED if e in row["entries"] and row["entries"][e]["wall_s"]}
    best = min(fixed, key=fixed.get)
    auto = row["entries"]["auto"]
    row.update(best=best, picked=_picked(auto), choice=auto.get("scheme_choice"),
               ratio=auto["wall_s"] / fixed[best])
    print(f"({key}) {label}: auto picked {row['picked']}, best {best}, auto / best {row['ratio']:.2f}", flush=True)
    return row


def _cell(e: dict | None) -> str:
    if e is None:
        return "—"
    if e["wall_s"] is None:
        return f"> {e['stopped_at_s']:.1f}"
    return f"{e['wall_s']:.2f}"


def _counts(e: dict | None) -> str:
    if e is None or e["wall_s"] is None:
        return "—"
    return (f"{e['velocity_evaluations']} / {e['layer_applications']} / {e.get('linear_iterations') or 0} / "
            f"{e.get('layer_matrices') or 0}")


def markdown(rows: list[dict], meta: dict) -> str:
    names = {"linearly_implicit": "li", "linearly_implicit/dense": "li/dense"}
    lines = [f"Wall time (s, median of {meta['rounds']} in one invocation, entries interleaved) of each fixed scheme "
             f"and of `auto` at rtol {RTOL:g}, the cases of the stepping benchmark at levels 2 and 3 made cheaper "
             f"(shorter kt, as each label says); li: linearly_implicit with the local preconditioner, li/dense: "
             f"with the dense one. \"> t\": stopped at {CAP:g}× the fastest entry so far (it cannot be the "
             f"fastest). auto / best: auto's median over the fastest fixed entry's (the issue's bound {BOUND:g}).",
             "",
             "| case | rkf23 | rkc | li | li/dense | auto | auto picked | best | auto / best |",
             "|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        e = r["entries"]
        lines.append(f"| {r['label']} | " + " | ".join(_cell(e.get(x)) for x in ENTRIES)
                     + f" | {names.get(r['picked'], r['picked'])} | {names.get(r['best'], r['best'])} | "
                     f"{r['ratio']:.2f} |")
    worst = max(rows, key=lambda r: r["ratio"])
    ok = all(r["ratio"] <= BOUND for r in rows)
    lines += ["", (f"Every case within {BOUND:g}×: {'yes' if ok else 'no'} (largest auto / best "
                   f"{worst['ratio']:.2f}, {worst['label']})."), "",
              "Counts of each entry's last run: velocity evaluations / layer applications / GMRES iterations / "
              "layer matrices (auto's include its measurement of ρ):", "",
              "| case | rkf23 | rkc | li | li/dense | auto |", "|---|---|---|---|---|---|"]
    for r in rows:
        e = r["entries"]
        lines.append(f"| {r['label']} | " + " | ".join(_counts(e.get(x)) for x in ENTRIES) + " |")
    lines += ["", "Why auto picked what it did (the run file's `time_scheme_choice`):", ""]
    for r in rows:
        lines.append(f"- {r['label']}: {r['choice']}")
    runs = sorted({r.get("run", meta["run"]) for r in rows})
    lines += ["", f"capsim {meta['version']}, {meta['machine']}; invocations (each row's entries in one): "
              f"{', '.join(runs)}."]
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("cases", nargs="*", help=f"cases to run (default every one: {' '.join(CASES)})")
    p.add_argument("--rounds", type=int, default=3)
    p.add_argument("--out", type=Path, default=OUT, help="the tables' path without its suffix (.md and .json are written)")
    args = p.parse_args(argv)
    keys = args.cases or list(CASES)
    unknown = [k for k in keys if k not in CASES]
    if unknown:
        p.error(f"unknown cases {unknown} (allowed: {' '.join(CASES)})")
    meta = {"version": __version__, "rounds": args.rounds, "rtol": RTOL,
            "machine": f"{platform.machine()}, {platform.python_version()}",
            "run": RUN}
    rows = []
    with tempfile.TemporaryDirectory() as d:
        tmp = Path(d)
        # compile / load every scheme's kernels before anything is timed
        for entry in ENTRIES:
            warm = json.loads(json.dumps(CASES["g2"][1]))
            warm.update(name=f"warm-{entry.replace('/', '-')}", mesh={"level": 1})
            warm["time"].update(VARIANTS.get(entry, {"scheme": entry}), t_end=0.05)
            warm["output"] = {"path": str(tmp / f"warm-{entry.replace('/', '-')}.h5")}
            run_case(case_from_dict(warm))
        for key in keys:
            rows.append(bench_case(key, args.rounds, tmp))
    old = {}
    if args.out.with_suffix(".json").exists() and args.cases:
        old = {r["case"]: r for r in json.loads(args.out.with_suffix(".json").read_text())["rows"]}
    merged = {**old, **{r["case"]: r for r in rows}}
    rows = [merged[k] for k in CASES if k in merged]
    args.out.with_suffix(".json").write_text(json.dumps({"meta": meta, "rows": rows}, indent=1) + "\n")
    args.out.with_suffix(".md").write_text(markdown(rows, meta))
    print(markdown(rows, meta))
    return 0


if __name__ == "__main__":
    sys.exit(main())

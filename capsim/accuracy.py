"""Ask for an accuracy, get the cheapest run (issue 44): ``time.rtol: auto`` and the case's
``accuracy`` target, from the error model measured by ``benchmarks/error_model.py``
(``capsim/error_model.json``; its tables: docs/benchmarks.md, "Error model").

The model holds, for each reported quantity q (D_xy, θ, S*_xy at t_end), the mesh's error at
each level e_mesh(q, level) (relative; θ absolute in rad), the time error per unit rtol
k_time(q) (the largest over the training cases: |q(rtol) − q(rtol → 0)| ≤ k_time · rtol),
and the cost: velocity evaluations per unit kt ≈ a · rtol^(−b), times the seconds of one
evaluation at each level. Both are the largest over training cases that span the shapes,
laws, λ and G of the validation: a prediction is an envelope, not a fit to one case.

- ``auto_rtol(level)``: the largest rtol of :data:`RTOL_LADDER` whose time error stays below
  :data:`TIME_FRACTION` of the level's mesh error for every quantity: a tighter tolerance
  buys no digit the mesh has.
- ``choose(quantity, target, relative, t_end)``: the (level, rtol) of least predicted cost whose
  predicted error, mesh plus time, meets the target; :class:`AccuracyError` when no level of
  the model can (a target finer than level 6 gives, a quantity the model has no value for).

This module reads a JSON file and does arithmetic: no numba, no capsim imports.
"""

from __future__ import annotations

import json
import math
from functools import lru_cache
from pathlib import Path
from typing import Any

MODEL_FILE = Path(__file__).with_name("error_model.json")
#: the time error time.rtol auto allows: this fraction of the level's mesh error
TIME_FRACTION = 0.1
#: the tolerances auto and the target choose among (loosest first). Never looser than 2e-3, whatever
#: the mesh: beyond the values at t_end the model knows, a loose tolerance lets the volume drift
#: (a tumbling oblate at λ 10, level 1, rkc: past the 1 % guard by kt 13 at rtol 1e-2, 0.19 % over
#: kt 40 at 2e-3; the promise table's case (e) likewise at 1e-2)
RTOL_LADDER = (2e-3, 1e-3, 5e-4, 2e-4, 1e-4, 5e-5, 2e-5, 1e-5)
#: the quantities a target may name (the model's), and their other names
ALIASES = {"theta": "theta", "θ": "theta", "D_xy": "D_xy", "D": "D_xy", "Sxy_star": "Sxy_star",
           "S*_xy": "Sxy_star"}


class AccuracyError(ValueError):
    """A target the model cannot meet or a quantity it has no value for (one line)."""


@lru_cache(maxsize=1)
def model() -> dict[str, Any]:
    """The error model (capsim/error_model.json)."""
    return json.loads(MODEL_FILE.read_text(encoding="utf-8"))


def entry(shape: str, lambda_one: bool) -> tuple[dict[str, Any], str]:
    """(the model's entry, its label) for a case of this rest shape and λ: the training case of
    the same shape and λ regime (λ = 1 or not), else the envelope of all, said so."""
    m = model()
    for e in m["classes"]:
        if e["shape"] == shape and e["lambda_one"] == lambda_one:
            return e, e["label"]
    return m["envelope"], (f"the envelope of every training case ({shape}, λ {'=' if lambda_one else '≠'} 1 is "
                           "outside the error model's training cases)")


def levels() -> list[int]:
    m = model()
    return sorted(int(k) for k in m["envelope"]["mesh"][m["quantities"][0]])


def mesh_error(e: dict[str, Any], quantity: str, level: int) -> float:
    return float(e["mesh"][quantity][str(level)])


def time_error(e: dict[str, Any], quantity: str, rtol: float) -> float:
    """The time error at this rtol: log-log interpolation between the measured tolerances (below
    the tightest, proportional to rtol; above the loosest, too)."""
    table = sorted((float(r), float(v)) for r, v in e["time"][quantity].items())
    rs, vs = [r for r, _ in table], [max(v, 1e-300) for _, v in table]
    if rtol <= rs[0]:
        return vs[0] * rtol / rs[0]
    if rtol >= rs[-1]:
        return vs[-1] * rtol / rs[-1]
    for (r0, v0), (r1, v1) in zip(zip(rs, vs), zip(rs[1:], vs[1:])):
        if r0 <= rtol <= r1:
            w = math.log(rtol / r0) / math.log(r1 / r0)
            return math.exp(math.log(v0) + w * math.log(v1 / v0))
    return vs[-1]


def auto_rtol(level: int, shape: str = "sphere", lambda_one: bool = True) -> tuple[float, str]:
    """(rtol, why) for time.rtol auto: the largest of RTOL_LADDER whose time error stays below
    TIME_FRACTION of the level's mesh error for every quantity."""
    e, label = entry(shape, lambda_one)
    names = model()["quantities"]
    level = max(level, min(levels()))  # level 0: its mesh error is above level 1's, as is its tolerance
    for rtol in RTOL_LADDER:
        if all(time_error(e, q, rtol) <= TIME_FRACTION * mesh_error(e, q, level) for q in names):
            break
    limiting = max(names, key=lambda q: time_error(e, q, rtol) / mesh_error(e, q, level))
    why = (f"auto: rtol {rtol:g} keeps the time error below {TIME_FRACTION:g} of the level-{level} mesh error "
           f"of every reported value ({limiting}: {time_error(e, limiting, rtol):.2g} against "
           f"{mesh_error(e, limiting, level):.2g}; error model of {label})")
    return rtol, why


def canonical(quantity: str) -> str:
    name = ALIASES.get(quantity)
    if name is None or name not in model()["quantities"]:
        raise AccuracyError(f"accuracy.quantity = {quantity!r}: the error model has {', '.join(model()['quantities'])}")
    return name


def predicted_cost(e: dict[str, Any], level: int, rtol: float, t_end: float) -> float:
    """Predicted wall seconds of a run to t_end at this level and rtol (one core)."""
    c = e["evaluations_per_kt"]
    evaluations = c["a"] * rtol ** (-c["b"]) * t_end
    return evaluations * float(model()["seconds_per_evaluation"][str(level)])


def choose(quantity: str, target: float, t_end: float, shape: str = "sphere", lambda_one: bool = True
           ) -> dict[str, Any]:
    """The (level, rtol) of least predicted cost whose predicted error, mesh plus time, meets
    ``target`` (relative for D_xy and S*_xy, rad for θ). AccuracyError when no level of the
    model can."""
    q = canonical(quantity)
    if not (isinstance(target, (int, float)) and math.isfinite(target) and target > 0):
        raise AccuracyError(f"accuracy.target = {target!r}: a positive number is expected")
    e, label = entry(shape, lambda_one)
    best = None
    for level in levels():
        for rtol in RTOL_LADDER:
            error = mesh_error(e, q, level) + time_error(e, q, rtol)
            if error <= target:
                cost = predicted_cost(e, level, rtol, t_end)
                if best is None or cost < best["cost_s"]:
                    best = {"quantity": q, "level": level, "rtol": rtol, "error": error, "cost_s": cost}
                break  # a tighter rtol at this level costs more
    if best is None:
        finest = mesh_error(e, q, max(levels()))
        raise AccuracyError(f"accuracy.target = {target:g}: finer than the finest level gives for {q} "
                            f"({finest:.2g} at level {max(levels())}; error model of {label}); ask for at least that")
    best["why"] = (f"accuracy {q} {target:g}: level {best['level']}, rtol {best['rtol']:g}; predicted error "
                   f"{best['error']:.2g}, predicted cost {best['cost_s']:.3g} s on one core (error model of {label})")
    return best

"""Ask for an accuracy, get the cheapest run: ``time.rtol: auto`` and the case's
``accuracy`` target, from the error model measured by ``benchmarks/error_model.py``
(``capsim/solve/error_model.json``; its tables: docs/benchmarks.md, "Error model").

The model holds, for each training case (shapes, laws, λ and G spanning the validation) and
each reported quantity q (D_xy, θ, S*_xy at t_end): the mesh's error at each level
e_mesh(q, level) (relative; θ absolute in rad), the time error at each rtol, and the cost:
velocity evaluations per unit kt ≈ a · rtol^(−b), times the seconds of one evaluation at
each level.

- ``nearest(features)``: the training cases nearest to a case (:data:`DISTANCE`: the rest
  shape first, then whether λ = 1, bending, the law and its parameter, G, λ, the aspect ratio); several within
  :data:`TIE` of the nearest give their largest errors. A shape no training case has takes the
  envelope of all, said so.
- ``auto_rtol(level, features)``: the largest rtol of :data:`RTOL_LADDER` whose time error stays
  below :data:`TIME_FRACTION` of the level's mesh error for every quantity: a tighter tolerance
  buys no digit the mesh has.
- ``choose(quantity, target, t_end, features)``: the (level, rtol) of least predicted cost whose
  predicted error, (mesh + time) × the model's safety factor for q, meets the target. The
  safety factor is measured, not chosen: leave each training case out, predict it from the
  others, and take the ratio actual / predicted that covers :data:`SAFETY_QUANTILE` of them
  (benchmarks/error_model.py). :class:`AccuracyError` when no level of the model can (a target
  finer than level 6 gives, a quantity the model has no value for).
- ``plan(quantity, target, t_end, features, method)``: how a target is met: ``predict`` (the
  choice above), ``measure`` (the ladder of :mod:`capsim.runs.ladder`: levels 1, 2, … at one rtol,
  each run's error estimated from the levels below it by :func:`measured_error`, the first that
  meets the target kept), or ``auto``: predict where the model is sure of the case, measure where
  it is not (outside its range, or its nearest training cases disagree :data:`SPREAD`-fold) and
  predicts a level finer than :data:`MEASURE_ABOVE_LEVEL`. A scene the model was not trained on
  (:data:`TRAINED_SCENE`: another flow or history, a wall, several capsules) is never predicted:
  ``auto`` measures it, ``predict`` is refused; a quantity the scene's symmetry fixes
  (:data:`FIXED_BY_SYMMETRY`) takes no target by any method.

The scene's own quantities (:data:`SCENE_QUANTITIES`, issue 54: ``lift``, ``slip``, ``separation``,
``migration``, ``gap``, each a column of the run's summary) have no training case: a target on one is
measured (the ladder), never predicted, and refused in a scene that does not have it (lift without a
wall, separation without a pair).

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


#: the scene's own quantities (issue 54): summary columns the error model has no training case for (a target
#: on one is measured, never predicted). Each: its short name (an alias), what the ladder reads of the run's
#: summary, what the scene must have (said when refused) and the test of the case's features
#: (Case.error_model_features) for it. Relative errors, as the model's D_xy and S*_xy (:data:`SCENE_TIME_ERROR`)
SCENE_QUANTITIES: dict[str, dict[str, Any]] = {
    "centroid_velocity_y": {"short": "lift", "reads": "the lift velocity's mean over the averaging window",
                            "needs": "a plane wall (wall:)",
                            "has": lambda f: bool(f.get("wall")) and f.get("flow") != "conduit"},
    "slip_velocity_x": {"short": "slip", "reads": "the slip velocity's mean over the averaging window",
                        "needs": "a wall, a conduit, a Poiseuille flow or several capsules (in an unbounded linear "
                                 "flow one capsule is carried with the flow: no slip)",
                        "has": lambda f: bool(f.get("wall")) or "axis_offset" in f or f.get("capsules", 1) > 1},
    "separation_y_final": {"short": "separation", "reads": "the pair's cross-stream separation at the end",
                           "needs": "two capsules (capsules:)", "has": lambda f: f.get("capsules", 1) == 2},
    "migration_y": {"short": "migration", "reads": "the centroid's migration in y from the start to the end",
                    "needs": "a Poiseuille flow (flow.kind poiseuille)",
                    "has": lambda f: "axis_offset" in f and not f.get("wall")},
    "wall_gap_final": {"short": "gap", "reads": "the gap between membrane and wall at the end",
                       "needs": "a wall or a conduit", "has": lambda f: bool(f.get("wall"))},
}
ALIASES.update({name: name for name in SCENE_QUANTITIES})
ALIASES.update({spec["short"]: name for name, spec in SCENE_QUANTITIES.items()})
#: every name a target may give (the model's, the scene's, their short names)
QUANTITY_NAMES = tuple(ALIASES)
#: the time error assumed for a scene quantity at tolerance rtol, relative: rtol times this. No training case
#: measures it; measured (level 2, kt 2, rtol 1e-3 and 2e-3 against 1e-5) it was 0.04-0.4 rtol for the lift,
#: slip, gap and migration of a sphere at h 1.6 from a wall and 1.5 a off a Poiseuille axis (R 5)
SCENE_TIME_ERROR = 1.0
#: a relative error at least this large says the value is within its own error of 0 (a lift far from the wall,
#: a migration that has not started): relative to it the error means nothing; the ladder's verdict says so and
#: gives the absolute error beside (it never turns the target into an absolute one silently)
MEANINGLESS_RELATIVE = 1.0


class AccuracyError(ValueError):
    """A target the model cannot meet or a quantity it has no value for (one line)."""


@lru_cache(maxsize=1)
def model() -> dict[str, Any]:
    """The error model (capsim/solve/error_model.json)."""
    return json.loads(MODEL_FILE.read_text(encoding="utf-8"))


#: how far a training case is from a case, per feature (a different rest shape outweighs every
#: other: the mesh's error is set first by the curvature it must resolve; then the λ regime, as
#: the double-layer solve changes the time error tenfold; then bending, law, G, λ, aspect ratio)
DISTANCE = {"shape": 100.0, "lambda_one": 10.0, "bending": 3.0, "law": 2.0, "law_parameter": 2.0,
            "log10_G": 2.0, "log10_lambda": 1.0, "aspect_ratio": 4.0}
#: training cases within this distance of the nearest count too (their largest error is taken)
TIE = 1.0
#: a case farther than this from every training case is outside the model's range (said so): e.g.
#: G or λ a decade and a half beyond the grid, or another law at another G
FAR = 2.5
#: rtol auto outside the training's range: never looser than this (the default before rtol auto, the
#: tolerance the validation tables were measured at)
OUTSIDE_RTOL = 1e-4
#: training cases whose errors at the chosen level differ more than this factor: the prediction is
#: uncertain there (said so, with the check to run)
SPREAD = 10.0
#: an uncertain prediction finer than this level is refused under method predict (method auto
#: measures instead: the ladder's levels 1-3 cost less than trusting it)
MEASURE_LEVEL = 3
#: method auto measures an uncertain prediction finer than this level: there the ladder's coarser
#: levels add a fraction of the predicted run's cost (levels 1-2 are ~0.3 of a level-3 run) and buy
#: the check; an uncertain level 1 or 2 is run as predicted, said so (its ladder would cost 1.5-3×
#: the run: benchmarks/accuracy_target.md)
MEASURE_ABOVE_LEVEL = 2
#: how a target is met (accuracy.method): auto picks predict or measure per case (plan)
METHODS = ("auto", "predict", "measure")
#: the measured ladder's largest observed order: beyond it two differences say little more
#: (the training's Richardson orders are clipped to [1.5, 4] alike, benchmarks/error_model.py)
LADDER_MAX_ORDER = 4.0
#: the ladder's order from only two levels (no observed order yet): the smallest of the training's
#: (clipped) orders; 18-40 % of its cases are below 2 (D_xy, S*_xy, θ), which 2 would underestimate
#: up to 1.6-fold: the level-2 estimate errs large, never small, on a case like them
LADDER_TWO_LEVEL_ORDER = 1.5
#: the fraction of left-out training cases whose error the safety factor covers (error_model.py)
SAFETY_QUANTILE = 0.9


def distance(a: dict[str, Any], b: dict[str, Any]) -> float:
    """The distance between two cases' features (:data:`DISTANCE`)."""
    w = DISTANCE
    lam_a, lam_b = float(a["viscosity_ratio"]), float(b["viscosity_ratio"])
    return (w["shape"] * (a["shape"] != b["shape"])
            + w["lambda_one"] * ((lam_a == 1.0) != (lam_b == 1.0))
            + w["bending"] * (bool(a["bending"]) != bool(b["bending"]))
            + w["law"] * (a["law"] != b["law"])
            # Skalak's C (area dilatation over shear) or Mooney-Rivlin's ψ: per decade of 1 + p
            + w["law_parameter"] * abs(math.log10((1.0 + a.get("law_parameter", 0.0)) / (1.0 + b.get("law_parameter", 0.0))))
            + w["log10_G"] * abs(math.log10(float(a["G"]) / float(b["G"])))
            + w["log10_lambda"] * abs(math.log10(lam_a / lam_b))
            + w["aspect_ratio"] * abs(float(a["aspect_ratio"]) - float(b["aspect_ratio"])))


def merge(cases: list[dict[str, Any]]) -> dict[str, Any]:
    """One model entry from several training cases: the largest error per level and per rtol,
    the smallest order, the largest cost."""
    names = cases[0]["mesh"].keys()
    out: dict[str, Any] = {"mesh": {}, "time": {}, "order": {}}
    for q in names:
        out["mesh"][q] = {lv: max(float(c["mesh"][q][lv]) for c in cases) for lv in cases[0]["mesh"][q]}
        out["time"][q] = {r: max(float(c["time"][q][r]) for c in cases) for r in cases[0]["time"][q]}
        out["order"][q] = min(float(c["order"][q]) for c in cases)
    a = max(float(c["evaluations_per_kt"]["a"]) for c in cases)
    b = max(float(c["evaluations_per_kt"]["b"]) for c in cases)
    out["evaluations_per_kt"] = {"a": a, "b": b}
    return out


def nearest(features: dict[str, Any], cases: list[dict[str, Any]] | None = None) -> tuple[dict[str, Any], str]:
    """(the model's entry, its label) for a case of these features: the training cases nearest to
    it (within TIE of the nearest, their largest errors); a shape none of them has: the envelope
    of all, said so."""
    cases = model()["cases"] if cases is None else cases
    ranked = sorted((distance(features, c["features"]), k) for k, c in enumerate(cases))
    if ranked[0][0] >= DISTANCE["shape"]:
        return merge(cases), (f"the envelope of every training case (no training case is a {features['shape']})")
    chosen = [cases[k] for d, k in ranked if d <= ranked[0][0] + TIE]
    label = "; ".join(c["label"] for c in chosen)
    outside = ranked[0][0] > FAR
    if outside:
        label += f" (the nearest is {ranked[0][0]:.2g} away, beyond {FAR:g}: outside the training's range)"
    return {**merge(chosen), "members": chosen, "outside": outside}, label


#: a sphere of the thin-shell law at G 0.1, λ 1: the training case of the demo (the default case)
DEFAULT_FEATURES = {"shape": "sphere", "aspect_ratio": 1.0, "law": "thin_shell", "law_parameter": 0.0, "G": 0.1,
                    "viscosity_ratio": 1.0, "bending": False}


#: the scene every training case ran in (benchmarks/error_model.py): one capsule in steady, unbounded
#: simple shear. Case.error_model_features gives a case's own; a scene that differs in any of these is
#: one the model has never seen (issue 51: its shear-only errors were 3.5-180x off in planar extension,
#: on the Poiseuille axis and after the flow stops), so nothing is predicted for it: method auto
#: measures it (the ladder), method predict is refused (:func:`scene_outside`)
TRAINED_SCENE = {"flow": "simple_shear", "history": "steady", "wall": False, "capsules": 1, "prestress": False}
#: how each scene feature that differs from the training's is named (to the user: the field that sets it)
SCENE_NAMES = {"flow": "flow.kind {v}", "history": "flow.history.kind {v} (the rate changes before t_end)",
               "wall": "a wall or a conduit", "capsules": "{v} capsules",
               # every training membrane was stress-free at rest (issue 55: another stress-free shape pre-stresses it)
               "prestress": "a pre-stressed membrane (shape.inflation or membrane.reference_shape)"}


def scene_outside(features: dict[str, Any] | None) -> str:
    """What in a case's scene the error model was not trained on ('' where nothing: a case without
    scene features is the training's scene)."""
    features = features or {}
    return ", ".join(SCENE_NAMES[k].format(v=features[k]) for k, trained in TRAINED_SCENE.items()
                     if k in features and features[k] != trained)


def _axisymmetric(f: dict[str, Any]) -> bool:
    """Uniaxial extension, or a capsule on the Poiseuille axis: the flow is axisymmetric about x."""
    return f.get("flow") == "uniaxial_extension" or (f.get("flow") in ("poiseuille", "conduit")
                                                     and f.get("axis_offset") == 0.0)


#: a quantity the scene's symmetry fixes, whatever the mesh: a target on it measures nothing (zero or a
#: constant at every level: the ladder's differences vanish and it would report any target met; a relative
#: error of zero is not defined), refused with the reason, by method (registry: (applies, quantity, why))
FIXED_BY_SYMMETRY = (
    (lambda f: f.get("flow") in ("planar_extension", "uniaxial_extension") or _axisymmetric(f), "Sxy_star",
     "the shear stress S*_xy vanishes by the flow's symmetry (a relative error of zero is not defined)"),
    (lambda f: f.get("flow") == "planar_extension", "theta",
     "θ is 0 by the flow's symmetry (the long axis lies along the stretching direction x at every level)"),
    (_axisymmetric, "theta",
     "θ is 0 or π/2 by the flow's axial symmetry (whichever of the x and y axes is longer: a jump, not a "
     "converging value)"),
    (_axisymmetric, "migration_y", "a capsule on the Poiseuille axis does not migrate (0 by the flow's axial symmetry)"),
)


def fixed_by_symmetry(quantity: str, features: dict[str, Any] | None) -> str:
    """Why the scene fixes this quantity whatever the mesh ('' where it does not): no target can be met on it."""
    f = features or {}
    return next((why for applies, q, why in FIXED_BY_SYMMETRY if q == quantity and applies(f)), "")


def entry(features: dict[str, Any] | None = None) -> tuple[dict[str, Any], str]:
    """(the model's entry, its label) for a case of these features (nearest)."""
    return nearest(features or DEFAULT_FEATURES)


def levels() -> list[int]:
    m = model()
    return sorted(int(k) for k in m["cases"][0]["mesh"][m["quantities"][0]])


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


def auto_rtol(level: int, features: dict[str, Any] | None = None) -> tuple[float, str]:
    """(rtol, why) for time.rtol auto: the largest of RTOL_LADDER whose time error stays below
    TIME_FRACTION of the level's mesh error for every quantity (the model's best estimate,
    without the safety factor of a target: this rule is a ratio of two estimates). In a scene the
    model was not trained on (:func:`scene_outside`: another flow, a history, a wall, several
    capsules) it estimates no time error: the rule's rtol, never looser than OUTSIDE_RTOL, and the
    reason says so (and how the steps follow the flow's history: capsim.scene.flows.History.steps)."""
    e, label = entry(features)
    names = model()["quantities"]
    level = max(level, min(levels()))  # level 0: its mesh error is above level 1's, as is its tolerance
    for rtol in RTOL_LADDER:
        if all(time_error(e, q, rtol) <= TIME_FRACTION * mesh_error(e, q, level) for q in names):
            break
    scene = scene_outside(features)
    if scene:
        from capsim.scene.flows import FLOW_HISTORIES  # numpy only

        rtol = min(rtol, OUTSIDE_RTOL)
        why = (f"auto: rtol {rtol:g}, not a predicted error: the error model was not trained on this scene "
               f"({scene}) and estimates no time error for it; auto takes no looser than {OUTSIDE_RTOL:g} there "
               "(the validation tables' tolerance): check with a tighter time.rtol")
        steps = FLOW_HISTORIES[features["history"]].steps if features.get("history") in FLOW_HISTORIES else ""
        return rtol, why + (f"; {steps}" if steps else "")
    outside = e.get("outside", False)
    if outside and rtol > OUTSIDE_RTOL:  # the model does not know this case: the tolerance validated without it
        rtol = OUTSIDE_RTOL
    limiting = max(names, key=lambda q: time_error(e, q, rtol) / mesh_error(e, q, level))
    why = (f"auto: rtol {rtol:g} keeps the time error below {TIME_FRACTION:g} of the level-{level} mesh error "
           f"of every reported value ({limiting}: {time_error(e, limiting, rtol):.2g} against "
           f"{mesh_error(e, limiting, level):.2g}; error model of {label})")
    if outside:
        why += f"; never looser than {OUTSIDE_RTOL:g} outside the training's range"
    return rtol, why


def canonical(quantity: str) -> str:
    """The column a target's quantity names (D -> D_xy, lift -> centroid_velocity_y); AccuracyError for a name
    neither the error model nor the scene quantities have."""
    name = ALIASES.get(quantity)
    if name is None or (name not in model()["quantities"] and name not in SCENE_QUANTITIES):
        raise AccuracyError(f"accuracy.quantity = {quantity!r}: allowed: {', '.join(model()['quantities'])} "
                            f"(the error model's), {', '.join(s['short'] for s in SCENE_QUANTITIES.values())} "
                            "(the scene's, measured)")
    return name


def short_name(quantity: str) -> str:
    """How a target's quantity is said: a scene quantity by its short name and column (lift,
    centroid_velocity_y), the model's by its name."""
    spec = SCENE_QUANTITIES.get(quantity)
    return f"{spec['short']} ({quantity})" if spec else quantity


def allowed_quantities(features: dict[str, Any] | None) -> list[str]:
    """The quantities a target may name in this scene: the model's (less those its symmetry fixes) and
    the scene quantities it has (by short name)."""
    f = features or {}
    names = [q for q in model()["quantities"] if not fixed_by_symmetry(q, f)]
    return names + [spec["short"] for q, spec in SCENE_QUANTITIES.items()
                    if spec["has"](f) and not fixed_by_symmetry(q, f)]


def is_relative(quantity: str) -> bool:
    """Whether a quantity's errors are relative (the convention; θ's are absolute, in rad)."""
    return quantity in SCENE_QUANTITIES or quantity not in model()["absolute"]


def ladder_time_error(quantity: str, rtol: float, features: dict[str, Any] | None = None) -> float:
    """The time error the ladder adds to each level's mesh estimate at one rtol: the model's prediction
    with its safety factor; for a scene quantity, which no training case has, SCENE_TIME_ERROR × rtol
    (relative)."""
    if quantity in SCENE_QUANTITIES:
        return SCENE_TIME_ERROR * rtol
    return safety(quantity) * time_error(entry(features)[0], quantity, rtol)


def _refuse_absent(quantity: str, features: dict[str, Any] | None) -> None:
    """A scene quantity the case's scene does not have: refused, naming what it needs and what is allowed."""
    spec = SCENE_QUANTITIES.get(quantity)
    features = features or {}  # none given: the training's scene (one capsule in unbounded shear)
    if spec is None or spec["has"](features):
        return
    raise AccuracyError(f"accuracy.quantity = {spec['short']!r}: {spec['short']} ({quantity}) needs {spec['needs']}, "
                        f"which this scene has not; allowed here: {', '.join(allowed_quantities(features))}")


def predicted_cost(e: dict[str, Any], level: int, rtol: float, t_end: float) -> float:
    """Predicted wall seconds of a run to t_end at this level and rtol (one core)."""
    c = e["evaluations_per_kt"]
    evaluations = c["a"] * rtol ** (-c["b"]) * t_end
    return evaluations * float(model()["seconds_per_evaluation"][str(level)])


def safety(quantity: str) -> float:
    """The factor on a predicted error that covers SAFETY_QUANTILE of the left-out training cases."""
    return float(model()["safety"][quantity])


def choose(quantity: str, target: float, t_end: float, features: dict[str, Any] | None = None,
           quiet_uncertain: bool = False) -> dict[str, Any]:
    """The (level, rtol) of least predicted cost whose predicted error, (mesh + time) × safety(q),
    meets ``target`` (relative for D_xy and S*_xy, rad for θ), with ``uncertain`` (what makes the
    prediction uncertain, '' when nothing does). AccuracyError when no level of the model can, and
    for an uncertain prediction finer than MEASURE_LEVEL unless ``quiet_uncertain``."""
    q = canonical(quantity)
    _check_target(target)
    _refuse_absent(q, features)
    _refuse_void(q, features)
    if q in SCENE_QUANTITIES:  # no training case has it: nothing to predict from
        raise AccuracyError(f"accuracy.method = 'predict': the error model has no training case for "
                            f"{short_name(q)}; give accuracy.method measure or auto (both run levels 1, 2, ... until "
                            "the case's own error estimate meets the target)")
    scene = scene_outside(features)
    if scene:  # never predicted silently from cases of another scene
        raise AccuracyError(f"accuracy.method = 'predict': the error model was trained on one capsule in steady, "
                            f"unbounded simple shear only, not on this scene ({scene}); give accuracy.method "
                            "measure or auto (both run levels 1, 2, ... until the case's own error estimate meets "
                            "the target)")
    e, label = entry(features)
    factor = safety(q)
    best = None
    for level in levels():
        for rtol in RTOL_LADDER:
            error = factor * (mesh_error(e, q, level) + time_error(e, q, rtol))
            if error <= target:
                cost = predicted_cost(e, level, rtol, t_end)
                if best is None or cost < best["cost_s"]:
                    best = {"quantity": q, "level": level, "rtol": rtol, "error": error, "cost_s": cost}
                break  # a tighter rtol at this level costs more
    if best is None:
        finest = factor * mesh_error(e, q, max(levels()))
        raise AccuracyError(f"accuracy.target = {target:g}: finer than the finest level gives for {q} "
                            f"({finest:.2g} at level {max(levels())}; error model of {label}); ask for at least that, "
                            "or measure this case's own errors: give accuracy.method measure")
    best["why"] = (f"accuracy {q} {target:g}: level {best['level']}, rtol {best['rtol']:g}; predicted error "
                   f"{best['error']:.2g} (safety factor {factor:.2g} included), predicted cost {best['cost_s']:.3g} s "
                   f"on one core (error model of {label})")
    caveat = uncertainty(e, q, best["level"])
    best["uncertain"] = caveat
    if caveat and best["level"] > MEASURE_LEVEL and not quiet_uncertain:
        # an uncertain prediction of a fine level: measuring the case's own errors (levels 1-3) costs
        # less than trusting it (the oblate 0.7 of benchmarks/accuracy_target.md: level 6 predicted, level 2 enough)
        raise AccuracyError(f"accuracy.target = {target:g}: the error model cannot place this case ({caveat}; "
                            f"it predicts level {best['level']}, {best['cost_s']:.2g} s); measuring is cheaper: "
                            "give accuracy.method measure (or auto), which runs levels 1, 2, ... until the case's own "
                            "error estimate meets the target")
    if caveat:
        best["why"] += f"; {caveat}: {CHECK}"
    return best


def plan(quantity: str, target: float, t_end: float, features: dict[str, Any] | None = None,
         method: str = "auto", max_level: int = 4) -> dict[str, Any]:
    """How the target is met: ``{"method": "predict", level, rtol, error, cost_s, why}`` (:func:`choose`)
    or ``{"method": "measure", "level": 1, rtol, why}`` (the ladder of :mod:`capsim.runs.ladder`, up to
    ``max_level``). ``auto`` predicts where the model is sure of the case and measures where it is not
    and predicts a level finer than MEASURE_ABOVE_LEVEL, or says no level can (an uncertain model's
    "impossible" is a guess too). AccuracyError for a target no method can take (an unknown quantity, not a positive number;
    under predict, what :func:`choose` refuses)."""
    if method not in METHODS:
        raise AccuracyError(f"accuracy.method = {method!r}: allowed: {', '.join(METHODS)}")
    q = canonical(quantity)
    _check_target(target)
    _refuse_absent(q, features)
    _refuse_void(q, features)
    if method == "predict":
        return {**choose(q, target, t_end, features), "method": "predict"}
    reason = "asked for (accuracy.method measure)"
    scene = scene_outside(features)
    if method == "auto" and q in SCENE_QUANTITIES:
        reason = f"the error model has no training case for {short_name(q)}"
    elif method == "auto" and scene:
        reason = f"the error model was not trained on this scene ({scene})"
    elif method == "auto":
        try:
            best = choose(q, target, t_end, features, quiet_uncertain=True)
        except AccuracyError:
            caveat = uncertainty(entry(features)[0], q, MEASURE_LEVEL)
            if not caveat:
                raise  # a model sure of the case says no level can: the target is refused
            reason = f"the error model cannot place this case ({caveat}; it predicts no level can)"
        else:
            if not best["uncertain"] or best["level"] <= MEASURE_ABOVE_LEVEL:
                return {**best, "method": "predict"}
            reason = f"the error model cannot place this case ({best['uncertain']}; it predicts level {best['level']})"
    rtol = ladder_rtol(q, target, features)
    why = (f"accuracy {q} {target:g}: measured, {reason}: levels 1, 2, ... up to {max_level} at rtol {rtol:g}, "
           "each run's error estimated from the levels below it (Richardson), the first that meets the target kept")
    if q in SCENE_QUANTITIES:
        why += (f"; the value: {SCENE_QUANTITIES[q]['reads']}; its error relative to it (the absolute beside), the "
                f"time error taken as {SCENE_TIME_ERROR:g} × rtol (not modelled); a value within its error of 0 "
                "meets no relative target (the verdict says so)")
    return {"method": "measure", "quantity": q, "level": 1, "rtol": rtol, "why": why}


def ladder_rtol(quantity: str, target: float, features: dict[str, Any] | None = None) -> float:
    """The measured ladder's one tolerance: the loosest of RTOL_LADDER whose predicted time error
    (with the safety factor, from the nearest training cases' largest) is at most TIME_FRACTION of
    the target. Not capped at OUTSIDE_RTOL outside the training's range, as rtol auto is: the
    ladder's differences at one rtol would show a time error that large as levels that do not
    converge, and 1e-4 made its levels cost 3-5× those at 2e-3 (benchmarks/accuracy_target.md)."""
    q = canonical(quantity)
    for rtol in RTOL_LADDER:
        if ladder_time_error(q, rtol, features) <= TIME_FRACTION * target:
            break
    return rtol


def _refuse_void(quantity: str, features: dict[str, Any] | None) -> None:
    why = fixed_by_symmetry(quantity, features)
    if why:
        raise AccuracyError(f"accuracy.quantity = {quantity!r}: {why}; no target on it can be predicted or measured "
                            "in this scene: give a target on another quantity, or mesh.level and time.rtol")


def _check_target(target: Any) -> None:
    if not (isinstance(target, (int, float)) and math.isfinite(target) and target > 0):
        raise AccuracyError(f"accuracy.target = {target!r}: a positive number is expected")


def observed_order(d_coarse: float, d_fine: float) -> float | None:
    """The order log2(d_coarse / d_fine) that two successive differences of a quantity over mesh
    levels show (f_(L−1) − f_(L−2), then f_L − f_(L−1)); None where they differ in sign or one is
    zero: levels that overshoot and come back show no order, however their sizes compare. The one
    rule of the ladder (:func:`measured_error`), ``capsim study --reference richardson`` and the
    error model's training (benchmarks/error_model.py)."""
    if not d_coarse * d_fine > 0:
        return None
    return math.log2(d_coarse / d_fine)


def measured_error(values: list[float], relative: bool, period: float | None = None) -> dict[str, Any]:
    """The error of the last of ``values`` (one quantity at consecutive mesh levels, one rtol) by
    Richardson from the levels below it: |f_L − f_(L−1)| / (2^p − 1), relative to |f_L| when
    ``relative``; differences taken modulo ``period`` (θ: π).

    p is the observed order log2(|d_(L−1)| / |d_L|) of the last two differences (at most
    LADDER_MAX_ORDER) where they have one sign and shrink: the levels converge. Where they do not
    (the sign changes, or the last difference is the larger: not yet in the asymptotic range)
    ``converging`` is False and the error is the larger difference: no estimate, a scale. From two
    levels only, p is LADDER_TWO_LEVEL_ORDER (``order_from_levels`` False).

    Returns {"error", "order", "converging", "order_from_levels"}."""
    def diff(a: float, b: float) -> float:
        d = a - b
        return (d + period / 2) % period - period / 2 if period else d

    if len(values) < 2:
        return {"error": math.inf, "order": math.nan, "converging": False, "order_from_levels": False}
    scale = max(abs(values[-1]), 1e-300) if relative else 1.0
    d = diff(values[-1], values[-2])
    if len(values) == 2:
        p = LADDER_TWO_LEVEL_ORDER
        return {"error": abs(d) / (2.0**p - 1.0) / scale, "order": p, "converging": True, "order_from_levels": False}
    d_prev = diff(values[-2], values[-3])
    if d == 0.0:
        return {"error": 0.0, "order": math.inf, "converging": True, "order_from_levels": True}
    p = observed_order(d_prev, d)
    if p is not None and p > 0:  # one sign, and the last difference the smaller: converging
        p = min(p, LADDER_MAX_ORDER)
        return {"error": abs(d) / (2.0**p - 1.0) / scale, "order": p, "converging": True, "order_from_levels": True}
    return {"error": max(abs(d), abs(d_prev)) / scale, "order": math.nan, "converging": False,
            "order_from_levels": True}


def uncertainty(e: dict[str, Any], quantity: str, level: int) -> str:
    """What makes a prediction uncertain ('' when nothing does): the case is outside the training's
    range, or its nearest training cases disagree SPREAD-fold (the reason alone; :data:`CHECK` is
    the check to run)."""
    members = e.get("members", [])
    errors = [float(c["mesh"][quantity][str(level)]) for c in members]
    if e.get("outside", False):
        return "outside the error model's range"
    if len(errors) > 1 and max(errors) > SPREAD * max(min(errors), 1e-300):
        return f"the nearest training cases disagree {max(errors) / max(min(errors), 1e-300):.0f}-fold at level {level}"
    return ""


#: what an uncertain prediction that is run as predicted says to do
CHECK = "check it with capsim run --verify, or give accuracy.method measure"

"""Physical units in, capsim's dimensionless numbers out (pint parses the quantities).

capsim scales lengths by the equal-volume radius a, times by the inverse shear
rate 1/k and membrane tensions by the elastic modulus E_s, so a case needs one
number for the flow strength: G = μ k a / E_s (``flow.shear_rate_G``). Papers often
quote the capillary number built on the surface shear modulus G_s instead,
Ca = μ k a / G_s; every elastic law of capsim has G_s = E_s / 3 (small-strain
shear modulus in units of E_s: ``membrane_law/G_s`` of a run file), so Ca = 3 G.

Worked examples (tests/test_units.py checks them):

- a red blood cell: k = 100 1/s, μ = 1.2 mPa·s, a = 2.8 μm, G_s = 6 μN/m →
  Ca = 1.2e-3 × 100 × 2.8e-6 / 6e-6 = 0.056, G = Ca / 3 = 0.018667, 1/k = 0.01 s;
- its membrane viscosity μ_s = 1e-7 N·s/m (the low end of the 0.5–5 × 10⁻⁷ N·s/m
  quoted for red cells; configs/rbc-viscous.yaml) in that fluid:
  Bq = μ_s/(μ a) = 1e-7 / (1.2e-3 × 2.8e-6) = 29.76, membrane time μ_s/G_s = 0.0167 s;
- an alginate capsule: k = 10 1/s, μ = 1 Pa·s (silicone oil), a = 1 mm,
  E_s = 0.1 N/m → G = 1 × 10 × 1e-3 / 0.1 = 0.1, Ca = 0.3, 1/k = 0.1 s.

Only :func:`parse` imports pint, so that importing this module (from the case
validation) costs nothing until a ``physical:`` block is given.
"""

from __future__ import annotations

import math
import re
from functools import lru_cache
from typing import Any

from capsim.errors import bounded_repr, first_line

__all__ = ["KINDS", "UnitsError", "conversion", "likeliest_slip", "parse", "physical_factors", "scale_values"]

#: G_s / E_s of every elastic law of capsim (capsim.numerics.membrane: the small-strain shear modulus)
SHEAR_OVER_ELASTIC_MODULUS = 1.0 / 3.0

#: what each physical value is: (SI unit it is converted to, what it must measure, an example)
KINDS: dict[str, tuple[str, str, str]] = {
    "shear_rate": ("1/s", "a shear rate (1/time)", "100 1/s"),
    "viscosity": ("Pa*s", "a dynamic viscosity (pressure × time)", "1.2 mPa*s"),
    "inner_viscosity": ("Pa*s", "a dynamic viscosity (pressure × time)", "6 mPa*s"),
    "radius": ("m", "a length", "2.8 um"),
    "surface_modulus": ("N/m", "a surface modulus (force / length)", "18 uN/m"),
    "shear_modulus": ("N/m", "a surface modulus (force / length)", "6 uN/m"),
    "bending_modulus": ("J", "an energy (a bending modulus)", "1.8e-19 J"),
    "membrane_viscosity": ("N*s/m", "a surface viscosity (force × time / length)", "2.5e-7 N*s/m"),
}


class UnitsError(ValueError):
    """A physical value that is not a positive, finite quantity of the right kind; one line."""


@lru_cache(maxsize=1)
def _registry():
    import pint

    return pint.UnitRegistry()


#: longest quantity text read; largest |exponent| of a power in it
MAX_TEXT = 100
MAX_EXPONENT = 30
_NUMBER = r"[+-]?\s*(?:\d+\.?\d*|\.\d+)(?:[eE][+-]?\d+)?"
_POWER = re.compile(r"(\*\*|\^)\s*(" + _NUMBER + r")?")


def _check_bounded(text: str) -> None:
    """Refuse, before pint evaluates it, a text whose evaluation could take unbounded
    time or memory: a long one, a power whose exponent is not a plain small number
    (``10**10**10`` is evaluated exactly by Python's integers and never ends)."""
    if len(text) > MAX_TEXT:
        raise UnitsError(f"{bounded_repr(text)}: at most {MAX_TEXT} characters")
    for match in _POWER.finditer(text):
        exponent = match.group(2)
        rest = text[match.end():].lstrip()
        if exponent is None or rest.startswith(("**", "^")):
            raise UnitsError(f"{bounded_repr(text)}: an exponent must be a plain number (as in 'um**2' or "
                             "'10**-6 m'), not an expression or another power")
        if abs(float(exponent.replace(" ", ""))) > MAX_EXPONENT:
            raise UnitsError(f"{bounded_repr(text)}: exponents up to {MAX_EXPONENT} in size")


def parse(text: Any, kind: str) -> float:
    """The value of `text` (``"1.2 mPa*s"``) in the SI unit of `kind` (:data:`KINDS`).

    Raises :class:`UnitsError` (one line) for a bare number, unknown units, the
    wrong dimension, or a value that is not positive and finite."""
    unit, what, example = KINDS[kind]
    if isinstance(text, bool) or not isinstance(text, str):
        raise UnitsError(f"must be a quantity with units as a string, e.g. '{example}' (got {bounded_repr(text)})")
    _check_bounded(text)
    ureg = _registry()
    try:
        quantity = ureg.Quantity(text.strip())
    except Exception as exc:  # pint's UndefinedUnitError, DefinitionSyntaxError, tokenizer errors …
        raise UnitsError(f"cannot read {bounded_repr(text)} as a quantity: {first_line(exc)}") from None
    if not isinstance(quantity, ureg.Quantity) or quantity.dimensionless:
        raise UnitsError(f"{bounded_repr(text)} has no units; give {what}, e.g. '{example}'")
    try:
        value = float(quantity.to(unit).magnitude)
    except Exception:  # DimensionalityError
        raise UnitsError(
            f"{bounded_repr(text)} is not {what}: its dimension is {quantity.dimensionality}, e.g. '{example}'"
        ) from None
    if not (math.isfinite(value) and value > 0):
        raise UnitsError(f"{bounded_repr(text)} must be positive and finite")
    return value


def check_given(given: dict[str, Any]) -> None:
    """`capsim units`'s values without the capillary number: shear rate, viscosity, radius and one of
    the two moduli, each parsed in its own units; UnitsError names the options missing or the value
    that does not parse (as --the-option)."""
    def option(kind: str) -> str:
        return "--" + kind.replace("_", "-")

    missing = [option(k) for k in ("shear_rate", "viscosity", "radius") if given.get(k) is None]
    surface, shear = given.get("surface_modulus"), given.get("shear_modulus")
    if (surface is None) == (shear is None):
        missing.append("--surface-modulus or --shear-modulus (one of the two)" if surface is None
                       else "only one of --surface-modulus and --shear-modulus")
    if missing:
        raise UnitsError(f"give {', '.join(missing)} (quantities with units, e.g. --radius '2.8 um')")
    for kind, value in ((k, v) for k, v in given.items() if v is not None):
        try:
            parse(value, kind)
        except UnitsError as exc:
            raise UnitsError(f"{option(kind)}: {exc}") from None


def conversion(shear_rate: Any, viscosity: Any, radius: Any, surface_modulus: Any = None,
               shear_modulus: Any = None, membrane_viscosity: Any = None, inner_viscosity: Any = None) -> dict[str, float]:
    """G = μ k a / E_s, Ca = μ k a / G_s = 3 G and the time unit 1/k (s) from physical values.

    Give the membrane's elastic modulus E_s (``surface_modulus``; for a drop, the
    surface tension) or its surface shear modulus G_s (``shear_modulus``), not both.
    Returns ``{"G", "Ca", "time_unit_s", "E_s_N_per_m", "G_s_N_per_m", "velocity_m_per_s",
    "tension_N_per_m"}``, and with the membrane's surface shear viscosity μ_s
    (``membrane_viscosity``) its Boussinesq number ``Bq`` = μ_s/(μ a)
    (``membrane.viscosity.shear``) and the membrane's viscoelastic time μ_s/G_s
    (``membrane_time_s``; kτ = Bq·Ca in units of 1/k); with the inner fluid's viscosity
    (``inner_viscosity``, the cytoplasm's) the viscosity ratio ``lambda`` = μ_in/μ
    (``flow.viscosity_ratio``).

    Every value returned is a positive, finite number: values whose product overflows or
    underflows (``1e300 1/s`` with ``1e300 Pa*s``) are a :class:`UnitsError` naming it.
    """
    if (surface_modulus is None) == (shear_modulus is None):
        raise UnitsError("give the surface modulus E_s or the shear modulus G_s (one of the two)")
    k = parse(shear_rate, "shear_rate")
    mu = parse(viscosity, "viscosity")
    a = parse(radius, "radius")
    if surface_modulus is not None:
        e_s = parse(surface_modulus, "surface_modulus")
        g_s = SHEAR_OVER_ELASTIC_MODULUS * e_s
    else:
        g_s = parse(shear_modulus, "shear_modulus")
        e_s = g_s / SHEAR_OVER_ELASTIC_MODULUS
    tension = mu * k * a
    out = {
        "G": tension / e_s, "Ca": tension / g_s, "time_unit_s": 1.0 / k,
        "E_s_N_per_m": e_s, "G_s_N_per_m": g_s, "velocity_m_per_s": k * a, "tension_N_per_m": tension,
        "shear_rate_per_s": k, "viscosity_Pa_s": mu, "radius_m": a,
    }
    if membrane_viscosity is not None:
        mu_s = parse(membrane_viscosity, "membrane_viscosity")
        out.update(Bq=mu_s / (mu * a), membrane_viscosity_N_s_per_m=mu_s, membrane_time_s=mu_s / g_s)
    if inner_viscosity is not None:
        mu_in = parse(inner_viscosity, "inner_viscosity")
        out.update({"lambda": mu_in / mu, "inner_viscosity_Pa_s": mu_in})
    check_finite(out)
    return out


#: what each value of :func:`conversion` is, in words (its error messages)
_CONVERTED = {
    "G": "G = mu k a / E_s", "Ca": "Ca = mu k a / G_s", "time_unit_s": "the time unit 1/k (s)",
    "E_s_N_per_m": "E_s (N/m)", "G_s_N_per_m": "G_s (N/m)", "velocity_m_per_s": "the velocity unit k a (m/s)",
    "tension_N_per_m": "the tension unit mu k a (N/m)", "Bq": "Bq = mu_s / (mu a)",
    "membrane_time_s": "the membrane time mu_s / G_s (s)", "lambda": "the viscosity ratio mu_in / mu",
}


def check_finite(out: dict[str, float]) -> None:
    """UnitsError naming the first value of `out` that is not a positive, finite number (a
    product of physical values that overflowed to inf or underflowed to 0)."""
    for key, value in out.items():
        if not (math.isfinite(value) and value > 0):
            exc = UnitsError(f"the values give {_CONVERTED.get(key, key)} = {value:.3g}, not a positive finite "
                             "number (it overflows or underflows): check their units")
            exc.key = key  # which value (capsim.config names the physical field it comes from)
            raise exc


#: the span of each physical value over the capsules and cells capsim is meant for (SI):
#: only used to say which value of a physical block that gives an absurd G most likely has
#: the wrong units (:func:`likeliest_slip`); nothing is refused on these alone
TYPICAL_SI = {
    "shear_rate": (1e-2, 1e5), "viscosity": (1e-4, 1e2), "radius": (1e-7, 1e-1),
    "surface_modulus": (1e-8, 1e1), "shear_modulus": (1e-8, 1e1),
}


_FLOW = ("shear_rate", "viscosity", "radius", "surface_modulus", "shear_modulus")
_MODULUS = ("surface_modulus", "shear_modulus")
#: the physical values each computed value (a key of :func:`conversion`'s result or a capsim
#: scale of :func:`check_scales`) is made of: the ones a message about it may name
INVOLVED: dict[str, tuple[str, ...]] = {
    "G": _FLOW, "Ca": _FLOW, "tension_N_per_m": _FLOW, "time_unit_s": ("shear_rate",),
    "E_s_N_per_m": _MODULUS, "G_s_N_per_m": _MODULUS, "velocity_m_per_s": ("shear_rate", "radius"),
    "Bq": ("membrane_viscosity",), "membrane_time_s": ("membrane_viscosity",), "lambda": ("inner_viscosity",),
    "a": ("radius",), "1/k": ("shear_rate",), "E_s": _MODULUS, "mu": ("viscosity",), "mu k a": _FLOW,
    "5/2 mu k V": _FLOW, "E_s a^2": ("radius", *_MODULUS), "a^2": ("radius",), "a^3": ("radius",),
    "mu k^2 a^3": _FLOW, "k/(4 pi)": ("shear_rate",), "a k": ("shear_rate", "radius"),
    "E_s/a": ("radius", *_MODULUS),
}


def likeliest_slip(values_si: dict[str, float]) -> str:
    """Of physical values (kind → SI magnitude) that give an implausible result together, the
    kind furthest (in decades) outside its span in :data:`TYPICAL_SI`, else the one furthest
    from its span's middle: the value to name in the message."""
    def decades(kind: str) -> tuple[float, float]:
        lo, hi = TYPICAL_SI[kind]
        x = math.log10(values_si[kind])
        outside = max(math.log10(lo) - x, x - math.log10(hi), 0.0)
        return outside, abs(x - 0.5 * (math.log10(lo) + math.log10(hi)))
    return max((k for k in values_si if k in TYPICAL_SI), key=decades)


def describe_conversion(out: dict[str, float]) -> str:
    """:func:`conversion`'s result as the lines `capsim units` prints."""
    return "\n".join([
        f"G  = mu k a / E_s  = {out['G']:.6g}   (flow.shear_rate_G)",
        f"Ca = mu k a / G_s  = {out['Ca']:.6g}   (= 3 G: G_s = E_s / 3 for every elastic law)",
        f"time unit 1/k      = {out['time_unit_s']:.6g} s   (kt = 1)",
        f"E_s = {out['E_s_N_per_m']:.6g} N/m, G_s = {out['G_s_N_per_m']:.6g} N/m, "
        f"velocity unit ka = {out['velocity_m_per_s']:.6g} m/s, tension unit mu k a = "
        f"{out['tension_N_per_m']:.6g} N/m",
    ] + ([f"Bq = mu_s / (mu a) = {out['Bq']:.6g}   (membrane.viscosity.shear); membrane time "
          f"mu_s / G_s = {out['membrane_time_s']:.6g} s (k tau = Bq Ca = {out['Bq'] * out['Ca']:.6g})"]
         if "Bq" in out else [])
      + ([f"lambda = mu_in / mu = {out['lambda']:.6g}   (flow.viscosity_ratio)"] if "lambda" in out else []))


# ---------------------------------------------------------------- capsim's scales in physical units (outputs)


def scale_values(out: dict[str, float]) -> dict[str, float]:
    """The SI magnitude (in the SI unit of :data:`capsim.quantities.SCALE_UNITS`) of each
    capsim scale, from :func:`conversion`'s result. V = (4π/3) a³: a is the equal-volume radius."""
    k, mu, a, e_s = out["shear_rate_per_s"], out["viscosity_Pa_s"], out["radius_m"], out["E_s_N_per_m"]
    try:
        a2, a3, k2 = a**2, a**3, k**2
    except OverflowError:  # a float power raises where a product is inf (check_scales refuses it)
        a2, a3, k2 = a * a, a * a * a, k * k
    volume = 4.0 / 3.0 * math.pi * a3
    return {
        "a": a, "1/k": 1.0 / k, "E_s": e_s, "mu": mu, "mu k a": mu * k * a,
        "5/2 mu k V": 2.5 * mu * k * volume, "E_s a^2": e_s * a2, "a^2": a2, "a^3": a3,
        "mu k^2 a^3": mu * k2 * a3, "k/(4 pi)": k / (4.0 * math.pi), "a k": a * k, "E_s/a": e_s / a,
    }


def check_scales(out: dict[str, float]) -> dict[str, float]:
    """The factor of each capsim scale in the unit shown (:data:`capsim.quantities.SCALE_UNITS`)
    from :func:`conversion`'s result, each a positive finite number, else a UnitsError naming
    the scale (its ``key``): physical values that are consistent (a sane G) but so extreme that
    an output in physical units overflows or underflows (a radius of 1e100 m: a³ in µm³)."""
    from capsim.quantities import SCALE_UNITS

    ureg = _registry()
    values = scale_values(out)
    factors = {}
    for scale, (si, shown) in SCALE_UNITS.items():
        factor = float(ureg.Quantity(values[scale], si).to(shown).magnitude)
        if not (math.isfinite(factor) and factor > 0):
            exc = UnitsError(f"the values give the scale {scale} = {factor:.3g} {shown}, not a positive finite number "
                             "(it overflows or underflows, so no output can be shown in physical units): check "
                             "their units")
            exc.key = scale
            raise exc
        factors[scale] = factor
    return factors


def physical_factors(physical: Any) -> dict[str, float]:
    """What a dimensionless value measured in each capsim scale is multiplied by to be in the
    unit shown (:data:`capsim.quantities.SCALE_UNITS`: 1/k → s, a → µm, μka → µN/m …), for a
    case's ``physical`` block (a :class:`capsim.config.Physical` or its dict). The unit
    changes go through pint; a factor that is not a positive finite number is a UnitsError."""
    if not isinstance(physical, dict):
        physical = physical.model_dump()
    try:
        out = conversion(physical["shear_rate"], physical["viscosity"], physical["radius"],
                         physical.get("surface_modulus"), physical.get("shear_modulus"))
        return check_scales(out)
    except UnitsError as exc:
        raise UnitsError(f"--units physical: the physical block: {exc}") from None


class NoPhysicalBlock(UnitsError):
    """--units physical for a run (or campaign) whose case has no physical block."""


def factors_for(case: Any, what: str) -> dict[str, float]:
    """:func:`physical_factors` of `case` (a Case); NoPhysicalBlock naming `what` when it has none."""
    if getattr(case, "physical", None) is None:
        raise NoPhysicalBlock(f"--units physical: {what} has no physical block (its case gives flow.shear_rate_G, "
                              "not the shear rate, viscosity, radius and modulus); allowed: --units capsim, or a "
                              "case with physical: (capsim units, docs/user_guide.md)")
    return physical_factors(case.physical)


# ---------------------------------------------------------------- the capillary number as an input


#: what Ca = μ k a / G_s fixes when it is given with three of the four: name → (SI unit, formula)
_SOLVED_BY_CA = {
    "shear_rate": ("1/s", "k = Ca G_s / (mu a)"),
    "viscosity": ("Pa*s", "mu = Ca G_s / (k a)"),
    "radius": ("m", "a = Ca G_s / (mu k)"),
    "shear_modulus": ("N/m", "G_s = mu k a / Ca"),
}


def check_capillary_number(ca: Any) -> float:
    """Ca as `flow.capillary_number` takes it: a positive, finite number (UnitsError otherwise)."""
    if isinstance(ca, bool) or not isinstance(ca, (int, float)) or not (math.isfinite(ca) and ca > 0):
        raise UnitsError(f"--capillary-number {ca!r}: must be a positive, finite number (Ca = mu k a / G_s, e.g. 0.1)")
    return float(ca)


def from_capillary_number(ca: float, given: dict[str, Any]) -> dict[str, Any]:
    """The conversion with Ca = μ k a / G_s as an input, consistent with ``flow.capillary_number``.

    `given` maps shear_rate, viscosity, radius, surface_modulus / shear_modulus (E_s = 3 G_s)
    and membrane_viscosity to quantity texts or None. With none of the first four: G = Ca/3
    only (``{"Ca", "G"}``; a drop, surface_tension: G = Ca). With three of the four (the
    modulus as E_s or G_s): the fourth is solved for (``solved``) and :func:`conversion` runs
    on all four. Anything else: UnitsError naming what to give."""
    ca = check_capillary_number(ca)
    for kind, value in given.items():  # each value named by its option when it is not a quantity of its kind
        if value is not None:
            try:
                parse(value, kind)
            except UnitsError as exc:
                raise UnitsError(f"--{kind.replace('_', '-')}: {exc}") from None
    g_s = given.get("shear_modulus")
    if given.get("surface_modulus") is not None:
        if g_s is not None:
            raise UnitsError("give only one of --surface-modulus and --shear-modulus")
        g_s = f"{parse(given['surface_modulus'], 'surface_modulus') * SHEAR_OVER_ELASTIC_MODULUS!r} N/m"
    four = {"shear_rate": given.get("shear_rate"), "viscosity": given.get("viscosity"),
            "radius": given.get("radius"), "shear_modulus": g_s}
    missing = [name for name, value in four.items() if value is None]
    if len(missing) == 4:
        if given.get("membrane_viscosity") is not None:
            raise UnitsError("--membrane-viscosity needs the viscosity and the radius (Bq = mu_s/(mu a)); give "
                             "three of --shear-rate, --viscosity, --radius, --shear-modulus with --capillary-number")
        return {"Ca": ca, "G": ca * SHEAR_OVER_ELASTIC_MODULUS}
    if not missing:
        raise UnitsError("--capillary-number fixes one of --shear-rate, --viscosity, --radius and the modulus: give "
                         "three of them with it, not all four (or leave out --capillary-number)")
    if len(missing) > 1:
        options = ", ".join("--" + name.replace("_", "-") for name in missing)
        raise UnitsError(f"--capillary-number with physical values: give three of --shear-rate, --viscosity, "
                         f"--radius and --surface-modulus/--shear-modulus (Ca fixes the fourth); missing {options}")
    name = missing[0]
    k, mu, a, gs = (parse(four[n], n) if n != name else None for n in ("shear_rate", "viscosity", "radius",
                                                                           "shear_modulus"))
    solved = {"shear_rate": lambda: ca * gs / (mu * a), "viscosity": lambda: ca * gs / (k * a),
              "radius": lambda: ca * gs / (mu * k), "shear_modulus": lambda: mu * k * a / ca}[name]()
    four[name] = f"{solved!r} {_SOLVED_BY_CA[name][0]}"
    out: dict[str, Any] = conversion(four["shear_rate"], four["viscosity"], four["radius"],
                                     shear_modulus=four["shear_modulus"],
                                     membrane_viscosity=given.get("membrane_viscosity"))
    out["solved"] = name
    out[f"{name}_SI"] = solved
    return out


def describe_capillary(out: dict[str, Any]) -> str:
    """:func:`from_capillary_number`'s result as the lines `capsim units` prints."""
    if "solved" not in out:
        return (f"Ca = {out['Ca']:.6g}   (flow.capillary_number)\n"
                f"G  = Ca / 3 = {out['G']:.6g}   (flow.shear_rate_G: G_s = E_s / 3 for every elastic law; "
                "a drop, law surface_tension: G = Ca)")
    name = out["solved"]
    unit, formula = _SOLVED_BY_CA[name]
    return (f"{formula} = {out[name + '_SI']:.6g} {unit}   (from --capillary-number)\n"
            + describe_conversion(out))

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

__all__ = ["KINDS", "UnitsError", "conversion", "parse", "physical_factors", "scale_values"]

#: G_s / E_s of every elastic law of capsim (capsim.membrane: the small-strain shear modulus)
SHEAR_OVER_ELASTIC_MODULUS = 1.0 / 3.0

#: what each physical value is: (SI unit it is converted to, what it must measure, an example)
KINDS: dict[str, tuple[str, str, str]] = {
    "shear_rate": ("1/s", "a shear rate (1/time)", "100 1/s"),
    "viscosity": ("Pa*s", "a dynamic viscosity (pressure × time)", "1.2 mPa*s"),
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


def conversion(shear_rate: Any, viscosity: Any, radius: Any, surface_modulus: Any = None,
               shear_modulus: Any = None, membrane_viscosity: Any = None) -> dict[str, float]:
    """G = μ k a / E_s, Ca = μ k a / G_s = 3 G and the time unit 1/k (s) from physical values.

    Give the membrane's elastic modulus E_s (``surface_modulus``; for a drop, the
    surface tension) or its surface shear modulus G_s (``shear_modulus``), not both.
    Returns ``{"G", "Ca", "time_unit_s", "E_s_N_per_m", "G_s_N_per_m", "velocity_m_per_s",
    "tension_N_per_m"}``, and with the membrane's surface shear viscosity μ_s
    (``membrane_viscosity``) its Boussinesq number ``Bq`` = μ_s/(μ a)
    (``membrane.viscosity.shear``) and the membrane's viscoelastic time μ_s/G_s
    (``membrane_time_s``; kτ = Bq·Ca in units of 1/k).
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
    return out


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
         if "Bq" in out else []))


# ---------------------------------------------------------------- capsim's scales in physical units (outputs)


def scale_values(out: dict[str, float]) -> dict[str, float]:
    """The SI magnitude (in the SI unit of :data:`capsim.quantities.SCALE_UNITS`) of each
    capsim scale, from :func:`conversion`'s result. V = (4π/3) a³: a is the equal-volume radius."""
    k, mu, a, e_s = out["shear_rate_per_s"], out["viscosity_Pa_s"], out["radius_m"], out["E_s_N_per_m"]
    volume = 4.0 / 3.0 * math.pi * a**3
    return {
        "a": a, "1/k": 1.0 / k, "E_s": e_s, "mu": mu, "mu k a": mu * k * a,
        "5/2 mu k V": 2.5 * mu * k * volume, "E_s a^2": e_s * a**2, "a^2": a**2, "a^3": a**3,
        "mu k^2 a^3": mu * k**2 * a**3, "k/(4 pi)": k / (4.0 * math.pi), "a k": a * k, "E_s/a": e_s / a,
    }


def physical_factors(physical: Any) -> dict[str, float]:
    """What a dimensionless value measured in each capsim scale is multiplied by to be in the
    unit shown (:data:`capsim.quantities.SCALE_UNITS`: 1/k → s, a → µm, μka → µN/m …), for a
    case's ``physical`` block (a :class:`capsim.config.Physical` or its dict). The unit
    changes go through pint."""
    from capsim.quantities import SCALE_UNITS

    if not isinstance(physical, dict):
        physical = physical.model_dump()
    out = conversion(physical["shear_rate"], physical["viscosity"], physical["radius"],
                     physical.get("surface_modulus"), physical.get("shear_modulus"))
    ureg = _registry()
    values = scale_values(out)
    return {scale: float(ureg.Quantity(values[scale], si).to(shown).magnitude)
            for scale, (si, shown) in SCALE_UNITS.items()}


class NoPhysicalBlock(UnitsError):
    """--units physical for a run (or campaign) whose case has no physical block."""


def factors_for(case: Any, what: str) -> dict[str, float]:
    """:func:`physical_factors` of `case` (a Case); NoPhysicalBlock naming `what` when it has none."""
    if getattr(case, "physical", None) is None:
        raise NoPhysicalBlock(f"--units physical: {what} has no physical block (its case gives flow.shear_rate_G, "
                              "not the shear rate, viscosity, radius and modulus); allowed: --units capsim, or a "
                              "case with physical: (capsim units, docs/user_guide.md)")
    return physical_factors(case.physical)

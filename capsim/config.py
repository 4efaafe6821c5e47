"""The one schema of a capsim case, its YAML loader and its error messages.

Every user mistake (missing file, bad YAML, unknown field, value out of range)
surfaces as a :class:`ConfigError` whose message is one line naming the file,
the dotted field, the bad value and what is allowed, e.g.::

    case.yaml: flow.G = -1.0: must be > 0

``flow.G`` is the flow's rate's name (its long name ``shear_rate_G`` is read too, and is what a
run file's stored case keeps): a problem is named as the case wrote it.
"""

from __future__ import annotations

import math
import os
import stat
import warnings
from contextvars import ContextVar
from collections.abc import Mapping
from typing import Any, Literal, Optional, Union, get_args, get_origin

import yaml
from pydantic import (
    AliasChoices,
    BaseModel,
    ConfigDict,
    Field,
    ValidationError,
    ValidationInfo,
    create_model,
    field_validator,
    model_validator,
)

from capsim.errors import bounded_repr, first_line
from capsim.scene.flows import (FLOW_FIELDS, FLOW_HISTORIES, FLOWS, HISTORY_FIELDS, SYMMETRY_CANDIDATES,
                          fields_problem, symmetries_kept)
from capsim.scene.conduit import CONDUIT_FIELDS, CONDUITS, TRUNCATION_DEFAULT
from capsim.solve.timestepping import DEFAULT_SCHEME, SCHEMES
from capsim.numerics.viscosity import VISCOSITY_MODELS
from capsim.numerics.mesh import BICONCAVE_REDUCED_VOLUME
from capsim.numerics.viscosity import is_active as is_viscous

#: the YAML writer of a resolved case: libyaml's where PyYAML has it (the same text, ~5x faster: a run
#: stores its case), else PyYAML's own
YAML_DUMPER = getattr(yaml, "CSafeDumper", yaml.SafeDumper)
#: ... and its reader (a campaign's worker reads every run's case text, a resume the stored one: PyYAML's
#: own parser took 17 ms a case, issue 57)
YAML_LOADER = getattr(yaml, "CSafeLoader", yaml.SafeLoader)


def yaml_text(text: str) -> Any:
    """A YAML text that capsim wrote (a resolved case, a stored campaign) as Python data."""
    return yaml.load(text, Loader=YAML_LOADER)

__all__ = [
    "load_case_with", "parse_sets",    "case_digest", "step_defining",
    "Case",
    "ConfigError",
    "Flow",
    "FlowHistory",
    "Guards",
    "Membrane",
    "MembraneViscosity",
    "Mesh",
    "Output",
    "Physical",
    "Quadrature",
    "Shape",
    "Solver",
    "Time",
    "apply_overrides",
    "case_from_dict",
    "load_case",
    "read_yaml",
]


class ConfigError(Exception):
    """A user mistake in a case: the message is one line, fit to print as is."""


class CaseWarning(UserWarning):
    """A case that capsim runs but has not been validated for (a value far outside the
    ranges of :data:`VALIDATED_RANGES`): one line naming the field, its value and the range."""


# ---------------------------------------------------------------- limits

#: longest case name: it becomes a file name (``<name>.h5``, ``<name>.h5.ckpt.npz`` and
#: temporary siblings), and file names are limited to 255 bytes; names are ASCII.
NAME_MAX = 200
#: most bytes read from a case or campaign file (a real one is a few kB)
MAX_FILE_BYTES = 1 << 20
#: most YAML nodes after expanding aliases (a case has ~60 leaves, a campaign a few thousand)
MAX_YAML_NODES = 100_000
#: deepest nesting of YAML mappings and sequences (a campaign needs 4)
MAX_YAML_DEPTH = 32
#: most snapshots a run may write: each is the (N_p, 3) positions, 1.5 MB at level 6
MAX_SNAPSHOTS = 10_000
#: where capsim's results have been checked (docs/validation.md, docs/known_answers.md,
#: docs/user_guide.md): a case outside one of these ranges is run, with a CaseWarning that
#: names the field, its value and the range. G: Jeffery's rigid limit at G = 5e-4
#: (known_answers.md), the robustness runs from the stiff G = 0.001 (D/G against first-order
#: theory) to G = 1 (no runaway); λ: 0.01 and 100 (validation.md);
#: κ/(E_s a²): the bending runs up to 1e-2 (the red cell's is 3.06e-3); Bq: the relaxation
#: times of the small-deformation theory at Bq_s = 0, 10, 30 (known_answers.md; the red cell's
#: is 29.8)
VALIDATED_RANGES = {
    "flow.shear_rate_G": (5e-4, 1.0),
    "flow.viscosity_ratio": (1e-2, 1e2),
    "membrane.bending_modulus": (0.0, 1e-2),
    "membrane.viscosity.shear": (0.0, 30.0),
    "membrane.viscosity.dilatational": (0.0, 30.0),
}
#: the farthest a capsule may start from the origin in any coordinate, in units of a: positions are
#: doubles and every shape value is measured about the capsule's own centroid (a linear flow's
#: uniform part carried exactly: capsim.solve.solver.CapsuleModel.carried_velocity), so round-off is |x| 1e-16,
#: 1e-10 a here; a capsule 1e6 a out gives the origin's D_xy to 1e-6
MAX_COORDINATE = 1e6
#: with a wall, the farthest a capsule may start from it (wall.distance's bound): the shear of the
#: wall's flow is not translation-invariant across it, so nothing is carried
WALL_REACH = 1e3
#: the G a `physical:` block may give: outside it the values are refused as a slip of units
#: (a radius of 2.8 m for 2.8 um gives G = 4e4; a capsule at G > 100 is torn apart at once and
#: one below 1e-6 is a rigid particle whose explicit time step is ~G times the flow's)
PHYSICAL_G_RANGE = (1e-6, 1e2)
#: the largest κ/(E_s a²) a `physical:` block may give (a vesicle-like membrane of small shear
#: modulus reaches ~10; 1e3 is bending a hundred thousand times the validated range)
PHYSICAL_BENDING_MAX = 1e3
#: the largest Boussinesq number membrane.viscosity takes (its fields' bound)
BQ_MAX = 1e4
#: the viscosity ratios flow.viscosity_ratio takes (its bound)
LAMBDA_RANGE = (1e-3, 1e3)
#: the membrane-law parameters and their defaults (the law functions of capsim.numerics.membrane
#: take the same defaults; tests/test_registries.py checks that they agree)
LAW_PARAMETER_DEFAULTS = {"mooney_rivlin": {"psi": 0.0}, "skalak": {"skalak_c": 10.0}}
#: membrane.skalak_c's bound: the area modulus 1 + 2C beyond it is stiffer than the stepping follows
SKALAK_MAX_C = 1e4
#: skalak_c auto (issue 55): the area change a Skalak membrane takes in shear is ΔA/A ≈ β G/(1 + 2C)
#: (the isotropic tension ~ μka over the area modulus); β the largest measured on the red cell in
#: 30 mPa s at 0.1-50 Pa: 9.4 at level 2 and 9.79 at level 3 (G 18.7, C 4600; 2.1-8.5 at C 10-1000:
#: benchmarks/rbc_high_stress.md). Not a bound for every cell: the nearly spherical stress-free state gave
#: 10.4 and λ 0.06 (100 mPa s) 10.1-14.5, areas up to 1.5 times the tolerance, which the run then reports.
#: C = (β G/ε - 1)/2 for the tolerance ε, at least SKALAK_AUTO_MIN_C.
SKALAK_AUTO_BETA = 9.8
#: the smallest C auto takes: the usual computational choice (area within ~1 % at G <= 0.05, the
#: default red cell's case, which auto leaves unchanged bit for bit)
SKALAK_AUTO_MIN_C = 10.0
#: membrane.area_tolerance's default: 2 % (the red cell's outline EI at 1 Pa moved 0.8 % between C 91, area
#: +0.5 %, and C 1000, +0.05 %; at 50 Pa C 1000's +8 % had lengthened it by 9 %: benchmarks/rbc_high_stress.md)
SKALAK_AUTO_AREA_TOLERANCE = 0.02


#: skalak_c auto needs a rest shape with excess area (reduced volume at most this): a red cell deforms
#: at nearly constant area, so its area change goes as G/(1 + 2C); a sphere's membrane must stretch to
#: deform at all (a Skalak sphere at G 0.05-0.2: ΔA/A ~ C^-1/2, 1.6 % at C 10, 0.35 % at C 200), its C is
#: the material's and sets the deformation itself. Measured at level 2, kt 6, G 0.2 and 1 (tests/
#: test_skalak_auto.py): an oblate spheroid of aspect 0.5 (ν 0.872) stays within 2 % (1.1, 1.5 %), a
#: prolate one of aspect 2 (ν 0.895) does not (2.5, 2.8 %)
SKALAK_AUTO_MAX_REDUCED_VOLUME = 0.88


def rest_reduced_volume(shape: Shape) -> float:
    """The reduced volume ν = V/(4π/3 (S/4π)^{3/2}) of a rest shape: 1 for a sphere, the spheroid's in
    closed form, at most 0.72 for the biconcave family (capsim.numerics.mesh.BICONCAVE_REDUCED_VOLUME)."""
    e = float(shape.aspect_ratio)
    if shape.kind == "biconcave":
        return 0.72  # the family's largest (its rest shapes are all below it)
    if shape.kind == "sphere" or e == 1.0:
        return 1.0
    if e < 1.0:  # oblate: equatorial radius 1, polar e
        ecc = math.sqrt(1.0 - e * e)
        area = 2.0 * math.pi * (1.0 + e * e / ecc * math.atanh(ecc))
    else:  # prolate
        ecc = math.sqrt(1.0 - 1.0 / (e * e))
        area = 2.0 * math.pi * (1.0 + e / ecc * math.asin(ecc))
    return (4.0 * math.pi / 3.0 * e) / (4.0 * math.pi / 3.0 * (area / (4.0 * math.pi)) ** 1.5)


def _skalak_c_unbounded(G: float, tolerance: float) -> float:
    """C = (β G/ε − 1)/2: ΔA/A ≈ β G/(1 + 2C) solved for the tolerance ε, before its bounds and rounding."""
    return 0.5 * (SKALAK_AUTO_BETA * G / tolerance - 1.0)


def skalak_c_for_stress(G: float, tolerance: float = SKALAK_AUTO_AREA_TOLERANCE) -> float:
    """The smallest Skalak C whose area change at capillary number G stays within `tolerance`
    (ΔA/A ≈ β G/(1 + 2C), β = SKALAK_AUTO_BETA), between SKALAK_AUTO_MIN_C and SKALAK_MAX_C, as a
    round number (two significant digits): the resolved case's C reads as it was chosen."""
    wanted = _skalak_c_unbounded(G, tolerance)
    if not wanted > SKALAK_AUTO_MIN_C:
        return SKALAK_AUTO_MIN_C
    digits = 10.0 ** (math.floor(math.log10(wanted)) - 1)
    return float(min(max(round(wanted / digits) * digits, SKALAK_AUTO_MIN_C), SKALAK_MAX_C))


def _auto_or_number(v: Any, interval: str) -> Any:
    """A field that is a number or auto (time.rtol, membrane.skalak_c): the word auto in any case (AUTO,
    Auto), a number given as text read as one; anything else refused in one line, not pydantic's one per
    member of the union."""
    if isinstance(v, str) and v.strip().lower() == "auto":
        return "auto"
    if isinstance(v, str):
        try:
            return _strict_scalar(v, float)
        except ValueError:
            raise ValueError(f"must be a number in {interval} or auto") from None
    if isinstance(v, float) and not math.isfinite(v):
        raise ValueError(f"must be a finite number in {interval} or auto")
    if not isinstance(v, (bool, int, float)):  # a list, a mapping: one line, not one per member of the union
        raise ValueError(f"must be a number in {interval} or auto")
    return v


class _FieldProblem(ValueError):
    """A cross-field check that names the field it is about (below a section's location)."""

    def __init__(self, field: str, value: Any, what: str) -> None:
        super().__init__(what)
        self.field, self.value, self.what = field, value, what


def _strict_scalar(v: Any, annotation: Any) -> Any:
    # YAML 1.1 reads yes/no/on/off as booleans: never let one become 1.0 or 0 for a
    # number (bool is an int subclass, so pydantic's lax float would take it).
    if isinstance(v, bool) and annotation is not bool:
        choices = get_args(annotation) if get_origin(annotation) is Literal else ()
        kind = {int: "an integer", float: "a number", str: "a string"}.get(
            annotation, "one of " + ", ".join(map(str, choices)) if choices else "a value of the field's kind"
        )
        raise ValueError(f"must be {kind}, not {str(v).lower()} (YAML reads yes/no/on/off as booleans)")
    if isinstance(v, (list, tuple)) and _holds_bool(v):
        # a list of numbers (a history table, a centre, a gradient): pydantic's lax float takes a
        # boolean inside it as 1.0 or 0.0, and a table of true/false ran as a rate of 1 and 0
        raise ValueError("must hold numbers, not true/false (YAML reads yes/no/on/off as booleans)")
    if annotation is float and isinstance(v, str):
        # PyYAML (YAML 1.1) reads `1e-4` (no dot) as the string "1e-4": a string that
        # is a plain decimal number is taken; 'nan', 'inf', '0x10', '1_0' are not.
        text = v.strip()
        try:
            ok = len(text) <= 40 and text.lstrip("+-")[:1] in tuple("0123456789.") and "_" not in text
            number = float(text) if ok else None
        except ValueError:
            number = None
        if number is None:
            raise ValueError("must be a number")
        return number
    return v


def _holds_bool(v: Any) -> bool:
    """Whether a (nested) list of scalars holds a boolean (mappings in it are their own sections)."""
    return any(isinstance(item, bool) or (isinstance(item, (list, tuple)) and _holds_bool(item)) for item in v)


class _Model(BaseModel):
    # Typos are errors, NaN/inf are never a sane parameter, and a resolved case
    # is an immutable description: change it with apply_overrides.
    model_config = ConfigDict(extra="forbid", allow_inf_nan=False, frozen=True)

    @field_validator("*", mode="before")
    @classmethod
    def _no_coercion(cls, v: Any, info: ValidationInfo) -> Any:
        return _strict_scalar(v, cls.model_fields[info.field_name].annotation)


def _in_range(v: float, lo: float, hi: float, why: str) -> float:
    if not lo <= v <= hi:
        raise ValueError(f"must be in [{lo:g}, {hi:g}] ({why})")
    return v


# Integers and booleans are strict so that `level: 2.5`, `level: "3"` or
# `stop_when_steady: 1` are refused rather than coerced. Floats take ints and
# decimal strings (PyYAML reads `1e-4` as a string) but never booleans.


#: smallest Evans-Fung thickness factor min(c0 + c2 s + c4 s²) of a biconcave rest shape: the
#: faces are then at least ~0.03 a apart, above a level-6 element (~0.025 a)
MIN_BICONCAVE_THICKNESS = 0.05


class Shape(_Model):
    """Rest shape of the capsule; lengths are scaled by the equal-volume radius a."""

    kind: Literal["sphere", "oblate", "prolate", "biconcave"] = "sphere"
    aspect_ratio: float = Field(
        1.0, gt=0,
        description="polar / equatorial axis of the spheroid, in [0.05, 20]: the rim of a flatter "
        "(or the tip of a longer) spheroid has a radius of curvature below a level-6 element "
        "(~0.025 a), so no mesh resolves it; spheroids only",
    )
    c0: float = Field(
        0.207, ge=-10, le=10,
        description="Evans-Fung biconcave coefficient; c0 + c2 s + c4 s² (s = r²/R0²) is the thickness "
        "profile and must stay positive on [0, 1] (else the disk has no inside); biconcave only",
    )
    c2: float = Field(2.003, ge=-10, le=10, description="Evans-Fung biconcave coefficient (see c0)")
    c4: float = Field(-1.123, ge=-10, le=10, description="Evans-Fung biconcave coefficient (see c0)")
    inflation: float = Field(
        0.0, gt=-0.5, le=0.5,
        description="pre-inflation α: the membrane's stress-free shape is the initial one shrunk by 1 + α about "
        "its centre, so at t = 0 it is stretched by 1 + α in every direction (Lac et al. 2004 use α = 0.05 so "
        "that the membrane is never compressed); every shape and law; 0: the initial shape is stress-free",
    )

    @field_validator("aspect_ratio")
    @classmethod
    def _aspect_matches_kind(cls, v: float, info: ValidationInfo) -> float:
        kind = info.data.get("kind")
        if kind == "oblate" and not v < 1:
            raise ValueError("must be in (0, 1) for an oblate spheroid")
        if kind == "prolate" and not v > 1:
            raise ValueError("must be > 1 for a prolate spheroid")
        if kind == "sphere" and v != 1:
            raise ValueError("must be 1 for a sphere (use kind: oblate or prolate)")
        return _in_range(v, 0.05, 20.0, "a rim flatter than 1:20 is below the finest mesh")

    @model_validator(mode="after")
    def _fields_of_the_kind(self) -> Shape:
        spheroid = self.kind in ("oblate", "prolate", "sphere")
        unused = ("c0", "c2", "c4") if spheroid else ("aspect_ratio",)
        for name in unused:
            value = getattr(self, name)
            if name in self.model_fields_set and value != type(self).model_fields[name].default:
                used = "biconcave shapes" if spheroid else "spheroids (oblate, prolate)"
                raise _FieldProblem(name, value, f"applies only to {used}, not to kind: {self.kind}; remove it")
        if self.kind == "biconcave":
            c0, c2, c4 = self.c0, self.c2, self.c4
            # minimum of the thickness profile h(s) = c0 + c2 s + c4 s² on 0 <= s <= 1
            candidates = [0.0, 1.0] + ([-c2 / (2 * c4)] if c4 > 0 and 0 < -c2 / (2 * c4) < 1 else [])
            s_min = min(candidates, key=lambda s: c0 + c2 * s + c4 * s * s)
            h_min = c0 + c2 * s_min + c4 * s_min * s_min
            name = "c0" if s_min == 0.0 else "c4" if "c4" in self.model_fields_set else "c2"
            if not h_min > 0:
                raise _FieldProblem(
                    name, getattr(self, name),
                    f"the Evans-Fung thickness c0 + c2 s + c4 s² = {h_min:.3g} <= 0 at s = r²/R0² = {s_min:.3g}: "
                    f"(c0, c2, c4) = ({c0:g}, {c2:g}, {c4:g}) give no surface; it must be > 0 on [0, 1]",
                )
            if not h_min >= MIN_BICONCAVE_THICKNESS:
                raise _FieldProblem(
                    name, getattr(self, name),
                    f"the Evans-Fung thickness c0 + c2 s + c4 s² = {h_min:.3g} at s = r²/R0² = {s_min:.3g}: "
                    f"(c0, c2, c4) = ({c0:g}, {c2:g}, {c4:g}) pinch the disk; it must be >= "
                    f"{MIN_BICONCAVE_THICKNESS:g} on [0, 1] (thinner, the two faces come closer than the "
                    "finest mesh's elements and the surface is degenerate)",
                )
        return self


class MembraneViscosity(_Model):
    """Surface viscosity of the membrane as Boussinesq numbers Bq = μ_s/(μ a), μ the outer
    viscosity (capsim.numerics.viscosity; docs/viscous_membrane.md). All zero: a purely elastic
    membrane, computed exactly as without this block."""

    model: Literal[tuple(VISCOSITY_MODELS)] = Field(  # type: ignore[valid-type]
        "kelvin_voigt",
        description="kelvin_voigt: viscous tension 2 mu_s (D - tr(D) P / 2) + mu_d tr(D) P added to the elastic "
        "one (Barthes-Biesel & Sgaier 1985)",
    )
    shear: float = Field(
        0.0, ge=0, le=BQ_MAX,
        description="surface shear viscosity Bq_s = mu_s / (mu a) (red cell: ~0.3-3); the velocity becomes a "
        "GMRES solve at every evaluation; validated up to 30 (a warning beyond)",
    )
    dilatational: float = Field(
        0.0, ge=0, le=BQ_MAX,
        description="surface dilatational viscosity Bq_d = mu_d / (mu a): isotropic viscous tension mu_d tr(D); "
        "validated up to 30 (a warning beyond)",
    )

    @model_validator(mode="after")
    def _parameters_of_the_model(self) -> "MembraneViscosity":
        allowed = VISCOSITY_MODELS[self.model].parameters
        for name in self.model_fields_set - {"model"}:
            if name not in allowed:
                raise _FieldProblem(name, getattr(self, name),
                                    f"is not a parameter of model: {self.model} (it takes {', '.join(allowed)})")
        return self

    @property
    def active(self) -> bool:
        return is_viscous(self.model_dump())


class ReferenceShape(_Model):
    """The membrane's stress-free shape, which its elastic and bending energies are measured from
    (capsim.numerics.mesh.stress_free_positions; docs/laws.md, "The stress-free shape")."""

    kind: Literal["rest", "sphere", "oblate", "biconcave"] = Field(
        "rest",
        description="rest: the initial shape itself (the default; no pre-stress); sphere, oblate, biconcave: another "
        "surface on the same mesh (node k of both the image of one point of the unit sphere), scaled to the initial "
        "shape's area: the membrane keeps its area and the cell differs from its stress-free state by its volume")
    aspect_ratio: float = Field(
        0.5, gt=0,
        description="oblate only: polar / equatorial axis of the stress-free spheroid, in [0.05, 1) (Peng et al. "
        "2014: a nearly spherical stress-free state, ~0.9-0.99)")
    reduced_volume: Optional[float] = Field(
        None,
        description=f"biconcave only: the stress-free disk's reduced volume V / (4π/3 (S/4π)^3/2), in "
        f"[{BICONCAVE_REDUCED_VOLUME[0]:g}, {BICONCAVE_REDUCED_VOLUME[1]:g}], reached by scaling the thickness of "
        "the Evans-Fung profile (the rest shape's c0, c2, c4 when it is biconcave; unset: that profile as it is, "
        "0.644 with the default coefficients)")

    @model_validator(mode="after")
    def _fields_of_the_kind(self) -> "ReferenceShape":
        for name, kind in (("aspect_ratio", "oblate"), ("reduced_volume", "biconcave")):
            if (name in self.model_fields_set and self.kind != kind
                    and getattr(self, name) != type(self).model_fields[name].default):  # a dumped case holds defaults
                raise _FieldProblem(name, getattr(self, name),
                                    f"applies only to kind: {kind}, not to kind: {self.kind}; remove it")
        if self.kind == "oblate" and not 0.05 <= self.aspect_ratio < 1:
            raise _FieldProblem("aspect_ratio", self.aspect_ratio, "must be in [0.05, 1) for an oblate spheroid "
                                "(kind: sphere for 1)")
        lo, hi = BICONCAVE_REDUCED_VOLUME
        if self.reduced_volume is not None and not lo <= self.reduced_volume <= hi:
            raise _FieldProblem("reduced_volume", self.reduced_volume,
                                f"must be in [{lo:g}, {hi:g}]: the biconcave family (its thickness scaled) reaches no "
                                "other; a nearly spherical stress-free state is kind: oblate")
        return self


class Membrane(_Model):
    """Constitutive law of the membrane (docs/laws.md)."""

    law: Literal["thin_shell", "neo_hookean", "mooney_rivlin", "skalak", "surface_tension"] = "thin_shell"
    psi: float = Field(
        LAW_PARAMETER_DEFAULTS["mooney_rivlin"]["psi"], ge=0, le=1,
        description="Mooney-Rivlin parameter psi'; law: mooney_rivlin only",
    )
    skalak_c: Union[float, Literal["auto"]] = Field(
        LAW_PARAMETER_DEFAULTS["skalak"]["skalak_c"],
        description="Skalak area-dilation parameter C, K_s/G_s = 1 + 2C (at most 1e4: the area modulus "
        "then makes the membrane force stiff beyond what the explicit stepping can follow); "
        "auto: a nearly area-incompressible membrane, C the smallest that keeps the area within "
        "membrane.area_tolerance at the case's G (docs/laws.md, \"The area modulus for the stress\"); "
        "skalak_c_choice then says what it chose; law: skalak only",
    )
    area_tolerance: float = Field(
        SKALAK_AUTO_AREA_TOLERANCE, gt=0, le=0.2,
        description="skalak_c auto only: the largest relative change of the membrane's area the chosen C "
        "aims at (a smaller one costs more: the step's stiffness grows with C/G)",
    )
    skalak_c_choice: Optional[str] = Field(
        None, description="set by capsim, not a setting: why skalak_c auto chose the C the case holds")
    traction: Literal["galerkin", "contour"] = Field(
        "galerkin",
        description="galerkin: Δf from the energy gradient and the consistent mass matrix "
        "(every node restrained); contour: the seed's element average (3.6)-(3.7)",
    )
    bending_modulus: float = Field(
        0.0, ge=0,
        description="bending modulus κ/(E_s a²) of a dihedral-hinge energy relative to the rest shape "
        "(0: none, the seed's membrane); needs traction: galerkin; validated up to 1e-2 (a warning beyond; "
        "from physical.bending_modulus at most 1e3)",
    )
    reference_shape: Optional[ReferenceShape] = Field(
        None,
        description="the stress-free shape the elastic and bending energies are measured from (none or kind rest: "
        "the initial shape; shape.inflation is the other way to pre-stress, give one); every law but surface_tension")
    viscosity: Optional[MembraneViscosity] = Field(
        None,
        description="surface viscosity {model, shear, dilatational} as Boussinesq numbers (docs/viscous_membrane.md); "
        "none: a purely elastic membrane; needs traction: galerkin",
    )

    @field_validator("skalak_c", mode="before")
    @classmethod
    def _skalak_c_auto_or_number(cls, v):
        return _auto_or_number(v, "(0, 1e4]")

    @field_validator("skalak_c")
    @classmethod
    def _skalak_c_in_range(cls, v):
        if v != "auto" and not 0 < v <= SKALAK_MAX_C:
            raise ValueError(f"must be in (0, {SKALAK_MAX_C:g}] (or auto)")
        return v

    @model_validator(mode="after")
    def _area_tolerance_needs_auto(self) -> Membrane:
        if self.area_tolerance != SKALAK_AUTO_AREA_TOLERANCE and self.skalak_c_choice is None \
                and self.skalak_c != "auto":
            raise _FieldProblem("area_tolerance", self.area_tolerance,
                                "applies only to skalak_c: auto (the C it chooses); remove it or set skalak_c: auto")
        return self

    @model_validator(mode="after")
    def _parameters_of_the_law(self) -> Membrane:
        for law, params in LAW_PARAMETER_DEFAULTS.items():
            for name, default in params.items():
                value = getattr(self, name)
                if self.law != law and name in self.model_fields_set and value != default:
                    raise _FieldProblem(name, value, f"applies only to law: {law}, not to law: {self.law}; remove it")
        return self

    @model_validator(mode="after")
    def _reference_shape_of_a_membrane(self):
        if self.stress_free_differs and self.law == "surface_tension":
            raise _FieldProblem("reference_shape.kind", self.reference_shape.kind,
                                "a drop (law: surface_tension) has no membrane and no stress-free shape; remove it")
        return self

    @property
    def stress_free_differs(self) -> bool:
        """Whether the stress-free shape is another surface than the initial one."""
        return self.reference_shape is not None and self.reference_shape.kind != "rest"

    @model_validator(mode="after")
    def _viscosity_needs_galerkin(self):
        if self.viscosity is not None and self.viscosity.active and self.traction != "galerkin":
            raise _FieldProblem(
                "traction", self.traction,
                "a viscous membrane (membrane.viscosity) needs traction: galerkin: the viscous traction is a "
                "Galerkin load (docs/viscous_membrane.md)")
        return self

    @model_validator(mode="after")
    def _bending_needs_galerkin(self):
        if self.bending_modulus > 0 and self.traction != "galerkin":
            raise ValueError(
                f"bending_modulus = {self.bending_modulus} needs traction: galerkin "
                f"(got traction: {self.traction}); the contour traction has no bending term"
            )
        return self


class Physical(_Model):
    """Dimensional values that give G = μ k a / E_s (quantities with units, parsed by
    pint: ``"100 1/s"``, ``"1.2 mPa*s"``, ``"2.8 um"``, ``"18 uN/m"``); capsim.units."""

    shear_rate: str = Field(description="the flow's rate, e.g. '100 1/s': the shear rate k of simple shear (and "
                            "above a wall), the extension rate ε of the extensions, U/R of Poiseuille flow, the scale "
                            "of a linear flow's velocity_gradient (capsim.scene.flows)")
    viscosity: str = Field(description="viscosity μ of the outer fluid, e.g. '1.2 mPa*s'")
    inner_viscosity: Optional[str] = Field(
        None, description="viscosity of the inner fluid (a cell's cytoplasm), e.g. '6 mPa*s'; gives "
        "flow.viscosity_ratio = λ = inner / outer viscosity, which must be in [1e-3, 1e3] (validated in "
        "[0.01, 100]: a warning outside)")
    radius: str = Field(description="equal-volume radius a, e.g. '2.8 um'")
    surface_modulus: Optional[str] = Field(
        None, description="membrane elastic modulus E_s (a drop: its surface tension), e.g. '18 uN/m'; "
        "or give shear_modulus")
    shear_modulus: Optional[str] = Field(
        None, description="surface shear modulus G_s = E_s / 3 of the elastic laws, e.g. '6 uN/m'; "
        "or give surface_modulus")
    membrane_viscosity: Optional[str] = Field(
        None, description="surface shear viscosity μ_s of the membrane, e.g. '2.5e-7 N*s/m' (red cell); gives "
        "membrane.viscosity.shear = Bq = μ_s / (μ a), Kelvin–Voigt, which must be at most 1e4 (validated up "
        "to 30: a warning beyond)")

    @field_validator("shear_rate", "viscosity", "inner_viscosity", "radius", "surface_modulus", "shear_modulus",
                     "membrane_viscosity", "bending_modulus",
                     mode="before")
    @classmethod
    def _a_quantity(cls, v: Any, info: ValidationInfo) -> Any:
        from capsim.units import parse

        if v is not None:
            parse(v, info.field_name)  # UnitsError is a ValueError: a one-line message
        return v

    @model_validator(mode="after")
    def _one_modulus(self) -> Physical:
        if (self.surface_modulus is None) == (self.shear_modulus is None):
            given = "not both" if self.surface_modulus is not None else "one of the two"
            raise ValueError(f"give surface_modulus (E_s) or shear_modulus (G_s), {given}")
        return self

    bending_modulus: Optional[str] = Field(
        None, description="membrane bending modulus κ, e.g. '1.8e-19 J'; membrane.bending_modulus is then "
        "computed as κ/(E_s a²), which must be finite and at most 1e3 (validated up to 1e-2: a warning beyond)")

    def bending_modulus_scaled(self) -> float:
        """κ/(E_s a²) from the physical κ, E_s (or 3 G_s) and a (inf where it overflows: divided
        step by step, never a ZeroDivisionError or an OverflowError)."""
        from capsim.units import parse

        E_s = self.conversion()["E_s_N_per_m"]
        a = parse(self.radius, "radius")
        kappa = parse(self.bending_modulus, "bending_modulus")
        try:
            return kappa / (E_s * a**2)  # the formula runs were resolved with: the same bits
        except (OverflowError, ZeroDivisionError):  # a² beyond a float, or 0
            return kappa / E_s / a / a

    def conversion(self) -> dict[str, float]:
        """G, Ca and the time unit (capsim.units.conversion)."""
        from capsim.units import conversion

        return conversion(self.shear_rate, self.viscosity, self.radius, self.surface_modulus, self.shear_modulus,
                          self.membrane_viscosity, self.inner_viscosity)


class FlowHistory(_Model):
    """How the flow's rate changes in time (capsim.scene.flows.FLOW_HISTORIES; docs/viscous_membrane.md,
    "Flows that change in time"). Times stay in units of 1/rate, the rate before any change."""

    kind: Literal[tuple(FLOW_HISTORIES)] = Field(  # type: ignore[valid-type]
        "steady", description="; ".join(f"{name}: {cls.description}" for name, cls in FLOW_HISTORIES.items()))
    stop_time: Optional[float] = Field(
        None, gt=0, description="kind: stop only: the kt at which the flow stops (at or after time.t_end: "
        "the flow never stops in the run, as in the two-step warm-up copies of a campaign)")
    step_time: Optional[float] = Field(None, gt=0, description="kind: step only: the kt at which the rate changes")
    step_factor: Optional[float] = Field(
        None, ge=-100, le=100, description="kind: step only: the rate after step_time, as a factor of the rate before")
    omega: Optional[float] = Field(
        None, gt=0, le=1e4, description="kind: oscillating only: the angular frequency ω in units of the rate "
        "(the rate is rate·sin(ω t))")
    table: Optional[list[list[float]]] = Field(
        None, description="kind: table only: rows [kt, factor], times increasing from 0, interpolated linearly")

    @model_validator(mode="after")
    def _fields_of_the_kind(self) -> "FlowHistory":
        problem = fields_problem(self, FLOW_HISTORIES, HISTORY_FIELDS)
        if problem is not None:
            raise _FieldProblem(*problem)
        return self


class Flow(_Model):
    """The undisturbed flow (kind, capsim.scene.flows) and its rate; G = μ·rate·a/E_s, viscosity ratio λ."""

    @model_validator(mode="before")
    @classmethod
    def _G_is_shear_rate_G(cls, data: Any) -> Any:
        """flow.G: the dimensionless rate of every flow (stored as shear_rate_G, its long name).
        G alone is left to the field's alias, so that a problem with it is named flow.G."""
        if isinstance(data, dict) and "G" in data and "shear_rate_G" in data:
            data = dict(data)
            G = data.pop("G")
            if data["shear_rate_G"] != G:
                raise _FieldProblem("G", G, f"and shear_rate_G = {data['shear_rate_G']!r} name one value (G is "
                                    "shear_rate_G's short name); give one of them")
        return data

    shear_rate_G: float = Field(
        0.1, gt=0, validation_alias=AliasChoices("shear_rate_G", "G"),
        description="G = μ·rate·a/E_s for every flow.kind (rate k, ε or U/R; `flow.G` is its short name); "
        "or give the case's `physical` block (then G is computed from it "
        "and stored here, and must be in [1e-6, 100]: outside, the units have slipped); validated in "
        "[5e-4, 1] (a warning outside)",
    )
    capillary_number: Optional[float] = Field(
        None, gt=0,
        description="Ca = μ k a / G_s, as papers that scale by the shear modulus G_s quote it; instead of "
        "flow.G, which is then computed: G = Ca/3 for the elastic laws (G_s = E_s/3), G = Ca for "
        "surface_tension (a drop: Ca = μka/γ)",
    )
    viscosity_ratio: float = Field(
        1.0, gt=0,
        description="internal / external viscosity λ, in [1e-3, 1e3]: the λ ≠ 1 double-layer operator "
        "has its spectrum in [min(1, λ), max(1, λ)], so its condition number is max(λ, 1/λ) and the "
        "solve's iterations grow like its square root; beyond 1e3 the capsule is a rigid particle; "
        "validated in [0.01, 100] (a warning outside); or give physical.inner_viscosity",
    )

    history: Optional[FlowHistory] = Field(
        None, description="none or {kind: steady}: steady shear; {kind: stop, stop_time: kt}: the flow stops at kt")

    kind: Literal[tuple(FLOWS)] = Field(  # type: ignore[valid-type]
        "simple_shear",
        description="the undisturbed flow (capsim.scene.flows): " + "; ".join(
            f"{name}: {cls.description} (rate: {cls.rate})" for name, cls in FLOWS.items())
        + ". flow.G (long name shear_rate_G) is G = μ·rate·a/E_s for every kind, and the time unit is 1/rate",
    )
    velocity_gradient: Optional[list[list[float]]] = Field(
        None, description="kind: linear only: the velocity gradient L (L_ij = ∂u_i/∂x_j) as 3 rows of 3 numbers, "
        "traceless, in units of the rate G is defined with (largest entry about 1)")
    poiseuille_radius: Optional[float] = Field(
        None, gt=1.0, le=1e4,
        description="kind: poiseuille only: the radius R of the unbounded Poiseuille flow (where it would vanish), "
        "in units of a; the rate is U/R, U the centreline speed")

    @model_validator(mode="after")
    def _fields_of_the_kind(self) -> "Flow":
        problem = fields_problem(self, FLOWS, FLOW_FIELDS)
        if problem is not None:
            raise _FieldProblem(*problem)
        return self

    @property
    def stop_time(self) -> float | None:
        """The kt at which the flow stops, None for steady shear."""
        return self.history.stop_time if self.history is not None and self.history.kind == "stop" else None

    @property
    def jump(self) -> tuple[float, float] | None:
        """(kt, factor after it) of a jump in the rate (kinds stop and step), None without one."""
        return None if self.history is None else FLOW_HISTORIES[self.history.kind].jump(self.history)

    @property
    def rate_factor(self):
        """a(t), the factor of the rate at time t, for a rate that varies smoothly; None otherwise."""
        return None if self.history is None else FLOW_HISTORIES[self.history.kind].factor(self.history)

    @field_validator("viscosity_ratio")
    @classmethod
    def _lambda_conditioning(cls, v: float) -> float:
        return _in_range(v, *LAMBDA_RANGE, "the double-layer solve's condition number is max(λ, 1/λ)")



#: faces of each base polyhedron
BASE_FACES = {"octahedron": 8, "icosahedron": 20}


#: mesh.symmetry: the point inversion x -> -x (half) holds for every orientation; the quarter
#: (mirror z -> -z and rotation by pi about z) only for an axis in the shear plane or along z
SYMMETRY_MODES = ("auto", "quarter", "half", "none")
#: a Skalak membrane above this G with skalak_c below SKALAK_HIGH_STRESS_C is warned of its area's growth
#: (benchmarks/rbc_high_stress.md: the red cell in 30 mPa s at 0.1-50 Pa against C)
SKALAK_SOFT_AREA_G = 1.0
SKALAK_HIGH_STRESS_C = 1000.0
#: the old boolean mesh.symmetry, still read
_SYMMETRY_FROM_BOOL = {True: "auto", False: "none"}


def axis_keeps_quarter_symmetry(axis, tol: float = 1e-12) -> bool:
    """Whether a head-tail symmetric rest shape with this axis is mapped onto itself by the
    mirror z -> -z and the rotation by pi about z: the axis in the plane z = 0, or along z."""
    x, y, z = axis
    return abs(z) <= tol or math.hypot(x, y) <= tol


def sphere_mesh_keeps_quarter_symmetry(base: str, axis) -> bool:
    """Whether the mesh of a sphere turned from y onto `axis` (capsim.numerics.mesh.rest_shape_mesh) is
    mapped onto itself by the mirror z -> -z and the rotation by pi about z: what auto then finds
    and uses. The sphere itself keeps both whatever its axis (which only labels the material
    director); its mesh does when the turn maps the base polyhedron's symmetries onto them (an
    axis in the shear plane or along z, and others such as [0, 1, 1] on the octahedron). Decided
    on the level-0 mesh: subdivision maps a symmetry of the base polyhedron to one of every level."""
    import numpy as np

    from capsim.numerics.mesh import rotation_onto, unit_sphere_mesh

    points = unit_sphere_mesh(base, 0).positions @ rotation_onto(axis).T
    for generator in (np.array([1.0, 1.0, -1.0]), np.array([-1.0, -1.0, 1.0])):
        images = points * generator
        distance = np.sqrt(((images[:, None, :] - points[None, :, :]) ** 2).sum(axis=2)).min(axis=1)
        if not np.all(distance <= 1e-9):
            return False
    return True


class Mesh(_Model):
    base: Literal["octahedron", "icosahedron"] = "octahedron"
    level: int = Field(3, ge=0, le=6, strict=True)
    symmetry: Literal["auto", "quarter", "half", "none"] = Field(
        "auto",
        description="symmetries of shear flow and the rest shape used to evaluate the boundary integrals "
        "at one node of each orbit: quarter = the mirror z -> -z and the rotation by pi about z (a quarter "
        "of the nodes; needs the rest shape's axis in the shear plane or along z), half = the point "
        "inversion x -> -x (half of the nodes; any orientation), none = every node (lets asymmetric modes "
        "develop), auto = the largest that the mesh has; the run file's 'symmetry' attribute says which "
        "group was used (mirror_z+rotation_z, inversion, none). The old true/false read as auto/none",
    )

    @field_validator("symmetry", mode="before")
    @classmethod
    def _symmetry_from_bool(cls, v: Any) -> Any:
        # runs before _Model's strict check (pydantic runs 'before' validators last-defined first)
        if isinstance(v, bool):
            return _SYMMETRY_FROM_BOOL[v]
        if not isinstance(v, str) or v not in SYMMETRY_MODES:
            raise ValueError(f"must be one of {', '.join(SYMMETRY_MODES)} (or true/false, read as auto/none)")
        return v

    @property
    def n_nodes(self) -> int:
        """Nodes of the 6-node mesh: F = F₀·4^level faces, F/2 + 2 vertices and 3F/2 edge midpoints."""
        return 2 * BASE_FACES[self.base] * 4 ** self.level + 2


class Quadrature(_Model):
    regular_order: Literal[1, 3, 4, 6, 7, 12] = Field(
        6, description="points of the symmetric Gauss rule on each element (degree 1, 2, 3, 4, 5, 6)"
    )
    # 2 vs 5 changes D_xy by 3e-5 (level 3, G = 0.1), far below the mesh error
    singular_order: int = Field(
        2, ge=1, le=20, strict=True,
        description="Duffy rule on the elements holding the target node: n radial x 2n angular "
        "Gauss-Legendre points on each of two sub-triangles",
    )
    # Sharp rims of flat shapes put elements close to a node without holding it;
    # with 0.5 (and singular_order 8) the double-layer identity error of b/a = 0.3
    # at level 3 falls from 6.6e-2 to 5.5e-3 for 4.7x the double-layer time (docs/method.md, "Numerical method")
    near_field_factor: float = Field(
        0.0, ge=0, le=3,
        description="integrate elements within this many element sizes of a node (not holding it) "
        "on subdivided triangles; 0 = off",
    )
    near_field_levels: int = Field(
        1, ge=1, le=3, strict=True, description="near-field elements are split into 4^levels triangles"
    )
    # two stiff capsules 0.06 a apart (level 2): A of Batchelor & Green 0.5608 without, 0.5523 with, level 3
    # 0.5486 (docs/known_answers.md, "Two capsules"); costs nothing while the capsules are apart
    capsule_near_field_factor: float = Field(
        2.0, ge=0, le=3,
        description="several capsules: integrate another capsule's elements within this many element sizes "
        "of a node on subdivided triangles (near_field_levels); 0 = off. Applies while near_field_factor "
        "is 0 (which covers every element)",
    )


#: the time options that belong to one scheme (set to another value with another scheme: an error),
#: from the scheme registry: each scheme declares its own (capsim.solve.timestepping.register_scheme)
SCHEME_OPTIONS = {name: tuple(cls.option_fields) for name, cls in SCHEMES.items() if cls.option_fields}


class _TimeCommon(_Model):
    """Adaptive time stepping (capsim.solve.timestepping); times in units of 1/k.

    The fields every scheme reads; :data:`Time` adds ``scheme`` and each registered
    scheme's own options."""

    t_end: float = Field(
        10.0, gt=0, description="end time, at least 1e-6 and at least dt_min (else no step is taken)"
    )
    rtol: Union[float, Literal["auto"]] = Field(
        "auto",
        description="the time error's bound, the same for every scheme: max over t of |D_xy error| <= 1.5 rtol "
        "and |theta error| <= 6 rtol rad (docs/time_stepping.md); at least 1e-10: the velocities it "
        "compares are accurate to ~1e-12 (quadrature round-off, solver.tol), so a smaller one chases noise. "
        "auto (the default): the largest tolerance whose time error stays below a tenth of the mesh level's "
        "own error (capsim.solve.accuracy, from the error model: docs/benchmarks.md, \"Error model\"); in a scene the "
        "model was not trained on (a flow.history, another flow.kind, a wall, several capsules) no looser than 1e-4, "
        "predicting nothing (docs/time_stepping.md, \"Flows that change in time\"); rtol_choice "
        "then says what it chose and why",
    )
    rtol_choice: Optional[str] = Field(
        None, description="set by capsim, not a setting: why time.rtol auto (or the accuracy target) chose "
        "the tolerance the case holds")
    # dt_min and dt_max come before dt_initial so that its check can see both.
    dt_min: float = Field(1.0e-8, gt=0)
    dt_max: float = Field(0.5, gt=0)
    dt_initial: float = Field(1.0e-3, gt=0)
    max_steps: int = Field(1_000_000, ge=1, strict=True)
    stop_when_steady: bool = Field(False, strict=True)
    stop_when_settled: bool = Field(
        False, strict=True,
        description="stop when the motion has settled (checked once per unit of kt), by the same rule as the "
        "summary's own 'settled': a steady shape, the last two whole orbits agreeing within 1 % (period and "
        "orbit constant), or the last two swings within 5 % (docs/method.md, \"Motion classes\"; "
        "capsim.solve.observables.orbit_settled)",
    )
    max_wall_s: Optional[float] = Field(
        None, gt=0, le=1e9,
        description="wall-time limit of one invocation in seconds: the run stops as 'interrupted' at the first "
        "step past it, with its checkpoint; --resume (or a sweep, which resumes) continues it with the limit "
        "counted afresh, so a long run advances by up to this much per invocation (default: none)",
    )

    @model_validator(mode="after")
    def _options_of_the_scheme(self):
        for scheme, cls in SCHEMES.items():  # the registry as it is now, a scheme added later included
            if scheme == self.scheme or scheme in SCHEMES[self.scheme].uses_options_of:
                continue
            for name in cls.option_fields:
                value = getattr(self, name)
                if name in self.model_fields_set and value != type(self).model_fields[name].default:
                    raise _FieldProblem(name, value,
                                        f"applies only to scheme: {scheme}, not to scheme: {self.scheme}; remove it")
        return self

    @field_validator("rtol", mode="before")
    @classmethod
    def _rtol_auto_or_number(cls, v):
        return _auto_or_number(v, "[1e-10, 1)")

    @field_validator("rtol")
    @classmethod
    def _rtol_above_round_off(cls, v):
        if v == "auto":
            return v
        if not v > 0:
            raise ValueError("must be > 0 (or auto)")
        if not v < 1:
            raise ValueError("must be < 1 (or auto)")
        if v < 1e-10:
            raise ValueError("must be >= 1e-10 (the velocities are accurate to ~1e-12)")
        return v

    @model_validator(mode="after")
    def _at_least_one_step(self):
        if self.t_end < max(1e-6, self.dt_min):
            raise _FieldProblem(
                "t_end", self.t_end,
                f"must be >= max(1e-6, dt_min = {self.dt_min:g}): a shorter run takes no step",
            )
        return self

    @field_validator("dt_max")
    @classmethod
    def _dt_max_above_min(cls, v: float, info: ValidationInfo) -> float:
        dt_min = info.data.get("dt_min")
        if dt_min is not None and not v > dt_min:
            raise ValueError(f"must be > dt_min ({dt_min:g})")
        return v

    @field_validator("dt_initial")
    @classmethod
    def _dt_initial_in_range(cls, v: float, info: ValidationInfo) -> float:
        lo, hi = info.data.get("dt_min"), info.data.get("dt_max")
        if lo is not None and hi is not None and not lo <= v <= hi:
            raise ValueError(f"must be in [dt_min, dt_max] = [{lo:g}, {hi:g}]")
        return v



def _time_model() -> type[_TimeCommon]:
    """The ``time`` section: the common fields, ``scheme`` (the registry's names) and every
    registered scheme's options, in the registry's order."""
    fields: dict[str, Any] = {"scheme": (Literal[tuple(SCHEMES)], Field(
        DEFAULT_SCHEME,
        description="; ".join(f"{name}: {cls.description}" for name, cls in SCHEMES.items()),
    ))}
    for cls in SCHEMES.values():
        for name, spec in cls.option_fields.items():
            if name in fields or name in _TimeCommon.model_fields:
                raise TypeError(f"time.{name} is declared twice (scheme {cls.name})")
            fields[name] = spec
    return create_model("Time", __base__=_TimeCommon, __module__=__name__, **fields)


#: the ``time`` section of a case (a pydantic model built from the scheme registry)
Time = _time_model()
Time.__doc__ = _TimeCommon.__doc__

class Solver(_Model):
    """Velocity solve for viscosity_ratio != 1 (double layer); unused at lambda = 1."""

    method: Literal["gmres", "substitution"] = Field(
        "gmres", description="GMRES (scipy, matrix-free) or the seed's successive substitution"
    )
    tol: float = Field(
        1.0e-6, gt=0, lt=1,
        description="relative residual of the velocity solve, at least 1e-14: below, the residual is the "
        "round-off of the double-layer sums (N_p terms of ~1e-16 each) and is never reached",
    )
    max_iter: int = Field(
        200, ge=20, le=1000, strict=True,
        description="most iterations (gmres: restart cycles of min(60, max_iter) steps) of the λ ≠ 1 "
        "solve, in [20, 1000]: the operator's spectrum lies in [min(1, λ), max(1, λ)], so fewer than 20 "
        "cannot reach the tolerance at a realistic λ such as 5, and more than 1000 is a solve that does "
        "not converge (a hang, not a result); substitution needs ln(tol) / ln(|1-λ|/(1+λ))",
    )
    volume_correction: bool = Field(
        True, strict=True,
        description="remove the discrete net flux of the nodal velocities (volume conservation)",
    )

    @field_validator("tol")
    @classmethod
    def _tol_above_round_off(cls, v: float) -> float:
        if v < 1e-14:
            raise ValueError("must be >= 1e-14 (the double-layer sums are exact only to round-off)")
        return v


class Output(_Model):
    path: str = Field("runs/{name}.h5", min_length=1, description="'{name}' is the case name")
    snapshot_every: float = Field(
        0.5, gt=0,
        description="time between full snapshots, 1/k; at least time.dt_min (the steps are clipped to "
        "the snapshot times) and at least time.t_end / 10000 (each snapshot holds every node)",
    )
    checkpoint_every_steps: int | None = Field(
        None, ge=1, strict=True,
        description="also write the restart checkpoint <path>.ckpt.npz every N accepted steps (default: none; "
        "the checkpoint follows the wall time, checkpoint_every_s)",
    )
    checkpoint_every_s: float = Field(
        10.0, gt=0,
        description="write the restart checkpoint <path>.ckpt.npz every M seconds of wall time (and when the run "
        "is stopped): a killed run redoes at most that much (killed before its first, --resume starts it again)",
    )


#: the smallest gap between membrane and wall the image integrals are resolved at (regular rule)
WALL_GAP_DEFAULT = 0.1
#: guards.min_capsule_gap: the smallest gap between two capsules' membranes a run goes on at (units of a)
CAPSULE_GAP_DEFAULT = 0.02


class Guards(_Model):
    """Stability guards checked after every accepted step; crossing one stops the
    run as 'unstable' (non-finite positions and dt < time.dt_min always do)."""

    min_element_quality: float = Field(
        0.05, ge=0, lt=1, description="worst vertex-triangle quality (1 = equilateral) allowed"
    )
    max_volume_drift: float = Field(0.01, gt=0, description="largest |V - V0| / V0 allowed")
    max_area_change: float = Field(2.0, gt=0, description="largest |A - A0| / A0 allowed")
    max_principal_stretch: float = Field(10.0, gt=1, description="largest membrane principal stretch allowed")
    min_dt_fraction: float = Field(
        1e-3, ge=0, lt=1,
        description="stop when the recent time step falls below this fraction of the typical one (stalled run)",
    )
    min_wall_gap: float = Field(
        WALL_GAP_DEFAULT, gt=0, le=1,
        description="with a wall: stop when the membrane comes closer to it than this (units of a); the wall's "
        "image integrals use the regular rule, whose error grows as the gap falls below an element's size "
        "(docs/known_answers.md, 'A capsule near a wall')",
    )

    min_capsule_gap: float = Field(
        CAPSULE_GAP_DEFAULT, gt=0, le=1,
        description="with several capsules (capsules): stop when two membranes come closer than this (units "
        "of a, the smallest node-to-node distance between two capsules); no contact force acts, so a closer "
        "approach is refused rather than allowed to overlap (docs/known_answers.md, 'Two capsules')",
    )



#: the CaseWarnings of the case being validated by case_from_dict (issued there, with its source)
_PENDING_WARNINGS: ContextVar[list[str] | None] = ContextVar("_PENDING_WARNINGS", default=None)
#: the warnings registry of CaseWarning: a text is shown once per process (a case is validated
#: several times on its way to a run), unless the warning filters say "always"
_SHOWN_WARNINGS: dict = {}


def _case_warning(text: str) -> None:
    pending = _PENDING_WARNINGS.get()
    if pending is not None:
        pending.append(text)
    else:
        _issue_warning(text, "<case>")


def _issue_warning(text: str, source: str) -> None:
    import multiprocessing

    if multiprocessing.parent_process() is not None:
        return  # a worker of a sweep or study: the process that planned its cases warned about them
    # one line: at line 0 of the case file, which has no source line to show beneath it
    warnings.warn_explicit(text, CaseWarning, filename=source, lineno=0, module="capsim.config",
                           registry=_SHOWN_WARNINGS)


def _substitution_problem(solver: Solver, lam: float) -> _FieldProblem | None:
    """Whether successive substitution can reach the solver's tolerance at this λ in max_iter."""
    if solver.method == "substitution" and lam != 1.0:
        # Richardson iteration with the optimal step: the error falls by |1-λ|/(1+λ) per iteration
        needed = math.ceil(math.log(solver.tol) / math.log(abs(1.0 - lam) / (1.0 + lam)))
        if solver.max_iter < needed:
            return _FieldProblem(
                "max_iter", solver.max_iter,
                f"substitution at viscosity_ratio = {lam:g} needs >= {needed} iterations to reach "
                f"tol = {solver.tol:g} (rate |1-λ|/(1+λ)); raise max_iter (<= 1000) or use method: gmres",
            )
    return None


class Wall(_Model):
    """The scene's boundary: a no-slip plane wall at rest, its normal along the velocity
    gradient (y), below the capsule (capsim.scene.flows, Blake's Green's function)."""

    distance: float = Field(
        ..., gt=1.0, le=1e3,
        description="h: the wall lies at y = y_c − h, h (units of a) below the capsule's initial centre y_c "
        "(with capsules: the first one's); the undisturbed shear flow vanishes on it, u∞ = k (y − y_c + h, 0, 0). "
        "The rest shape must clear it by guards.min_wall_gap",
    )


class Conduit(_Model):
    """The scene's conduit: a rigid tube or duct along x that the capsules flow through
    (capsim.scene.conduit), with flow.kind conduit, its fully developed pressure-driven flow."""

    kind: Literal[tuple(CONDUITS)] = Field(  # type: ignore[valid-type]
        ..., description="the conduit's cross-section: " + "; ".join(
            f"{name}: {cls.description}" for name, cls in CONDUITS.items()))
    radius: Optional[float] = Field(
        None, gt=1.0, le=100.0, description="kind: tube only: its radius R in units of a (the capsule's a/R = 1/R)")
    half_widths: Optional[tuple[float, float]] = Field(
        None, description="kind: duct only: its half-widths [h_y, h_z] in units of a, each in (1, 100]")
    throat_radius: Optional[float] = Field(
        None, gt=0.2, le=100.0, description="kind: constriction only: the radius R_c of its narrowest section (units "
        "of a; below 1 the capsule is squeezed through it)")
    throat_length: Optional[float] = Field(
        None, gt=0.0, le=100.0, description="kind: constriction only: ℓ, the narrowing spans |x| < ℓ (units of a)")
    length: Optional[float] = Field(
        None, gt=0, le=1e3, description="the truncated conduit's length L (units of a); default: from "
        "conduit.truncation (the disturbance's decay along the conduit, docs/conduits.md)")
    truncation: float = Field(
        TRUNCATION_DEFAULT, gt=0, le=1e-3,
        description="the truncation error the closed ends may cause, relative to the capsule's values: the "
        "length is chosen so that A exp(-k l/h) is below it (k/h the slowest decay rate of a disturbance along the "
        "conduit, l the distance from the capsule's reach to an end, A = 1e-3 measured; docs/conduits.md)")
    element_size: Optional[float] = Field(
        None, gt=0.05, le=5.0, description="the wall's element size near the capsules (units of a; growing "
        "away from them); default: 2πh/24, h the half-width (docs/conduits.md: the accuracy it gives)")

    @field_validator("half_widths")
    @classmethod
    def _half_widths_in_range(cls, v):
        if v is not None and not all(1.0 < h <= 100.0 for h in v):
            raise ValueError(f"each half-width must be in (1, 100] (units of a), got {list(v)}")
        return v

    @model_validator(mode="after")
    def _fields_of_the_kind(self) -> "Conduit":
        problem = fields_problem(self, CONDUITS, CONDUIT_FIELDS)
        if problem is not None:
            raise _FieldProblem(*problem)
        if self.kind == "constriction" and not self.throat_radius < self.radius:
            raise _FieldProblem("throat_radius", self.throat_radius, f"must be below conduit.radius = {self.radius:g} "
                                "(the tube narrows to it)")
        if self.length is not None:
            from capsim.scene.conduit import NEAR_REACH, conduit_kind, truncation_error

            kind = conduit_kind(self)
            error = truncation_error(self, kind, self.length)
            if self.length <= 2 * NEAR_REACH or error > self.truncation:
                raise _FieldProblem("length", self.length, f"is too short for conduit.truncation = "
                                    f"{self.truncation:g}: its ends err by {min(error, 1.0):.2g}; leave length out "
                                    "(chosen from the truncation) or raise the truncation")
        return self


class Capsule(_Model):
    """One capsule of a scene of several (``capsules:``): where it starts, and what differs from
    the top-level sections, which every field it leaves out takes (capsim.scene.bodies)."""

    center: tuple[float, float, float] = Field(
        ..., description="the capsule's centroid [x, y, z] at t = 0 in units of a, within 1e6 a of the origin "
        "in every coordinate (with a wall: within 1e3 a of it; inside flow.poiseuille_radius of the Poiseuille axis)")
    shape: Optional[Shape] = Field(None, description="its rest shape (default: the top-level shape)")
    initial_axis: Optional[tuple[float, float, float]] = Field(
        None, description="direction of its rest shape's symmetry axis at t = 0 (default: the top-level "
        "initial_axis / initial_tilt_deg)")
    initial_tilt_deg: Optional[float] = Field(
        None, ge=-90, le=90, description="its in-plane tilt about z (give this or initial_axis, not both)")
    membrane: Optional[Membrane] = Field(
        None, description="its membrane: the top-level law, traction and viscosity, its own law parameters "
        "(psi, skalak_c) and bending_modulus (default: the top-level membrane)")
    modulus_ratio: float = Field(
        1.0, gt=0, le=1e3,
        description="its membrane's elastic modulus E_s over the top-level one's, the unit of every modulus "
        "(a stiffer cell: > 1); its own G is flow.G / modulus_ratio")
    viscosity_ratio: Optional[float] = Field(
        None, gt=0, description="its λ, inner over outer viscosity (default: flow.viscosity_ratio)")

    @model_validator(mode="after")
    def _one_orientation(self) -> Capsule:
        if self.initial_axis is not None and self.initial_tilt_deg is not None:
            raise _FieldProblem("initial_axis", list(self.initial_axis),
                                "give initial_axis or initial_tilt_deg, not both; remove one")
        if self.initial_axis is not None and not math.fsum(c * c for c in self.initial_axis) > 0:
            raise _FieldProblem("initial_axis", list(self.initial_axis), "must be a nonzero direction")
        return self


class Accuracy(_Model):
    """An accuracy target (capsim.solve.accuracy): the mesh level and time.rtol that meet it, predicted at
    the least cost from the error model (docs/benchmarks.md, "Error model"), or measured on the
    case's own levels 1, 2, ... (capsim.runs.ladder)."""

    quantity: str = Field(
        ..., description="the value the target is for: D_xy, theta (θ) or Sxy_star (S*_xy) at t_end (the error "
        "model's: predicted or measured), or the scene's own, always measured by the ladder: lift and slip (a wall "
        "run's window means), gap (the final wall gap), separation (a pair's final cross-stream separation), "
        "migration (the centroid's drift across a Poiseuille flow); stored as the column it names "
        "(capsim.solve.accuracy.SCENE_QUANTITIES)")
    target: float = Field(
        ..., gt=0, lt=1,
        description="its largest error: relative (a fraction of the value) for D_xy and Sxy_star, in rad for theta")
    method: Literal["auto", "predict", "measure"] = Field(
        "auto", description="predict: the level and rtol the error model predicts; measure: run levels 1, 2, ... "
        "at one rtol and keep the first whose own error estimate (Richardson from the levels below it) meets the "
        "target; auto: predict where the model is sure of the case, measure where it is not. Set to what auto "
        "chose in a resolved case")
    max_level: int = Field(
        4, ge=2, le=6, description="measure: the finest level the ladder runs (level 5 costs minutes to hours a run)")
    choice: Optional[str] = Field(
        None, description="set by capsim, not a setting: the level and rtol chosen, the predicted error and cost, "
        "or the ladder to run")

    @field_validator("quantity", mode="before")
    @classmethod
    def _a_quantity_capsim_reports(cls, v: Any) -> Any:
        if not isinstance(v, str):
            return v  # the strict check names the type
        from capsim.solve.accuracy import AccuracyError, canonical  # numpy and the model's JSON only

        try:
            return canonical(v)
        except AccuracyError as exc:
            raise ValueError(str(exc).split(": ", 1)[1]) from None


class Case(_Model):
    """One simulation: every knob that changes the result, nothing else.

    Built in three steps: the fields, each validated alone; then the case resolved, once
    (:meth:`_resolved`: the values capsim derives from what was given -- G from
    flow.capillary_number or physical, λ, the bending modulus and the membrane viscosity from
    physical -- and after them the mesh level and time.rtol the error model chooses, so that it
    chooses for this case's G, λ and bending); then the cross-field checks, which only check (a
    capsule's own G, a wall's clearance at the chosen level, a scene's symmetry)."""

    name: str = Field(
        min_length=1, max_length=NAME_MAX, pattern=r"^[A-Za-z0-9._-]+$",
        description=f"at most {NAME_MAX} characters: it becomes a file name (255-byte limit, less suffixes)",
    )
    shape: Shape = Shape()
    membrane: Membrane = Membrane()
    flow: Flow = Flow()
    initial_tilt_deg: float = Field(
        0.0, ge=-90, le=90,
        description="in-plane shorthand for the initial orientation: rotation of the rest shape about z; "
        "its symmetry axis is then (-sin t, cos t, 0). Give this or initial_axis, not both",
    )
    initial_axis: Optional[tuple[float, float, float]] = Field(
        None,
        description="direction [x, y, z] of the rest shape's symmetry axis at t = 0 (normalised on load); "
        "the shape is turned from the y-axis onto it by the smallest rotation (about z when the axis lies "
        "in the shear plane, so [-sin t, cos t, 0] is initial_tilt_deg t). Unset: [0, 1, 0] turned by "
        "initial_tilt_deg",
    )
    initial_center: Optional[tuple[float, float, float]] = Field(
        None, description="the rest shape's centroid [x, y, z] at t = 0 in units of a (default: the origin), "
        "within 1e6 a of it in every coordinate (inside flow.poiseuille_radius of the Poiseuille axis); "
        "e.g. off the axis of flow.kind poiseuille. Away from the origin the mesh keeps fewer symmetries "
        "(mesh.symmetry auto finds which)",
    )
    mesh: Mesh = Mesh()
    quadrature: Quadrature = Quadrature()
    time: Time = Time()
    solver: Solver = Solver()
    guards: Guards = Guards()
    output: Output = Field(default_factory=Output, validate_default=True)
    wall: Optional[Wall] = Field(
        None, description="a no-slip plane wall below the capsule (none: unbounded flow); simple shear, any λ, "
        "any membrane; the run stops 'unstable' (guard min_wall_gap) before the membrane touches it")
    conduit: Optional[Conduit] = Field(
        None, description="a rigid conduit (a tube or a duct along x) the capsules flow through, with flow.kind "
        "conduit (its pressure-driven flow; G = μU/E_s with U the mean velocity); the run stops 'unstable' (guard "
        "min_wall_gap) before a membrane touches its wall")
    accuracy: Optional[Accuracy] = Field(
        None, description="an accuracy target: capsim picks mesh.level and time.rtol that meet it at the least "
        "predicted cost (give it or those two, not both); capsim run --verify checks it afterwards")
    capsules: Optional[list[Capsule]] = Field(
        None, min_length=1,
        description="several capsules (capsim.scene.bodies): each with its center and, where it differs from the "
        "top-level sections, its shape and orientation; every other field comes from the top-level sections. "
        "Left out: one capsule, placed by initial_center",
    )
    physical: Optional[Physical] = Field(
        None,
        description="dimensional shear rate, viscosity, radius and modulus instead of flow.G, "
        "which is then computed and stored (giving both is an error, unless flow.G is the "
        "value they give, as in a resolved case)",
    )

    @model_validator(mode="after")
    def _resolved(self) -> Case:
        """The one resolving step (the first 'after' validator: pydantic runs them in the order defined).
        The derived values first, each refusing a physical value it cannot take: G (capillary number or
        physical block), λ, κ and Bq; then the level and rtol, whose error model reads G, λ and bending
        (before issue 52 it chose them from the defaults of a case given in physical units or by Ca)."""
        self._G_from_capillary_number()
        self._G_from_physical()
        self._lambda_from_physical()
        self._bending_from_physical()
        self._Bq_from_physical()
        self._area_modulus_from_the_stress()
        self._level_and_tolerance_from_the_error_model()
        return self

    def _area_modulus_from_the_stress(self) -> None:
        """membrane.skalak_c auto: the C that keeps the area within membrane.area_tolerance at this case's G
        (skalak_c_for_stress), for the top-level membrane and each capsule's own (at its own G, flow.G over
        its modulus_ratio); a resolved case holds the number and skalak_c_choice says why."""
        G = self.flow.shear_rate_G

        def chosen(membrane: Membrane, G_here: float, shape: Shape, field: str) -> Membrane:
            nu = rest_reduced_volume(shape)
            if nu > SKALAK_AUTO_MAX_REDUCED_VOLUME:
                raise _FieldProblem(field, "auto", f"needs a rest shape with excess area (reduced volume at most "
                                    f"{SKALAK_AUTO_MAX_REDUCED_VOLUME:g}; this {shape.kind}'s is {nu:.3g}): a nearly "
                                    "spherical membrane must stretch to deform, its C is the material's; give a number")
            C = skalak_c_for_stress(G_here, membrane.area_tolerance)
            capped = f"; capped at {SKALAK_MAX_C:g}: the area may change by more" \
                if _skalak_c_unbounded(G_here, membrane.area_tolerance) > SKALAK_MAX_C else ""
            why = (f"auto: C {C:g} for G {G_here:.4g} and area_tolerance {membrane.area_tolerance:g} "
                   f"(dA/A ~ {SKALAK_AUTO_BETA:g} G/(1 + 2C), at least {SKALAK_AUTO_MIN_C:g}){capped}")
            new = membrane.model_copy(update={"skalak_c": C, "skalak_c_choice": why})
            object.__setattr__(new, "__pydantic_fields_set__", set(membrane.model_fields_set))
            return new

        if self.membrane.skalak_c == "auto":
            object.__setattr__(self, "membrane", chosen(self.membrane, G, self.shape, "membrane.skalak_c"))
        if self.capsules and any(c.membrane is not None and c.membrane.skalak_c == "auto" for c in self.capsules):
            capsules = []
            for i, c in enumerate(self.capsules):
                if c.membrane is not None and c.membrane.skalak_c == "auto":
                    fields = set(c.model_fields_set)
                    c = c.model_copy(update={"membrane": chosen(c.membrane, G / c.modulus_ratio, c.shape or self.shape,
                                                                f"capsules[{i}].membrane.skalak_c")})
                    object.__setattr__(c, "__pydantic_fields_set__", fields)
                capsules.append(c)
            object.__setattr__(self, "capsules", capsules)

    def _level_and_tolerance_from_the_error_model(self) -> Case:
        """The accuracy target's level and rtol, else time.rtol auto's rtol (capsim.solve.accuracy); a
        resolved case (a run file's) holds the choice and is taken as it is."""
        from capsim.solve import accuracy as error_model

        stale = self.accuracy is not None and self.accuracy.choice is not None and not self._choice_holds()
        if stale:
            # a resolved case whose target (or method, or level, or rtol) was edited, or a hand-written
            # choice: kept, it would run a level chosen for another target beside this one (or none, the
            # target then ignored); the target chooses again, its level and rtol replacing the case's
            _case_warning(f"accuracy.choice ({self.accuracy.choice[:60]}...) was not made for accuracy "
                          f"{self.accuracy.quantity} {self.accuracy.target:g} at mesh.level {self.mesh.level}, "
                          f"time.rtol {self.time.rtol}: the target chooses the level and rtol again")
        if self.accuracy is not None and (self.accuracy.choice is None or stale):
            for field, given in (("mesh.level", "level" in self.mesh.model_fields_set),
                                 ("time.rtol", self.time.rtol != "auto")):
                if given and not stale:
                    raise _FieldProblem("accuracy", self.accuracy.quantity,
                                        f"give accuracy or {field}, not both: the target chooses it; remove one")
            try:
                best = error_model.plan(self.accuracy.quantity, self.accuracy.target, self.time.t_end,
                                        self.error_model_features(), self.accuracy.method, self.accuracy.max_level)
            except error_model.AccuracyError as exc:  # "accuracy.<field> = <value>: why": the field it names
                field = str(exc).split(" = ", 1)[0]
                name = field.removeprefix("accuracy.")
                value = getattr(self.accuracy, name) if name in Accuracy.model_fields else self.accuracy.target
                raise _FieldProblem(field if name in Accuracy.model_fields else "accuracy.target", value,
                                    str(exc).split(": ", 1)[1]) from None
            self._set_derived("accuracy", "method", best["method"], chosen=True)
            self._set_derived("mesh", "level", best["level"], chosen=True)
            self._set_derived("time", "rtol", best["rtol"], chosen=True)
            self._set_derived("time", "rtol_choice", best["why"], chosen=True)
            self._set_derived("accuracy", "choice", best["why"], chosen=True)
        elif self.time.rtol == "auto":
            rtol, why = error_model.auto_rtol(self.mesh.level, self.error_model_features())
            self._set_derived("time", "rtol", rtol, chosen=True)
            self._set_derived("time", "rtol_choice", why, chosen=True)
        return self

    def _choice_holds(self) -> bool:
        """Whether accuracy.choice is the one capsim made for this target, method and max_level at this
        case's mesh.level and time.rtol (its text, capsim.solve.accuracy.choose and plan, names them)."""
        a, rtol = self.accuracy, self.time.rtol
        head = f"accuracy {a.quantity} {a.target:g}: "
        if not a.choice.startswith(head) or rtol == "auto":
            return False
        rest = a.choice[len(head):]
        if a.method == "predict":
            return rest.startswith(f"level {self.mesh.level}, rtol {rtol:g};")
        return (a.method == "measure" and self.mesh.level == 1 and rest.startswith("measured, ")
                and f" up to {a.max_level} at rtol {rtol:g}, " in rest)

    def error_model_features(self) -> dict[str, Any]:
        """What selects the case's training cases in the error model (capsim.solve.accuracy.nearest): rest
        shape and aspect ratio, law and its parameter, G, λ, bending (several capsules: the first
        one's shape and membrane, the λ farthest from 1); and its scene, which the training cases
        share (capsim.solve.accuracy.TRAINED_SCENE: another is measured, never predicted): flow.kind, the
        history as it acts before t_end, the wall, the number of capsules, and in Poiseuille flow
        the first capsule's distance from the axis (capsim.solve.accuracy.FIXED_BY_SYMMETRY)."""
        from capsim.scene import Scene  # numpy only

        scene = Scene.of(self)  # the scene's features: its flow, its boundaries, its capsules
        first = scene.specs[0]
        membrane = first.membrane or self.membrane
        parameter = {"skalak": "skalak_c", "mooney_rivlin": "psi"}.get(membrane.law)
        history = self.flow.history
        # a stop or a step at or after t_end never acts in the run: the steady scene
        changes_at = None if history is None else (history.stop_time if history.kind == "stop" else
                                                   history.step_time if history.kind == "step" else 0.0)
        acting = history is not None and history.kind != "steady" and changes_at < self.time.t_end
        features = {"shape": first.shape.kind, "aspect_ratio": float(first.shape.aspect_ratio), "law": membrane.law,
                    "law_parameter": float(getattr(membrane, parameter)) if parameter else 0.0,
                    "G": float(self.flow.shear_rate_G),
                    "viscosity_ratio": float(max(self.viscosity_ratios, key=lambda v: abs(math.log(v)))),
                    "bending": membrane.bending_modulus > 0,
                    "flow": scene.flow_kind, "history": history.kind if acting else "steady",
                    "wall": scene.has_boundary, "capsules": scene.body_count,
                    "prestress": bool(first.shape.inflation) or membrane.stress_free_differs}
        if self.flow.kind in ("poiseuille", "conduit"):  # the axis is x: the distance in y and z
            features["axis_offset"] = float(math.hypot(self.center[1], self.center[2]))
        return features

    def _placed(self) -> list[tuple[str, tuple[float, float, float]]]:
        """(field, centre) of every capsule the case places (none: one at the origin)."""
        if self.capsules:
            return [(f"capsules[{i}].center", tuple(c.center)) for i, c in enumerate(self.capsules)]
        return [("initial_center", tuple(self.initial_center))] if self.initial_center is not None else []

    @model_validator(mode="after")
    def _a_scene_capsim_can_place(self) -> Case:
        """Where capsules may start, and what a scene of them may hold: near the origin (round-off),
        inside a Poiseuille flow's radius, within the wall's reach; no inflation of a drop; each
        capsule's own G (flow.shear_rate_G / modulus_ratio) and λ plausible (validate refuses
        what run would)."""
        for field, center in self._placed():
            if not max(abs(v) for v in center) <= MAX_COORDINATE:
                raise _FieldProblem(field, list(center), f"must lie within {MAX_COORDINATE:g} a of the origin in "
                                    "every coordinate: positions are doubles, whose round-off (1e-16 |x|) beyond "
                                    "that exceeds 1e-10 a; place the scene near the origin")
            if self.wall is not None and abs(center[1] - self.wall_y) > WALL_REACH:
                raise _FieldProblem(field, list(center), f"lies {abs(center[1] - self.wall_y):.4g} a from the wall: "
                                    f"at most {WALL_REACH:g} (wall.distance's bound), where the shear of the wall's "
                                    "flow carries a capsule at that speed")
            if self.flow.kind == "poiseuille":
                R, r = self.flow.poiseuille_radius, math.hypot(center[1], center[2])
                if not r < R:
                    raise _FieldProblem(field, list(center), f"lies {r:.4g} a from the axis, outside "
                                        f"flow.poiseuille_radius R = {R:g} (where the flow vanishes; beyond it runs "
                                        "backwards): place the capsule inside R")
                if r + 1.0 > R:
                    _case_warning(f"{field} = {list(center)}: the capsule (radius ~1 a) reaches beyond "
                                  f"flow.poiseuille_radius R = {R:g} ({r:.4g} a from the axis), where the unbounded "
                                  "Poiseuille flow runs backwards: the run goes ahead in that flow, which is no tube's")
        if self.membrane.law == "surface_tension":  # a drop: no membrane whose rest shape could be shrunk
            shapes = [("shape", self.shape)] + [(f"capsules[{i}].shape", c.shape)
                                                for i, c in enumerate(self.capsules or ()) if c.shape is not None]
            for field, shape in shapes:
                if shape.inflation:
                    raise _FieldProblem(f"{field}.inflation", shape.inflation,
                                        "pre-inflates a membrane, and membrane.law surface_tension (a drop) has "
                                        "none; remove it")
        # two ways to a pre-stressed membrane: shape.inflation (the initial shape shrunk) or another
        # stress-free shape (membrane.reference_shape); one capsule takes one
        from capsim.scene import body_specs

        for j, spec in enumerate(body_specs(self)):
            membrane = spec.membrane or self.membrane
            if spec.shape.inflation and membrane.stress_free_differs:
                where = f"capsules[{j}]." if self.capsules else ""
                raise _FieldProblem(f"{where}shape.inflation", spec.shape.inflation,
                                    f"and membrane.reference_shape kind {membrane.reference_shape.kind} both set the "
                                    "stress-free shape; give one (inflation α is a stress-free shape similar to the "
                                    "initial one, smaller by 1 + α)")
        G, (glo, ghi), (llo, lhi) = (self.flow.shear_rate_G, VALIDATED_RANGES["flow.shear_rate_G"],
                                     VALIDATED_RANGES["flow.viscosity_ratio"])
        for i, capsule in enumerate(self.capsules or ()):
            own = G / capsule.modulus_ratio
            if not own <= PHYSICAL_G_RANGE[1]:
                raise _FieldProblem(f"capsules[{i}].modulus_ratio", capsule.modulus_ratio,
                                    f"gives the capsule its own G = flow.G / modulus_ratio = {own:.3g}, "
                                    f"above {PHYSICAL_G_RANGE[1]:g}: a membrane that soft is torn apart at once")
            if not glo <= own <= ghi:
                _case_warning(f"capsules[{i}].modulus_ratio = {capsule.modulus_ratio:g} gives the capsule its own G "
                              f"= {own:.3g}, outside [{glo:g}, {ghi:g}], the range capsim is validated in "
                              "(docs/validation.md): the run goes ahead, its accuracy is untested")
            lam = capsule.viscosity_ratio
            if lam is not None and not llo <= lam <= lhi:
                _case_warning(f"capsules[{i}].viscosity_ratio = {lam:g} is outside [{llo:g}, {lhi:g}], the range "
                              "capsim is validated in (docs/validation.md): the run goes ahead, its accuracy is untested")
        return self

    @model_validator(mode="after")
    def _a_wall_this_case_can_take(self) -> Case:
        if self.wall is None:
            return self
        from capsim.scene import BOUNDARIES, body_mesh, body_specs

        flows = BOUNDARIES["plane_wall"].flows  # the flows the wall admits: those that vanish on it
        if self.flow.kind not in flows:
            raise _FieldProblem("flow.kind", self.flow.kind, f"cannot be bounded by a wall (it does not vanish on a "
                                f"plane y = const); with wall: {', '.join(flows)}")
        from capsim.numerics.geometry import numpy_quadrature  # a check need not import numba

        # each capsule's own mesh (up to level 3, accurate to 2e-5 a there; level 0's nodes lie 5 % out)
        gap = self.guards.min_wall_gap
        for j, spec in enumerate(body_specs(self)):
            with numpy_quadrature():
                lowest = float(body_mesh(spec, self.mesh.base, min(self.mesh.level, 3))[0][:, 1].min())
            if lowest - self.wall_y >= gap:
                continue
            if self.capsules:
                raise _FieldProblem(f"capsules[{j}].center", list(spec.center),
                                    f"its rest shape reaches {lowest - self.wall_y:.4g} a above the wall: it must "
                                    f"clear it by guards.min_wall_gap = {gap:g}")
            below = spec.center[1] - lowest
            raise _FieldProblem("wall.distance", self.wall.distance,
                                f"the rest shape reaches {below:.4g} a below its centre: it must clear the wall by "
                                f"guards.min_wall_gap = {gap:g} (give distance > {below + gap:.4g})")
        return self

    @model_validator(mode="after")
    def _a_conduit_this_case_can_take(self) -> Case:
        if (self.conduit is None) != (self.flow.kind != "conduit"):
            if self.conduit is None:
                raise _FieldProblem("flow.kind", self.flow.kind, "is the flow of a conduit: give the conduit section")
            raise _FieldProblem("conduit", self.conduit.kind, f"takes flow.kind conduit (its pressure-driven flow), "
                                f"not {self.flow.kind}")
        if self.conduit is None:
            return self
        if self.wall is not None:
            raise _FieldProblem("wall", self.wall.distance, "and a conduit cannot bound one scene; remove one")
        from capsim.numerics.geometry import numpy_quadrature  # a check need not import numba
        from capsim.scene import Scene, body_mesh, body_specs
        from capsim.scene.conduit import MAX_WALL_NODES, conduit_kind

        kind = conduit_kind(self.conduit)
        wall = Scene.of(self).boundaries[0]
        nodes = kind.mesh(wall.length, wall.size_near, wall.size_far, wall.near_half_length).n_nodes  # numpy, ms
        if nodes > MAX_WALL_NODES:
            raise _FieldProblem("conduit.element_size", self.conduit.element_size,
                                f"gives the {kind.describe()} ({wall.length:.3g} a long) a wall of {nodes} nodes, whose "
                                f"dense matrix takes {(3 * nodes) ** 2 * 8 / 1e9:.2g} GB: at most {MAX_WALL_NODES} nodes "
                                "(raise conduit.element_size, or shorten the conduit or the capsule's travel)")
        gap = self.guards.min_wall_gap
        for j, spec in enumerate(body_specs(self)):
            with numpy_quadrature():
                nodes = body_mesh(spec, self.mesh.base, min(self.mesh.level, 3))[0]
            clearance = float(kind.gap(nodes).min())
            if clearance >= gap:
                continue
            placed = bool(self.capsules) or self.initial_center is not None
            field = (f"capsules[{j}].center" if self.capsules else "initial_center") if placed else \
                f"conduit.{kind.uses[0]}"
            value = list(spec.center) if placed else getattr(self.conduit, kind.uses[0])
            if clearance < 0:
                raise _FieldProblem(field, value, f"puts the capsule outside the {kind.describe()}: its rest shape "
                                    f"reaches {-clearance:.4g} a beyond the wall; place it inside")
            raise _FieldProblem(field, value, f"leaves the capsule {clearance:.4g} a from the {kind.describe()}'s "
                                f"wall: it must clear it by guards.min_wall_gap = {gap:g}")
        return self

    @model_validator(mode="after")
    def _an_area_modulus_for_the_stress(self) -> Case:
        """A Skalak membrane far above G 1 with a soft area modulus grows in area and collapses onto
        itself (benchmarks/rbc_high_stress.md: the red cell with C = 10 stops unstable at G 3.7, its area
        +17 %; C = 1000 ran to G 18.7 within 8 %): said before the run, which goes ahead."""
        m, G = self.membrane, self.flow.shear_rate_G
        if m.law == "skalak" and m.skalak_c_choice is None and G > SKALAK_SOFT_AREA_G \
                and m.skalak_c < SKALAK_HIGH_STRESS_C:
            _case_warning(f"membrane.skalak_c = {m.skalak_c:g} at G = {G:.3g}: above G {SKALAK_SOFT_AREA_G:g} "
                          f"the membrane's area grows (the red cell with C 10: +17 % at G 3.7, then an unstable "
                          f"stop; C 100: +8 %, unstable at G 18.7); skalak_c: auto chooses C "
                          f"{skalak_c_for_stress(G):g} here, for an area within {100 * SKALAK_AUTO_AREA_TOLERANCE:g} % "
                          "(benchmarks/rbc_high_stress.md; a real membrane's C is ~1e5)")
        return self

    @model_validator(mode="after")
    def _capsules_this_case_can_take(self) -> Case:
        """Several capsules (capsim.scene.bodies): placed apart from each other and the wall, their
        membranes and λ the top-level ones, a scene whose arrays fit."""
        if not self.capsules:
            return self
        from capsim.scene import MAX_CAPSULES, MAX_SCENE_NODES, body_specs, start_problem

        n = len(self.capsules)
        if self.initial_center is not None:
            raise _FieldProblem("initial_center", list(self.initial_center),
                                "give initial_center or capsules (each with its center), not both; remove one")
        if n > MAX_CAPSULES:
            raise _FieldProblem("capsules", f"{n} capsules", f"at most {MAX_CAPSULES} capsules in one scene")
        if n * self.mesh.n_nodes > MAX_SCENE_NODES:
            raise _FieldProblem("capsules", f"{n} capsules",
                                f"{n} x {self.mesh.n_nodes} nodes (mesh.level {self.mesh.level}) exceed the "
                                f"{MAX_SCENE_NODES} nodes a scene may hold; use fewer capsules or a lower mesh.level")
        for i, capsule in enumerate(self.capsules):
            own = capsule.membrane
            for name in ("law", "traction", "viscosity"):  # one membrane model for the scene (capsim.scene.bodies)
                if own is not None and getattr(own, name) != getattr(self.membrane, name):
                    raise _FieldProblem(f"capsules[{i}].membrane.{name}", getattr(own, name) if name != "viscosity"
                                        else "given",
                                        f"differs from the top-level membrane.{name}: every capsule takes one {name} "
                                        "(its own law parameters, bending_modulus and modulus_ratio may differ)")
            lam = capsule.viscosity_ratio
            if lam is not None and lam != self.flow.viscosity_ratio:
                lo, hi = LAMBDA_RANGE
                if not lo <= lam <= hi:
                    raise _FieldProblem(f"capsules[{i}].viscosity_ratio", lam, f"must be in [{lo:g}, {hi:g}]")
                if self.solver.method == "substitution":
                    raise _FieldProblem(f"capsules[{i}].viscosity_ratio", lam,
                                        "differs from flow.viscosity_ratio: capsules of different λ need "
                                        "solver.method gmres")
        if n > 1:
            if self.mesh.symmetry in ("quarter", "half"):
                raise _FieldProblem("mesh.symmetry", self.mesh.symmetry,
                                    "with several capsules use auto (it finds the symmetries the scene keeps) or none")
        specs = body_specs(self)
        from capsim.numerics.geometry import numpy_quadrature  # a check need not import numba

        with numpy_quadrature():
            problem = start_problem(specs, self.mesh.base, min(self.mesh.level, 3), self.guards.min_capsule_gap)
        if problem is not None:
            raise _FieldProblem(*problem)
        return self

    def _G_from_capillary_number(self) -> Case:
        Ca = self.flow.capillary_number
        if Ca is None:
            return self
        if self.physical is not None:
            raise _FieldProblem("flow.capillary_number", Ca, "give flow.capillary_number or physical, not both; remove one")
        from capsim.units import SHEAR_OVER_ELASTIC_MODULUS

        G = Ca * (1.0 if self.membrane.law == "surface_tension" else SHEAR_OVER_ELASTIC_MODULUS)
        if not self._given_agrees("flow", "shear_rate_G", G, "flow.capillary_number", f"Ca = {Ca:g} gives G = {G:.6g}"):
            self._set_derived("flow", "shear_rate_G", G)
        return self

    def _given_agrees(self, section: str, name: str, value: float, source: str, gives: str) -> bool:
        """Whether the case gives ``section.name`` itself, a field computed from `source`
        (physical values, Ca): a resolved case holds both and is accepted when they agree;
        a disagreement is a one-line error. False when the case leaves it to `source`."""
        model = getattr(self, section)
        if name not in model.model_fields_set:
            return False
        if not math.isclose(getattr(model, name), value, rel_tol=1e-9):
            raise _FieldProblem(f"{section}.{name}", getattr(model, name),
                                f"give {section}.{name} or {source}, not both ({gives}); remove one")
        return True

    def _set_derived(self, section: str, name: str, value: Any, chosen: bool = False) -> None:
        """The section with a computed value (frozen models: set once while validating). ``chosen``:
        a value capsim chooses (rtol auto, the accuracy target) is left out of the fields the user
        set, so that a campaign's run ids, made of those, do not change with it."""
        old = getattr(self, section)
        new = old.model_copy(update={name: value})
        if chosen:
            object.__setattr__(new, "__pydantic_fields_set__", set(old.model_fields_set))
        object.__setattr__(self, section, new)

    # ---- values computed from the physical block: finite, inside their fields' bounds, and
    # refused naming the physical value the user gave (not the computed field)

    def _physical_given(self, *kinds: str) -> str:
        """'shear_rate '100 1/s', viscosity …' of the physical block's values of `kinds` that are given."""
        return ", ".join(f"{kind} {bounded_repr(getattr(self.physical, kind))}" for kind in kinds
                         if getattr(self.physical, kind) is not None)

    def _physical_problem(self, kind: str, what: str) -> _FieldProblem:
        return _FieldProblem(f"physical.{kind}", getattr(self.physical, kind), what)

    def _conversion(self) -> dict[str, float]:
        """The physical block's conversion (capsim.units.conversion); a product that overflows or
        underflows is refused naming the physical value most likely in the wrong units."""
        from capsim.units import INVOLVED, UnitsError, check_scales, likeliest_slip, parse

        try:
            out = self.physical.conversion()
            self._plausible_G(out["G"])  # before the scales: the likelier slip, in the words of G
            check_scales(out)
            return out
        except UnitsError as exc:
            problem = exc
        four = ("shear_rate", "viscosity", "radius", "surface_modulus", "shear_modulus")
        involved = [k for k in INVOLVED.get(getattr(problem, "key", None), four)
                    if getattr(self.physical, k) is not None]
        culprit = involved[0] if len(involved) == 1 else likeliest_slip(
            {k: parse(getattr(self.physical, k), k) for k in involved})
        others = self._physical_given(*(k for k in involved if k != culprit))
        raise self._physical_problem(culprit, f"{problem}" + (f" (with {others})" if others else ""))

    def _plausible_G(self, G: float) -> None:
        """Refuse a G from the physical block outside PHYSICAL_G_RANGE, naming its likeliest slip."""
        from capsim.units import likeliest_slip, parse

        lo, hi = PHYSICAL_G_RANGE
        if not lo <= G <= hi:
            four = [k for k in ("shear_rate", "viscosity", "radius", "surface_modulus", "shear_modulus")
                    if getattr(self.physical, k) is not None]
            culprit = likeliest_slip({k: parse(getattr(self.physical, k), k) for k in four})
            vlo, vhi = VALIDATED_RANGES["flow.shear_rate_G"]
            raise self._physical_problem(
                culprit,
                f"with {self._physical_given(*(k for k in four if k != culprit))} gives G = mu k a / E_s = {G:.3g}, "
                f"outside [{lo:g}, {hi:g}] (capsim is validated for G in [{vlo:g}, {vhi:g}]): check the units")

    def _bending_from_physical(self) -> Case:
        if self.physical is None or self.physical.bending_modulus is None:
            return self
        self._conversion()
        kappa = self.physical.bending_modulus_scaled()
        if not (math.isfinite(kappa) and kappa <= PHYSICAL_BENDING_MAX):
            raise self._physical_problem(
                "bending_modulus",
                f"gives membrane.bending_modulus = κ/(E_s a²) = {kappa:.3g} (with "
                f"{self._physical_given('radius', 'surface_modulus', 'shear_modulus')}), "
                f"which must be finite and at most {PHYSICAL_BENDING_MAX:g} (validated up to "
                f"{VALIDATED_RANGES['membrane.bending_modulus'][1]:g}): check the units")
        if not self._given_agrees("membrane", "bending_modulus", kappa, "physical.bending_modulus",
                                  f"physical gives κ/(E_s a²) = {kappa:.6g}"):
            self._set_derived("membrane", "bending_modulus", kappa)
        return self

    def _G_from_physical(self) -> Case:
        if self.physical is None:
            return self
        G = self._conversion()["G"]
        if self._given_agrees("flow", "shear_rate_G", G, "physical", f"physical gives G = {G:.6g}"):
            return self
        self._set_derived("flow", "shear_rate_G", G)
        return self

    @field_validator("initial_axis", mode="before")
    @classmethod
    def _unit_axis(cls, v: Any) -> Any:
        if v is None:
            return v
        if not (isinstance(v, (list, tuple)) and len(v) == 3):
            raise ValueError("must be a list of three numbers [x, y, z]")
        try:  # each component as a float field takes it: a decimal string ('1e-3', as YAML reads it) too
            parts = [_strict_scalar(c, float) for c in v]
        except ValueError:
            raise ValueError("must be a list of three numbers [x, y, z]") from None
        if not all(isinstance(c, (int, float)) and not isinstance(c, bool) for c in parts):
            raise ValueError("must be a list of three numbers [x, y, z]")
        try:
            parts = [float(c) for c in parts]  # an integer of 400 digits: OverflowError
        except OverflowError:
            raise ValueError("must be three finite numbers") from None
        if not all(math.isfinite(c) for c in parts):
            raise ValueError("must be three finite numbers")
        largest = max(abs(c) for c in parts)
        if largest == 0.0:
            raise ValueError("must be a nonzero vector (the direction of the rest shape's axis)")
        try:
            norm = math.sqrt(sum(c**2 for c in parts))
        except OverflowError:  # a component above ~1e154
            norm = math.inf
        if math.isfinite(norm) and norm > 1e-140:  # the squares neither overflow nor underflow
            if abs(norm - 1.0) <= 1e-15:  # already unit (a resolved case): kept as is, so reloading is exact
                return tuple(parts)
            return tuple(c / norm for c in parts)  # as before: a run's stored axis stays the bit it was
        # scaled by the largest component first: no square overflows (1e200) or underflows (1e-160)
        scaled = [c / largest for c in parts]
        norm = math.sqrt(sum(c * c for c in scaled))
        return tuple(c / norm for c in scaled)

    def _Bq_from_physical(self) -> Case:
        if self.physical is None or self.physical.membrane_viscosity is None:
            return self
        Bq = self._conversion()["Bq"]
        if not Bq <= BQ_MAX:
            raise self._physical_problem(
                "membrane_viscosity",
                f"gives membrane.viscosity.shear = Bq = mu_s / (mu a) = {Bq:.3g} (with "
                f"{self._physical_given('viscosity', 'radius')}), which must be at most {BQ_MAX:g} (validated up "
                f"to {VALIDATED_RANGES['membrane.viscosity.shear'][1]:g}): check the units")
        given = self.membrane.viscosity
        if given is not None and "shear" in given.model_fields_set:
            if not math.isclose(given.shear, Bq, rel_tol=1e-9):  # a resolved case holds both
                raise _FieldProblem(
                    "membrane.viscosity.shear", given.shear,
                    f"give membrane.viscosity.shear or physical.membrane_viscosity, not both (physical gives "
                    f"Bq = {Bq:.6g}); remove one")
            return self
        viscosity = (given or MembraneViscosity()).model_copy(update={"shear": Bq})
        viscosity = MembraneViscosity.model_validate(viscosity.model_dump())  # its checks, shear now set
        membrane = Membrane.model_validate({**self.membrane.model_dump(), "viscosity": viscosity.model_dump()})
        object.__setattr__(self, "membrane", membrane)
        return self

    def _lambda_from_physical(self) -> Case:
        if self.physical is None or self.physical.inner_viscosity is None:
            return self
        lam = self._conversion()["lambda"]
        lo, hi = LAMBDA_RANGE
        if not lo <= lam <= hi:
            vlo, vhi = VALIDATED_RANGES["flow.viscosity_ratio"]
            raise self._physical_problem(
                "inner_viscosity",
                f"with viscosity {bounded_repr(self.physical.viscosity)} gives flow.viscosity_ratio = λ = {lam:.3g}, "
                f"which must be in [{lo:g}, {hi:g}] (validated in [{vlo:g}, {vhi:g}]): check the units")
        if self._given_agrees("flow", "viscosity_ratio", lam, "physical.inner_viscosity",
                              f"physical gives λ = {lam:.6g}"):
            return self
        self._set_derived("flow", "viscosity_ratio", lam)
        problem = _substitution_problem(self.solver, lam)  # the solver's check saw λ before it was derived
        if problem is not None:
            raise _FieldProblem(f"solver.{problem.field}", problem.value, problem.what)
        return self

    @model_validator(mode="after")
    def _one_orientation(self) -> Case:
        # a resolved case of an axis-only run stores initial_tilt_deg 0: accepted
        if self.initial_axis is not None and self.initial_tilt_deg != 0.0:
            raise _FieldProblem(
                "initial_axis", list(self.initial_axis),
                f"give initial_axis or initial_tilt_deg (= {self.initial_tilt_deg:g}), not both; remove one",
            )
        if self.mesh.symmetry == "quarter" and not axis_keeps_quarter_symmetry(self.axis):
            shown = f"[{', '.join(f'{c:.6g}' for c in self.axis)}]"
            if self.shape.kind != "sphere":
                raise _FieldProblem(
                    "mesh.symmetry", "quarter",
                    f"needs the rest shape's axis in the shear plane (z = 0) or along z, got initial_axis "
                    f"{shown}; use half, auto or none",
                )
            # a sphere keeps it whatever its axis; its mesh, turned onto the axis, as auto finds it
            if not sphere_mesh_keeps_quarter_symmetry(self.mesh.base, self.axis):
                raise _FieldProblem(
                    "mesh.symmetry", "quarter",
                    f"the {self.mesh.base} mesh of a sphere turned onto initial_axis {shown} does not keep it "
                    "(auto uses half for it); use half, auto or none, or an axis in the shear plane or along z",
                )
        from capsim.scene import Scene  # numpy only

        kept = symmetries_kept(Scene.of(self).far_field)
        for group in SYMMETRY_CANDIDATES.get(self.mesh.symmetry, ()) if self.mesh.symmetry != "auto" else ():
            if group not in kept:
                scene = f"flow.kind {self.flow.kind}" + (" above a wall" if self.wall is not None else "")
                raise _FieldProblem("mesh.symmetry", self.mesh.symmetry,
                                    f"{scene} does not keep it ({group}); use auto or none")
            if any(self.center):  # initial_center, or the one capsule of a capsules list
                where = "capsules[0].center" if self.capsules else "initial_center"
                raise _FieldProblem("mesh.symmetry", self.mesh.symmetry,
                                    f"a capsule placed away from the origin ({where}) does not keep it; "
                                    "use auto (it finds the symmetries left) or none")
        return self

    @property
    def center(self) -> tuple[float, float, float]:
        """The rest shape's centroid at t = 0: initial_center (with capsules: the first one's
        center), else the origin."""
        if self.capsules:
            return self.capsules[0].center
        return self.initial_center if self.initial_center is not None else (0.0, 0.0, 0.0)

    @property
    def viscosity_ratios(self) -> tuple[float, ...]:
        """λ of every capsule (flow.viscosity_ratio unless a capsule has its own)."""
        lam = self.flow.viscosity_ratio
        if not self.capsules:
            return (lam,)
        return tuple(c.viscosity_ratio if c.viscosity_ratio is not None else lam for c in self.capsules)

    @property
    def n_capsules(self) -> int:
        """How many capsules the scene holds (capsules, else 1)."""
        return len(self.capsules) if self.capsules else 1

    @property
    def wall_y(self) -> float | None:
        """y of the scene's wall (wall.distance below the initial centre); None without one."""
        return None if self.wall is None else float(self.center[1] - self.wall.distance)

    @property
    def axis(self) -> tuple[float, float, float]:
        """The rest shape's symmetry axis at t = 0: initial_axis, or y turned by initial_tilt_deg."""
        if self.initial_axis is not None:
            return self.initial_axis
        t = math.radians(self.initial_tilt_deg)
        return (-math.sin(t), math.cos(t), 0.0)

    @model_validator(mode="after")
    def _the_scheme_can_run_it(self) -> Case:
        problem = SCHEMES[self.time.scheme].case_problem(self)  # e.g. a preconditioner the mesh is too large for
        if problem is not None:
            raise _FieldProblem(*problem)
        return self

    @model_validator(mode="after")
    def _within_validated_ranges(self) -> Case:
        """A CaseWarning for each value outside the range capsim is validated in (VALIDATED_RANGES),
        naming the physical value it comes from when the physical block gave it."""
        viscosity = self.membrane.viscosity
        values = {
            "flow.shear_rate_G": self.flow.shear_rate_G, "flow.viscosity_ratio": self.flow.viscosity_ratio,
            "membrane.bending_modulus": self.membrane.bending_modulus,
            "membrane.viscosity.shear": viscosity.shear if viscosity is not None else 0.0,
            "membrane.viscosity.dilatational": viscosity.dilatational if viscosity is not None else 0.0,
        }
        physical = self.physical
        sources = {} if physical is None else {
            "flow.shear_rate_G": "physical",
            "flow.viscosity_ratio": physical.inner_viscosity and f"physical.inner_viscosity = {physical.inner_viscosity!r}",
            "membrane.bending_modulus": physical.bending_modulus and
            f"physical.bending_modulus = {physical.bending_modulus!r}",
            "membrane.viscosity.shear": physical.membrane_viscosity and
            f"physical.membrane_viscosity = {physical.membrane_viscosity!r}",
        }
        for field, value in values.items():
            lo, hi = VALIDATED_RANGES[field]
            if not lo <= value <= hi:
                source = sources.get(field)
                given = f" (from {source})" if source else ""
                field = USER_NAMES.get(field, field)
                _case_warning(f"{field} = {value:.3g}{given} is outside [{lo:g}, {hi:g}], the range capsim is "
                              "validated in (docs/validation.md): the run goes ahead, its accuracy is untested")
        return self

    @field_validator("solver")
    @classmethod
    def _solver_can_converge(cls, v: Solver, info: ValidationInfo) -> Solver:
        flow = info.data.get("flow")
        problem = _substitution_problem(v, flow.viscosity_ratio if flow is not None else 1.0)
        if problem is not None:
            raise problem
        return v

    @field_validator("output")
    @classmethod
    def _snapshots_bounded(cls, v: Output, info: ValidationInfo) -> Output:
        time = info.data.get("time")
        if time is not None:
            lo = max(time.dt_min, time.t_end / MAX_SNAPSHOTS)
            if v.snapshot_every < lo:
                raise _FieldProblem(
                    "snapshot_every", v.snapshot_every,
                    f"must be >= max(time.dt_min, time.t_end / {MAX_SNAPSHOTS}) = {lo:g} "
                    "(steps are clipped to snapshot times; each snapshot holds every node)",
                )
        return v

    @field_validator("output")
    @classmethod
    def _resolve_output_path(cls, v: Output, info: ValidationInfo) -> Output:
        name = info.data.get("name")
        if name is not None and "{name}" in v.path:
            return v.model_copy(update={"path": v.path.replace("{name}", name)})
        return v

    def to_yaml(self, user_names: bool = False) -> str:
        """The resolved case (all defaults filled); `load_case` reads it back equal. ``user_names``:
        fields by the names a user writes (flow.G; `capsim validate`), else as a run file stores
        them (flow.shear_rate_G: the stored format is unchanged)."""
        data = self.model_dump(mode="json")
        if user_names:
            for full, short in USER_NAMES.items():
                *sections, leaf = full.split(".")
                node = data
                for part in sections:
                    node = node[part]
                new = short.rsplit(".", 1)[-1]
                items = [(new if k == leaf else k, v) for k, v in node.items()]  # renamed in place, order kept
                node.clear()
                node.update(items)
        return yaml.dump(data, Dumper=YAML_DUMPER, sort_keys=False)


# ---------------------------------------------------------------- loading


class _UniqueKeyLoader(yaml.SafeLoader):
    """SafeLoader for untrusted files: refuses duplicate keys (PyYAML silently keeps
    the last), keys that are lists or mappings, nesting deeper than MAX_YAML_DEPTH
    and documents whose aliases expand to more than MAX_YAML_NODES nodes (an alias
    bomb), all on the node graph, before any Python object is built."""

    _depth = 0

    def compose_node(self, parent, index):
        # the composer recurses once per level: stop long before Python's recursion limit
        self._depth += 1
        try:
            if self._depth > MAX_YAML_DEPTH:
                raise yaml.composer.ComposerError(
                    None, None, f"nested deeper than {MAX_YAML_DEPTH} levels", self.peek_event().start_mark
                )
            return super().compose_node(parent, index)
        finally:
            self._depth -= 1

    def get_single_data(self):
        node = self.get_single_node()
        if node is None:
            return None
        _check_expanded_size(node)
        return self.construct_document(node)


def _node_children(node: yaml.Node) -> list:
    if isinstance(node, yaml.SequenceNode):
        return list(node.value)
    if isinstance(node, yaml.MappingNode):
        return [n for pair in node.value for n in pair]
    return []


def _check_expanded_size(root: yaml.Node) -> None:
    """Count the nodes of the document with every alias expanded (linear in the
    distinct nodes: shared ones are counted once and multiplied), refusing cycles."""
    sizes: dict[int, int] = {}
    on_path: set[int] = set()
    stack: list[tuple[yaml.Node, bool]] = [(root, False)]
    while stack:
        node, finished = stack.pop()
        key = id(node)
        if finished:
            on_path.discard(key)
            size = 1 + sum(sizes[id(c)] for c in _node_children(node))
            if size > MAX_YAML_NODES:
                raise yaml.composer.ComposerError(
                    None, None,
                    f"aliases expand to more than {MAX_YAML_NODES} values (an alias bomb?)", node.start_mark,
                )
            sizes[key] = size
            continue
        if key in sizes:
            continue
        if key in on_path:
            raise yaml.composer.ComposerError(None, None, "an alias refers to itself", node.start_mark)
        on_path.add(key)
        stack.append((node, True))
        for child in _node_children(node):
            if id(child) in on_path:
                raise yaml.composer.ComposerError(None, None, "an alias refers to itself", child.start_mark)
            if id(child) not in sizes:
                stack.append((child, False))


def _construct_mapping(loader: yaml.SafeLoader, node: yaml.MappingNode, deep: bool = False):
    loader.flatten_mapping(node)  # merge keys (<<) first, so that their keys are checked too
    seen: set = set()
    for key_node, _ in node.value:
        if not isinstance(key_node, yaml.ScalarNode):
            kind = "list" if isinstance(key_node, yaml.SequenceNode) else "mapping"
            raise yaml.constructor.ConstructorError(
                None, None, f"a key must be a plain name, not a {kind}", key_node.start_mark
            )
        key = loader.construct_object(key_node, deep=deep)
        if key in seen:
            raise yaml.constructor.ConstructorError(
                None, None, f"duplicate key {bounded_repr(key)}", key_node.start_mark
            )
        seen.add(key)
    return loader.construct_mapping(node, deep=deep)


_UniqueKeyLoader.add_constructor(
    yaml.resolver.BaseResolver.DEFAULT_MAPPING_TAG, _construct_mapping
)


def read_yaml(path: str | os.PathLike) -> Any:
    """The data of a case or campaign file, read with every limit; mistakes raise a one-line ConfigError.

    Only a regular file is read (a FIFO or a device such as /dev/zero is refused
    without blocking), at most MAX_FILE_BYTES of it.
    """
    source = os.fspath(path)
    try:
        # O_NONBLOCK: opening a FIFO must not wait for a writer; fstat then refuses it
        fd = os.open(source, os.O_RDONLY | getattr(os, "O_NONBLOCK", 0))
    except FileNotFoundError:
        raise ConfigError(f"{source}: no such file") from None
    except OSError as exc:
        raise ConfigError(f"{source}: cannot read: {exc.strerror or exc}") from None
    try:
        info = os.fstat(fd)
        if stat.S_ISDIR(info.st_mode):
            raise ConfigError(f"{source}: is a directory, not a YAML file")
        if not stat.S_ISREG(info.st_mode):
            raise ConfigError(f"{source}: not a regular file (a pipe, device or socket); give a YAML file")
        if info.st_size > MAX_FILE_BYTES:
            raise ConfigError(f"{source}: {info.st_size} bytes; a YAML input is at most {MAX_FILE_BYTES} bytes")
        with os.fdopen(fd, "rb", closefd=False) as fh:
            raw = fh.read(MAX_FILE_BYTES + 1)
    except OSError as exc:
        raise ConfigError(f"{source}: cannot read: {exc.strerror or exc}") from None
    finally:
        os.close(fd)
    if len(raw) > MAX_FILE_BYTES:
        raise ConfigError(f"{source}: more than {MAX_FILE_BYTES} bytes; a YAML input is at most that")
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError:
        raise ConfigError(f"{source}: not a text file (expected YAML)") from None
    try:
        return yaml.load(text, Loader=_UniqueKeyLoader)
    except yaml.YAMLError as exc:
        raise ConfigError(f"{source}: not valid YAML: {_yaml_problem(exc)}") from None
    except ValueError as exc:  # an integer of more digits than Python converts (4300)
        raise ConfigError(f"{source}: not valid YAML: {first_line(exc)[:120]}") from None
    except RecursionError:
        raise ConfigError(f"{source}: not valid YAML: nested too deeply") from None


def step_defining(case: dict) -> dict:
    """The part of a resolved case (``case.model_dump(mode="json")``) that fixes its
    step sequence and so its results: not its name, guards, output location,
    checkpoint cadence or wall-time limit (a run may be resumed, moved or renamed
    across those)."""
    out = {k: v for k, v in case.items() if k not in ("guards", "name")}
    physical = out.get("physical")
    if isinstance(physical, dict) and physical.get("inner_viscosity", 0) is None:
        # added later: a case without it hashes as it did before the field existed
        out["physical"] = {k: v for k, v in physical.items() if k != "inner_viscosity"}
    out["output"] = {k: v for k, v in case.get("output", {}).items() if k == "snapshot_every"}
    out["time"] = {k: v for k, v in case.get("time", {}).items() if k != "max_wall_s"}
    # flow.kind came after runs were written without it: its default is the flow they ran
    out["flow"] = {k: v for k, v in case.get("flow", {}).items() if not (k == "kind" and v == "simple_shear")}
    return out


def case_digest(case: "Case | dict") -> str:
    """A hash of :func:`step_defining`: two runs with one digest compute the same thing."""
    import hashlib
    import json

    data = case.model_dump(mode="json") if isinstance(case, Case) else case
    return hashlib.sha256(json.dumps(step_defining(data), sort_keys=True, default=str).encode()).hexdigest()[:16]


def load_case(path: str | os.PathLike) -> Case:
    """Read and validate a case file; any mistake raises a one-line ConfigError."""
    source = os.fspath(path)
    data = read_yaml(source)
    if data is None:
        raise ConfigError(f"{source}: file is empty (expected a mapping with at least 'name')")
    return case_from_dict(data, source=source)


def case_from_dict(d: Any, source: str = "<dict>") -> Case:
    """Validate a plain mapping as a Case; mistakes raise a one-line ConfigError."""
    if not isinstance(d, Mapping):
        raise ConfigError(
            f"{source}: top level must be a mapping of fields, got {type(d).__name__}"
        )
    outer = _PENDING_WARNINGS.get()
    token = _PENDING_WARNINGS.set([])
    try:
        case = Case.model_validate(dict(d))
    except ValidationError as exc:
        raise ConfigError(_format_validation_error(exc, source)) from None
    finally:
        pending = _PENDING_WARNINGS.get()
        _PENDING_WARNINGS.reset(token)
    if outer is not None:  # resolve_case: only the final case's warnings are issued, by it
        outer[:] = pending
        return case
    for text in pending:  # only for a case that validated
        _issue_warning(text, source)
    return case


#: longest --set text: a field path and a value, not a document
SET_MAX = 1000


def parse_sets(sets: list[str] | None) -> dict[str, Any]:
    """``--set FIELD=VALUE`` texts as {dotted field: YAML value}; a bad one is a one-line ConfigError."""
    out: dict[str, Any] = {}
    for text in sets or ():
        shown = bounded_repr(text)
        if len(text) > SET_MAX:
            raise ConfigError(f"--set {shown}: at most {SET_MAX} characters")
        key, sep, raw = text.partition("=")
        key = key.strip()
        if not sep or not key or any(not part.isidentifier() for part in key.split(".")):
            raise ConfigError(f"--set {shown}: give FIELD=VALUE with a dotted case field, e.g. --set mesh.level=2")
        try:
            value = yaml.safe_load(raw) if raw.strip() else None
        except yaml.YAMLError as exc:
            raise ConfigError(f"--set {shown}: the value is not YAML ({first_line(exc)})") from None
        except ValueError as exc:  # an integer of more digits than Python converts
            raise ConfigError(f"--set {shown}: {first_line(exc)[:120]}") from None
        if value is None:
            raise ConfigError(f"--set {shown}: no value after '='")
        if key in out:
            raise ConfigError(f"--set {key} is given twice")
        out[key] = value
    return out


def load_case_with(path: str | os.PathLike, sets: list[str] | None = None, **overrides: Any) -> Case:
    """The case at `path` with ``--set`` texts and dotted `overrides` (None: not given) applied."""
    return resolve_case(path, sets, **overrides)


#: field (or section) set → the fields computed from it, each dropped from the old case when
#: the first is set and the second is not (``--set physical.shear_rate=50 1/s`` gives a new G),
#: as (derived field, the field of the old case it was computed from; None: always). Every
#: physical value enters G; the radius and the moduli enter κ/(E_s a²) and the viscosity and
#: the radius Bq = μ_s/(μ a) too, when the case computes them from physical.
_UNSET = "<unless the case set it>"  # a derived field's source: dropped unless the old case gave it itself
#: skalak_c chosen by auto (its choice set): back to auto when what it was chosen for changes
_AUTO_AREA_MODULUS = (("membrane.skalak_c", "membrane.skalak_c_choice"), ("membrane.skalak_c_choice", None))
#: a derived field whose default is not auto: what it goes back to when it is chosen again
_CHOOSE_AGAIN = {"membrane.skalak_c": "auto"}
DERIVED_FIELDS = {
    "physical": (("flow.shear_rate_G", None), ("membrane.bending_modulus", "physical.bending_modulus"),
                 ("membrane.viscosity.shear", "physical.membrane_viscosity"),
                 ("flow.viscosity_ratio", "physical.inner_viscosity"), *_AUTO_AREA_MODULUS),
    "flow.capillary_number": (("flow.shear_rate_G", None), *_AUTO_AREA_MODULUS),
    "physical.bending_modulus": (("membrane.bending_modulus", None),),
    "physical.membrane_viscosity": (("membrane.viscosity.shear", None),),
    "physical.inner_viscosity": (("flow.viscosity_ratio", None),),
    # skalak_c auto chooses again for another G or tolerance; a C the user sets is no longer a choice
    "flow.shear_rate_G": _AUTO_AREA_MODULUS,
    "membrane.area_tolerance": _AUTO_AREA_MODULUS,
    "membrane.skalak_c": (("membrane.skalak_c_choice", None),),
    # time.rtol auto and the accuracy target choose again for another level or target
    "mesh.level": (("time.rtol", "time.rtol_choice"), ("time.rtol_choice", None), ("accuracy.choice", None)),
    "accuracy": (("mesh.level", _UNSET), ("time.rtol", _UNSET), ("time.rtol_choice", None), ("accuracy.choice", None),
                 ("accuracy.method", _UNSET)),
}


def _was_set(case: Case, dotted: str) -> bool:
    """Whether the case gave the dotted field itself (not its default, nor a value capsim chose)."""
    *path, name = dotted.split(".")
    node: Any = case
    for part in path:
        node = getattr(node, part, None)
        if node is None:
            return False
    return name in node.model_fields_set


def _lookup(data: dict, dotted: str) -> Any:
    """The value at a dotted path of a case's dict, None where a part is missing."""
    node: Any = data
    for part in dotted.split("."):
        node = node.get(part) if isinstance(node, dict) else None
    return node


def resolve_case(source: Any, sets: list[str] | None = None, **overrides: Any) -> Case:
    """A case from a path, a dict or a Case, with ``--set`` texts and overrides by dotted name
    (``**{"time.t_end": 2}``, or ``time__t_end=2``; None: not given); a field given both ways
    is an error. One-line ConfigError."""
    dotted = parse_sets(list(sets) if sets else None)
    for key, value in overrides.items():
        key = key.replace("__", ".")
        if value is not None:
            if key in dotted:
                raise ConfigError(f"--set {key} and its own option both given; give one")
            dotted[key] = value
    pending: list[str] = []
    token = _PENDING_WARNINGS.set(pending)  # the warnings of the case with the overrides applied only
    try:
        if isinstance(source, (str, os.PathLike)):
            case, where = load_case(source), os.fspath(source)
        elif isinstance(source, Case):
            case, where = source, "<case>"
        elif isinstance(source, dict):
            case, where = case_from_dict(dict(source)), "<dict>"
        else:
            raise ConfigError(f"a case is a path, a dict or a Case, got {type(source).__name__}")
        try:
            case = apply_overrides(case, **dotted) if dotted else case
        except ConfigError as exc:
            text = str(exc)
            prefix = "<overrides>: "
            raise ConfigError(f"{where}: --set/options: {text[len(prefix):] if text.startswith(prefix) else text}") from None
    finally:
        _PENDING_WARNINGS.reset(token)
    for text in pending:
        _issue_warning(text, where)
    return case


#: dotted names that are another field's short name
_ALIASES = {"flow.G": "flow.shear_rate_G"}
#: a field's name as a user writes it and capsim names it back (`capsim validate`, warnings)
USER_NAMES = {full: short for short, full in _ALIASES.items()}


def _overrides_touch(keys: list[str], given: str) -> bool:
    """Whether any of the (alias-resolved) dotted keys is the field or section `given`, or lies inside it."""
    return any(key == given or key.startswith(given + ".") for key in keys)


def _choose_capsule_area_moduli_again(data: dict, keys: list[str]) -> None:
    """A capsule's own skalak_c chosen by auto (capsules[i].membrane) goes back to auto when the case's G
    changes, as the top-level one does (DERIVED_FIELDS): each capsule's G is flow.G over its modulus_ratio.
    What changes G is what DERIVED_FIELDS derives flow.shear_rate_G from, and the field itself."""
    G_sources = [given for given, derived in DERIVED_FIELDS.items() if ("flow.shear_rate_G", None) in derived]
    if "capsules" in keys or not any(_overrides_touch(keys, g) for g in [*G_sources, "flow.shear_rate_G"]):
        return
    for capsule in data.get("capsules") or ():
        membrane = capsule.get("membrane") if isinstance(capsule, dict) else None
        if isinstance(membrane, dict) and membrane.get("skalak_c_choice") is not None:
            membrane["skalak_c"], membrane["skalak_c_choice"] = "auto", None


def apply_overrides(case: Case, **dotted: Any) -> Case:
    """A re-validated copy of `case` with dotted fields replaced.

    ``apply_overrides(case, **{"time.t_end": 5.0, "mesh.level": 2})``.
    Renaming a case whose output path was the default also moves the output.
    """
    data = case.model_dump()
    if "name" in dotted and "output.path" not in dotted and (
        case.output.path == Output().path.replace("{name}", case.name)
    ):
        data["output"]["path"] = Output().path
    old = case.model_dump()
    keys = [_ALIASES.get(k, k) for k in dotted]  # the fields the overrides name, flow.G as flow.shear_rate_G
    for given, derived_fields in DERIVED_FIELDS.items():
        # a derived value is computed anew from what it derives from, not the old one kept
        if not _overrides_touch(keys, given):
            continue
        for derived, source in derived_fields:
            if source == _UNSET:
                if derived in dotted or _was_set(case, derived):
                    continue
            elif derived in dotted or (source is not None and _lookup(old, source) is None):
                continue
            *path, field = derived.split(".")
            parent = _lookup(data, ".".join(path))
            if isinstance(parent, dict) and derived in _CHOOSE_AGAIN:
                parent[field] = _CHOOSE_AGAIN[derived]
            elif isinstance(parent, dict):
                parent.pop(field, None)
    _choose_capsule_area_moduli_again(data, keys)
    for key, value in dotted.items():
        key = _ALIASES.get(key, key)
        parts = key.split(".")
        node, model = data, Case
        for i, part in enumerate(parts[:-1]):
            child = node.get(part) if isinstance(node, dict) else None
            field = model.model_fields.get(part) if model is not None else None
            model = section_model(field.annotation) if field is not None else None
            if child is None and model is not None and isinstance(node, dict):
                # an optional section the case leaves out (physical, membrane.viscosity, flow.history)
                # is made from the --set values, as a campaign's sweep of its fields makes it
                child = node[part] = {}
            if not isinstance(child, dict):
                where = ".".join(parts[: i + 1])
                raise ConfigError(f"<overrides>: {key}: '{where}' is not a section of the case")
            node = child
        node[parts[-1]] = value
    return case_from_dict(data, source="<overrides>")


# ---------------------------------------------------------------- messages


def _yaml_problem(exc: yaml.YAMLError) -> str:
    problem = getattr(exc, "problem", None) or first_line(exc)
    problem = bounded_repr(problem, 200)[1:-1] if len(problem) > 200 else problem
    mark = getattr(exc, "problem_mark", None)
    if mark is not None:
        return f"{problem} (line {mark.line + 1}, column {mark.column + 1})"
    return problem


def section_model(annotation: Any) -> type[BaseModel] | None:
    """The model of a section field: the annotation itself, or the model inside an
    Optional[Model] (flow.physical, membrane.viscosity); None for a leaf field."""
    ann = next((a for a in get_args(annotation) if isinstance(a, type) and issubclass(a, BaseModel)), annotation)
    return ann if isinstance(ann, type) and issubclass(ann, BaseModel) else None


def _item_model(annotation: Any) -> type[BaseModel] | None:
    """The model of a list-of-sections field's items (Optional[list[Capsule]]: Capsule)."""
    for a in get_args(annotation):
        if get_origin(a) is list:
            return section_model(get_args(a)[0])
    return None


def _model_at(loc: tuple, root: type[BaseModel] | None = None) -> type[BaseModel] | None:
    """The model class that owns the field at `loc` (loc of its parent), from `root` (a Case)."""
    model: type[BaseModel] | None = Case if root is None else root
    for part in loc:
        if isinstance(part, int):  # an item of a list of sections (capsules): the list's item model
            continue
        field = model.model_fields.get(part) if isinstance(part, str) else None
        model = (section_model(field.annotation) or _item_model(field.annotation)) if field is not None else None
        if model is None:
            return None
    return model


def _show(value: Any) -> str:
    # bounded: never the repr of a whole (possibly huge) value
    return bounded_repr(value)


_MESSAGES = {
    "greater_than": "must be > {gt}",
    "greater_than_equal": "must be >= {ge}",
    "less_than": "must be < {lt}",
    "less_than_equal": "must be <= {le}",
    "finite_number": "must be a finite number",
    "float_type": "must be a number",
    "float_parsing": "must be a number",
    "int_type": "must be an integer",
    "int_parsing": "must be an integer",
    "int_from_float": "must be an integer",
    "bool_type": "must be true or false",
    "bool_parsing": "must be true or false",
    "string_type": "must be a string",
    "string_too_short": "must not be empty",
    "string_too_long": "must have at most {max_length} characters",
    "string_pattern_mismatch": "must contain only letters, digits, '.', '_' or '-'",
    "literal_error": "must be one of {expected}",
    "model_type": "must be a mapping of fields",
    "model_attributes_type": "must be a mapping of fields",
    "dict_type": "must be a mapping of fields",
}


def _dotted(parts) -> str:
    # a location part can be a user's (huge) key
    return ".".join(p if isinstance(p, str) and len(p) <= 40 else bounded_repr(p, 40) for p in map(str, parts))


def _describe(err: dict, root: type[BaseModel] | None = None) -> str:
    loc = tuple(err["loc"])
    dotted = _dotted(loc)
    kind = err["type"]
    problem = err.get("ctx", {}).get("error")
    if isinstance(problem, _FieldProblem):
        dotted = _dotted([*loc, problem.field])
        return f"{dotted} = {_show(problem.value)}: {problem.what}"
    if kind == "extra_forbidden":
        owner = _model_at(loc[:-1], root)
        allowed = ", ".join(owner.model_fields) if owner is not None else "?"
        return f"{dotted}: unknown field {bounded_repr(str(loc[-1]))} (allowed: {allowed})"
    if kind == "missing":
        return f"{dotted}: required field is missing"
    template = _MESSAGES.get(kind)
    if template is not None:
        try:
            ctx = {k: f"{v:g}" if isinstance(v, float) else v for k, v in err.get("ctx", {}).items()}
            what = template.format(**ctx)
        except (KeyError, IndexError):
            what = err["msg"]
    else:
        what = err["msg"].removeprefix("Value error, ")
        what = what[:1].lower() + what[1:]
    if not loc:  # a check of the whole model: its message names the fields; its input is the whole file
        return what
    return f"{dotted} = {_show(err.get('input'))}: {what}"


def model_from_mapping(model: type[BaseModel], d: Any, source: str) -> Any:
    """A schema other than the case's (a campaign, a fit) validated from a plain mapping; a mistake
    is a one-line ConfigError naming the field, as a case's."""
    if not isinstance(d, Mapping):
        raise ConfigError(f"{source}: top level must be a mapping of fields, got {type(d).__name__}")
    try:
        return model.model_validate(dict(d))
    except ValidationError as exc:
        raise ConfigError(format_validation_error(exc, source, root=model)) from None


def format_validation_error(exc: ValidationError, source: str, root: type[BaseModel] | None = None) -> str:
    """The one line of every schema error (a case's, a campaign's: `root`), at most three problems."""
    errors = exc.errors(include_url=False)
    shown = "; ".join(_describe(e, root) for e in errors[:3])
    more = f" (and {len(errors) - 3} more)" if len(errors) > 3 else ""
    return " ".join(f"{source}: {shown}{more}".split())


_format_validation_error = format_validation_error  # the name this module's callers use
describe_error = _describe  # one schema problem in words (a campaign's messages use it too)
#: the strict base of every YAML-loaded model (a case's sections, a campaign)
StrictModel = _Model

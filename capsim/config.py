"""The one schema of a capsim case, its YAML loader and its error messages.

Every user mistake (missing file, bad YAML, unknown field, value out of range)
surfaces as a :class:`ConfigError` whose message is one line naming the file,
the dotted field, the bad value and what is allowed, e.g.::

    case.yaml: flow.shear_rate_G = -1.0: must be > 0
"""

from __future__ import annotations

import os
from collections.abc import Mapping
from typing import Any, Literal

import yaml
from pydantic import (
    BaseModel,
    ConfigDict,
    Field,
    ValidationError,
    ValidationInfo,
    field_validator,
    model_validator,
)

__all__ = [
    "Case",
    "ConfigError",
    "Flow",
    "Guards",
    "Membrane",
    "Mesh",
    "Output",
    "Quadrature",
    "Shape",
    "Solver",
    "Time",
    "apply_overrides",
    "case_from_dict",
    "load_case",
]


class ConfigError(Exception):
    """A user mistake in a case: the message is one line, fit to print as is."""


class _Model(BaseModel):
    # Typos are errors, NaN/inf are never a sane parameter, and a resolved case
    # is an immutable description: change it with apply_overrides.
    model_config = ConfigDict(extra="forbid", allow_inf_nan=False, frozen=True)


# Integers and booleans are strict so that `level: 2.5`, `level: "3"` or
# `stop_when_steady: 1` are refused rather than coerced. Floats stay lax:
# PyYAML (YAML 1.1) reads `1e-4` (no dot) as the string "1e-4".


class Shape(_Model):
    """Rest shape of the capsule; lengths are scaled by the equal-volume radius a."""

    kind: Literal["sphere", "oblate", "prolate", "biconcave"] = "sphere"
    aspect_ratio: float = Field(1.0, gt=0, description="polar / equatorial axis of the spheroid")
    c0: float = Field(0.207, description="Evans-Fung biconcave coefficient")
    c2: float = Field(2.003, description="Evans-Fung biconcave coefficient")
    c4: float = Field(-1.123, description="Evans-Fung biconcave coefficient")

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
        return v


class Membrane(_Model):
    """Constitutive law of the membrane (design.md, 'Laws')."""

    law: Literal["thin_shell", "neo_hookean", "mooney_rivlin", "skalak", "surface_tension"] = "thin_shell"
    psi: float = Field(0.0, ge=0, le=1, description="Mooney-Rivlin parameter psi'")
    skalak_c: float = Field(10.0, gt=0, description="Skalak area-dilation parameter C")
    traction: Literal["galerkin", "contour"] = Field(
        "galerkin",
        description="galerkin: Δf from the energy gradient and the consistent mass matrix "
        "(every node restrained); contour: the seed's element average (3.6)-(3.7)",
    )
    bending_modulus: float = Field(
        0.0, ge=0,
        description="bending modulus κ/(E_s a²) of a dihedral-hinge energy relative to the rest shape "
        "(0: none, the seed's membrane); needs traction: galerkin",
    )

    @model_validator(mode="after")
    def _bending_needs_galerkin(self):
        if self.bending_modulus > 0 and self.traction != "galerkin":
            raise ValueError(
                f"bending_modulus = {self.bending_modulus} needs traction: galerkin "
                f"(got traction: {self.traction}); the contour traction has no bending term"
            )
        return self


class Flow(_Model):
    """Simple shear v = (k y, 0, 0); G = mu k a / E_s, viscosity ratio lambda."""

    shear_rate_G: float = Field(0.1, gt=0)
    viscosity_ratio: float = Field(1.0, gt=0)


class Mesh(_Model):
    base: Literal["octahedron", "icosahedron"] = "octahedron"
    level: int = Field(3, ge=0, le=6, strict=True)
    symmetry: bool = Field(
        True, strict=True,
        description="use the mirror symmetry about z = 0 (halves the boundary-integral work; "
        "false lets out-of-plane asymmetry develop)",
    )


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
    # at level 3 falls from 6.6e-2 to 5.5e-3 for 4.7x the double-layer time (README)
    near_field_factor: float = Field(
        0.0, ge=0, le=3,
        description="integrate elements within this many element sizes of a node (not holding it) "
        "on subdivided triangles; 0 = off",
    )
    near_field_levels: int = Field(
        1, ge=1, le=3, strict=True, description="near-field elements are split into 4^levels triangles"
    )


class Time(_Model):
    """Adaptive RKF23 stepping; times in units of 1/k."""

    t_end: float = Field(10.0, gt=0)
    rtol: float = Field(1.0e-4, gt=0, lt=1)
    # dt_min and dt_max come before dt_initial so that its check can see both.
    dt_min: float = Field(1.0e-8, gt=0)
    dt_max: float = Field(0.5, gt=0)
    dt_initial: float = Field(1.0e-3, gt=0)
    max_steps: int = Field(1_000_000, ge=1, strict=True)
    stop_when_steady: bool = Field(False, strict=True)

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


class Solver(_Model):
    """Velocity solve for viscosity_ratio != 1 (double layer); unused at lambda = 1."""

    method: Literal["gmres", "substitution"] = Field(
        "gmres", description="GMRES (scipy, matrix-free) or the seed's successive substitution"
    )
    tol: float = Field(1.0e-6, gt=0, lt=1, description="relative residual of the velocity solve")
    max_iter: int = Field(200, ge=1, strict=True)
    volume_correction: bool = Field(
        True, description="remove the discrete net flux of the nodal velocities (volume conservation)"
    )


class Output(_Model):
    path: str = Field("runs/{name}.h5", min_length=1, description="'{name}' is the case name")
    snapshot_every: float = Field(0.5, gt=0, description="time between full snapshots, 1/k")
    checkpoint_every_steps: int = Field(
        50, ge=1, strict=True, description="write the restart checkpoint <path>.ckpt.npz every N accepted steps"
    )
    checkpoint_every_s: float = Field(
        60.0, gt=0, description="... and at least every M seconds of wall time"
    )


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


class Case(_Model):
    """One simulation: every knob that changes the result, nothing else."""

    name: str = Field(min_length=1, pattern=r"^[A-Za-z0-9._-]+$")
    shape: Shape = Shape()
    membrane: Membrane = Membrane()
    flow: Flow = Flow()
    initial_tilt_deg: float = Field(0.0, ge=-90, le=90)
    mesh: Mesh = Mesh()
    quadrature: Quadrature = Quadrature()
    time: Time = Time()
    solver: Solver = Solver()
    guards: Guards = Guards()
    output: Output = Field(default_factory=Output, validate_default=True)

    @field_validator("output")
    @classmethod
    def _resolve_output_path(cls, v: Output, info: ValidationInfo) -> Output:
        name = info.data.get("name")
        if name is not None and "{name}" in v.path:
            return v.model_copy(update={"path": v.path.replace("{name}", name)})
        return v

    def to_yaml(self) -> str:
        """The resolved case (all defaults filled); `load_case` reads it back equal."""
        return yaml.safe_dump(self.model_dump(mode="json"), sort_keys=False)


# ---------------------------------------------------------------- loading


class _UniqueKeyLoader(yaml.SafeLoader):
    """SafeLoader that refuses duplicate keys (PyYAML silently keeps the last)."""


def _construct_mapping(loader: yaml.SafeLoader, node: yaml.MappingNode, deep: bool = False):
    seen: set = set()
    for key_node, _ in node.value:
        key = loader.construct_object(key_node, deep=deep)
        if key in seen:
            raise yaml.constructor.ConstructorError(
                None, None, f"duplicate key {key!r}", key_node.start_mark
            )
        seen.add(key)
    return loader.construct_mapping(node, deep=deep)


_UniqueKeyLoader.add_constructor(
    yaml.resolver.BaseResolver.DEFAULT_MAPPING_TAG, _construct_mapping
)


def load_case(path: str | os.PathLike) -> Case:
    """Read and validate a case file; any mistake raises a one-line ConfigError."""
    source = os.fspath(path)
    try:
        with open(source, encoding="utf-8") as fh:
            text = fh.read()
    except FileNotFoundError:
        raise ConfigError(f"{source}: no such file") from None
    except UnicodeDecodeError:
        raise ConfigError(f"{source}: not a text file (expected YAML)") from None
    except OSError as exc:
        raise ConfigError(f"{source}: cannot read: {exc.strerror or exc}") from None
    try:
        data = yaml.load(text, Loader=_UniqueKeyLoader)
    except yaml.YAMLError as exc:
        raise ConfigError(f"{source}: not valid YAML: {_yaml_problem(exc)}") from None
    if data is None:
        raise ConfigError(f"{source}: file is empty (expected a mapping with at least 'name')")
    return case_from_dict(data, source=source)


def case_from_dict(d: Any, source: str = "<dict>") -> Case:
    """Validate a plain mapping as a Case; mistakes raise a one-line ConfigError."""
    if not isinstance(d, Mapping):
        raise ConfigError(
            f"{source}: top level must be a mapping of fields, got {type(d).__name__}"
        )
    try:
        return Case.model_validate(dict(d))
    except ValidationError as exc:
        raise ConfigError(_format_validation_error(exc, source)) from None


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
    for key, value in dotted.items():
        parts = key.split(".")
        node = data
        for i, part in enumerate(parts[:-1]):
            child = node.get(part) if isinstance(node, dict) else None
            if not isinstance(child, dict):
                where = ".".join(parts[: i + 1])
                raise ConfigError(f"<overrides>: {key}: '{where}' is not a section of the case")
            node = child
        node[parts[-1]] = value
    return case_from_dict(data, source="<overrides>")


# ---------------------------------------------------------------- messages


def _yaml_problem(exc: yaml.YAMLError) -> str:
    problem = getattr(exc, "problem", None) or str(exc).splitlines()[0]
    mark = getattr(exc, "problem_mark", None)
    if mark is not None:
        return f"{problem} (line {mark.line + 1}, column {mark.column + 1})"
    return problem


def _model_at(loc: tuple) -> type[BaseModel] | None:
    """The model class that owns the field at `loc` (loc of its parent)."""
    model: type[BaseModel] = Case
    for part in loc:
        field = model.model_fields.get(part) if isinstance(part, str) else None
        ann = field.annotation if field is not None else None
        if not (isinstance(ann, type) and issubclass(ann, BaseModel)):
            return None
        model = ann
    return model


def _show(value: Any) -> str:
    text = repr(value)
    return text if len(text) <= 60 else text[:57] + "..."


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
    "string_pattern_mismatch": "must contain only letters, digits, '.', '_' or '-'",
    "literal_error": "must be one of {expected}",
    "model_type": "must be a mapping of fields",
    "model_attributes_type": "must be a mapping of fields",
    "dict_type": "must be a mapping of fields",
}


def _describe(err: dict) -> str:
    loc = tuple(err["loc"])
    dotted = ".".join(str(p) for p in loc)
    kind = err["type"]
    if kind == "extra_forbidden":
        owner = _model_at(loc[:-1])
        allowed = ", ".join(owner.model_fields) if owner is not None else "?"
        return f"{dotted}: unknown field {str(loc[-1])!r} (allowed: {allowed})"
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
    return f"{dotted} = {_show(err.get('input'))}: {what}"


def _format_validation_error(exc: ValidationError, source: str) -> str:
    errors = exc.errors(include_url=False)
    shown = "; ".join(_describe(e) for e in errors[:3])
    more = f" (and {len(errors) - 3} more)" if len(errors) > 3 else ""
    return " ".join(f"{source}: {shown}{more}".split())

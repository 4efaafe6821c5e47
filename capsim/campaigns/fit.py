"""Fits: case fields (membrane parameters, G, ...) inferred from measured run outputs.

A fit file names a partial case (``base``), the case fields to infer with their
bounds, a CSV of measurements and an output directory::

    name: fit-modulus-shear
    base: {shape: {kind: sphere}, mesh: {level: 1}, time: {t_end: 3}}
    parameters:
      flow.G: {bounds: [0.002, 0.05], initial: 0.02, log: true}
    data: data/fit-modulus-shear.csv     # relative to the fit file
    output: {dir: runs/fit-modulus-shear}

The CSV's columns are *conditions* (case fields by dotted path: ``flow.viscosity_ratio``,
``physical.shear_rate``), *observables* (run outputs, the summary's names:
``D_xy``, ``theta``, ``ttf_ratio``, ...) and ``<observable>_sd``, each observable's
standard deviation. An empty observable cell is a point not measured.

Method: weighted least squares, by DFO-LS (``method.optimizer: dfols``, the default: linear
models of the residuals interpolated through the evaluations, one evaluation an iteration) or
scipy's ``trf`` with forward differences. Every evaluation of the model runs one case per
distinct row of conditions with the parameters set, through the campaign runner
(:func:`capsim.campaigns.campaign.run_campaign`) in ``<output.dir>/runs``: the run ids are keyed
by the case, so a refit, a resumed fit or a fit with one more data point reuses every run that
exists. The residual of point i is ``(model_i − data_i) / σ_i`` with ``σ_i² = sd_i² + e_i²``,
e_i the run's own error estimate of that observable where its file has one (``--error-estimate``
or a measured accuracy target): the discretisation error is treated as one more independent
error of the point. The parameters are optimised as unit variables ``u`` in [0, 1] across their
bounds (on log10 of the value for ``log: true``); the Jacobian's points are 1e-3 (dfols'
``radius_end``) to 1-2 % (trf's ``diff_step``) of the bound range apart, far above the adaptive
time stepping's noise in an output (about rtol relative, a step sequence changing with the
parameter), so that it measures the slope and not that noise (docs/fit.md). The covariance is ``(JᵀJ)⁻¹`` with
the weighted J when the data have sd columns (absolute errors: intervals from the normal
quantile), else ``s² (JᵀJ)⁻¹`` with ``s² = Σr²/(m − n)`` (intervals from Student's t with
m − n degrees of freedom); a log parameter's interval is symmetric in log10 of the value.
"""

from __future__ import annotations

import csv
import json
import math
import os
import re
import sys
from collections.abc import Callable, Mapping
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, Literal, Optional

import numpy as np
from pydantic import Field, model_validator

from capsim.campaigns.campaign import (
    CAMPAIGN_FILE, Campaign, _check_dotted, campaign_from_dict, canonical_field, expand_campaign, run_campaign,
)
from capsim.config import ConfigError, StrictModel, model_from_mapping, read_yaml
from capsim.errors import bounded_repr

__all__ = ["FitSpec", "FitError", "FitResult", "OBSERVABLES", "fit_from_dict", "load_fit", "plan_line", "run_fit",
           "plot_fit"]

#: the fit's result file in its output directory
RESULT_FILE = "fit.json"
#: typical iterations of trf on these problems (the printed expectation; max_evaluations bounds it)
TYPICAL_ITERATIONS = 5


def _observables() -> tuple[str, ...]:
    """The run outputs a data column may name: the summary's numbers (capsim.campaigns.summary),
    each with an entry in capsim.quantities, less spreads, error bars and bookkeeping."""
    from capsim.campaigns.summary import _FLOATS
    from capsim.quantities import key_for

    skip = {"wall_time_s", "accuracy_target_met", "settled", "ttf_ratio_kind", "rigid_turn", "orbits_averaged",
            "averaging_t_from", "averaging_t_to"}
    out = []
    for name in _FLOATS:
        if name in skip or name.endswith(("_std", "_error_estimate")):
            continue
        try:
            key_for(name, "campaign")
        except KeyError:
            continue
        out.append(name)
    return tuple(out)


#: observable column names (run outputs)
OBSERVABLES: tuple[str, ...] = _observables()


class FitError(RuntimeError):
    """A fit that cannot go on (a run that did not complete); one line."""


# ---------------------------------------------------------------- the spec


class FitParameter(StrictModel):
    """One parameter to infer: a case field with bounds and a starting value."""

    bounds: list[float] = Field(min_length=2, max_length=2, description="[lower, upper], lower < upper")
    initial: float = Field(description="starting value, within the bounds")
    log: bool = Field(False, description="optimise log10 of the value (bounds > 0); the interval is symmetric there")
    unit: Optional[str] = Field(None, description="unit of bounds and initial for a physical.* field, e.g. 'uN/m'")

    @model_validator(mode="after")
    def _consistent(self) -> FitParameter:
        lo, hi = self.bounds
        if not lo < hi:
            raise ValueError(f"bounds = {self.bounds}: lower must be < upper")
        if not lo <= self.initial <= hi:
            raise ValueError(f"initial = {self.initial:g}: must be within bounds [{lo:g}, {hi:g}]")
        if self.log and lo <= 0:
            raise ValueError(f"bounds = {self.bounds}: log: true needs bounds > 0")
        return self


class FitMethod(StrictModel):
    """Settings of the least-squares fit."""

    optimizer: Literal["dfols", "trf"] = Field(
        "dfols", description="dfols: DFO-LS's interpolation models, every evaluation reused (measured at level 1: 50-55 runs for "
        "two parameters over five rows, against 80 with trf); trf: scipy's least_squares with forward differences")
    radius_start: float = Field(0.2, gt=0, le=0.5, description="dfols: the first trust region's radius in unit "
                                "variables (fraction of the bound range): the first steps' size")
    radius_end: float = Field(1e-3, gt=0, lt=0.5, description="dfols: stop when the trust region's radius is this "
                              "(unit variables): the resolution of the estimate and the spacing of the points its "
                              "Jacobian is interpolated from, large against the runs' time-stepping noise")
    diff_step: float = Field(0.01, gt=0, le=0.2, description="trf: forward-difference step in unit variables "
                             "(fraction of the bound range): large against the runs' time-stepping noise")
    max_evaluations: int = Field(30, ge=1, le=1000, description="most model evaluations (trf: scipy's max_nfev, the "
                                 "Jacobian's evaluations come on top)")
    xtol: float = Field(1e-4, gt=0, lt=1, description="trf: stop when a step moves the unit variables less than this")
    confidence: float = Field(0.95, gt=0, lt=1, description="level of the intervals")
    coarse_level: Optional[int] = Field(
        None, ge=1, le=4, description="fit first at this mesh level (cheaper runs), then at the case's own from that "
        "estimate, the first radius three of its standard errors: fewer runs at the case's level (mesh sequencing)")

    @model_validator(mode="after")
    def _radii(self) -> FitMethod:
        if not self.radius_end < self.radius_start:
            raise ValueError(f"radius_end = {self.radius_end:g}: must be below radius_start ({self.radius_start:g})")
        return self


class FitOutput(StrictModel):
    dir: str = Field(min_length=1, description="directory of fit.json, summary.nc, fit.png and the runs (runs/)")
    figure: bool = Field(True, description="draw fit.png, the model through the data")


class FitSpec(StrictModel):
    """A fit; see the module docstring."""

    name: str = Field(min_length=1, max_length=100, pattern=r"^[A-Za-z0-9._-]+$")
    base: dict[str, Any] = Field(default_factory=dict, description="partial case, shared by every run")
    parameters: dict[str, FitParameter] = Field(min_length=1, description="case field -> bounds, initial, log")
    data: str = Field(min_length=1, description="CSV of conditions, observables and <observable>_sd")
    method: FitMethod = Field(default_factory=FitMethod)
    output: FitOutput


@dataclass
class FitData:
    """The measurements: per row its conditions; per point its row, observable, value and sd."""

    conditions: list[dict[str, Any]]
    rows: np.ndarray
    observables: list[str]
    observable: list[str]
    values: np.ndarray
    sd: np.ndarray | None  # None: no sd columns (unweighted, s² from the residuals)
    #: observable -> the unit its column carries ("ttf_ratio [rad/s]"); absent: capsim's own value
    units: dict[str, str] = field(default_factory=dict)

    @property
    def n_points(self) -> int:
        return len(self.values)


@dataclass
class Fit:
    """A validated fit: the spec, its data, where its files go."""

    spec: FitSpec
    data: FitData
    source: str

    @property
    def out_dir(self) -> Path:
        return Path(self.spec.output.dir)

    @property
    def runs_dir(self) -> Path:
        return self.out_dir / "runs"

    @property
    def names(self) -> list[str]:
        return list(self.spec.parameters)

    def distinct_conditions(self) -> list[dict[str, Any]]:
        seen: dict[str, dict] = {}
        for cond in self.data.conditions:
            seen.setdefault(json.dumps(cond, sort_keys=True), cond)
        return list(seen.values())


def load_fit(path: str | os.PathLike) -> Fit:
    """Read a fit file; the data path is relative to the file's directory. One-line ConfigError."""
    source = os.fspath(path)
    return fit_from_dict(read_yaml(source), source=source, base_dir=Path(source).parent)


def fit_from_dict(d: Any, source: str = "<fit>", base_dir: str | os.PathLike = ".") -> Fit:
    """Validate a fit, its data and every case its first evaluation runs (before any run starts)."""
    if isinstance(d, Fit):
        return d
    spec = model_from_mapping(FitSpec, d, source)
    if "name" in spec.base or isinstance(spec.base.get("output"), dict) and "path" in spec.base["output"]:
        raise ConfigError(f"{source}: base: name and output.path are set per run by the fit; remove them")
    fields: dict[str, str] = {}
    for key, par in spec.parameters.items():
        _check_dotted(key, f"{source}: parameters")
        full = canonical_field(key)
        if full in fields:
            raise ConfigError(f"{source}: parameters: {fields[full]} and {key} name one field ({full}); give it once")
        fields[full] = key
        physical = full.startswith("physical.")
        if physical and par.unit is None:
            raise ConfigError(f"{source}: parameters.{key}.unit: missing; a physical field needs the unit of its "
                              "bounds and initial value, e.g. unit: uN/m")
        if not physical and par.unit is not None:
            raise ConfigError(f"{source}: parameters.{key}.unit = {par.unit!r}: only a physical.* field takes a unit "
                              "(capsim's own fields are dimensionless)")
    path = Path(spec.data)
    path = path if path.is_absolute() else Path(base_dir) / path
    data = read_data(path, fields)
    n = len(spec.parameters)
    need = n if data.sd is not None else n + 1
    if data.n_points < need:
        why = "" if data.sd is not None else " (no sd columns: one more than the parameters, to estimate s²)"
        raise ConfigError(f"{source}: data: {data.n_points} data point{'s' * (data.n_points != 1)} for {n} "
                          f"parameter{'s' * (n != 1)}: at least {need} needed{why}")
    if spec.method.optimizer == "dfols" and spec.method.max_evaluations < n + 2:
        raise ConfigError(f"{source}: method.max_evaluations = {spec.method.max_evaluations}: dfols needs at least "
                          f"n + 2 = {n + 2} (its first model takes n + 1 evaluations, then one an iteration)")
    fit = Fit(spec, data, source)
    # every case of the first evaluation, validated as a campaign validates its runs
    first = _campaign(fit, [_point(fit, [p.initial for p in spec.parameters.values()])], source=source)
    case = expand_campaign(first)[0].case()  # the first run's case: its mesh level, its physical block
    coarse = spec.method.coarse_level
    if coarse is not None and coarse >= case.mesh.level:
        raise ConfigError(f"{source}: method.coarse_level = {coarse}: must be below the runs' mesh level "
                          f"({case.mesh.level})")
    if data.units:  # and each column's unit reachable from its runs (a physical block where a scale is needed)
        for obs, unit in data.units.items():
            try:
                output_in_unit(obs, unit, case)
            except ConfigError as exc:
                raise ConfigError(f"{source}: {exc}") from None
    return fit


def read_data(path: Path, parameters: Mapping[str, str] = {}) -> FitData:
    """The measurements of a CSV (lines starting with '#' are comments); one-line ConfigError."""
    where = f"data {bounded_repr(str(path))}"
    try:
        with open(path, encoding="utf-8", newline="") as fh:
            lines = [line for line in fh.read(16 * 2**20).splitlines() if line.strip() and not line.startswith("#")]
    except (OSError, UnicodeDecodeError) as exc:
        raise ConfigError(f"{where}: cannot read ({getattr(exc, 'strerror', None) or type(exc).__name__})") from None
    rows = list(csv.reader(lines))
    if len(rows) < 2:
        raise ConfigError(f"{where}: no data rows (a header line of column names, then one line per measurement)")
    header, column_units = [], {}
    for cell in rows[0]:
        name, unit = _split_unit(cell.strip(), where)
        header.append(name)
        if unit:
            column_units[name] = unit
    if len(set(header)) != len(header):
        raise ConfigError(f"{where}: a column name appears twice ({', '.join(sorted({h for h in header if header.count(h) > 1}))})")
    conditions, observables, sds = [], [], {}
    for name in header:
        if name.endswith("_sd") and name[:-3] in header:
            sds[name[:-3]] = name
        elif name in OBSERVABLES:
            observables.append(name)
        elif "." in name:
            _check_dotted(name, f"{where}: column")
            if canonical_field(name) in parameters:
                raise ConfigError(f"{where}: column {name!r} is a parameter of the fit; a condition cannot be fitted")
            conditions.append(name)
        else:
            raise ConfigError(f"{where}: column {bounded_repr(name)} names no run output and no case field (outputs: "
                              f"{', '.join(OBSERVABLES[:12])}, ...; conditions are dotted case fields such as "
                              "flow.viscosity_ratio; uncertainties are <output>_sd)")
    if not observables:
        raise ConfigError(f"{where}: no observable column (a run output such as {', '.join(OBSERVABLES[:4])})")
    for name in column_units:
        if name in conditions:
            raise ConfigError(f"{where}: column {name!r} [{column_units[name]}]: a condition carries its unit in its "
                              "cells ('50 1/s'), not in the header")
    units = {}
    for obs in observables:
        unit, sd_unit = column_units.get(obs, ""), column_units.get(sds.get(obs, ""), "")
        if sd_unit and sd_unit != unit:
            raise ConfigError(f"{where}: {sds[obs]} [{sd_unit}]: an sd column takes its observable's unit "
                              f"({obs} [{unit or 'capsim units'}])")
        if unit:
            output_unit_kind(obs, unit, where)  # refused here if it cannot be one
            units[obs] = unit
    if sds and set(sds) != set(observables):
        lacking = [o for o in observables if o not in sds]
        raise ConfigError(f"{where}: {', '.join(o + '_sd' for o in lacking)} missing: give an sd column for every "
                          "observable or for none")
    cond_rows, point_row, point_obs, values, sd = [], [], [], [], []
    for r, row in enumerate(rows[1:], start=1):
        if len(row) != len(header):
            raise ConfigError(f"{where}: line {r + 1}: {len(row)} cells for {len(header)} columns")
        cells = dict(zip(header, (c.strip() for c in row)))
        cond = {}
        for name in conditions:
            if not cells[name]:
                raise ConfigError(f"{where}: line {r + 1}: {name} is empty; every row needs its conditions")
            cond[name] = _cell_value(cells[name])
        cond_rows.append(cond)
        for obs in observables:
            if not cells[obs]:
                continue  # not measured
            value = _number(cells[obs], f"{where}: line {r + 1}: {obs}")
            values.append(value)
            point_row.append(r - 1)
            point_obs.append(obs)
            if sds:
                s = _number(cells[sds[obs]], f"{where}: line {r + 1}: {sds[obs]}")
                if not s > 0:
                    raise ConfigError(f"{where}: line {r + 1}: {sds[obs]} = {s:g}: must be > 0")
                sd.append(s)
    return FitData(cond_rows, np.array(point_row, dtype=int), observables, point_obs, np.array(values),
                   np.array(sd) if sds else None, units)


_UNIT_IN_HEADER = re.compile(r"^(?P<name>[^\[\]]+?)\s*\[(?P<unit>[^\[\]]+)\]$")
#: pint's names of angles: a frequency column in one of them counts radians (or degrees) per time,
#: a revolution being 2π rad; pint itself treats the radian as dimensionless (1 Hz -> 1 rad/s)
_ANGLE_UNITS = ("radian", "degree", "revolution", "turn", "cycle")


def _split_unit(cell: str, where: str) -> tuple[str, str]:
    """'ttf_ratio [rad/s]' -> ('ttf_ratio', 'rad/s'); a name without brackets -> (name, '')."""
    if "[" not in cell and "]" not in cell:
        return cell, ""
    m = _UNIT_IN_HEADER.match(cell)
    if m is None:
        raise ConfigError(f"{where}: column {bounded_repr(cell)}: a unit is written after the name in brackets, "
                          "as in 'length_along [um]'")
    return m.group("name").strip(), m.group("unit").strip()


def output_unit_kind(observable: str, unit: str, where: str) -> str:
    """How a run output is converted to a column's unit, refused in one line where it cannot be:
    "scale" (a value in a capsim scale: times the case's factor, then pint), "own" (a value with its
    own unit, an angle in rad or a time in s: pint), "frequency" (the k/(4π) scale's revolutions per
    time, with angles counted: 1 revolution = 2π rad)."""
    from capsim.quantities import SCALE_UNITS, TABLE, key_for
    from capsim.units import _registry

    q = TABLE[key_for(observable, "campaign")]
    ureg = _registry()
    try:
        target = ureg.Unit(unit)
    except Exception:  # noqa: BLE001 - pint's many parse errors: one line
        raise ConfigError(f"{where}: column {observable} [{unit}]: {bounded_repr(unit)} is not a unit pint reads "
                          "(e.g. um, Hz, rad/s, deg)") from None
    if q.scale in SCALE_UNITS:
        shown = SCALE_UNITS[q.scale][1]
        kind = "frequency" if q.scale == "k/(4 pi)" else "scale"
        source = ureg.Unit(shown)
    elif q.units in ("rad", "degree", "s"):
        kind, shown, source = "own", q.units, ureg.Unit(q.units)
    else:
        raise ConfigError(f"{where}: column {observable} [{unit}]: {observable} is a pure number (no physical unit); "
                          "remove the unit")
    if source.dimensionality != target.dimensionality:
        raise ConfigError(f"{where}: column {observable} [{unit}]: {observable} is in {shown} with --units physical; "
                          f"{unit} is not convertible to it")
    return kind


def output_in_unit(observable: str, unit: str, case: Any) -> float:
    """The factor that turns a run's dimensionless `observable` into `unit` for `case`: the case's
    scale factor (its physical block) times pint's conversion; a frequency in an angle per time counts
    2π rad a revolution. ConfigError (one line) for a scaled output of a case without a physical block."""
    from capsim.quantities import SCALE_UNITS, TABLE, key_for
    from capsim.units import _registry, physical_factors

    q = TABLE[key_for(observable, "campaign")]
    ureg = _registry()
    kind = output_unit_kind(observable, unit, "data")
    if kind == "own":
        return float(ureg.Quantity(1.0, q.units).to(unit).magnitude)
    if getattr(case, "physical", None) is None:
        raise ConfigError(f"data: column {observable} [{unit}]: the case has no physical block, so {observable} has "
                          "no physical value; give the base a physical: block or the column in capsim units")
    factor = physical_factors(case.physical)[q.scale]  # to SCALE_UNITS' shown unit
    if kind == "frequency" and any(a in str(ureg.Unit(unit)) for a in _ANGLE_UNITS):
        return float(factor * ureg.Quantity(1.0, "revolution/second").to(unit).magnitude)
    return float(factor * ureg.Quantity(1.0, SCALE_UNITS[q.scale][1]).to(unit).magnitude)


def _cell_value(text: str) -> Any:
    """A condition cell: a number, else the text (a physical quantity such as '50 1/s')."""
    try:
        value = float(text)
    except ValueError:
        return text
    return int(value) if value.is_integer() and "." not in text and "e" not in text.lower() else value


def _number(text: str, where: str) -> float:
    try:
        value = float(text)
    except ValueError:
        value = math.nan
    if not math.isfinite(value):
        raise ConfigError(f"{where} = {bounded_repr(text)}: must be a finite number")
    return value


# ---------------------------------------------------------------- the model


def _to_unit(par: FitParameter, x: float) -> float:
    lo, hi = par.bounds
    if par.log:
        return (math.log10(x) - math.log10(lo)) / (math.log10(hi) - math.log10(lo))
    return (x - lo) / (hi - lo)


def _from_unit(par: FitParameter, u: float) -> float:
    lo, hi = par.bounds
    u = min(max(float(u), 0.0), 1.0)
    x = 10 ** (math.log10(lo) + u * (math.log10(hi) - math.log10(lo))) if par.log else lo + u * (hi - lo)
    return float(f"{x:.10g}")  # a value a resumed fit writes again identically (the run id holds it)


def _point(fit: Fit, x: list[float]) -> dict[str, Any]:
    """The case values of the parameters at x (a physical field as a quantity with its unit)."""
    out = {}
    for (key, par), value in zip(fit.spec.parameters.items(), x):
        out[key] = f"{value:.10g} {par.unit}" if par.unit else value
    return out


def _campaign(fit: Fit, points: list[dict[str, Any]], source: str = "<fit>") -> Campaign:
    """One campaign of the runs at these parameter points, each at every distinct row of conditions."""
    rows = [{**cond, **point} for point in points for cond in fit.distinct_conditions()]
    seen: dict[str, dict] = {}
    for row in rows:  # one run per case
        seen.setdefault(json.dumps(row, sort_keys=True, default=str), row)
    rows = list(seen.values())
    keys = list(rows[0])
    if not keys:
        raise ConfigError(f"{source}: nothing varies")
    return campaign_from_dict({"name": fit.spec.name, "base": _filled_base(fit),
                               "zip": {k: [row[k] for row in rows] for k in keys},
                               "output": {"dir": str(fit.runs_dir)}}, source=source)


def _filled_base(fit: Fit) -> dict[str, Any]:
    """The base with the parameters' initial values and the first row's conditions written in, so that
    it is a whole case by itself (a physical block needs its modulus and rate); every run sets its own."""
    from capsim.campaigns.campaign import _set_dotted

    base = json.loads(json.dumps(fit.spec.base))
    initial = _point(fit, [p.initial for p in fit.spec.parameters.values()])
    for key, value in {**fit.data.conditions[0], **initial}.items():
        _set_dotted(base, key, value)
    return base


def _run_error(path: str, observable: str, value: float) -> float:
    """The run's own error estimate of `observable` (absolute), or NaN where its file has none:
    the error_estimate group (``capsim run --error-estimate``), else the kept level's absolute
    error of a measured accuracy target for that quantity."""
    from capsim.campaigns.summary import read_run

    record = read_run(path) or {}
    e = record.get(f"{observable}_error_estimate", math.nan)
    if isinstance(e, float) and math.isfinite(e):
        return abs(e)
    try:
        import h5py

        with h5py.File(path, "r") as f:
            group = f.get("accuracy")
            if group is not None and "absolute_errors" in group:
                quantity = group.attrs.get("quantity", group["quantity"][()] if "quantity" in group else b"")
                quantity = quantity.decode() if isinstance(quantity, bytes) else str(quantity)
                if quantity == observable:
                    e = float(np.asarray(group["absolute_errors"])[-1])
                    return abs(e) if math.isfinite(e) else math.nan
    except Exception:  # noqa: BLE001 - no readable estimate: the data's sd alone
        pass
    return math.nan


@dataclass
class _Evaluator:
    """The model: parameters -> one run per distinct row of conditions -> the observables at each point."""

    fit: Fit
    workers: int | None
    log: Callable[[str], None]
    cache: dict[tuple, tuple[np.ndarray, np.ndarray, list[str]]] = field(default_factory=dict)
    runs_executed: int = 0
    evaluations: int = 0
    used: dict[str, dict] = field(default_factory=dict)  # run id -> its zip values (every run the fit used)

    def __call__(self, x: list[float]) -> tuple[np.ndarray, np.ndarray, list[str]]:
        """(model value, run error, run id) per data point at parameters x."""
        key = tuple(x)
        if key in self.cache:
            return self.cache[key]
        fit = self.fit
        campaign = _campaign(fit, [_point(fit, x)])
        specs = expand_campaign(campaign)
        outcome = run_campaign(campaign, workers=self.workers, overwrite=True)
        if outcome["interrupted"]:
            raise KeyboardInterrupt("fit interrupted; its finished runs are kept for the next fit")
        ran = outcome["total"] - outcome["skipped"]
        self.runs_executed += ran
        self.evaluations += 1
        bad = [r for r in outcome["records"] if r["status"] != "completed"]
        if bad:
            raise FitError(f"{fit.source}: run {bad[0]['run_id']} did not complete ({bad[0]['status']}: "
                           f"{bounded_repr(bad[0]['status_reason'], 160)[1:-1]}); narrow the parameters' bounds or "
                           "change the base case")
        from capsim.campaigns.summary import read_run

        by_cond = {}
        for spec in specs:
            cond = {k: v for k, v in spec.params.items() if k not in fit.spec.parameters}
            by_cond[json.dumps(cond, sort_keys=True)] = spec
            self.used[spec.run_id] = spec.params
        model, err, ids = [], [], []
        records: dict[str, dict] = {}
        factors: dict[tuple[str, str], float] = {}
        for row, obs in zip(fit.data.rows, fit.data.observable):
            spec = by_cond[json.dumps(fit.data.conditions[row], sort_keys=True)]
            record = records.setdefault(spec.run_id, read_run(spec.path) or {})
            value = float(record.get(obs, math.nan))
            if not math.isfinite(value):
                raise FitError(f"{fit.source}: run {spec.run_id} has no {obs} (status {record.get('status', '?')}, "
                               f"motion {record.get('motion', '?') or '?'}); a longer time.t_end may settle it")
            e = _run_error(spec.path, obs, value)
            unit = fit.data.units.get(obs)
            if unit:  # the column's unit: the run's value (and its error) times the case's factor
                factor = factors.get((spec.run_id, obs))
                if factor is None:
                    factor = factors[spec.run_id, obs] = output_in_unit(obs, unit, spec.case())
                value, e = value * factor, e * factor
            model.append(value)
            err.append(e)
            ids.append(spec.run_id)
        shown = ", ".join(f"{k}={v:.6g}" for k, v in zip(fit.names, x))
        self.log(f"  evaluation {self.evaluations}: {shown}: {len(specs)} runs ({ran} of them run now)")
        self.cache[key] = out = (np.array(model), np.array(err), ids)
        return out


def _sigma(data: FitData, run_error: np.ndarray) -> np.ndarray:
    """σ_i of each point: sqrt(sd² + e²) with sd the data's, e the run's own error (0 where none);
    1 for data without sd (unweighted: the scale is s², estimated from the residuals)."""
    if data.sd is None:
        return np.ones(data.n_points)
    e = np.where(np.isfinite(run_error), run_error, 0.0)
    return np.sqrt(data.sd ** 2 + e ** 2)


# ---------------------------------------------------------------- the fit


@dataclass
class FitResult:
    """What a fit found; ``to_dict()`` is fit.json."""

    name: str
    parameters: list[str]
    estimates: dict[str, float]
    std_errors: dict[str, float]
    intervals: dict[str, list[float]]
    confidence: float
    units: dict[str, str]
    at_bound: dict[str, bool]
    correlations: list[list[float]]
    covariance: list[list[float]]
    covariance_form: str
    residuals: list[dict[str, Any]]
    chi2: float
    dof: int
    reduced_chi2: float
    n_points: int
    n_runs: int
    n_runs_executed: int
    n_evaluations: int
    runs_per_evaluation: int
    success: bool
    message: str
    runs_dir: str
    summary: str = ""
    figure: str = ""
    coarse_level: Optional[int] = None
    n_runs_coarse: int = 0  # of n_runs, those at the coarse level (method.coarse_level)

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)

    def table(self) -> str:
        """The closing table: estimates, intervals, correlations, cost."""
        pct = f"{100 * self.confidence:g}%"
        lines = [f"{'parameter':<28} {'estimate':>12} {'std error':>12}  {pct} interval"]
        for p in self.parameters:
            lo, hi = self.intervals[p]
            unit = f" {self.units[p]}" if self.units[p] else ""
            flag = "  (at a bound)" if self.at_bound[p] else ""
            lines.append(f"{p:<28} {self.estimates[p]:>12.5g} {self.std_errors[p]:>12.3g}  [{lo:.5g}, {hi:.5g}]"
                         f"{unit}{flag}")
        if len(self.parameters) > 1:
            for i, p in enumerate(self.parameters):
                for j in range(i + 1, len(self.parameters)):
                    lines.append(f"correlation {p} / {self.parameters[j]}: {self.correlations[i][j]:+.3f}")
        lines.append(f"chi2 {self.chi2:.4g} on {self.dof} degrees of freedom (reduced {self.reduced_chi2:.3g}); "
                     f"covariance {self.covariance_form}")
        if not self.success:  # said, not only in the exit code: the numbers above are not a minimum's
            lines.append(f"NOT converged ({self.message}): the estimates are the optimiser's last point and the "
                         "intervals its Jacobian's there; raise method.max_evaluations or narrow the bounds")
        coarse = (f"; {self.n_runs_coarse} of them at the coarse mesh level {self.coarse_level}, "
                  f"{self.n_runs - self.n_runs_coarse} at the case's" if self.coarse_level is not None else "")
        lines.append(f"{self.n_runs} runs ({self.runs_per_evaluation} per evaluation, {self.n_evaluations} "
                     f"evaluations{coarse}), {self.n_runs_executed} run now, the others reused from {self.runs_dir}")
        return "\n".join(lines)


def typical_evaluations(optimizer: str, n: int) -> int:
    """The evaluations a fit of n parameters typically costs (the printed expectation), measured on the
    synthetic fits of benchmarks/fit_coverage.py and docs/fit.md's example from a start within a factor 2:
    dfols 8-9 for one parameter and 10-11 for two (n + 1 for its first model, then one an iteration);
    trf 1 + n a Gauss-Newton iteration, about TYPICAL_ITERATIONS of them."""
    return 7 + 2 * n if optimizer == "dfols" else (1 + n) * TYPICAL_ITERATIONS


def plan_line(fit: Fit) -> str:
    """What the fit will cost, said before it starts."""
    n = len(fit.spec.parameters)
    per = len(fit.distinct_conditions())
    m = fit.spec.method
    typical = typical_evaluations(m.optimizer, n)
    at_most = per * m.max_evaluations * ((1 + n) if m.optimizer == "trf" else 1)
    how = ("one evaluation an iteration after n + 1 for its first model (DFO-LS)" if m.optimizer == "dfols"
           else f"{1 + n} evaluations per iteration (forward differences)")
    coarse = (f"; first at the coarse mesh level {m.coarse_level} (as many again there), then at the case's from "
              "its estimate (fewer)" if m.coarse_level is not None else "")
    return (f"fit {fit.spec.name}: {fit.data.n_points} data points, {n} parameter{'s' * (n != 1)}; {per} runs per "
            f"evaluation, {how}: about {per * typical} runs in {typical} evaluations, at most {at_most}{coarse}; "
            f"runs that exist in {fit.runs_dir} are reused")


def _stderr(line: str) -> None:
    print(line, file=sys.stderr, flush=True)


def _unit_covariance(jac: np.ndarray, chi2: float, data: FitData, n: int) -> tuple[np.ndarray, float | None]:
    """The estimate's covariance in unit variables from the weighted residuals' Jacobian: (JᵀJ)⁻¹ when the
    data have sd columns (s² None), else s² (JᵀJ)⁻¹ with s² = χ²/(m − n) estimated from the residuals."""
    J = np.atleast_2d(jac)
    cov = np.linalg.pinv(J.T @ J)
    if data.sd is not None:
        return cov, None
    s2 = chi2 / max(data.n_points - n, 1)
    return s2 * cov, s2


def _at_level(fit: Fit, level: int) -> Fit:
    """The same fit with every run at mesh level `level` (its runs keyed apart by their case)."""
    base = json.loads(json.dumps(fit.spec.base))
    base.setdefault("mesh", {})["level"] = level
    return Fit(fit.spec.model_copy(update={"base": base}), fit.data, fit.source)


def run_fit(fit: Fit, *, workers: int | None = 1, log: Callable[[str], None] | None = _stderr) -> FitResult:
    """Fit the parameters to the data; writes ``<output.dir>/fit.json`` (and summary.nc, fit.png).

    `log` receives the plan line, one line per evaluation and the closing table (None: silent).
    """
    from scipy import stats

    log = log or (lambda line: None)
    spec, data = fit.spec, fit.data
    _check_owner(fit)
    log(plan_line(fit))
    pars = list(spec.parameters.values())

    def residuals_of(model: _Evaluator) -> Callable[[np.ndarray], np.ndarray]:
        def residuals(u: np.ndarray) -> np.ndarray:
            values, err, _ = model([_from_unit(p, ui) for p, ui in zip(pars, u)])
            return (values - data.values) / _sigma(data, err)
        return residuals

    u0 = np.array([_to_unit(p, p.initial) for p in pars])
    m = spec.method
    coarse = None
    if m.coarse_level is not None:  # mesh sequencing: the coarse level's estimate starts the case's level
        coarse = _Evaluator(_at_level(fit, m.coarse_level), workers, log)
        log(f"  at the coarse mesh level {m.coarse_level}:")
        first = OPTIMIZERS[m.optimizer](residuals_of(coarse), u0, m)
        r0 = residuals_of(coarse)(first.u)  # the estimate's evaluation, made already
        se_u = np.sqrt(np.clip(np.diag(_unit_covariance(first.jac, float(r0 @ r0), data, len(pars))[0]), 0, None))
        # three standard errors of the coarse estimate: the case's level moves it by the mesh's error, of
        # that order where the coarse level is worth its name (never below four final radii)
        radius = float(np.clip(3.0 * se_u.max(), 4.0 * m.radius_end, m.radius_start))
        u0, m = first.u, m.model_copy(update={"radius_start": radius})
        log(f"  at the case's mesh level, from there (first radius {radius:.3g}):")
    model = _Evaluator(fit, workers, log)
    solution = OPTIMIZERS[m.optimizer](residuals_of(model), u0, m)
    x = [_from_unit(p, ui) for p, ui in zip(pars, solution.u)]
    values, err, ids = model(x)
    sigma = _sigma(data, err)
    r = (values - data.values) / sigma
    n, n_pts = len(pars), data.n_points
    dof = n_pts - n
    chi2 = float(r @ r)
    cov_u, s2 = _unit_covariance(solution.jac, chi2, data, n)
    if s2 is None:
        form = "(J^T J)^-1 of the residuals weighted by 1/sqrt(sd^2 + run error^2)"
        q = float(stats.norm.ppf(0.5 + m.confidence / 2))
    else:
        form = f"s^2 (J^T J)^-1, s^2 = {s2:.4g} from the residuals (no sd columns)"
        q = float(stats.t.ppf(0.5 + m.confidence / 2, dof))
    # from unit variables to the fitted scale z (log10 x or x), then the delta method for x
    span = np.array([math.log10(p.bounds[1] / p.bounds[0]) if p.log else p.bounds[1] - p.bounds[0] for p in pars])
    cov_z = cov_u * np.outer(span, span)
    sd_z = np.sqrt(np.clip(np.diag(cov_z), 0, None))
    dxdz = np.array([xi * math.log(10) if p.log else 1.0 for p, xi in zip(pars, x)])
    cov_x = cov_z * np.outer(dxdz, dxdz)
    with np.errstate(invalid="ignore", divide="ignore"):
        corr = cov_z / np.outer(sd_z, sd_z)
    estimates, errors, intervals, units, at_bound = {}, {}, {}, {}, {}
    for i, (key, p) in enumerate(spec.parameters.items()):
        z = math.log10(x[i]) if p.log else x[i]
        lo, hi = z - q * sd_z[i], z + q * sd_z[i]
        estimates[key] = x[i]
        errors[key] = float(math.sqrt(max(cov_x[i, i], 0.0)))
        intervals[key] = [10 ** lo, 10 ** hi] if p.log else [lo, hi]
        units[key] = p.unit or ""
        at_bound[key] = bool(solution.at_bound[i])
    point_rows = []
    for k in range(n_pts):
        row = int(data.rows[k])
        point_rows.append({"row": row + 1, "conditions": data.conditions[row], "observable": data.observable[k],
                           "unit": data.units.get(data.observable[k], ""),
                           "data": float(data.values[k]), "sd": float(data.sd[k]) if data.sd is not None else None,
                           "run_error": float(err[k]) if math.isfinite(err[k]) else None,
                           "model": float(values[k]), "residual": float(r[k]), "run_id": ids[k]})
    result = FitResult(
        name=spec.name, parameters=list(spec.parameters), estimates=estimates, std_errors=errors,
        intervals=intervals, confidence=m.confidence, units=units, at_bound=at_bound,
        correlations=np.nan_to_num(corr, nan=0.0).tolist(), covariance=cov_x.tolist(), covariance_form=form,
        residuals=point_rows, chi2=chi2, dof=dof, reduced_chi2=chi2 / dof if dof > 0 else math.nan,
        n_points=n_pts, n_runs=len(model.used) + (len(coarse.used) if coarse else 0),
        n_runs_executed=model.runs_executed + (coarse.runs_executed if coarse else 0),
        n_evaluations=model.evaluations + (coarse.evaluations if coarse else 0),
        runs_per_evaluation=len(fit.distinct_conditions()), coarse_level=spec.method.coarse_level,
        n_runs_coarse=len(coarse.used) if coarse else 0,
        success=solution.success, message=solution.message, runs_dir=str(fit.runs_dir),
    )
    _finish(fit, model, result, log)
    return result


@dataclass
class _Solution:
    """An optimiser's answer in unit variables: the estimate, the weighted residuals' Jacobian there,
    which parameters ended on a bound, and whether it converged (with its message)."""

    u: np.ndarray
    jac: np.ndarray
    at_bound: np.ndarray
    success: bool
    message: str


def _solve_trf(residuals: Callable[[np.ndarray], np.ndarray], u0: np.ndarray, m: FitMethod) -> _Solution:
    """scipy's trf with forward differences: 1 + n evaluations an iteration.

    scipy's diff_step is relative to the variable (its step is diff_step·|v|): optimised as v = 1 + u in
    [1, 2], the step is 1-2 % of each bound range and never shrinks towards the time stepping's noise
    near a lower bound (u → 0, where a step relative to u would vanish). The unit variables make
    x_scale = 1 (a shift does not change the Jacobian)."""
    from scipy import optimize

    res = optimize.least_squares(lambda v: residuals(v - 1.0), u0 + 1.0, jac="2-point", bounds=(1.0, 2.0),
                                 method="trf", x_scale=1.0, diff_step=m.diff_step, xtol=m.xtol, ftol=1e-6, gtol=1e-8,
                                 max_nfev=m.max_evaluations)
    return _Solution(res.x - 1.0, np.atleast_2d(res.jac), res.active_mask != 0, bool(res.success), str(res.message))


def _solve_dfols(residuals: Callable[[np.ndarray], np.ndarray], u0: np.ndarray, m: FitMethod) -> _Solution:
    """DFO-LS (Cartis, Fiala, Marteau & Roberts 2019): a trust region on linear models of the residuals
    interpolated through n + 1 evaluated points, each iteration one evaluation, every evaluation kept
    in the model (no forward differences). It stops when the radius reaches ``radius_end``; its
    Jacobian at the estimate is the model's, interpolated from points within about that distance (so
    ``radius_end`` plays ``diff_step``'s part: large against the runs' noise, small against the
    model's curvature)."""
    import dfols

    n = len(u0)
    # the first interpolation points are u0 + radius_start along each axis (DFO-LS steps back from a bound)
    sol = dfols.solve(residuals, u0, bounds=(np.zeros(n), np.ones(n)), rhobeg=m.radius_start, rhoend=m.radius_end,
                      maxfun=m.max_evaluations, do_logging=False, print_progress=False)
    if sol.flag == sol.EXIT_INPUT_ERROR or sol.x is None or sol.jacobian is None:
        raise FitError(f"DFO-LS refused the problem: {sol.msg}")
    u = np.asarray(sol.x, dtype=float)
    at_bound = (u <= m.radius_end) | (u >= 1.0 - m.radius_end)
    return _Solution(u, np.atleast_2d(sol.jacobian), at_bound, sol.flag == sol.EXIT_SUCCESS, str(sol.msg))


#: the least-squares optimisers (FitMethod.optimizer): residuals(u), u0, method -> _Solution
OPTIMIZERS: dict[str, Callable[..., _Solution]] = {"dfols": _solve_dfols, "trf": _solve_trf}


def _check_owner(fit: Fit) -> None:
    """Refuse an output directory whose runs belong to another fit or campaign (one line)."""
    held = fit.runs_dir / CAMPAIGN_FILE
    if held.exists():
        try:
            name = (read_yaml(held) or {}).get("name")
        except (ConfigError, AttributeError):
            name = None
        if name != fit.spec.name:
            raise ConfigError(f"output.dir = {bounded_repr(fit.spec.output.dir)}: its runs/ holds "
                              f"{bounded_repr(name)}, not the fit {fit.spec.name!r}; use another output.dir")


def _finish(fit: Fit, model: _Evaluator, result: FitResult, log: Callable[[str], None]) -> None:
    """Every run the fit used at the case's mesh level (a coarse stage's stay in runs/ for a refit) as one
    campaign (runs/campaign.yaml, runs.json: nothing is run again),
    its netCDF summary, fit.json and the figure."""
    from capsim.campaigns.summary import summarize_to_file
    from capsim.storage.files import write_durably

    keys = list(next(iter(model.used.values())))
    campaign = campaign_from_dict({"name": fit.spec.name, "base": _filled_base(fit),
                                   "zip": {k: [p[k] for p in model.used.values()] for k in keys},
                                   "output": {"dir": str(fit.runs_dir)}})
    run_campaign(campaign, workers=1, overwrite=True)  # every run completed: writes the index only
    path, _ = summarize_to_file(fit.runs_dir, fit.out_dir / "summary.nc", overwrite=True)
    result.summary = str(path)
    if fit.spec.output.figure:
        result.figure = str(plot_fit(result, fit.out_dir / "fit.png"))
    text = json.dumps(result.to_dict(), indent=1, default=str)
    write_durably(fit.out_dir / RESULT_FILE, lambda fh: fh.write(text.encode("utf-8")), "the previous fit.json is kept")
    log(result.table())


def _axis_value(key: str, value: Any) -> float | None:
    """A condition as a number for the figure's axis: a physical quantity in SI; None for another text."""
    if isinstance(value, (int, float)) and not isinstance(value, bool):
        return float(value)
    if isinstance(value, str) and key.startswith("physical."):
        from capsim.units import parse

        try:
            return float(parse(value, key.split(".", 1)[1]))
        except Exception:  # noqa: BLE001 - not a quantity: the row number stands in
            return None
    return None


def plot_fit(result: FitResult, path: str | os.PathLike) -> Path:
    """The model at the estimates through the data (one panel per observable, against the first
    numeric condition, else the row), with the data's error bars; written to `path`."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    observables = list(dict.fromkeys(p["observable"] for p in result.residuals))
    fig, axes = plt.subplots(1, len(observables), figsize=(4.5 * len(observables), 3.6), squeeze=False)
    for ax, obs in zip(axes[0], observables):
        pts = [p for p in result.residuals if p["observable"] == obs]
        conds = [k for k in pts[0]["conditions"] if _axis_value(k, pts[0]["conditions"][k]) is not None]
        xs = [_axis_value(conds[0], p["conditions"][conds[0]]) if conds else p["row"] for p in pts]
        order = np.argsort(xs)
        xs = np.asarray(xs, dtype=float)[order]
        data = np.array([p["data"] for p in pts])[order]
        sd = np.array([p["sd"] or 0.0 for p in pts])[order]
        fitted = np.array([p["model"] for p in pts])[order]
        ax.errorbar(xs, data, yerr=sd if sd.any() else None, fmt="o", label="data")
        ax.plot(xs, fitted, "-s", label="model at the estimates")
        ax.set_xlabel((conds[0] + (" (SI)" if conds[0].startswith("physical.") else "")) if conds else "data row")
        unit = pts[0].get("unit") or ""
        ax.set_ylabel(f"{obs} [{unit}]" if unit else obs)
        ax.legend(fontsize=8)
    shown = ", ".join(f"{p} = {result.estimates[p]:.4g}" for p in result.parameters)
    fig.suptitle(f"{result.name}: {shown}", fontsize=9)
    fig.tight_layout()
    path = Path(path)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path

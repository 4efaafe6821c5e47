"""A campaign directory → one xarray Dataset → netCDF.

Each run file contributes one record: its status, and the steady-state
observables of its ``summary`` group when present; otherwise the ``run`` group
and the last row of the time series, with NaN (or "") for what the file does
not hold. Swept fields become dimensions (a ``run`` dimension when the runs are
not a full grid). The run files are read through :mod:`capsim.storage.store`; units,
long names and definitions come from the one table :mod:`capsim.quantities`.

Each record carries its context: the motion's period and amplitudes,
the averaging window, the mesh (base, level), the law and its parameters, the
bending modulus, the time scheme and tolerance, status and reason, the error
estimates when ``--error-estimate`` ran, the intrinsic viscosity (5/2)·S*_xy, and
``steady_average`` = 0 for a run whose values are not means over a settled motion
(transient, unstable, unclassified). The file follows CF-1.10: text variables are
written as char arrays, categorical values as flag variables (flag_values, flag_meanings).
"""

from __future__ import annotations

import json
import os
from collections.abc import Iterator, Mapping
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

import numpy as np
import xarray as xr

from capsim._version import __version__
from capsim.campaigns.campaign import CAMPAIGN_FILE, INDEX_FILE, canonical_field, expand_campaign, load_campaign, load_index
from capsim.config import Case, ConfigError
from capsim.errors import bounded_repr
from capsim.quantities import (FLAGS, SETTLED_MOTIONS, TABLE, TURNING_MOTIONS, UNIT_SYSTEMS, attrs_for, case_field_attrs,
                               global_attrs, physical_attrs)
from capsim.storage.store import case_from_trajectory, read_run_digest, read_run_record, read_run_status

__all__ = ["SUMMARY_ATTRS", "read_run", "read_run_status", "summarize_campaign", "text_encoding", "write_summary"]

_FLOATS = ("D_xy", "theta", "ttf_ratio", "Sxy_star", "N1_star", "N2_star",
           "D_xy_std", "theta_std", "ttf_ratio_std", "Sxy_star_std", "N1_star_std", "N2_star_std",
           "wall_time_s", "volume_drift", "compressed_fraction", "min_tension",
           # the motion and the window the values are means over
           "period", "D_xy_amplitude", "theta_amplitude", "averaging_t_from", "averaging_t_to",
           "intrinsic_viscosity", "intrinsic_viscosity_std",
           # the director's orbit (issue 26)
           "orbit_period", "orbit_constant", "orbit_constant_first", "orbit_constant_drift", "final_polar_angle",
           # the classifier's evidence and the rotations told apart (issue 39)
           "settled", "orbit_constant_change", "orbit_period_change", "orbits_averaged", "shape_period",
           "body_rotation_ratio", "tank_treading_ratio", "rigid_turn", "ttf_ratio_kind",
           # lift (or migration) and slip of the centroid (issues 41, 42)
           "centroid_velocity_y", "centroid_velocity_y_std", "slip_velocity_x", "slip_velocity_x_std",
           "dissipation_ratio", "dissipation_ratio_std",
           # several capsules (issue 43): the closest approach and a pair's relative trajectory (_SCENE_FLOATS)
           "min_capsule_gap", "separation_y_initial", "separation_y_peak", "separation_y_final", "separation_x_final",
           "D_xy_error_estimate", "theta_error_estimate", "ttf_ratio_error_estimate", "Sxy_star_error_estimate",
           # a measured accuracy target (capsim.runs.ladder): met 1, not met 0, none NaN
           "accuracy_target_met",
           # a capsule in a conduit (issue 53, _CONDUIT_FLOATS): its speed over U, ΔP+, migration, lengths
           "centroid_velocity_x", "centroid_velocity_x_std", "extra_pressure_drop", "extra_pressure_drop_std",
           "axis_offset", "axis_offset_std", "length_along", "length_along_std", "width_across", "width_across_std",
           # a wall's gap and the migration across the flow, start to end (issue 54, _DRIFT_FLOATS)
           "wall_gap_initial", "wall_gap_final", "wall_gap_min", "centroid_y_initial", "centroid_y_final",
           "migration_y")
_STRINGS = ("status", "status_reason", "motion")
#: the numbers only a scene of several capsules has: left out of a campaign none of whose runs has them
_SCENE_FLOATS = frozenset({"min_capsule_gap", "separation_y_initial", "separation_y_peak", "separation_y_final",
                           "separation_x_final"})
#: the numbers only a run in a conduit has: left out of a campaign none of whose runs has them
_CONDUIT_FLOATS = frozenset({"centroid_velocity_x", "centroid_velocity_x_std", "extra_pressure_drop",
                             "extra_pressure_drop_std", "axis_offset", "axis_offset_std", "length_along",
                             "length_along_std", "width_across", "width_across_std"})
#: the numbers of a wall's gap and of the migration: left out of a campaign none of whose runs has them (no wall;
#: run files written before issue 54)
_DRIFT_FLOATS = frozenset({"wall_gap_initial", "wall_gap_final", "wall_gap_min", "centroid_y_initial",
                           "centroid_y_final", "migration_y"})
#: the context of a run from its resolved case: name -> (dtype, value for a run without a case)
_CONTEXT = {"level": (np.int64, -1), "mesh_base": (np.int8, -1), "law": (object, ""),
            "skalak_c": (np.float64, np.nan), "psi": (np.float64, np.nan), "bending_modulus": (np.float64, np.nan),
            "time_scheme": (np.int8, -1), "rtol": (np.float64, np.nan), "steady_average": (np.int8, 0)}
#: motions whose window means are settled values
_SETTLED = frozenset(SETTLED_MOTIONS)  # old names too (oscillating): old files read as they were
#: settled motions whose in-plane long axis turns round and round: no mean inclination (run
#: files written before issue 30 still hold the folded mean)
_TURNING = TURNING_MOTIONS

_WHERE = "campaign"  # the qualified entries of capsim.quantities for this file


class _SummaryAttrs(Mapping):
    """The attributes of a summary variable, by name, from :mod:`capsim.quantities`."""

    def __getitem__(self, name: str) -> dict[str, str]:
        return attrs_for(name, _WHERE)

    def __iter__(self) -> Iterator[str]:
        names = {key.split("/", 1)[1] if key.startswith(f"{_WHERE}/") else key for key in TABLE}
        return iter(sorted(n for n in names if "/" not in n))

    def __len__(self) -> int:
        return sum(1 for _ in self)


#: Read-only view of the quantity table as the summary resolves it (``SUMMARY_ATTRS["D_xy"]``).
SUMMARY_ATTRS: Mapping[str, dict[str, str]] = _SummaryAttrs()


def read_run(path: str | os.PathLike) -> dict[str, Any] | None:
    """The summary record of one run file, or None when there is no readable file."""
    found = read_run_record(path)
    if found is None:
        return None
    attrs, summary, run, last = found["attrs"], found["summary"], found["run"], found["last"]
    n = found["n_steps"]
    record: dict[str, Any] = {
        "status": str(attrs.get("status", "")),
        "status_reason": str(attrs.get("status_reason", "")),
        "motion": str(summary.get("motion", "")),
    }
    estimate = found.get("error_estimate", {})
    if not _estimate_of_this_end(estimate, last):
        estimate = {}  # of an earlier end (a file extended before issue 38): not of these values
    for name in _FLOATS:
        if name.endswith("_error_estimate"):  # of the window mean, else of the value at t_end
            q = name[: -len("_error_estimate")]
            value = estimate.get(f"{q}_mean", estimate.get(q, np.nan))
        else:
            value = summary.get(name, run.get(name, last.get(name, np.nan)))
        record[name] = float(value) if isinstance(value, (int, float)) else np.nan
    met = found.get("accuracy", {}).get("met")
    record["accuracy_target_met"] = float(bool(met)) if met is not None else np.nan
    if np.isnan(record["volume_drift"]) and "volume" in last:
        record["volume_drift"] = last["volume"] / found["first"]["volume"] - 1.0
    # [μ] = (5/2) S*_xy: μ_eff = μ (1 + φ [μ]) for a dilute suspension of volume fraction φ
    record["intrinsic_viscosity"] = 2.5 * record["Sxy_star"]
    record["intrinsic_viscosity_std"] = 2.5 * record["Sxy_star_std"]
    steps = summary.get("steps", run.get("steps", n - 1 if n else -1))
    record["steps"] = int(steps)
    # the classifier's own verdict where the file has it (issue 39: the last whole orbits agree), else its class
    settled = record["settled"] == 1.0 if np.isfinite(record["settled"]) else record["motion"] in _SETTLED
    record["steady_average"] = int(record["status"] == "completed" and settled)
    if record["motion"] in _TURNING:
        # the long axis turns through every angle: a mean of θ over whole periods is no property
        # of the motion (and its spread the whole range), so θ has no settled value
        for name in ("theta", "theta_std", "theta_error_estimate"):
            record[name] = np.nan
    try:
        case = case_from_trajectory({"attrs": attrs})
    except Exception:  # no or an unreadable config_yaml: the context stays unknown
        case = None
    if case is not None:
        record.update(_context(case))
        used = str(attrs.get("time_scheme_used", ""))
        if used in FLAGS["time_scheme"]:  # the scheme that ran (auto's choice), not the one asked for
            record["time_scheme"] = _flag("time_scheme", used)
    return record


def _estimate_of_this_end(estimate: dict[str, Any], last: dict[str, float]) -> bool:
    """Whether an error estimate was made of the run as it ends now: it keeps each quantity's
    value at its t_end (``<q>_value``, the trajectory's last row when it was made), which is
    the last row still unless the run was extended since (θ is stored unwrapped: not compared)."""
    for q in ("D_xy", "ttf_ratio", "Sxy_star"):
        then, now = estimate.get(f"{q}_value"), last.get(q)
        if isinstance(then, float) and isinstance(now, float) and not (then == now or (then != then and now != now)):
            return False
    return True


def _flag(name: str, value: str) -> int:
    return FLAGS[name].index(value)


def _context(case: Case) -> dict[str, Any]:
    """What a reader needs to trust a run's numbers, from its resolved case."""
    m = case.membrane
    return {
        "level": case.mesh.level, "mesh_base": _flag("mesh_base", case.mesh.base), "law": m.law,
        "skalak_c": m.skalak_c if m.law == "skalak" else np.nan,
        "psi": m.psi if m.law == "mooney_rivlin" else np.nan,
        "bending_modulus": m.bending_modulus,
        "time_scheme": _flag("time_scheme", case.time.scheme), "rtol": case.time.rtol,
    }


def _dim_names(keys: list[str]) -> dict[str, str]:
    """Last dotted component (`shear_rate_G`), or the whole path with '_' when two clash; of the
    field's full name (a sweep of flow.G is a shear_rate_G dimension, as its runs are)."""
    full = [canonical_field(key) for key in keys]
    short = [key.rsplit(".", 1)[-1] for key in full]
    return {key: f.replace(".", "_") if short.count(s) > 1 else s for key, f, s in zip(keys, full, short)}


def _attrs_for(name: str, dotted: str | None = None) -> dict[str, Any]:
    """Attributes of a variable (`name`) or of the coordinate of case field `dotted`;
    a categorical one also gets CF's flag_values and flag_meanings."""
    if dotted is not None:
        return dict(case_field_attrs(canonical_field(dotted)), case_field=dotted)  # the name the campaign sweeps
    attrs: dict[str, Any] = attrs_for(name, _WHERE)
    if name in FLAGS:
        attrs["flag_values"] = np.arange(len(FLAGS[name]), dtype=np.int8)
        attrs["flag_meanings"] = " ".join(FLAGS[name])
    return attrs


def _coordinate(name: str, dotted: str, values: list) -> tuple:
    """(dim, values, attrs) of a swept case field. A vector-valued field (initial_axis)
    cannot be a CF coordinate: its coordinate is the index of each value, 0, 1, …, and
    the attribute ``case_field_values`` lists the values in that order."""
    attrs = _attrs_for(name, dotted)
    if any(isinstance(v, (list, tuple)) for v in values):
        attrs = dict(attrs, case_field_values="; ".join(json.dumps(list(v)) for v in values),
                     long_name=f"index of the swept {dotted}")
        return name, np.arange(len(values), dtype=np.int64), attrs
    kind = dotted.split(".", 1)[1] if dotted.startswith("physical.") else None
    if kind is not None and all(isinstance(v, str) for v in values):
        # a swept physical value ('50 1/s'): the coordinate is its SI magnitude, so that it
        # sorts and plots as a number; the texts as given are kept beside it
        from capsim.units import KINDS, parse

        unit, what, _ = KINDS[kind]
        attrs = dict(attrs, units=unit, long_name=f"{kind.replace('_', ' ')} ({what}, SI)",
                     case_field_values="; ".join(values))
        return name, np.array([parse(v, kind) for v in values], dtype=np.float64), attrs
    return name, np.asarray(values), attrs


def summarize_campaign(directory: str | os.PathLike, units: str = "capsim") -> xr.Dataset:
    """One Dataset for a campaign directory written by ``capsim sweep``; with ``units="physical"``
    every variable that has a capsim scale (:mod:`capsim.quantities`) is in physical units
    (:func:`to_physical`)."""
    if not isinstance(units, str) or units not in UNIT_SYSTEMS:
        raise ConfigError(f"units = {bounded_repr(units)}: allowed: {', '.join(UNIT_SYSTEMS)}")
    if not isinstance(directory, (str, os.PathLike)):
        raise ConfigError(f"directory = {bounded_repr(directory)}: a path to a campaign's output directory is "
                          "expected")
    directory = Path(directory)
    if not directory.exists():
        raise ConfigError(f"{directory}: no such directory (a campaign's output directory is expected)")
    if not directory.is_dir():
        raise ConfigError(f"{directory}: a directory of run files (a campaign's output.dir, written by capsim "
                          "sweep) is expected, got a file")
    if not (directory / CAMPAIGN_FILE).exists() or not (directory / INDEX_FILE).exists():
        raise ConfigError(f"{directory}: not a campaign directory (no {CAMPAIGN_FILE} or {INDEX_FILE}: capsim "
                          "sweep writes them)")
    campaign = load_campaign(directory / CAMPAIGN_FILE)
    index = load_index(directory, campaign)  # a damaged runs.json: rebuilt from the run files
    if campaign.is_grid and campaign.sweep:
        keys = list(campaign.sweep)
        names = _dim_names(keys)
        dims = tuple(names[k] for k in keys)
        shape = tuple(len(v) for v in campaign.sweep.values())
        coords = {names[k]: _coordinate(names[k], k, campaign.sweep[k]) for k in keys}
    else:
        keys = list(campaign.sweep) + list(campaign.zip)
        names = _dim_names(keys)
        dims, shape = ("run",), (len(index),)
        coords = {"run": ("run", np.asarray(list(index), dtype=object), _attrs_for("run_id"))}
        for k in keys:
            values = [entry["params"][k] for entry in index.values()]
            coords[names[k]] = ("run",) + _coordinate(names[k], k, values)[1:]

    data: dict[str, np.ndarray] = {name: np.full(shape, np.nan) for name in _FLOATS}
    data.update({name: np.full(shape, "", dtype=object) for name in _STRINGS})
    data["steps"] = np.full(shape, -1, dtype=np.int64)
    # the context, unless swept (then it is a coordinate already); from the campaign for a missing run
    context = {name: np.full(shape, fill, dtype=dtype) for name, (dtype, fill) in _CONTEXT.items()
               if name not in coords}
    data.update(context)
    planned = {spec.run_id: spec for spec in expand_campaign(campaign)}
    data["status"][...] = "missing"
    if dims != ("run",):
        data["run_id"] = np.full(shape, "", dtype=object)
    for i, (run_id, entry) in enumerate(index.items()):
        at = tuple(entry["grid_index"]) if dims != ("run",) else (i,)
        if "run_id" in data:
            data["run_id"][at] = run_id
        record = read_run(directory / entry["file"])
        # a run file of another case at this run's path is not this run's result
        foreign = (record is not None and run_id in planned
                   and read_run_digest(directory / entry["file"]) != planned[run_id].digest())
        if foreign:
            record = None
        if run_id in planned and (record is None or "level" not in record):
            for name, value in _context(planned[run_id].case()).items():
                if name in context:
                    context[name][at] = value
        if foreign:
            data["status"][at] = "foreign"
            data["status_reason"][at] = f"{entry['file']} holds the run file of another case"
            continue
        if record is None:
            if entry.get("status") not in (None, "pending", "completed"):
                data["status"][at] = entry["status"]
                data["status_reason"][at] = entry.get("status_reason", "")
            continue
        for name, value in record.items():
            if name in data:
                data[name][at] = value

    ds = xr.Dataset(
        {name: (dims, values, _attrs_for(name)) for name, values in data.items()
         if not (name in (_SCENE_FLOATS | _CONDUIT_FLOATS | _DRIFT_FLOATS) and np.isnan(values).all())},
        coords=coords,
    )
    if units == "physical":
        ds = to_physical(ds, _physical_factors(index, planned, dims, shape))
    ds.attrs = {
        **global_attrs(f"capsim campaign {campaign.name}"),
        "capsim_version": __version__,
        "created": datetime.now(timezone.utc).isoformat(timespec="seconds"),
        "campaign_name": campaign.name,
        "campaign_yaml": campaign.to_yaml(),
    }
    if units == "physical":
        ds.attrs["capsim_units"] = ("physical: every variable with a capsim scale is that value times its scale from "
                                    "the run's physical block, in the units it names; the coordinates are the swept "
                                    "case values as given")
    return ds


def _physical_factors(index: dict, planned: dict, dims: tuple, shape: tuple) -> dict[str, np.ndarray]:
    """Per run, the factor of each capsim scale from its case's physical block (they differ
    between runs of a sweep over physical.*); a campaign without one: NoPhysicalBlock."""
    from capsim.quantities import SCALE_UNITS
    from capsim.units import factors_for

    out = {scale: np.full(shape, np.nan) for scale in SCALE_UNITS}
    for i, run_id in enumerate(index):
        if run_id not in planned:
            continue  # an old entry of the index: its values are NaN anyway
        at = tuple(index[run_id]["grid_index"]) if dims != ("run",) else (i,)
        for scale, factor in factors_for(planned[run_id].case(), f"run {run_id}").items():
            out[scale][at] = factor
    return out


def to_physical(ds: xr.Dataset, factors: dict[str, np.ndarray]) -> xr.Dataset:
    """`ds` with each data variable that has a capsim scale times that scale's factor (an array
    over the runs, or a number) and the attributes of :func:`capsim.quantities.physical_attrs`:
    the unit is the table's, never spelled here."""
    ds = ds.copy()
    for name, var in ds.data_vars.items():
        scale = var.attrs.get("scale")
        if scale not in factors:
            continue
        attrs = {**var.attrs, **physical_attrs(name, _WHERE)}
        attrs.pop("scale", None)
        ds[name] = var * factors[scale]
        ds[name].attrs = attrs
    return ds


def text_encoding(ds: xr.Dataset) -> dict[str, dict[str, str]]:
    """Text variables (and coordinates) as netCDF char arrays (CF; checkers read no
    variable-length strings); xarray reads them back as strings."""
    return {name: {"dtype": "S1"} for name, var in ds.variables.items() if var.dtype.kind in "OU"}


def write_summary(ds: xr.Dataset, path: str | os.PathLike) -> Path:
    """Write with the netCDF4 engine; text as char arrays (:func:`text_encoding`); the text
    ``run`` coordinate of a zip campaign as the auxiliary coordinate ``run_id``."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    if "run" in ds.coords and ds["run"].dtype.kind in "OU":
        # CF: a coordinate variable (named as its dimension) is numeric and monotonic; the run ids
        # of a zip campaign are an auxiliary coordinate run_id(run) instead
        ds = ds.rename_vars({"run": "run_id"})
    ds.to_netcdf(path, engine="netcdf4", encoding=text_encoding(ds))
    return path


def summarize_to_file(directory: str | os.PathLike, output: str | os.PathLike | None = None, *,
                      overwrite: bool = False, units: str = "capsim"):
    """`capsim summarize`: the campaign in `directory` summarised into `output` (default
    DIR/summary.nc) through the output guards (never over the campaign's own files or
    one of its runs; another file than a summary only with `overwrite`) and a temporary
    file renamed into place. Returns (path, Dataset)."""
    from capsim.storage.files import (
        CAMPAIGN_FILE, INDEX_FILE, check_writable, guard_output, is_run_file, is_summary_file, replace_atomically,
    )

    directory = Path(directory)
    ds = summarize_campaign(directory, units)
    path = Path(output) if output is not None else directory / "summary.nc"
    check_writable(path)
    inputs = [directory / CAMPAIGN_FILE, directory / INDEX_FILE]
    if path.exists() and path.resolve().parent == directory.resolve() and is_run_file(path):
        inputs.append(path)  # one of the campaign's runs
    guard_output(path, inputs, overwrite, ours=is_summary_file)
    replace_atomically(path, lambda tmp: write_summary(ds, tmp))
    return path, ds

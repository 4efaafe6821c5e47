"""A campaign directory → one xarray Dataset → netCDF.

Each run file contributes one record: its status, and the steady-state
observables of its ``summary`` group when present; otherwise the ``run`` group
and the last row of the time series, with NaN (or "") for what the file does
not hold. Swept fields become dimensions (a ``run`` dimension when the runs are
not a full grid). Units, long names and definitions come from the one table
:data:`SUMMARY_ATTRS`.
"""

from __future__ import annotations

import os
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

import h5py
import numpy as np
import xarray as xr

from capsim import __version__

__all__ = ["SUMMARY_ATTRS", "read_run", "read_run_status", "summarize_campaign", "write_summary"]

_STEADY = "at the end of the run (mean over the steady window when the run reports one)"
_STRESSLET = "particle stresslet S = ∫ [Δf x − μ(1−λ)(u n + n u)] dS divided by the rigid-sphere value (5/2) μ k V"

# One table: every variable and coordinate of the summary. Scaling as in
# design.md: lengths by a, time by 1/k, tension by E_s.
SUMMARY_ATTRS: dict[str, dict[str, str]] = {
    "D_xy": {"long_name": "Taylor deformation parameter in the xy-plane", "units": "1",
             "definition": f"(L − B)/(L + B), L and B the longest and shortest semi-axes in the xy-plane "
                           f"of the equivalent ellipsoid (same inertia tensor), {_STEADY}"},
    "theta": {"long_name": "inclination of the long axis", "units": "rad",
              "definition": f"angle from the x-axis (flow direction) to the long axis in the xy-plane, {_STEADY}"},
    "ttf_ratio": {"long_name": "normalised tank-treading frequency", "units": "1",
                  "definition": "f / f_s, f the frequency at which a material node circles the centroid in "
                                "the xy-plane, f_s = k/(4π) the rotation frequency of a rigid sphere"},
    "Sxy_star": {"long_name": "normalised particle shear stress", "units": "1",
                 "definition": f"S_xy / ((5/2) μ k V), {_STRESSLET}"},
    "N1_star": {"long_name": "normalised first normal stress difference", "units": "1",
                "definition": f"(S_xx − S_yy) / ((5/2) μ k V), {_STRESSLET}"},
    "N2_star": {"long_name": "normalised second normal stress difference", "units": "1",
                "definition": f"(S_yy − S_zz) / ((5/2) μ k V), {_STRESSLET}"},
    "status": {"long_name": "final status of the run", "units": "",
               "definition": "completed, unstable, interrupted or failed as recorded in the run file; "
                             "missing when the run has no readable file"},
    "status_reason": {"long_name": "why the run stopped", "units": "", "definition": "one line from the run"},
    "motion": {"long_name": "class of steady motion", "units": "",
               "definition": "as classified by the run: steady, oscillating, tumbling, transient "
                             "or unstable; empty when the run did not classify it"},
    "steps": {"long_name": "accepted time steps", "units": "1",
              "definition": "number of accepted RKF23 steps; -1 when the run has no file"},
    "wall_time_s": {"long_name": "wall-clock time of the run", "units": "s",
                    "definition": "elapsed time of run_case, mesh construction included"},
    "volume_drift": {"long_name": "relative volume change", "units": "1",
                     "definition": "(V − V0)/V0 at the end of the run; V the enclosed volume"},
    "compressed_fraction": {"long_name": "fraction of the membrane in compression", "units": "1",
                            "definition": "share of vertices whose smaller principal tension is negative at the "
                                          "end of the run; a membrane without bending stiffness would wrinkle there"},
    "min_tension": {"long_name": "smallest principal membrane tension", "units": "mu k a",
                    "definition": "minimum over the vertices of the smaller principal tension at the end of "
                                  "the run, divided by G (tension in units of mu k a)"},
    "run_id": {"long_name": "run identifier", "units": "",
               "definition": "readable swept values and a hash of the resolved case; the run file is <run_id>.h5"},
    # coordinates (swept case fields)
    "shear_rate_G": {"long_name": "dimensionless shear rate G", "units": "1",
                     "definition": "G = μ k a / E_s, μ the outer viscosity, k the shear rate, a the "
                                   "equal-volume radius, E_s the membrane elastic modulus"},
    "viscosity_ratio": {"long_name": "viscosity ratio λ", "units": "1",
                        "definition": "λ = μ_inside / μ_outside"},
    "initial_tilt_deg": {"long_name": "initial tilt of the rest shape", "units": "degree",
                         "definition": "rotation of the rest shape about the z-axis at t = 0"},
    "aspect_ratio": {"long_name": "rest-shape aspect ratio", "units": "1",
                     "definition": "polar / equatorial axis of the rest spheroid"},
    "level": {"long_name": "mesh subdivision level", "units": "1",
              "definition": "subdivisions of the base polyhedron"},
    "law": {"long_name": "membrane constitutive law", "units": "", "definition": "see design.md, 'Laws'"},
}

for _name in ("D_xy", "theta", "ttf_ratio", "Sxy_star", "N1_star", "N2_star"):
    _base = SUMMARY_ATTRS[_name]
    SUMMARY_ATTRS[f"{_name}_std"] = {
        "long_name": f"standard deviation of the {_base['long_name']}",
        "units": _base["units"],
        "definition": f"standard deviation of {_name} over the steady window; NaN when not reported",
    }

_FLOATS = ("D_xy", "theta", "ttf_ratio", "Sxy_star", "N1_star", "N2_star",
           "D_xy_std", "theta_std", "ttf_ratio_std", "Sxy_star_std", "N1_star_std", "N2_star_std",
           "wall_time_s", "volume_drift", "compressed_fraction", "min_tension")
_STRINGS = ("status", "status_reason", "motion")


def _scalar(value: Any) -> Any:
    if isinstance(value, bytes):
        return value.decode("utf-8")
    if isinstance(value, np.ndarray) and value.shape == ():
        value = value[()]
    if isinstance(value, np.generic):
        return value.item()
    return value


def _group(f: h5py.File, name: str) -> dict[str, Any]:
    if name not in f or not isinstance(f[name], h5py.Group):
        return {}
    out = {}
    for key, ds in f[name].items():
        if isinstance(ds, h5py.Dataset) and ds.shape == ():
            out[key] = ds.asstr()[()] if h5py.check_string_dtype(ds.dtype) else _scalar(ds[()])
    return out


def read_run_status(path: str | os.PathLike) -> str | None:
    """The status attribute of a run file; None when there is no readable file."""
    try:
        with h5py.File(path, "r", locking=False) as f:
            return str(_scalar(f.attrs.get("status", "")))
    except (OSError, ValueError):
        return None


def read_run(path: str | os.PathLike) -> dict[str, Any] | None:
    """The summary record of one run file, or None when there is no readable file."""
    try:
        with h5py.File(path, "r", locking=False) as f:
            attrs = {k: _scalar(v) for k, v in f.attrs.items()}
            summary, run = _group(f, "summary"), _group(f, "run")
            ts = f["timeseries"] if "timeseries" in f else {}
            n = min((len(ds) for ds in ts.values()), default=0)
            last = {k: float(ds[n - 1]) for k, ds in ts.items()} if n else {}
            first_volume = float(ts["volume"][0]) if n and "volume" in ts else np.nan
    except (OSError, ValueError, KeyError):
        return None
    record: dict[str, Any] = {
        "status": str(attrs.get("status", "")),
        "status_reason": str(attrs.get("status_reason", "")),
        "motion": str(summary.get("motion", "")),
    }
    for name in _FLOATS:
        value = summary.get(name, run.get(name, last.get(name, np.nan)))
        record[name] = float(value) if isinstance(value, (int, float)) else np.nan
    if np.isnan(record["volume_drift"]) and "volume" in last:
        record["volume_drift"] = last["volume"] / first_volume - 1.0
    steps = summary.get("steps", run.get("steps", n - 1 if n else -1))
    record["steps"] = int(steps)
    return record


def _dim_names(keys: list[str]) -> dict[str, str]:
    """Last dotted component (`shear_rate_G`), or the whole path with '_' when two clash."""
    short = [key.rsplit(".", 1)[-1] for key in keys]
    return {key: key.replace(".", "_") if short.count(s) > 1 else s for key, s in zip(keys, short)}


def _attrs_for(name: str, dotted: str | None = None) -> dict[str, str]:
    found = SUMMARY_ATTRS.get(name)
    if found is None and dotted is not None:
        found = SUMMARY_ATTRS.get(dotted.rsplit(".", 1)[-1])
    if found is None:
        return {"long_name": dotted or name, "units": "", "definition": f"case field {dotted or name}"}
    return dict(found, **({"case_field": dotted} if dotted else {}))


def summarize_campaign(directory: str | os.PathLike) -> xr.Dataset:
    """One Dataset for a campaign directory written by ``capsim sweep``."""
    from capsim.campaign import CAMPAIGN_FILE, INDEX_FILE, load_campaign, load_index

    directory = Path(directory)
    if not (directory / CAMPAIGN_FILE).exists() or not (directory / INDEX_FILE).exists():
        raise FileNotFoundError(f"{directory}: not a campaign directory (no {CAMPAIGN_FILE} or {INDEX_FILE})")
    campaign = load_campaign(directory / CAMPAIGN_FILE)
    index = load_index(directory)
    if campaign.is_grid and campaign.sweep:
        keys = list(campaign.sweep)
        names = _dim_names(keys)
        dims = tuple(names[k] for k in keys)
        shape = tuple(len(v) for v in campaign.sweep.values())
        coords = {names[k]: (names[k], np.asarray(campaign.sweep[k]), _attrs_for(names[k], k)) for k in keys}
    else:
        keys = list(campaign.sweep) + list(campaign.zip)
        names = _dim_names(keys)
        dims, shape = ("run",), (len(index),)
        coords = {"run": ("run", np.asarray(list(index), dtype=object), _attrs_for("run_id"))}
        for k in keys:
            values = [entry["params"][k] for entry in index.values()]
            coords[names[k]] = ("run", np.asarray(values), _attrs_for(names[k], k))

    data: dict[str, np.ndarray] = {name: np.full(shape, np.nan) for name in _FLOATS}
    data.update({name: np.full(shape, "", dtype=object) for name in _STRINGS})
    data["steps"] = np.full(shape, -1, dtype=np.int64)
    data["status"][...] = "missing"
    if dims != ("run",):
        data["run_id"] = np.full(shape, "", dtype=object)
    for i, (run_id, entry) in enumerate(index.items()):
        at = tuple(entry["grid_index"]) if dims != ("run",) else (i,)
        if "run_id" in data:
            data["run_id"][at] = run_id
        record = read_run(directory / entry["file"])
        if record is None:
            if entry.get("status") not in (None, "pending", "completed"):
                data["status"][at] = entry["status"]
                data["status_reason"][at] = entry.get("status_reason", "")
            continue
        for name, value in record.items():
            data[name][at] = value

    ds = xr.Dataset(
        {name: (dims, values, _attrs_for(name)) for name, values in data.items()},
        coords=coords,
    )
    ds.attrs = {
        "title": f"capsim campaign {campaign.name}",
        "capsim_version": __version__,
        "created": datetime.now(timezone.utc).isoformat(timespec="seconds"),
        "campaign_name": campaign.name,
        "campaign_yaml": campaign.to_yaml(),
    }
    return ds


def write_summary(ds: xr.Dataset, path: str | os.PathLike) -> Path:
    """Write with the netCDF4 engine; strings as variable-length strings."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    ds.to_netcdf(path, engine="netcdf4")
    return path

"""A campaign directory → one xarray Dataset → netCDF.

Each run file contributes one record: its status, and the steady-state
observables of its ``summary`` group when present; otherwise the ``run`` group
and the last row of the time series, with NaN (or "") for what the file does
not hold. Swept fields become dimensions (a ``run`` dimension when the runs are
not a full grid). The run files are read through :mod:`capsim.store`; units,
long names and definitions come from the one table :mod:`capsim.quantities`.
"""

from __future__ import annotations

import os
from collections.abc import Iterator, Mapping
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

import numpy as np
import xarray as xr

from capsim import __version__
from capsim.campaign import CAMPAIGN_FILE, INDEX_FILE, load_campaign, load_index
from capsim.quantities import TABLE, attrs_for, case_field_attrs
from capsim.store import read_run_record, read_run_status

__all__ = ["SUMMARY_ATTRS", "read_run", "read_run_status", "summarize_campaign", "write_summary"]

_FLOATS = ("D_xy", "theta", "ttf_ratio", "Sxy_star", "N1_star", "N2_star",
           "D_xy_std", "theta_std", "ttf_ratio_std", "Sxy_star_std", "N1_star_std", "N2_star_std",
           "wall_time_s", "volume_drift", "compressed_fraction", "min_tension")
_STRINGS = ("status", "status_reason", "motion")

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
    for name in _FLOATS:
        value = summary.get(name, run.get(name, last.get(name, np.nan)))
        record[name] = float(value) if isinstance(value, (int, float)) else np.nan
    if np.isnan(record["volume_drift"]) and "volume" in last:
        record["volume_drift"] = last["volume"] / found["first"]["volume"] - 1.0
    steps = summary.get("steps", run.get("steps", n - 1 if n else -1))
    record["steps"] = int(steps)
    return record


def _dim_names(keys: list[str]) -> dict[str, str]:
    """Last dotted component (`shear_rate_G`), or the whole path with '_' when two clash."""
    short = [key.rsplit(".", 1)[-1] for key in keys]
    return {key: key.replace(".", "_") if short.count(s) > 1 else s for key, s in zip(keys, short)}


def _attrs_for(name: str, dotted: str | None = None) -> dict[str, str]:
    """Attributes of a variable (`name`) or of the coordinate of case field `dotted`."""
    if dotted is not None:
        return case_field_attrs(dotted)
    return attrs_for(name, _WHERE)


def summarize_campaign(directory: str | os.PathLike) -> xr.Dataset:
    """One Dataset for a campaign directory written by ``capsim sweep``."""
    directory = Path(directory)
    if not (directory / CAMPAIGN_FILE).exists() or not (directory / INDEX_FILE).exists():
        raise FileNotFoundError(f"{directory}: not a campaign directory (no {CAMPAIGN_FILE} or {INDEX_FILE})")
    campaign = load_campaign(directory / CAMPAIGN_FILE)
    index = load_index(directory, campaign)  # a damaged runs.json: rebuilt from the run files
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

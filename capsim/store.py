"""HDF5 trajectory of one run, written incrementally so that a killed run
leaves a readable file.

Layout::

    /                    attrs: config_yaml, capsim_version, status, status_reason,
                                created, finished, and any run attrs
    /mesh/elements       (Ne, 6) int    6-node triangles (3 vertices, 3 mid-side nodes)
    /mesh/rest_positions (Np, 3)        node positions of the rest shape
    /mesh/positions      (n_snap, Np, 3) snapshots, one per chunk
    /mesh/snapshot_t     (n_snap,)      time of each snapshot (dimension scale)
    /timeseries/<name>   (n_steps,)     one value per accepted step, t as scale
    /<group>             e.g. summary: scalars, arrays and strings

Units and long names come from the one table :data:`VARIABLE_ATTRS`.
"""

from __future__ import annotations

import os
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

import h5py
import numpy as np

__all__ = [
    "STATUSES", "CheckpointError", "TrajectoryError", "TrajectoryWriter", "VARIABLE_ATTRS",
    "checkpoint_path", "read_checkpoint", "read_trajectory", "remove_checkpoint", "write_checkpoint",
]

STATUSES = frozenset({"completed", "unstable", "interrupted", "failed"})

# Scaling (design.md): lengths by a, time by 1/k, tension by E_s.
VARIABLE_ATTRS: dict[str, dict[str, str]] = {
    "t": {"units": "k^-1", "long_name": "time kt"},
    "dt": {"units": "k^-1", "long_name": "accepted time step"},
    "step": {"units": "1", "long_name": "step index"},
    "D_xy": {"units": "1", "long_name": "Taylor deformation (L-B)/(L+B) in the xy-plane"},
    "theta": {"units": "rad", "long_name": "inclination of the long axis from the x-axis"},
    "volume": {"units": "a^3", "long_name": "enclosed volume"},
    "area": {"units": "a^2", "long_name": "surface area"},
    "volume_drift": {"units": "1", "long_name": "relative volume change (V - V0)/V0"},
    "L": {"units": "a", "long_name": "longest semi-axis of the equivalent ellipsoid in xy"},
    "B": {"units": "a", "long_name": "shortest semi-axis of the equivalent ellipsoid in xy"},
    "ttf_ratio": {"units": "1", "long_name": "tank-treading frequency / rigid-sphere value k/(4 pi)"},
    "tt_angle": {"units": "rad", "long_name": "unwrapped mean angle about the centroid of the nodes starting in z = 0"},
    "Sxy_star": {"units": "1", "long_name": "particle stresslet S_xy / (5/2 mu k V)"},
    "N1_star": {"units": "1", "long_name": "first normal stress difference S_xx - S_yy, same scale"},
    "N2_star": {"units": "1", "long_name": "second normal stress difference S_yy - S_zz, same scale"},
    "motion": {"units": "", "long_name": "steady, oscillating, tumbling, transient or unstable"},
    "period": {"units": "k^-1", "long_name": "oscillation period, or rotation period (theta turning by 2 pi)"},
    "min_tension": {"units": "mu k a", "long_name": "smallest principal membrane tension over the vertices, tension / G"},
    "compressed_fraction": {"units": "1", "long_name": "fraction of vertices whose smaller principal tension is negative"},
    "error_estimate": {"units": "1", "long_name": "RKF23 local error estimate / rtol"},
    "solver_iterations": {"units": "1", "long_name": "iterations of the velocity solve"},
    "solver_residual": {"units": "1", "long_name": "relative residual of the velocity solve"},
    "positions": {"units": "a", "long_name": "node positions"},
    "snapshot_t": {"units": "k^-1", "long_name": "time of the snapshot"},
}

_STEP_FLUSH_EVERY = 20


class TrajectoryError(Exception):
    """A trajectory file that cannot be read; the message is one line naming it."""


class CheckpointError(Exception):
    """A restart checkpoint that is missing or cannot be read; one line naming it."""


def _now() -> str:
    return datetime.now(timezone.utc).isoformat(timespec="seconds")


def _label(ds: h5py.Dataset, name: str) -> None:
    for key, value in VARIABLE_ATTRS.get(name, {}).items():
        ds.attrs[key] = value


class TrajectoryWriter:
    """Append-only writer of one run's trajectory.

    Rows are buffered in memory and written to the file together on every
    flush: each ``append_snapshot``, ``write_group``, ``close`` and every
    ``_STEP_FLUSH_EVERY`` ``append_step`` calls (one resize per column per
    flush instead of per row: per-row HDF5 writes cost more than the physics of
    a level-3 step). A killed run keeps every row up to its last flush.
    Use as a context manager: an exception marks the file 'failed' (or
    'interrupted' for Ctrl-C) with the exception text, then propagates.
    """

    def __init__(
        self,
        path: str | os.PathLike,
        *,
        config_yaml: str,
        elements: np.ndarray,
        rest_positions: np.ndarray,
        version: str,
        attrs: dict[str, Any] | None = None,
    ) -> None:
        elements = np.asarray(elements)
        rest_positions = np.asarray(rest_positions, dtype=np.float64)
        if elements.ndim != 2 or elements.shape[1] != 6:
            raise ValueError(f"elements must have shape (Ne, 6), got {elements.shape}")
        if rest_positions.ndim != 2 or rest_positions.shape[1] != 3:
            raise ValueError(f"rest_positions must have shape (Np, 3), got {rest_positions.shape}")
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._n_nodes = rest_positions.shape[0]
        self._keys: tuple[str, ...] | None = None
        self._n_steps = 0
        self._n_snapshots = 0
        self._unflushed_steps = 0
        self._pending: list[list[float]] = []

        # Default libver on purpose: libver="latest" writes a superblock whose
        # "open for write" flag survives a SIGKILL and then refuses every reader.
        self._file = h5py.File(self.path, "w")
        f = self._file
        f.attrs["config_yaml"] = config_yaml
        f.attrs["capsim_version"] = version
        f.attrs["status"] = "running"
        f.attrs["status_reason"] = ""
        f.attrs["created"] = _now()
        for key, value in (attrs or {}).items():
            f.attrs[key] = value

        mesh = f.create_group("mesh")
        mesh.create_dataset("elements", data=elements.astype(np.int64))
        _label(mesh.create_dataset("rest_positions", data=rest_positions), "positions")
        self._positions = mesh.create_dataset(
            "positions",
            shape=(0, self._n_nodes, 3),
            maxshape=(None, self._n_nodes, 3),
            chunks=(1, self._n_nodes, 3),
            dtype=np.float64,
        )
        self._snapshot_t = mesh.create_dataset(
            "snapshot_t", shape=(0,), maxshape=(None,), chunks=(256,), dtype=np.float64
        )
        _label(self._positions, "positions")
        _label(self._snapshot_t, "snapshot_t")
        self._snapshot_t.make_scale("snapshot_t")
        self._positions.dims[0].attach_scale(self._snapshot_t)
        self._timeseries = f.create_group("timeseries")
        f.flush()

    @classmethod
    def reopen(cls, path: str | os.PathLike, n_steps: int, n_snapshots: int) -> TrajectoryWriter:
        """Reopen a trajectory to append to it, cut back to its first ``n_steps`` rows
        and ``n_snapshots`` snapshots (those of a checkpoint); status back to 'running'.

        The file is checked read-only first, so that a file too short or unreadable
        raises :class:`TrajectoryError` without being touched.
        """
        data = read_trajectory(path)
        have_steps = len(data["timeseries"].get("t", ()))
        have_snaps = len(data["snapshot_t"])
        if have_steps < n_steps or have_snaps < n_snapshots:
            raise TrajectoryError(
                f"{os.fspath(path)}: holds {have_steps} steps and {have_snaps} snapshots, "
                f"the checkpoint needs {n_steps} and {n_snapshots}"
            )
        self = cls.__new__(cls)
        self.path = Path(path)
        try:
            self._file = h5py.File(self.path, "a")
        except OSError as exc:
            first = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
            raise TrajectoryError(f"{self.path}: cannot reopen for appending: {first}") from None
        f = self._file
        mesh = f["mesh"]
        self._positions, self._snapshot_t = mesh["positions"], mesh["snapshot_t"]
        self._n_nodes = self._positions.shape[1]
        self._positions.resize((n_snapshots, self._n_nodes, 3))
        self._snapshot_t.resize((n_snapshots,))
        self._timeseries = f["timeseries"]
        self._keys = tuple(self._timeseries) or None
        for ds in self._timeseries.values():
            ds.resize((n_steps,))
        for name in ("summary", "run"):  # rewritten when the run ends
            if name in f:
                del f[name]
        self._n_steps, self._n_snapshots, self._unflushed_steps = n_steps, n_snapshots, 0
        self._pending = []
        f.attrs["status"] = "running"
        f.attrs["status_reason"] = ""
        f.attrs["resumed"] = _now()
        f.flush()
        return self

    def steps(self) -> dict[str, np.ndarray]:
        """Every time series written so far, one array per column."""
        self._write_pending()
        return {key: ds[: self._n_steps] for key, ds in self._timeseries.items()}

    # -- context manager -------------------------------------------------
    def __enter__(self) -> TrajectoryWriter:
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        if self.closed:
            return
        if exc is None:
            self.close("completed")
        elif isinstance(exc, KeyboardInterrupt):
            self.close("interrupted", "KeyboardInterrupt")
        else:
            self.close("failed", f"{type(exc).__name__}: {exc}")

    @property
    def closed(self) -> bool:
        return not self._file.id.valid

    # -- writing ---------------------------------------------------------
    def append_step(self, values: dict[str, float]) -> None:
        """Append one row; the keys of the first row fix the columns."""
        if self._keys is None:
            self._create_timeseries(tuple(values))
        elif set(values) != set(self._keys):
            new = sorted(set(values) - set(self._keys))
            gone = sorted(set(self._keys) - set(values))
            raise ValueError(
                f"append_step keys must match the first row: new {new}, missing {gone}"
            )
        self._pending.append([float(values[key]) for key in self._keys])
        self._n_steps += 1
        self._unflushed_steps += 1
        if self._unflushed_steps >= _STEP_FLUSH_EVERY:
            self.flush()

    def _write_pending(self) -> None:
        if not self._pending:
            return
        block = np.array(self._pending, dtype=np.float64)
        n = self._n_steps
        start = n - block.shape[0]
        for j, key in enumerate(self._keys):
            ds = self._timeseries[key]
            ds.resize((n,))
            ds[start:n] = block[:, j]
        self._pending = []

    def _create_timeseries(self, keys: tuple[str, ...]) -> None:
        if not keys:
            raise ValueError("append_step needs at least one value")
        for key in keys:
            ds = self._timeseries.create_dataset(
                key, shape=(0,), maxshape=(None,), chunks=(1024,), dtype=np.float64
            )
            _label(ds, key)
        if "t" in keys:
            t = self._timeseries["t"]
            t.make_scale("t")
            for key in keys:
                if key != "t":
                    self._timeseries[key].dims[0].attach_scale(t)
        self._keys = keys

    def append_snapshot(self, t: float, positions: np.ndarray) -> None:
        positions = np.asarray(positions, dtype=np.float64)
        if positions.shape != (self._n_nodes, 3):
            raise ValueError(
                f"positions must have shape ({self._n_nodes}, 3), got {positions.shape}"
            )
        n = self._n_snapshots + 1
        self._positions.resize((n, self._n_nodes, 3))
        self._positions[n - 1] = positions
        self._snapshot_t.resize((n,))
        self._snapshot_t[n - 1] = float(t)
        self._n_snapshots = n
        self.flush()

    def set_attrs(self, **attrs: Any) -> None:
        """Set root attributes (scalars, strings, small arrays)."""
        for key, value in attrs.items():
            self._file.attrs[key] = value
        self._file.flush()

    def write_group(self, name: str, data: dict[str, Any]) -> None:
        """Write (or replace) group `name` with scalars, arrays, strings or nested dicts."""
        if name in self._file:
            del self._file[name]
        _write_dict(self._file.create_group(name), data)
        self.flush()

    def flush(self) -> None:
        self._write_pending()
        self._file.flush()
        self._unflushed_steps = 0

    def close(self, status: str, reason: str = "") -> None:
        """Record the final status and close; a second call does nothing."""
        if status not in STATUSES:
            raise ValueError(f"status must be one of {sorted(STATUSES)}, got {status!r}")
        if self.closed:
            return
        self._write_pending()
        self._file.attrs["status"] = status
        self._file.attrs["status_reason"] = reason
        self._file.attrs["finished"] = _now()
        self._file.flush()
        self._file.close()


def _write_dict(group: h5py.Group, data: dict[str, Any]) -> None:
    for key, value in data.items():
        if isinstance(value, dict):
            _write_dict(group.create_group(key), value)
        elif value is None:
            raise TypeError(f"cannot store None for '{group.name}/{key}'")
        else:
            group.create_dataset(key, data=value)


# ---------------------------------------------------------------- checkpoints


def checkpoint_path(trajectory_path: str | os.PathLike) -> Path:
    """Where the restart checkpoint of a trajectory lives: ``<path>.ckpt.npz``."""
    return Path(os.fspath(trajectory_path) + ".ckpt.npz")


def write_checkpoint(path: str | os.PathLike, arrays: dict[str, Any]) -> None:
    """Write arrays and scalars to an .npz atomically: a killed writer leaves the
    previous checkpoint in place, never half of a new one."""
    path = Path(path)
    tmp = path.with_name(path.name + ".tmp")
    with open(tmp, "wb") as fh:
        np.savez(fh, **{key: np.asarray(value) for key, value in arrays.items()})
    os.replace(tmp, path)


def read_checkpoint(path: str | os.PathLike) -> dict[str, np.ndarray]:
    source = os.fspath(path)
    if not os.path.exists(source):
        raise CheckpointError(f"{source}: no checkpoint (nothing to resume)")
    try:
        with np.load(source, allow_pickle=False) as data:
            return {key: data[key] for key in data.files}
    except Exception as exc:  # zipfile, ValueError, OSError: all mean a damaged file
        first = str(exc).splitlines()[0] if str(exc) else ""
        raise CheckpointError(f"{source}: unreadable checkpoint: {type(exc).__name__}: {first}".rstrip(": ")) from None


def remove_checkpoint(path: str | os.PathLike) -> None:
    Path(path).unlink(missing_ok=True)
    Path(os.fspath(path) + ".tmp").unlink(missing_ok=True)


# ---------------------------------------------------------------- reading


def _decode(value: Any) -> Any:
    if isinstance(value, bytes):
        return value.decode("utf-8")
    if isinstance(value, np.generic):
        return value.item()
    return value


def _read_group(group: h5py.Group) -> dict[str, Any]:
    out: dict[str, Any] = {}
    for key, item in group.items():
        if isinstance(item, h5py.Group):
            out[key] = _read_group(item)
        elif h5py.check_string_dtype(item.dtype) is not None:
            out[key] = item.asstr()[()]
        elif item.shape == ():
            out[key] = _decode(item[()])
        else:
            out[key] = item[()]
    return out


def read_trajectory(path: str | os.PathLike) -> dict[str, Any]:
    """Read a whole trajectory into memory.

    Returns ``{"attrs", "timeseries", "elements", "rest_positions", "positions",
    "snapshot_t", "summary"}``. A file cut short by a killed run is read up to
    its last complete row (all time series trimmed to the same length).
    """
    source = os.fspath(path)
    if not os.path.exists(source):
        raise TrajectoryError(f"{source}: no such file")
    if os.path.isdir(source):
        raise TrajectoryError(f"{source}: is a directory, not a trajectory file")
    try:
        is_hdf5 = h5py.is_hdf5(source)
    except OSError as exc:
        raise TrajectoryError(f"{source}: cannot read: {exc}") from None
    if not is_hdf5:
        raise TrajectoryError(f"{source}: not an HDF5 file (empty, truncated or another format)")
    try:
        # No lock: a running (or killed) writer must not stop us from reading.
        with h5py.File(source, "r", locking=False) as f:
            return _read_open(f)
    except KeyError as exc:
        raise TrajectoryError(f"{source}: not a capsim trajectory (missing {exc})") from None
    except (OSError, RuntimeError, ValueError) as exc:
        first = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        raise TrajectoryError(f"{source}: unreadable HDF5 file (truncated or corrupt?): {first}") from None


def _read_open(f: h5py.File) -> dict[str, Any]:
    attrs = {key: _decode(value) for key, value in f.attrs.items()}
    mesh = f["mesh"]
    timeseries = {key: ds[()] for key, ds in f["timeseries"].items()}
    if timeseries:
        n = min(len(v) for v in timeseries.values())
        timeseries = {key: v[:n] for key, v in timeseries.items()}
    positions = mesh["positions"][()]
    snapshot_t = mesh["snapshot_t"][()]
    n_snap = min(len(positions), len(snapshot_t))
    return {
        "attrs": attrs,
        "timeseries": timeseries,
        "elements": mesh["elements"][()],
        "rest_positions": mesh["rest_positions"][()],
        "positions": positions[:n_snap],
        "snapshot_t": snapshot_t[:n_snap],
        "summary": _read_group(f["summary"]) if "summary" in f else {},
    }

"""The run file: every read and write of it (and of its restart checkpoint).

An HDF5 trajectory of one run, written incrementally so that a killed run
leaves a readable file.

Layout::

    /                    attrs: config_yaml, capsim_version, status, status_reason,
                                created, finished, and any run attrs; requested_case_yaml
                                where a measured accuracy target's ladder kept the run
    /mesh/elements       (Ne, 6) int    6-node triangles (3 vertices, 3 mid-side nodes)
    /mesh/rest_positions (Np, 3)        node positions of the rest shape
    /mesh/positions      (n_snap, Np, 3) snapshots, one per chunk
    /mesh/snapshot_t     (n_snap,)      time of each snapshot (dimension scale)
    /timeseries/<name>   (n_steps,)     one value per accepted step, t as scale
                         (n_steps, n_caps) several capsules: a per-capsule column, capsule as scale
    /membrane_law        the law, its parameters and moduli   (write_membrane_law)
    /rest_shape          measures of the rest shape           (write_rest_shape)
    /run                 the state at the end and the cost    (write_run_record)
    /summary             motion and window statistics         (write_summary)
    /error_estimate      capsim run --error-estimate          (write_error_estimate)
    /accuracy            a measured accuracy target's ladder  (write_accuracy)

Every dataset takes units, long_name and definition from the one table
:mod:`capsim.quantities`; every group its ``definition`` from
:data:`capsim.quantities.GROUPS`. Readers: :func:`read_trajectory` (all of it),
:func:`read_run_record` (the scalars a summary needs), :func:`read_run_status`,
:func:`read_case`.
"""

from __future__ import annotations

import contextlib
import itertools
import os
import shutil
import threading
import time
from datetime import datetime, timezone
from pathlib import Path
from typing import Any, Callable

import h5py
import numpy as np

from capsim.config import Case, case_from_dict, yaml_text
from capsim.errors import first_line
from capsim.storage.files import (
    FileIdentity, FileLock, LockedError, StorageError, copy_and_replace, free_bytes, lock_path, require_room,
    room_bytes,
)
from capsim.storage.checkpoint import (  # noqa: F401 - the checkpoint's names, as this module offered them
    CheckpointError, checkpoint_path, read_checkpoint, remove_checkpoint, write_checkpoint,
)
from capsim.storage.files import is_run_file  # noqa: F401 - part of this module's reading API
from capsim.storage.files import mb as _mb
from capsim.storage.files import tmp_name as _tmp_name
from capsim.storage.files import write_failure as _write_failure
from capsim.quantities import GROUPS, attrs_for, global_attrs

__all__ = [
    "STATUSES", "CheckpointError", "FileLock", "LockedError", "StorageError", "TrajectoryError", "TrajectoryWriter",
    "free_bytes", "is_run_file", "lock_path",
    "case_from_trajectory", "checkpoint_path", "guard_run_output", "mark_abandoned", "open_run", "read_case", "read_checkpoint", "read_run_record",
    "END_STATE", "read_end_state", "read_run_status", "read_trajectory", "remove_checkpoint", "write_checkpoint",
    "move_run", "write_accuracy", "write_error_estimate", "writer_of",
]

STATUSES = frozenset({"completed", "unstable", "interrupted", "failed"})
#: the root attribute of a run kept by a measured accuracy target's ladder: the case that asked
REQUESTED_CASE = "requested_case_yaml"
#: the root dataset holding a completed run's end state (what ``--resume --t-end`` extends)
END_STATE = "end_state"

#: the buffered rows are written every _STEP_FLUSH_EVERY steps once _FLUSH_INTERVAL_S has passed since
#: the last flush (or at _STEP_FLUSH_MAX rows, whatever the time): a slow run's rows reach the disk every
#: 20 steps, a fast one's once a second (a level-2 run flushed ~70 columns every 20 steps, 4 % of its time)
_STEP_FLUSH_EVERY = 20
_FLUSH_INTERVAL_S = 1.0
_STEP_FLUSH_MAX = 1000
#: free space ``--resume`` asks for beyond a copy of the run file (the cut is made on the copy)
RESUME_HEADROOM_BYTES = 16 * 2**20


class TrajectoryError(Exception):
    """A run file that cannot be read (missing, not a capsim run file, damaged, or being written
    by a running capsim process and not readable just then); the message is one line naming it."""


#: room a writer keeps free beyond the largest flush (a snapshot and a chunk of every column),
#: so that a run stopped by a full disk can still close its file with its status
WRITE_MARGIN_BYTES = 2**20


def _needed_bytes(n_nodes: int, columns: tuple[str, ...] | None) -> int:
    n_columns = len(columns or ())  # no columns yet: no chunk of them to allocate
    return WRITE_MARGIN_BYTES + 2 * (24 * n_nodes + 8 * 1024 * n_columns)


def _now() -> str:
    return datetime.now(timezone.utc).isoformat(timespec="seconds")


def _label(ds: h5py.Dataset, name: str, where: str | None = None) -> None:
    """Units, long_name, definition (and scale) of `name` from the quantity table.

    A name without an entry is written unlabelled rather than failing a run;
    tests/test_quantities.py catches it.
    """
    try:
        attrs = attrs_for(name, where)
    except KeyError:
        return
    set_text_attrs(ds, attrs)


#: a scalar dataspace and h5py's variable-length UTF-8 string type, as ``attrs[key] = "text"`` writes them
_SCALAR_SPACE = h5py.h5s.create(h5py.h5s.SCALAR)
_TEXT_TYPE = h5py.h5t.py_create(h5py.string_dtype("utf-8"), logical=True)
_TEXT_DTYPE = h5py.string_dtype("utf-8")


def _column_dcpl() -> h5py.h5p.PropDCID:
    """A time-series column's creation properties, as h5py's create_dataset makes them for
    chunks=(1024,) (an extendible float64 column)."""
    dcpl = h5py.h5p.create(h5py.h5p.DATASET_CREATE)
    dcpl.set_chunk((1024,))
    dcpl.set_fill_time(h5py.h5d.FILL_TIME_IFSET)
    dcpl.set_obj_track_times(False)
    return dcpl


_COLUMN_DCPL = _column_dcpl()


def set_text_attrs(obj: h5py.HLObject, attrs: dict[str, Any]) -> None:
    """``obj.attrs[key] = value`` for each item, the text and number ones through h5py's low-level calls:
    the same variable-length UTF-8 (or <f8, <i8) attribute, a third of the time (a run file's ~130 labelled datasets
    took ~45 ms at ~0.1 ms an attribute, a level-2 run's tenth)."""
    for key, value in attrs.items():
        number = _NUMBER_TYPES.get(type(value))  # a float or an int as h5py stores it (<f8, <i8)
        if not isinstance(value, str) and number is None:
            obj.attrs[key] = value
            continue
        name = key.encode("utf-8")
        if h5py.h5a.exists(obj.id, name):
            h5py.h5a.delete(obj.id, name)
        if number is None:
            h5py.h5a.create(obj.id, name, _TEXT_TYPE, _SCALAR_SPACE).write(np.array(value, dtype=_TEXT_DTYPE))
        else:
            data = np.array(value, dtype=number)
            h5py.h5a.create(obj.id, name, h5py.h5t.py_create(data.dtype), _SCALAR_SPACE).write(data)


def _describe(group: h5py.Group, name: str) -> None:
    if name in GROUPS:
        group.attrs["definition"] = GROUPS[name]


#: The dimension (and index coordinate) of the per-capsule columns of a scene of several capsules
CAPSULE_DIM = "capsule"

#: The NAME netCDF-4 gives a dimension scale that is a dimension only, not a variable
#: (netCDF-C, h5netcdf and xarray read such a dataset as the dimension alone).
_NOT_A_VARIABLE = b"This is a netCDF dimension but not a netCDF variable."


def _dimension(group: h5py.Group, name: str, size: int) -> h5py.Dataset:
    """The netCDF-4 dimension `name` (length `size`, no coordinate variable) of `group`."""
    if name in group:
        return group[name]
    ds = group.create_dataset(name, shape=(size,), dtype=">f4")
    ds.make_scale(_NOT_A_VARIABLE + f"{size:10d}".encode("ascii"))
    return ds


def _index(group: h5py.Group, name: str, size: int) -> h5py.Dataset:
    """The coordinate variable 0 … size-1 of dimension `name` (a labelled dimension scale)."""
    ds = group.create_dataset(name, data=np.arange(size, dtype=np.int64))
    _label(ds, name)
    ds.make_scale(name)
    return ds


def _is_dimension(ds: h5py.Dataset) -> bool:
    """True for a dimension-only scale written by :func:`_dimension` (not data)."""
    name = ds.attrs.get("NAME", b"")
    return isinstance(name, (bytes, np.bytes_)) and bytes(name).startswith(_NOT_A_VARIABLE)


def _attach(ds: h5py.Dataset, *scales: h5py.Dataset) -> None:
    """Label every axis of `ds` with its dimension scale (netCDF-4 dimensions)."""
    for axis, scale in enumerate(scales):
        ds.dims[axis].attach_scale(scale)


def _mesh_group(mesh: h5py.Group, n_nodes: int, n_elements: int) -> None:
    """The run file's ``mesh`` group for `n_nodes` nodes and `n_elements` elements, its elements and
    rest positions zero and its dimension scales made but not attached (:func:`_header_image` attaches them)."""
    _describe(mesh, "mesh")
    # netCDF-4 dimensions with index coordinates, so that xarray opens the group as it is (issue 16)
    _index(mesh, "node", n_nodes), _index(mesh, "xyz", 3)
    _index(mesh, "element", n_elements), _index(mesh, "element_node", 6)
    _label(mesh.create_dataset("elements", shape=(n_elements, 6), dtype=np.int64), "elements")
    _label(mesh.create_dataset("rest_positions", shape=(n_nodes, 3), dtype=np.float64), "rest_positions")
    positions = mesh.create_dataset(
        "positions",
        shape=(0, n_nodes, 3),
        maxshape=(None, n_nodes, 3),
        chunks=(1, n_nodes, 3),
        dtype=np.float64,
    )
    snapshot_t = mesh.create_dataset(
        "snapshot_t", shape=(0,), maxshape=(None,), chunks=(256,), dtype=np.float64
    )
    _label(positions, "positions")
    _label(snapshot_t, "snapshot_t")
    snapshot_t.make_scale("snapshot_t")


#: (nodes, elements) -> the image of a run file's skeleton for a mesh of that size (:func:`_header_image`)
_header_images: dict[tuple[int, int], bytes] = {}


def _header_image(n_nodes: int, n_elements: int) -> bytes:
    """The in-memory image of a run file's skeleton: CF's global attributes, the ``mesh`` group
    (elements and rest positions zero, its dimension scales attached) and the empty ``timeseries``."""
    # Default libver on purpose: libver="latest" writes a superblock whose
    # "open for write" flag survives a SIGKILL and then refuses every reader.
    f = h5py.File(f"capsim-header-{os.getpid()}-{next(_template_files)}", "w", driver="core", backing_store=False)
    f.attrs.update(global_attrs("capsim run"))  # CF: Conventions, the scale definitions (issue 16)
    mesh = f.create_group("mesh")
    _mesh_group(mesh, n_nodes, n_elements)
    _attach(mesh["elements"], mesh["element"], mesh["element_node"])
    _attach(mesh["rest_positions"], mesh["node"], mesh["xyz"])
    _attach(mesh["positions"], mesh["snapshot_t"], mesh["node"], mesh["xyz"])
    _describe(f.create_group("timeseries"), "timeseries")
    f.flush()
    image = f.id.get_file_image()
    f.close()
    return image


class TrajectoryWriter:
    """Append-only writer of one run's trajectory.

    Rows are buffered in memory and written to the file together on every
    flush: each ``write_group``, ``close``, ``flush`` (a checkpoint's) and every
    ``_STEP_FLUSH_EVERY`` ``append_step`` calls once ``_FLUSH_INTERVAL_S`` has passed since the
    last (at most ``_STEP_FLUSH_MAX`` rows buffered) (one resize per column per
    flush instead of per row: per-row HDF5 writes cost more than the physics of
    a level-3 step). A snapshot is on disk when ``append_snapshot`` returns (the
    file is flushed; the buffered rows are not written with it). A killed run keeps
    every row up to its last flush and every snapshot.
    Use as a context manager: an exception marks the file 'failed' (or
    'interrupted' for Ctrl-C) with the exception text, then propagates.
    """

    def __init__(self, path: str | os.PathLike, **header: Any) -> None:
        """Create the file under a temporary name next to `path` and move it into
        place once its header is on disk: a failure (a full disk) leaves whatever
        was at `path` as it was, and no half-written file. Write failures raise
        :class:`StorageError`. The caller holds the run file's :class:`FileLock`."""
        target = Path(path)
        target.parent.mkdir(parents=True, exist_ok=True)
        self._creating = _tmp_name(target)
        # The header is built in memory and written with plain writes: a full disk or a
        # file-size limit then fails one write() cleanly, never inside HDF5's metadata
        # cache (where it has crashed the process, leaving a file no reader opens).
        try:
            image = self._build_image(**header)
        except (OSError, RuntimeError) as exc:
            raise StorageError(_write_failure(target, exc) + "; nothing was changed") from None
        require_room(target, len(image) + _needed_bytes(np.size(header.get("rest_positions", ())) // 3, ()),
                     "a new run file")
        try:
            self._creating.unlink(missing_ok=True)  # a stale one of a dead process of this pid
            with open(self._creating, "xb") as fh:
                fh.write(image)
                fh.flush()
                os.fsync(fh.fileno())
            os.replace(self._creating, target)
        except OSError as exc:
            self._creating.unlink(missing_ok=True)
            raise StorageError(_write_failure(target, exc) + "; nothing was changed") from None
        self.path = target
        try:
            self._file = h5py.File(target, "a")
            self._identity = FileIdentity(target)
            self._cut_back(0, 0, resumed=False)
        except (OSError, RuntimeError) as exc:
            self.abandon()
            raise StorageError(_write_failure(target, exc)) from None

    def _check_room(self) -> None:
        """Refuse a write that could leave the file system (or the file-size limit)
        without room for the metadata that keeps the file readable: HDF5 cannot
        undo half a flush. What is left is enough to close the file with its status."""
        need = _needed_bytes(self._n_nodes, self._keys)
        room = room_bytes(self.path.parent, self._file.id.get_filesize())
        if room < need:
            raise StorageError(f"{self.path}: cannot write: disk full ({_mb(room)} of room on its file system or "
                               f"under the file-size limit, a flush needs {_mb(need)})")

    def _guarded(self, write: Callable[[], None]) -> None:
        self._identity.check()  # the file at the path is still the one this run writes
        self._check_room()
        try:
            write()
        except (OSError, RuntimeError) as exc:  # h5py reports a failed write as either
            raise StorageError(_write_failure(self.path, exc)) from None

    @staticmethod
    def _build_image(
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
        n_nodes, n_elements = rest_positions.shape[0], elements.shape[0]
        # the file's skeleton (the mesh's labelled objects and dimension scales, the groups, CF's global
        # attributes) is this process's image for a mesh of this size, made once (``_header_image``); this
        # run's values and attributes are written into a copy of it in memory
        image = _header_images.get((n_nodes, n_elements)) if TEMPLATES else None
        if image is None:
            image = _header_image(n_nodes, n_elements)
            if TEMPLATES:
                if len(_header_images) >= _TEMPLATE_LIMIT:
                    _header_images.clear()
                _header_images[(n_nodes, n_elements)] = image
        fapl = h5py.h5p.create(h5py.h5p.FILE_ACCESS)
        fapl.set_fapl_core(backing_store=False)
        fapl.set_file_image(image)
        f = h5py.File(h5py.h5f.open(f"capsim-header-{os.getpid()}-{next(_template_files)}".encode("ascii"),
                                    h5py.h5f.ACC_RDWR, fapl=fapl))
        h5py.h5d.open(f.id, b"mesh/elements").write(h5py.h5s.ALL, h5py.h5s.ALL,
                                                    np.ascontiguousarray(elements, dtype=np.int64))
        h5py.h5d.open(f.id, b"mesh/rest_positions").write(h5py.h5s.ALL, h5py.h5s.ALL,
                                                          np.ascontiguousarray(rest_positions))
        from capsim.numerics.threads import policy_attrs  # numba-free: the threads this run computes with

        set_text_attrs(f, {"config_yaml": config_yaml, "capsim_version": version, "status": "running",
                           "status_reason": "", "created": _now(), **policy_attrs(), **(attrs or {})})
        f.flush()
        image = f.id.get_file_image()
        f.close()
        return image

    @classmethod
    def reopen(
        cls, path: str | os.PathLike, n_steps: int, n_snapshots: int,
        verify: Callable[[dict[str, Any]], None] | None = None,
    ) -> TrajectoryWriter:
        """Reopen a trajectory to append to it, cut back to its first ``n_steps`` rows
        and ``n_snapshots`` snapshots (those of a checkpoint); status back to 'running'.

        The file is checked read-only first (and handed to ``verify``, which raises
        to refuse it), so that a file too short, unreadable or foreign raises
        without being touched. Then the free space is checked (:data:`RESUME_HEADROOM_BYTES`
        beyond a copy of the file), and the cut is made on a copy moved into place:
        a write failure (a full disk) leaves the file as it was and raises
        :class:`StorageError`. The caller holds the run file's :class:`FileLock`.
        """
        data = read_trajectory(path)
        have_steps = len(data["timeseries"].get("t", ()))
        have_snaps = len(data["snapshot_t"])
        if have_steps < n_steps or have_snaps < n_snapshots:
            raise TrajectoryError(
                f"{os.fspath(path)}: holds {have_steps} steps and {have_snaps} snapshots, "
                f"the checkpoint needs {n_steps} and {n_snapshots}"
            )
        if verify is not None:
            verify(data)
        self = cls.__new__(cls)
        self.path = Path(path)
        size = os.path.getsize(self.path)
        room = room_bytes(self.path.parent) - size  # the copy takes `size` of it, then grows
        if room < RESUME_HEADROOM_BYTES:
            raise StorageError(
                f"{self.path}: {_mb(room)} of room beyond a copy of the file on its file system (or under the "
                f"file-size limit), resuming needs {_mb(RESUME_HEADROOM_BYTES)}; nothing was changed"
            )
        tmp = _tmp_name(self.path)
        try:
            shutil.copyfile(self.path, tmp)
            self._file = h5py.File(tmp, "a")
            self._cut_back(n_steps, n_snapshots)
            os.replace(tmp, self.path)
            self._identity = FileIdentity(self.path)
        except (OSError, RuntimeError) as exc:
            if getattr(self, "_file", None) is not None:
                try:
                    self._file.close()
                except Exception:
                    pass
            tmp.unlink(missing_ok=True)
            raise StorageError(_write_failure(self.path, exc) + "; the run file is unchanged") from None
        return self

    def _cut_back(self, n_steps: int, n_snapshots: int, resumed: bool = True) -> None:
        f = self._file
        mesh = f["mesh"]
        self._positions, self._snapshot_t = mesh["positions"], mesh["snapshot_t"]
        self._n_nodes = self._positions.shape[1]
        self._positions.resize((n_snapshots, self._n_nodes, 3))
        self._snapshot_t.resize((n_snapshots,))
        self._timeseries = f["timeseries"]
        self._keys = tuple(k for k in self._timeseries if k != CAPSULE_DIM) or None
        self._columns = [self._timeseries[key] for key in self._keys or ()]
        self._wide = {i for i, ds in enumerate(self._columns) if ds.ndim == 2}
        for ds in self._columns:
            ds.resize((n_steps, *ds.shape[1:]))
        # rewritten when the run ends; the error estimate was of the window and the end that the
        # run had, so it goes too (`capsim run --error-estimate` makes a new one)
        for name in ("summary", "run", "error_estimate", "accuracy"):
            if name in f:
                del f[name]
        if REQUESTED_CASE in f.attrs:  # extended, the run is no longer the ladder's answer to that case
            del f.attrs[REQUESTED_CASE]
        self._n_steps, self._n_snapshots, self._unflushed_steps = n_steps, n_snapshots, 0
        self._flushed_at = time.monotonic()
        self._pending = []
        if resumed:
            f.attrs["status"] = "running"
            f.attrs["status_reason"] = ""
            f.attrs["resumed"] = _now()
            f.flush()

    def steps(self) -> dict[str, np.ndarray]:
        """Every time series written so far, one array per column."""
        self._write_pending()
        return {key: ds[: self._n_steps] for key, ds in self._timeseries.items() if key != CAPSULE_DIM}

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

    def attr(self, name: str, default: Any = None) -> Any:
        """A root attribute of the open file (as stored; `default` when absent)."""
        return self._file.attrs.get(name, default)

    def still_ours(self) -> bool:
        """The file at the path is still the one this writer opened (not deleted, not replaced)."""
        try:
            self._identity.check()
            return True
        except StorageError:
            return False

    @property
    def closed(self) -> bool:
        return not self._file.id.valid

    # -- writing ---------------------------------------------------------
    def append_step(self, values: dict[str, float]) -> None:
        """Append one row; the keys of the first row fix the columns. A key that starts with "_" is
        the observer's own (what a stopping rule reads: a conduit's end clearance), never a column."""
        if self._keys is None:
            values = {key: value for key, value in values.items() if not key.startswith("_")}
            self._create_timeseries(tuple(values), {key: int(np.size(v)) for key, v in values.items()
                                                    if isinstance(v, np.ndarray)})
        elif len(values) - sum(key[:1] == "_" for key in values) != len(self._keys) or \
                not all(key in values for key in self._keys):  # (cheaper than two sets a row)
            values = {key: value for key, value in values.items() if not key.startswith("_")}
            new = sorted(set(values) - set(self._keys))
            gone = sorted(set(self._keys) - set(values))
            raise ValueError(
                f"append_step keys must match the first row: new {new}, missing {gone}"
            )
        if self._wide:  # several capsules: a per-capsule column holds one value per capsule
            self._pending.append([np.asarray(values[key], dtype=np.float64) if i in self._wide
                                  else float(values[key]) for i, key in enumerate(self._keys)])
        else:
            self._pending.append([float(values[key]) for key in self._keys])
        self._n_steps += 1
        self._unflushed_steps += 1
        if self._unflushed_steps >= _STEP_FLUSH_EVERY and (
                self._unflushed_steps >= _STEP_FLUSH_MAX or time.monotonic() - self._flushed_at >= _FLUSH_INTERVAL_S):
            self.flush()

    def _write_pending(self) -> None:
        if not self._pending:
            return
        if self._wide:  # else one column after another (_append), the handles kept
            self._write_pending_wide()
            return
        columns = np.array(self._pending, dtype=np.float64).T.copy()  # C order: each column contiguous
        for ds, column in zip(self._columns, columns):
            _append(ds, column, self._n_steps)
        self._pending = []

    def _write_pending_wide(self) -> None:
        """The buffered rows of a scene of several capsules: (steps, capsules) columns beside the
        scene's own (the rows are few per flush next to an evaluation of several capsules)."""
        n, m = self._n_steps, len(self._pending)
        for i, ds in enumerate(self._columns):
            data = np.array([row[i] for row in self._pending], dtype=np.float64)
            ds.resize((n, *ds.shape[1:]))
            ds[n - m:n] = data
        self._pending = []

    def _create_timeseries(self, keys: tuple[str, ...], widths: dict[str, int] | None = None) -> None:
        """The columns of the first row; ``widths``: the per-capsule columns of a scene of several
        capsules and how many capsules (a (t, capsule) dataset each, the capsule's index a coordinate)."""
        if not keys:
            raise ValueError("append_step needs at least one value")
        widths = widths or {}

        def make(group: h5py.Group) -> list[h5py.Dataset]:
            columns = []
            for key in keys:
                w = widths.get(key)
                if w is None:  # one column: h5py's create_dataset through the low-level calls (~70 columns a run)
                    ds = h5py.Dataset(h5py.h5d.create(group.id, key.encode("utf-8"), h5py.h5t.IEEE_F64LE,
                                                      h5py.h5s.create_simple((0,), (h5py.h5s.UNLIMITED,)),
                                                      dcpl=_COLUMN_DCPL))
                else:
                    ds = group.create_dataset(key, shape=(0, w), maxshape=(None, w),
                                              chunks=(max(1, 4096 // w), w), dtype=np.float64)
                _label(ds, key)
                columns.append(ds)
            if "t" in keys:
                columns[keys.index("t")].make_scale("t")
            return columns

        if widths or not TEMPLATES:  # several capsules (rare; an evaluation of several costs far more): made here
            columns = make(self._timeseries)
        else:  # the header's empty group replaced by this process's template of these columns
            def build(group: h5py.Group) -> None:
                _describe(group, "timeseries")
                make(group)

            del self._file["timeseries"]
            with _template_lock:
                source, _ = _template(("timeseries", keys), build)
                self._timeseries = _copy_template(source, self._file, "timeseries")
            columns = [h5py.Dataset(h5py.h5d.open(self._timeseries.id, key.encode("utf-8"))) for key in keys]
        capsule = _index(self._timeseries, CAPSULE_DIM, next(iter(widths.values()))) if widths else None
        if "t" in keys:
            t = columns[keys.index("t")]
            for key, ds in zip(keys, columns):
                if key != "t":
                    h5py.h5ds.attach_scale(ds.id, t.id, 0)
                    if key in widths:
                        h5py.h5ds.attach_scale(ds.id, capsule.id, 1)
        self._keys = keys
        self._columns = columns
        self._wide = {i for i, key in enumerate(keys) if key in widths}

    def append_snapshot(self, t: float, positions: np.ndarray) -> None:
        positions = np.asarray(positions, dtype=np.float64)
        if positions.shape != (self._n_nodes, 3):
            raise ValueError(
                f"positions must have shape ({self._n_nodes}, 3), got {positions.shape}"
            )
        n = self._n_snapshots + 1

        def write() -> None:
            # as the rows' columns (h5py's resize and selection took ~0.8 ms a snapshot); then the file is
            # flushed: the snapshot is on disk (the buffered rows follow at their own flush, every
            # _STEP_FLUSH_EVERY steps or more: writing ~60 columns at every snapshot took 1.1 ms more)
            _append(self._positions, positions[None], n)
            _append(self._snapshot_t, np.array([t], dtype=np.float64), n)
            self._file.flush()

        self._guarded(write)
        self._n_snapshots = n

    def set_attrs(self, **attrs: Any) -> None:
        """Set root attributes (scalars, strings, small arrays)."""
        def write() -> None:
            for key, value in attrs.items():
                self._file.attrs[key] = value
            self._file.flush()

        self._guarded(write)

    def write_group(self, name: str, data: dict[str, Any]) -> None:
        """Write (or replace) group `name` with scalars, arrays, strings or nested dicts.

        The groups of the layout go through their named writers
        (``write_group("summary", d)`` is ``write_summary(d)``).
        """
        named = {"membrane_law": self.write_membrane_law, "rest_shape": self.write_rest_shape,
                 "run": self.write_run_record, "summary": self.write_summary}
        if name in named:
            named[name](data)
        else:
            self._write_group(name, data)

    def write_membrane_law(self, law: dict[str, Any]) -> None:
        """The ``membrane_law`` group from :func:`capsim.numerics.membrane.law_attributes`:
        name, G_s, K_s, poisson_ratio, ca_over_G and ``parameters/<p>`` (empty
        group for a law without parameters). The moduli's scale (``units: E_s``
        in the dict) is stated by the table's attributes, not as a dataset."""
        data = {k: v for k, v in law.items() if k not in ("units", "parameters")}
        # {"none": 0.0} is the placeholder older callers pass for "no parameters"
        data["parameters"] = {k: v for k, v in (law.get("parameters") or {}).items() if k != "none"}
        self._write_group("membrane_law", data)

    def write_rest_shape(self, shape: dict[str, Any]) -> None:
        """The ``rest_shape`` group from :func:`capsim.numerics.mesh.rest_shape_attributes`."""
        self._write_group("rest_shape", shape)

    def write_run_record(self, record: dict[str, Any]) -> None:
        """The ``run`` group: the state at the end of the run and its cost
        (t, steps, rejected_steps, wall_time_s, D_xy, …); rewritten on resume."""
        self._write_group("run", record)

    def write_summary(self, summary: dict[str, Any]) -> None:
        """The ``summary`` group from :func:`capsim.solve.observables.run_summary`
        (motion, window means and standard deviations); rewritten on resume."""
        self._write_group("summary", summary)

    def write_end_state(self, blob: bytes) -> None:
        """The dataset ``end_state``: the bytes of the state a run reached at its t_end
        (:func:`capsim.storage.checkpoint.end_state_bytes`), from which ``--resume --t-end`` extends it."""
        def write() -> None:
            self.drop_end_state()
            ds = self._file.create_dataset(END_STATE, data=np.frombuffer(blob, dtype=np.uint8))
            _label(ds, END_STATE)
            # a netCDF-4 dimension of its own, so that xarray opens the root as it is (no phony dims)
            # its dimension: a netCDF dimension without a coordinate variable (no data: an
            # index of 8 bytes per byte would multiply the dataset's size by nine)
            dim = _dimension(self._file, f"{END_STATE}_byte", ds.shape[0])
            _label(dim, f"{END_STATE}_byte")
            _attach(ds, dim)
            self._file.flush()

        self._guarded(write)

    def drop_end_state(self) -> None:
        """Remove ``end_state``: a run being extended is no longer at it (its checkpoint takes over)."""
        for name in (END_STATE, f"{END_STATE}_byte"):
            if name in self._file:
                del self._file[name]

    def _write_group(self, name: str, data: dict[str, Any]) -> None:
        self._check_room()
        if name in self._file:
            del self._file[name]
        _new_group(self._file, name, data, name, describe=True)
        self.flush()

    def flush(self) -> None:
        """Write the buffered rows and flush; refused (:class:`StorageError`) where the room is short."""
        def write() -> None:
            self._write_pending()
            self._file.flush()

        self._guarded(write)
        self._unflushed_steps = 0
        self._flushed_at = time.monotonic()

    def abandon(self) -> None:
        """Close the handle without writing more (after a write failure): the file keeps its last flush."""
        try:
            self._file.close()
        except Exception:  # noqa: BLE001 - a full disk may refuse even the close's metadata
            pass

    def close(self, status: str, reason: str = "") -> None:
        """Record the final status and close; a second call does nothing."""
        if status not in STATUSES:
            raise ValueError(f"status must be one of {sorted(STATUSES)}, got {status!r}")
        if self.closed:
            return
        self._write_pending()
        set_text_attrs(self._file, {"status": status, "status_reason": reason, "finished": _now()})
        self._file.flush()
        self._file.close()


def _append(dataset: h5py.Dataset, block: np.ndarray, length: int) -> None:
    """Extend the extendible ``dataset`` along its first axis to ``length`` and write ``block`` (float64,
    its last ``len(block)`` entries) there, as ``resize`` and ``__setitem__`` do, through the low-level
    calls: h5py's name lookup and selection building cost ~0.2 ms a dataset (a flush wrote ~70 columns)."""
    block = np.ascontiguousarray(block, dtype=np.float64)
    shape = (length, *block.shape[1:])
    dataset.id.set_extent(shape)
    space = dataset.id.get_space()
    space.select_hyperslab((length - block.shape[0],) + (0,) * (block.ndim - 1), block.shape)
    dataset.id.write(h5py.h5s.create_simple(block.shape), space, block)


# -- templates: the labelled objects every run file repeats, made once a process ----------------------------
#
# HDF5 spends ~30 µs on each attribute it creates and ~40 µs on each dataset (inside the library: a
# run file's ~135 labelled datasets and ~580 attributes took ~35 ms of a level-2 campaign run's ~95 ms
# outside its evaluations), but copies a whole group of them (H5Ocopy) in a tenth of that. So a group
# of labelled scalars, and the time series' empty labelled columns, are made once per process in an
# in-memory file and copied into each run file; then only the values are written. The copy is the same
# objects with the same attributes: the file is unchanged. Dimension scales are attached after the copy
# (H5Ocopy does not carry an attached scale's references into another file).

#: False: every object made in the run file itself (the test that the templates change nothing)
TEMPLATES = True
#: templates kept per process before the in-memory file is started afresh (a campaign's runs share a few)
_TEMPLATE_LIMIT = 64
_template_file: h5py.File | None = None
_template_files = itertools.count()
#: held from a template's values written to its copy made: a Dask worker runs several runs in threads
#: of one process, and another run's values must not be written into the template in between
_template_lock = threading.RLock()
#: signature -> (the template's name in the in-memory file, its datasets by name)
_templates: dict[tuple, tuple[bytes, dict[str, h5py.h5d.DatasetID]]] = {}


def _template(signature: tuple, build: Callable[[h5py.Group], None]) -> tuple[bytes, dict[str, h5py.h5d.DatasetID]]:
    """This process's template of `signature`, made by ``build`` on its first use (`signature` must fix
    everything ``build`` writes but the datasets' values): its name and its datasets (the group's own)."""
    global _template_file
    found = _templates.get(signature)
    if found is not None:
        return found
    if _template_file is None or len(_templates) >= _TEMPLATE_LIMIT:
        if _template_file is not None:
            _template_file.close()
        _templates.clear()
        # a name of its own (HDF5 refuses to create a file by the name of one still open)
        _template_file = h5py.File(f"capsim-templates-{os.getpid()}-{next(_template_files)}", "w", driver="core",
                                   backing_store=False)
    name = f"t{len(_templates)}"
    group = _template_file.create_group(name)
    build(group)
    datasets = {key: h5py.h5d.open(group.id, key.encode("utf-8")) for key, item in group.items()
                if isinstance(item, h5py.Dataset)}
    _templates[signature] = found = (name.encode("ascii"), datasets)
    return found


def _copy_template(source: bytes, parent: h5py.Group, name: str) -> h5py.Group:
    """The template `source` copied to ``parent/name`` (H5Ocopy: its objects, attributes and data)."""
    h5py.h5o.copy(_template_file.id, source, parent.id, name.encode("utf-8"))
    return parent[name]


#: a group with at least this many scalars is copied from a template (fewer: made directly)
_TEMPLATE_MIN_SCALARS = 4


def _scalar_kind(value: Any) -> str | None:
    """How a template holds `value`: the dtype of a number, "str", "bool"; None for what it does not
    (arrays, lists, dicts: written directly)."""
    if type(value) is str:
        return "str"
    if type(value) in (bool, np.bool_):
        return "bool"
    return _NUMBER_TYPES.get(type(value))


def _new_group(parent: h5py.Group, name: str, data: dict[str, Any], where: str | None, describe: bool) -> None:
    """Group ``parent/name`` holding `data` as :func:`_write_dict` writes it (its ``definition`` where
    `describe`): the labelled scalars from a template, written there with this group's values and copied
    (writing into the in-memory template and copying takes half the time of writing after the copy)."""
    kinds = {key: kind for key, value in data.items() if (kind := _scalar_kind(value)) is not None}
    if len(kinds) < _TEMPLATE_MIN_SCALARS or not TEMPLATES:
        group = parent.create_group(name)
        if describe:
            _describe(group, name)
        _write_dict(group, data, where)
        return

    def build(group: h5py.Group) -> None:
        if describe:
            _describe(group, name)
        _write_dict(group, {key: data[key] for key in kinds}, where)

    with _template_lock:
        source, scalars = _template((name if describe else None, where, tuple(kinds.items())), build)
        for key, kind in kinds.items():
            if kind in ("str", "bool"):
                h5py.Dataset(scalars[key])[()] = data[key]
            else:
                scalars[key].write(h5py.h5s.ALL, h5py.h5s.ALL, np.array(data[key], dtype=kind))
        group = _copy_template(source, parent, name)
    _write_dict(group, {key: value for key, value in data.items() if key not in kinds}, where)


def _write_dict(group: h5py.Group, data: dict[str, Any], where: str | None = None) -> None:
    """Datasets for `data` (nested dicts as subgroups), labelled as names in group `where`."""
    for key, value in data.items():
        if isinstance(value, dict) and key == CAPSULE_DIM:
            # one value per capsule (a run of several): the capsule's index a shared coordinate
            sub = group.create_group(key)
            n = len(next(iter(value.values())))
            capsule = _index(sub, CAPSULE_DIM, n)
            for name, values in value.items():
                values = np.asarray(values)
                if values.dtype == object:
                    values = values.astype(h5py.string_dtype())
                _label(ds := sub.create_dataset(name, data=values), name, where)
                _attach(ds, capsule)
        elif isinstance(value, dict):
            _new_group(group, key, value, where, describe=False)
        elif value is None:
            raise TypeError(f"cannot store None for '{group.name}/{key}'")
        elif type(value) in _NUMBER_TYPES:  # most of a summary: a scalar dataset by the low-level calls
            _label(_scalar_dataset(group, key, value), key, where)
        else:
            _label(ds := group.create_dataset(key, data=value), key, where)
            # an array gets a netCDF-4 dimension per axis (<key>_dim<i>), so xarray reads the group
            _attach(ds, *(_dimension(group, f"{key}_dim{i}", n) for i, n in enumerate(ds.shape)))


#: the scalars :func:`_scalar_dataset` writes and their dtypes, as h5py stores them (bool, str and arrays go
#: through h5py's create_dataset: an enum, a string, dimensions)
_NUMBER_TYPES = {float: "<f8", np.float64: "<f8", int: "<i8", np.int64: "<i8"}


def _scalar_dataset(group: h5py.Group, key: str, value: Any) -> h5py.Dataset:
    """``group.create_dataset(key, data=value)`` of a float or an int by the low-level calls: a summary's
    ~100 scalars took ~10 ms through h5py's."""
    data = np.array(value, dtype=_NUMBER_TYPES[type(value)])
    dataset = h5py.h5d.create(group.id, key.encode("utf-8"), h5py.h5t.py_create(data.dtype), _SCALAR_SPACE)
    dataset.write(h5py.h5s.ALL, h5py.h5s.ALL, data)
    return h5py.Dataset(dataset)


def write_error_estimate(path: str | os.PathLike, estimate: dict[str, Any]) -> None:
    """Store an error estimate (:func:`capsim.campaigns.study.error_estimate`) as the run
    file's ``error_estimate`` group, replacing any (holding the run file's lock).

    The group is written into a copy that is renamed over the run file (room for the
    copy checked first): a full disk or a kill leaves the completed run file as it was."""
    _write_group(path, "error_estimate", tuple(estimate), lambda group: _write_dict(group, estimate, "error_estimate"))


def write_accuracy(path: str | os.PathLike, record: dict[str, Any], held: FileLock | None = None) -> None:
    """Store a measured accuracy target's ladder (:func:`capsim.runs.ladder.run_measured`) as the kept
    run file's ``accuracy`` group, replacing any, as :func:`write_error_estimate` does: the
    per-level lists (values, error estimates, orders, costs) over the coordinate ``level``, the
    rest (target, rtol, verdict) as scalars. `held`: the caller's lock of `path` (the ladder holds
    its output's from start to end), else taken here."""
    per_level = {k: v for k, v in record.items() if isinstance(v, (list, tuple)) and k != "level"}

    def fill(group: h5py.Group) -> None:
        _write_dict(group, {k: v for k, v in record.items() if k not in per_level and k != "level"}, "accuracy")
        level = group.create_dataset("level", data=np.asarray(record["level"], dtype=np.int64))
        _label(level, "level", "accuracy")
        level.make_scale("level")
        for key, values in per_level.items():
            _label(ds := group.create_dataset(key, data=np.asarray(values)), key, "accuracy")
            _attach(ds, level)

    _write_group(path, "accuracy", tuple(record), fill, held)


def move_run(source: str | os.PathLike, target: str | os.PathLike, config_yaml: str, overwrite: bool = True,
             requested_case_yaml: str | None = None, held: FileLock | None = None) -> None:
    """Move a completed run file to `target` (same file system), its stored case rewritten to
    `config_yaml` (the case with its new output.path, so that ``capsim run TARGET --resume``
    reads the path it is at); an existing target is replaced only with `overwrite`
    (:class:`capsim.storage.files.OutputError` otherwise). The ladder of a measured accuracy target keeps
    each completed level this way (capsim.runs.ladder), with the case that asked for it as the root
    attribute ``requested_case_yaml``: the run is that request's result (a campaign's run of
    that case finds it its own, :func:`read_run_identity`). `held`: the caller's lock of `target`
    (the ladder holds it across its levels), else taken here. A checkpoint beside `source` (an
    interrupted run's) moves with it, beside `target`, so that ``--resume`` finds it there."""
    from capsim.storage.files import OutputError

    with _holding(target, held):
        if not overwrite and os.path.exists(target):
            raise OutputError(f"{target} exists; use --overwrite to replace it")
        with h5py.File(source, "a") as f:
            f.attrs["config_yaml"] = config_yaml
            if requested_case_yaml is not None:
                f.attrs[REQUESTED_CASE] = requested_case_yaml
        checkpoint_path(target).unlink(missing_ok=True)  # an older run's: not of the file that comes
        os.replace(source, target)
        if checkpoint_path(source).exists():
            os.replace(checkpoint_path(source), checkpoint_path(target))


def _holding(path: str | os.PathLike, held: FileLock | None):
    """`path`'s lock: the caller's `held` one (checked to be of `path`), else a new one taken here."""
    if held is None:
        return FileLock(path)
    if held.path != lock_path(path):
        raise ValueError(f"the lock held is of {held.target}, not of {path}")
    return contextlib.nullcontext(held)


def _write_group(path: str | os.PathLike, name: str, keys: tuple[str, ...], fill, held: FileLock | None = None) -> None:
    """Group `name` (replacing any) filled by ``fill(group)``, written into a copy renamed over the run file."""
    def change(copy: Path) -> None:
        with h5py.File(copy, "a") as f:
            if name in f:
                del f[name]
            group = f.create_group(name)
            _describe(group, name)
            fill(group)

    with _holding(path, held):
        copy_and_replace(path, change, headroom=_needed_bytes(0, keys))


# ---------------------------------------------------------------- checkpoints


def guard_run_output(path: str | os.PathLike, inputs: list, *, overwrite: bool = False, resume: bool = False) -> None:
    """Refuse (:class:`capsim.storage.files.OutputError`, one line) a run's output path before the
    run: a name capsim keeps for a checkpoint or a lock, a path that cannot be written,
    one of the inputs, or an existing file without `overwrite` (or `resume`); the
    checkpoint and lock beside it must not be inputs either."""
    from capsim.storage.files import CHECKPOINT_SUFFIX, LOCK_SUFFIX, OutputError, check_writable, guard_output

    out = Path(path)
    if out.name.endswith((CHECKPOINT_SUFFIX, LOCK_SUFFIX)):
        raise OutputError(f"output path {out}: a name capsim keeps for a run's checkpoint or lock; choose another")
    check_writable(out)
    guard_output(out, inputs, overwrite or resume, option="--overwrite (or --resume to continue it)")
    for derived in (checkpoint_path(out), lock_path(out)):
        guard_output(derived, inputs, True)


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
        elif _is_dimension(item):
            continue
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
    its last complete row (all time series trimmed to the same length). A file that
    is not a capsim run file, or cannot be read, raises :class:`TrajectoryError`
    (one line; a file a running capsim process writes is retried, then named as such).
    """
    def read(f: h5py.File) -> dict[str, Any]:
        try:
            return _read_open(f)
        except KeyError as exc:
            raise TrajectoryError(f"{os.fspath(path)}: not a capsim trajectory (missing {exc})") from None

    return _read_run_file(path, read)


#: a file a running capsim process writes is read again this often, this far apart, before
#: it is reported as being written (a reader may meet its metadata half-flushed)
_BUSY_TRIES, _BUSY_WAIT_S = 8, 0.25


def writer_of(path: str | os.PathLike) -> str | None:
    """Whether a capsim process writes `path` now (holds its lock): its pid as text ("" when the
    lock holds none), or None when no process does. Takes no lock and creates no file."""
    import errno
    import fcntl

    try:
        fd = os.open(lock_path(path), os.O_RDONLY | os.O_NOFOLLOW | os.O_CLOEXEC)
    except OSError:
        return None
    try:
        try:
            fcntl.flock(fd, fcntl.LOCK_SH | fcntl.LOCK_NB)
        except OSError as exc:
            if exc.errno not in (errno.EWOULDBLOCK, errno.EAGAIN, errno.EACCES):
                return None
            holder = os.pread(fd, 20, 0).decode("ascii", "replace").strip()
            if holder == str(os.getpid()):  # this process (a resume reads the file it has locked)
                return None
            return holder if holder.isdigit() else ""
        fcntl.flock(fd, fcntl.LOCK_UN)
        return None
    except OSError:
        return None
    finally:
        os.close(fd)


def _not_a_run_file(f: h5py.File) -> str | None:
    """Why an open HDF5 file is not a capsim run file (None when it is one): every run file
    has its case in the root attribute ``config_yaml`` from its first byte on disk."""
    if "config_yaml" in f.attrs:
        return None
    names = set(f.attrs)
    if "campaign_yaml" in names:
        return "a campaign summary (capsim summarize), not a run file: open it with xarray.open_dataset"
    if "case_yaml" in names:
        return "an accuracy study (capsim study), not a run file: open it with xarray.open_dataset"
    if not names and not len(f):
        return "an empty HDF5 file, not a capsim run file"
    return "not a capsim run file (an HDF5 file without the config_yaml attribute of every run file)"


def _read_run_file(path: str | os.PathLike, read: Callable[[h5py.File], Any]) -> Any:
    """``read(f)`` of the run file at `path` opened read-only without a lock (a running or killed
    writer must not stop a reader), after checking that it is one; every failure a one-line
    :class:`TrajectoryError`.

    A file that another capsim process writes (:func:`writer_of`) is read from an image of
    it taken in one read into memory (HDF5's core driver): read in place, its chunk index
    may point past the end the reader saw at opening, as the writer appends a snapshot
    meanwhile. An image taken mid-flush is taken again a few times; a file that stays
    unreadable is refused as being written, never called corrupt."""
    import time

    source = os.fspath(path)
    if not os.path.exists(source):
        raise TrajectoryError(f"{source}: no such file")
    if os.path.isdir(source):
        raise TrajectoryError(f"{source}: is a directory, not a run file")
    writer = writer_of(source)
    for attempt in range(_BUSY_TRIES):
        in_memory = {} if writer is None else {"driver": "core", "backing_store": False}
        try:
            if not h5py.is_hdf5(source):
                problem = "not an HDF5 file (empty, truncated or another format)"
            else:
                with h5py.File(source, "r", locking=False, **in_memory) as f:
                    why = _not_a_run_file(f)
                    if why is not None:
                        raise TrajectoryError(f"{source}: {why}")
                    return read(f)
        except (OSError, RuntimeError, ValueError) as exc:
            problem = f"unreadable HDF5 file (truncated or corrupt?): {first_line(exc)}"
        writer = writer_of(source)
        if writer is None:
            raise TrajectoryError(f"{source}: {problem}")
        if attempt + 1 < _BUSY_TRIES:
            time.sleep(_BUSY_WAIT_S)
    by = f" (process {writer})" if writer else ""
    raise TrajectoryError(f"{source}: being written by a running capsim process{by}, and not readable in a "
                          f"consistent state just now; read it again, or once the run has ended")


def _read_open(f: h5py.File) -> dict[str, Any]:
    attrs = {key: _decode(value) for key, value in f.attrs.items()}
    mesh = f["mesh"]
    timeseries = {key: ds[()] for key, ds in f["timeseries"].items() if key != CAPSULE_DIM}
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


def _scalar(value: Any) -> Any:
    """A plain Python value for an attribute or a scalar dataset's value."""
    if isinstance(value, bytes):
        return value.decode("utf-8")
    if isinstance(value, np.ndarray) and value.shape == ():
        value = value[()]
    if isinstance(value, np.generic):
        return value.item()
    return value


def _scalars(f: h5py.File, name: str) -> dict[str, Any]:
    """The scalar datasets of group `name` (strings decoded); {} without the group."""
    if name not in f or not isinstance(f[name], h5py.Group):
        return {}
    out = {}
    for key, ds in f[name].items():
        if isinstance(ds, h5py.Dataset) and ds.shape == ():
            out[key] = ds.asstr()[()] if h5py.check_string_dtype(ds.dtype) else _scalar(ds[()])
    return out


def read_end_state(path: str | os.PathLike) -> bytes | None:
    """The ``end_state`` bytes of a run that reached its t_end; None when the file has none."""
    try:
        with h5py.File(path, "r", locking=False) as f:
            return f[END_STATE][()].tobytes() if END_STATE in f else None
    except (OSError, ValueError):
        return None


def read_run_status(path: str | os.PathLike) -> str | None:
    """The status attribute of a run file; None when there is no readable file."""
    try:
        with h5py.File(path, "r", locking=False) as f:
            return str(_scalar(f.attrs.get("status", "")))
    except (OSError, ValueError):
        return None


def mark_abandoned(path: str | os.PathLike, reason: str) -> bool:
    """Record 'failed' and `reason` in a run file left 'running' by a process that died
    (SIGKILL, out of memory), so that the file says what the campaign knows. Made on a
    copy renamed into place, under the file's lock (a live writer keeps it: then
    nothing is done). Returns whether the file was changed."""
    if read_run_status(path) != "running":
        return False
    try:
        with FileLock(path):
            def change(copy: Path) -> None:
                with h5py.File(copy, "a") as f:
                    f.attrs["status"] = "failed"
                    f.attrs["status_reason"] = reason
                    f.attrs["finished"] = _now()

            copy_and_replace(path, change, headroom=WRITE_MARGIN_BYTES)
        return True
    except (LockedError, StorageError, OSError, RuntimeError):
        return False


def read_run_identity(path: str | os.PathLike) -> tuple[str | None, str | None]:
    """(status, :func:`capsim.config.case_digest` of the stored case) of a run file, in one
    opening; (None, None) when there is no readable file, a None digest when its case is not one.
    A run kept by a measured accuracy target's ladder: the digest of the case that asked for it."""
    from capsim.config import case_digest

    try:
        with h5py.File(path, "r", locking=False) as f:
            status = str(_scalar(f.attrs.get("status", "")))
            # a ladder's kept run answers the case that asked for it (move_run)
            text = _scalar(f.attrs.get(REQUESTED_CASE, f.attrs.get("config_yaml", "")))
    except (OSError, ValueError):
        return None, None
    try:
        stored = yaml_text(text) if isinstance(text, str) and text else None
        digest = case_digest(case_from_dict(stored).model_dump(mode="json")) if isinstance(stored, dict) else None
    except Exception:  # noqa: BLE001 - a damaged or foreign case: no digest
        digest = None
    return status, digest


def read_run_digest(path: str | os.PathLike) -> str | None:
    """:func:`capsim.config.case_digest` of the case a run file holds; None when unreadable."""
    return read_run_identity(path)[1]


def read_run_record(path: str | os.PathLike) -> dict[str, Any] | None:
    """The scalars of a run file, without its arrays: ``{"attrs", "summary", "run",
    "error_estimate", "accuracy", "first", "last", "n_steps"}`` (root attributes, the scalar datasets
    of the ``summary``, ``run``, ``error_estimate`` and ``accuracy`` groups, the first and last rows of the time series and
    their number). None when there is no readable file. Cheap on a large file,
    and safe on one a running or killed writer holds (no lock)."""
    try:
        with h5py.File(path, "r", locking=False) as f:
            attrs = {k: _scalar(v) for k, v in f.attrs.items()}
            summary, run = _scalars(f, "summary"), _scalars(f, "run")
            estimate = _scalars(f, "error_estimate")
            accuracy = _scalars(f, "accuracy")  # a measured accuracy target's verdict (capsim.runs.ladder)
            # the scene's columns (a scene of several capsules has (t, capsule) ones too: not scalars)
            ts = {k: ds for k, ds in f["timeseries"].items() if ds.ndim == 1 and k != CAPSULE_DIM} \
                if "timeseries" in f else {}
            n = min((len(ds) for ds in ts.values()), default=0)
            first = {k: float(ds[0]) for k, ds in ts.items()} if n else {}
            last = {k: float(ds[n - 1]) for k, ds in ts.items()} if n else {}
    except (OSError, ValueError, KeyError):
        return None
    return {"attrs": attrs, "summary": summary, "run": run, "error_estimate": estimate, "accuracy": accuracy,
            "first": first, "last": last, "n_steps": n}


#: HDF5 bookkeeping attributes of dimension scales, not metadata a reader wants
_SCALE_ATTRS = frozenset({"CLASS", "NAME", "REFERENCE_LIST", "DIMENSION_LIST", "_Netcdf4Dimid", "_Netcdf4Coordinates"})


def _group_dataset(group: h5py.Group):
    """The datasets of one group as an xarray Dataset, dimensions from the dimension
    scales; every dimension cut to the shortest length a dataset along it has (a
    killed writer may have grown one column of a flush and not the next)."""
    import xarray as xr

    found: dict[str, tuple[list[str], Any, dict[str, Any]]] = {}
    for key, item in group.items():
        if not isinstance(item, h5py.Dataset) or _is_dimension(item):
            continue
        if item.is_scale and item.ndim == 1:
            dims = [key]
        else:  # unlabelled axes (a file written before issue 16): <key>_dim<i>
            dims = [item.dims[i][0].name.rsplit("/", 1)[-1] if len(item.dims[i]) else f"{key}_dim{i}"
                    for i in range(item.ndim)]
        data = item.asstr()[()] if h5py.check_string_dtype(item.dtype) is not None else item[()]
        attrs = {k: _scalar(v) for k, v in item.attrs.items() if k not in _SCALE_ATTRS}
        found[key] = (dims, data, attrs)
    sizes: dict[str, int] = {}
    for dims, data, _ in found.values():
        for dim, n in zip(dims, np.shape(data)):
            sizes[dim] = min(sizes.get(dim, n), n)
    variables = {}
    for key, (dims, data, attrs) in found.items():
        if dims:
            data = np.asarray(data)[tuple(slice(0, sizes[d]) for d in dims)]
        variables[key] = xr.Variable(dims, data, attrs)
    coords = {k: v for k, v in variables.items() if v.dims == (k,)}
    data_vars = {k: v for k, v in variables.items() if k not in coords}
    ds = xr.Dataset(data_vars, coords=coords)
    ds.attrs = {k: _scalar(v) for k, v in group.attrs.items()}
    return ds


def open_run(path: str | os.PathLike):
    """A run file as an ``xarray.DataTree``: the root (the run's attributes: status,
    the resolved case ``config_yaml``, versions …) and one node per group
    (``timeseries``, ``mesh``, ``summary``, ``run``, ``membrane_law``, ``rest_shape``,
    ``error_estimate``), every variable with the attributes of the quantity table.

    Read into memory and closed (a running writer is not disturbed); a file cut short
    by a killed run is read up to its last complete row, like :func:`read_trajectory`.
    ``open_run(p)["timeseries"]["D_xy"]`` is D_xy(t). The same groups open with
    ``xarray.open_dataset(p, group="timeseries", engine="h5netcdf")``.
    """
    import xarray as xr

    def read(f: h5py.File) -> dict[str, Any]:
        nodes: dict[str, Any] = {}

        def visit(name: str, item: Any) -> None:
            if isinstance(item, h5py.Group):
                nodes["/" + name] = _group_dataset(item)

        nodes["/"] = _group_dataset(f)
        f.visititems(visit)
        return nodes

    nodes = _read_run_file(path, read)
    tree = getattr(xr, "DataTree", None)
    return tree.from_dict(nodes) if tree is not None else nodes


def case_from_trajectory(data: dict[str, Any]) -> Case:
    """The Case a trajectory was run with, from :func:`read_trajectory`'s ``attrs``."""
    return case_from_dict(yaml_text(data["attrs"]["config_yaml"]), source="config_yaml")


def read_case(path: str | os.PathLike) -> Case:
    """The Case a run file was run with (its stored ``config_yaml``), without reading its arrays."""
    source = os.fspath(path)
    try:
        with h5py.File(source, "r", locking=False) as f:
            text = _scalar(f.attrs["config_yaml"])
    except KeyError:
        raise TrajectoryError(f"{source}: not a capsim trajectory (no config_yaml)") from None
    except (OSError, ValueError) as exc:
        first = first_line(exc)
        raise TrajectoryError(f"{source}: cannot read: {first}") from None
    return case_from_trajectory({"attrs": {"config_yaml": text}})

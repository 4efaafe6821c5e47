"""The restart checkpoint of a run: its one owner (format, writing, reading, validation).

``<run>.h5.ckpt.npz`` beside the run file, an ``.npz`` of the run's parts (the
integrator, the model, the observer, the snapshot schedule: each a flat mapping
of arrays and scalars, stored as ``<part>.<key>``) and a header: the resolved case
(``config_yaml``), the wall time spent, :data:`FORMAT`, and where it stands
(``steps``, ``t``). Written atomically (a temporary file, fsync, rename): a killed
writer leaves the previous checkpoint, never half of a new one.

:func:`load` refuses (:class:`ResumeError`, one line) a checkpoint of another
case, of another format or with a damaged header; :func:`check_parts` refuses
parts that cannot be this run's. The runner asks this module for a state and
hands it back; it knows nothing of the format.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from capsim.config import Case, step_defining, yaml_text
from capsim.errors import bounded_repr, first_line
from capsim.storage.files import CHECKPOINT_SUFFIX, tmp_name, write_durably
from capsim.storage.schedules import end_tolerance

__all__ = [
    "FORMAT", "PARTS", "CheckpointError", "ResumeError", "check_parts", "checkpoint_path", "end_state_bytes",
    "first_difference", "load_end_state", "without_t_end",
    "load", "read_checkpoint", "remove_checkpoint", "save", "step_defining_of", "stored_case", "write_checkpoint",
]


class CheckpointError(Exception):
    """A restart checkpoint that is missing or cannot be read; one line naming it."""


class ResumeError(Exception):
    """A run that cannot be resumed (no or damaged checkpoint, unreadable
    trajectory, a different case); the message is one line."""


def checkpoint_path(trajectory_path: str | os.PathLike) -> Path:
    """Where the restart checkpoint of a trajectory lives: ``<path>.ckpt.npz``."""
    return Path(os.fspath(trajectory_path) + CHECKPOINT_SUFFIX)


def write_checkpoint(path: str | os.PathLike, arrays: dict[str, Any]) -> None:
    """Write arrays and scalars to an .npz atomically: a killed writer leaves the
    previous checkpoint in place, never half of a new one."""
    write_durably(path, lambda fh: np.savez(fh, **{key: np.asarray(value) for key, value in arrays.items()}),
                  "the previous checkpoint is kept")


def read_checkpoint(path: str | os.PathLike) -> dict[str, np.ndarray]:
    source = os.fspath(path)
    if not os.path.exists(source):
        raise CheckpointError(f"{source}: no checkpoint (nothing to resume)")
    try:
        with open(source, "rb") as fh:
            head = fh.read(len(_NPZ_MAGIC[0]))
    except OSError as exc:
        raise CheckpointError(f"{source}: unreadable checkpoint: {exc.strerror or first_line(exc)}") from None
    try:
        return _npz_arrays(source, head)
    except _Damaged as exc:
        raise CheckpointError(f"{source}: unreadable checkpoint: the file is damaged ({exc}); it cannot be resumed "
                              "from: --overwrite starts the run again") from None


#: how an .npz (a zip archive) begins: a member, or an empty archive
_NPZ_MAGIC = (b"PK\x03\x04", b"PK\x05\x06")


class _Damaged(Exception):
    """What is wrong with bytes that should be an .npz of the checkpoint's format (one line)."""


def _npz_arrays(source: Any, head: bytes) -> dict[str, np.ndarray]:
    """The arrays of an .npz (a path or a file object) whose first bytes are `head`; :class:`_Damaged`
    otherwise. Never loads pickled objects, and never suggests to: capsim writes plain arrays only,
    so anything else means a damaged file, not one to be trusted."""
    if not head.startswith(_NPZ_MAGIC):
        raise _Damaged("not an .npz archive" + (": it is empty" if not head else ""))
    try:
        with np.load(source, allow_pickle=False) as data:
            return {key: data[key] for key in data.files}
    except ValueError as exc:
        if "pickle" in str(exc).lower():  # numpy's advice to load it "unsafely" does not apply
            raise _Damaged("a member holds Python objects, not arrays") from None
        raise _Damaged(f"{type(exc).__name__}: {first_line(exc, default='')}".rstrip(": ")) from None
    except Exception as exc:  # noqa: BLE001 - zipfile, OSError, EOFError: all mean a damaged file
        raise _Damaged(f"{type(exc).__name__}: {first_line(exc, default='')}".rstrip(": ")) from None


def remove_checkpoint(path: str | os.PathLike) -> None:
    Path(path).unlink(missing_ok=True)
    tmp_name(path).unlink(missing_ok=True)


FORMAT = 2
PARTS = ("integrator", "model", "observer", "snapshots")


def flatten(parts: dict[str, dict[str, Any]]) -> dict[str, Any]:
    return {f"{part}.{key}": value for part, state in parts.items() for key, value in state.items()
            if value is not None}


def unflatten(arrays: dict[str, Any]) -> dict[str, dict[str, Any]]:
    parts: dict[str, dict[str, Any]] = {part: {} for part in PARTS}
    for key, value in arrays.items():
        part, _, rest = key.partition(".")
        if part in parts:
            parts[part][rest] = value.item() if isinstance(value, np.ndarray) and value.ndim == 0 else value
    return parts


def step_defining_of(case: dict) -> dict:
    """The part of a resolved case that fixes the step sequence, name kept: the
    checkpoint is the run's own (:func:`capsim.config.step_defining`)."""
    out = step_defining(case)
    if "name" in case:
        out["name"] = case["name"]
    return out


def first_difference(a: dict, b: dict, prefix: str = "", where: str = "the checkpoint") -> str | None:
    for key in sorted(set(a) | set(b), key=str):
        found = _value_difference(a.get(key), b.get(key), f"{prefix}{key}", where)
        if found:
            return found
    return None


def _value_difference(va: Any, vb: Any, name: str, where: str) -> str | None:
    """The first place two values differ, as first_difference says it: into mappings and lists
    item by item (a capsules list cut to its first characters read the same in both)."""
    if isinstance(va, dict) and isinstance(vb, dict):
        return first_difference(va, vb, f"{name}.", where)
    if isinstance(va, list) and isinstance(vb, list) and va != vb:
        if len(va) != len(vb):
            return f"{name} has {len(vb)} items in {where}, {len(va)} now"
        for i, (xa, xb) in enumerate(zip(va, vb)):
            found = _value_difference(xa, xb, f"{name}[{i}]", where)
            if found:
                return found
    if va != vb:
        return f"{name} = {bounded_repr(vb)} in {where}, {bounded_repr(va)} now"
    return None


def stored_case(text: Any) -> dict | None:
    """A stored config_yaml as a mapping; None when it is not one (garbage, not YAML)."""
    if isinstance(text, np.ndarray):
        text = text.item() if text.ndim == 0 else None
    if isinstance(text, bytes):
        text = text.decode("utf-8", "replace")
    if not isinstance(text, str) or len(text) > 1_000_000:
        return None
    try:
        data = yaml_text(text)
    except yaml.YAMLError:
        return None
    return data if isinstance(data, dict) else None


def _header_number(saved: dict[str, Any], key: str, path: Path, *, integer: bool = False) -> float:
    """A scalar of the checkpoint's header, refused unless a finite number >= 0 (whole with `integer`)."""
    if key not in saved:
        raise ResumeError(f"{path}: bad checkpoint: {key} is missing")
    value = np.asarray(saved[key])
    if value.shape != () or value.dtype.kind not in "iuf":
        shown = bounded_repr(value.item() if value.shape == () else value)
        raise ResumeError(f"{path}: bad checkpoint: {key} = {shown}: must be a number")
    x = float(value)
    if not (np.isfinite(x) and x >= 0) or (integer and not x.is_integer()):
        kind = "a whole number >= 0" if integer else "a finite number >= 0"
        raise ResumeError(f"{path}: bad checkpoint: {key} = {x!r}: must be {kind}")
    return x


def load(path: Path, case: Case) -> tuple[dict[str, dict[str, Any]], float]:
    """The parts of a checkpoint of this case and the wall time spent before it
    (the header checked here, the parts against the run by :func:`check_parts`)."""
    try:
        saved = read_checkpoint(path)
    except CheckpointError as exc:
        raise ResumeError(str(exc)) from None
    # t_end may differ (--resume --t-end T on an interrupted run): the steps before the end do not
    # depend on it; it must lie beyond where the run stopped
    parts, wall = _validated(saved, path, case, extending=True)
    t_stop = float(parts["integrator"]["t"])
    if not case.time.t_end > t_stop + end_tolerance(t_stop):
        raise ResumeError(f"{path}: the run stopped at kt = {t_stop:g}; time.t_end = {case.time.t_end:g} must be "
                          "later to continue it (--t-end)")
    return parts, wall


def end_state_bytes(parts: dict[str, dict[str, Any]], config_yaml: str, wall_s: float) -> bytes:
    """The state of a run that reached its t_end, in the checkpoint's format, as the bytes
    the run file keeps (dataset ``end_state``) so that ``--resume --t-end T`` can extend it."""
    import io

    buffer = io.BytesIO()
    np.savez(buffer, **{key: np.asarray(value) for key, value in {**flatten(parts), **_header(parts, config_yaml, wall_s)}.items()})
    return buffer.getvalue()


def load_end_state(blob: bytes, path: Path, case: Case) -> tuple[dict[str, dict[str, Any]], float]:
    """The parts of a completed run's end state (:func:`end_state_bytes`) to extend it to
    ``case.time.t_end``: the same checks as :func:`load`, except that t_end may differ
    and must lie beyond where the run stopped."""
    import io

    try:
        saved = _npz_arrays(io.BytesIO(blob), blob[:len(_NPZ_MAGIC[0])])
    except _Damaged as exc:
        raise ResumeError(f"{path}: unreadable end state: the run file's end_state is damaged ({exc}); the run "
                          "cannot be extended: run the case to the later t_end with --overwrite") from None
    parts, wall = _validated(saved, path, case, extending=True)
    t_stop = float(parts["integrator"]["t"])
    if not case.time.t_end > t_stop + end_tolerance(t_stop):
        raise ResumeError(f"{path}: the run already reached kt = {t_stop:g}; time.t_end = {case.time.t_end:g} "
                          f"must be later to extend it (--t-end)")
    return parts, wall


#: what an extension may change besides t_end: the texts that explain a resolved choice of level
#: and tolerance (an accuracy target's names the predicted cost, which grows with t_end); the
#: level and tolerance themselves must agree
_EXPLANATIONS = {"time": ("t_end", "rtol_choice"), "accuracy": ("choice",)}


def without_t_end(case: dict) -> dict:
    """A resolved case with its time.t_end (and the texts explaining its choices) dropped: what an
    extended run must share with its start."""
    out = dict(case)
    for section, keys in _EXPLANATIONS.items():
        if isinstance(out.get(section), dict):
            out[section] = {k: v for k, v in out[section].items() if k not in keys}
    return out


def _validated(saved: dict[str, Any], path: Path, case: Case, *, extending: bool) -> tuple[dict[str, dict[str, Any]], float]:
    fmt = np.asarray(saved.get("format", -1))
    if fmt.shape != () or fmt.dtype.kind not in "iu" or int(fmt) != FORMAT or "config_yaml" not in saved:
        raise ResumeError(f"{path}: not a capsim checkpoint of format {FORMAT}")
    saved_case = stored_case(saved["config_yaml"])
    if saved_case is None:
        raise ResumeError(f"{path}: bad checkpoint: config_yaml is not a case (not a YAML mapping)")
    now, then = step_defining_of(case.model_dump(mode="json")), step_defining_of(saved_case)
    if extending:
        now, then = without_t_end(now), without_t_end(then)
    diff = first_difference(now, then)
    if diff is not None:
        raise ResumeError(f"{path}: belongs to another case: {diff}")
    wall = _header_number(saved, "wall_s", path)
    for key in ("steps", "t"):
        _header_number(saved, key, path, integer=key == "steps")
    parts = unflatten(saved)
    for key in ("steps", "t"):
        if key in parts["integrator"] and np.asarray(parts["integrator"][key]).shape == () and \
                parts["integrator"][key] != np.asarray(saved[key]).item():
            raise ResumeError(f"{path}: bad checkpoint: {key} = {np.asarray(saved[key]).item()!r} in the header, "
                              f"{parts['integrator'][key]!r} in the integrator's state")
    return parts, wall


def check_parts(path: Path, parts: dict[str, dict[str, Any]], fresh: dict[str, dict[str, Any]],
                 t_end: float) -> None:
    """Refuse a checkpoint whose state cannot be this run's: every entry a fresh run
    has must be there, numeric and finite, of the fresh run's shape (nodal arrays of
    this mesh's node count), counters whole numbers >= 0, t within [0, t_end], dt > 0."""
    def bad(name: str, what: str) -> ResumeError:
        return ResumeError(f"{path}: bad checkpoint: {name} {what}")

    nodal = np.shape(fresh["integrator"]["y"])
    for part in PARTS:
        have, want_part = parts[part], fresh[part]
        for key, want in want_part.items():
            if want is not None and key not in have:
                raise bad(f"{part}.{key}", "is missing")
        for key, value in have.items():
            name, want = f"{part}.{key}", want_part.get(key)
            arr = np.asarray(value)
            if arr.dtype.kind not in "biuf":
                raise bad(name, f"= {bounded_repr(value)}: must be numbers (dtype {arr.dtype})")
            if arr.dtype.kind == "f" and not np.all(np.isfinite(arr)):
                raise bad(name, f"holds {int(np.count_nonzero(~np.isfinite(arr)))} non-finite values")
            if part == "integrator" and (arr.ndim or (want is not None and np.ndim(want))):
                if arr.shape != nodal:
                    raise bad(name, f"has shape {arr.shape}, this mesh needs {nodal}")
            elif part == "model" and key.startswith("warm_"):
                if arr.ndim != 2 or arr.shape[1] != 3:
                    raise bad(name, f"has shape {arr.shape}, expected (n, 3)")
            elif want is not None and arr.ndim != np.ndim(want):
                raise bad(name, f"has shape {arr.shape}, expected {np.shape(want)}")
            elif want is None and part == "observer" and arr.ndim != 1:
                raise bad(name, f"has shape {arr.shape}, expected (n,)")
            if want is not None and np.ndim(want) == 0 and np.asarray(want).dtype.kind in "iub":
                x = float(arr) if arr.ndim == 0 else -1.0
                if not (x >= 0 and x.is_integer()):
                    raise bad(name, f"= {bounded_repr(value)}: must be a whole number >= 0")
    ig, snaps = parts["integrator"], parts["snapshots"]
    t, dt = float(ig["t"]), float(ig["dt"])
    if not 0.0 <= t <= t_end + end_tolerance(t_end):
        raise bad("integrator.t", f"= {t!r}: must be in [0, time.t_end = {t_end!r}]")
    if not dt > 0.0:
        raise bad("integrator.dt", f"= {dt!r}: must be > 0")
    if not 1 <= int(snaps["count"]) <= int(ig["steps"]) + 1:
        raise bad("snapshots.count", f"= {int(snaps['count'])}: must be in [1, steps + 1 = {int(ig['steps']) + 1}]")
    if not 0.0 <= float(snaps["last_time"]) <= t:
        raise bad("snapshots.last_time", f"= {float(snaps['last_time'])!r}: must be in [0, t = {t!r}]")


def save(path: str | os.PathLike, parts: dict[str, dict[str, Any]], config_yaml: str, wall_s: float) -> None:
    """Write the run's parts with the header (case, wall time, format, steps and t)."""
    write_checkpoint(path, {**flatten(parts), **_header(parts, config_yaml, wall_s)})


def _header(parts: dict[str, dict[str, Any]], config_yaml: str, wall_s: float) -> dict[str, Any]:
    # steps and t also at the top level: where the checkpoint stands, for whoever watches it
    return {"config_yaml": config_yaml, "wall_s": wall_s, "format": FORMAT,
            "steps": parts["integrator"]["steps"], "t": parts["integrator"]["t"]}

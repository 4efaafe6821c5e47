"""Campaigns: a grid (or zip) of cases run on a process pool or a Dask cluster.

A campaign file names a partial case (``base``), the case fields to sweep as a
full grid (``sweep``) and fields that vary together (``zip``), and an output
directory::

    name: fig9-spheres
    base: {shape: {kind: sphere}, mesh: {level: 3}, time: {t_end: 20}}
    sweep:
      flow.shear_rate_G: [0.0125, 0.025, 0.05, 0.1, 0.2, 0.45]
      flow.viscosity_ratio: [0.2, 1.0, 5.0]
    zip: {}
    output: {dir: runs/fig9-spheres}

Every expanded case is validated before any run starts. Each run gets a stable
id (readable swept values plus a hash of every case field the campaign sets, so
a changed base never reuses an old file) and writes ``<dir>/<id>.h5``. The directory
also holds ``campaign.yaml`` (the campaign as resolved) and ``runs.json`` (the
index of runs: id, file, swept values, grid position, last known status).

Executors
---------
Local (default): :func:`capsim.campaigns.executor.run_batch`, N spawned worker
processes with ``cores // N`` numba threads each (processes x threads = cores,
set before numba is imported, :mod:`capsim.numerics.threads`); the kernels of every
kind of case in the campaign are compiled (and cached on disk) once in the
parent before the workers start.
Dask: with ``scheduler="tcp://host:port"`` the runs are submitted to an
existing ``dask.distributed`` cluster (``pip install 'capsim[cluster]'``).
Each run applies capsim's thread policy in its worker process before numba is
imported: ``cores // (the cluster's worker threads on that host)`` numba threads,
unless the worker's environment sets ``NUMBA_NUM_THREADS`` (which wins); one run
per worker process, numba threads filling the node's cores::

    dask scheduler                                   # prints tcp://HOST:8786
    NUMBA_NUM_THREADS=4 dask worker tcp://HOST:8786 --nworkers 4 --nthreads 1   # 16-core node
    capsim sweep campaign.yaml --scheduler tcp://HOST:8786

The workers need capsim installed and the output directory on a shared file
system. On Dask there is no per-run kt in the progress line, and Ctrl-C drops
the pending runs but lets the running ones finish (unrecorded: redone next time).

Resume: a run whose file says ``completed`` is skipped; any other is redone.
Extension: a raised base t_end (``sweep --set time.t_end=...``) extends each completed run
in place from its end state; a lowered one, or extending a measured accuracy target's
kept runs, is refused before anything in the directory is written (``--overwrite`` redoes them).
One run that raises is recorded as ``failed`` with its reason; the others go
on. Ctrl-C cancels the pending runs and stops the running ones, whose files
are closed with status ``interrupted`` (redone on the next sweep).
"""

from __future__ import annotations

import hashlib
import itertools
import json
import math
import os
import re
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Annotated, Any

import yaml
from pydantic import BaseModel, ConfigDict, Field, ValidationError, model_validator

from capsim.config import NAME_MAX, YAML_DUMPER, yaml_text, Case, ConfigError, StrictModel, case_from_dict, model_from_mapping, read_yaml, section_model
from capsim.errors import bounded_repr, first_line
from capsim.campaigns.executor import WORKER_DIED, SigtermAsInterrupt, one_line, run_batch
from capsim.storage.files import write_durably
from capsim.storage.store import FileLock, StorageError
from capsim.numerics.threads import apply_policy as apply_thread_policy
from capsim.numerics.threads import usable_cores  # noqa: F401  (processes x threads = these cores)

__all__ = [
    "Campaign",
    "RunSpec",
    "expand_campaign",
    "load_campaign",
    "run_campaign",
    "execute_run",
    "campaign_from_dict",
]

from capsim.storage.files import CAMPAIGN_FILE, INDEX_FILE  # noqa: E402 - named once, for every guard
#: default most runs of a campaign (``capsim sweep --max-runs``): every run is validated
#: before the first starts (~3 ms each), and a grid this large is nearly always a mistake
MAX_RUNS = 10_000
#: longest campaign name (it names the directory's campaign; run ids carry their own limit)
CAMPAIGN_NAME_MAX = 100


_Model = StrictModel  # as strict as a case: unknown fields, NaN/inf and coerced scalars are errors


class CampaignOutput(_Model):
    dir: str = Field(min_length=1, description="directory of the run files, campaign.yaml, runs.json")


_Values = Annotated[list[Any], Field(min_length=1)]


class Campaign(_Model):
    """A sweep over dotted case fields; see the module docstring."""

    name: str = Field(
        min_length=1, max_length=CAMPAIGN_NAME_MAX, pattern=r"^[A-Za-z0-9._-]+$",
        description=f"at most {CAMPAIGN_NAME_MAX} characters",
    )
    base: dict[str, Any] = Field(default_factory=dict, description="partial case, shared by every run")
    sweep: dict[str, _Values] = Field(default_factory=dict, description="full grid over these fields")
    zip: dict[str, _Values] = Field(default_factory=dict, description="fields that vary together")
    output: CampaignOutput

    @model_validator(mode="after")
    def _consistent(self) -> Campaign:
        lengths = {key: len(values) for key, values in self.zip.items()}
        if len(set(lengths.values())) > 1:
            shown = ", ".join(f"{key} has {n}" for key, n in lengths.items())
            raise ValueError(f"zip lists must have equal lengths ({shown})")
        both = sorted(set(self.sweep) & set(self.zip))
        if both:
            raise ValueError(f"{', '.join(both)} cannot be in both sweep and zip")
        named: dict[str, str] = {}
        for key in [*self.sweep, *self.zip]:  # flow.G and flow.shear_rate_G are one field
            other = named.setdefault(canonical_field(key), key)
            if other != key:
                raise ValueError(f"{other} and {key} name one field ({canonical_field(key)}); vary it once")
        output = self.base.get("output")
        if "name" in self.base or (isinstance(output, dict) and "path" in output):
            raise ValueError("base: name and output.path are set per run by the campaign; remove them")
        for section in ("sweep", "zip"):
            for key in getattr(self, section):
                if key in ("name", "output.path"):
                    raise ValueError(f"{section}.{key}: name and output.path are set per run by the campaign")
        return self

    def to_yaml(self) -> str:
        return yaml.dump(self.model_dump(mode="json"), Dumper=YAML_DUMPER, sort_keys=False)

    @property
    def is_grid(self) -> bool:
        """True when the runs form a full grid over the swept fields (no zip)."""
        return not self.zip


class RunSpec(BaseModel):
    """One expanded run: what a worker needs, and where it sits in the campaign."""

    model_config = ConfigDict(frozen=True)

    run_id: str
    path: str
    params: dict[str, Any]
    grid_index: tuple[int, ...]
    case_yaml: str

    def case(self) -> Case:
        return case_from_dict(yaml_text(self.case_yaml), source=self.run_id)

    def digest(self) -> str:
        """:func:`capsim.config.case_digest` of this run's case (what its run file must hold)."""
        from capsim.config import case_digest

        return case_digest(self.case())


# ---------------------------------------------------------------- loading


def load_campaign(path: str | os.PathLike, max_runs: int = MAX_RUNS) -> Campaign:
    """Read a campaign file (with the case loader's limits); any mistake raises a one-line ConfigError."""
    source = os.fspath(path)
    return campaign_from_dict(read_yaml(source), source=source, max_runs=max_runs)


def load_campaign_with(path: str | os.PathLike, sets: list[str] | None = None, *, max_runs: int = MAX_RUNS,
                       data: Any = None) -> Campaign:
    """The campaign at `path` (or its already read `data`) with ``--set`` texts written
    into its base; a field the campaign sweeps cannot be set. One-line ConfigError."""
    from capsim.config import parse_sets

    if max_runs < 1:
        raise ConfigError(f"--max-runs = {max_runs}: must be >= 1")
    dotted = parse_sets(sets)
    data = read_yaml(path) if data is None else data
    if dotted and isinstance(data, dict):
        data = dict(data)
        base = json.loads(json.dumps(data.get("base") or {}, default=str)) if isinstance(
            data.get("base") or {}, dict) else data.get("base")
        varied = {canonical_field(k) for k in [*(data.get("sweep") or {}), *(data.get("zip") or {})]
                  if isinstance(k, str)}
        for key, value in dotted.items():
            if canonical_field(key) in varied:
                raise ConfigError(f"--set {key}: the campaign sweeps this field; change its sweep instead")
            node = base
            parts = key.split(".")
            for part in parts[:-1]:
                if not isinstance(node, dict):
                    break
                node = node.setdefault(part, {})
            if not isinstance(node, dict):
                raise ConfigError(f"--set {key}: '{'.'.join(parts[:-1])}' is not a section of the case")
            node[parts[-1]] = value
        data["base"] = base
    return campaign_from_dict(data, source=str(path), max_runs=max_runs)


def campaign_from_dict(d: Any, source: str = "<campaign>", max_runs: int = MAX_RUNS) -> Campaign:
    """Validate a campaign and every case it expands to (before any run starts).

    A campaign of more than ``max_runs`` runs is refused from its size alone,
    before any case is built.
    """
    campaign = model_from_mapping(Campaign, d, source)
    n_runs = count_runs(campaign)
    if n_runs > max_runs:
        sizes = " x ".join(
            [f"{short_name(k)} {len(v)}" for k, v in campaign.sweep.items()]
            + ([f"zip {len(next(iter(campaign.zip.values())))}"] if campaign.zip else [])
        )
        raise ConfigError(
            f"{source}: sweep/zip: the campaign has {n_runs} runs ({bounded_repr(sizes, 120)[1:-1]}), more than "
            f"--max-runs {max_runs}; split it into smaller campaigns or raise --max-runs"
        )
    case_from_dict({**campaign.base, "name": "base"}, source=f"{source}: base")
    for section in ("sweep", "zip"):
        for key in getattr(campaign, section):
            _check_dotted(key, f"{source}: {section}")
    expand_campaign(campaign, source=source)
    return campaign


def count_runs(campaign: Campaign) -> int:
    """Number of runs of the campaign (grid size times zip length), without expanding it."""
    zip_len = len(next(iter(campaign.zip.values()))) if campaign.zip else 1
    return math.prod(len(v) for v in campaign.sweep.values()) * zip_len


def _check_dotted(key: str, where: str) -> None:
    """Refuse a dotted path that is not a leaf field of a Case (or a field's short name: flow.G)."""
    from capsim.config import _ALIASES

    model: type[BaseModel] = Case
    parts = _ALIASES.get(key, key).split(".")
    for i, part in enumerate(parts):
        field = model.model_fields.get(part)
        if field is None:
            owner = ".".join(parts[:i]) or "a case"
            raise ConfigError(
                f"{where}: {bounded_repr(key)} is not a case field ({bounded_repr(owner)[1:-1]} has: "
                f"{', '.join(model.model_fields)})"
            )
        ann = section_model(field.annotation)  # an optional section too (membrane.viscosity, flow.history)
        is_section = ann is not None
        last = i == len(parts) - 1
        if is_section and last:
            raise ConfigError(f"{where}: {key!r} is a section; sweep one of its fields ({', '.join(ann.model_fields)})")
        if not is_section and not last:
            raise ConfigError(f"{where}: {bounded_repr(key)}: {'.'.join(parts[: i + 1])} is not a section")
        if is_section:
            model = ann


# ---------------------------------------------------------------- expansion


def short_name(key: str) -> str:
    """Readable name of a swept field: its last dotted component."""
    return key.rsplit(".", 1)[-1]


def _show_value(value: Any, position: int = 0) -> str:
    """A swept value as a run id shows it; a structured one (a list of capsules, each a mapping)
    by its position in the sweep's list (its digest tells the cases apart)."""
    if isinstance(value, dict) or (isinstance(value, (list, tuple)) and any(isinstance(v, dict) for v in value)):
        return str(position)
    text = format(value, "g") if isinstance(value, float) else str(value)
    return re.sub(r"[^A-Za-z0-9._-]", "_", text)


def canonical_field(key: str) -> str:
    """A dotted case field by its full name (``flow.G`` is ``flow.shear_rate_G``)."""
    from capsim.config import _ALIASES

    return _ALIASES.get(key, key)


def _set_dotted(data: dict, key: str, value: Any) -> None:
    """Set a dotted field, under its full name; a short name of the same field that the base
    writes (a sweep of flow.G over a base with flow.shear_rate_G, or the reverse) gives way."""
    from capsim.config import _ALIASES

    full = canonical_field(key)
    node = data
    *sections, leaf = full.split(".")
    for part in sections:
        node = node.setdefault(part, {})
    for other in (name for name, target in _ALIASES.items() if target == full):
        if isinstance(node, dict):
            node.pop(other.rsplit(".", 1)[-1], None)
    node[leaf] = value


def expand_campaign(campaign: Campaign, source: str = "<campaign>") -> list[RunSpec]:
    """Every run of the campaign, in grid order (last swept field fastest)."""
    out_dir = Path(campaign.output.dir)
    sweep_keys = list(campaign.sweep)
    grid = itertools.product(*(range(len(v)) for v in campaign.sweep.values()))
    zip_len = len(next(iter(campaign.zip.values()))) if campaign.zip else 1
    specs: list[RunSpec] = []
    seen: dict[str, dict] = {}
    for index in grid:
        for z in range(zip_len):
            params = {key: campaign.sweep[key][i] for key, i in zip(sweep_keys, index)}
            params.update({key: values[z] for key, values in campaign.zip.items()})
            data = json.loads(json.dumps(campaign.base))
            for key, value in params.items():
                _set_dotted(data, key, value)
            label = ", ".join(f"{k}={bounded_repr(v)}" for k, v in params.items()) or "the only run"
            label = label if len(label) <= 160 else label[:157] + "..."
            data["name"] = "run"
            case = case_from_dict(data, source=f"{source}: run {label}")
            # Only what the campaign sets (coerced by the schema, so 1 and 1.0 agree): a default
            # added to capsim later does not rename every run of an existing campaign.
            physics = case.model_dump(mode="json", exclude_unset=True, exclude={"name", "output"})
            # nor t_end: a campaign extended to a later t_end (sweep --set time.t_end=...) keeps its
            # run files, which are extended in place
            physics.get("time", {}).pop("t_end", None)
            digest = hashlib.sha1(json.dumps(physics, sort_keys=True).encode()).hexdigest()[:8]
            positions = {**dict(zip(sweep_keys, index)), **{key: z for key in campaign.zip}}
            readable = "-".join(f"{short_name(k)}{_show_value(v, positions[k])}" for k, v in params.items())
            run_id = f"{readable}-{digest}" if readable else digest
            if len(run_id) > NAME_MAX:
                raise ConfigError(
                    f"{source}: sweep/zip: run {label} has an id of {len(run_id)} characters "
                    f"({bounded_repr(run_id, 50)}), more than {NAME_MAX}: it names the run's files and "
                    "a file name is at most 255 bytes; sweep fewer fields or shorter values"
                )
            if run_id in seen:
                raise ConfigError(
                    f"{source}: runs {bounded_repr(seen[run_id], 120)} and {bounded_repr(params, 120)} are the same case"
                )
            seen[run_id] = params
            path = out_dir / f"{run_id}.h5"
            data["name"] = run_id
            data.setdefault("output", {})["path"] = str(path)
            case = case_from_dict(data, source=f"{source}: run {label}")
            grid_index = tuple(index) if campaign.is_grid else (len(specs),)
            specs.append(RunSpec(
                run_id=run_id, path=str(path), params=params, grid_index=grid_index,
                case_yaml=case.to_yaml(),
            ))
    return specs


# ---------------------------------------------------------------- one run


def _record(spec: RunSpec, status: str, reason: str, **extra: Any) -> dict[str, Any]:
    return {"run_id": spec.run_id, "status": status, "status_reason": reason, **extra}


def execute_run(spec: RunSpec, progress: Any = None) -> dict[str, Any]:
    """Run one case in this process; never raises for a failing case.

    Returns the run summary (or a ``failed`` record with the exception text).
    `progress` is run_case's progress callback. A run interrupted earlier
    continues from its checkpoint (same step sequence as an uninterrupted run);
    otherwise a stale file of an earlier attempt is removed first so that the
    file on disk belongs to this attempt.
    """
    try:
        # A Dask worker (or any fresh process) gets capsim's thread policy before numba loads;
        # in a pool worker or once numba is imported this changes nothing.
        if "numba" not in sys.modules:
            apply_thread_policy(workers=_dask_slots_on_this_host())
        import numba

        from capsim.runs.runner import ResumeError, run_case
        from capsim.storage.store import checkpoint_path

        case = spec.case()
        summary = None
        if (checkpoint_path(spec.path).exists() and Path(spec.path).exists()) or _file_status(spec) == EXTENDABLE:
            try:
                summary = run_case(case, progress=progress, resume=True)
            except ResumeError:
                summary = None  # damaged or foreign checkpoint: start over
        if summary is None:  # the new file replaces a stale one atomically, under the run file's lock
            summary = run_case(case, progress=progress)
        return _record(spec, summary["status"], summary["status_reason"], summary=summary,
                       numba_threads=numba.get_num_threads())
    except Exception as exc:  # one bad case must not stop the campaign
        return _record(spec, "failed", one_line(exc))


def _dask_slots_on_this_host() -> int:
    """Runs a Dask cluster may run at once on this host (its workers' threads); 1 off Dask.

    Each run then gets cores // slots numba threads, as the local pool's workers do.
    """
    try:
        from distributed import get_worker

        worker = get_worker()
    except (ImportError, ValueError):  # not inside a Dask task
        return 1
    try:
        host = worker.address.rsplit(":", 1)[0]
        workers = worker.client.scheduler_info(n_workers=-1)["workers"]
        slots = sum(int(w.get("nthreads", 1)) for a, w in workers.items() if a.rsplit(":", 1)[0] == host)
        return max(1, slots)
    except Exception:  # an older distributed, a lost scheduler: all cores
        return 1


# ---------------------------------------------------------------- campaign


#: the status of a run whose path holds the run file of another case
FOREIGN = "foreign"


def _file_status(spec: RunSpec) -> str | None:
    """The status of the run file at a run's path; :data:`FOREIGN` when that file
    holds another case (another G, level, ...), so that it is neither skipped as
    done nor summarised as this run; None when there is no readable file."""
    from capsim.storage.store import read_run_identity

    status, digest = read_run_identity(spec.path)
    if status is None:
        return None
    if digest == spec.digest():
        return status
    held = _held_t_end(spec)
    if held is None:
        return FOREIGN
    t_end, measured = held
    ours = spec.case().time.t_end
    if t_end > ours:
        return SHORTENED
    if t_end == ours:  # another explanation of the same choice (a newer capsim's text): not this run's file
        return FOREIGN
    if measured:
        return MEASURED
    if status != "completed":  # an unfinished run of this case: resumed or redone, to the new t_end
        return status
    return EXTENDABLE if _has_end_state(spec) else FOREIGN


#: a completed run file of this run's case to an earlier t_end, with the end state that
#: ``--resume`` extends (the campaign's base time.t_end raised: ``sweep --set time.t_end=...``)
EXTENDABLE = "extendable"
#: a run file of this run's case to a later t_end: the campaign's t_end was lowered, which is
#: not an extension (the sweep is refused before anything is written; --overwrite redoes the runs)
SHORTENED = "shortened"
#: the kept run of a measured accuracy target (its ladder's verdict holds at the t_end it
#: measured) asked for at a later t_end: refused like SHORTENED (an extension would keep a run
#: whose error nobody measured at the new t_end, and it drops the ladder from the file)
MEASURED = "measured"
#: the statuses that refuse the whole sweep unless --overwrite (then they are redone)
_REFUSING = (SHORTENED, MEASURED)


def _held_t_end(spec: RunSpec) -> tuple[float, bool] | None:
    """(t_end, measured) of the case the file at the run's path holds, when that case is this
    run's but for its t_end (and the texts that explain its choices, which name a cost that grows
    with t_end); measured: the file is a measured target's kept run. None otherwise."""
    from capsim.storage.checkpoint import without_t_end
    from capsim.config import step_defining
    from capsim.storage.store import REQUESTED_CASE, read_run_record

    try:
        attrs = (read_run_record(spec.path) or {}).get("attrs", {})
        text = attrs.get(REQUESTED_CASE) or attrs.get("config_yaml")
        stored = case_from_dict(yaml_text(text), source=spec.path).model_dump(mode="json")
        ours = spec.case().model_dump(mode="json")
        if without_t_end(step_defining(stored)) != without_t_end(step_defining(ours)):
            return None
        return float(stored["time"]["t_end"]), REQUESTED_CASE in attrs
    except Exception:  # noqa: BLE001 - an unreadable file is not this run's
        return None


def _has_end_state(spec: RunSpec) -> bool:
    """Whether the completed file at the run's path kept the end state an extension continues from."""
    from capsim.storage.store import read_end_state

    try:
        return read_end_state(spec.path) is not None
    except Exception:  # noqa: BLE001 - an unreadable file is not this run's to extend
        return False


def _refusal(campaign: Campaign, specs: list[RunSpec], statuses: list[str | None]) -> str | None:
    """Why the campaign's t_end cannot be applied to the runs already in its directory (one line),
    or None. Checked before anything is written: campaign.yaml and runs.json stay as they were."""
    t_end = specs[0].case().time.t_end if specs else math.nan
    where = bounded_repr(campaign.output.dir)
    for status, why in (
        (SHORTENED, "already run to kt {held:g}; shortening a campaign is not an extension"),
        (MEASURED, "are kept runs of a measured accuracy target, whose ladder measured the error at kt "
                   "{held:g}; extending them would keep runs whose error nobody measured at the new t_end"),
    ):
        hit = [spec for spec, s in zip(specs, statuses) if s == status]
        if hit:
            held = max((_held_t_end(spec) or (math.nan,))[0] for spec in hit)
            return (f"time.t_end = {t_end:g}: {len(hit)} of the {len(specs)} runs in {where} "
                    f"({hit[0].run_id}{', ...' if len(hit) > 1 else ''}) {why.format(held=held)}; nothing was "
                    f"changed: use another output.dir, or --overwrite to redo them to kt {t_end:g}")
    return None


def campaign_digest(campaign: Campaign) -> str:
    """The identity of a campaign: a hash of its name, base, sweep and zip (not of
    its output.dir, so that a copied or moved directory stays the campaign's)."""
    data = campaign.model_dump(mode="json", exclude={"output"})
    # not of the base's t_end either: raising it (sweep --set time.t_end=...) extends the same campaign
    data["base"].get("time", {}).pop("t_end", None)
    return hashlib.sha256(json.dumps(data, sort_keys=True).encode()).hexdigest()[:16]


def _index_entries(specs: list[RunSpec], old: dict[str, Any]) -> dict[str, dict]:
    """runs.json's entries, statuses from the run files (runs.json itself is never trusted for them)."""
    runs = {}
    for s in specs:
        status = _file_status(s) or "pending"
        before = old.get(s.run_id) if isinstance(old.get(s.run_id), dict) else {}
        reason = before.get("status_reason", "") if before.get("status") == status else ""
        runs[s.run_id] = {"file": Path(s.path).name, "params": s.params, "grid_index": list(s.grid_index),
                          "status": status, "status_reason": reason if isinstance(reason, str) else ""}
    return runs


class _Index:
    """runs.json: every run's id, file, swept values and last known status (from the
    run files; a damaged runs.json is rebuilt). Written atomically (temporary file,
    fsync, rename); a write that fails is remembered, not raised, once the runs are
    under way (:attr:`write_error`): the run files keep every status."""

    def __init__(self, out_dir: Path, specs: list[RunSpec], digest: str) -> None:
        self.path = out_dir / INDEX_FILE
        self.digest = digest
        self.write_error: str | None = None
        try:
            old = _read_index(out_dir)[0] if self.path.exists() else {}
        except ConfigError:  # damaged: rebuilt from the run files
            old = {}
        self.runs = _index_entries(specs, old)

    def update(self, record: dict[str, Any]) -> None:
        entry = self.runs[record["run_id"]]
        entry["status"] = record["status"]
        entry["status_reason"] = record["status_reason"]
        try:
            self.write()
        except StorageError as exc:
            self.write_error = str(exc)

    def write(self) -> None:
        text = json.dumps({"campaign": self.digest, "runs": self.runs}, indent=1, default=str)
        write_durably(self.path, lambda fh: fh.write(text.encode("utf-8")), "the previous runs.json is kept")


def _read_index(out_dir: str | os.PathLike) -> tuple[dict[str, dict], str | None]:
    """(runs, campaign digest) of runs.json; ConfigError (one line) for a damaged one."""
    path = Path(out_dir) / INDEX_FILE
    try:
        with open(path, encoding="utf-8") as fh:
            data = json.loads(fh.read(64 * 2**20 + 1))
        runs = data["runs"]
        if not isinstance(runs, dict) or not all(isinstance(v, dict) for v in runs.values()):
            raise TypeError("runs is not a mapping of entries")
    except (OSError, ValueError, KeyError, TypeError) as exc:
        raise ConfigError(f"{path}: damaged index ({type(exc).__name__}: {bounded_repr(first_line(exc), 80)[1:-1]})") from None
    digest = data.get("campaign")
    return runs, digest if isinstance(digest, str) else None


def load_index(out_dir: str | os.PathLike, campaign: Campaign | None = None) -> dict[str, dict]:
    """The runs of runs.json. A damaged runs.json is rebuilt from the run files when
    the campaign is given (``campaign.yaml``), else a one-line ConfigError."""
    try:
        return _read_index(out_dir)[0]
    except ConfigError:
        if campaign is None:
            raise
        return _index_entries(expand_campaign(campaign), {})


ProgressCallback = Callable[[dict[str, Any]], None]


def run_campaign(
    campaign: Campaign,
    *,
    workers: int | None = None,
    scheduler: str | None = None,
    resume: bool = True,
    progress: ProgressCallback | None = None,
    overwrite: bool = False,
) -> dict[str, Any]:
    """Run every run of the campaign that is not already completed.

    Returns ``{"total", "skipped", "completed", "failed", "interrupted",
    "records"}``; ``failed`` counts every run that did not complete.
    ``progress`` is called with ``{"total", "skipped", "done", "failed",
    "running", "kt": {run_id: t}}`` whenever something changes.

    The directory belongs to one campaign (:func:`campaign_digest`): another one is
    refused (ConfigError) unless ``overwrite``; a second sweep on it while this one
    runs is refused by the directory's lock (:class:`capsim.storage.store.LockedError`).
    A failure to write ``campaign.yaml`` or ``runs.json`` raises
    :class:`capsim.storage.store.StorageError` (at the end, once the runs are under way).
    """
    if scheduler is not None:  # before the directory's lock: a bad address holds nothing
        check_scheduler(scheduler)
    specs = expand_campaign(campaign)
    out_dir = Path(campaign.output.dir)
    try:
        out_dir.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise ConfigError(
            f"output.dir = {str(out_dir)!r}: cannot create or write the campaign directory "
            f"({exc.strerror or type(exc).__name__})"
        ) from None
    with FileLock(out_dir, what="campaign directory (another sweep is running on it)"):
        return _run_locked(campaign, specs, out_dir, workers=workers, scheduler=scheduler, resume=resume,
                           progress=progress, overwrite=overwrite)


#: seconds to wait for a scheduler to accept a connection and to greet
SCHEDULER_TIMEOUT_S = 5.0


def check_scheduler(address: str, timeout: float = SCHEDULER_TIMEOUT_S) -> None:
    """Refuse (ConfigError, one line, within `timeout` seconds each for the connection
    and the greeting) an address that is not ``tcp://HOST:PORT`` of a Dask scheduler:
    a malformed one, a closed port, a service that is not Dask (a Dask scheduler
    sends its handshake at once: a frame of 8-byte total length and frame count)."""
    import socket
    import struct

    shown = bounded_repr(address)
    allowed = "allowed: tcp://HOST:PORT of a running Dask scheduler (dask scheduler prints it)"
    if not isinstance(address, str) or not address.startswith("tcp://"):
        raise ConfigError(f"--scheduler {shown}: not a scheduler address; {allowed}")
    hostport = address[len("tcp://"):].rstrip("/")
    host, sep, port_text = hostport.rpartition(":")
    host = host[1:-1] if host.startswith("[") and host.endswith("]") else host
    if not sep or not host or not port_text.isdigit() or not 1 <= int(port_text) <= 65535 or "/" in host:
        raise ConfigError(f"--scheduler {shown}: no HOST:PORT with a port in 1..65535; {allowed}")
    try:
        with socket.create_connection((host, int(port_text)), timeout=timeout) as sock:
            sock.settimeout(timeout)
            greeting = b""
            while len(greeting) < 16:
                chunk = sock.recv(16 - len(greeting))
                if not chunk:
                    break
                greeting += chunk
    except socket.timeout:
        raise ConfigError(f"--scheduler {shown}: no Dask scheduler answered within {timeout:g} s; {allowed}") from None
    except (OSError, UnicodeError, ValueError) as exc:
        reason = getattr(exc, "strerror", None) or first_line(exc)
        raise ConfigError(f"--scheduler {shown}: cannot connect ({reason}); {allowed}") from None
    if len(greeting) < 16:
        raise ConfigError(f"--scheduler {shown}: the service there closed the connection; it is not a Dask "
                          f"scheduler; {allowed}")
    total, frames = struct.unpack("<QQ", greeting)
    if not (0 < total < 2**30 and 0 < frames <= 10_000):
        raise ConfigError(f"--scheduler {shown}: the service there is not a Dask scheduler; {allowed}")


def plan_lines(campaign: Campaign, source: str = "<campaign>") -> list[str]:
    """A dry run (``capsim validate CAMPAIGN.yaml``): a head line, then per run its id, what
    a sweep would do (run, or skip a completed file that holds this run's case), its
    path and swept values."""
    specs = expand_campaign(campaign, source=source)
    statuses = [_file_status(spec) for spec in specs]
    refusal = _refusal(campaign, specs, statuses)
    actions = [_PLAN_ACTIONS.get(status, "run") for status in statuses]
    if refusal is not None:  # the sweep refuses every run (without --overwrite)
        actions = ["refused"] * len(specs)
    extend = f", {actions.count('extend')} to extend" if "extend" in actions else ""
    lines = [f"{campaign.name}: {len(specs)} runs, {actions.count('run')} to run{extend} -> {campaign.output.dir}"]
    width = max(len(spec.run_id) for spec in specs)
    for spec, action in zip(specs, actions):
        swept = ", ".join(f"{k}={v}" for k, v in spec.params.items())
        lines.append(f"{spec.run_id:<{width}}  {action:<16}  {spec.path}" + (f"  {swept}" if swept else ""))
    if refusal is not None:
        lines.append(f"refused: {refusal}")
    return lines


#: what a sweep does with a run whose file has this status (validate's dry run); any other: run it
_PLAN_ACTIONS = {"completed": "skip (completed)", EXTENDABLE: "extend", FOREIGN: "refused (foreign)",
                 SHORTENED: "refused", MEASURED: "refused"}


def _owner(out_dir: Path) -> tuple[str | None, str]:
    """(digest, name) of the campaign a directory holds; (None, "") for none."""
    path = out_dir / CAMPAIGN_FILE
    if path.exists():
        try:
            held = Campaign.model_validate(read_yaml(os.fspath(path)))
            return campaign_digest(held), held.name
        except (ConfigError, ValidationError, TypeError, ValueError):
            pass
    if (out_dir / INDEX_FILE).exists():
        try:
            digest = _read_index(out_dir)[1]
        except ConfigError:
            digest = None
        if digest is not None:
            return digest, "?"
    if path.exists():
        return "unreadable", "?"
    return None, ""


def _claim(campaign: Campaign, out_dir: Path, overwrite: bool) -> str:
    """This campaign's digest, once the directory is its own; campaign.yaml written atomically."""
    digest = campaign_digest(campaign)
    held, name = _owner(out_dir)
    if held is not None and held != digest and not overwrite:
        what = ("a campaign.yaml that is not a readable campaign" if held == "unreadable"
                else f"another campaign ({bounded_repr(name)}, {held})")
        raise ConfigError(
            f"output.dir = {bounded_repr(str(out_dir))}: holds {what}, not {bounded_repr(campaign.name)} "
            f"({digest}); nothing was changed: use another output.dir, or --overwrite to take the directory over"
        )
    path = out_dir / CAMPAIGN_FILE
    text = campaign.to_yaml()
    try:
        current = path.read_text(encoding="utf-8") if path.exists() else None
    except (OSError, UnicodeDecodeError):
        current = None
    if current != text:
        write_durably(path, lambda fh: fh.write(text.encode("utf-8")), "nothing was changed")
    return digest


def _run_locked(campaign, specs, out_dir, *, workers, scheduler, resume, progress, overwrite) -> dict[str, Any]:
    if not overwrite:  # before campaign.yaml or runs.json is touched
        refusal = _refusal(campaign, specs, [_file_status(spec) for spec in specs])
        if refusal is not None:
            raise ConfigError(refusal)
    digest = _claim(campaign, out_dir, overwrite)
    index = _Index(out_dir, specs, digest)
    todo, refused = [], []
    for spec in specs:
        status = index.runs[spec.run_id]["status"]
        if resume and status == "completed":
            index.runs[spec.run_id].update(status="completed", status_reason="")
        elif status == FOREIGN and not overwrite:  # never replaced unasked
            reason = (f"{spec.path} holds the run file of another case; nothing was changed: "
                      "move it away, or pass --overwrite to replace it")
            index.runs[spec.run_id].update(status=FOREIGN, status_reason=reason)
            refused.append(_record(spec, FOREIGN, reason))
        else:
            todo.append(spec)
    index.write()
    state = {"total": len(specs), "skipped": len(specs) - len(todo) - len(refused), "done": 0, "failed": 0,
             "running": 0, "kt": {}}  # kt: the runs started and not finished
    records: list[dict] = list(refused)
    state["failed"] += len(refused)
    interrupted = False
    if todo:
        runner = _run_dask if scheduler else _run_local
        with SigtermAsInterrupt():
            interrupted = runner(todo, index, state, records, progress, workers=workers, scheduler=scheduler)
    if index.write_error is not None:
        raise StorageError(f"{index.write_error} (the run files keep each run's status; the next sweep rebuilds "
                           "runs.json from them)")
    return {
        "total": len(specs),
        "skipped": state["skipped"],
        "completed": sum(r["status"] == "completed" for r in records),
        "failed": sum(r["status"] != "completed" for r in records),
        "interrupted": interrupted,
        "records": records,
    }


def _finish(record: dict, index: _Index, state: dict, records: list, progress) -> None:
    records.append(record)
    index.update(record)
    state["done" if record["status"] == "completed" else "failed"] += 1
    state["kt"].pop(record["run_id"], None)
    if progress is not None:
        progress(state)


def _reconcile(spec: RunSpec, record: dict) -> dict:
    """A run whose worker died: the record follows its file (completed before the worker
    died: completed; left 'running': marked failed in the file too), so that runs.json
    never contradicts the files."""
    if record["status"] != "failed" or not record["status_reason"].startswith(WORKER_DIED):
        return record
    from capsim.storage.store import mark_abandoned, read_run_record

    status = _file_status(spec)
    if status == "completed":
        found = read_run_record(spec.path) or {}
        return _record(spec, "completed", "", summary=dict(found.get("summary", {})))
    mark_abandoned(spec.path, record["status_reason"])
    return record


def _run_local(todo, index, state, records, progress, *, workers, scheduler) -> bool:
    def done(i: int, record: dict) -> None:
        _finish(_reconcile(todo[i], record), index, state, records, progress)

    def running(kt: dict[str, float]) -> None:
        state["kt"] = kt
        state["running"] = len(kt)
        if progress is not None:
            progress(state)

    outcome = run_batch(
        todo, execute_run, keys=[s.run_id for s in todo], workers=workers, warm=[s.case() for s in todo],
        failure=lambda i, status, reason: _record(todo[i], status, reason),
        on_done=done, on_progress=running, name="campaign",
    )
    return outcome.interrupted


def _run_dask(todo, index, state, records, progress, *, workers, scheduler) -> bool:
    try:
        from distributed import Client, as_completed
    except ImportError:
        raise ConfigError("--scheduler needs dask.distributed: pip install 'capsim[cluster]'") from None
    with Client(scheduler, timeout="30s") as client:
        futures = [
            client.submit(execute_run, spec, key=f"capsim-{spec.run_id}-{time.time_ns()}", pure=False)
            for spec in todo
        ]
        by_key = {f.key: spec for f, spec in zip(futures, todo)}
        state["running"] = len(futures)
        try:
            for fut in as_completed(futures):
                try:
                    record = fut.result()
                except Exception as exc:  # the worker was lost
                    record = _record(by_key[fut.key], "failed", f"worker lost: {type(exc).__name__}: {exc}")
                state["running"] -= 1
                _finish(record, index, state, records, progress)
            return False
        except KeyboardInterrupt:
            # Pending runs are dropped; a run already on a worker thread cannot be stopped
            # and finishes there, unrecorded; the next sweep redoes it.
            client.cancel(futures)
            return True

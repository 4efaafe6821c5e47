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
Local (default): a ``ProcessPoolExecutor`` (spawn context) with N worker
processes; each worker sets ``NUMBA_NUM_THREADS = cores // N`` in its
initializer, before numba is imported, so processes x threads = cores. The
numba kernels are compiled (and cached on disk) once in the parent, by a
one-step level-0 run, before the workers start.
Dask: with ``scheduler="tcp://host:port"`` the runs are submitted to an
existing ``dask.distributed`` cluster (``pip install 'capsim[cluster]'``).
One run per worker process, numba threads filling the node's cores::

    dask scheduler                                   # prints tcp://HOST:8786
    NUMBA_NUM_THREADS=4 dask worker tcp://HOST:8786 --nworkers 4 --nthreads 1   # 16-core node
    capsim sweep campaign.yaml --scheduler tcp://HOST:8786

The workers need capsim installed and the output directory on a shared file
system. On Dask there is no per-run kt in the progress line, and Ctrl-C drops
the pending runs but lets the running ones finish (unrecorded: redone next time).

Resume: a run whose file says ``completed`` is skipped; any other is redone.
One run that raises is recorded as ``failed`` with its reason; the others go
on. Ctrl-C cancels the pending runs and stops the running ones, whose files
are closed with status ``interrupted`` (redone on the next sweep).
"""

from __future__ import annotations

import concurrent.futures as cf
import hashlib
import itertools
import json
import math
import multiprocessing
import os
import queue
import re
import signal
import tempfile
import threading
import time
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Annotated, Any

import yaml
from pydantic import BaseModel, ConfigDict, Field, ValidationError, model_validator

from capsim.config import NAME_MAX, Case, ConfigError, case_from_dict, read_yaml
from capsim.errors import bounded_repr

__all__ = [
    "Campaign",
    "RunSpec",
    "expand_campaign",
    "load_campaign",
    "run_campaign",
    "execute_run",
    "campaign_from_dict",
]

INDEX_FILE = "runs.json"
CAMPAIGN_FILE = "campaign.yaml"
#: default most runs of a campaign (``capsim sweep --max-runs``): every run is validated
#: before the first starts (~3 ms each), and a grid this large is nearly always a mistake
MAX_RUNS = 10_000
#: longest campaign name (it names the directory's campaign; run ids carry their own limit)
CAMPAIGN_NAME_MAX = 100


class _Model(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


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
        output = self.base.get("output")
        if "name" in self.base or (isinstance(output, dict) and "path" in output):
            raise ValueError("base: name and output.path are set per run by the campaign; remove them")
        for section in ("sweep", "zip"):
            for key in getattr(self, section):
                if key in ("name", "output.path"):
                    raise ValueError(f"{section}.{key}: name and output.path are set per run by the campaign")
        return self

    def to_yaml(self) -> str:
        return yaml.safe_dump(self.model_dump(mode="json"), sort_keys=False)

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
        return case_from_dict(yaml.safe_load(self.case_yaml), source=self.run_id)


# ---------------------------------------------------------------- loading


def load_campaign(path: str | os.PathLike, max_runs: int = MAX_RUNS) -> Campaign:
    """Read a campaign file (with the case loader's limits); any mistake raises a one-line ConfigError."""
    source = os.fspath(path)
    return campaign_from_dict(read_yaml(source), source=source, max_runs=max_runs)


def campaign_from_dict(d: Any, source: str = "<campaign>", max_runs: int = MAX_RUNS) -> Campaign:
    """Validate a campaign and every case it expands to (before any run starts).

    A campaign of more than ``max_runs`` runs is refused from its size alone,
    before any case is built.
    """
    if not isinstance(d, Mapping):
        raise ConfigError(f"{source}: top level must be a mapping of fields, got {type(d).__name__}")
    try:
        campaign = Campaign.model_validate(dict(d))
    except ValidationError as exc:
        raise ConfigError(_format_error(exc, source)) from None
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


def _format_error(exc: ValidationError, source: str) -> str:
    parts = []
    for err in exc.errors(include_url=False)[:3]:
        loc = ".".join(p if isinstance(p, str) and len(p) <= 40 else bounded_repr(p, 40) for p in map(str, err["loc"]))
        if err["type"] == "extra_forbidden":
            owner = Campaign if len(err["loc"]) == 1 else CampaignOutput
            what = f"unknown field {bounded_repr(str(err['loc'][-1]))} (allowed: {', '.join(owner.model_fields)})"
        elif err["type"] == "missing":
            what = "required field is missing"
        else:
            what = err["msg"].removeprefix("Value error, ")
            value = err.get("input")
            if err["loc"] and not isinstance(value, (dict, BaseModel)):
                what += f" (got {bounded_repr(value)})"
        parts.append(f"{loc}: {what}" if loc else what)
    return " ".join(f"{source}: {'; '.join(parts)}".split())


def _check_dotted(key: str, where: str) -> None:
    """Refuse a dotted path that is not a leaf field of a Case."""
    model: type[BaseModel] = Case
    parts = key.split(".")
    for i, part in enumerate(parts):
        field = model.model_fields.get(part)
        if field is None:
            owner = ".".join(parts[:i]) or "a case"
            raise ConfigError(
                f"{where}: {key!r} is not a case field ({owner} has: {', '.join(model.model_fields)})"
            )
        ann = field.annotation
        is_section = isinstance(ann, type) and issubclass(ann, BaseModel)
        last = i == len(parts) - 1
        if is_section and last:
            raise ConfigError(f"{where}: {key!r} is a section; sweep one of its fields ({', '.join(ann.model_fields)})")
        if not is_section and not last:
            raise ConfigError(f"{where}: {key!r}: {'.'.join(parts[: i + 1])} is not a section")
        if is_section:
            model = ann


# ---------------------------------------------------------------- expansion


def short_name(key: str) -> str:
    """Readable name of a swept field: its last dotted component."""
    return key.rsplit(".", 1)[-1]


def _show_value(value: Any) -> str:
    text = format(value, "g") if isinstance(value, float) else str(value)
    return re.sub(r"[^A-Za-z0-9._-]", "_", text)


def _set_dotted(data: dict, key: str, value: Any) -> None:
    node = data
    *sections, leaf = key.split(".")
    for part in sections:
        node = node.setdefault(part, {})
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
            data["name"] = "run"
            case = case_from_dict(data, source=f"{source}: run {label}")
            # Only what the campaign sets (coerced by the schema, so 1 and 1.0 agree): a default
            # added to capsim later does not rename every run of an existing campaign.
            physics = case.model_dump(mode="json", exclude_unset=True, exclude={"name", "output"})
            digest = hashlib.sha1(json.dumps(physics, sort_keys=True).encode()).hexdigest()[:8]
            readable = "-".join(f"{short_name(k)}{_show_value(v)}" for k, v in params.items())
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


def execute_run(spec: RunSpec, progress_queue: Any = None) -> dict[str, Any]:
    """Run one case in this process; never raises for a failing case.

    Returns the run summary (or a ``failed`` record with the exception text).
    A run interrupted earlier continues from its checkpoint (same step
    sequence as an uninterrupted run); otherwise a stale file of an earlier
    attempt is removed first so that the file on disk belongs to this attempt.
    """
    try:
        import numba

        from capsim.runner import ResumeError, run_case  # numba is first imported here, in the worker
        from capsim.store import checkpoint_path

        case = spec.case()
        callback = None
        if progress_queue is not None:
            progress_queue.put((spec.run_id, 0.0))  # started: the parent counts it as running
            callback = _QueueProgress(spec.run_id, progress_queue)
        summary = None
        if checkpoint_path(spec.path).exists() and Path(spec.path).exists():
            try:
                summary = run_case(case, progress=callback, resume=True)
            except ResumeError:
                summary = None  # damaged or foreign checkpoint: start over
        if summary is None:
            Path(spec.path).unlink(missing_ok=True)
            summary = run_case(case, progress=callback)
        return _record(spec, summary["status"], summary["status_reason"], summary=summary,
                       numba_threads=numba.get_num_threads())
    except Exception as exc:  # one bad case must not stop the campaign
        first = str(exc).splitlines()[0] if str(exc) else ""
        return _record(spec, "failed", f"{type(exc).__name__}: {first}".rstrip(": "))


class _QueueProgress:
    """Forward a run's kt to the parent at most once a second."""

    def __init__(self, run_id: str, q: Any) -> None:
        self.run_id, self.q, self._last = run_id, q, -math.inf

    def __call__(self, state: dict) -> None:
        now = time.monotonic()
        if now - self._last >= 1.0:
            self._last = now
            self.q.put((self.run_id, float(state.get("t", math.nan))))


# Set once per worker process by its initializer (the pool's way to hand over
# objects that cannot travel with each task).
_WORKER_QUEUE: Any = None
_WORKER_STOP: Any = None


_WORKER_BUSY = threading.Event()


def _init_worker(numba_threads: int, progress_queue: Any, stop: Any) -> None:
    # Must run before numba is imported: NUMBA_NUM_THREADS is read once, at import.
    os.environ["NUMBA_NUM_THREADS"] = str(numba_threads)
    # Ctrl-C goes to the whole process group; the parent decides what stops.
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    # So does a batch system's SIGTERM. An idle worker must not die of it: it waits
    # for work holding the task queue's lock, and dying there would leave every other
    # worker, and the pool's shutdown, waiting for that lock for ever. A running case
    # replaces this handler with run_case's, which closes the run as 'interrupted'.
    signal.signal(signal.SIGTERM, _ignore_while_idle)
    global _WORKER_QUEUE, _WORKER_STOP
    _WORKER_QUEUE, _WORKER_STOP = progress_queue, stop
    threading.Thread(target=_exit_with_parent, args=(os.getppid(),), daemon=True).start()


def _ignore_while_idle(signum, frame) -> None:
    """SIGTERM between runs: nothing to stop; the parent shuts the pool down."""


def _exit_with_parent(parent: int) -> None:
    # A killed parent must not leave workers computing for nobody: SIGTERM closes
    # the running run's file as 'interrupted' (run_case's guard); then the worker ends.
    while os.getppid() == parent:
        time.sleep(2.0)
    if _WORKER_BUSY.is_set():
        os.kill(os.getpid(), signal.SIGTERM)
        while _WORKER_BUSY.is_set():
            time.sleep(0.2)
    os._exit(0)


def _pool_run(spec: RunSpec) -> dict[str, Any]:
    if _WORKER_STOP is not None and _WORKER_STOP.is_set():
        return _record(spec, "interrupted", "campaign stopped before this run started")
    _WORKER_BUSY.set()
    try:
        return execute_run(spec, _WORKER_QUEUE)
    finally:
        _WORKER_BUSY.clear()


def warm_numba(specs: list[RunSpec]) -> None:
    """Compile and cache the kernels once: one step of a level-0 copy of each distinct kind of case."""
    from capsim.config import apply_overrides
    from capsim.runner import run_case

    kinds: dict[tuple, Case] = {}
    for spec in specs:
        case = spec.case()
        kinds.setdefault((case.membrane.law, case.membrane.traction, case.flow.viscosity_ratio != 1.0), case)
    with tempfile.TemporaryDirectory() as tmp:
        for case in kinds.values():
            tiny = apply_overrides(case, **{
                "mesh.level": 0, "time.t_end": case.time.dt_initial, "time.max_steps": 2,
                "output.path": os.path.join(tmp, "warm.h5"),
            })
            try:
                run_case(tiny)
            except Exception:  # the real run reports its own failure
                pass


# ---------------------------------------------------------------- campaign


def usable_cores() -> int:
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:
        return os.cpu_count() or 1


def _file_status(path: str) -> str | None:
    from capsim.summary import read_run_status

    return read_run_status(path)


class _Index:
    """runs.json: every run's id, file, swept values and last known status."""

    def __init__(self, out_dir: Path, specs: list[RunSpec]) -> None:
        self.path = out_dir / INDEX_FILE
        old = load_index(out_dir) if self.path.exists() else {}
        self.runs = {
            s.run_id: {
                "file": Path(s.path).name, "params": s.params, "grid_index": list(s.grid_index),
                "status": old.get(s.run_id, {}).get("status", "pending"),
                "status_reason": old.get(s.run_id, {}).get("status_reason", ""),
            }
            for s in specs
        }

    def update(self, record: dict[str, Any]) -> None:
        entry = self.runs[record["run_id"]]
        entry["status"] = record["status"]
        entry["status_reason"] = record["status_reason"]
        self.write()

    def write(self) -> None:
        tmp = self.path.with_suffix(".json.tmp")
        tmp.write_text(json.dumps({"runs": self.runs}, indent=1, default=str))
        os.replace(tmp, self.path)  # atomic: a reader never sees half a file


def load_index(out_dir: str | os.PathLike) -> dict[str, dict]:
    with open(Path(out_dir) / INDEX_FILE, encoding="utf-8") as fh:
        return json.load(fh)["runs"]


ProgressCallback = Callable[[dict[str, Any]], None]


def run_campaign(
    campaign: Campaign,
    *,
    workers: int | None = None,
    scheduler: str | None = None,
    resume: bool = True,
    progress: ProgressCallback | None = None,
) -> dict[str, Any]:
    """Run every run of the campaign that is not already completed.

    Returns ``{"total", "skipped", "completed", "failed", "interrupted",
    "records"}``; ``failed`` counts every run that did not complete.
    ``progress`` is called with ``{"total", "skipped", "done", "failed",
    "running", "kt": {run_id: t}}`` whenever something changes.
    """
    specs = expand_campaign(campaign)
    out_dir = Path(campaign.output.dir)
    try:
        out_dir.mkdir(parents=True, exist_ok=True)
        (out_dir / CAMPAIGN_FILE).write_text(campaign.to_yaml(), encoding="utf-8")
    except OSError as exc:
        raise ConfigError(
            f"output.dir = {str(out_dir)!r}: cannot create or write the campaign directory "
            f"({exc.strerror or type(exc).__name__})"
        ) from None
    index = _Index(out_dir, specs)
    todo = []
    for spec in specs:
        status = _file_status(spec.path) if resume else None
        if status == "completed":
            index.runs[spec.run_id].update(status="completed", status_reason="")
        else:
            todo.append(spec)
    index.write()
    state = {"total": len(specs), "skipped": len(specs) - len(todo), "done": 0, "failed": 0,
             "running": 0, "kt": {}}  # kt: the runs started and not finished
    records: list[dict] = []
    interrupted = False
    if todo:
        runner = _run_dask if scheduler else _run_local
        with _SigtermAsInterrupt():
            interrupted = runner(todo, index, state, records, progress, workers=workers, scheduler=scheduler)
    return {
        "total": len(specs),
        "skipped": state["skipped"],
        "completed": sum(r["status"] == "completed" for r in records),
        "failed": sum(r["status"] != "completed" for r in records),
        "interrupted": interrupted,
        "records": records,
    }


class _SigtermAsInterrupt:
    """A batch system's SIGTERM stops the campaign the way Ctrl-C does."""

    def __enter__(self):
        self._old = None
        if threading.current_thread() is threading.main_thread():
            self._old = signal.signal(signal.SIGTERM, self._handle)
        return self

    @staticmethod
    def _handle(signum, frame):
        raise KeyboardInterrupt(f"signal {signum}")

    def __exit__(self, *exc):
        if self._old is not None:
            signal.signal(signal.SIGTERM, self._old)
        return False


def _finish(record: dict, index: _Index, state: dict, records: list, progress) -> None:
    records.append(record)
    index.update(record)
    state["done" if record["status"] == "completed" else "failed"] += 1
    state["kt"].pop(record["run_id"], None)
    if progress is not None:
        progress(state)


def _run_local(todo, index, state, records, progress, *, workers, scheduler) -> bool:
    cores = usable_cores()
    n = max(1, min(workers or cores, len(todo)))
    threads = max(1, cores // n)
    warm_numba(todo)
    ctx = multiprocessing.get_context("spawn")
    kt_queue, stop = ctx.Queue(), ctx.Event()
    pool = cf.ProcessPoolExecutor(n, mp_context=ctx, initializer=_init_worker, initargs=(threads, kt_queue, stop))
    futures = {pool.submit(_pool_run, spec): spec for spec in todo}
    pending = set(futures)
    finished_ids: set[str] = set()
    try:
        while pending:
            finished, pending = cf.wait(pending, timeout=0.5, return_when=cf.FIRST_COMPLETED)
            _drain(kt_queue, state, finished_ids)
            for fut in finished:
                spec = futures[fut]
                try:
                    record = fut.result()
                except Exception as exc:  # a worker process died (killed, out of memory)
                    record = _record(spec, "failed", f"worker died: {type(exc).__name__}: {exc}")
                finished_ids.add(spec.run_id)
                _finish(record, index, state, records, progress)
            state["running"] = len(state["kt"])
            if progress is not None:
                progress(state)
        pool.shutdown(wait=True)
        return False
    except KeyboardInterrupt:
        # Runs already handed to a worker cannot be cancelled here: the event makes them return at once.
        stop.set()
        for fut in pending:
            fut.cancel()
        # SIGTERM reaches run_case's guard: the run closes its file as 'interrupted'.
        for proc in list(getattr(pool, "_processes", {}).values()):
            if proc.is_alive():
                os.kill(proc.pid, signal.SIGTERM)
        pool.shutdown(wait=True, cancel_futures=True)
        recorded = {r["run_id"] for r in records}
        for fut, spec in futures.items():
            if not fut.done() or fut.cancelled() or spec.run_id in recorded:
                continue
            try:
                record = fut.result()
            except Exception as exc:  # the worker ended between runs
                record = _record(spec, "interrupted", f"campaign stopped: {type(exc).__name__}")
            if record["status"] == "failed":
                # The stop signal can surface as any exception (e.g. from inside a numba call).
                record = dict(record, status="interrupted", status_reason=f"campaign stopped: {record['status_reason']}")
            _finish(record, index, state, records, None)
        return True
    finally:
        kt_queue.close()


def _drain(q: Any, state: dict, finished_ids: set[str]) -> None:
    while True:
        try:
            run_id, t = q.get_nowait()
        except (queue.Empty, OSError, ValueError):
            return
        if run_id not in finished_ids:  # a late message must not revive a finished run
            state["kt"][run_id] = t


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

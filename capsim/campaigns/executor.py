"""One batch executor for campaigns (``capsim sweep``) and studies (``capsim study``).

:func:`run_batch` runs a list of items through a task on a process pool (spawn
context: the numba kernels run on OpenMP threads, and forking a process that has
used them kills the child), or in this process for a study with one worker:

- **threads**: N worker processes, each with ``cores // N`` numba threads, set by
  the worker's initializer through :func:`capsim.numerics.threads.apply_policy` before
  numba is imported (processes x threads = cores; a user's ``NUMBA_NUM_THREADS``
  wins).
- **one warm-up**: :func:`warm_up` compiles (and caches on disk) every kernel
  the batch will use, from a level-0, two-step copy of one case of each kernel
  kind (:func:`kernel_kind`: law, traction, λ ≠ 1, bending, near field, mirror
  symmetry, solver). It runs once in the parent before the workers start (so
  that they do not all compile the same kernels at once), and once in each
  worker before its first task (loading the cached kernels), so that a run's
  wall time measures the run, not the JIT.
- **failures as records**: a task that raises, or a worker that dies, gives a
  record built by the caller's ``failure(index, status, reason)``; the batch goes on.
- **signals**: Ctrl-C, SIGTERM (a batch system) or SIGHUP in the parent cancels the
  pending items and sends SIGTERM to the running ones, whose runs close their
  files as ``interrupted``; idle workers ignore SIGTERM (they wait for work
  holding the task queue's lock; dying there would hang the pool's shutdown).
  The parent's handler only records the signal (:class:`_StopRequests`); the batch's
  loop acts on it at its next check, so no KeyboardInterrupt lands inside a lock or
  inside the stop itself, and a second Ctrl-C changes nothing. Workers are spawned with
  the stop signals blocked, unblocked once their initializer has set what they do.
  A stop that the parent's warm-up run took as its own stops the batch too.
  A worker whose parent was killed stops its run and exits.
- **the main script**: the workers run capsim's own task on capsim's own items and need
  nothing of the program that started the batch, so they are started without importing its
  main script again (spawn would, and a script without an ``if __name__ == "__main__":``
  guard would then start the batch again in every worker). :func:`in_spawned_import_of_main`
  tells a library call that it runs inside such a re-import (a pool of the user's own).
- **progress**: a task gets a callback ``progress(state)`` (run_case's progress
  protocol); the worker forwards ``state["t"]`` to the parent at most once a
  second, and the parent calls ``on_progress({key: t})`` of the running items.
"""

from __future__ import annotations

import concurrent.futures as cf
import contextlib
import math
import multiprocessing
import numbers
import os
import queue
import signal
import sys
import tempfile
import threading
import time
import types
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from capsim.errors import first_line
from capsim.numerics import threads

__all__ = ["BatchOutcome", "SigtermAsInterrupt", "check_workers", "in_spawned_import_of_main", "kernel_kind",
           "number_list", "one_line", "path_arg", "path_list", "refuse_in_spawned_import_of_main", "run_batch",
           "text_list", "warm_up"]

#: task(item, progress) -> record (a dict with at least "status" and "status_reason")
Task = Callable[[Any, Any], dict]
#: failure(index, status, reason) -> the record of an item that has no record of its own
Failure = Callable[[int, str, str], dict]


def one_line(exc: BaseException) -> str:
    """'Type: first line of the message' (the type alone when the message is empty)."""
    first = first_line(exc, default="")
    return f"{type(exc).__name__}: {first}" if first else type(exc).__name__


# ---------------------------------------------------------------- the caller (the library face's arguments)


def _config_error(name: str, value: Any, what: str):
    from capsim.config import ConfigError
    from capsim.errors import bounded_repr

    return ConfigError(f"{name} = {bounded_repr(value)}: {what}")


def check_workers(workers: Any, name: str = "workers", *, default: str | None = "one per core") -> int | None:
    """`workers` as the CLI's ``--workers`` takes it: a whole number >= 1 (None where a `default`
    is named); anything else a one-line :class:`capsim.config.ConfigError`."""
    if workers is None and default is not None:
        return None
    if isinstance(workers, bool) or not isinstance(workers, numbers.Integral) or workers < 1:
        or_default = f" (or None: {default})" if default else ""
        raise _config_error(name, workers, f"must be a whole number >= 1{or_default}")
    return int(workers)


def text_list(value: Any, name: str) -> list[str] | None:
    """None, one text or a sequence of texts (``sets``) as a list of texts: one text is a list of
    one, never the list of its characters; anything else a one-line ConfigError."""
    if value is None:
        return None
    if isinstance(value, str):
        return [value]
    items = None if isinstance(value, (bytes, Mapping)) or not isinstance(value, Iterable) else list(value)
    if items is None or not all(isinstance(v, str) for v in items):
        raise _config_error(name, value, "a text or a list of texts is expected (e.g. [\"mesh.level=1\"])")
    return items


def path_arg(value: Any, name: str) -> Path | None:
    """One path argument (None stays None); anything else a one-line ConfigError."""
    if value is None:
        return None
    if not isinstance(value, (str, os.PathLike)):
        raise _config_error(name, value, "a path is expected")
    return Path(value)


def path_list(value: Any, name: str) -> list[Path]:
    """One path or a sequence of paths (``inputs``) as a list of paths (one path is a list of one)."""
    if isinstance(value, (str, os.PathLike)):
        return [Path(value)]
    items = None if isinstance(value, (bytes, Mapping)) or not isinstance(value, Iterable) else list(value)
    if items is None or not all(isinstance(v, (str, os.PathLike)) for v in items):
        raise _config_error(name, value, "a path or a list of paths is expected")
    return [Path(v) for v in items]


def number_list(value: Any, name: str, *, whole: bool = False) -> list:
    """One number or a sequence of numbers (``levels``, ``rtols``) as a non-empty list (whole
    numbers as ints where `whole`); a text, an empty list or anything else a one-line ConfigError."""
    kind = "whole numbers" if whole else "numbers"

    def number(v: Any) -> bool:
        if isinstance(v, bool) or not isinstance(v, numbers.Real) or not math.isfinite(float(v)):
            return False
        return not whole or float(v).is_integer()

    if isinstance(value, numbers.Real) and not isinstance(value, bool):
        value = [value]
    elif isinstance(value, (str, bytes, Mapping)) or not isinstance(value, Iterable):
        raise _config_error(name, value, f"a list of {kind} is expected (e.g. {name}=[...]), not a "
                                         f"{type(value).__name__}")
    value = list(value)
    if not value:
        raise _config_error(name, value, "give at least one")
    bad = [v for v in value if not number(v)]
    if bad:
        raise _config_error(name, value, f"{bad[0]!r} is not a finite {'whole ' if whole else ''}number")
    return [int(v) for v in value] if whole else [float(v) for v in value]


def in_spawned_import_of_main() -> bool:
    """Whether this process is a spawned child still importing its parent's main script (the
    way ``multiprocessing`` starts a child by spawn): a batch started there would start again
    in every child. The flag is the one ``multiprocessing`` itself checks before it refuses
    to start a process from such an import."""
    return bool(getattr(multiprocessing.current_process(), "_inheriting", False))


def refuse_in_spawned_import_of_main(what: str) -> None:
    """A one-line :class:`capsim.config.ConfigError` when :func:`in_spawned_import_of_main`."""
    if in_spawned_import_of_main():
        from capsim.config import ConfigError

        raise ConfigError(f"{what} was called while a process started by spawn imports the main script again; "
                          f"put the call under `if __name__ == \"__main__\":` in the script")


@contextlib.contextmanager
def _without_main_script():
    """While worker processes start: the main module as an empty one, so that a spawned
    worker does not import the main script again (the workers run capsim's task on capsim's
    items; nothing of the script is theirs to run). Spawn re-imports the main module when it
    has a ``__file__`` or a ``__spec__``; an empty module has neither."""
    main = sys.modules.get("__main__")
    if main is None or (getattr(main, "__spec__", None) is None and getattr(main, "__file__", None) is None):
        yield
        return
    stand_in = types.ModuleType("__main__")
    sys.modules["__main__"] = stand_in
    try:
        yield
    finally:
        if sys.modules.get("__main__") is stand_in:
            sys.modules["__main__"] = main


# ---------------------------------------------------------------- warm-up


def kernel_kind(case) -> tuple:
    """What decides which numba kernels a case compiles (and with which signatures): the law,
    traction, λ ≠ 1 and its solver, bending, the near field, the symmetry in use, the time
    scheme and (linearly implicit) its preconditioner, which compile kernels of their own
    (the dense one's layer matrices: ~10 s), and the membrane's viscosity model."""
    from capsim.config import axis_keeps_quarter_symmetry

    m, q, tc = case.membrane, case.quadrature, case.time
    symmetry = case.mesh.symmetry
    if symmetry == "auto":
        symmetry = "quarter" if axis_keeps_quarter_symmetry(case.axis) else "half"
    double_layer = any(lam != 1.0 for lam in case.viscosity_ratios)
    return (
        m.law, m.traction, double_layer, m.bending_modulus > 0,
        q.near_field_factor > 0, symmetry,
        case.solver.method if double_layer else None,
        tc.scheme, tc.preconditioner if tc.scheme == "linearly_implicit" else None,
        m.viscosity.model if m.viscosity is not None and m.viscosity.active else None,
    )


def distinct_kinds(cases: Sequence) -> list:
    """One case of each kernel kind, in first-seen order."""
    kinds: dict[tuple, Any] = {}
    for case in cases:
        kinds.setdefault(kernel_kind(case), case)
    return list(kinds.values())


_WARMED: set[tuple] = set()


def warm_up(cases: Sequence) -> str | None:
    """Compile/load every kernel the cases use, once per process: a level-0, two-step copy of each kind.

    Returns the reason of a warm-up run that a signal stopped (run_case takes SIGINT and SIGTERM
    while it runs and returns 'interrupted': the caller must hear of that stop), else None."""
    todo = [c for c in distinct_kinds(cases) if kernel_kind(c) not in _WARMED]
    if not todo:
        return None
    from capsim.config import apply_overrides
    from capsim.runs.runner import run_case

    with tempfile.TemporaryDirectory(prefix="capsim-warm-") as tmp:
        for case in todo:
            # a plain level-0 run: without the accuracy target, which would choose the level (or run its ladder)
            tiny = apply_overrides(case, **{
                "accuracy": None, "mesh.level": 0, "time.t_end": 2.0 * case.time.dt_initial, "time.max_steps": 2,
                "time.stop_when_steady": False, "time.stop_when_settled": False, "time.max_wall_s": None,
                "output.path": os.path.join(tmp, "warm.h5"),
            })
            try:
                result = run_case(tiny)
            except Exception:  # the real run reports its own failure
                result = None
            except KeyboardInterrupt:  # a second Ctrl-C while the tiny run closed its file
                return "interrupted by SIGINT during the kernels' warm-up"
            reason = result["status_reason"] if result is not None and result["status"] == "interrupted" else ""
            if any(sig.name in reason for sig in _STOP_SIGNALS):  # a signal, not a limit of the case
                return reason
            _WARMED.add(kernel_kind(case))
    from capsim.solve.timestepping import load_step_kernels

    load_step_kernels()  # every scheme's: the tiny run's level may choose another scheme than the case's
    return None


# ---------------------------------------------------------------- signals


class SigtermAsInterrupt:
    """A batch system's SIGTERM stops the batch the way Ctrl-C does (main thread only)."""

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


#: the signals that stop a batch (SIGHUP: its terminal closed)
_STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)


class _StopRequests:
    """SIGINT, SIGTERM and SIGHUP while a batch runs, as a request that the batch's own loop takes
    up at its next check (:meth:`check` raises KeyboardInterrupt there, at a point of its choosing).

    The handler never raises. A KeyboardInterrupt raised by a handler lands wherever the main
    thread happens to be: inside concurrent.futures' locks ("RuntimeError: release unlocked
    lock"), or inside the stop path itself when a second Ctrl-C follows the first by
    milliseconds, which left the pool's shutdown half done and the process waiting on its
    workers for ever. A second signal while stopping changes nothing: the stop is under way. A
    signal the process inherited as ignored (a background job's SIGINT) stays ignored. Main
    thread only (elsewhere Python cannot set handlers, and signals reach the main thread)."""

    def __init__(self) -> None:
        self.signum: int | None = None
        self._old: dict[int, Any] = {}

    def __enter__(self) -> _StopRequests:
        if threading.current_thread() is threading.main_thread():
            for sig in _STOP_SIGNALS:
                if signal.getsignal(sig) is not signal.SIG_IGN:
                    self._old[sig] = signal.signal(sig, self._handle)
        return self

    def _handle(self, signum, frame) -> None:
        if self.signum is None:
            self.signum = signum

    def request(self, signum: int) -> None:
        """A stop that reached this process another way (a warm-up run that a signal stopped)."""
        self._handle(signum, None)

    def check(self) -> None:
        if self.signum is not None:
            raise KeyboardInterrupt(f"signal {int(self.signum)}")

    def __exit__(self, *exc) -> bool:
        for sig, old in self._old.items():
            signal.signal(sig, old)
        return False


@contextlib.contextmanager
def _signals_blocked():
    """While worker processes are spawned: the stop signals blocked in this thread, so that the
    workers start with them blocked (a spawned process inherits the signal mask) and unblock
    them in their initializer, once SIGINT is ignored and SIGTERM handled there. A Ctrl-C to
    the process group while a worker imports capsim killed it with a traceback and broke the
    pool; now it waits, pending, and is ignored (the parent decides what stops). The parent's own
    signals wait here too and are then taken by its :class:`_StopRequests`."""
    if not hasattr(signal, "pthread_sigmask"):
        yield
        return
    old = signal.pthread_sigmask(signal.SIG_BLOCK, _STOP_SIGNALS)
    try:
        yield
    finally:
        signal.pthread_sigmask(signal.SIG_SETMASK, old)


def _stopping_signal(exc: BaseException) -> int:
    """The signal behind a KeyboardInterrupt: the one SigtermAsInterrupt or _StopRequests named, else SIGINT."""
    for sig in _STOP_SIGNALS:
        if str(exc) == f"signal {int(sig)}":
            return sig
    return signal.SIGINT


# ---------------------------------------------------------------- worker side


class _QueueProgress:
    """Forward a run's kt to the parent at most once a second."""

    def __init__(self, key: str, q: Any) -> None:
        self.key, self.q, self._last = key, q, -math.inf

    def __call__(self, state: dict) -> None:
        now = time.monotonic()
        if now - self._last >= 1.0:
            self._last = now
            self.q.put((self.key, float(state.get("t", math.nan)), os.getpid()))


# Set once per worker process by its initializer (the pool's way to hand over
# objects that cannot travel with each task).
_WORKER_QUEUE: Any = None
_WORKER_STOP: Any = None
_WORKER_STOP_SIGNAL: Any = None
_WORKER_WARM: list = []
_WORKER_BUSY = threading.Event()
_WORKER_PARENT: int | None = None  # the pool's process; another parent means it died
_NOT_STARTED = "capsim-executor: not started"


def _relayed_signal() -> int | None:
    """The signal that stopped the batch in the parent (relayed to this worker as SIGTERM)."""
    value = getattr(_WORKER_STOP_SIGNAL, "value", 0)
    return int(value) or None


def _init_worker(numba_threads: int, progress_queue: Any, stop: Any, warm: list, stop_signal: Any = None) -> None:
    # Before numba is imported: the thread count, layer and wait policy are read once, at import.
    threads.apply_policy(numba_threads)
    # Ctrl-C goes to the whole process group; the parent decides what stops.
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    # So does a batch system's SIGTERM. An idle worker must not die of it: it waits
    # for work holding the task queue's lock, and dying there would leave every other
    # worker, and the pool's shutdown, waiting for that lock for ever. A running case
    # replaces this handler with run_case's, which closes the run as 'interrupted'.
    signal.signal(signal.SIGTERM, _ignore_while_idle)
    signal.signal(signal.SIGHUP, _ignore_while_idle)  # a closed terminal: the parent stops the batch
    if hasattr(signal, "pthread_sigmask"):  # blocked while the parent spawned this worker (_signals_blocked)
        signal.pthread_sigmask(signal.SIG_UNBLOCK, _STOP_SIGNALS)
    global _WORKER_QUEUE, _WORKER_STOP, _WORKER_WARM, _WORKER_PARENT, _WORKER_STOP_SIGNAL
    _WORKER_QUEUE, _WORKER_STOP, _WORKER_WARM = progress_queue, stop, warm
    _WORKER_STOP_SIGNAL = stop_signal
    from capsim.runs import runner

    runner.RELAYED_SIGNAL = _relayed_signal  # a run stopped by the parent names the parent's signal
    _WORKER_PARENT = os.getppid()
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


def _orphaned() -> bool:
    """The pool's process died: the task queue may still hand out items, none may start."""
    return _WORKER_PARENT is not None and os.getppid() != _WORKER_PARENT


def _stopped() -> bool:
    return _orphaned() or (_WORKER_STOP is not None and _WORKER_STOP.is_set())


def _pool_task(task: Task, key: str, item: Any) -> Any:
    if _stopped():
        return _NOT_STARTED
    _WORKER_BUSY.set()
    try:
        warm_up(_WORKER_WARM)
        if _stopped():
            return _NOT_STARTED
        progress = None
        if _WORKER_QUEUE is not None:
            _WORKER_QUEUE.put((key, 0.0, os.getpid()))  # started: the parent counts it as running
            progress = _QueueProgress(key, _WORKER_QUEUE)
        try:
            return task(item, progress)
        except Exception as exc:  # the task's own failure, not the worker's: a record in the parent
            return _Failed(one_line(exc))
    finally:
        _WORKER_BUSY.clear()


@dataclass(frozen=True)
class _Failed:
    """A task that raised in a worker (turned into the caller's failure record in the parent)."""

    reason: str


# ---------------------------------------------------------------- the batch


@dataclass
class BatchOutcome:
    """Records in item order (None: never started) and whether the batch was stopped."""

    records: list[dict | None]
    interrupted: bool


def run_batch(
    items: Sequence[Any],
    task: Task,
    *,
    keys: Sequence[str],
    failure: Failure,
    workers: int | None = None,
    warm: Sequence = (),
    in_process: bool = False,
    order: Sequence[int] | None = None,
    on_done: Callable[[int, dict], None] | None = None,
    on_progress: Callable[[dict[str, float]], None] | None = None,
    stop_on_interrupted: bool = False,
    name: str = "batch",
) -> BatchOutcome:
    """Run ``task(item, progress)`` for every item; see the module docstring.

    `workers` processes (default: the usable cores; never more than the items),
    or this process when `in_process`. `warm`: the cases whose kernels to warm
    up. `order`: submission order (default: item order). `on_done(index,
    record)` is called in this process as each item finishes. With
    `stop_on_interrupted`, an item whose record says ``interrupted`` (its run
    caught Ctrl-C or SIGTERM) stops the batch like Ctrl-C does. `name` is used
    in the reasons of items that the stop cut off.
    """
    if len(keys) != len(items):
        raise ValueError(f"{len(keys)} keys for {len(items)} items")
    order = list(range(len(items))) if order is None else list(order)
    outcome = BatchOutcome([None] * len(items), interrupted=False)

    def done(i: int, record: dict) -> None:
        outcome.records[i] = record
        if on_done is not None:
            on_done(i, record)

    with _StopRequests() as stop:
        if in_process:
            _run_here(items, task, order, warm, failure, done, stop_on_interrupted, outcome, stop)
        elif items:
            _run_pool(items, task, keys, order, warm, failure, done, on_progress, workers,
                      stop_on_interrupted, name, outcome, stop)
    return outcome


def _warm_or_stop(cases: Sequence, stop: _StopRequests) -> None:
    """warm_up, a stop that its runs swallowed passed on to `stop`; then stop.check()."""
    try:
        reason = warm_up(cases)
    except KeyboardInterrupt:
        reason = "SIGINT"
    if reason is not None:
        stop.request(next((s for s in _STOP_SIGNALS if s.name in reason), signal.SIGINT))  # the one it names
    stop.check()


def _run_here(items, task, order, warm, failure, done, stop_on_interrupted, outcome, stop) -> None:
    try:
        _warm_or_stop(warm, stop)
        for i in order:
            stop.check()  # a signal between two items (run_case takes them during its run)
            try:
                record = task(items[i], None)
            except Exception as exc:  # one bad item must not sink the batch
                record = failure(i, "failed", one_line(exc))
            done(i, record)
            if stop_on_interrupted and record.get("status") == "interrupted":
                outcome.interrupted = True
                return
    except KeyboardInterrupt:
        outcome.interrupted = True


#: how the reason of an item whose worker process died begins (callers reconcile such items)
WORKER_DIED = "worker died"


class _PoolBroken(Exception):
    """A worker process died (killed, out of memory): the pool can take no more work."""


def _culprits(procs: dict[int, Any], started: dict[str, int], finished: set[str]) -> set[str]:
    """The items whose worker died of its own accord (a signal other than the pool's
    SIGTERM, or an exit without a result): the others were stopped by the pool."""
    dead = set()
    for pid, proc in procs.items():
        proc.join(timeout=5.0)
        code = proc.exitcode
        if code is not None and code not in (0, -signal.SIGTERM):
            dead.add(pid)
    held = {key for key, pid in started.items() if key not in finished}
    if not dead:  # no exit status tells: every run in progress is suspect
        return held
    return {key for key in held if started[key] in dead}  # empty when the dead worker was between runs


#: open files a pool needs: the parent's own, then pipes, queues and semaphores per worker
_FILES_BASE, _FILES_PER_WORKER = 64, 16


def _ensure_open_files(n_workers: int) -> None:
    """Raise the soft open-file limit to what a pool of `n_workers` needs (up to the hard
    limit), or refuse before any worker starts: a pool that runs out of descriptors
    half-way leaves workers dying with tracebacks."""
    import errno
    import resource

    need = _FILES_BASE + _FILES_PER_WORKER * n_workers
    soft, hard = resource.getrlimit(resource.RLIMIT_NOFILE)
    if soft == resource.RLIM_INFINITY or soft >= need:
        return
    if hard == resource.RLIM_INFINITY or hard >= need:
        resource.setrlimit(resource.RLIMIT_NOFILE, (need, hard))
        return
    raise OSError(errno.EMFILE, f"Too many open files: the open-file limit {soft} (hard {hard}) is below the "
                                f"{need} that {n_workers} worker processes need; raise it (ulimit -n) or use "
                                "fewer --workers")


def _run_pool(items, task, keys, order, warm, failure, done, on_progress, workers,
              stop_on_interrupted, name, outcome, stop) -> None:
    cores = threads.usable_cores()
    n = max(1, min(workers or cores, len(items)))
    _ensure_open_files(n)
    n_threads = threads.threads_per_worker(n, cores)
    kinds = distinct_kinds(list(warm))
    try:
        _warm_or_stop(kinds, stop)  # compile into the on-disk cache once, before n workers would each compile
    except KeyboardInterrupt:  # stopped before any worker started: no run began
        outcome.interrupted = True
        for i in order:
            done(i, failure(i, "interrupted", f"{name} stopped before this run started"))
        return
    ctx = multiprocessing.get_context("spawn")
    kt_queue, stop_event, stop_signal = ctx.Queue(), ctx.Event(), ctx.Value("i", 0)
    finished: set[str] = set()
    todo = list(order)
    try:
        # A dead worker breaks the whole pool: the item it held fails, the pool is built
        # anew and every other unfinished item runs again (a run stopped by the pool's
        # SIGTERM resumes from its checkpoint). Each round finishes at least one item.
        for _ in range(len(items) + 1):
            todo = _pool_round(items, task, keys, todo, kinds, failure, done, on_progress, n, n_threads, ctx,
                               kt_queue, stop_event, stop_signal, finished, stop_on_interrupted, name, outcome, stop)
            if not todo or outcome.interrupted:
                break
        # pools that broke again and again with none of these items started (workers that die
        # as they start): each item gets its record, none is dropped from the counts
        for i in todo:
            if outcome.records[i] is None:
                done(i, failure(i, "failed", f"{WORKER_DIED} as they started, {len(items) + 1} times; "
                                             "this run never started"))
    finally:
        kt_queue.close()


def _pool_round(items, task, keys, order, kinds, failure, done, on_progress, n, n_threads, ctx, kt_queue, stop,
                stop_signal, finished, stop_on_interrupted, name, outcome, requests) -> list[int]:
    """One pool over `order`; returns the items to run again after a worker died ([] when done).
    `stop`: the workers' event; `requests`: this process's signals (:class:`_StopRequests`)."""
    # the workers start in the submits (spawn starts them as work arrives, up to n), with the
    # stop signals blocked until their initializer has set what they do there
    with _without_main_script(), _signals_blocked():
        pool = cf.ProcessPoolExecutor(min(n, len(order)), mp_context=ctx, initializer=_init_worker,
                                      initargs=(n_threads, kt_queue, stop, kinds, stop_signal))
        futures = {pool.submit(_pool_task, task, keys[i], items[i]): i for i in order}
    pending = set(futures)
    running: dict[str, float] = {}
    started: dict[str, int] = {}
    procs: dict[int, Any] = {}

    def collect(fut) -> dict:
        i = futures[fut]
        try:
            record = fut.result()
        except cf.process.BrokenProcessPool:
            raise _PoolBroken from None
        except Exception as exc:  # noqa: BLE001 - the worker failed otherwise
            return failure(i, "failed", f"{WORKER_DIED}: {one_line(exc)}")
        if isinstance(record, str) and record == _NOT_STARTED:
            return failure(i, "interrupted", f"{name} stopped before this run started")
        if isinstance(record, _Failed):
            return failure(i, "failed", record.reason)
        return record

    try:
        while pending:
            requests.check()  # a signal, taken up here and nowhere else
            procs.update(getattr(pool, "_processes", None) or {})
            ready, pending = cf.wait(pending, timeout=0.2, return_when=cf.FIRST_COMPLETED)
            _drain(kt_queue, running, finished, started)
            broken = False
            for fut in ready:
                i = futures[fut]
                try:
                    record = collect(fut)
                except _PoolBroken:
                    broken = True
                    continue
                finished.add(keys[i])
                running.pop(keys[i], None)
                done(i, record)
                if stop_on_interrupted and record.get("status") == "interrupted":
                    raise KeyboardInterrupt(record.get("status_reason", ""))
            if broken:
                pool.shutdown(wait=True, cancel_futures=True)
                _drain(kt_queue, running, finished, started)
                guilty = _culprits(procs, started, finished)
                again = []
                for fut, i in futures.items():
                    if keys[i] in finished:
                        continue
                    if keys[i] in guilty:
                        finished.add(keys[i])
                        done(i, failure(i, "failed", f"{WORKER_DIED} (killed, or out of memory) while running this; "
                                                     "the other runs went on"))
                    else:
                        again.append(i)
                return again
            if on_progress is not None:
                on_progress(dict(running))
        pool.shutdown(wait=True)
        return []
    except KeyboardInterrupt as exc:
        outcome.interrupted = True
        stop_signal.value = int(_stopping_signal(exc))  # the runs name it, not the SIGTERM that relays it
        # Items already handed to a worker cannot be cancelled here: the event makes them return at once.
        stop.set()
        for fut in pending:
            fut.cancel()
        # SIGTERM reaches run_case's guard: the run closes its file as 'interrupted'.
        for proc in list(getattr(pool, "_processes", {}).values()):
            if proc.is_alive():
                os.kill(proc.pid, signal.SIGTERM)
        pool.shutdown(wait=True, cancel_futures=True)
        for fut, i in futures.items():
            if not fut.done() or fut.cancelled() or outcome.records[i] is not None:
                continue
            try:
                record = fut.result()
            except Exception as exc:  # the worker ended between runs
                record = failure(i, "interrupted", f"{name} stopped: {type(exc).__name__}")
            if isinstance(record, str) and record == _NOT_STARTED:
                record = failure(i, "interrupted", f"{name} stopped before this run started")
            elif isinstance(record, _Failed):
                record = failure(i, "interrupted", f"{name} stopped: {record.reason}")
            elif record["status"] == "failed":
                # The stop signal can surface as any exception (e.g. from inside a numba call).
                record = dict(record, status="interrupted", status_reason=f"{name} stopped: {record['status_reason']}")
            done(i, record)
        return []


def _drain(q: Any, running: dict[str, float], finished: set[str], started: dict[str, int]) -> None:
    while True:
        try:
            key, t, pid = q.get_nowait()
        except (queue.Empty, OSError, ValueError):
            return
        if key not in finished:  # a late message must not revive a finished item
            running[key] = t
            started[key] = pid

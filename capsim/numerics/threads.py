"""Thread policy for the numba kernels, chosen and applied before numba is imported.

numba reads ``NUMBA_NUM_THREADS`` and ``NUMBA_THREADING_LAYER`` once, when it is
imported, and libgomp (numba's OpenMP layer) reads ``OMP_WAIT_POLICY`` once,
when it is loaded. So the policy is applied by whoever starts a computing
process, before the first ``import numba``: the CLI's callback, the pool
workers' initializer (:mod:`capsim.campaigns.executor`), and :func:`capsim.campaigns.campaign.execute_run`
(a Dask worker). This module imports nothing from numba or numpy.

The policy (benchmark: ``make bench-threads``, docs/performance.md, "Threads"):

- **threading layer**: the first of :data:`LAYERS` that loads, ``omp`` (libgomp)
  with ``OMP_WAIT_POLICY=PASSIVE``, then ``tbb`` (only when the TBB library is
  installed), then ``workqueue`` (always there). With libgomp's default wait
  policy an idle thread spins at every barrier; a velocity evaluation crosses
  about ten of them, and when one of the threads is descheduled (another busy
  process, a campaign's own workers) the others spin for its whole time slice:
  2 threads ran 7x slower than 1 on a shared 2-core machine. PASSIVE threads
  sleep at once and cost nothing measurable on a quiet machine.
- **thread count**: ``auto`` = the cores this process may run on
  (``os.sched_getaffinity``), divided between the worker processes of a batch
  so that processes x threads = cores.

A variable the user set (``NUMBA_NUM_THREADS``, ``NUMBA_THREADING_LAYER``,
``OMP_WAIT_POLICY``) wins and is reported (:attr:`ThreadPolicy.user`,
:func:`policy_attrs`). The variables capsim set itself are listed, with their
values, in ``CAPSIM_THREAD_POLICY``, so that a child process (a pool worker) may
set them again for its share of the cores while a value the user changed since
still counts as the user's.
"""

from __future__ import annotations

import ctypes
import importlib.util
import os
import sys
from dataclasses import dataclass, field
from pathlib import Path

__all__ = [
    "ENV_BLAS_TIMEOUT", "ENV_LAYER", "ENV_THREADS", "ENV_WAIT", "LAYERS", "ThreadPolicy", "apply_policy", "available_layers",
    "choose_policy", "policy_attrs", "threads_per_worker", "usable_cores",
]

ENV_THREADS = "NUMBA_NUM_THREADS"
ENV_LAYER = "NUMBA_THREADING_LAYER"
ENV_WAIT = "OMP_WAIT_POLICY"
ENV_BLAS_TIMEOUT = "OPENBLAS_THREAD_TIMEOUT"
_VARIABLES = (ENV_THREADS, ENV_LAYER, ENV_WAIT, ENV_BLAS_TIMEOUT)
#: the variables capsim set in this environment, as NAME=VALUE;... (not the user's)
_MARK = "CAPSIM_THREAD_POLICY"

#: threading layers in order of preference (the first that loads is used)
LAYERS = ("omp", "tbb", "workqueue")
#: the OpenMP wait policy capsim sets: idle threads sleep instead of spinning
WAIT_POLICY = "PASSIVE"
#: OpenBLAS's idle threads spin 2^n cycles before they sleep (its default n = 28,
#: about 0.1 s): after every LU or matrix product of the dense stage
#: preconditioner they took the cores from the numba kernels that followed (a
#: level-2 run of case (g) took 5.5 s instead of 2.9 s). n = 4 is its minimum.
#: OpenBLAS reads it when it loads, so it is set before numpy is imported.
BLAS_THREAD_TIMEOUT = "4"

# The numba extension module behind each layer (workqueue has no dependency).
_LAYER_MODULES = {"omp": "omppool", "tbb": "tbbpool", "workqueue": "workqueue"}


def usable_cores() -> int:
    """The cores this process may run on (its CPU affinity), at least 1."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # not Linux
        return os.cpu_count() or 1


def threads_per_worker(workers: int, cores: int | None = None) -> int:
    """numba threads for each of `workers` processes so that processes x threads = cores."""
    return max(1, (usable_cores() if cores is None else cores) // max(1, workers))


def _layer_loads(layer: str) -> bool:
    """True when numba's extension for `layer` and the library it links (libgomp, libtbb) load."""
    spec = importlib.util.find_spec("numba")
    if spec is None or not spec.submodule_search_locations:
        return False
    folder = Path(next(iter(spec.submodule_search_locations))) / "np" / "ufunc"
    for path in sorted(folder.glob(f"{_LAYER_MODULES[layer]}.*")):
        if path.suffix in (".so", ".pyd", ".dylib"):
            try:
                ctypes.CDLL(str(path))  # loads libgomp / libtbb with it: OMP_* must be set before
            except OSError:
                return False
            return True
    return False


def available_layers() -> tuple[str, ...]:
    """The threading layers of :data:`LAYERS` that load in this environment."""
    return tuple(layer for layer in LAYERS if layer == "workqueue" or _layer_loads(layer))


def _ours(env) -> dict[str, str]:
    """The variables capsim set (name -> value), as recorded in the environment."""
    pairs = (item.partition("=") for item in env.get(_MARK, "").split(";") if item)
    return {name: value for name, _, value in pairs if name in _VARIABLES}


def _user_value(name: str, env) -> str | None:
    """The user's value of `name`: set, not empty, and not the value capsim put there."""
    value = env.get(name)
    if value is None or value.strip() == "":
        return None
    return None if _ours(env).get(name) == value else value


@dataclass(frozen=True)
class ThreadPolicy:
    """The three settings and which of them came from the user's environment."""

    num_threads: int
    layer: str
    wait_policy: str
    user: dict[str, str] = field(default_factory=dict)
    applied: bool = False  # False: numba was already imported, nothing could change

    def describe(self) -> str:
        """One line: what is used and what came from the user."""
        text = f"{self.num_threads} numba threads, layer {self.layer}, OMP_WAIT_POLICY={self.wait_policy}"
        if self.user:
            text += " (from your environment: " + ", ".join(f"{k}={v}" for k, v in self.user.items()) + ")"
        return text


def choose_policy(threads: int | str = "auto", *, workers: int = 1, env=None) -> ThreadPolicy:
    """The policy for a process that will run `threads` numba threads (``auto``: its share of the cores).

    `workers` is the number of processes sharing the cores (a pool); a value
    in `env` (default ``os.environ``) that the user set wins.
    """
    env = os.environ if env is None else env
    user = {name: value for name in _VARIABLES if (value := _user_value(name, env)) is not None}
    if threads == "auto":
        n = threads_per_worker(workers)
    else:
        n = int(threads)
        if n < 1:
            raise ValueError(f"threads must be >= 1 or 'auto', got {threads!r}")
    wait = user.get(ENV_WAIT, WAIT_POLICY)
    layer = user.get(ENV_LAYER)
    if layer is None:
        layer = "workqueue"
        for candidate in LAYERS:
            if candidate == "workqueue" or _layer_loads(candidate):
                layer = candidate
                break
    return ThreadPolicy(num_threads=int(user.get(ENV_THREADS, n)), layer=layer, wait_policy=wait, user=user)


class ThreadsError(ValueError):
    """A thread variable of the environment that numba would refuse with a traceback; one line."""


#: the values of NUMBA_THREADING_LAYER numba knows
KNOWN_LAYERS = ("default", "safe", "forksafe", "threadsafe", "tbb", "omp", "workqueue")
MAX_THREADS = 1024


def check_user_variables(env=os.environ) -> None:
    """Refuse (ThreadsError, one line) a NUMBA_NUM_THREADS that is not a whole number in
    1..MAX_THREADS or a NUMBA_THREADING_LAYER numba does not know, before numba reads them."""
    threads = env.get(ENV_THREADS)
    if threads is not None and threads.strip() != "":
        text = threads.strip()
        if not (text.isdigit() and len(text) <= 6 and 1 <= int(text) <= MAX_THREADS):
            raise ThreadsError(f"{ENV_THREADS}={threads[:40]!r}: must be a whole number from 1 to {MAX_THREADS}; "
                               "unset it to let capsim choose")
    layer = env.get(ENV_LAYER)
    if layer is not None and layer.strip() != "" and layer.strip().lower() not in KNOWN_LAYERS:
        raise ThreadsError(f"{ENV_LAYER}={layer[:40]!r}: unknown threading layer; allowed: "
                           f"{', '.join(KNOWN_LAYERS)}")


def apply_policy(threads: int | str = "auto", *, workers: int = 1) -> ThreadPolicy:
    """Choose the policy and put it in ``os.environ`` (before numba is imported).

    A variable the user set is left as it is. The first call in a process
    decides (a later one returns the same policy), and once numba is imported
    nothing can change any more: the policy in effect is returned with
    ``applied=False``.
    """
    global _APPLIED
    env = os.environ
    if _APPLIED is not None:
        return _APPLIED
    check_user_variables(env)
    if "numba" in sys.modules:
        return _in_effect()
    user = {name: value for name in _VARIABLES if (value := _user_value(name, env)) is not None}
    # The wait policy first: probing the omp layer loads libgomp, which reads it once.
    if ENV_WAIT not in user:
        env[ENV_WAIT] = WAIT_POLICY
    if ENV_LAYER not in user:
        env.pop(ENV_LAYER, None)
    policy = choose_policy(threads, workers=workers, env=env)
    ours = {}
    for name, value in ((ENV_THREADS, str(policy.num_threads)), (ENV_LAYER, policy.layer),
                        (ENV_WAIT, policy.wait_policy), (ENV_BLAS_TIMEOUT, BLAS_THREAD_TIMEOUT)):
        if name not in user:
            env[name] = value
            ours[name] = value
    env[_MARK] = ";".join(f"{k}={v}" for k, v in ours.items())
    _APPLIED = ThreadPolicy(policy.num_threads, policy.layer, policy.wait_policy, user=user, applied=True)
    return _APPLIED


_APPLIED: ThreadPolicy | None = None


def _in_effect() -> ThreadPolicy:
    attrs = policy_attrs()
    user = {name: value for name in _VARIABLES if (value := _user_value(name, os.environ)) is not None}
    return ThreadPolicy(int(attrs["numba_num_threads"]), str(attrs["numba_threading_layer"]),
                        str(attrs["omp_wait_policy"]), user=user, applied=False)


def policy_attrs() -> dict[str, str | int]:
    """The settings in effect in this process, for a run file's root attributes.

    - ``numba_threading_layer``: the layer numba runs its parallel kernels on
      (``numba.threading_layer()``) once one has run in this process; before
      that, the configured one (a named layer is the one numba will load, or
      fail; ``default`` lets numba pick tbb, omp, workqueue in that order).
      ``numba_threading_layer_source`` says which: ``running`` or ``configured``.
    - ``numba_num_threads``: the threads a parallel kernel uses
      (``numba.get_num_threads()`` once numba is imported, else the configured count).
    - ``omp_wait_policy``: ``OMP_WAIT_POLICY`` (``unset``: libgomp's default,
      spinning for a while at every barrier; only the omp layer reads it).
    - ``openblas_thread_timeout``: ``OPENBLAS_THREAD_TIMEOUT`` (``unset``: OpenBLAS's
      default, idle BLAS threads spinning for about 0.1 s after each call).
    - ``thread_policy_user_env``: the variables that came from the user's
      environment instead of capsim's policy (``NAME=value``, comma-separated; "" if none).
    """
    env = os.environ
    numba = sys.modules.get("numba")
    source = "configured"
    if numba is not None:
        configured = str(getattr(numba.config, "THREADING_LAYER", env.get(ENV_LAYER, "default")))
        try:
            layer = str(numba.threading_layer())
            source = "running"
        except ValueError:  # no parallel kernel has run in this process yet
            layer = configured
        n = int(numba.get_num_threads())
    else:
        layer = env.get(ENV_LAYER) or "default"
        text = env.get(ENV_THREADS, "").strip()
        n = int(text) if text.isdigit() else usable_cores()
    user = [f"{name}={value}" for name in _VARIABLES if (value := _user_value(name, env)) is not None]
    return {
        "numba_threading_layer": layer,
        "numba_threading_layer_source": source,
        "numba_num_threads": n,
        "omp_wait_policy": env.get(ENV_WAIT) or "unset",
        "openblas_thread_timeout": env.get(ENV_BLAS_TIMEOUT) or "unset",
        "thread_policy_user_env": ", ".join(user),
    }


#: full-mesh nodes from which a run's parallel kernels use every thread they were given: below it
#: one thread (measured on the demo, level 3 = 1026 nodes with quarter symmetry: one thread
#: 3.6 s, two 4.0 s, a second thread's fork-join cost outweighs its share of ~1 ms of
#: sums; again after the evaluation was made 2.3x cheaper: the run 1.3-1.5 s on one thread
#: against 1.6-1.7 s on two, alternated five times, docs/performance.md, "One evaluation and the demo"); level
#: 4 = 4098 nodes: two threads 1.53x faster over a run (kt 2), 1.5-1.8x per evaluation, quiet
#: machine, benchmarks/threads_level4.md; issue 29, docs/performance.md, "Threads")
PARALLEL_MIN_NODES = 2000


def threads_for_work(n_nodes: int, available: int) -> int:
    """The threads a run of `n_nodes` (full mesh) uses out of `available`: one below
    :data:`PARALLEL_MIN_NODES`, else all of them."""
    return max(1, available) if n_nodes >= PARALLEL_MIN_NODES else 1


def set_run_threads(n_nodes: int) -> int | None:
    """Set numba's thread count for a run by its work (:func:`threads_for_work`), unless
    the user chose it (``NUMBA_NUM_THREADS``); returns the count set, None when left."""
    if _user_value(ENV_THREADS, os.environ) is not None:
        return None
    import numba

    n = threads_for_work(n_nodes, numba.config.NUMBA_NUM_THREADS)
    numba.set_num_threads(n)
    return n

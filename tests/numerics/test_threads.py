"""Thread policy (capsim.numerics.threads): chosen before numba loads, recorded in every run file.

A CLI run and a pool worker get the policy (read back from the run file's root
attributes), and a user's NUMBA_NUM_THREADS / NUMBA_THREADING_LAYER /
OMP_WAIT_POLICY wins over it and is reported.
"""

import os
import subprocess
import sys

import h5py
import pytest
import yaml

from capsim.numerics import threads
from capsim.campaigns.campaign import campaign_from_dict, run_campaign

VARIABLES = (threads.ENV_THREADS, threads.ENV_LAYER, threads.ENV_WAIT, threads.ENV_BLAS_TIMEOUT, "CAPSIM_THREAD_POLICY")
CASE = {"name": "threads", "mesh": {"level": 0}, "time": {"t_end": 0.05}, "output": {"snapshot_every": 0.05}}


def clean_env(**user):
    env = {k: v for k, v in os.environ.items() if k not in VARIABLES}
    env.update(user)
    return env


def root_attrs(path):
    with h5py.File(path, "r") as f:
        return {k: (v.decode() if isinstance(v, bytes) else v) for k, v in f.attrs.items()}


def chosen_layer():
    return threads.available_layers()[0]


# ---------------------------------------------------------------- choice


def test_policy_choice_and_the_users_variables_win():
    policy = threads.choose_policy(env={})
    assert policy.layer == chosen_layer() and policy.layer in threads.LAYERS
    assert policy.wait_policy == "PASSIVE"
    assert policy.num_threads == threads.usable_cores() and not policy.user
    assert threads.choose_policy(workers=2, env={}).num_threads == max(1, threads.usable_cores() // 2)
    assert threads.choose_policy(3, env={}).num_threads == 3
    user = threads.choose_policy(env={"NUMBA_NUM_THREADS": "5", "OMP_WAIT_POLICY": "ACTIVE",
                                      "NUMBA_THREADING_LAYER": "workqueue"})
    assert (user.num_threads, user.wait_policy, user.layer) == (5, "ACTIVE", "workqueue")
    assert user.user == {"NUMBA_NUM_THREADS": "5", "NUMBA_THREADING_LAYER": "workqueue", "OMP_WAIT_POLICY": "ACTIVE"}
    assert "from your environment: NUMBA_NUM_THREADS=5" in user.describe()
    # What capsim set in a parent (listed in CAPSIM_THREAD_POLICY) is not the user's: a child re-splits it;
    # a value changed since is the user's again.
    inherited = {"NUMBA_NUM_THREADS": "2", "CAPSIM_THREAD_POLICY": "NUMBA_NUM_THREADS=2;OMP_WAIT_POLICY=PASSIVE",
                 "OMP_WAIT_POLICY": "PASSIVE"}
    assert threads.choose_policy(1, env=inherited).num_threads == 1
    assert threads.choose_policy(1, env=inherited).user == {}
    assert threads.choose_policy(1, env=dict(inherited, NUMBA_NUM_THREADS="4")).num_threads == 4
    with pytest.raises(ValueError):
        threads.choose_policy(0, env={})


def test_apply_sets_the_environment_before_numba_and_records_it():
    """In a fresh interpreter: apply_policy puts the policy in os.environ; numba then runs with it."""
    code = (
        "import os, capsim.numerics.threads as t; p = t.apply_policy(workers=2); "
        "import numba, numpy as np\n"
        "@numba.njit(parallel=True)\n"
        "def f(a):\n"
        "    s = 0.0\n"
        "    for i in numba.prange(a.size): s += a[i]\n"
        "    return s\n"
        "f(np.ones(64)); a = t.policy_attrs(); "
        "print(p.applied, a['numba_threading_layer'], a['numba_threading_layer_source'], a['numba_num_threads'], "
        "a['omp_wait_policy'], a['openblas_thread_timeout'], repr(a['thread_policy_user_env']))"
    )
    out = subprocess.run([sys.executable, "-c", code], env=clean_env(), capture_output=True, text=True, check=True)
    assert out.stdout.split() == ["True", chosen_layer(), "running", str(max(1, threads.usable_cores() // 2)),
                                  "PASSIVE", threads.BLAS_THREAD_TIMEOUT, "''"]


# ---------------------------------------------------------------- CLI run


def _cli_run(tmp_path, env):
    case = tmp_path / "case.yaml"
    case.write_text(yaml.safe_dump(CASE))
    out = tmp_path / "run.h5"
    res = subprocess.run([sys.executable, "-m", "capsim.face.cli", "run", str(case), "-o", str(out), "-q"],
                         env=env, capture_output=True, text=True, timeout=300)
    assert res.returncode == 0, res.stderr
    return root_attrs(out), res.stderr


def test_cli_run_gets_the_policy(tmp_path):
    attrs, stderr = _cli_run(tmp_path, clean_env())
    assert attrs["numba_threading_layer"] == chosen_layer()
    # a level-0 mesh runs on one thread (issue 29: threads chosen by the work), out of the cores given
    assert attrs["numba_num_threads"] == threads.threads_for_work(int(attrs["n_nodes"]), threads.usable_cores()) == 1
    assert attrs["omp_wait_policy"] == "PASSIVE"
    assert attrs["thread_policy_user_env"] == ""
    assert "threads:" not in stderr


def test_threads_follow_the_work():
    assert threads.threads_for_work(1026, 2) == 1  # level 3: one thread is faster
    assert threads.threads_for_work(4098, 2) == 2  # level 4: two threads 1.18x faster per evaluation
    assert threads.threads_for_work(4098, 0) == 1


def test_cli_run_users_variables_override_the_policy(tmp_path):
    env = clean_env(NUMBA_NUM_THREADS="1", OMP_WAIT_POLICY="ACTIVE", NUMBA_THREADING_LAYER="workqueue")
    attrs, stderr = _cli_run(tmp_path, env)
    assert (attrs["numba_num_threads"], attrs["omp_wait_policy"], attrs["numba_threading_layer"]) == (
        1, "ACTIVE", "workqueue")
    assert attrs["thread_policy_user_env"] == "NUMBA_NUM_THREADS=1, NUMBA_THREADING_LAYER=workqueue, OMP_WAIT_POLICY=ACTIVE"
    assert "threads: 1 numba threads, layer workqueue" in stderr and "from your environment" in stderr


# ---------------------------------------------------------------- pool workers


def _sweep(tmp_path, name):
    campaign = campaign_from_dict({
        "name": name, "base": {k: v for k, v in CASE.items() if k not in ("name", "output")},
        "sweep": {"flow.shear_rate_G": [0.05, 0.1]}, "output": {"dir": str(tmp_path / name)},
    })
    result = run_campaign(campaign, workers=2)
    assert result["completed"] == 2, result["records"]
    return [root_attrs(r["summary"]["path"]) for r in result["records"]], result["records"]


def test_pool_workers_get_the_policy_and_the_users_variable_wins(tmp_path, monkeypatch):
    for name in VARIABLES:
        monkeypatch.delenv(name, raising=False)
    attrs, records = _sweep(tmp_path, "policy")
    per_worker = max(1, threads.usable_cores() // 2)
    for a, r in zip(attrs, records):
        assert a["numba_num_threads"] == r["numba_threads"] == per_worker
        assert a["omp_wait_policy"] == "PASSIVE"
        assert a["numba_threading_layer"] == chosen_layer()
        assert a["thread_policy_user_env"] == ""

    monkeypatch.setenv("OMP_WAIT_POLICY", "ACTIVE")
    monkeypatch.setenv("NUMBA_NUM_THREADS", "1")
    attrs, records = _sweep(tmp_path, "user")
    for a, r in zip(attrs, records):
        assert a["omp_wait_policy"] == "ACTIVE"
        assert a["numba_num_threads"] == r["numba_threads"] == 1
        assert a["thread_policy_user_env"] == "NUMBA_NUM_THREADS=1, OMP_WAIT_POLICY=ACTIVE"

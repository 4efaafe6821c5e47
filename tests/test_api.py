"""The library face (issue 31): ``import capsim`` offers load_case, run, sweep, summarize, study,
open_run, Case and RunResult without loading numba; ``capsim.run`` runs a case file as
``capsim run`` does (thread policy, output guard, the same numbers) and the CLI commands
call these functions. Tiny runs only (mesh level 0-1, kt <= 0.2)."""

from __future__ import annotations

import ast
import importlib
import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

import capsim
from capsim import api

ROOT = Path(__file__).resolve().parents[1]
PUBLIC = ("load_case", "run", "sweep", "summarize", "study", "open_run", "Case", "RunResult")


def _python(code: str, cwd: Path, env_drop: tuple[str, ...] = ()) -> subprocess.CompletedProcess:
    env = {k: v for k, v in os.environ.items() if k not in env_drop and not k.startswith(("NUMBA_", "CAPSIM_"))}
    env["PYTHONPATH"] = str(ROOT)
    return subprocess.run([sys.executable, "-c", code], cwd=cwd, env=env, capture_output=True, text=True,
                          timeout=600)


def _cli(args: list[str], cwd: Path) -> subprocess.CompletedProcess:
    return _python(f"import sys; from capsim.face.cli import app; sys.argv = ['capsim'] + {args!r}; app()", cwd)


def _tiny_sphere(tmp_path: Path) -> Path:
    """configs/sphere.yaml (the demo) cut to level 1 and kt = 0.2, writing under tmp_path."""
    import yaml

    data = yaml.safe_load((ROOT / "configs" / "sphere.yaml").read_text())
    data["mesh"]["level"] = 1
    data["time"]["t_end"] = 0.2
    data["output"] = {"path": "runs/tiny.h5", "snapshot_every": 0.1}
    path = tmp_path / "sphere.yaml"
    path.write_text(yaml.safe_dump(data))
    return path


def test_import_capsim_offers_the_library_without_loading_numba():
    out = _python("import capsim, sys; names = [n for n in capsim.__all__ if n != 'RunResult'];"
                  "[getattr(capsim, n) for n in names]; print('numba' in sys.modules)", ROOT)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == "False"
    for name in PUBLIC:
        assert name in capsim.__all__
        assert (getattr(capsim, name).__doc__ or "").strip(), f"capsim.{name} has no docstring"
    with pytest.raises(AttributeError, match="no attribute 'nonsense'"):
        capsim.nonsense  # noqa: B018


def test_load_case_takes_a_file_a_dict_and_overrides(tmp_path):
    from capsim.config import ConfigError

    from_file = capsim.load_case(ROOT / "configs" / "sphere.yaml", sets=["flow.shear_rate_G=0.2"], mesh__level=1)
    assert (from_file.mesh.level, from_file.flow.shear_rate_G) == (1, 0.2)
    from_dict = capsim.load_case({"name": "d", "mesh": {"level": 0}}, **{"time.t_end": 0.5})
    assert isinstance(from_dict, capsim.Case) and from_dict.time.t_end == 0.5 and from_dict.mesh.level == 0
    with pytest.raises(ConfigError, match="mesh.level") as bad:
        capsim.load_case({"mesh": {"level": -3}})
    assert "\n" not in str(bad.value)


def test_capsim_run_of_the_demo_file_is_the_cli_run_and_refuses_to_overwrite(tmp_path):
    case = _tiny_sphere(tmp_path)
    (tmp_path / "cli").mkdir()
    (tmp_path / "lib").mkdir()
    cli = _cli(["run", str(case), "-q"], tmp_path / "cli")
    assert cli.returncode == 0, cli.stderr
    code = (f"import capsim, json, os; r = capsim.run({str(case)!r}, overwrite=True);"
            "print(json.dumps({'status': r.status, 'D_xy': r['D_xy'], 'final': r.final_D_xy,"
            " 'policy': os.environ.get('CAPSIM_THREAD_POLICY')}))")
    lib = _python(code, tmp_path / "lib")
    assert lib.returncode == 0, lib.stderr
    result = json.loads(lib.stdout.strip().splitlines()[-1])
    assert result["status"] == "completed"
    assert result["policy"], "capsim.run did not apply the thread policy"

    import h5py

    with h5py.File(tmp_path / "cli" / "runs" / "tiny.h5") as f_cli, h5py.File(tmp_path / "lib" / "runs" / "tiny.h5") as f_lib:
        assert f_cli["timeseries/D_xy"][()].tolist() == f_lib["timeseries/D_xy"][()].tolist()
        assert float(f_lib["timeseries/D_xy"][-1]) == result["final"]

    # again, without overwrite: the CLI's one line, as an exception
    again = _python(f"import capsim; capsim.run({str(case)!r})", tmp_path / "lib")
    assert again.returncode != 0 and "OutputError" in again.stderr
    cli_again = _cli(["run", str(case), "-q"], tmp_path / "cli")
    assert cli_again.returncode == 2
    cli_line = cli_again.stderr.strip().splitlines()[-1]
    assert cli_line.startswith("error: ") and "--overwrite" in cli_line
    assert again.stderr.strip().splitlines()[-1] == "capsim.storage.files.OutputError: " + cli_line[len("error: "):].replace(
        str(tmp_path / "cli"), str(tmp_path / "lib"))


def test_run_refuses_an_existing_file_before_computing(tmp_path):
    from capsim.storage.files import OutputError

    out = tmp_path / "taken.h5"
    out.write_bytes(b"not yours")
    with pytest.raises(OutputError, match="--overwrite"):
        capsim.run({"name": "x", "mesh": {"level": 0}, "time": {"t_end": 0.01}}, output=out)
    assert out.read_bytes() == b"not yours"


def test_sweep_summarize_and_open_run_from_python(tmp_path):
    import yaml

    campaign = tmp_path / "c.yaml"
    campaign.write_text(yaml.safe_dump({
        "name": "s",
        "base": {"mesh": {"level": 0}, "time": {"t_end": 0.05}, "output": {"snapshot_every": 0.05}},
        "sweep": {"flow.shear_rate_G": [0.05, 0.1]},
        "output": {"dir": str(tmp_path / "runs")},
    }))
    result = capsim.sweep(campaign, workers=1)
    assert (result["total"], result["completed"], result["failed"]) == (2, 2, 0)
    ds = capsim.summarize(tmp_path / "runs")
    assert (tmp_path / "runs" / "summary.nc").exists()
    assert ds.sizes[next(iter(ds["D_xy"].dims))] == 2 and "D_xy" in ds
    run_file = sorted((tmp_path / "runs").glob("*.h5"))[0]
    tree = capsim.open_run(run_file)
    assert "D_xy" in tree["timeseries"].to_dataset()


def test_every_computing_cli_command_calls_the_library():
    """No CLI command does work the library does not expose: run, sweep, summarize and study call
    capsim.api, and none of them calls the engine (run_case, run_campaign, run_study,
    summarize_to_file) itself."""
    tree = ast.parse((ROOT / "capsim" / "face" / "cli.py").read_text())
    engine = {"run_case", "run_campaign", "run_study", "summarize_to_file"}
    commands = {node.name: node for node in tree.body if isinstance(node, ast.FunctionDef)}
    for name in ("run", "sweep", "summarize", "study"):
        calls = {n.func.attr if isinstance(n.func, ast.Attribute) else getattr(n.func, "id", "")
                 for n in ast.walk(commands[name]) if isinstance(n, ast.Call)}
        called_api = {n.attr for n in ast.walk(commands[name])
                      if isinstance(n, ast.Attribute) and isinstance(n.value, ast.Name) and n.value.id == "api"}
        assert name in called_api, f"capsim {name} does not call capsim.api.{name}"
        assert not calls & engine, f"capsim {name} calls {calls & engine} directly"
    for name in ("run", "sweep", "summarize", "study", "load_case", "open_run"):
        assert getattr(api, name) is getattr(capsim, name)
    # capsim.study is the library function, also once the study module is loaded (it lives in
    # capsim.campaigns, no longer at capsim.study where importing it replaced the attribute)
    importlib.import_module("capsim.campaigns.study")
    assert capsim.study is api.study


def test_the_first_run_after_an_install_says_it_is_compiling(tmp_path):
    """An empty numba cache (NUMBA_CACHE_DIR) is reported before the run compiles (issue 29)."""
    import os
    import subprocess
    import sys

    import yaml

    case = tmp_path / "c.yaml"
    case.write_text(yaml.safe_dump({"name": "c", "mesh": {"level": 0}, "time": {"t_end": 0.02}}))
    env = {**os.environ, "NUMBA_CACHE_DIR": str(tmp_path / "cache")}
    env.pop("NUMBA_NUM_THREADS", None)
    first = subprocess.run([sys.executable, "-m", "capsim.face.cli", "run", str(case), "-o", str(tmp_path / "a.h5")],
                           env=env, capture_output=True, text=True, timeout=600)
    assert first.returncode == 0, first.stderr[-2000:]
    assert "compiling the numba kernels" in first.stderr
    second = subprocess.run([sys.executable, "-m", "capsim.face.cli", "run", str(case), "-o", str(tmp_path / "b.h5")],
                            env=env, capture_output=True, text=True, timeout=600)
    assert second.returncode == 0 and "compiling" not in second.stderr


def test_kernels_cached_looks_where_numba_caches_the_kernels(monkeypatch, tmp_path):
    """Without NUMBA_CACHE_DIR, numba caches beside the kernels' module (capsim/numerics/); the
    'compiling the numba kernels' notice asks there, not beside api.py."""
    from pathlib import Path

    from capsim.api import kernels_cached
    from capsim.numerics import kernels

    monkeypatch.delenv("NUMBA_CACHE_DIR", raising=False)
    beside = Path(kernels.__file__).parent / "__pycache__"
    assert kernels_cached() == (beside.is_dir() and any(beside.glob("kernels.*.nbi")))
    monkeypatch.setenv("NUMBA_CACHE_DIR", str(tmp_path))
    assert not kernels_cached()
    (tmp_path / "some" / "where").mkdir(parents=True)
    (tmp_path / "some" / "where" / "kernels.layer_sum-1.py311.nbi").write_bytes(b"")
    assert kernels_cached()

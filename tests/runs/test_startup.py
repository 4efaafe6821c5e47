"""`capsim run`'s start-up (issue 29): the run path imports no module it does not use.

`make demo` is a 2-3 s command of which the imports were a third; a module pulled in
by one careless top-level import (scipy.spatial for one nearest-neighbour query,
scipy.linalg through the scheme registry of capsim.config, a plotting or units stack)
costs every run ~0.1 s. Each check runs in a fresh interpreter and reads sys.modules.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]

#: never needed by `capsim run` (plots, the xarray view of a run file, units, exports)
NOT_FOR_A_RUN = ("scipy.spatial", "matplotlib", "xarray", "pint", "dask", "pandas", "meshio", "netCDF4", "h5netcdf")


def _loaded_after(code: str, cwd: Path, watch: tuple[str, ...]) -> list[str]:
    """The modules of `watch` in sys.modules once `code` has run (its exit included)."""
    probe = (f"import atexit, json, sys\n"
             f"atexit.register(lambda: print(json.dumps(sorted(m for m in {list(watch)!r} if m in sys.modules))))\n"
             f"{code}\n")
    env = {k: v for k, v in os.environ.items() if not k.startswith(("NUMBA_", "CAPSIM_"))}
    env["PYTHONPATH"] = str(ROOT)
    out = subprocess.run([sys.executable, "-c", probe], cwd=cwd, env=env, capture_output=True, text=True, timeout=600)
    assert out.returncode == 0, out.stderr[-2000:]
    return json.loads(out.stdout.strip().splitlines()[-1])


def test_reading_a_case_loads_no_numerics():
    """The CLI, a case and the checkpoint module (what `capsim validate` and the start of
    `capsim run` load) import neither scipy nor numba nor HDF5."""
    loaded = _loaded_after("import capsim.face.cli, capsim.config, capsim.storage.checkpoint\n"
                           "capsim.config.load_case_with('configs/sphere.yaml', [])", ROOT,
                           ("scipy", "numba", "h5py", *NOT_FOR_A_RUN))
    assert loaded == []


def test_the_run_path_imports_nothing_it_does_not_use(tmp_path):
    """A whole (tiny) `capsim run` of the demo's case: no plotting, xarray, units or KD-tree."""
    import yaml

    data = yaml.safe_load((ROOT / "configs" / "sphere.yaml").read_text())
    data["mesh"]["level"] = 1
    data["time"]["t_end"] = 0.2
    data["output"] = {"path": "runs/tiny.h5", "snapshot_every": 0.1}
    (tmp_path / "sphere.yaml").write_text(yaml.safe_dump(data))
    run = ("from capsim.face.cli import app\n"
           "sys.argv = ['capsim', 'run', 'sphere.yaml']\n"
           "try:\n    app()\nexcept SystemExit as exc:\n    assert not exc.code, exc.code")
    loaded = _loaded_after(run, tmp_path, ("h5py", "numba", *NOT_FOR_A_RUN))
    assert (tmp_path / "runs" / "tiny.h5").exists()
    assert loaded == ["h5py", "numba"]  # what the run does need: the probe sees the imports made while it runs


def test_the_cli_leaves_its_heap_to_the_os_at_exit():
    """capsim.face.cli freezes the heap at exit (atexit handlers run last-registered first, so this
    probe, registered before the import, runs after it): the interpreter's teardown then skips
    collecting numba's, pydantic's and scipy's objects, ~0.2 s of every command."""
    code = ("import atexit, gc\n"
            "atexit.register(lambda: print('frozen' if gc.get_freeze_count() else 'not frozen'))\n"
            "import capsim.face.cli\n")
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr[-2000:]
    assert out.stdout.strip() == "frozen"


#: one case of every scene kind (issue 52): each flow kind, each flow history, a wall, several
#: capsules; test_every_scene_kind_is_sampled keeps it in step with the registries
SCENES = {
    "simple_shear": {"flow": {"kind": "simple_shear", "G": 0.05}},
    "planar_extension": {"flow": {"kind": "planar_extension", "G": 0.05}},
    "uniaxial_extension": {"flow": {"kind": "uniaxial_extension", "G": 0.05}},
    "linear": {"flow": {"kind": "linear", "G": 0.05, "velocity_gradient": [[0, 1, 0], [0, 0, 0], [0, 0, 0]]}},
    "poiseuille": {"flow": {"kind": "poiseuille", "G": 0.05, "poiseuille_radius": 5.0}},
    "history steady": {"flow": {"G": 0.05, "history": {"kind": "steady"}}},
    "history stop": {"flow": {"G": 0.05, "history": {"kind": "stop", "stop_time": 0.5}}},
    "history step": {"flow": {"G": 0.05, "history": {"kind": "step", "step_time": 0.5, "step_factor": 2.0}}},
    "history oscillating": {"flow": {"G": 0.05, "history": {"kind": "oscillating", "omega": 1.0}}},
    "history table": {"flow": {"G": 0.05, "history": {"kind": "table", "table": [[0.0, 1.0], [1.0, 2.0]]}}},
    "wall": {"flow": {"G": 0.05}, "wall": {"distance": 2.0}},
    "capsules": {"flow": {"G": 0.05}, "capsules": [{"center": [4.0, -0.5, 0.0]}, {"center": [-4.0, 0.5, 0.0]}]},
    "capsules above a wall": {"flow": {"G": 0.05}, "wall": {"distance": 2.0},
                              "capsules": [{"center": [4.0, 0.0, 0.0]}, {"center": [-4.0, 0.5, 0.0]}]},
    "conduit": {"flow": {"kind": "conduit", "G": 0.05}, "conduit": {"kind": "tube", "radius": 2.0}},
    "conduit duct": {"flow": {"kind": "conduit", "G": 0.05}, "conduit": {"kind": "duct", "half_widths": [2.0, 1.5]}},
    "conduit constriction": {"flow": {"kind": "conduit", "G": 0.05}, "initial_center": [-4.0, 0.0, 0.0],
                             "conduit": {"kind": "constriction", "radius": 2.0, "throat_radius": 1.2,
                                         "throat_length": 3.0}},
}


def test_every_scene_kind_is_sampled():
    from capsim.scene.conduit import CONDUITS
    from capsim.scene.flows import FLOW_HISTORIES, FLOWS

    assert {f"conduit {k}" for k in CONDUITS if k != "tube"} <= set(SCENES)
    assert set(FLOWS) <= set(SCENES) and {f"history {k}" for k in FLOW_HISTORIES} <= set(SCENES)


def test_validating_every_scene_kind_loads_no_numerics(tmp_path):
    """`capsim validate` of each scene kind imports neither numba nor scipy nor HDF5 (issue 52:
    a wall's or several capsules' start check measured their rest meshes through a numba kernel,
    ~0.3 s of imports for a command that reads a file). One interpreter validates them in turn
    and reports, after each, what it has loaded."""
    import yaml

    paths = {}
    for i, (scene, part) in enumerate(SCENES.items()):
        paths[scene] = tmp_path / f"scene{i}.yaml"
        paths[scene].write_text(yaml.safe_dump({"name": f"scene{i}", "mesh": {"level": 1}, "time": {"t_end": 1.0},
                                                **part}))
    watch = ("scipy", "numba", "h5py", *NOT_FOR_A_RUN)
    code = ("import contextlib, io, json\n"
            "from capsim.face.cli import app\n"
            "report = {}\n"
            f"for scene, path in {({k: str(v) for k, v in paths.items()})!r}.items():\n"
            "    out = io.StringIO()\n"
            "    with contextlib.redirect_stdout(out):\n"
            "        try:\n            app(['validate', path])\n"
            "        except SystemExit as exc:\n            assert not exc.code, (scene, exc.code)\n"
            "    assert 'flow:' in out.getvalue(), scene\n"
            f"    report[scene] = sorted(m for m in {list(watch)!r} if m in sys.modules)\n"
            "print(json.dumps(report))\n")
    probe = f"import sys\n{code}"
    env = {k: v for k, v in os.environ.items() if not k.startswith(("NUMBA_", "CAPSIM_"))}
    env["PYTHONPATH"] = str(ROOT)
    out = subprocess.run([sys.executable, "-c", probe], cwd=tmp_path, env=env, capture_output=True, text=True,
                         timeout=600)
    assert out.returncode == 0, out.stderr[-2000:]
    report = json.loads(out.stdout.strip().splitlines()[-1])
    assert report == {scene: [] for scene in SCENES}

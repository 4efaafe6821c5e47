"""Imports among capsim modules run one way: no cycle, imports inside functions included.

A lazy import (to keep the CLI fast, or to set numba's thread count before numba
loads) is fine; one that hides a cycle is not. The graph is read from the
source with ``ast``, so an import inside a function counts like one at the top.
"""

import ast
from pathlib import Path

PACKAGE = Path(__file__).resolve().parents[1] / "capsim"


def _module_name(path: Path) -> str:
    parts = path.relative_to(PACKAGE.parent).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _sources() -> list[Path]:
    """Every module of the package, its sub-packages' included (capsim/scene/...)."""
    return sorted(PACKAGE.rglob("*.py"))


def _imports(path: Path, modules: set[str], text: str | None = None) -> set[str]:
    """Every capsim module `path` imports (or `text`, its source as given), at any depth of its code."""
    found: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text() if text is None else text, filename=str(path))):
        if isinstance(node, ast.Import):
            names = [alias.name for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level:  # relative: from . import x / from .x import y, from the module's package
                package = _module_name(path).split(".")
                package = package if path.stem == "__init__" else package[:-1]
                package = package[:len(package) - node.level + 1]
                base = ".".join(package) + (f".{node.module}" if node.module else "")
            else:
                base = node.module or ""
            # `from capsim.storage import store` imports the module capsim.storage.store, and not the
            # package's __init__ as such when every name it takes is a module
            names = [f"{base}.{alias.name}" for alias in node.names]
            if not all(name in modules for name in names):
                names.append(base)
        else:
            continue
        for name in names:
            if name in modules:
                found.add(name)
    found.discard(_module_name(path))
    return found


def import_graph() -> dict[str, set[str]]:
    paths = _sources()
    modules = {_module_name(p) for p in paths}
    return {_module_name(p): _imports(p, modules) for p in paths}


def _find_cycle(graph: dict[str, set[str]]) -> list[str] | None:
    state: dict[str, int] = {}  # 1 on the stack, 2 done
    stack: list[str] = []

    def visit(node: str) -> list[str] | None:
        state[node] = 1
        stack.append(node)
        for dep in sorted(graph[node]):
            if state.get(dep) == 1:
                return stack[stack.index(dep):] + [dep]
            if dep not in state:
                cycle = visit(dep)
                if cycle:
                    return cycle
        stack.pop()
        state[node] = 2
        return None

    for node in sorted(graph):
        if node not in state:
            cycle = visit(node)
            if cycle:
                return cycle
    return None


def test_the_graph_sees_function_level_imports():
    graph = import_graph()
    assert "capsim.storage.store" in graph["capsim.runs.runner"]
    # summary -> campaign, and not back (campaign reads run status through store)
    assert "capsim.campaigns.campaign" in graph["capsim.campaigns.summary"]
    assert "capsim.campaigns.summary" not in graph["capsim.campaigns.campaign"]


def test_no_import_cycle_among_capsim_modules():
    cycle = _find_cycle(import_graph())
    assert cycle is None, "import cycle: " + " -> ".join(cycle)


def test_the_cycle_finder_finds_a_cycle():
    assert _find_cycle({"a": {"b"}, "b": {"c"}, "c": {"a"}}) == ["a", "b", "c", "a"]
    assert _find_cycle({"a": {"b"}, "b": set()}) is None


# ---------------------------------------------------------------- the layers (the wings, issue 52)

#: the package's layers, bottom first: a module may import its own layer and those below it,
#: never one above (no back arrow). The root's modules each have their place: errors, units and
#: the quantity table under everything; the case schema (config) names the numerics', the
#: scene's and the solve's registries and is read by the run store and everything above; the
#: library face (capsim, capsim.api) sits with the CLI at the top.
LAYERS = (
    {"capsim._version", "capsim._surface", "capsim.errors", "capsim.quantities", "capsim.units"},
    {"capsim.numerics"},
    {"capsim.scene"},
    {"capsim.solve"},
    {"capsim.config"},
    {"capsim.storage"},
    {"capsim.runs"},
    {"capsim.campaigns"},
    {"capsim.face", "capsim.api", "capsim"},
)


def _layer(module: str) -> int:
    """The layer of a module: the root module itself, else the sub-package it lives in."""
    parts = module.split(".")
    for name in (module, ".".join(parts[:2])):
        for rank, members in enumerate(LAYERS):
            if name in members:
                return rank
    raise AssertionError(f"{module} is in no layer: add its sub-package to LAYERS")


def _runtime_imports(path: Path, modules: set[str]) -> set[str]:
    """As `_imports`, less the imports under ``if TYPE_CHECKING:`` (annotations, no dependency)."""
    tree = ast.parse(path.read_text(), filename=str(path))
    for node in ast.walk(tree):
        if isinstance(node, ast.If) and getattr(node.test, "id", getattr(node.test, "attr", None)) == "TYPE_CHECKING":
            node.body = [ast.Pass()]
    return _imports(path, modules, ast.unparse(tree))


def test_every_module_has_a_layer_and_the_root_is_small():
    graph = import_graph()
    for module in graph:
        _layer(module)
    root = {m for m in graph if m.count(".") == 1 and (PACKAGE / (m.split(".")[1] + ".py")).exists()}
    assert root == {"capsim._surface", "capsim._version", "capsim.api", "capsim.config", "capsim.errors",
                    "capsim.quantities", "capsim.units"}, root


def test_no_back_arrow_between_layers():
    """A lower layer never imports a higher one, imports inside functions included."""
    paths = _sources()
    modules = {_module_name(p) for p in paths}
    arrows = []
    for path in paths:
        module = _module_name(path)
        for dep in _runtime_imports(path, modules):
            if _layer(dep) > _layer(module):
                arrows.append(f"{module} -> {dep}")
    assert not arrows, arrows


def test_the_layer_rule_sees_a_back_arrow():
    assert _layer("capsim.numerics.kernels") < _layer("capsim.solve.solver") < _layer("capsim.face.cli")
    assert _layer("capsim.config") < _layer("capsim.storage.store")
    assert _layer("capsim.errors") < _layer("capsim.numerics.mesh")


def test_no_re_export_shim_at_the_old_paths():
    """The modules moved into the sub-packages left nothing behind at the package's root."""
    for name in ("kernels", "solver", "flows", "store", "files", "runner", "campaign", "cli", "plot", "export",
                 "bodies", "accuracy", "threads"):
        assert not (PACKAGE / f"{name}.py").exists(), name


def test_quantities_and_summary_stay_light():
    """The quantity table imports nothing of capsim; the summary no h5py, store no numba."""
    graph = import_graph()
    assert graph["capsim.quantities"] == set()
    for module, banned in (("campaigns.summary", "h5py"), ("quantities", "numba"), ("storage.store", "numba")):
        tree = ast.parse(_path(module).read_text())
        names = {alias.name.split(".")[0] for node in ast.walk(tree)
                 if isinstance(node, (ast.Import, ast.ImportFrom))
                 for alias in (node.names if isinstance(node, ast.Import) else [ast.alias(node.module or "")])}
        assert banned not in names, f"capsim.{module} imports {banned}"


def _path(module: str) -> Path:
    """The source of a module named from the package down: "face.cli" -> capsim/face/cli.py."""
    return PACKAGE.joinpath(*module.split(".")).with_suffix(".py")


def _imported_names(module: str) -> set[str]:
    tree = ast.parse(_path(module).read_text())
    return {alias.name for node in ast.walk(tree) if isinstance(node, (ast.Import, ast.ImportFrom))
            for alias in (node.names if isinstance(node, ast.Import) else [ast.alias(node.module or "")])}


def test_the_cli_is_a_thin_face():
    """cli.py parses and prints (issue 27): no HDF5, no file naming or renaming of its own, <= 600 lines."""
    import re

    text = _path("face.cli").read_text()
    assert not any(name.split(".")[0] == "h5py" for name in _imported_names("face.cli"))
    found = [line for line in text.splitlines() if re.search(r"h5py|ckpt|tmp-|rename|replace\(", line)]
    assert not found, found
    assert len(text.splitlines()) <= 600


def test_only_the_checkpoint_module_knows_the_checkpoint_format():
    """Its format (the constant, the npz writer) in capsim/storage/checkpoint.py; its name in capsim/storage/files.py."""
    import re

    for path in _sources():
        text = path.read_text()
        if path.name != "checkpoint.py":
            assert not re.search(r"CHECKPOINT_FORMAT|^FORMAT =|np\.savez", text, re.M), path.name
        if path.name != "files.py":  # the name as a literal of code (documentation may mention it)
            assert not re.search(r"[\"']\.ckpt\.npz", text), path.name


def test_every_writer_uses_the_one_temporary_name():
    """Temporary files are named by capsim.storage.files.tmp_name alone: no module builds its own."""
    import re

    for path in _sources():
        if path.name == "files.py":
            continue
        assert not re.search(r"\.tmp-|\+ \"\.tmp\"|\.tmp\"\)", path.read_text()), path.name


def test_one_formatter_for_every_schema_error():
    """A case's and a campaign's schema errors are worded by config.format_validation_error alone
    (issue 27): no other module walks a ValidationError's list of problems."""
    import re

    for path in _sources():
        if path.name != "config.py":
            assert not re.search(r"\.errors\(", path.read_text()), path.name
    # the campaign's base model is the case schema's strict base
    from capsim.campaigns.campaign import Campaign
    from capsim.config import StrictModel

    assert issubclass(Campaign, StrictModel)


# ---------------------------------------------------------------- the scene (capsim/scene/, issue 52)

#: what the scene may import of capsim: the flows, the meshes and the kernels under it (a
#: boundary kind's regular part is a kernel), the membrane laws (the capsules' own materials);
#: nothing of the solve, the time stepping, the files, the campaigns or the face
SCENE_MAY_IMPORT = {"capsim.scene.flows", "capsim.numerics.mesh", "capsim.numerics.geometry", "capsim.numerics.quadrature", "capsim.numerics.kernels",
                    "capsim.numerics.membrane", "capsim.numerics.conduit_mesh", "capsim.numerics.rigid_surface",
                    "capsim.errors"}


def test_the_scene_imports_nothing_above_it():
    graph = import_graph()
    scene = {m for m in graph if m == "capsim.scene" or m.startswith("capsim.scene.")}
    assert {"capsim.scene", "capsim.scene.scene", "capsim.scene.bodies", "capsim.scene.boundaries",
            "capsim.scene.plane_wall"} <= scene
    for module in sorted(scene):
        above = graph[module] - scene - SCENE_MAY_IMPORT
        assert not above, f"{module} imports {sorted(above)}"
    assert not (PACKAGE / "bodies.py").exists()  # moved into the scene, no shim left


def test_a_boundary_kind_is_one_module_of_the_scene():
    """Every registered boundary kind is defined in a module of its own in capsim/scene/, and no
    module outside it names the kind's class or calls its kernels: a new kind (a tube, a periodic
    box) is one module there."""
    import re

    from capsim.scene import BOUNDARIES

    assert "plane_wall" in BOUNDARIES
    homes = {}
    for name, kind in BOUNDARIES.items():
        assert kind.__module__.startswith("capsim.scene."), (name, kind.__module__)
        assert kind.__module__ not in homes.values(), f"two boundary kinds in {kind.__module__}"
        homes[name] = kind.__module__
        home = PACKAGE.parent / (kind.__module__.replace(".", "/") + ".py")
        for path in _sources():
            if path != home:
                assert not re.search(rf"\b{kind.__name__}\b", path.read_text()), (kind.__name__, path.name)
    # the wall's kernels are called from its module alone
    for path in _sources():
        if path.name not in ("kernels.py", "plane_wall.py"):
            assert not re.search(r"wall_image_(sum|double_layer)\(", path.read_text()), path.name


def test_the_walls_position_is_read_in_three_modules():
    """The wall's distance and position (wall.distance, the case's wall_y, the kernels' y_wall) are
    read in the wall's module, the schema's validation and the kernels alone (docs/developer.md,
    "The scene"); everyone else asks the scene."""
    import re

    readers = {_module_name(path) for path in _sources()
               if re.search(r"\bwall_y\b|\by_wall\b|wall\.distance", path.read_text())}
    assert readers <= {"capsim.scene.plane_wall", "capsim.config", "capsim.numerics.kernels"}, readers


def test_no_module_fishes_a_scene_part_off_the_model_or_the_case():
    """No getattr(model, "wall_y" | "bodies" | "far_field" ...) or getattr(case, "wall" | "capsules"):
    the scene's parts are asked of the scene (model.scene, Scene.of(case))."""
    import re

    pattern = re.compile(r"getattr\((model|self\.model|case), \"(wall|wall_y|bodies|far_field|capsules|scene)\"")
    for path in _sources():
        assert not pattern.search(path.read_text()), path.name


# ---------------------------------------------------------------- one public surface per package (issue 52)

#: the sub-packages whose __init__ is a lazy table (PEP 562) of the names their modules give
SURFACES = ("capsim.numerics", "capsim.solve", "capsim.storage", "capsim.runs", "capsim.campaigns", "capsim.face")


def _top_level_definitions(module: str) -> set[str]:
    """The names a module binds itself at its top level (def, class, assignment), not by an import."""
    names = set()
    for node in ast.parse(_path(module.removeprefix("capsim.")).read_text()).body:
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
            names.add(node.name)
        elif isinstance(node, (ast.Assign, ast.AnnAssign)):
            for target in node.targets if isinstance(node, ast.Assign) else [node.target]:
                names |= {n.id for n in ast.walk(target) if isinstance(n, ast.Name)}
    return names


def test_each_sub_package_has_one_lazy_public_surface():
    """Every name of a sub-package's ``__all__`` resolves to an object defined in one of its own
    modules (not a re-export, no name shadowing a module); and importing the six packages, in a
    fresh interpreter, loads none of numba, h5py, matplotlib, xarray, scipy."""
    import importlib
    import inspect
    import json
    import os
    import subprocess
    import sys

    for package in SURFACES:
        pkg = importlib.import_module(package)
        modules = {p.stem for p in (PACKAGE / package.split(".")[1]).glob("*.py")} - {"__init__"}
        assert pkg.__all__ and len(set(pkg.__all__)) == len(pkg.__all__), package
        assert set(pkg.__all__) <= set(dir(pkg)), package
        for name in pkg.__all__:
            assert name not in modules, f"{package}.{name} is also a module's name"
            home = f"{package}." + next(module for module, names in pkg._SURFACE.items() if name in names.split())
            assert home.startswith(package + "."), (package, name, home)
            value = getattr(pkg, name)
            assert value is getattr(importlib.import_module(home), name), (package, name)
            assert name in _top_level_definitions(home), f"{name} is imported into {home}, not defined there"
            if inspect.isclass(value) or inspect.isfunction(value) or hasattr(value, "py_func"):
                assert value.__module__ == home, (package, name, value.__module__)
        try:
            pkg.no_such_name
        except AttributeError:
            pass
        else:
            raise AssertionError(f"{package} invents a name")

    banned = ["numba", "h5py", "matplotlib", "xarray", "scipy"]
    code = (f"import sys, json\nimport {', '.join(SURFACES)}\n"
            f"print(json.dumps(sorted(m for m in {banned!r} if m in sys.modules)))\n")
    env = {k: v for k, v in os.environ.items() if not k.startswith(("NUMBA_", "CAPSIM_"))}
    env["PYTHONPATH"] = str(PACKAGE.parent)
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr[-2000:]
    assert json.loads(out.stdout.strip().splitlines()[-1]) == []


def test_the_command_line_starts_without_package_metadata_or_numerics():
    """Importing the CLI loads neither importlib.metadata (30 ms: the version is a literal in
    capsim/_version.py) nor numpy, numba, scipy, h5py, pydantic or pint (issue 57: a command loads
    what it uses); the installed metadata's version is that literal."""
    import subprocess
    import sys
    from importlib.metadata import version

    import capsim

    probe = ("import sys, capsim.face.cli; print(' '.join(m for m in ('importlib.metadata', 'numpy', 'numba', "
             "'scipy', 'h5py', 'pydantic', 'pint') if m in sys.modules))")
    loaded = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, check=True).stdout.split()
    assert loaded == [], loaded
    assert version("capsim") == capsim.__version__

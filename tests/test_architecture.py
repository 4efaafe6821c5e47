"""Imports among capsim modules run one way: no cycle, imports inside functions included.

A lazy import (to keep the CLI fast, or to set numba's thread count before numba
loads) is fine; one that hides a cycle is not. The graph is read from the
source with ``ast``, so an import inside a function counts like one at the top.
"""

import ast
from pathlib import Path

PACKAGE = Path(__file__).resolve().parents[1] / "capsim"


def _module_name(path: Path) -> str:
    return "capsim" if path.stem == "__init__" else f"capsim.{path.stem}"


def _imports(path: Path, modules: set[str]) -> set[str]:
    """Every capsim module `path` imports, at any depth of its code."""
    found: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text(), filename=str(path))):
        if isinstance(node, ast.Import):
            names = [alias.name for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level:  # relative: from . import x / from .x import y
                base = "capsim" + (f".{node.module}" if node.module else "")
            else:
                base = node.module or ""
            # `from capsim import store` imports the module capsim.store
            names = [base] + [f"{base}.{alias.name}" for alias in node.names]
        else:
            continue
        for name in names:
            if name in modules:
                found.add(name)
    found.discard(_module_name(path))
    return found


def import_graph() -> dict[str, set[str]]:
    paths = sorted(PACKAGE.glob("*.py"))
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
    assert "capsim.store" in graph["capsim.runner"]
    # summary -> campaign, and not back (campaign reads run status through store)
    assert "capsim.campaign" in graph["capsim.summary"]
    assert "capsim.summary" not in graph["capsim.campaign"]


def test_no_import_cycle_among_capsim_modules():
    cycle = _find_cycle(import_graph())
    assert cycle is None, "import cycle: " + " -> ".join(cycle)


def test_the_cycle_finder_finds_a_cycle():
    assert _find_cycle({"a": {"b"}, "b": {"c"}, "c": {"a"}}) == ["a", "b", "c", "a"]
    assert _find_cycle({"a": {"b"}, "b": set()}) is None


def test_quantities_and_summary_stay_light():
    """The quantity table imports nothing of capsim; the summary no h5py, store no numba."""
    graph = import_graph()
    assert graph["capsim.quantities"] == set()
    for module, banned in (("summary", "h5py"), ("quantities", "numba"), ("store", "numba")):
        tree = ast.parse((PACKAGE / f"{module}.py").read_text())
        names = {alias.name.split(".")[0] for node in ast.walk(tree)
                 if isinstance(node, (ast.Import, ast.ImportFrom))
                 for alias in (node.names if isinstance(node, ast.Import) else [ast.alias(node.module or "")])}
        assert banned not in names, f"capsim.{module} imports {banned}"


def _imported_names(module: str) -> set[str]:
    tree = ast.parse((PACKAGE / f"{module}.py").read_text())
    return {alias.name for node in ast.walk(tree) if isinstance(node, (ast.Import, ast.ImportFrom))
            for alias in (node.names if isinstance(node, ast.Import) else [ast.alias(node.module or "")])}


def test_the_cli_is_a_thin_face():
    """cli.py parses and prints (issue 27): no HDF5, no file naming or renaming of its own, <= 600 lines."""
    import re

    text = (PACKAGE / "cli.py").read_text()
    assert not any(name.split(".")[0] == "h5py" for name in _imported_names("cli"))
    found = [line for line in text.splitlines() if re.search(r"h5py|ckpt|tmp-|rename|replace\(", line)]
    assert not found, found
    assert len(text.splitlines()) <= 600


def test_only_the_checkpoint_module_knows_the_checkpoint_format():
    """Its format (the constant, the npz writer) in capsim/checkpoint.py; its name in capsim/files.py."""
    import re

    for path in PACKAGE.glob("*.py"):
        text = path.read_text()
        if path.name != "checkpoint.py":
            assert not re.search(r"CHECKPOINT_FORMAT|^FORMAT =|np\.savez", text, re.M), path.name
        if path.name != "files.py":  # the name as a literal of code (documentation may mention it)
            assert not re.search(r"[\"']\.ckpt\.npz", text), path.name


def test_every_writer_uses_the_one_temporary_name():
    """Temporary files are named by capsim.files.tmp_name alone: no module builds its own."""
    import re

    for path in PACKAGE.glob("*.py"):
        if path.name == "files.py":
            continue
        assert not re.search(r"\.tmp-|\+ \"\.tmp\"|\.tmp\"\)", path.read_text()), path.name


def test_one_formatter_for_every_schema_error():
    """A case's and a campaign's schema errors are worded by config.format_validation_error alone
    (issue 27): no other module walks a ValidationError's list of problems."""
    import re

    for path in PACKAGE.glob("*.py"):
        if path.name != "config.py":
            assert not re.search(r"\.errors\(", path.read_text()), path.name
    # the campaign's base model is the case schema's strict base
    from capsim.campaign import Campaign
    from capsim.config import StrictModel

    assert issubclass(Campaign, StrictModel)

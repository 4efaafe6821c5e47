"""The docs name only what the code has (issue 38, finding 9): every page of the docs, the
README and REPRODUCTION.md are read for the names they cite, and each is looked up in the code.

* case fields written dotted (``time.max_wall_s``, ``flow.shear_rate_G = 0.1``): the schema;
* commands and their options (``capsim sweep ... --workers 2``): the CLI;
* groups and datasets of a run file (``/timeseries``, ``mesh/positions``, ``summary/``): a run
  file written here;
* figure kinds (``--kind steady``): capsim.face.plot's registry;
* motion classes (``motion = tumbling``, a code span on a line about the motion): the classes
  of capsim.quantities (an old name only where the line says it is old);
* summary dimensions (``dimension `x` ``): the names summarize gives them.
"""

from __future__ import annotations

import re
from pathlib import Path

import h5py
import pytest
import typer

import capsim

ROOT = Path(__file__).resolve().parents[1]
# capsim/api.py: its docstrings are the Python API page (mkdocstrings renders them)
PAGES = sorted({*ROOT.glob("docs/*.md"), *ROOT.glob("docs/**/*.md"), ROOT / "README.md", ROOT / "REPRODUCTION.md",
                ROOT / "capsim" / "api.py"})

SECTIONS = ("shape", "membrane", "flow", "mesh", "quadrature", "time", "guards", "solver", "output", "physical",
            "accuracy")
_DOTTED = re.compile(rf"\b((?:{'|'.join(SECTIONS)})(?:\.[A-Za-z_][A-Za-z0-9_]*)+)\b")
_SPAN = re.compile(r"`([^`\n]+)`")
_COMMAND = re.compile(r"(?<![\w.])capsim[ \t]+([a-z][a-z-]*)((?:[^\n`|;&)]*))")
_OPTION = re.compile(r"(?<![\w-])(--[a-z][a-z-]*)")
_KIND = re.compile(r"--kind[ =]+([a-z_]+)")
_FENCE = re.compile(r"^(```|~~~)[^\n]*\n(.*?)^\1", re.M | re.S)
#: the groups at the top of a run file; a path in a code span starting with one of these (or
#: with "/") names a group or dataset of the run file
_RUN_FILE_TOPS = ("mesh", "timeseries", "summary", "run", "membrane_law", "rest_shape", "snapshots",
                  "error_estimate", "end_state", "membrane")
_H5PATH = re.compile(r"^/?[a-z_]+(?:/[a-z_0-9]+)*/?$")


def _code_texts(text: str) -> list[str]:
    """Inline code spans and fenced code blocks of a page."""
    blocks = [m.group(2) for m in _FENCE.finditer(text)]
    rest = _FENCE.sub("", text)
    return blocks + _SPAN.findall(rest)


def _case_model():
    from capsim.config import Case

    return Case


def _resolves(dotted: str) -> bool:
    """Whether a dotted name is a section or field of the case schema or of a campaign
    (``output.dir``), or an attribute of a capsim module (``membrane.LAWS``)."""
    import importlib

    module, _, attr = dotted.partition(".")
    # a module is named by its own name (membrane.LAWS), wherever its layer put it
    for home in ("capsim", *(f"capsim.{p.name}" for p in sorted(Path(capsim.__file__).parent.iterdir())
                             if (p / "__init__.py").exists())):
        try:
            if "." not in attr and hasattr(importlib.import_module(f"{home}.{module}"), attr):
                return True
        except ImportError:
            pass
    from capsim.campaigns.campaign import Campaign
    from capsim.config import _ALIASES  # a field's short name (flow.G) names that field

    dotted = _ALIASES.get(dotted, dotted)
    return _in_model(_case_model(), dotted) or _in_model(Campaign, dotted)


def _in_model(model, dotted: str) -> bool:
    from pydantic import BaseModel

    parts = dotted.split(".")
    for i, part in enumerate(parts):
        fields = getattr(model, "model_fields", None)
        if fields is None or part not in fields:
            return False
        annotation = fields[part].annotation
        inner = [a for a in getattr(annotation, "__args__", ()) if isinstance(a, type) and issubclass(a, BaseModel)]
        if isinstance(annotation, type) and issubclass(annotation, BaseModel):
            model = annotation
        elif inner:
            model = inner[0]
        else:
            return i == len(parts) - 1
    return True


def _cli():
    from capsim.face.cli import app

    group = typer.main.get_command(app)
    return {name: {opt for p in cmd.params for opt in (*getattr(p, "opts", ()), *getattr(p, "secondary_opts", ()))}
            for name, cmd in group.commands.items()}


@pytest.fixture(scope="module")
def run_file_paths(tmp_path_factory) -> set[str]:
    from capsim.config import case_from_dict
    from capsim.runs.runner import run_case

    tmp = tmp_path_factory.mktemp("names")
    case = case_from_dict({"name": "n", "mesh": {"level": 0}, "time": {"t_end": 0.2},
                           "output": {"path": str(tmp / "n.h5")}})
    run_case(case)
    # a pair of capsules: the summary's capsule group
    pair = case_from_dict({"name": "p", "mesh": {"level": 0}, "time": {"t_end": 0.2},
                           "capsules": [{"center": [-2.0, 0.2, 0.0]}, {"center": [2.0, -0.2, 0.0]}],
                           "output": {"path": str(tmp / "p.h5")}})
    run_case(pair)
    paths: set[str] = set()
    for name in ("n.h5", "p.h5"):
        with h5py.File(tmp / name, "r") as f:
            f.visit(paths.add)
    return paths


def _pages():
    return [(p, p.read_text(encoding="utf-8")) for p in PAGES]


def test_every_dotted_case_field_a_page_names_is_in_the_schema():
    missing = []
    for page, text in _pages():
        for code in _code_texts(text):
            for dotted in _DOTTED.findall(code):
                if dotted.endswith((".yaml", ".h5", ".nc", ".md", ".py")) or not _resolves(dotted):
                    if not dotted.endswith((".yaml", ".h5", ".nc", ".md", ".py")):
                        missing.append(f"{page.relative_to(ROOT)}: {dotted}")
    assert not missing, "fields the schema does not have:\n" + "\n".join(sorted(set(missing)))


def test_every_command_and_option_a_page_names_exists():
    commands = _cli()
    missing = []
    for page, text in _pages():
        for code in _code_texts(text):
            for m in _COMMAND.finditer(code):
                name, rest = m.group(1), m.group(2)
                if name not in commands:
                    missing.append(f"{page.relative_to(ROOT)}: capsim {name}")
                    continue
                for option in _OPTION.findall(rest):
                    if option not in commands[name] and option not in ("--help", "--version"):
                        missing.append(f"{page.relative_to(ROOT)}: capsim {name} {option}")
    assert not missing, "commands or options the CLI does not have:\n" + "\n".join(sorted(set(missing)))


def test_every_figure_kind_a_page_names_exists():
    from capsim.face.plot import KINDS

    missing = [f"{page.relative_to(ROOT)}: --kind {kind}" for page, text in _pages()
               for code in _code_texts(text) for kind in _KIND.findall(code) if kind not in KINDS]
    assert not missing, "figure kinds capsim.face.plot does not have:\n" + "\n".join(sorted(set(missing)))


def test_every_run_file_group_a_page_names_exists(run_file_paths):
    missing = []
    for page, text in _pages():
        for span in _SPAN.findall(_FENCE.sub("", text)):
            token = span.strip()
            if not _H5PATH.match(token) or "/" not in token:
                continue
            parts = [p for p in token.strip("/").split("/") if p]
            if not parts or (parts[0] not in _RUN_FILE_TOPS and not token.startswith("/")):
                continue
            if token.startswith("/") and parts[0] not in _RUN_FILE_TOPS and len(parts) == 1:
                missing.append(f"{page.relative_to(ROOT)}: {token}")
                continue
            if "/".join(parts) not in run_file_paths and parts[0] not in ("error_estimate", "end_state"):
                missing.append(f"{page.relative_to(ROOT)}: {token}")
    assert not missing, "run-file groups or datasets a run file does not have:\n" + "\n".join(sorted(set(missing)))


def test_every_motion_class_a_page_names_exists():
    from capsim.quantities import MOTION_ALIASES, MOTIONS

    words = set(MOTIONS) | set(MOTION_ALIASES) | {"oscillating", "steady", "swinging", "transient", "relaxing"}
    missing = []
    for page, text in _pages():
        for line in text.splitlines():
            if not re.search(r"motion|class|orbit", line.lower()):
                continue
            old_named = re.search(r"\b(was|old|older|before|formerly|alias|aliases|renamed|read as)\b", line, re.I)
            for span in _SPAN.findall(line):
                token = span.strip()
                if token in words and token not in MOTIONS and not old_named:
                    missing.append(f"{page.relative_to(ROOT)}: `{token}` in: {line.strip()[:100]}")
    assert not missing, "motion classes capsim does not report:\n" + "\n".join(sorted(set(missing)))


def test_every_summary_dimension_a_page_names_exists():
    """A summary's dimensions are named by the swept field's last part (``shear_rate_G``,
    ``viscosity_ratio``), ``run`` for a zip, the campaign's own; a page that names a
    dimension ``G`` or ``lam`` names one no summary has."""
    from capsim.config import Case

    leaves = set()

    def walk(model):
        for name, field in model.model_fields.items():
            leaves.add(name)
            annotation = field.annotation
            for a in (annotation, *getattr(annotation, "__args__", ())):
                if isinstance(a, type) and hasattr(a, "model_fields"):
                    walk(a)

    walk(Case)
    allowed = leaves | {"run"} | {"t", "snapshot", "node", "element"}  # and a run file's own
    missing = []
    for page, text in _pages():
        for m in re.finditer(r"dimensions?\s+((?:`[^`]+`(?:\s*(?:,|and|or|/)\s*)?)+)", _FENCE.sub("", text)):
            for name in _SPAN.findall(m.group(1)):
                if re.fullmatch(r"[A-Za-z_]\w*", name) and name not in allowed:
                    missing.append(f"{page.relative_to(ROOT)}: dimension `{name}`")
    assert not missing, "summary dimensions summarize does not make:\n" + "\n".join(sorted(set(missing)))

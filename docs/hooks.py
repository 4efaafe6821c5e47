"""MkDocs hooks: the generated reference pages (docs/gen_reference.py) are added to the site at
every build, so the case-file reference and the quantity table never drift from the code."""

from __future__ import annotations

import importlib.util
from pathlib import Path

from mkdocs.structure.files import File

_GEN = Path(__file__).with_name("gen_reference.py")


def _generator():
    spec = importlib.util.spec_from_file_location("capsim_docs_gen_reference", _GEN)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def on_files(files, config):
    gen = _generator()
    for page in gen.PAGES:
        files.append(File.generated(config, page, content=gen.generate(page)))
    return files

"""The documentation site (mkdocs.yml, docs/): the generated references say what the code
holds, and every page, included file and generated page the site names is real.

The site itself is built by `make docs` (CI, warnings as errors); these checks need no
docs generator."""

from __future__ import annotations

import importlib.util
import re
from pathlib import Path

import yaml

ROOT = Path(__file__).resolve().parents[1]


def _generator():
    spec = importlib.util.spec_from_file_location("gen_reference", ROOT / "docs" / "gen_reference.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _leaf_keys(data, prefix=""):
    for key, value in data.items():
        dotted = f"{prefix}{key}"
        yield dotted
        if isinstance(value, dict):
            yield from _leaf_keys(value, dotted + ".")


def _nav_pages(nav) -> list[str]:
    out = []
    for item in nav:
        value = next(iter(item.values())) if isinstance(item, dict) else item
        out.extend(_nav_pages(value) if isinstance(value, list) else [value])
    return out


def test_case_reference_lists_every_field_of_the_schema():
    from capsim.config import Case, load_case

    page = _generator().case_file_markdown()
    documented = set(re.findall(r"^\| `([\w.]+)` \|", page, re.M))
    # every field of the models, at every depth (optional sections included) ...
    schema = {dotted for dotted, _, _ in _generator().schema_fields(Case)}
    sections = {name for name, f in Case.model_fields.items() if _generator()._models_in(f.annotation)}
    assert schema - sections <= documented, f"undocumented fields: {sorted(schema - sections - documented)}"
    assert documented <= schema, f"documented fields not in the schema: {sorted(documented - schema)}"
    # ... and every key `capsim validate` prints for the shipped cases
    for path in sorted((ROOT / "configs").glob("*.yaml")):
        printed = yaml.safe_load(load_case(path).to_yaml())
        keys = set(_leaf_keys(printed)) - sections
        assert keys <= documented, f"{path.name}: fields validate prints but the reference lacks: {sorted(keys - documented)}"


def test_case_reference_states_defaults_and_bounds_from_the_schema():
    page = _generator().case_file_markdown()
    row = re.search(r"^\| `mesh.level` \|([^\n]*)$", page, re.M).group(1)
    from capsim.config import Mesh

    field = Mesh.model_fields["level"]
    assert f"`{field.default}`" in row
    bounds = [getattr(m, a) for m in field.metadata for a in ("ge", "le") if getattr(m, a, None) is not None]
    assert bounds and all(f"`{b}`" in row for b in bounds), row
    scheme_row = re.search(r"^\| `time.scheme` \|([^\n]*)$", page, re.M).group(1)
    from capsim.solve.timestepping import SCHEMES

    assert all(f"`{name}`" in scheme_row for name in SCHEMES)


def test_quantity_reference_lists_every_quantity():
    from capsim.quantities import TABLE

    page = _generator().quantities_markdown()
    listed = re.findall(r"^\| `([^`]+)` \|", page, re.M)
    assert sorted(listed) == sorted(TABLE)


def test_every_page_and_include_of_the_site_is_real():
    config = yaml.safe_load((ROOT / "mkdocs.yml").read_text())
    generated = set(_generator().PAGES)
    for page in _nav_pages(config["nav"]):
        assert (ROOT / "docs" / page).is_file() or page in generated, f"mkdocs.yml names a missing page: {page}"
    on_disk = {p.relative_to(ROOT / "docs").as_posix() for p in (ROOT / "docs").rglob("*.md")}
    assert on_disk <= set(_nav_pages(config["nav"])), f"pages not in the nav: {sorted(on_disk - set(_nav_pages(config['nav'])))}"
    assert not generated & on_disk, "a generated page is also a file in docs/"
    for md in (ROOT / "docs").rglob("*.md"):
        for included in re.findall(r'^--8<-- "([^"]+)"', md.read_text(), re.M):
            assert (ROOT / included).is_file(), f"{md.name} includes a missing file: {included}"
    benchmarks = (ROOT / "docs" / "benchmarks.md").read_text()
    for md in sorted((ROOT / "benchmarks").glob("*.md")):
        assert f'--8<-- "benchmarks/{md.name}"' in benchmarks, f"docs/benchmarks.md does not include {md.name}"

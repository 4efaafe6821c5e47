"""The schema's and the CLI's choices are the registries' (issue 13, item 6).

capsim.config stays free of numba and numpy (the CLI imports it to check a case
before any kernel loads), so its ``Literal`` choices are written out there and
checked here against the registries of the modules that implement them.
"""

from __future__ import annotations

import inspect
from typing import get_args

import pytest

from capsim.face import cli
from capsim import config
from capsim.config import Case, Membrane, Mesh, Quadrature, Shape, Solver, Time


def _choices(model, field: str) -> tuple:
    return get_args(model.model_fields[field].annotation)


def test_membrane_laws_are_the_registry():
    from capsim.numerics.membrane import LAWS

    assert set(_choices(Membrane, "law")) == set(LAWS)


def test_rest_shapes_and_bases_are_the_registries():
    from capsim.numerics.mesh import BASE_POLYHEDRA, REST_SHAPES

    assert set(_choices(Shape, "kind")) == set(REST_SHAPES)
    assert set(_choices(Mesh, "base")) == set(BASE_POLYHEDRA)


def test_traction_and_solver_methods_are_the_registries():
    from capsim.numerics import membrane
    from capsim.solve import solver

    traction = getattr(membrane, "TRACTION_METHODS", None) or solver.TRACTION_METHODS
    assert set(_choices(Membrane, "traction")) == set(traction)
    assert set(_choices(Solver, "method")) == set(solver.SOLVER_METHODS)


def test_regular_orders_are_the_quadrature_rules():
    from capsim.numerics.quadrature import REGULAR_ORDERS

    assert set(_choices(Quadrature, "regular_order")) == set(REGULAR_ORDERS)


def test_time_schemes_are_the_registry():
    if "scheme" not in Time.model_fields:
        pytest.skip("the case has no time.scheme field yet")
    from capsim.solve.timestepping import SCHEMES

    assert set(_choices(Time, "scheme")) == set(SCHEMES)
    # a summary's time_scheme flag has a code for every scheme
    from capsim.quantities import FLAGS

    assert FLAGS["time_scheme"] == tuple(SCHEMES)


def test_law_parameters_and_defaults_are_defined_once():
    """Every law parameter is a Membrane field whose default is the law functions' default."""
    from capsim.numerics.membrane import LAWS

    with_params = {name: law for name, law in LAWS.items() if law.parameters}
    assert set(config.LAW_PARAMETER_DEFAULTS) == set(with_params)
    for name, law in with_params.items():
        assert set(config.LAW_PARAMETER_DEFAULTS[name]) == set(law.parameters)
        for func in (law.energy, law.derivatives):
            signature = inspect.signature(func).parameters
            for param, default in config.LAW_PARAMETER_DEFAULTS[name].items():
                assert signature[param].default == default, (name, func.__name__, param)
        for param, default in config.LAW_PARAMETER_DEFAULTS[name].items():
            assert Membrane.model_fields[param].default == default


def test_cli_choices_are_the_registries():
    from capsim.face import plot
    from capsim.campaigns.campaign import MAX_RUNS

    assert tuple(cli._PLOT_KINDS) == tuple(plot.KINDS)
    sweep_max_runs = inspect.signature(cli.sweep).parameters["max_runs"].default
    assert sweep_max_runs.default == MAX_RUNS


def test_every_case_section_is_a_schema_model():
    # _check_dotted and the error messages walk Case.model_fields: every section is a model
    sections = {name for name, f in Case.model_fields.items() if isinstance(f.annotation, type)
                and issubclass(f.annotation, config.BaseModel)}
    assert sections == {"shape", "membrane", "flow", "mesh", "quadrature", "time", "solver", "guards", "output"}


def _click_choices(command: str, option: str) -> tuple:
    """The choices the CLI itself accepts for `option` of `command` (what --help lists)."""
    import typer

    group = typer.main.get_command(cli.app)
    param = next(p for p in group.commands[command].params if p.name == option)
    if hasattr(param, "type_descriptor"):  # typer >= 0.2x: the annotation it parses into
        return tuple(m.value for m in param.type_descriptor.annotation)
    return tuple(param.type.choices)


def test_cli_choice_enums_are_the_registries():
    """--kind, --format, --reference (and the figure suffixes) are enums whose values are the registries'."""
    from capsim.face import export, plot
    from capsim.campaigns import study

    assert tuple(m.value for m in cli.PlotKind) == tuple(plot.KINDS)
    assert tuple(m.value for m in cli.ExportFormat) == tuple(export.FORMATS)
    assert tuple(m.value for m in cli.StudyReference) == tuple(study.REFERENCES)
    assert tuple(cli._FIGURE_FORMATS) == tuple(plot.FIGURE_FORMATS) == tuple(cli._FIGURE_MAGIC)
    assert tuple(cli._EXPORT_FORMATS) == tuple(export.FORMATS)
    assert tuple(cli._STUDY_REFERENCES) == tuple(study.REFERENCES)


def test_cli_parameters_accept_exactly_the_registries():
    from capsim.face import export, plot
    from capsim.campaigns import study

    assert _click_choices("plot", "kind") == tuple(plot.KINDS)
    assert _click_choices("export", "fmt") == tuple(export.FORMATS)
    assert _click_choices("study", "reference") == tuple(study.REFERENCES)


def test_a_scheme_declares_its_options_and_builds_itself():
    """Adding a time scheme is one class in capsim.solve.timestepping (issue 27): its option
    fields become time.<option> in the schema, its settings are what it is built with."""
    from pydantic import Field

    from capsim import config
    from capsim.solve import timestepping

    @timestepping.register_scheme
    class Demo(timestepping.EmbeddedRungeKutta):
        name = "demo_scheme"
        description = "a test scheme"
        option_fields = {"demo_knob": (int, Field(3, ge=1, strict=True, description="demo_scheme: a knob"))}

        @classmethod
        def settings(cls, case, model):
            assert case.time.demo_knob == 7
            return super().settings(case, model)

    try:
        time_model = config._time_model()
        assert "demo_knob" in time_model.model_fields and "demo_scheme" in str(time_model.model_fields["scheme"])
        t = time_model(scheme="demo_scheme", demo_knob=7)
        assert t.demo_knob == 7
        with pytest.raises(Exception, match="applies only to scheme: demo_scheme"):
            time_model(scheme="rkf23", demo_knob=7)
    finally:
        del timestepping.SCHEMES["demo_scheme"]
    assert config.SCHEME_OPTIONS == {name: tuple(cls.option_fields) for name, cls in timestepping.SCHEMES.items()
                                     if cls.option_fields}


def test_the_runner_names_no_scheme():
    from pathlib import Path

    import capsim.runs.runner
    from capsim.solve.timestepping import SCHEMES

    text = Path(capsim.runs.runner.__file__).read_text()
    assert not [name for name in SCHEMES if f'"{name}"' in text or f"'{name}'" in text]

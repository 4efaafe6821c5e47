"""capsim fit: a known G recovered from capsim's own D_xy plus noise, the refusals, a refit's reuse."""

import json
import math

import numpy as np
import pytest

import capsim
from capsim.campaigns.fit import FitError, fit_from_dict, load_fit, run_fit  # noqa: F401
from capsim.config import ConfigError

G_TRUE = 0.01
LAMBDAS = (0.5, 1.0, 2.0)
REL_SD = 0.01  # the synthetic noise: 1 % of D_xy
BASE = {"shape": {"kind": "sphere"}, "mesh": {"level": 1}, "time": {"t_end": 2.0}}


def _truth(tmp_path):
    """D_xy at G_TRUE for each λ, run by capsim at the fit's own level (the model is exact at the truth)."""
    out = []
    for lam in LAMBDAS:
        case = {**BASE, "name": "truth", "flow": {"G": G_TRUE, "viscosity_ratio": lam},
                "output": {"path": str(tmp_path / f"truth-{lam}.h5")}}
        result = capsim.run(case, overwrite=True)
        assert result.status == "completed"
        out.append(float(result["D_xy"]))
    return np.array(out)


def _spec(tmp_path, rows, **changes):
    csv = tmp_path / "data.csv"
    header = "flow.viscosity_ratio,D_xy,D_xy_sd"
    csv.write_text("# synthetic: capsim level 1 at G = 0.01 plus N(0, sd)\n" + header + "\n"
                   + "".join(f"{lam},{float(d)!r},{float(sd)!r}\n" for lam, d, sd in rows))
    spec = {"name": "fit-test", "base": BASE,
            "parameters": {"flow.G": {"bounds": [0.002, 0.05], "initial": 0.02, "log": True}},
            "data": str(csv), "output": {"dir": str(tmp_path / "out"), "figure": False}}
    spec.update(changes)
    return spec


@pytest.fixture(scope="module")
def fitted(tmp_path_factory):
    tmp_path = tmp_path_factory.mktemp("fit")
    D = _truth(tmp_path)
    rng = np.random.default_rng(56)
    sd = REL_SD * D
    noisy = D + rng.normal(0.0, sd)
    rows = list(zip(LAMBDAS, noisy, sd))
    lines = []
    fit = fit_from_dict(_spec(tmp_path, rows), source="fit-test.yaml")
    result = run_fit(fit, workers=1, log=lines.append)
    return tmp_path, D, noisy, sd, fit, result, lines


def test_recovers_G_within_its_interval_and_the_first_order_inverse(fitted):
    tmp_path, D, noisy, sd, fit, result, lines = fitted
    G = result.estimates["flow.G"]
    lo, hi = result.intervals["flow.G"]
    print(f"G {G:.6g} [{lo:.6g}, {hi:.6g}], inverse {float(np.mean(4 * noisy / 25)):.6g}, std error "
          f"{result.std_errors['flow.G']:.3g}, {result.n_evaluations} evaluations, {result.n_runs} runs")
    assert result.success and result.n_points == 3 and result.dof == 2
    assert lo < G_TRUE < hi  # the 95 % interval covers the truth (seed 56)
    assert hi / lo < 1.05  # 1 % noise on three points: an interval of a few per cent, not a shrug
    # the interval is the noise propagated: D ≈ c_i G near the truth, so σ_G ≈ 1 / sqrt(Σ (D_i/G)² / sd_i²)
    propagated = 1.0 / math.sqrt(np.sum((D / G_TRUE) ** 2 / sd ** 2))
    assert result.std_errors["flow.G"] == pytest.approx(propagated, rel=0.2)
    # First-order theory D = (25/4) G inverted point by point: level 1 gives D/(25G/4) = 0.98-1.0 at
    # G = 0.01 for λ = 0.5-2 (measured), so the inverse agrees with the fit within 3 %.
    inverse = float(np.mean(4 * noisy / 25))
    assert G == pytest.approx(inverse, rel=0.03)
    # residuals per point, normalised by σ = sqrt(sd² + run error²) (these runs have no error estimate)
    assert [p["row"] for p in result.residuals] == [1, 2, 3]
    for p, d, s in zip(result.residuals, noisy, sd):
        assert p["residual"] == pytest.approx((p["model"] - d) / s, rel=1e-9)
        assert p["run_error"] is None
    assert result.chi2 == pytest.approx(sum(p["residual"] ** 2 for p in result.residuals), rel=1e-9)
    # the cost: said before it starts, and counted
    assert lines[0].startswith("fit fit-test: 3 data points, 1 parameter; 3 runs per evaluation")
    assert result.runs_per_evaluation == 3 and result.n_runs == 3 * result.n_evaluations
    assert result.n_runs_executed == result.n_runs
    assert f"{result.n_runs} runs (3 per evaluation" in lines[-1]
    written = json.loads((tmp_path / "out" / "fit.json").read_text())
    assert written["estimates"]["flow.G"] == G and written["n_runs"] == result.n_runs
    assert (tmp_path / "out" / "summary.nc").exists()


def test_a_refit_runs_nothing(fitted):
    tmp_path, D, noisy, sd, fit, result, lines = fitted
    again = run_fit(load_fit_dict(fit), workers=1, log=None)
    assert again.n_runs_executed == 0
    assert again.n_runs == result.n_runs
    assert again.estimates == result.estimates


def test_the_two_optimisers_agree_and_dfols_costs_fewer_runs(fitted):
    """The same data fitted with scipy's trf (forward differences): the same estimate within a tenth of
    its standard error and the same standard error within 5 %; DFO-LS made fewer evaluations (8 against
    11 measured: it keeps every evaluation in its model instead of differencing at each iterate)."""
    tmp_path, D, noisy, sd, fit, result, lines = fitted
    spec = fit.spec.model_dump(mode="json")
    spec["method"]["optimizer"] = "trf"
    spec["output"]["dir"] = str(tmp_path / "out-trf")
    trf = run_fit(fit_from_dict(spec, source="trf.yaml"), workers=1, log=None)
    se = result.std_errors["flow.G"]
    print(f"dfols {result.estimates['flow.G']:.7g} ± {se:.3g} in {result.n_evaluations} evaluations; trf "
          f"{trf.estimates['flow.G']:.7g} ± {trf.std_errors['flow.G']:.3g} in {trf.n_evaluations}")
    assert abs(trf.estimates["flow.G"] - result.estimates["flow.G"]) < 0.1 * se
    assert trf.std_errors["flow.G"] == pytest.approx(se, rel=0.05)
    assert result.n_evaluations < trf.n_evaluations


def load_fit_dict(fit):
    return fit_from_dict(fit.spec.model_dump(mode="json"), source="again.yaml")


@pytest.mark.parametrize("change, message", [
    ({"parameters": {"flow.shear_rat": {"bounds": [0.01, 0.1], "initial": 0.02}}},
     "fit.yaml: parameters: 'flow.shear_rat' is not a case field (flow has: "),
    ({"parameters": {"flow.G": {"bounds": [0.01, 0.1], "initial": 0.5}}},
     "initial = 0.5: must be within bounds [0.01, 0.1]"),
    ({"method": {"radius_start": 0.01, "radius_end": 0.02}}, "radius_end = 0.02: must be below radius_start (0.01)"),
    ({"method": {"optimizer": "lbfgs"}}, "method.optimizer"),
    ({"method": {"max_evaluations": 2}}, "method.max_evaluations = 2: dfols needs at least n + 2 = 3"),
    ({"parameters": {"physical.shear_modulus": {"bounds": [1, 10], "initial": 2}}},
     "parameters.physical.shear_modulus.unit: missing"),
    ({"parameters": {"flow.G": {"bounds": [0.002, 0.05], "initial": 0.02},
                     "flow.viscosity_ratio": {"bounds": [0.1, 10], "initial": 1}}},
     "column 'flow.viscosity_ratio' is a parameter of the fit"),
    ({"parameters": {"flow.G": {"bounds": [0.002, 0.05], "initial": 0.02},
                     "membrane.skalak_c": {"bounds": [0.1, 10], "initial": 1}},
      "base": {**BASE, "membrane": {"law": "skalak"}}},
     "data: 1 data point for 2 parameters: at least 2 needed"),
])
def test_refusals_are_one_line(tmp_path, change, message):
    with pytest.raises(ConfigError) as info:
        fit_from_dict(_spec(tmp_path, [(1.0, 0.06, 0.001)], **change), source="fit.yaml")
    assert message in str(info.value)
    assert "\n" not in str(info.value)
    assert not (tmp_path / "out").exists()  # refused before anything is run or written


@pytest.mark.parametrize("header, message", [
    ("flow.viscosity_ratio,Dxy,Dxy_sd", "column 'Dxy' names no run output and no case field"),
    ("flow.viscosity_rat,D_xy,D_xy_sd", "'flow.viscosity_rat' is not a case field"),
    ("flow.viscosity_ratio,D_xy,theta_sd", "column 'theta_sd' names no run output"),
])
def test_data_column_refusals(tmp_path, header, message):
    spec = _spec(tmp_path, [(1.0, 0.06, 0.001)])
    (tmp_path / "data.csv").write_text(header + "\n1.0,0.06,0.001\n")
    with pytest.raises(ConfigError) as info:
        fit_from_dict(spec, source="fit.yaml")
    assert message in str(info.value) and "\n" not in str(info.value)


def test_without_sd_needs_one_point_more(tmp_path):
    spec = _spec(tmp_path, [])
    (tmp_path / "data.csv").write_text("flow.viscosity_ratio,D_xy\n1.0,0.06\n")
    with pytest.raises(ConfigError, match=r"1 data point for 1 parameter: at least 2 needed \(no sd columns"):
        fit_from_dict(spec, source="fit.yaml")


def test_an_output_dir_of_another_fit_is_refused(tmp_path):
    fit = fit_from_dict(_spec(tmp_path, [(1.0, 0.06, 0.001)]), source="fit.yaml")
    (tmp_path / "out" / "runs").mkdir(parents=True)
    (tmp_path / "out" / "runs" / "campaign.yaml").write_text("name: other\n")
    with pytest.raises(ConfigError, match=r"its runs/ holds 'other', not the fit 'fit-test'; use another output.dir"):
        run_fit(fit, log=None)
    assert sorted(p.name for p in (tmp_path / "out" / "runs").iterdir()) == ["campaign.yaml"]  # nothing run


@pytest.mark.parametrize("spec, workers, message", [
    (42, 1, "spec = 42: a fit file or a mapping of its fields is expected"),
    ({}, 0, "workers = 0: must be a whole number >= 1"),
])
def test_api_fit_refusals(spec, workers, message):
    from capsim.api import fit

    with pytest.raises(ConfigError, match=message):
        fit(spec, workers=workers)


def test_the_cli_refuses_a_bad_fit_in_one_line(tmp_path):
    """capsim fit FIT.yaml: a parameter that is not a case field is one line on stderr, exit 2, nothing written."""
    import yaml
    from typer.testing import CliRunner

    from capsim.face.cli import app

    spec = _spec(tmp_path, [(1.0, 0.06, 0.001)], parameters={"flow.Gee": {"bounds": [0.002, 0.05], "initial": 0.02}})
    path = tmp_path / "fit.yaml"
    path.write_text(yaml.safe_dump(spec))
    result = CliRunner().invoke(app, ["fit", str(path)])
    assert result.exit_code == 2, result.output
    lines = [line for line in result.output.splitlines() if line.strip()]
    assert len(lines) == 1 and lines[0].startswith("error: ") and "flow.Gee" in lines[0], result.output
    assert not (tmp_path / "out").exists()


def test_validate_reads_a_fit_file_and_says_its_plan(tmp_path):
    """capsim validate FIT.yaml: the fit's plan (its data checked, its cost in runs), nothing run; a bad fit
    file is one line, exit 2 (before: read as a campaign, 'unknown field parameters')."""
    import yaml
    from typer.testing import CliRunner

    from capsim.face.cli import app

    path = tmp_path / "fit.yaml"
    path.write_text(yaml.safe_dump(_spec(tmp_path, [(1.0, 0.06, 0.001), (2.0, 0.07, 0.001)])))
    result = CliRunner().invoke(app, ["validate", str(path)])
    assert result.exit_code == 0, result.output
    assert result.output.startswith("fit fit-test: 2 data points, 1 parameter; 2 runs per evaluation")
    assert not (tmp_path / "out").exists()
    path.write_text(yaml.safe_dump(_spec(tmp_path, [(1.0, 0.06, 0.001)], parameters={"flow.Gee": {
        "bounds": [0.002, 0.05], "initial": 0.02}})))
    result = CliRunner().invoke(app, ["validate", str(path)])
    assert result.exit_code == 2 and result.output.startswith("error: ") and "flow.Gee" in result.output


# ---------------------------------------------------------------- units on observable columns

_PHYSICAL_BASE = {"shape": {"kind": "sphere"}, "mesh": {"level": 1}, "time": {"t_end": 1.0},
                  "physical": {"viscosity": "1 mPa*s", "radius": "50 um"}}


def _unit_fit(tmp_path, header, rows, base=_PHYSICAL_BASE, name="data.csv"):
    csv = tmp_path / name
    csv.write_text(header + "\n" + "".join(r + "\n" for r in rows))
    return {"name": "fit-units", "base": base,
            "parameters": {"physical.shear_modulus": {"bounds": [1, 50], "initial": 10, "log": True, "unit": "uN/m"}},
            "data": str(csv), "output": {"dir": str(tmp_path / "out"), "figure": False}}


def test_a_column_in_physical_units_is_the_run_output_times_its_scale(tmp_path):
    """ttf_ratio in rad/s is ω = ttf_ratio k/2 (a revolution is 2π rad: pint alone would read 1 Hz as 1 rad/s),
    in Hz f = ttf_ratio k/(4π), in rpm 60 f; θ in degrees 180/π θ; the same runs (one run dir, reused)."""
    from capsim.campaigns.fit import _Evaluator

    rates = ("2 1/s", "4 1/s")
    plain = fit_from_dict(_unit_fit(tmp_path, "physical.shear_rate,ttf_ratio,theta",
                                    [f"{k},0.5,0.3" for k in rates]), source="plain.yaml")
    model, _, ids = _Evaluator(plain, 1, lambda line: None)([10.0])
    ttf, theta = model[0::2], model[1::2]
    for unit, factor in (("rad/s", np.array([1.0, 2.0])), ("Hz", np.array([2.0, 4.0]) / (4 * np.pi)),
                         ("rpm", 60 * np.array([2.0, 4.0]) / (4 * np.pi))):
        fit = fit_from_dict(_unit_fit(tmp_path, f"physical.shear_rate,ttf_ratio [{unit}],theta [deg]",
                                      [f"{k},0.5,0.3" for k in rates], name=f"{unit.replace('/', '_')}.csv"),
                            source="units.yaml")
        evaluator = _Evaluator(fit, 1, lambda line: None)
        converted, _, ids_u = evaluator([10.0])
        assert ids_u == ids and evaluator.runs_executed == 0  # the same runs, reused
        assert converted[0::2] == pytest.approx(ttf * factor, rel=1e-12), unit
        assert converted[1::2] == pytest.approx(np.degrees(theta), rel=1e-12)


@pytest.mark.parametrize("header, base, message", [
    ("physical.shear_rate,D_xy [um]", _PHYSICAL_BASE, "column D_xy [um]: D_xy is a pure number (no physical unit); "
     "remove the unit"),
    ("physical.shear_rate,theta [um]", _PHYSICAL_BASE, "column theta [um]: theta is in rad with --units physical; um "
     "is not convertible to it"),
    ("physical.shear_rate,ttf_ratio [blorps]", _PHYSICAL_BASE, "'blorps' is not a unit pint reads"),
    ("physical.shear_rate,ttf_ratio [Hz,ttf_ratio_sd [rad/s]", _PHYSICAL_BASE, "a unit is written after the name in "
     "brackets"),
    ("physical.shear_rate,ttf_ratio [Hz],ttf_ratio_sd [rad/s]", _PHYSICAL_BASE, "ttf_ratio_sd [rad/s]: an sd column "
     "takes its observable's unit (ttf_ratio [Hz])"),
    ("physical.shear_rate [1/s],ttf_ratio", _PHYSICAL_BASE, "a condition carries its unit in its cells"),
    ("flow.viscosity_ratio,length_along [um]", {"shape": {"kind": "sphere"}, "mesh": {"level": 1}},
     "the case has no physical block, so length_along has no physical value"),
])
def test_column_unit_refusals(tmp_path, header, base, message):
    n = header.count(",") + 1
    cells = ["2 1/s" if h.startswith("physical") else "1.0" for h in header.split(",")][:n]
    spec = _unit_fit(tmp_path, header, [",".join(cells)] * 2, base=base)
    if base is not _PHYSICAL_BASE:
        spec["parameters"] = {"flow.G": {"bounds": [0.002, 0.05], "initial": 0.02, "log": True}}
    with pytest.raises(ConfigError) as info:
        fit_from_dict(spec, source="fit.yaml")
    assert message in str(info.value) and "\n" not in str(info.value)


def test_mesh_sequencing_fits_at_the_coarse_level_first(tmp_path):
    """method.coarse_level 1 under level-2 runs: the level-1 fit's estimate (and three of its standard
    errors as the first radius) starts the level-2 fit, which then needs few evaluations: at most 7
    (6 measured: n + 1 = 2 for its first model, then steps; a level-2 fit from the initial value took
    benchmark), and recovers the level-2 truth within its interval; the summary holds the level-2 runs."""
    base2 = {**BASE, "mesh": {"level": 2}}
    D = []
    for lam in LAMBDAS:
        case = {**base2, "name": "truth2", "flow": {"G": G_TRUE, "viscosity_ratio": lam},
                "output": {"path": str(tmp_path / f"truth2-{lam}.h5")}}
        D.append(float(capsim.run(case, overwrite=True)["D_xy"]))
    D = np.array(D)
    sd = REL_SD * D
    noisy = D + np.random.default_rng(57).normal(0.0, sd)
    spec = _spec(tmp_path, list(zip(LAMBDAS, noisy, sd)), base=base2,
                 method={"coarse_level": 1})
    lines = []
    result = run_fit(fit_from_dict(spec, source="seq.yaml"), workers=1, log=lines.append)
    lo, hi = result.intervals["flow.G"]
    fine_evaluations = (result.n_runs - result.n_runs_coarse) // 3
    print(f"G {result.estimates['flow.G']:.6g} [{lo:.6g}, {hi:.6g}]; {result.n_runs_coarse} runs at level 1, "
          f"{result.n_runs - result.n_runs_coarse} at level 2")
    assert lo < G_TRUE < hi
    assert result.coarse_level == 1 and result.n_runs_coarse >= 9 and 2 <= fine_evaluations <= 7
    assert "at the coarse mesh level 1" in lines[0] and "at the coarse mesh level 1, " in lines[-1]
    with pytest.raises(ConfigError, match="method.coarse_level = 2: must be below the runs' mesh level \\(2\\)"):
        fit_from_dict(_spec(tmp_path, list(zip(LAMBDAS, noisy, sd)), base=base2, method={"coarse_level": 2}),
                      source="seq.yaml")


def test_a_fit_that_does_not_converge_says_so(fitted, tmp_path):
    """max_evaluations too small: success False, the closing table says NOT converged and why (its
    exit code is 1)."""
    _, D, noisy, sd, fit, result, lines = fitted
    spec = fit.spec.model_dump(mode="json")
    spec["method"]["max_evaluations"] = 3
    spec["output"]["dir"] = str(tmp_path / "short")
    short = run_fit(fit_from_dict(spec, source="short.yaml"), workers=1, log=None)
    assert not short.success
    assert "NOT converged (" in short.table() and "raise method.max_evaluations" in short.table()
    assert "NOT converged" not in result.table()

"""Red cells against measurement (issue 40): campaigns/tran-son-tay-1984.yaml at the conditions
of Tran-Son-Tay, Sutera & Rao, Biophys. J. 46 (1984) 65-72, and its tank-treading frequency
against their measured one at k = 114.3 1/s (docs/validation.md, "Red cells against
measurement"; benchmarks/tran_son_tay.py runs all five shear rates at level 2)."""

from __future__ import annotations

import math
from pathlib import Path

import pytest

from capsim.campaigns.campaign import expand_campaign, load_campaign

ROOT = Path(__file__).resolve().parents[2]
CAMPAIGN = ROOT / "campaigns" / "tran-son-tay-1984.yaml"
ELASTIC = ROOT / "campaigns" / "tran-son-tay-1984-elastic.yaml"

# The paper's conditions (young cells), as the paper states them:
MU_OUT = 35e-3            # Pa s: "final suspension viscosity with 2% RBC of 35 ± 1 cP"
MU_IN = 10e-3             # Pa s: "the cytoplasmic viscosity was initially assigned the value of 10 cP"
VOLUME = 111e-18          # m^3: young cells, V = 111 um^3 (Nash & Wyard 1980, as they assign it)
G_S = 2.5e-6              # N/m: configs/rbc-viscous.yaml's source (Dimitrakopoulos 2012)
KAPPA = 1.8e-19           # J: Evans 1983
# Table I (shear rate 1/s, f rad/s, SD) and Table III (membrane viscosity, 1e-4 dyn s/cm = 1e-7 N s/m)
RATES = (28.6, 42.9, 57.1, 114.3, 171.4)
F_MEASURED = {114.3: (24.6, 1.07)}
MU_S = (0.96e-7, 0.72e-7, 0.53e-7, 0.53e-7, 0.57e-7)

#: within 10 % of the measured frequency at k = 114.3 1/s (the issue asks 25 % at every rate;
#: the measurement's SD is 4.3 % there and capsim was +2.5 % off: 10 % catches a change of the
#: computed frequency by more than ~7 %)
TOLERANCE = 0.10


def _cases(path):
    return [spec.case() for spec in expand_campaign(load_campaign(path), str(path))]


@pytest.mark.filterwarnings("ignore::UserWarning")
def test_campaign_resolves_to_the_papers_dimensionless_numbers():
    a = (3.0 * VOLUME / (4.0 * math.pi)) ** (1.0 / 3.0)
    cases = _cases(CAMPAIGN)
    elastic = _cases(ELASTIC)
    assert [float(c.physical.shear_rate.split()[0]) for c in cases] == list(RATES)
    for case, k, mu_s, el in zip(cases, RATES, MU_S, elastic):
        radius = float(case.physical.radius.split()[0]) * 1e-6
        assert radius == pytest.approx(a, rel=2e-3)  # 2.98 um for V = 111 um^3
        assert case.flow.shear_rate_G == pytest.approx(MU_OUT * k * radius / (3.0 * G_S), rel=1e-9)
        assert case.flow.viscosity_ratio == pytest.approx(MU_IN / MU_OUT, rel=1e-9)
        assert case.membrane.viscosity.shear == pytest.approx(mu_s / (MU_OUT * radius), rel=1e-9)
        assert case.membrane.bending_modulus == pytest.approx(KAPPA / (3.0 * G_S * radius**2), rel=1e-9)
        assert (case.shape.kind, case.membrane.law, case.membrane.skalak_c) == ("biconcave", "skalak", 10.0)
        # the elastic twin differs only in having no membrane viscosity
        assert el.membrane.viscosity is None or el.membrane.viscosity.shear == 0.0
        assert el.flow.shear_rate_G == case.flow.shear_rate_G
        assert el.flow.viscosity_ratio == case.flow.viscosity_ratio
    # the numbers the docs quote: G 0.398 ... 2.38, Bq_s 0.920 ... 0.508
    assert cases[0].flow.shear_rate_G == pytest.approx(0.398, abs=1e-3)
    assert cases[-1].flow.shear_rate_G == pytest.approx(2.38, abs=1e-2)
    assert cases[0].membrane.viscosity.shear == pytest.approx(0.920, abs=1e-3)


@pytest.mark.filterwarnings("ignore::UserWarning")
def test_tank_treading_frequency_against_measurement_at_114_3_per_s(tmp_path):
    """The campaign's run at k = 114.3 1/s (their membrane viscosity 0.53e-7 N s/m), level 2, to
    its t_end kt = 70: more than one whole revolution of the membrane in the second half, which
    the summary's ttf_ratio counts (about 30 s on one core). Measured: f = 24.6 ± 1.07 rad/s;
    capsim gave 25.2 rad/s (+2.5 %) when this test was written (docs/validation.md)."""
    import yaml

    from capsim.config import case_from_dict
    from capsim.runs.runner import run_case

    data = yaml.safe_load(CAMPAIGN.read_text())
    case = data["base"]
    i = RATES.index(114.3)
    for key, values in data["zip"].items():
        case["physical"][key.split(".")[1]] = values[i]
    assert case["physical"]["shear_rate"] == "114.3 1/s"
    assert case["mesh"]["level"] == 2
    case["name"] = "tts"
    case["output"] = {"path": str(tmp_path / "tts.h5"), "snapshot_every": case["time"]["t_end"]}
    result = run_case(case_from_dict(case))
    assert result.status == "completed"
    s = result.summary
    # a tank-treading membrane on a shape that does not turn (it swings about a mean)
    assert abs(s["body_rotation_ratio"]) < 0.05
    assert s["ttf_ratio_kind"] == 0.0
    f = s["ttf_ratio"] * 114.3 / 2.0  # ttf_ratio = omega / (k/2), omega in rad per 1/k
    f_measured, sd = F_MEASURED[114.3]
    assert abs(f / f_measured - 1.0) < TOLERANCE, (f, f_measured, sd)

"""Every case and campaign shipped in configs/ and campaigns/ validates."""

from pathlib import Path

import pytest

from capsim.campaigns.campaign import expand_campaign, load_campaign
from capsim.config import load_case

ROOT = Path(__file__).resolve().parents[1]


@pytest.mark.parametrize("path", sorted((ROOT / "configs").glob("*.yaml")), ids=lambda p: p.name)
def test_config_validates(path):
    case = load_case(path)
    assert case.name


@pytest.mark.parametrize("path", sorted((ROOT / "campaigns").glob("*.yaml")), ids=lambda p: p.name)
def test_campaign_expands(path):
    specs = expand_campaign(load_campaign(path))
    assert len(specs) >= 3
    assert len({s.run_id for s in specs}) == len(specs)


@pytest.mark.parametrize("path", sorted((ROOT / "campaigns").glob("*.yaml")), ids=lambda p: p.name)
def test_campaign_within_the_input_limits(path):
    from capsim.campaigns.campaign import MAX_RUNS, count_runs
    from capsim.config import NAME_MAX

    campaign = load_campaign(path)
    specs = expand_campaign(campaign)
    assert count_runs(campaign) == len(specs) <= MAX_RUNS
    assert max(len(s.run_id) for s in specs) <= NAME_MAX


@pytest.mark.parametrize("path", sorted((ROOT / "fits").glob("*.yaml")), ids=lambda p: p.name)
def test_fit_loads_with_its_data(path):
    """Every fit shipped in fits/ validates with its CSV (capsim fit refuses a bad one before any run)."""
    from capsim.campaigns.fit import load_fit

    fit = load_fit(path)
    assert fit.data.n_points >= len(fit.spec.parameters)

"""What an input file is, a case, a campaign or a fit, and what `capsim validate` says of it.

The kind is read from the file's top level: a fit has ``parameters`` and ``data``
(capsim.campaigns.fit), a campaign ``base``, ``sweep`` or ``zip`` (capsim.campaigns.campaign),
anything else is a case (capsim.config)."""

from __future__ import annotations

import os
from typing import Any

from capsim.config import load_case_with, read_yaml


def input_kind(data: Any) -> str:
    """'fit', 'campaign' or 'case' for a file's top-level mapping."""
    keys = set(data) if isinstance(data, dict) else set()
    if {"parameters", "data"} <= keys:
        return "fit"
    return "campaign" if keys & {"base", "sweep", "zip"} else "case"


def describe(path: str | os.PathLike, sets: list[str] | None = None, *, max_runs: int = 10_000) -> str:
    """`capsim validate`'s text: a case resolved with every default filled in, a campaign's runs (what a
    sweep would do with each), or a fit's plan (its data and the cases of its first evaluation checked,
    its cost in runs). A mistake raises a one-line ConfigError."""
    source = os.fspath(path)
    data = read_yaml(source)
    kind = input_kind(data)
    if kind == "fit":
        from capsim.campaigns.fit import load_fit, plan_line

        return plan_line(load_fit(source)) + "\n"
    if kind == "campaign":
        from capsim.campaigns.campaign import load_campaign_with, plan_lines

        campaign = load_campaign_with(source, sets, max_runs=max_runs, data=data)
        return "\n".join(plan_lines(campaign, source=source)) + "\n"
    return load_case_with(source, sets).to_yaml(user_names=True)  # flow.G, as a case writes it

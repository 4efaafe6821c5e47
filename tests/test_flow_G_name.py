"""flow.G is the flow's rate's name (issue 52, item 4): a case may say G or its long name
shear_rate_G (read as before); what capsim says back to a user names G: a refusal of a G the case
gave, the validated-range warning, `capsim validate`'s resolved case (read back equal). The run
file's stored case and the summaries keep shear_rate_G (file formats unchanged)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest
import yaml

from capsim.config import ConfigError, case_from_dict, load_case

ROOT = Path(__file__).resolve().parents[1]


def _validate(tmp_path, text: str) -> subprocess.CompletedProcess:
    path = tmp_path / "case.yaml"
    path.write_text(text)
    return subprocess.run([sys.executable, "-m", "capsim.face.cli", "validate", str(path)], cwd=tmp_path,
                          capture_output=True, text=True, timeout=120)


def test_a_bad_G_is_refused_by_the_name_the_case_gave():
    with pytest.raises(ConfigError, match=r"^<dict>: flow\.G = -1: must be > 0$"):
        case_from_dict({"name": "x", "flow": {"G": -1}})
    with pytest.raises(ConfigError, match=r"flow\.shear_rate_G = -1: must be > 0"):
        case_from_dict({"name": "x", "flow": {"shear_rate_G": -1}})  # the long name, as before
    with pytest.raises(ConfigError, match=r"flow\.G = 0\.2: and shear_rate_G = 0\.3 name one value"):
        case_from_dict({"name": "x", "flow": {"G": 0.2, "shear_rate_G": 0.3}})
    assert case_from_dict({"name": "x", "flow": {"G": 0.2, "shear_rate_G": 0.2}}).flow.shear_rate_G == 0.2


def test_validate_prints_G_and_reads_it_back_equal(tmp_path):
    proc = _validate(tmp_path, "name: w\nflow: {shear_rate_G: 0.05, kind: planar_extension}\n")
    assert proc.returncode == 0, proc.stderr
    flow = yaml.safe_load(proc.stdout)["flow"]
    assert flow["G"] == 0.05 and "shear_rate_G" not in flow and list(flow)[0] == "G"
    (tmp_path / "back.yaml").write_text(proc.stdout)
    assert load_case(tmp_path / "back.yaml") == load_case(tmp_path / "case.yaml")
    # the stored case (a run file's config_yaml, a campaign's case_yaml) keeps its format
    assert "shear_rate_G: 0.05" in load_case(tmp_path / "case.yaml").to_yaml()


def test_the_range_warning_names_G(tmp_path):
    proc = _validate(tmp_path, "name: w\nflow: {G: 3}\n")
    assert proc.returncode == 0, proc.stderr
    assert "CaseWarning: flow.G = 3 is outside [0.0005, 1]" in proc.stderr


def test_the_package_and_capsim_help_say_what_capsim_does():
    """pyproject's description and `capsim --help` name the scenes and the machinery capsim has now,
    not 'simple shear' alone (issue 52, item 4)."""
    import tomllib

    from typer.testing import CliRunner

    from capsim.face.cli import app

    description = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["description"]
    helptext = " ".join(CliRunner().invoke(app, ["--help"]).output.replace("│", " ").split())
    for text in (description, helptext):
        for word in ("extension", "Poiseuille", "wall", "several", "accuracy", "campaign"):
            assert word in text, (word, text)

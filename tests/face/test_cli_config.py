import subprocess
import sys

import yaml
from typer.testing import CliRunner

from capsim.face.cli import app
from capsim.config import Case, load_case

runner = CliRunner()


def test_validate_prints_resolved_yaml(tmp_path):
    path = tmp_path / "case.yaml"
    path.write_text("name: demo\nmesh: {level: 2}\n")
    result = runner.invoke(app, ["validate", str(path)])
    assert result.exit_code == 0, result.output
    resolved = yaml.safe_load(result.stdout)
    assert resolved["mesh"]["level"] == 2
    assert resolved["output"]["path"] == "runs/demo.h5"
    assert Case.model_validate(resolved) == load_case(path)


def test_validate_bad_file_exits_2_with_one_line(tmp_path):
    path = tmp_path / "bad.yaml"
    path.write_text("name: x\nflow: {shear_rate_G: -1.0}\n")
    proc = subprocess.run(
        [sys.executable, "-m", "capsim.face.cli", "validate", str(path)], capture_output=True, text=True
    )
    assert proc.returncode == 2
    assert proc.stdout == ""
    assert proc.stderr == f"error: {path}: flow.shear_rate_G = -1.0: must be > 0\n"


def test_run_with_bad_case_or_override_exits_2_before_running(tmp_path):
    missing = tmp_path / "missing.yaml"
    result = runner.invoke(app, ["run", str(missing)])
    assert result.exit_code == 2
    assert result.stderr.strip() == f"error: {missing}: no such file"

    good = tmp_path / "case.yaml"
    good.write_text("name: x\n")
    result = runner.invoke(app, ["run", str(good), "--level", "9"])
    assert result.exit_code == 2
    assert result.stderr.count("\n") == 1 and "mesh.level = 9: must be <= 6" in result.stderr
    assert "Traceback" not in result.output


def test_run_refuses_a_directory_as_output(tmp_path):
    good = tmp_path / "case.yaml"
    good.write_text("name: x\n")
    result = runner.invoke(app, ["run", str(good), "-o", str(tmp_path)])
    assert result.exit_code == 2
    assert "is a directory" in result.stderr and result.stderr.count("\n") == 1


def test_validate_never_blocks_on_a_fifo_or_reads_dev_zero(tmp_path):
    """In a real process (a hang would hit the timeout): one line, exit 2."""
    import os

    fifo = tmp_path / "case.yaml"
    os.mkfifo(fifo)
    zero = tmp_path / "zero.yaml"
    zero.symlink_to("/dev/zero")
    for path in (fifo, zero):
        proc = subprocess.run(
            [sys.executable, "-m", "capsim.face.cli", "validate", str(path)], capture_output=True, text=True, timeout=60
        )
        assert proc.returncode == 2
        assert proc.stdout == ""
        assert proc.stderr == f"error: {path}: not a regular file (a pipe, device or socket); give a YAML file\n"

"""Smoke tests: run the installed ``gtsam-rotid`` command as a user would."""

import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from gtsam_rotid import Dataset, simulate
from gtsam_rotid.simulate import GroundTruth


def gtsam_rotid_command() -> list[str]:
    script = Path(sys.executable).parent / "gtsam-rotid"
    if script.exists():
        return [str(script)]
    found = shutil.which("gtsam-rotid")
    if found:
        return [found]
    pytest.fail("the gtsam-rotid console script is not installed next to this Python")


def run(*args, check=True):
    result = subprocess.run([*gtsam_rotid_command(), *args], capture_output=True, text=True, timeout=600)
    if check:
        assert result.returncode == 0, result.stderr
    return result


def test_help_lists_commands():
    out = run("--help").stdout
    for command in ("simulate", "demo"):
        assert command in out


def test_simulate_writes_a_dataset_that_loads_back_identically(tmp_path):
    out = tmp_path / "d"
    result = run("simulate", "--scene", "reference", "--seed", "4", "--duration", "4", "-o", str(out))
    assert "6 measurements" in result.stdout
    loaded = Dataset.load(out)
    expected, truth = simulate.reference_scene(seed=4, duration=4.0)
    assert loaded == expected
    assert GroundTruth.load(out / "truth.json").to_dict() == truth.to_dict()


def test_simulate_refuses_to_overwrite(tmp_path):
    out = tmp_path / "d"
    run("simulate", "--duration", "2", "-o", str(out))
    before = (out / "dataset.json").read_bytes()
    result = run("simulate", "--duration", "2", "--seed", "1", "-o", str(out), check=False)
    assert result.returncode == 1
    assert "overwrite" in result.stderr
    assert (out / "dataset.json").read_bytes() == before
    run("simulate", "--duration", "2", "--seed", "1", "-o", str(out), "--overwrite")
    assert Dataset.load(out) == simulate.reference_scene(seed=1, duration=2.0)[0]


def test_simulate_single_crossing(tmp_path):
    out = tmp_path / "sc"
    run("simulate", "--scene", "single-crossing", "--duration", "2", "-o", str(out))
    dataset = Dataset.load(out)
    assert dataset.metadata["scene"] == "single-crossing"


def test_bad_arguments_give_clear_errors(tmp_path):
    result = run("simulate", "--scene", "nowhere", "-o", str(tmp_path / "x"), check=False)
    assert result.returncode == 2 and "invalid choice" in result.stderr
    result = run("simulate", "--noise-var", "-1", "-o", str(tmp_path / "x"), check=False)
    assert result.returncode == 1 and "noise_var" in result.stderr
    assert not (tmp_path / "x").exists()


def test_demo_runs():
    result = run("demo", "--duration", "3")
    assert "reference scene" in result.stdout
    assert "true arm_T_camera" in result.stdout

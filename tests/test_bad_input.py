"""The bad-input corpus of the command line: each case gets exit code 1 and one line that names the culprit (no
traceback), and no file of the user's is deleted, overwritten or left half-written."""

from __future__ import annotations

import json

import numpy as np
import pytest

from gtsam_rotid.cli import main


@pytest.fixture(scope="module")
def simulated(tmp_path_factory):
    root = tmp_path_factory.mktemp("corpus")
    assert main(["simulate", "--scene", "reference", "--duration", "6", "-o", str(root / "ds")]) == 0
    assert main(["calibrate", str(root / "ds"), "-o", str(root / "result.json")]) == 0
    return root


def fails_naming(capsys, argv, *words):
    assert main(argv) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "Traceback" not in err, err  # one line
    for word in words:
        assert word in err, err
    return err


@pytest.mark.parametrize("argv, words", [
    (["--duration", "-5"], ["duration must be a finite number > 0", "-5"]),
    (["--noise-var", "nan"], ["noise_var must be a finite number >= 0", "nan"]),
])
def test_impossible_scenes_are_refused_by_their_field(tmp_path, capsys, argv, words):
    fails_naming(capsys, ["simulate", "--scene", "reference", *argv, "-o", str(tmp_path / "x")], *words)
    assert not (tmp_path / "x").exists()


def test_nothing_of_the_users_is_deleted_or_overwritten(simulated, tmp_path, capsys):
    ds = simulated / "ds"
    notes = ds / "notes.txt"
    notes.write_text("mine")
    fails_naming(capsys, ["simulate", "--scene", "reference", "--duration", "6", "-o", str(ds), "--overwrite"],
                 "notes.txt", "not part of the dataset")
    assert notes.read_text() == "mine"
    notes.unlink()
    before = (ds / "dataset.json").read_bytes()
    fails_naming(capsys, ["calibrate", str(ds), "-o", str(ds / "dataset.json"), "--overwrite"], "dataset.json")
    assert (ds / "dataset.json").read_bytes() == before  # its own input is never its output
    mine = tmp_path / "out.json.tmp"
    mine.write_text("mine")
    assert main(["calibrate", str(ds), "-o", str(tmp_path / "out.json")]) == 0
    assert main(["export", str(tmp_path / "out.json"), "--to", "yaml", "-o", str(tmp_path / "out.json.yaml")]) == 0
    assert mine.read_text() == "mine"  # a file of the user's beside the output is not a temporary of ours


def test_results_unfit_or_not_rigid_are_not_exported(simulated, tmp_path, capsys):
    data = json.loads((simulated / "result.json").read_text())
    data["covariance"] = np.full((6, 6), np.nan).tolist()
    nan = tmp_path / "nan.json"
    nan.write_text(json.dumps(data))
    fails_naming(capsys, ["export", str(nan), "--to", "ros2"], "NaN", "--force")
    data = json.loads((simulated / "result.json").read_text())
    data["arm_T_camera"][0][0] *= 1.2
    scaled = tmp_path / "scaled.json"
    scaled.write_text(json.dumps(data))
    fails_naming(capsys, ["export", str(scaled), "--to", "matrix"], "scaled.json", "not a rigid transform")

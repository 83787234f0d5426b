"""Smoke tests: run the installed ``gtsam-rotid`` command as a user would."""

import json
import shutil
import subprocess
import sys
from pathlib import Path

import gtsam
import numpy as np
import pytest

from gtsam_rotid import Dataset, cli, simulate
from gtsam_rotid.estimate import CalibrationResult, Method
from gtsam_rotid.simulate import GroundTruth

#: A noise-free scene that simulates in ~2 s and calibrates in a few seconds.
FAST_SCENE = ("--duration", "6", "--noise-var", "0", "--n-measurements", "5")


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
    for command in ("simulate", "calibrate", "demo"):
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




# ---------------------------------------------------------------------------------------------------
# calibrate and demo


@pytest.fixture(scope="module")
def noise_free_dataset(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("cli") / "noise_free"
    run("simulate", *FAST_SCENE, "-o", str(out))
    return out


def error_to_truth(result_path: Path, truth_path: Path) -> tuple[CalibrationResult, float, float]:
    """Rotation (rad) and translation (m) error of a saved result, from the files alone."""
    result = CalibrationResult.load(result_path)
    truth = GroundTruth.load(truth_path).arm_T_camera
    rotation = np.linalg.norm(gtsam.Rot3.Logmap(truth.rotation().between(result.arm_T_camera.rotation())))
    translation = np.linalg.norm(result.arm_T_camera.translation() - truth.translation())
    return result, float(rotation), float(translation)


def assert_prints_error_vs_truth(stdout: str) -> None:
    """The error against the truth per axis, in units of the reported 1-sigma when the covariance is usable (and
    then its chi-square), else with the words that no comparison is made."""
    assert "error vs truth" in stdout
    usable = "COVARIANCE UNUSABLE" not in stdout
    for label in ("rotation, camera axes (deg)", "translation, camera frame (mm)", "position, arm frame (mm)"):
        line = next((line for line in stdout.splitlines() if label in line), None)
        assert line is not None, f"no {label!r} line in:\n{stdout}"
        assert ("sigma" in line) == usable, line
    if usable:
        assert "Mahalanobis chi2" in stdout
    else:
        assert "covariance unusable: no comparison with a 1-sigma" in stdout


def test_cli_methods_are_the_estimators():
    assert set(cli.METHODS) == {m.value for m in Method}


def test_cli_intrinsics_are_the_options():
    from gtsam_rotid.calibration import options

    assert cli.INTRINSICS == options.INTRINSICS
    assert cli.DEFAULT_INTRINSICS_SIGMA == options.DEFAULT_INTRINSICS_SIGMA
    assert options.CalibrationOptions().intrinsics_sigma == options.DEFAULT_INTRINSICS_SIGMA


@pytest.mark.parametrize("method", ["joint", "paper"])
def test_calibrate_noise_free_recovers_truth(noise_free_dataset, method, tmp_path):
    out = tmp_path / "result.json"
    result = run("calibrate", str(noise_free_dataset), "--method", method, "-o", str(out))
    assert f"calibrating ({method})" in result.stdout
    assert f"arm_T_camera ({method}, converged" in result.stdout
    assert_prints_error_vs_truth(result.stdout)
    assert f"wrote {out}" in result.stdout
    loaded, rotation, translation = error_to_truth(out, noise_free_dataset / "truth.json")
    assert loaded.method == method
    assert loaded.converged
    assert rotation < 1e-6
    assert translation < 1e-6


def test_calibrate_refines_intrinsics_and_exports_the_camera(noise_free_dataset, tmp_path):
    """Noise-free pixels: the refined fx and cx are the simulator's camera; the camera export reads back."""
    from gtsam_rotid.camerafiles import load_camera
    from gtsam_rotid.dataset import Dataset

    out = tmp_path / "result.json"
    result = run("calibrate", str(noise_free_dataset), "--refine-intrinsics", "fx", "cx", "--intrinsics-sigma",
                 "0.02", "10", "-o", str(out))
    assert "intrinsics refined with the pose (prior 1 sigma 2 % focal, 10 px principal point" in result.stdout
    loaded, rotation, translation = error_to_truth(out, noise_free_dataset / "truth.json")
    assert loaded.refined_intrinsics == ("fx", "cx") and rotation < 1e-6 and translation < 1e-6
    camera = Dataset.load(noise_free_dataset).camera
    run("export", str(out), "--to", "camera", "-o", str(tmp_path / "camera.yaml"))
    np.testing.assert_allclose(load_camera(tmp_path / "camera.yaml").K, camera.K, rtol=0, atol=1e-4)
    refused = run("calibrate", str(noise_free_dataset), "--refine-intrinsics", "k1", check=False)
    assert refused.returncode != 0 and "invalid choice: 'k1'" in refused.stderr


def test_calibrate_takes_the_tracks_own_offsets(noise_free_dataset, tmp_path):
    from gtsam_rotid.export import load_result

    out = tmp_path / "result.json"
    result = run("calibrate", str(noise_free_dataset), "--track-offset-px", "0.2", "-o", str(out))
    assert "an image offset of its own, 0.2 px" in result.stdout
    assert load_result(out).track_offset_px == 0.2
    refused = run("calibrate", str(noise_free_dataset), "--track-offset-px", "-1", check=False)
    assert refused.returncode != 0 and "--track-offset-px must be None or a finite number >= 0" in refused.stderr


def test_calibrate_refuses_to_overwrite_and_keeps_the_old_file(noise_free_dataset, tmp_path):
    dataset = tmp_path / "without_truth"
    shutil.copytree(noise_free_dataset, dataset)
    (dataset / "truth.json").unlink()
    out = tmp_path / "result.json"
    out.write_bytes(b'{"an": "older result"}\n')
    before = out.read_bytes()
    result = run("calibrate", str(dataset), "-o", str(out), check=False)
    assert result.returncode == 1
    assert str(out) in result.stderr and "--overwrite" in result.stderr
    assert "Traceback" not in result.stderr
    assert out.read_bytes() == before
    result = run("calibrate", str(dataset), "--method", "weighted", "-o", str(out), "--overwrite")
    assert "error vs truth" not in result.stdout  # no truth.json next to this dataset
    loaded, rotation, translation = error_to_truth(out, noise_free_dataset / "truth.json")
    assert loaded.method == "weighted"
    assert rotation < 1e-6
    assert translation < 1e-6


class _StubResult:
    """Stands in for a calibration (no truth is compared against it); saved by the real CalibrationResult.save."""

    save = CalibrationResult.save

    def to_dict(self) -> dict:
        return {"stub": True}


def test_calibrate_keeps_a_result_file_that_appears_while_it_runs(noise_free_dataset, tmp_path, monkeypatch,
                                                                    capsys):
    """The output is checked before calibrating, but a file written meanwhile must not be replaced either."""
    import gtsam_rotid.calibration as calibration

    dataset = tmp_path / "without_truth"
    shutil.copytree(noise_free_dataset, dataset)
    (dataset / "truth.json").unlink()
    out = tmp_path / "result.json"
    theirs = b'{"written": "by someone else during the calibration"}\n'

    def calibrate_while_someone_writes(dataset, method, options=None):
        out.write_bytes(theirs)
        return _StubResult()

    monkeypatch.setattr(calibration, "calibrate", calibrate_while_someone_writes)
    monkeypatch.setattr(cli, "summary", lambda result: "stub result")
    assert cli.main(["calibrate", str(dataset), "-o", str(out)]) == 1
    assert f"{out} exists; pass --overwrite" in capsys.readouterr().err
    assert out.read_bytes() == theirs
    assert cli.main(["calibrate", str(dataset), "-o", str(out), "--overwrite"]) == 0
    assert json.loads(out.read_text()) == {"stub": True}


def test_calibrate_missing_dataset_is_a_clear_error(tmp_path):
    missing = tmp_path / "no_such_dataset"
    out = tmp_path / "result.json"
    result = run("calibrate", str(missing), "-o", str(out), check=False)
    assert result.returncode == 1
    assert str(missing) in result.stderr
    assert "Traceback" not in result.stderr
    assert not out.exists()
    result = run("calibrate", str(tmp_path), check=False)  # a directory, but not a dataset
    assert result.returncode == 1 and "dataset.json is missing" in result.stderr


def test_calibrate_joint_sigma_widens_the_covariance(noise_free_dataset, tmp_path):
    """Noise-free pixels give a micrometre covariance; joint readings declared 0.1 deg uncertain give millimetres."""
    out = tmp_path / "result.json"
    run("calibrate", str(noise_free_dataset), "--joint-sigma-deg", "0.1", "-o", str(out))
    loaded, _, translation = error_to_truth(out, noise_free_dataset / "truth.json")
    assert translation < 1e-6  # the estimate itself is unchanged: the readings are exact here
    assert np.all(loaded.sigma_mm_arm > 0.1) and np.all(loaded.sigma_mm_arm < 20.0), loaded.sigma_mm_arm
    bad = run("calibrate", str(noise_free_dataset), "--joint-sigma-deg", "-1", check=False)
    assert bad.returncode != 0 and "--joint-sigma-deg must be a finite value >= 0" in bad.stderr


def test_calibrate_errors_name_the_flags_not_the_options_fields(noise_free_dataset):
    for flags, said in ((["--encoder-sigma-deg", "-1"], "--encoder-sigma-deg must be a positive number of degrees"),
                        (["--time-offset-sigma", "-2"], "--time-offset-sigma must be a number of seconds >= 0"),
                        (["--time-offset", "nan"], "--time-offset must be a finite number of seconds"),
                        (["--refine-intrinsics", "--intrinsics-sigma", "0", "1"],
                         "--intrinsics-sigma must be two positive numbers (focal length fraction"),
                        (["--refine-intrinsics", "--intrinsics-sigma", "5", "20"],  # 5 % typed as 5
                         "a fraction of the focal length (0.05 for 5 %)"),
                        (["--intrinsics-sigma", "0.02", "5"], "--intrinsics-sigma applies with --refine-intrinsics"),
                        (["--joint-offset-sigma-deg", "0"], "--joint-offset-sigma-deg must be a positive")):
        bad = run("calibrate", str(noise_free_dataset), *flags, check=False)
        assert bad.returncode == 1 and said in bad.stderr and "CalibrationOptions" not in bad.stderr, bad.stderr


def test_calibrate_joint_offsets_prints_and_saves_them(noise_free_dataset, tmp_path):
    """--joint-offsets with no names: every joint between the first and the spinning one, in the summary and the
    JSON; exact readings give offsets of zero; a joint that cannot have one is named."""
    out = tmp_path / "result.json"
    done = run("calibrate", str(noise_free_dataset), "--joint-offsets", "--joint-offset-sigma-deg", "0.5",
               "-o", str(out))
    assert "joint offsets refined with the pose (prior 1 sigma 0.5 deg" in done.stdout
    loaded, rotation, translation = error_to_truth(out, noise_free_dataset / "truth.json")
    assert list(loaded.joint_offsets) == [f"j2s6s200_joint_{i}" for i in (2, 3, 4, 5)]
    assert np.all(np.abs(list(loaded.joint_offsets.values())) < 1e-6) and translation < 1e-6
    bad = run("calibrate", str(noise_free_dataset), "--joint-offsets", "j2s6s200_joint_6", check=False)
    assert bad.returncode != 0 and "'j2s6s200_joint_6' is the spinning joint" in bad.stderr


def test_calibrate_bad_method_is_a_usage_error(noise_free_dataset):
    result = run("calibrate", str(noise_free_dataset), "--method", "best", check=False)
    assert result.returncode == 2 and "invalid choice" in result.stderr


def test_demo_without_video_calibrates_and_prints_the_true_error(tmp_path):
    out = tmp_path / "demo"
    result = run("demo", "--no-video", *FAST_SCENE, "--out", str(out))
    stdout = result.stdout
    assert "reference scene" in stdout and "true arm_T_camera" in stdout
    assert "simulating..." in stdout and "calibrating (joint)..." in stdout and "calibrated in" in stdout
    assert "1-sigma position, arm frame (mm)" in stdout and "1-sigma rotation (deg)" in stdout
    assert_prints_error_vs_truth(stdout)
    loaded, rotation, translation = error_to_truth(out / "result.json", out / "dataset" / "truth.json")
    assert loaded.method == "joint"
    assert rotation < 1e-6
    assert translation < 1e-6
    before = (out / "result.json").read_bytes()
    again = run("demo", "--no-video", *FAST_SCENE, "--out", str(out), check=False)  # refused before simulating
    assert again.returncode == 1 and "--overwrite" in again.stderr
    assert (out / "result.json").read_bytes() == before


def test_demo_from_video_runs_the_whole_pipeline(tmp_path):
    """The default demo renders, tracks and calibrates (a short scene here; the full one in the README)."""
    out = tmp_path / "video-demo"
    result = run("demo", "--duration", "6", "--n-measurements", "4", "--out", str(out))
    stdout = result.stdout
    assert "rendered, tracked and calibrated" in stdout and "calibrating (joint)..." in stdout
    assert_prints_error_vs_truth(stdout)
    assert (out / "result.json").is_file() and (out / "dataset" / "truth.json").is_file()
    assert sorted(p.name for p in out.glob("overlay_m*.png")) == [f"overlay_m{k}.png" for k in range(4)]
    refused = run("demo", "--noise-var", "1", check=False)  # pixel noise belongs to simulated tracks
    assert refused.returncode == 1 and "--no-video" in refused.stderr
    planted = run("demo", "--outlier-fraction", "0.1", check=False)  # so do planted wrong tracks
    assert planted.returncode == 1 and "--no-video" in planted.stderr and "--outlier-fraction" in planted.stderr


def test_calibrate_syncs_the_readings_a_dataset_carries(tmp_path):
    """A dataset whose spins carry their joint's readings (ramped spins, read 30 ms late) is calibrated synced by
    default: the summary gives the clocks' offset (camera minus encoder: -30 ms), the JSON keeps it within 3 sigma
    of the truth; --no-sync ignores the readings, --time-offset-sigma 0 holds the offset at --time-offset."""
    root = tmp_path / "synced"
    run("simulate", "--seed", "2", "--duration", "6", "--n-measurements", "5", "--spin-ramp", "2", "--encoder-rate",
        "100", "--encoder-sigma-deg", "0.02", "--encoder-time-offset", "0.03", "-o", str(root))
    assert all(m.spin_readings is not None for m in Dataset.load(root))
    out = tmp_path / "result.json"
    done = run("calibrate", str(root), "-o", str(out))
    assert "every spin (synced); the clocks' offset (camera minus encoder)" in done.stdout
    result = CalibrationResult.load(out)
    assert result.synced == (0, 1, 2, 3, 4) and abs(result.time_offset_s + 0.03) < 3 * result.time_offset_sigma_s
    assert "encoders:" not in run("calibrate", str(root), "--no-sync").stdout
    held = run("calibrate", str(root), "--time-offset=-0.03", "--time-offset-sigma", "0").stdout
    assert "(camera minus encoder) taken as -30.0 ms (held)" in held

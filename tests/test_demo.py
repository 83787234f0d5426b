"""Tests of gtsam_rotid.demo: ``run_demo`` prints the result and its true error, writes the dataset, the result and
one overlay per measurement, and refuses existing output before any work.

The short rendered run is the session's ``demo`` fixture (tests/conftest.py), shared with test_pixels.py.
"""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest
from scene_parameters import DEMO_N_MEASUREMENTS as N_MEASUREMENTS

from gtsam_rotid import Dataset, InputError, OutputError
from gtsam_rotid.demo import demo_files, run_demo
from gtsam_rotid.estimate import CalibrationResult


def test_demo_prints_the_result_and_its_true_error(demo):
    _, _, text = demo
    assert "arm_T_camera (joint" in text
    assert "error vs truth" in text and "Mahalanobis chi2" in text
    assert "RMS" in text and "frames" in text


def test_demo_writes_dataset_result_and_one_overlay_per_measurement(demo):
    out, run, _ = demo
    files = demo_files(out, N_MEASUREMENTS)
    loaded = Dataset.load(files["dataset"])
    assert len(loaded) == N_MEASUREMENTS
    assert loaded.n_observations == run.scene.dataset.n_observations
    assert all(t.frames is not None for m in loaded for t in m.tracks)
    assert (files["dataset"] / "truth.json").is_file()
    result = CalibrationResult.load(files["result"])
    assert np.allclose(result.arm_T_camera.matrix(), run.result.arm_T_camera.matrix())
    assert "RMS" in files["tracking"].read_text()
    assert len(files["overlays"]) == N_MEASUREMENTS
    for path in files["overlays"]:
        image = cv2.imread(str(path))
        assert image is not None and image.shape[0] > 400 and image.shape[1] > 400
        assert image.std() > 10  # a picture, not a blank canvas
    assert set(run.paths) >= set(files["overlays"])
    json.loads(files["result"].read_text())


def test_demo_refuses_existing_output_before_any_work(tmp_path):
    (tmp_path / "result.json").write_text("{}")
    with pytest.raises(OutputError, match="result.json exists"):
        run_demo(tmp_path, duration=1.0, n_measurements=3, progress=False, print=lambda *a, **k: None)
    (tmp_path / "file").write_text("")
    with pytest.raises(OutputError, match="not a directory"):
        run_demo(tmp_path / "file", progress=False, print=lambda *a, **k: None)


def test_the_demo_skips_the_arm_poses_the_mesh_renderer_cannot_render_and_names_them():
    """Spins of the joint before the wrist swing the whole hand: on seed 0 pose 1's swing leaves the image, so the
    demo (`demo --spin-joints J5 J6`) skips that pose for a spare one and says why; too few renderable poses are
    refused before any rendering."""
    from gtsam_rotid import simulate
    from gtsam_rotid.demo import _renderable
    from gtsam_rotid.meshrender import MeshRenderConfig

    arm = simulate.reference_scene(0, duration=1.0)[0].arm
    j5, j6 = arm.joint_names[4], arm.joint_names[5]
    simulated, truth = simulate.reference_scene(0, duration=1.0, n_measurements=8, spin_joints=(j5, j6))
    lines: list[str] = []
    kept, kept_truth = _renderable(simulated, truth, MeshRenderConfig(), lines.append, 2, 6)
    assert lines[0].startswith(f"arm pose 1 is skipped: the mesh renderer cannot render its spin of {j5}: only ")
    assert "inside the image over a whole turn" in lines[0]
    poses = kept_truth.config["rendered_poses"]
    assert len(poses) == 6 and poses[0] == 0 and 1 not in poses and len(lines) == 1 + (poses[-1] - 6)
    assert len(kept) == len(kept_truth.measurements) == 12
    assert [m.spin_joint for m in kept] == [j5, j6] * 6
    for m, mt, k in zip(kept, kept_truth.measurements, [k for p in poses for k in (2 * p, 2 * p + 1)], strict=True):
        np.testing.assert_array_equal(m.joint_angles, simulated[k].joint_angles)
        np.testing.assert_array_equal(mt.joint_angles, simulated[k].joint_angles)
    first = Dataset(simulated.arm, simulated.camera, list(simulated)[:6], metadata=simulated.metadata)
    with pytest.raises(InputError, match="can render 2 arm pose"):  # poses 0-2: pose 1 skipped
        _renderable(first, type(truth)(truth.arm_T_camera, truth.measurements[:6], truth.config),
                    MeshRenderConfig(), lines.append, 2)


def test_a_failed_calibration_keeps_the_tracked_dataset(tmp_path, monkeypatch):
    """Minutes of rendering and tracking are not lost when the calibration fails: the dataset (with the truth) and
    the tracking summary are written first, and the output says where they are."""
    import gtsam_rotid.calibration
    from gtsam_rotid.calibration import CalibrationError
    from gtsam_rotid.render import RenderConfig

    def refuse(*args, **kwargs):
        raise CalibrationError("refused for the test")

    monkeypatch.setattr(gtsam_rotid.calibration, "calibrate", refuse)
    lines: list[str] = []
    with pytest.raises(CalibrationError, match="refused for the test"):
        run_demo(tmp_path / "out", duration=1.0, n_measurements=3, progress=False, render_config=RenderConfig(),
                 print=lambda *args, **kwargs: lines.append(" ".join(str(a) for a in args)))
    files = demo_files(tmp_path / "out", 3)
    assert len(Dataset.load(files["dataset"])) == 3 and (files["dataset"] / "truth.json").is_file()
    assert "RMS" in files["tracking"].read_text() and not files["result"].exists()
    assert f"the tracked dataset is kept in {files['dataset']}" in "\n".join(lines)

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

from gtsam_rotid import Dataset, OutputError
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


def test_the_demo_leaves_out_the_spins_the_mesh_renderer_cannot_render_and_names_them():
    """Spins of the joint before the wrist swing the whole hand: on seed 0 one pose's swing leaves the image, so
    the demo (`demo --spin-joints J5 J6`) renders the other eleven spins and says which one it left out and why."""
    from gtsam_rotid import simulate
    from gtsam_rotid.demo import _renderable
    from gtsam_rotid.meshrender import MeshRenderConfig

    arm = simulate.reference_scene(0, duration=1.0)[0].arm
    j5, j6 = arm.joint_names[4], arm.joint_names[5]
    simulated, truth = simulate.reference_scene(0, duration=1.0, spin_joints=(j5, j6))
    lines: list[str] = []
    kept, kept_truth = _renderable(simulated, truth, MeshRenderConfig(), lines.append, 2)
    assert len(lines) == 2 and lines[0].startswith(f"the spin of {j5} at arm pose 1 is left out: the mesh renderer")
    assert "inside the image over a whole turn" in lines[0] and lines[1].endswith("measurements 0-10 below")
    assert len(kept) == len(kept_truth.measurements) == len(simulated) - 1
    assert [m.spin_joint for m in kept] == [m.spin_joint for k, m in enumerate(simulated) if k != 2]
    for m, mt in zip(kept, kept_truth.measurements, strict=True):
        np.testing.assert_array_equal(m.joint_angles, mt.joint_angles)
    one = Dataset(simulated.arm, simulated.camera, [simulated[0]], metadata=simulated.metadata)
    same = _renderable(one, type(truth)(truth.arm_T_camera, [truth.measurements[0]], truth.config),
                       MeshRenderConfig(), lines.append)
    assert len(same[0]) == 1 and len(lines) == 2  # every spin renderable: nothing said, nothing left out

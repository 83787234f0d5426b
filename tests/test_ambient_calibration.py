"""A short textured scene, calibrated from pixels: the robot's own meshes with printed text on the hand and no dots,
5 s spins, rendered, tracked by the corner tracker and calibrated. Its covariance must hold the error it makes.

One scene (about a minute on one core), and one tracked 20 s scene from the benchmark's data; the benchmark
``benchmarks/ambient.py`` measures many.
"""

import json
from pathlib import Path

import gtsam
import numpy as np

from gtsam_rotid import Dataset, simulate
from gtsam_rotid.calibration import stage2
from gtsam_rotid.estimate import CalibrationOptions, calibrate
from gtsam_rotid.meshrender import MeshRenderConfig
from gtsam_rotid.pixels import dataset_from_video
from gtsam_rotid.tracking import TRACK_OFFSET_PX, TrackerParams, tracker_metadata
from gtsam_rotid.words import summary

CHI2_999_6DOF = 22.458


def test_short_textured_scene_calibrates_within_its_covariance():
    dataset, truth = simulate.reference_scene(seed=0, duration=5.0)
    scene = dataset_from_video(dataset, truth, MeshRenderConfig(covering="text", seed=0),
                               TrackerParams(features="corners"), progress=False)
    kept = [len(m.tracks) for m in scene.dataset]
    # measured: 35, 25, 51, 3, 35, 12 corner tracks (40, 25, 61, 6, 54, 14 on another machine: OpenCV builds differ)
    assert sum(k >= 10 for k in kept) >= 5, kept
    result = calibrate(scene.dataset)
    error = result.error_to(truth.arm_T_camera)
    chi2 = float(error @ np.linalg.solve(result.covariance, error))
    # measured: 0.5 mm and 0.094 deg off (worst axis), 1 sigma 4.6 mm and 0.49 deg, chi2 of the error 0.85 (the
    # 3- and 12-track poses left out: the four others determine the pose without them)
    assert result.covariance_usable, summary(result)
    assert chi2 < CHI2_999_6DOF, (chi2, summary(result))
    assert np.max(np.abs(error[3:])) < 0.005  # and a calibration: mm, not cm


DATA = Path(__file__).parent / "data" / "jaco2_text_seed0"


def test_a_textured_scene_whose_axes_share_a_bias_holds_its_covariance(monkeypatch):
    """The tracked Jaco2 text scene of the ambient benchmark (seed 0, 20 s spins, the default tracker; the tracks
    and the true pose are in ``tests/data``). The tracks' smooth drift moves its poses' image axes 0.2-0.3 px
    (3-4x their 1 sigma: no statistic inside a measurement sees it); scaled by a common factor the covariance
    left the error at chi-square 29 and called it usable. With the axes' common floor it holds the error. The
    axes pass their test (P = 0.26 > 0.2) but lie above its median, and the scale and floor take a share of their
    reading (AxisConsistency): when they switched on only below the level, no floor was applied here and the error
    was at chi-square 40 under the covariance. The tracks' shapes ask for another camera (chi-square 25 for 3 dof;
    the camera file is exact): judged at scale 1, since the axes pass, they flag it (the partial scale, which would
    excuse them here, also excused two wrong cameras of the intrinsics-check benchmark). With its tracker named
    (the dataset was saved before datasets named it), the tracker's own offsets per track count such shared errors
    and the exact camera is not called wrong."""
    dataset = Dataset.load(DATA / "dataset")
    truth = gtsam.Pose3(np.array(json.loads((DATA / "truth.json").read_text(encoding="utf-8"))["arm_T_camera"]))

    def chi2(result):
        error = result.error_to(truth)
        return float(error @ np.linalg.solve(result.covariance, error))

    floored = calibrate(dataset)
    test = floored.axis_consistency
    assert test.consistent and test.p_value > 0.2 and test.scale > 1.0 and test.floor_px > 0.0
    # measured: scale 1.69, floor 0.042 px, the error 0.63 mm at chi2 10.4 (1 sigma 0.88 mm); flagged by the
    # shapes' check alone, if at all
    assert chi2(floored) < CHI2_999_6DOF and set(floored.untrusted) <= {"intrinsics_shapes"}, summary(floored)
    assert f"a floor of {test.floor_px:.2g} px" in summary(floored)
    named = Dataset.load(DATA / "dataset")
    assert "tracker" not in named.metadata
    named.metadata["tracker"] = tracker_metadata(TrackerParams())
    with_offsets = calibrate(named)
    # measured: the shapes' chi2 12.7 for 3 dof (P 0.005, 25.2 without the offsets), not flagged; the error at
    # chi2 13.5, usable
    assert not with_offsets.intrinsics_shapes["flagged"], summary(with_offsets)
    assert with_offsets.covariance_usable and chi2(with_offsets) < CHI2_999_6DOF, summary(with_offsets)
    # the mechanism: with the free phase the same fit with the factor alone is a confident wrong number (chi2 33;
    # the rigid spin's factor alone: chi2 17.5)
    monkeypatch.setattr(stage2, "_axis_floor", lambda *args, **kwargs: (0.0, None))
    factor_only = calibrate(dataset, options=CalibrationOptions(spin_model="free"))
    assert factor_only.covariance_usable and chi2(factor_only) > CHI2_999_6DOF


UR5 = Path(__file__).parent / "data" / "ur5_photo_seed0"


def test_a_precise_pose_that_no_other_checks_is_held_by_the_trackers_track_offsets():
    """The tracked UR5 photo scene of the ambient benchmark (seed 0, 20 s spins, the default tracker). Its sixth
    pose (21 tracks, an arc of 272 deg) has an image axis 0.33 px off the truth, ten times its 1 sigma, and alone
    determines two directions of the pose (leverage 1: the other poses' axes are 30x less precise there), so the
    axes' test cannot see it. Without a floor the error is far outside the covariance; only the camera check
    flags it (the biased axis reads as a camera change: cx and cy some 16-27 px off, at P 1e-6; the camera file is
    exact), where it had been called usable; with the default tracker's track offsets, which the tracker writes
    into its datasets, the covariance holds the error (the pose's axis rests on a few long arcs, through whose
    leverage their own offsets move it)."""
    dataset = Dataset.load(UR5 / "dataset")
    truth = gtsam.Pose3(np.array(json.loads((UR5 / "truth.json").read_text(encoding="utf-8"))["arm_T_camera"]))

    def chi2(result):
        error = result.error_to(truth)
        return float(error @ np.linalg.solve(result.covariance, error))

    assert "tracker" not in dataset.metadata  # saved before datasets named their tracker
    bare = calibrate(dataset)
    assert bare.axis_floor_px == 0.0 and bare.axis_consistency.consistent
    assert chi2(bare) > 10 * CHI2_999_6DOF  # measured: 527
    assert not bare.covariance_usable and set(bare.untrusted) == {"intrinsics_shapes"}
    # the words name both causes: the camera file, and the tracks taken as unbiased (with the offsets to try)
    corner = TRACK_OFFSET_PX["corners"]
    assert "check the camera file" in summary(bare) and f"--track-offset-px {corner:g}" in summary(bare)

    dataset.metadata["tracker"] = tracker_metadata(TrackerParams())
    result = calibrate(dataset)
    assert result.track_offset_px == TRACK_OFFSET_PX["auto"] > 0.0 and result.axis_floor_px == 0.0
    assert f"an image offset of its own, {TRACK_OFFSET_PX['auto']:g} px" in summary(result)
    assert not result.covariance_usable or chi2(result) < CHI2_999_6DOF, (chi2(result), summary(result))
    assert np.max(np.abs(result.error_to(truth)[3:])) < 0.005


BLUR = Path(__file__).parent / "data" / "jaco2_photo_blur_seed0"


def test_a_thin_poses_wrong_axis_is_not_blamed_on_the_robots_zero_positions():
    """The blurred Jaco2 photo scene of the ambient benchmark (seed 0, 20 s spins, motion blur; tracks and truth in
    ``tests/data``). Offsets of the joints' zero positions explain all six axes, which the camera as given does
    not (P < 1e-3), but so does leaving out one pose, and the offsets are not called the likely cause: the user
    is not sent to the robot's mastering although its kinematics are exact. (With stage 1's jackknife dealing its
    groups over the kept tracks, the pose left out was the thin one, of 18 tracks (``weak_one_out``), and the
    estimate held its error at chi-square 0.37; with its groups dealt over all usable tracks another pose is left
    out and leaving out a fourth instead fits as well: ambiguous, not usable, 3.2 mm off at chi-square 10.)"""
    dataset = Dataset.load(BLUR / "dataset")
    truth = gtsam.Pose3(np.array(json.loads((BLUR / "truth.json").read_text(encoding="utf-8"))["arm_T_camera"]))
    result = calibrate(dataset)
    check = result.axis_consistency.kinematics
    assert check["exact_p"] < 1e-3 and check["one_out_measurement"] is not None and not check["likely"], check
    assert "kinematics" not in result.untrusted and "zero positions" not in summary(result)
    error = result.error_to(truth)
    assert not result.covariance_usable or float(error @ np.linalg.solve(result.covariance, error)) < CHI2_999_6DOF

"""calibration.evidence and the records between stages: a measurement of thin evidence is classified and named by the
caller's index, and the robust stage 2 returns what second opinions changed instead of changing what it was given."""

import re
from dataclasses import replace

import numpy as np
from thin_tracks import _thin

from gtsam_rotid import Dataset, Measurement, simulate
from gtsam_rotid.calibration.evidence import classify, poor_minimum, weak_words
from gtsam_rotid.calibration.initial import _initial
from gtsam_rotid.calibration.options import CalibrationOptions
from gtsam_rotid.calibration.stage2 import _refined_stage1, _robust_weighted


def _stages(dataset, index=None):
    arm, camera, measurements, options = dataset.arm, dataset.camera, list(dataset), CalibrationOptions()
    starts, setup, anchors = _initial(arm, camera, measurements, options, index)
    start, stage1 = _refined_stage1(arm, camera, measurements, starts[0], setup, options, anchors[0])
    return setup, stage1, start, anchors[0], options


def test_a_thin_measurement_is_classified_weak_and_named_by_the_callers_index():
    dataset, _ = simulate.reference_scene(seed=2, duration=20.0, noise_var=0.05)
    thin = _thin(dataset, 2, n_tracks=3, shortest=20, longest=60)
    measurements = [thin[k] if k == 3 else m for k, m in enumerate(dataset)]
    # the caller's measurement 2 was left out before (no usable tracks): internal position 3 is the caller's 4
    index = [0, 1, 3, 4, 5, 6][:len(measurements)]
    setup, stage1, _, _, _ = _stages(Dataset(dataset.arm, dataset.camera, measurements), index)
    evidence = classify(setup, stage1)
    assert list(evidence.weak) == [3]
    assert re.fullmatch(r"[23] tracks, longest arc \d+° \(at most\)", evidence.weak[3])  # stage 1 may reject one
    assert evidence.dropped == frozenset()
    words = weak_words(setup, evidence)
    assert f"measurement {index[3]}: {evidence.weak[3]}" in words
    assert "the tracking, more likely than the joint angles" in words
    refusal = str(poor_minimum(np.zeros(len(stage1)), 13.8, "a test", setup, evidence))
    assert refusal.index("check the joint angles") < refusal.index(f"measurement {index[3]}: {evidence.weak[3]}")


def test_the_robust_stage_2_returns_second_opinions_and_leaves_its_input_alone():
    """A wrong shoulder reading makes measurement 2 disagree: its second opinion (here a stand-in that returns a
    changed copy of its fit once) is in the returned record's fits, not in the list stage 2 was given."""
    dataset, _ = simulate.reference_scene(seed=22, noise_var=1.5, duration=12.0)
    measurements = list(dataset)
    q = np.array(measurements[2].joint_angles, dtype=float)
    q[1] += np.radians(3.0)
    measurements[2] = Measurement(q, measurements[2].tracks)
    setup, stage1, start, anchor, options = _stages(Dataset(dataset.arm, dataset.camera, measurements))
    given = list(stage1)
    asked = []

    def opinion(k, pose, fits):
        asked.append(k)
        return (replace(fits[k], iterations=fits[k].iterations + 1000) if asked.count(k) == 1 else None), np.nan

    fit = _robust_weighted(setup=setup, camera=dataset.camera, stage1=stage1, start=start, options=options,
                           anchor=anchor, second_opinion=opinion)
    assert 2 in asked and 2 not in fit.used
    assert all(a is b for a, b in zip(stage1, given, strict=True))  # the caller's fits are untouched
    assert fit.stage1[2].iterations == stage1[2].iterations + 1000
    assert all(fit.stage1[k] is stage1[k] for k in range(len(stage1)) if k not in asked)
    assert fit.evidence == classify(setup, stage1) and set(fit.chi2) == set(range(len(stage1)))


def test_an_axis_miss_is_measured_in_pixels_and_in_the_least_joint_error_that_explains_it():
    from types import SimpleNamespace

    import gtsam

    from gtsam_rotid.calibration.evidence import axis_misses
    from gtsam_rotid.calibration.setup import _setup
    from gtsam_rotid.graph import axis_test_points
    from gtsam_rotid.initialise import line_through_points
    dataset, truth = simulate.reference_scene(seed=3, duration=12.0, noise_var=0.01)
    arm, camera, measurements = dataset.arm, dataset.camera, list(dataset)
    setup = _setup(arm, camera, measurements, CalibrationOptions())
    pose = truth.arm_T_camera

    def image_axis(joint_angles, spin_joint):  # the FK axis at these joint angles as the true pose projects it
        points = axis_test_points(arm.wrist_axis(np.asarray(joint_angles, dtype=float), spin_joint))
        return line_through_points(camera.project(np.array([pose.transformTo(p) for p in points]), distort=False))

    m = measurements[1]
    q = np.array(m.joint_angles, dtype=float)
    exact = [SimpleNamespace(image_axis=image_axis(q, m.spin_joint)) for _ in measurements]
    miss_px, joint_deg = axis_misses(arm, measurements, setup, exact, camera, pose, [1])[1]
    assert miss_px < 1e-6 and joint_deg < 1e-6
    # the image axis of the arm with its second joint 0.2 degrees on: the FK axis at the readings misses it, and the
    # least joint error that explains the miss is at most those 0.2 degrees, and of their size
    q[1] += np.radians(0.2)
    moved = [SimpleNamespace(image_axis=image_axis(q, m.spin_joint)) for _ in measurements]
    miss_px, joint_deg = axis_misses(arm, measurements, setup, moved, camera, pose, [1])[1]
    assert miss_px > 0.3 and 0.05 < joint_deg <= 0.2 + 1e-3, (miss_px, joint_deg)
    # the camera turned half a turn about its x axis sees the FK axis behind it: no distance
    behind = pose.compose(gtsam.Pose3(gtsam.Rot3.Rx(np.pi), np.zeros(3)))
    assert all(behind.transformTo(p)[2] < 0.0 for p in axis_test_points(setup.axes[1]))
    assert axis_misses(arm, measurements, setup, moved, camera, behind, [1]) == {}

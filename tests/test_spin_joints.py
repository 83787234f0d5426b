"""Spins of other joints than the wrist (``Measurement.spin_joint``): the arm's axis of any joint, the dataset
format's field (version 2; version 1 still loads), the simulator's truth against the arm's own forward kinematics,
and calibrations that use them, checked against ground truth the estimator never sees."""

import json

import numpy as np
import pytest

from gtsam_rotid import Arm, Camera, Dataset, Measurement, cli, simulate
from gtsam_rotid.calibration import CalibrationOptions
from gtsam_rotid.errors import ArmError, InputError, RotIdError, ValidationError
from gtsam_rotid.estimate import calibrate
from gtsam_rotid.simulate import SceneConfig
from gtsam_rotid.words import summary

ARM = Arm.from_robot("kinova")
J5, J6 = ARM.joint_names[4], ARM.joint_names[5]


@pytest.fixture(scope="module")
def noise_free():
    return simulate.simulate(SceneConfig(duration=8.0, n_measurements=3, noise_var=0.0, spin_joints=(J5, J6)),
                             seed=2, arm=ARM)


def test_the_axis_of_another_joint_is_its_frame_and_its_offset_derivatives_are_finite_differences():
    q = ARM.random_joint_angles(np.random.default_rng(1))
    axis = ARM.wrist_axis(q, J5)
    frame = ARM.arm_T_joint(q, J5)
    np.testing.assert_allclose(axis.point, frame.translation(), atol=1e-12)
    np.testing.assert_allclose(axis.direction, frame.rotation().matrix() @ ARM.wrist_axis_local(J5), atol=1e-12)
    assert abs(axis.direction @ ARM.wrist_axis(q).direction) < 1 - 1e-3  # not the wrist's axis
    joints = [1, 2, 3, 4, 5]  # joint 5 is the spinning one and joint 6 comes after it: no derivative
    line, d_point, d_direction = ARM.wrist_axis_offset_derivatives(q, joints, None, J5)
    np.testing.assert_allclose(line.point, axis.point, atol=1e-12)
    step = 1e-6
    for c, j in enumerate(joints):
        plus, minus = q.copy(), q.copy()
        plus[j] += step
        minus[j] -= step
        a, b = ARM.wrist_axis(plus, J5), ARM.wrist_axis(minus, J5)
        np.testing.assert_allclose(d_point[:, c], (a.point - b.point) / (2 * step), atol=1e-7)
        np.testing.assert_allclose(d_direction[:, c], (a.direction - b.direction) / (2 * step), atol=1e-7)
    assert np.all(d_point[:, 3:] == 0) and np.all(d_direction[:, 3:] == 0)
    with pytest.raises(ArmError, match="'joint_7' is not a revolute joint of the model"):
        ARM.wrist_axis(q, "joint_7")
    with pytest.raises(InputError, match=f"spin joint '{J6}' comes after the wrist joint '{J5}'"):
        simulate.simulate(SceneConfig(duration=1.0, spin_joints=(J6,)), arm=Arm.from_robot("kinova", wrist_joint=J5))
    with pytest.raises(InputError, match="is the arm's first joint: its axis is fixed"):
        simulate.simulate(SceneConfig(duration=1.0, spin_joints=(ARM.joint_names[0],)), arm=ARM)
    with pytest.raises(InputError, match="names a joint twice"):
        simulate.simulate(SceneConfig(duration=1.0, spin_joints=(J5, J6, J5)), arm=ARM)


def test_offsets_reach_the_last_spinning_joint():
    assert ARM.offset_joints(True, [J5]) == [1, 2, 3]
    assert ARM.offset_joints(True, [J5, J6]) == [1, 2, 3, 4]
    assert ARM.offset_joints([J5], [J5, None]) == [4]  # (None: the wrist)
    with pytest.raises(ArmError, match=f"'{J5}' is the spinning joint"):
        ARM.offset_joints([J5], [J5])
    with pytest.raises(ArmError, match=f"'{J6}' is the last spinning joint"):
        ARM.offset_joints([J6], [J5, J6])


def test_simulated_spins_of_another_joint_move_the_hand_as_the_arm_does(noise_free):
    dataset, truth = noise_free
    assert [m.spin_joint for m in dataset] == [J5, J6] * 3
    for k, (measurement, m_truth) in enumerate(zip(dataset, truth.measurements, strict=True)):
        q = dataset.joint_angles(k)
        joint = ARM.joint_names.index(measurement.spin_joint)
        axis = ARM.wrist_axis(q, measurement.spin_joint)
        np.testing.assert_allclose(m_truth.axis_point, axis.point, atol=1e-12)
        np.testing.assert_allclose(m_truth.axis_direction, axis.direction, atol=1e-12)
        camera_T_arm = truth.arm_T_camera.inverse()
        for j, track in enumerate(measurement.tracks):
            # the feature is fixed on the hand: its wrist-frame point at the first frame, carried by the arm's
            # forward kinematics with the spinning joint turned by each frame's spin angle
            points = m_truth.feature_points(j, track.frames)
            local = ARM.arm_T_wrist(q).transformTo(m_truth.feature_points(j, [0])[0])
            for i in (0, len(track) // 2, len(track) - 1):
                turned = q.copy()
                turned[joint] += m_truth.spin_angles[track.frames[i]]
                np.testing.assert_allclose(ARM.arm_T_wrist(turned).transformFrom(local), points[i], atol=1e-12)
            pixels = dataset.camera.project(np.array([camera_T_arm.transformFrom(p) for p in points]))
            np.testing.assert_allclose(track.pixels, pixels, atol=1e-9)


def test_the_mesh_renderer_spins_the_measurements_joint_as_the_arm_kinematics_turn_it(noise_free):
    from gtsam_rotid import meshrender as mr

    dataset, truth = noise_free
    assert dataset[0].spin_joint == J5 and dataset[1].spin_joint == J6  # (the same arm pose)
    meshes = mr.load_arm_meshes(ARM)
    config = mr.MeshRenderConfig(noise_sigma=0.0)
    spin = mr.render_mesh_measurement(dataset, truth, 0, config, meshes=meshes, frames=slice(0, 240, 40))
    wrist = mr.render_mesh_measurement(dataset, truth, 1, config, meshes=meshes, frames=[0])
    assert spin.spin_joint == J5 and wrist.spin_joint == J6
    # joint 5's spin turns the link between joints 5 and 6 as well as everything the wrist's turns
    assert set(wrist.moving_links) < set(spin.moving_links)
    assert any("link_5" in name for name in set(spin.moving_links) - set(wrist.moving_links))
    ys, xs = np.nonzero(spin.moving_mask(0))
    pick = np.random.default_rng(0).choice(len(xs), size=30, replace=False)
    pixels = np.column_stack([xs[pick], ys[pick]]).astype(float)
    points = spin.surface_points(0, pixels)
    assert np.all(np.isfinite(points))
    frames = np.array([0, 40, 120, 200])
    projected, _ = spin.project_points(points, frames)
    # independently: camera_T_arm * arm_T_joint5(q with joint 5 turned by the spin) * p
    mt = truth.measurements[0]
    camera_T_arm = truth.arm_T_camera.inverse()
    moved = 0.0
    for row, f in enumerate(frames):
        q = np.array(mt.joint_angles, dtype=float)
        q[4] += mt.spin_angles[f]
        arm_T_link = ARM.arm_T_joint(q, J5)
        expected = dataset.camera.project(
            np.array([camera_T_arm.transformFrom(arm_T_link.transformFrom(p)) for p in points]))
        np.testing.assert_allclose(projected[row], expected, atol=1e-6)
        np.testing.assert_allclose(spin.arm_T_link(int(f)).matrix(), arm_T_link.matrix(), atol=1e-12)
        moved = max(moved, float(np.max(np.linalg.norm(expected - pixels, axis=1))))
    assert moved > 50.0  # (the hand swings across the image, not about the wrist's axis)
    # the spinning frame's origin sits on the simulator's axis of joint 5, and the frames show the swing
    np.testing.assert_allclose(spin.arm_T_link(0).translation(), mt.axis_point, atol=1e-9)
    assert not np.array_equal(spin.frame(0), spin.frame(3))


def test_the_cylinder_renderer_turns_its_dots_about_the_measurements_spin_axis(noise_free):
    from gtsam_rotid.render import render_measurement

    dataset, truth = noise_free
    mt = truth.measurements[0]
    spin = render_measurement(dataset, truth, 0, frames=slice(0, 240, 60))
    assert spin.n_frames == 4 and spin.frame(0).shape == (dataset.camera.height, dataset.camera.width)
    # each dot's truth: its centre on a circle about joint 5's axis (from the arm, not the renderer), turned by
    # the frame's spin angle
    axis = ARM.wrist_axis(mt.joint_angles, J5)
    dots, camera_T_arm = spin.dots, truth.arm_T_camera.inverse()
    for row, f in enumerate(spin.frame_indices):
        phase = dots.phase + mt.spin_angles[f]
        centres = (axis.point + dots.offset[:, None] * axis.direction
                   + dots.radius[:, None] * (np.cos(phase)[:, None] * mt.e1 + np.sin(phase)[:, None] * mt.e2))
        expected = dataset.camera.project(np.array([camera_T_arm.transformFrom(c) for c in centres]))
        seen = spin.visible[row]
        assert seen.sum() >= 5
        np.testing.assert_allclose(spin.truth_pixels[row][seen], expected[seen], atol=1e-6)


def test_the_dataset_keeps_the_spinning_joint_and_still_reads_version_1(noise_free, tmp_path):
    dataset, _ = noise_free
    root = dataset.save(tmp_path / "v2")
    document = json.loads((root / "dataset.json").read_text())
    assert document["version"] == 2 and document["measurements"][0]["spin_joint"] == J5
    loaded = Dataset.load(root)
    assert [m.spin_joint for m in loaded] == [J5, J6] * 3 and loaded.measurements == dataset.measurements
    assert f"measurement 0 (spin of {J5})" in loaded.summary()

    wrist_only = Dataset(dataset.arm, dataset.camera, [Measurement(m.joint_angles, m.tracks) for m in dataset])
    root = wrist_only.save(tmp_path / "v1")
    document = json.loads((root / "dataset.json").read_text())
    assert document["version"] == 1 and all("spin_joint" not in m for m in document["measurements"])  # (readable
    assert [m.spin_joint for m in Dataset.load(root)] == [None] * 6                                    # by older)
    document["measurements"][1]["spin_joint"] = J5  # version 1 has no such field
    (root / "dataset.json").write_text(json.dumps(document))
    with pytest.raises(ValidationError, match=r"format-1 schema at \$\.measurements\[1\]"):
        Dataset.load(root)

    with pytest.raises(ValidationError, match=r"^measurement 2: spin_joint 'joint_5' is not a revolute joint"):
        Dataset(dataset.arm, dataset.camera, [*dataset.measurements[:2],
                                              Measurement(dataset.joint_angles(2), dataset[2].tracks,
                                                          spin_joint="joint_5")])
    with pytest.raises(ValidationError, match="spin_joint must be a joint name"):
        Measurement(dataset.joint_angles(0), dataset[0].tracks, spin_joint=5)


def test_spins_of_two_joints_calibrate_within_their_covariance_and_forgetting_which_is_refused():
    dataset, truth = simulate.simulate(SceneConfig(duration=10.0, n_measurements=4, spin_joints=(J5, J6)),
                                       seed=4, arm=ARM)
    result = calibrate(dataset)
    assert result.covariance_usable, result.untrusted
    e = result.error_to(truth.arm_T_camera)
    assert e @ np.linalg.solve(result.covariance, e) < 22.46  # the 99.9 % point of 6 dof
    assert np.linalg.norm(e[3:]) < 2e-3
    # the same tracks said to be the wrist's spins: the axes disagree, never a confident number
    forgot = Dataset(dataset.arm, dataset.camera, [Measurement(m.joint_angles, m.tracks) for m in dataset])
    try:
        wrong = calibrate(forgot)
    except RotIdError as refusal:
        assert "disagree" in str(refusal)
    else:
        e = wrong.error_to(truth.arm_T_camera)
        assert not wrong.covariance_usable or e @ np.linalg.solve(wrong.covariance, e) < 22.46


def test_offsets_with_spins_of_two_joints_hold_their_covariance():
    dataset, truth = simulate.simulate(SceneConfig(duration=10.0, n_measurements=5, spin_joints=(J5, J6)),
                                       seed=3, arm=ARM)
    offsets = np.radians([0.0, 0.4, -0.3, 0.3, 0.4, 0.0])  # joints 2-5; the true angle is the reading plus it
    readings = Dataset(dataset.arm, dataset.camera, [Measurement(dataset.joint_angles(k) - offsets, m.tracks,
                                                                 spin_joint=m.spin_joint)
                                                     for k, m in enumerate(dataset)])
    result = calibrate(readings, options=CalibrationOptions(joint_offsets=True))
    assert list(result.joint_offsets) == ARM.joint_names[1:5]  # joint 5's offset shows in joint 6's spins
    assert result.covariance_usable, result.untrusted
    e = result.error_to(truth.arm_T_camera)
    assert e @ np.linalg.solve(result.covariance, e) < 22.46
    miss = np.array(list(result.joint_offsets.values())) - offsets[1:5]
    assert miss @ np.linalg.solve(result.joint_offsets_covariance, miss) < 18.47  # 99.9 % point, 4 dof
    assert max(result.joint_offsets_sigma_deg.values()) < 0.2  # determined, not the 1 degree prior
    assert [m.spin_joint for m in result.measurements] == [J5, J6] * 5
    assert "spin the joint before the wrist too" not in summary(result)  # (it did)


def test_the_command_line_simulates_spins_of_named_joints(tmp_path, capsys):
    out = tmp_path / "spins"
    assert cli.main(["simulate", "-o", str(out), "--duration", "5", "--n-measurements", "4",
                     "--spin-joints", J5, J6]) == 0
    assert [m.spin_joint for m in Dataset.load(out)] == [J5, J6] * 4
    assert cli.main(["simulate", "-o", str(tmp_path / "bad"), "--spin-joints", "joint_5"]) == 1
    err = capsys.readouterr().err
    assert "'joint_5' is not a revolute joint" in err and J5 in err
    assert not (tmp_path / "bad").exists()


def test_offsets_that_explain_most_of_a_systematic_disagreement_are_not_scaled_away():
    """Panda, readings of joints 2-6 off by 0.5 degrees, two spins per pose, calibrated with the kinematics as given:
    four of twelve measurements are left out and the rest still disagree; offsets explain the axes far better than
    any one wrong measurement, if not all the way (their fit P = 0.002). The scaled covariance called this usable
    (16 mm off, chi-square 312); it must be flagged, with the offsets named."""
    panda = Arm.from_robot("panda")
    config = SceneConfig(robot="panda", duration=12.0, camera=Camera.from_fov(640, 480, 60.0),
                         camera_eye=(1.1, -0.4, 0.8), camera_target=(0.4, 0.0, 0.4),
                         spin_joints=tuple(panda.joint_names[5:7]))
    dataset, truth = simulate.simulate(config, seed=5, arm=panda)
    offsets = np.zeros(panda.dof)
    offsets[1:6] = np.radians(0.5) * np.random.default_rng(10_005).choice([-1.0, 1.0], size=5)
    readings = Dataset(panda, dataset.camera, [Measurement(dataset.joint_angles(k) - offsets, m.tracks,
                                                           spin_joint=m.spin_joint) for k, m in enumerate(dataset)])
    result = calibrate(readings)
    e = result.error_to(truth.arm_T_camera)
    assert e @ np.linalg.solve(result.covariance, e) > 22.46  # wrong beyond its covariance ...
    assert not result.covariance_usable and "kinematics" in result.untrusted  # ... and flagged
    assert "come far closer (not all the way: more is off) once the joints" in summary(result)

import numpy as np
import pytest

from gtsam_rotid import Arm, Camera, InputError, SimulationError, simulate
from gtsam_rotid.simulate import GroundTruth, SceneConfig

DISTORTED = Camera([[560.0, 0.0, 322.0], [0.0, 565.0, 236.0], [0.0, 0.0, 1.0]], 640, 480,
                   [-0.25, 0.08, 0.0005, -0.0007, -0.01])


@pytest.fixture(scope="module")
def noise_free():
    return simulate.reference_scene(seed=3, noise_var=0.0, duration=15.0, camera=DISTORTED)


def circle_distances(dataset, truth, k, j, circle=None):
    """Back-project each pixel of track j onto the plane of its true circle (or of ``circle``); return
    |X - centre| - r and the 3-D points. Uses only the camera model and the ground-truth circle."""
    track = dataset[k].tracks[j]
    centre, normal, radius = truth.measurements[k].circle(j) if circle is None else circle
    arm_T_camera = truth.arm_T_camera
    R = arm_T_camera.rotation().matrix()
    origin = arm_T_camera.translation()
    rays = dataset.camera.rays(track.pixels) @ R.T
    s = ((centre - origin) @ normal) / (rays @ normal)
    points = origin + s[:, None] * rays
    return np.linalg.norm(points - centre, axis=1) - radius, points


def test_noise_free_tracks_lie_on_projected_true_circles(noise_free):
    dataset, truth = noise_free
    for k in range(len(dataset)):
        for j in range(len(dataset[k].tracks)):
            error, points = circle_distances(dataset, truth, k, j)
            assert np.max(np.abs(error)) < 1e-7, (k, j)
            centre, normal, _ = truth.measurements[k].circle(j)
            assert np.max(np.abs((points - centre) @ normal)) < 1e-7


def test_truth_axes_are_the_arms_forward_kinematics(noise_free):
    dataset, truth = noise_free
    arm = Arm.from_robot("kinova")
    for k, m in enumerate(truth.measurements):
        axis = arm.wrist_axis(dataset.joint_angles(k))
        np.testing.assert_allclose(m.axis_point, axis.point, atol=1e-12)
        np.testing.assert_allclose(m.axis_direction, axis.direction, atol=1e-12)


def test_hidden_points_never_appear(noise_free):
    dataset, truth = noise_free
    cfg = SceneConfig()
    centre_of_camera = truth.arm_T_camera.translation()
    camera_T_arm = truth.arm_T_camera.inverse()
    for k, measurement in enumerate(dataset):
        mt = truth.measurements[k]
        for j, track in enumerate(measurement.tracks):
            points = mt.feature_points(j, track.frames)
            centre, normal, _ = mt.circle(j)
            outward = points - centre
            outward /= np.linalg.norm(outward, axis=1, keepdims=True)
            to_camera = centre_of_camera - points
            facing = np.sum(outward * to_camera, axis=1) / np.linalg.norm(to_camera, axis=1)
            assert np.all(facing > cfg.visibility_cos), (k, j)
            camera_points = np.array([camera_T_arm.transformFrom(p) for p in points])
            np.testing.assert_allclose(dataset.camera.project(camera_points), track.pixels, atol=1e-8)
            assert np.all(dataset.camera.in_image(track.pixels))


def test_tracks_restart_every_revolution(noise_free):
    dataset, truth = noise_free
    # 15 s at 0.5 rad/s is 1.2 turns: some feature is seen, hidden, and seen again as a new track
    features = [t.feature for t in truth.measurements[0].tracks]
    assert len(features) > len(set(features))
    for track in dataset[0].tracks:
        assert np.all(np.diff(track.frames) == 1)
        assert len(track) >= SceneConfig().min_track_length


def test_poses_respect_scene_constraints(noise_free):
    dataset, truth = noise_free
    cfg = SceneConfig()
    eye = truth.arm_T_camera.translation()
    directions = []
    for m in truth.measurements:
        ray = m.axis_point - eye
        angle = np.degrees(np.arccos(abs(ray @ m.axis_direction) / np.linalg.norm(ray)))
        assert cfg.axis_view_angle_deg[0] <= angle <= cfg.axis_view_angle_deg[1]
        directions.append(m.axis_direction)
    cosines = np.abs(np.array(directions) @ np.array(directions).T)[np.triu_indices(len(directions), 1)]
    assert np.all(cosines < np.cos(np.radians(cfg.min_axis_separation_deg)))
    assert all(dataset.arm.within_limits(dataset.joint_angles(k)) for k in range(len(dataset)))


def test_seed_reproduces_and_differs():
    a, ta = simulate.reference_scene(seed=11, duration=5.0)
    b, tb = simulate.reference_scene(seed=11, duration=5.0)
    c, _ = simulate.reference_scene(seed=12, duration=5.0)
    assert a == b
    assert ta.to_dict() == tb.to_dict()
    assert a != c


def test_pixel_noise_has_requested_variance():
    clean, _ = simulate.reference_scene(seed=5, noise_var=0.0, duration=20.0)
    noisy, _ = simulate.reference_scene(seed=5, noise_var=1.5, duration=20.0)
    diffs = []
    for mc, mn in zip(clean, noisy, strict=True):
        # same seed: the same features in the same order; noise can only trim a track at the image border
        for tc, tn in zip(mc.tracks, mn.tracks, strict=False):
            if np.array_equal(tc.frames, tn.frames):
                diffs.append(tn.pixels - tc.pixels)
    diffs = np.vstack(diffs)
    assert len(diffs) > 5000
    # sample variance of > 10^4 values: 5 % is many standard errors wide
    assert np.var(diffs) == pytest.approx(1.5, rel=0.05)
    assert abs(np.mean(diffs)) < 0.05


def test_outlier_tracks_are_planted_and_off_the_circles():
    dataset, truth = simulate.reference_scene(seed=2, noise_var=0.0, duration=10.0, outlier_fraction=0.3,
                                              n_measurements=3)
    for k in range(len(dataset)):
        flags = [t.is_outlier for t in truth.measurements[k].tracks]
        assert sum(flags) == round(0.3 * len(flags))
        for j, is_outlier in enumerate(flags):
            if not is_outlier:
                assert np.max(np.abs(circle_distances(dataset, truth, k, j)[0])) < 1e-7
            else:
                # an outlier arc lies on the circle of no true feature of this measurement
                inliers = [i for i, flag in enumerate(flags) if not flag]
                for i in inliers:
                    error, _ = circle_distances(dataset, truth, k, j, truth.measurements[k].circle(i))
                    assert np.max(np.abs(error)) > 1e-3


def test_single_crossing_axes_meet_in_one_point():
    dataset, truth = simulate.single_crossing_scene(seed=1, duration=5.0)
    crossing = np.array(truth.config["crossing_point"])
    arm = dataset.arm
    directions = []
    for k in range(len(dataset)):
        axis = arm.wrist_axis(dataset.joint_angles(k))
        assert axis.distance_to([crossing])[0] < 1e-6
        directions.append(axis.direction)
    assert len(dataset) == 6
    assert np.linalg.matrix_rank(np.array(directions), tol=0.1) == 3  # genuinely different orientations


def test_explicit_poses_and_unusable_pose():
    dataset, truth = simulate.reference_scene(seed=0, duration=3.0, n_measurements=2)
    poses = tuple(tuple(dataset.joint_angles(k)) for k in range(2))
    again, truth2 = simulate.simulate(SceneConfig(joint_angles=poses, duration=3.0), seed=9)
    np.testing.assert_allclose(again.joint_angles(1), poses[1])
    bad = (poses[0], tuple(np.zeros(6) + 3.0))
    with pytest.raises(SimulationError, match="measurement 1: the given arm pose is unusable"):
        simulate.simulate(SceneConfig(joint_angles=bad, duration=3.0), seed=0)


def test_bad_config_rejected():
    with pytest.raises(ValueError, match="noise_var"):
        simulate.reference_scene(noise_var=-1.0)
    with pytest.raises(ValueError, match="outlier_fraction"):
        simulate.reference_scene(outlier_fraction=1.5)
    with pytest.raises(SimulationError, match="arm poses with the wrist in view"):
        simulate.reference_scene(camera_eye=(5.0, 5.0, 5.0), camera_target=(6.0, 6.0, 6.0), max_pose_samples=500,
                                 duration=1.0)


def test_ground_truth_round_trip(tmp_path, noise_free):
    _, truth = noise_free
    truth.save(tmp_path / "truth.json")
    loaded = GroundTruth.load(tmp_path / "truth.json")
    assert loaded.to_dict() == truth.to_dict()
    assert loaded.arm_T_camera.equals(truth.arm_T_camera, 1e-12)
    with pytest.raises(FileExistsError):
        truth.save(tmp_path / "truth.json")


@pytest.mark.parametrize("robot", ["ur10", "panda", "xarm7"])
def test_other_arms(robot):
    dataset, truth = simulate.simulate(SceneConfig(robot=robot, duration=3.0, n_measurements=3), seed=0)
    assert len(dataset) == 3 and dataset.arm.name == robot
    assert dataset.n_observations > 1000


@pytest.mark.parametrize("field, value, words", [
    ("duration", -5.0, "duration must be a finite number > 0"), ("noise_var", float("nan"), "noise_var must be"),
    ("fps", 0.0, "fps must be"), ("n_measurements", 0, "n_measurements must be"),
    ("wrist_speed", 0.0, "wrist_speed must be"), ("outlier_fraction", 1.5, "outlier_fraction must be"),
])
def test_a_scene_that_cannot_be_made_is_refused_by_its_field(field, value, words):
    with pytest.raises(InputError, match=words):
        simulate.simulate(simulate.SceneConfig(**{field: value}))


def test_a_ramped_spin_and_the_joints_readings():
    """``spin_ramp`` speeds the spin up from rest and down again; ``encoder_rate`` gives each measurement the
    spinning joint's readings, stamped ``encoder_time_offset`` s ahead: between two frames a feature turns
    right-handed about the FK axis by the readings' change between their times on the encoder's clock."""
    from gtsam_rotid.simulate import spin_profile

    config = SceneConfig(n_measurements=2, duration=4.0, spin_ramp=1.0, encoder_rate=250.0, encoder_sigma_deg=0.0,
                         encoder_time_offset=0.04, noise_var=0.0)
    dataset, truth = simulate.simulate(config, seed=5)
    t = np.linspace(-1.0, 5.0, 6001)
    angle = spin_profile(t, config)
    speed = np.gradient(angle, t)
    assert np.all(angle[t <= 0] == 0) and np.allclose(angle[t >= 4.0], angle[-1])
    assert abs(speed[np.argmin(abs(t - 2.0))] - 0.5) < 1e-9 and abs(speed[np.argmin(abs(t - 0.5))] - 0.25) < 1e-3
    assert np.allclose(spin_profile(t, config.with_(spin_ramp=0.0)), 0.5 * t)
    arm = dataset.arm
    for m, m_truth in zip(dataset.measurements, truth.measurements, strict=True):
        readings = m.spin_readings
        assert readings.times[0] < 0.04 and readings.times[-1] > 4.04 and len(readings.frame_times) == 120
        np.testing.assert_allclose(readings.frame_times, np.arange(120) / 30.0)
        f = 77
        axis = arm.wrist_axis(m.joint_angles)
        track = next(j for j, tr in enumerate(m.tracks) if f in tr.frames)
        start = m_truth.feature_points(track, [0])[0]  # the feature at frame 0, turned by the readings' change
        turned = np.interp(readings.frame_times[f] + 0.04, readings.times, readings.angles) - np.interp(
            0.04, readings.times, readings.angles)
        r = start - axis.point
        c, s = np.cos(turned), np.sin(turned)
        d = axis.direction
        rotated = axis.point + r * c + np.cross(d, r) * s + d * (d @ r) * (1 - c)
        np.testing.assert_allclose(m_truth.feature_points(track, [f])[0], rotated, atol=1e-6)
    plain, _ = simulate.simulate(config.with_(encoder_rate=0.0), seed=5)
    assert all(m.spin_readings is None for m in plain.measurements)

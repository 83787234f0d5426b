"""The graph builder inside a user's own factor graph (SLAM-style use), against ground truth it never sees."""

import gtsam
import numpy as np
import pytest
from gtsam.symbol_shorthand import L, O, X

from gtsam_rotid import InputError, simulate
from gtsam_rotid.dataset import Measurement, SpinReadings
from gtsam_rotid.estimate import calibrate
from gtsam_rotid.factors import CoaxialLineFactor, RigidLineFactor
from gtsam_rotid.graph import Model, RotIdGraph, initial_circle, initial_circles, lm_params


@pytest.fixture(scope="module")
def scene():
    return simulate.reference_scene(seed=3, noise_var=0.0, duration=6.0, n_measurements=5)


def lm(graph, values, diagonal_damping=True):
    params = lm_params(relative_tolerance=1e-12, diagonal_damping=diagonal_damping)
    return gtsam.LevenbergMarquardtOptimizer(graph, values, params).optimize()


def solve_measurements(builder, graph, values, dataset, truth):
    """Every measurement of ``dataset`` added to the graph, LM (isotropic damping), and the result, its Marginals
    and the chi-square of the pose's error against the truth under its marginal covariance."""
    for k, m in enumerate(dataset):
        builder.add_measurement(graph, values, k, m)
    result = lm(graph, values, diagonal_damping=False)
    marginals = gtsam.Marginals(graph, result)
    error = truth.arm_T_camera.localCoordinates(result.atPose3(X(0)))
    return result, marginals, float(error @ np.linalg.solve(marginals.marginalCovariance(X(0)), error))


def user_graph(pose_start, cad_pose, cad_sigmas):
    """A user's graph: their own pose variable X(0) with a CAD prior, and an unrelated landmark L(0)."""
    graph, values = gtsam.NonlinearFactorGraph(), gtsam.Values()
    values.insert(X(0), pose_start)
    graph.add(gtsam.PriorFactorPose3(X(0), cad_pose, gtsam.noiseModel.Diagonal.Sigmas(cad_sigmas)))
    values.insert(L(0), gtsam.Point3(1.0, 2.0, 3.0))
    graph.add(gtsam.PriorFactorPoint3(L(0), gtsam.Point3(1.0, 2.0, 3.0), gtsam.noiseModel.Isotropic.Sigma(3, 0.1)))
    return graph, values


@pytest.mark.parametrize("model", ["pose", "line", "projected"])
def test_builder_fuses_with_a_cad_prior(scene, model):
    dataset, truth = scene
    T = truth.arm_T_camera
    # a CAD prior about 1 deg / 1 cm off the truth, and the optimisation started from it
    cad = T.retract(np.array([0.01, -0.015, 0.005, 0.01, -0.005, 0.0075]))
    sigmas = np.array([0.02, 0.02, 0.02, 0.02, 0.02, 0.02])
    graph, values = user_graph(cad, cad, sigmas)
    n_user_factors = graph.size()
    builder = RotIdGraph(dataset.arm, dataset.camera, pose_key=X(0), line_symbol="a", circle_symbol="b", model=model)
    made = [builder.add_measurement(graph, values, k, m) for k, m in enumerate(dataset)]
    # the builder made its own keys (no line variables in the pose-bound model) and left the user's alone
    for keys in made:
        assert (keys.line_key is None) == (model == "pose")
        assert all(gtsam.Symbol(c).chr() == ord("b") for c in keys.circles)
        if model == "projected":  # one factor for all tracks, on the line only: no circle variables
            assert keys.circles == [] and len(keys.circle_factors) == 1 and keys.coaxial is not None
        else:
            assert len(keys.circles) == len(keys.circle_factors) >= 2
    assert graph.size() == n_user_factors + sum(len(k.circle_factors) + (k.tie_factor >= 0) for k in made)
    # The projected model from ~1 deg off needs isotropic damping: diagonal damping of its reduced problem leaves
    # each line's tilt within its projection plane (free of the tie, and no longer held back by damped circles)
    # nearly undamped, and LM's long steps along it can lead it to a wrong solution (see factors/coaxial.py).
    result = lm(graph, values, diagonal_damping=model != "projected")
    error = T.localCoordinates(result.atPose3(X(0)))
    cad_error = T.localCoordinates(cad)
    covariance = gtsam.Marginals(graph, result).marginalCovariance(X(0))
    assert np.all(np.sqrt(np.diag(covariance)) < 0.2 * sigmas)  # the spins add much information to the prior
    # Noise-free spins say "truth" and the prior says "cad": the fused estimate is their information-weighted
    # mean, error = Sigma_fused H_prior cad_error (to first order), far closer to the truth than the prior.
    expected = covariance @ (cad_error / sigmas**2)
    np.testing.assert_allclose(error, expected, atol=0.05 * np.max(np.abs(expected)))
    assert np.linalg.norm(error) < 0.05 * np.linalg.norm(cad_error)
    np.testing.assert_allclose(result.atPoint3(L(0)), [1.0, 2.0, 3.0])


def test_builder_refuses_existing_keys_and_changes_nothing(scene):
    dataset, truth = scene
    graph, values = user_graph(truth.arm_T_camera, truth.arm_T_camera, np.full(6, 0.1))
    builder = RotIdGraph(dataset.arm, dataset.camera, pose_key=X(0), line_symbol="l", circle_symbol="c",
                         model=Model.LINE)
    values.insert(gtsam.symbol("l", 2), gtsam.Rot3())  # the user already has l2
    size, keys_before = graph.size(), set(values.keys())
    with pytest.raises(InputError, match="measurement 2: key l2 already exists"):
        builder.add_measurement(graph, values, 2, dataset[2])
    assert graph.size() == size and set(values.keys()) == keys_before
    values.insert(gtsam.symbol("c", 1 * 100_000 + 0), np.zeros(2))  # and a circle key of measurement 1
    with pytest.raises(InputError, match="measurement 1, track 0: key c100000 already exists"):
        builder.add_measurement(graph, values, 1, dataset[1])
    assert graph.size() == size


def test_builder_needs_a_pose(scene):
    dataset, _ = scene
    builder = RotIdGraph(dataset.arm, dataset.camera, pose_key=X(7))
    with pytest.raises(InputError, match="insert an initial arm_T_camera"):
        builder.add_measurement(gtsam.NonlinearFactorGraph(), gtsam.Values(), 0, dataset[0])
    with pytest.raises(InputError, match="unknown model 'plane'"):
        RotIdGraph(dataset.arm, dataset.camera, model="plane")
    with pytest.raises(InputError, match="must differ"):
        RotIdGraph(dataset.arm, dataset.camera, line_symbol="q", circle_symbol="q")


def test_builder_starts_from_calibrate_on_noisy_spins():
    """The documented recipe: calibrate for the start, then the builder's graph plus a CAD prior."""
    dataset, truth = simulate.reference_scene(seed=5, noise_var=1.5, duration=12.0, n_measurements=5)
    first = calibrate(dataset)
    graph, values = user_graph(first.arm_T_camera, first.arm_T_camera, np.full(6, 1.0))  # a vague prior
    builder = RotIdGraph(dataset.arm, dataset.camera, pose_key=X(0), track_sigma_px=first.sigma_px)
    with pytest.raises(InputError, match="key l0 already exists"):  # the user's landmark L(0) is symbol l0
        builder.add_measurement(graph, values, 0, dataset[0])
    builder = RotIdGraph(dataset.arm, dataset.camera, pose_key=X(0), line_symbol="a",
                         track_sigma_px=first.sigma_px)
    for k, m in enumerate(dataset):
        builder.add_measurement(graph, values, k, m)
    result = lm(graph, values)
    pose = result.atPose3(X(0))
    covariance = gtsam.Marginals(graph, result).marginalCovariance(X(0))
    error = truth.arm_T_camera.localCoordinates(pose)
    assert np.all(np.abs(error) < 4.0 * np.sqrt(np.diag(covariance)))


def test_projected_model_equals_the_line_model_on_noisy_spins():
    """Variable projection changes the cost of a solve, not its answer: the same pose and pose marginal (from a
    start near the solution: from ~1 deg / 1 cm off, LM on the projected model can stall; see README)."""
    dataset, truth = simulate.reference_scene(seed=5, noise_var=1.5, duration=12.0, n_measurements=4)
    start = calibrate(dataset, method="weighted")
    solved = {}
    for model in ("line", "projected"):
        graph, values = gtsam.NonlinearFactorGraph(), gtsam.Values()
        values.insert(X(0), start.arm_T_camera)
        builder = RotIdGraph(dataset.arm, dataset.camera, pose_key=X(0), track_sigma_px=start.sigma_px, model=model)
        for k, m in enumerate(dataset):
            keys = builder.add_measurement(graph, values, k, m)
            if model == "projected":  # one factor for all tracks, on the line only: no circle variables
                assert keys.circles == [] and len(keys.circle_factors) == 1 and keys.coaxial is not None
        result = lm(graph, values)
        solved[model] = (result.atPose3(X(0)), gtsam.Marginals(graph, result).marginalCovariance(X(0)))
    (pose_line, cov_line), (pose_projected, cov_projected) = solved["line"], solved["projected"]
    sigma = np.sqrt(np.diag(cov_line))
    assert np.all(np.abs(pose_line.localCoordinates(pose_projected)) < 1e-3 * sigma)
    np.testing.assert_allclose(np.sqrt(np.diag(cov_projected)), sigma, rtol=1e-3)


def test_rigid_spin_in_a_users_graph():
    """spin_model="rigid": one rigid-spin factor per measurement whose tracks have frame indices (the free phase for
    one without), a pose within its covariance of the truth, and a covariance below the free phase's (the rigid
    spin knows that all features turn together)."""
    dataset, truth = simulate.reference_scene(seed=5, noise_var=1.5, duration=12.0, n_measurements=4)
    start = calibrate(dataset, method="weighted")
    frameless = Measurement(dataset[3].joint_angles, [t.pixels for t in dataset[3].tracks])
    solved = {}
    for spin in ("free", "rigid"):
        graph, values = gtsam.NonlinearFactorGraph(), gtsam.Values()
        values.insert(X(0), start.arm_T_camera)
        builder = RotIdGraph(dataset.arm, dataset.camera, pose_key=X(0), track_sigma_px=start.sigma_px,
                             model="projected", spin_model=spin)
        for k, m in enumerate(list(dataset)[:3] + [frameless]):
            keys = builder.add_measurement(graph, values, k, m)
            assert keys.circles == [] and len(keys.circle_factors) == 1
            rigid = spin == "rigid" and k < 3
            assert isinstance(keys.coaxial, RigidLineFactor) == rigid and isinstance(keys.coaxial, CoaxialLineFactor)
            points = sum(len(m.tracks[j].pixels) for j in keys.tracks)
            assert graph.at(keys.circle_factors[0]).dim() == (2 if rigid else 1) * points
        result = lm(graph, values, diagonal_damping=False)
        solved[spin] = (result.atPose3(X(0)), gtsam.Marginals(graph, result).marginalCovariance(X(0)))
    pose, covariance = solved["rigid"]
    error = truth.arm_T_camera.localCoordinates(pose)
    assert error @ np.linalg.solve(covariance, error) < 22.5  # the 99.9 % point for 6 dof
    assert np.all(np.diag(covariance) < np.diag(solved["free"][1]))
    with pytest.raises(InputError, match="unknown spin_model 'rigd'"):
        RotIdGraph(dataset.arm, dataset.camera, spin_model="rigd")


def test_tie_covariance_widens_the_tie_and_a_bad_one_adds_nothing(scene):
    """The joint readings' uncertainty as a tie covariance: the tie's noise model is sigma^2 I + C, and a C that is
    not 2x2 is refused before anything is added."""
    from gtsam_rotid.estimate import joint_tie_covariance, test_point_jacobian

    dataset, truth = scene
    builder = RotIdGraph(dataset.arm, dataset.camera, pose_key=X(0), line_symbol="m", model=Model.LINE,
                         tie_sigma_px=1e-3)  # "l" would meet the user graph's landmark L(0)
    graph, values = user_graph(truth.arm_T_camera, truth.arm_T_camera, np.full(6, 0.1))
    size, keys_before = graph.size(), set(values.keys())
    with pytest.raises(InputError, match="tie_covariance must be a finite 2x2 matrix"):
        builder.add_measurement(graph, values, 0, dataset[0], tie_covariance=np.eye(3))
    assert graph.size() == size and set(values.keys()) == keys_before
    q = dataset[0].joint_angles
    C = joint_tie_covariance(dataset.camera, dataset.arm.wrist_axis(q), None, truth.arm_T_camera,
                             np.radians(0.05) * test_point_jacobian(dataset.arm, q))
    assert C.shape == (2, 2) and np.all(np.linalg.eigvalsh(C) >= 0) and np.trace(C) > 1e-4  # px², not nothing
    keys = builder.add_measurement(graph, values, 0, dataset[0], tie_covariance=C)
    R = graph.at(keys.tie_factor).noiseModel().R()  # square-root information: R^T R = (sigma^2 I + C)^-1
    np.testing.assert_allclose(np.linalg.inv(R.T @ R), 1e-6 * np.eye(2) + C, rtol=1e-9, atol=1e-15)


def test_joint_offsets_in_a_users_graph():
    """Joints before the wrist read 0.3-0.5 deg off their zero on every pose: the exact-kinematics graph is confidently
    wrong; with the offsets as a variable (1 deg prior) the pose and the offsets the poses determine come back
    within their covariance. The first joint's offset turns the whole arm as the pose does: named, it stays at its
    prior (``True`` leaves it out)."""
    from gtsam_rotid.calibration import initial_pose
    from gtsam_rotid.dataset import Dataset

    dataset, truth = simulate.reference_scene(seed=4, noise_var=1.5, duration=12.0)
    offsets = np.radians([0.0, -0.3, 0.4, 0.3, -0.4])  # the true angle is the reading plus the offset
    shift = np.zeros(len(dataset.arm.joint_names))
    shift[:5] = offsets
    readings = Dataset(dataset.arm, dataset.camera,
                       [Measurement(dataset.joint_angles(k) - shift, m.tracks) for k, m in enumerate(dataset)])
    start = initial_pose(readings.arm, readings.camera, list(readings))
    solved = {}
    every = readings.arm.joint_names[:5]
    assert RotIdGraph(readings.arm, readings.camera, joint_offsets=True).offset_names == every[1:]
    for joints in (None, every):
        graph, values = gtsam.NonlinearFactorGraph(), gtsam.Values()
        values.insert(X(0), start)
        builder = RotIdGraph(readings.arm, readings.camera, pose_key=X(0), model="projected", spin_model="rigid",
                             joint_offsets=joints)
        if joints:
            with pytest.raises(InputError, match="insert the joint offsets first"):
                builder.add_measurement(graph, values, 0, readings[0])
            builder.add_offsets_prior(graph, values, sigma_deg=1.0)
        result, marginals, solved[joints is not None] = solve_measurements(builder, graph, values, readings, truth)
        if joints:
            assert builder.offset_names == every
            estimate, covariance = result.atVector(builder.offsets_key), marginals.marginalCovariance(O(0))
            sigma_deg = np.degrees(np.sqrt(np.diag(covariance)))
            assert sigma_deg[0] > 0.99 and np.all(sigma_deg[1:] < 0.3)  # joint 1: the prior; the others: determined
            miss = estimate - offsets
            assert miss @ np.linalg.solve(covariance, miss) < 20.5  # the 99.9 % point for 5 dof
    assert solved[False] > 100.0 and solved[True] < 22.5  # the 99.9 % point for 6 dof
    with pytest.raises(InputError, match="use model 'line' or 'projected'"):
        RotIdGraph(readings.arm, readings.camera, model="pose", joint_offsets=True)


def test_intrinsics_in_a_users_graph():
    """A camera file 2 % long in focal length and 8 px off in cx: the fixed-intrinsics graph is confidently wrong;
    with the intrinsics a Cal3_S2 variable (a prior as wide as a camera file could be off) the pose and the focal
    length and principal point come back within their covariance. The free phase and the line model are refused."""
    from gtsam.symbol_shorthand import K

    from gtsam_rotid.calibration import initial_pose
    from gtsam_rotid.dataset import Dataset

    dataset, truth = simulate.reference_scene(seed=3, duration=20.0)
    given = Dataset(dataset.arm, dataset.camera.with_intrinsics_changed(1.02, 8.0), list(dataset))
    start = initial_pose(given.arm, given.camera, list(given))
    for model, spin in (("line", "free"), ("projected", "free"), ("line", "rigid")):
        with pytest.raises(InputError, match="refining the intrinsics needs model='projected' and spin_model"):
            RotIdGraph(given.arm, given.camera, model=model, spin_model=spin, intrinsics_key=K(0))
    solved = {}
    for key in (None, K(0)):
        graph, values = gtsam.NonlinearFactorGraph(), gtsam.Values()
        values.insert(X(0), start)
        builder = RotIdGraph(given.arm, given.camera, pose_key=X(0), model="projected", spin_model="rigid",
                             intrinsics_key=key)
        if key is not None:
            with pytest.raises(InputError, match="insert the intrinsics first"):
                builder.add_measurement(graph, values, 0, given[0])
            fx, fy = given.camera.K[0, 0], given.camera.K[1, 1]
            builder.add_intrinsics_prior(graph, values, [0.05 * fx, 0.05 * fy, 1e-6, 20.0, 20.0])
        result, marginals, solved[key is not None] = solve_measurements(builder, graph, values, given, truth)
        if key is not None:
            true = dataset.camera.K
            miss = (result.atCal3_S2(key).vector() - np.array([true[0, 0], true[1, 1], 0.0, true[0, 2], true[1, 2]]))
            chosen = [0, 1, 3, 4]
            covariance = marginals.marginalCovariance(key)[np.ix_(chosen, chosen)]
            assert miss[chosen] @ np.linalg.solve(covariance, miss[chosen]) < 18.47  # the 99.9 % point for 4 dof
    assert solved[False] > 100.0 and solved[True] < 22.5  # the 99.9 % point for 6 dof


def test_synced_spins_in_a_users_graph():
    """encoder_sigma_deg and time_offset_key: the measurements' spin readings put a prior on their rigid spins'
    angles, the clocks' offset a variable of the user's graph. On ramped spins read 40 ms late the offset is found
    within its 3 sigma, the pose within its covariance, which is below the unsynced rigid spin's."""
    from gtsam.symbol_shorthand import T

    dataset, truth = simulate.reference_scene(seed=7, noise_var=1.5, duration=8.0, n_measurements=4, spin_ramp=2.0,
                                              encoder_rate=100.0, encoder_sigma_deg=0.02, encoder_time_offset=0.04)
    start = calibrate(dataset, method="weighted")
    solved = {}
    for synced in (False, True):
        graph, values = gtsam.NonlinearFactorGraph(), gtsam.Values()
        values.insert(X(0), start.arm_T_camera)
        builder = RotIdGraph(dataset.arm, dataset.camera, pose_key=X(0), track_sigma_px=start.sigma_px,
                             model="projected", spin_model="rigid", encoder_sigma_deg=0.02 if synced else None,
                             time_offset_key=T(0) if synced else None)
        if synced:
            with pytest.raises(InputError, match="insert the time offset first"):
                builder.add_measurement(graph, values, 0, dataset[0])
            builder.add_time_offset_prior(graph, values, sigma_s=0.5)
        for k, m in enumerate(dataset):
            keys = builder.add_measurement(graph, values, k, m)
            factor = keys.coaxial
            assert (factor.encoder is not None) == synced
            assert graph.at(keys.circle_factors[0]).dim() == 2 * factor.tracks.n_points + (
                factor.tracks.n_frames if synced else 0)
        result = lm(graph, values, diagonal_damping=False)
        marginals = gtsam.Marginals(graph, result)
        solved[synced] = (result.atPose3(X(0)), marginals.marginalCovariance(X(0)))
        if synced:
            delta, sigma = float(result.atVector(T(0))[0]), float(np.sqrt(marginals.marginalCovariance(T(0))[0, 0]))
            assert abs(delta - 0.04) < 3 * sigma and sigma < 0.01
    pose, covariance = solved[True]
    error = truth.arm_T_camera.localCoordinates(pose)
    assert error @ np.linalg.solve(covariance, error) < 22.5  # the 99.9 % point for 6 dof
    assert np.all(np.diag(covariance) < np.diag(solved[False][1]))


def test_synced_mode_refuses_what_it_cannot_use():
    from gtsam.symbol_shorthand import T

    dataset, truth = simulate.reference_scene(seed=7, duration=4.0, n_measurements=2, encoder_rate=50.0)
    with pytest.raises(InputError, match="synced mode .* needs model='projected' and spin_model='rigid'"):
        RotIdGraph(dataset.arm, dataset.camera, model="projected", encoder_sigma_deg=0.05)
    with pytest.raises(InputError, match="a time offset variable needs synced mode"):
        RotIdGraph(dataset.arm, dataset.camera, model="projected", spin_model="rigid", time_offset_key=T(0))
    with pytest.raises(InputError, match="encoder_sigma_deg must be a positive angle"):
        RotIdGraph(dataset.arm, dataset.camera, model="projected", spin_model="rigid", encoder_sigma_deg=0.0)
    builder = RotIdGraph(dataset.arm, dataset.camera, model="projected", spin_model="rigid", encoder_sigma_deg=0.05,
                         time_offset_key=T(0))
    graph, values = gtsam.NonlinearFactorGraph(), gtsam.Values()
    values.insert(builder.pose_key, truth.arm_T_camera)
    builder.add_time_offset_prior(graph, values, sigma_s=0.1, initial_s=2.0)  # beyond the readings' half second
    with pytest.raises(InputError, match=r"measurement 0: the spin readings \(-0.500-4.480 s\) do not cover"):
        builder.add_measurement(graph, values, 0, dataset[0])
    assert graph.size() == 1 and values.size() == 2  # nothing added
    # one offset variable per camera clock: a spin's readings must name a clock the mapping has, inserted first
    clocks = RotIdGraph(dataset.arm, dataset.camera, model="projected", spin_model="rigid", encoder_sigma_deg=0.05,
                        time_offset_key={"left": T(1), "right": T(2)})
    r = dataset[0].spin_readings
    on = {name: dataset[0].replace(spin_readings=SpinReadings(r.frame_times, r.times, r.angles, clock=name))
          for name in ("left", "right", "other")}
    graph, values = gtsam.NonlinearFactorGraph(), gtsam.Values()
    values.insert(clocks.pose_key, truth.arm_T_camera)
    clocks.add_time_offset_prior(graph, values, sigma_s=0.1, clock="left")
    with pytest.raises(InputError, match=r"no time offset variable for the clock 'other'"):
        clocks.add_measurement(graph, values, 0, on["other"])
    with pytest.raises(InputError, match=r"insert the time offset first \(RotIdGraph.add_time_offset_prior, "
                                         r"clock='right'\)"):
        clocks.add_measurement(graph, values, 0, on["right"])
    assert clocks.add_measurement(graph, values, 0, on["left"]).coaxial.time_key == T(1)
    with pytest.raises(InputError, match="one distinct key per clock"):
        RotIdGraph(dataset.arm, dataset.camera, model="projected", spin_model="rigid", encoder_sigma_deg=0.05,
                   time_offset_key={"left": T(1), "right": T(1)})


def test_initial_circles_batch_equals_one_track_at_a_time():
    """The batched start circles (one array pass for all tracks) give each track's ``initial_circle``: odd and even
    counts (the median's two cases), one-ray tracks, rays in any order; a simulated measurement's circles about
    its true axis start within a millimetre of the truth."""
    rng = np.random.default_rng(3)
    for _ in range(10):
        point, direction = rng.normal(size=3), rng.normal(size=3)
        direction /= np.linalg.norm(direction)
        counts = rng.integers(1, 30, size=6)
        rays = [np.column_stack([rng.normal(size=(n, 2)), np.ones(n)]) for n in counts]
        centres = np.column_stack([rng.normal(size=(6, 2)), np.ones(6)])
        one = np.array([initial_circle(point, direction, r, c) for r, c in zip(rays, centres, strict=True)])
        np.testing.assert_allclose(initial_circles(point, direction, rays, centres), one, rtol=1e-12, atol=1e-12)
    assert initial_circles(point, direction, [], np.zeros((0, 3))).shape == (0, 2)
    # noise-free pixels of circles about a known axis: the circles' radii come back (the offsets along the axis
    # up to where the ellipse-centre ray meets it)
    axis_point, axis_direction = np.array([0.05, -0.02, 0.6]), np.array([0.3, 0.9, 0.3])
    axis_direction /= np.linalg.norm(axis_direction)
    u = np.cross(axis_direction, [1.0, 0.0, 0.0])
    u /= np.linalg.norm(u)
    v = np.cross(axis_direction, u)
    phases = np.linspace(0.0, 2.0 * np.pi, 90, endpoint=False)
    radii, rays = [0.03, 0.05, 0.08], []
    for r in radii:
        points = axis_point + r * (np.outer(np.cos(phases), u) + np.outer(np.sin(phases), v))
        rays.append(points / points[:, 2:])
    centres = np.array([axis_point / axis_point[2]] * 3)
    np.testing.assert_allclose(initial_circles(axis_point, axis_direction, rays, centres)[:, 1], radii, atol=1e-3)

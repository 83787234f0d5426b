"""Pose planning and accuracy prediction (issue 16): the prediction against an independent Cramér-Rao bound, the
plan's constraints checked by the simulator and by Pinocchio, plans against random poses, degenerate pose sets,
next best poses, and the command line."""

import math
import os
import re
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import gtsam
import numpy as np
import pinocchio as pin
import pytest

from gtsam_rotid import simulate
from gtsam_rotid.arm import Arm
from gtsam_rotid.cli import main
from gtsam_rotid.collisions import ArmCollisions
from gtsam_rotid.dataset import Dataset
from gtsam_rotid.errors import InputError
from gtsam_rotid.planning import (
    PlanningError,
    PlanOptions,
    plan_poses,
    predict_accuracy,
    predicted_spins,
    random_valid_poses,
)

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))

#: a quick search (few candidates and guess samples) for the simulator's scenes: its noise and texture
QUICK = PlanOptions(candidates=40, guess_samples=2, pixel_sigma=math.sqrt(1.5), axis_floor_px=0.0,
                    radius_range=(0.03, 0.06), offset_range=(0.0, 0.10))


@pytest.fixture(scope="module")
def kinova():
    return Arm.from_robot("kinova")


@pytest.fixture(scope="module")
def collisions(kinova):
    return ArmCollisions(kinova)


@pytest.fixture(scope="module")
def scene():
    return simulate.reference_scene(seed=0, duration=20.0)


@pytest.mark.parametrize("spin_model", ["rigid", "free"])
def test_prediction_matches_an_independent_cramer_rao_bound(scene, spin_model):
    """The prediction (typical texture at the guess, its own graph, thinned frames) against the bound of the
    simulated scene's own tracks at every frame (the benchmark's graphs at the truth: the rigid spin's, or the
    pose-bound graph at the true circles for the free phase): same poses, camera and recording."""
    from accuracy import crlb, crlb_rigid

    dataset, truth = scene
    bound = np.sqrt(np.diag((crlb_rigid if spin_model == "rigid" else crlb)(dataset, truth, 1.5)))
    options = QUICK.with_(guess_samples=1, spin_model=spin_model)
    prediction = predict_accuracy(dataset.arm, dataset.camera, truth.arm_T_camera,
                                  [m.joint_angles for m in truth.measurements], options)
    ratio = np.sqrt(np.diag(prediction.covariance)) / bound
    print("prediction / bound", ratio)
    # the scene's 12 features are drawn at random, the prediction's spread evenly: the same to ~10 %
    assert np.all((ratio > 0.9) & (ratio < 1.1)), ratio
    assert prediction.observability.is_observable
    assert len(prediction.problems) == 6


@pytest.mark.parametrize("intrinsics, offsets", [(True, False), (False, True), (True, True)],
                         ids=["intrinsics", "offsets", "offsets and intrinsics"])
def test_prediction_with_nuisances_free_matches_an_independent_bound(scene, intrinsics, offsets):
    """``refine_intrinsics`` and / or ``joint_offsets``: the pose's marginal with fx, fy, cx, cy and every offset
    before the wrist free under their priors against the benchmark's bound of the same problem
    (``benchmarks/refinement.py``, the simulated tracks at the truth); wider than the exact model's on every axis."""
    from refinement import _offset_bound

    from gtsam_rotid.dataset import Dataset

    dataset, truth = scene
    poses = [m.joint_angles for m in truth.measurements]
    readings = Dataset(dataset.arm, dataset.camera, list(dataset))
    joints = dataset.arm.offset_joints(True) if offsets else []
    bound, _, _ = _offset_bound(dataset, truth, readings, joints, np.zeros(len(joints)), 2.0,
                                (0.05, 20.0) if intrinsics else None)
    options = QUICK.with_(guess_samples=1, spin_model="rigid")
    free = predict_accuracy(dataset.arm, dataset.camera, truth.arm_T_camera, poses,
                            options.with_(refine_intrinsics=intrinsics, joint_offsets=offsets,
                                          joint_offset_sigma_deg=2.0))
    exact = predict_accuracy(dataset.arm, dataset.camera, truth.arm_T_camera, poses, options)
    ratio = np.sqrt(np.diag(free.covariance)) / np.sqrt(np.diag(bound))
    print("prediction / bound", ratio)
    assert np.all((ratio > 0.85) & (ratio < 1.15)), ratio
    assert np.all(free.sigma > exact.sigma)
    assert free.information.shape == (6, 6) and free.per_pose[0].shape == (6, 6)


def test_nuisances_the_prediction_cannot_free_are_refused(scene):
    """The free phase with the intrinsics; offsets of a joint the arm has not, or of the spinning one; a bad prior.
    Offsets of some joints only widen the prediction less than all of them."""
    dataset, truth = scene
    poses = [m.joint_angles for m in truth.measurements]
    options = QUICK.with_(guess_samples=1, spin_model="rigid")
    with pytest.raises(PlanningError, match="rigid"):
        predict_accuracy(dataset.arm, dataset.camera, truth.arm_T_camera, poses,
                         options.with_(refine_intrinsics=True, spin_model="free"))
    for bad, said in (((dataset.arm.wrist_joint,), "spinning"), (("no_such_joint",), "no_such_joint")):
        with pytest.raises(InputError, match=said):
            predict_accuracy(dataset.arm, dataset.camera, truth.arm_T_camera, poses, options.with_(joint_offsets=bad))
    for bad in (0.0, -1.0, float("nan")):
        with pytest.raises(PlanningError, match="joint_offset_sigma_deg must be a positive"):
            predict_accuracy(dataset.arm, dataset.camera, truth.arm_T_camera, poses,
                             options.with_(joint_offsets=True, joint_offset_sigma_deg=bad))
    joints = dataset.arm.offset_joints(True)
    names = tuple(dataset.arm.joint_names[j] for j in joints[1:3])
    every, some, exact = (predict_accuracy(dataset.arm, dataset.camera, truth.arm_T_camera, poses,
                                           options.with_(joint_offsets=o)) for o in (True, names, False))
    assert np.all(some.sigma <= every.sigma * (1 + 1e-9)) and np.all(some.sigma >= exact.sigma * (1 - 1e-9))
    assert np.any(some.sigma < every.sigma * 0.999)


def test_a_recorded_dataset_adds_its_intrinsics_information_to_a_plan_that_refines_them(scene):
    """``dataset_information`` with ``refine_intrinsics``: the pose's and the intrinsics' information of the recorded
    tracks (its pose block the exact model's), so that what the recording already knows of the pose is counted with
    the intrinsics free: less than with them exact."""
    from gtsam_rotid.planning import PlanningError, dataset_information

    dataset, truth = scene
    options = QUICK.with_(guess_samples=1, spin_model="rigid")
    exact = dataset_information(dataset, truth.arm_T_camera, options)
    free = dataset_information(dataset, truth.arm_T_camera, options.with_(refine_intrinsics=True))
    assert exact.shape == (6, 6) and free.shape == (10, 10)
    np.testing.assert_allclose(free[:6, :6], exact, rtol=1e-6)
    one = [truth.measurements[0].joint_angles]
    with_exact = predict_accuracy(dataset.arm, dataset.camera, truth.arm_T_camera, one, options,
                                  prior_information=exact)
    with_free = predict_accuracy(dataset.arm, dataset.camera, truth.arm_T_camera, one,
                                 options.with_(refine_intrinsics=True), prior_information=free)
    assert with_exact.with_prior and with_free.with_prior
    assert np.all(with_free.sigma > with_exact.sigma)
    with pytest.raises(PlanningError, match="prior_information must be 6x6"):
        predict_accuracy(dataset.arm, dataset.camera, truth.arm_T_camera, one, options, prior_information=free)
    # and the offsets', after the intrinsics'
    n = len(dataset.arm.offset_joints(True))
    both = dataset_information(dataset, truth.arm_T_camera, options.with_(refine_intrinsics=True, joint_offsets=True))
    assert both.shape == (10 + n, 10 + n)
    np.testing.assert_allclose(both[:10, :10], free, rtol=1e-6, atol=1e-9 * np.abs(free).max())
    with_both = predict_accuracy(dataset.arm, dataset.camera, truth.arm_T_camera, one,
                                 options.with_(refine_intrinsics=True, joint_offsets=True), prior_information=both)
    assert np.all(with_both.sigma > with_free.sigma)


def test_a_recorded_dataset_is_counted_at_its_own_noise_and_trackers_floor(scene):
    """``dataset_information`` counts the recording as ``calibrate`` would: at the pixel noise its tracks show
    (simulated at 1.22 px) and its tracker's floor, not at the plan's (0.5 px, no floor) for the poses to come."""
    from gtsam_rotid.planning import dataset_information

    dataset, truth = scene
    plan = PlanOptions(pixel_sigma=0.5, axis_floor_px=0.0, spin_model="rigid")
    measured = dataset_information(dataset, truth.arm_T_camera, plan)
    at_true = dataset_information(dataset, truth.arm_T_camera, plan.with_(pixel_sigma=math.sqrt(1.5)),
                                  measured=False)
    at_plans = dataset_information(dataset, truth.arm_T_camera, plan, measured=False)
    sigma = {name: np.sqrt(np.diag(np.linalg.inv(info))) for name, info in
             (("measured", measured), ("true", at_true), ("plan", at_plans))}
    np.testing.assert_allclose(sigma["measured"], sigma["true"], rtol=0.03)
    assert np.all(sigma["measured"] > 2.0 * sigma["plan"])
    # the dataset's tracker's floor is counted (the plan's is for the poses to come)
    floored = Dataset(dataset.arm, dataset.camera, list(dataset), metadata={"tracker": {"axis_floor_px": 0.3}})
    with_floor = np.sqrt(np.diag(np.linalg.inv(dataset_information(floored, truth.arm_T_camera, plan))))
    assert np.all(with_floor >= sigma["measured"] * (1 - 1e-9)) and np.any(with_floor > 1.2 * sigma["measured"])
    # and so are its tracks' own offsets
    offsets = Dataset(dataset.arm, dataset.camera, list(dataset), metadata={"tracker": {"track_offset_px": 0.5}})
    with_offsets = np.sqrt(np.diag(np.linalg.inv(dataset_information(offsets, truth.arm_T_camera, plan))))
    assert np.all(with_offsets >= sigma["measured"] * (1 - 1e-9)) and np.any(with_offsets > 1.2 * sigma["measured"])


def test_refine_intrinsics_plans_for_the_pose_marginal(kinova):
    """A plan with the intrinsics free predicts the pose's marginal; it is no worse under that model than the plan
    for the exact model (same candidates: the same seed and search)."""
    camera = simulate.SceneConfig().camera
    config = simulate.SceneConfig()
    from gtsam_rotid.geometry import look_at

    guess = look_at(config.camera_eye, config.camera_target, config.camera_up)
    options = QUICK.with_(candidates=60, search_seconds=None, jobs=1, spin_model="rigid", refine_intrinsics=True)
    plan = plan_poses(kinova, camera, guess, 6, options, collisions=None)
    other = plan_poses(kinova, camera, guess, 6, options.with_(refine_intrinsics=False), collisions=None)
    again = predict_accuracy(kinova, camera, guess, other.joint_angles, options)
    assert np.allclose(predict_accuracy(kinova, camera, guess, plan.joint_angles, options).sigma,
                       plan.prediction.sigma)
    assert max(plan.prediction.worst[0] / options.worst_axis_deg, plan.prediction.worst[1] / options.worst_axis_mm) \
        <= 1.001 * max(again.worst[0] / options.worst_axis_deg, again.worst[1] / options.worst_axis_mm)


def test_prediction_scales_with_noise_and_spin_length(scene, kinova):
    dataset, truth = scene
    poses = [m.joint_angles for m in truth.measurements]
    base = predict_accuracy(kinova, dataset.camera, truth.arm_T_camera, poses, QUICK.with_(guess_samples=1))
    noisy = predict_accuracy(kinova, dataset.camera, truth.arm_T_camera, poses,
                             QUICK.with_(guess_samples=1, pixel_sigma=2 * QUICK.pixel_sigma))
    np.testing.assert_allclose(noisy.sigma, 2 * base.sigma, rtol=1e-3)
    floored = predict_accuracy(kinova, dataset.camera, truth.arm_T_camera, poses,
                               QUICK.with_(guess_samples=1, axis_floor_px=0.3))
    assert np.all(floored.sigma > base.sigma)


def test_a_spinning_joint_with_limits_turns_back_and_forth():
    """The Panda's joint 7 turns through 332°, less than a 20 s spin at 0.5 rad/s: the prediction sees that arc."""
    panda = Arm.from_robot("panda")
    config = simulate.SceneConfig(robot="panda", camera_eye=(1.1, -0.4, 0.8), camera_target=(0.4, 0.0, 0.4))
    dataset, truth = simulate.simulate(config.with_(duration=1.0), seed=0, arm=panda)
    poses = [m.joint_angles for m in truth.measurements]
    options = QUICK.with_(guess_samples=1)
    limited = predict_accuracy(panda, config.camera, truth.arm_T_camera, poses, options)
    free = predict_accuracy(panda, config.camera, truth.arm_T_camera, poses, options.with_(respect_wrist_limits=False))
    assert limited.spin_range_deg == pytest.approx(math.degrees(panda.wrist_range()))
    assert free.spin_range_deg is None
    assert np.all(limited.sigma > free.sigma)


def test_single_crossing_poses_are_predicted_degenerate():
    dataset, truth = simulate.single_crossing_scene(seed=0, duration=2.0)
    prediction = predict_accuracy(dataset.arm, dataset.camera, truth.arm_T_camera,
                                  [m.joint_angles for m in truth.measurements], QUICK.with_(guess_samples=1))
    assert not prediction.observability.is_observable
    crossing = np.array(truth.config["crossing_point"])
    ray = crossing - truth.arm_T_camera.translation()
    undetermined = truth.arm_T_camera.rotation().matrix() @ prediction.observability.unobservable_directions[0][3:]
    assert abs(undetermined @ ray) / np.linalg.norm(ray) > 0.99  # along the ray to the common point


def test_collisions_self_floor_and_lines_of_sight(kinova, collisions):
    assert collisions.self_collision(np.zeros(kinova.dof)) is not None  # the Jaco2's zero pose folds into itself
    _, truth = simulate.reference_scene(seed=0, duration=1.0)
    for m in truth.measurements:
        assert collisions.self_collision(m.joint_angles) is None
    # the base link (a cylinder about the z axis at the origin) between a camera and a point behind it
    centre = np.array([2.0, 0.0, 0.08])
    assert collisions.hidden(truth.measurements[0].joint_angles, centre, [[-0.3, 0.0, 0.08]])[0]
    assert not collisions.hidden(truth.measurements[0].joint_angles, centre, [[1.5, 0.0, 0.08]])[0]
    # an independent check of the floor: the lowest vertex of each link's collision mesh, placed by Pinocchio
    rng = np.random.default_rng(3)
    model, data = kinova.model, kinova.model.createData()
    geometry_data = collisions.model.createData()
    for _ in range(20):
        q = kinova.random_joint_angles(rng)
        pin.updateGeometryPlacements(model, data, collisions.model, geometry_data, kinova.configuration(q))
        lowest = min((np.asarray(g.geometry.vertices()) @ np.asarray(m.rotation)[2] + m.translation[2]).min()
                     for g, m in zip(collisions.model.geometryObjects, geometry_data.oMg, strict=True)
                     if g.parentJoint > 1)
        assert (collisions.below_floor(q) is not None) == (lowest < 0.0)


def test_the_default_texture_is_the_end_effectors_own_surface(kinova, collisions):
    options = PlanOptions().with_texture(kinova, collisions)
    # the Jaco2's hand and fingers lie along -z of its wrist joint, up to ~16 cm from it and ~11 cm from the axis
    assert -0.17 < options.offset_range[0] < options.offset_range[1] < 0.0
    assert 0.02 < options.radius_range[0] < options.radius_range[1] < 0.11
    assert PlanOptions().with_texture(kinova, None).offset_range == (0.0, 0.10)
    assert QUICK.with_texture(kinova, collisions) is QUICK


def test_plan_satisfies_its_constraints_and_beats_random_poses(kinova, collisions):
    config = simulate.SceneConfig(duration=20.0)
    _, truth = simulate.simulate(config.with_(duration=1.0), seed=0)
    guess = truth.arm_T_camera
    plan = plan_poses(kinova, config.camera, guess, 6, QUICK, collisions=collisions)
    assert len(plan.joint_angles) == 6 and plan.prediction.observability.is_observable
    for q in plan.joint_angles:
        assert kinova.within_limits(q)
        assert collisions.self_collision(q) is None and collisions.below_floor(q) is None
    # the simulator accepts them at the true camera (its own image, distance and view-angle checks) and records
    # the spins; the calibration of that recording is within its covariance of the truth
    from gtsam_rotid.estimate import calibrate

    dataset, truth2 = simulate.simulate(config.with_(joint_angles=tuple(tuple(q) for q in plan.joint_angles)),
                                        seed=5)
    result = calibrate(dataset)
    error = truth2.arm_T_camera.localCoordinates(result.arm_T_camera)
    assert error @ np.linalg.solve(plan.prediction.covariance, error) < 22.5  # 99.9 % for 6 dof
    worst = plan.prediction.worst
    for seed in range(3):
        random = predict_accuracy(kinova, config.camera, guess,
                                  random_valid_poses(kinova, config.camera, guess, 6, QUICK, collisions=collisions,
                                                     seed=seed), QUICK)
        assert worst[0] < random.worst[0] and worst[1] < random.worst[1]


def test_plan_on_two_processes_is_valid_and_repeatable(kinova, collisions, monkeypatch):
    """``jobs=2``: two shares of the candidates, each with its own random stream; the plan satisfies the constraints,
    its prediction (ranked at ``rank_samples`` of the guess samples) is the prediction of its poses at all of them,
    and the same seed gives the same plan, forked or with the shares run here in turn, or with a forked process that
    hangs or dies replaced by its share run here."""
    import gtsam_rotid.planning as planning

    config = simulate.SceneConfig(duration=20.0)
    _, truth = simulate.simulate(config.with_(duration=1.0), seed=0)
    options = QUICK.with_(jobs=2, candidates=24, guess_samples=3, rank_samples=2)
    plan = plan_poses(kinova, config.camera, truth.arm_T_camera, 6, options, collisions=collisions)
    assert plan.candidates == options.candidates and len(plan.joint_angles) == 6
    check = predict_accuracy(kinova, config.camera, truth.arm_T_camera, plan.joint_angles, options,
                             collisions=collisions)
    assert check.problems == [None] * 6
    np.testing.assert_allclose(plan.prediction.sigma, check.sigma, rtol=1e-9)
    again = plan_poses(kinova, config.camera, truth.arm_T_camera, 6, options, collisions=collisions)
    np.testing.assert_array_equal(np.array(again.joint_angles), np.array(plan.joint_angles))
    # a forked process that hangs (a lock held at the fork) or dies without answering: killed, its share run here
    monkeypatch.setattr(planning, "SHARE_WAIT_MIN_S", 0.5)
    monkeypatch.setattr(planning, "SHARE_WAIT_FACTOR", 1.0)
    for child in (lambda part, writer: time.sleep(3600), lambda part, writer: os._exit(3)):
        monkeypatch.setattr(planning, "_share_child", child)
        with pytest.warns(RuntimeWarning, match="search process 1 of 1 gave no answer"):
            rescued = plan_poses(kinova, config.camera, truth.arm_T_camera, 6, options, collisions=collisions)
        np.testing.assert_array_equal(np.array(rescued.joint_angles), np.array(plan.joint_angles))
    monkeypatch.setattr(planning.multiprocessing, "get_all_start_methods", lambda: ["spawn"])
    here = plan_poses(kinova, config.camera, truth.arm_T_camera, 6, options, collisions=collisions)
    np.testing.assert_array_equal(np.array(here.joint_angles), np.array(plan.joint_angles))
    with pytest.raises(PlanningError, match="jobs"):
        options.with_(jobs=0).check()


def test_without_a_deadline_the_search_does_not_depend_on_the_clock(kinova, collisions, monkeypatch):
    """On a machine so slow that every clock reading is past the deadline, the search stops at a third of its
    candidates; with ``search_seconds=None`` it searches them all, as on any machine."""
    import gtsam_rotid.planning as planning

    config = simulate.SceneConfig(duration=20.0)
    _, truth = simulate.simulate(config.with_(duration=1.0), seed=0)
    clock = iter(range(0, 10**9, 100))
    monkeypatch.setattr(planning.time, "perf_counter", lambda: float(next(clock)))
    options = QUICK.with_(jobs=1, candidates=24, guess_samples=1)
    hurried = plan_poses(kinova, config.camera, truth.arm_T_camera, 6, options, collisions=collisions)
    assert hurried.candidates < options.candidates
    patient = plan_poses(kinova, config.camera, truth.arm_T_camera, 6, options.with_(search_seconds=None),
                         collisions=collisions)
    assert patient.candidates == options.candidates
    with pytest.raises(PlanningError, match="search_seconds"):
        options.with_(search_seconds=0.0).check()


def test_a_host_with_busy_threads_plans_without_forking():
    """A host such as a Dask worker runs other threads when it plans: a fork copies whatever lock they hold (one
    inside a BLAS call left the forked search hanging under load), so with other threads running the shares run
    here in turn, and give the plan that forked shares give. In a subprocess with a timeout: a hang fails the test."""
    script = textwrap.dedent("""
        import faulthandler
        faulthandler.dump_traceback_later(400, exit=True)  # where a hang sits, in the failure's stderr
        import logging, math, threading, numpy as np
        from gtsam_rotid.arm import Arm
        from gtsam_rotid import planning, simulate
        config = simulate.SceneConfig(duration=20.0)
        _, truth = simulate.simulate(config.with_(duration=1.0), seed=0)
        options = planning.PlanOptions(candidates=24, guess_samples=2, rank_samples=1, pixel_sigma=math.sqrt(1.5),
                                       axis_floor_px=0.0, radius_range=(0.03, 0.06), offset_range=(0.0, 0.10),
                                       jobs=2)
        arm = Arm.from_robot("kinova")
        assert not planning._other_threads()
        forked = planning.plan_poses(arm, config.camera, truth.arm_T_camera, 6, options)
        logging.basicConfig(level=logging.INFO, handlers=[logging.NullHandler()])
        stop = threading.Event()
        def busy():
            a = np.random.default_rng(0).normal(size=(300, 300))
            while not stop.is_set():
                np.linalg.inv(a @ a.T + np.eye(300))
                logging.getLogger("host").info("working")
        threads = [threading.Thread(target=busy, daemon=True) for _ in range(2)]
        for t in threads:
            t.start()
        assert planning._other_threads()
        plan = planning.plan_poses(arm, config.camera, truth.arm_T_camera, 6, options)
        stop.set()
        assert np.array_equal(np.array(plan.joint_angles), np.array(forked.joint_angles))
        print("planned", len(plan.joint_angles), plan.candidates)
    """)
    env = {**os.environ, **{name: "2" for name in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS")}}
    proc = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=600, env=env)
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert "planned 6 24" in proc.stdout


def test_next_best_pose_resolves_a_single_crossing(kinova, collisions):
    dataset, truth = simulate.single_crossing_scene(seed=0, duration=2.0, n_measurements=4)
    poses = [m.joint_angles for m in truth.measurements]
    options = QUICK.with_(guess_samples=1)
    before = predict_accuracy(kinova, dataset.camera, truth.arm_T_camera, poses, options)
    plan = plan_poses(kinova, dataset.camera, truth.arm_T_camera, 1, options, collisions=collisions,
                      prior_information=before.information)
    after = predict_accuracy(kinova, dataset.camera, truth.arm_T_camera, poses + plan.joint_angles, options)
    assert not before.observability.is_observable and after.observability.is_observable
    assert plan.prediction.observability.is_observable
    assert plan.sigma_before is not None and plan.sigma_before.max() > 1e5 * plan.prediction.sigma.max()


def test_plan_refuses_a_camera_that_sees_no_workable_pose(kinova, collisions):
    away = gtsam.Pose3(gtsam.Rot3(), np.array([0.0, 0.0, 5.0]))  # 5 m up, looking up
    with pytest.raises(PlanningError, match="satisfy the constraints"):
        plan_poses(kinova, simulate.SceneConfig().camera, away, 6, QUICK.with_(max_draws=300),
                   collisions=collisions)
    with pytest.raises(PlanningError, match="pixel_sigma"):
        PlanOptions(pixel_sigma=-1.0).check()


def test_predicted_spins_are_in_the_image(scene):
    dataset, truth = scene
    spins = predicted_spins(dataset.arm, dataset.camera, truth.arm_T_camera,
                            [m.joint_angles for m in truth.measurements], QUICK)
    assert all(s is not None and len(s.tracks) >= 2 for s in spins)
    assert all(dataset.camera.in_image(t.pixels).all() for s in spins for t in s.tracks)


def _camera_yaml(path: Path) -> Path:
    path.write_text("image_width: 640\nimage_height: 480\ncamera_matrix:\n  rows: 3\n  cols: 3\n  data: [570.0, 0, "
                    "319.5, 0, 570.0, 239.5, 0, 0, 1]\ndistortion_coefficients:\n  rows: 1\n  cols: 5\n"
                    "  data: [0, 0, 0, 0, 0]\n")
    return path


def test_cli_plan_then_predict(tmp_path, capsys):
    camera = _camera_yaml(tmp_path / "camera.yaml")
    guess = ["-0.45", "0.25", "0.95", "125.6", "0", "72.6"]  # the reference scene's camera
    poses = tmp_path / "poses.csv"
    common = ["--robot", "kinova", "--camera", str(camera), "--camera-guess", *guess, "--no-progress"]
    assert main(["plan", *common, "-n", "6", "--candidates", "30", "-o", str(poses), "--plot",
                 str(tmp_path / "plan.png")]) == 0
    out = capsys.readouterr().out
    assert "PREDICTED 1σ" in out and "all six degrees of freedom" in out
    lines = poses.read_text().splitlines()
    assert lines[0].split(",") == Arm.from_robot("kinova").joint_names and len(lines) == 7
    assert (tmp_path / "plan.png").stat().st_size > 10_000
    # nothing is overwritten
    assert main(["plan", *common, "--candidates", "30", "-o", str(poses)]) == 1
    assert "exists" in capsys.readouterr().err
    assert main(["predict", *common, "--poses", str(poses)]) == 0
    exact = capsys.readouterr().out
    assert "PREDICTED 1σ" in exact and "the camera file's intrinsics exact" in exact
    # the intrinsics to be refined: a wider 1σ, and the words say what it assumes
    assert main(["predict", *common, "--poses", str(poses), "--refine-intrinsics", "--intrinsics-sigma", "0.02",
                 "5"]) == 0
    freed = capsys.readouterr().out
    assert "the intrinsics refined with the pose (fx, fy, cx, cy free under a prior of 2 % and 5 px)" in freed
    sigmas = [re.search(r"translation ([\d.]+), ([\d.]+), ([\d.]+) mm", text).groups() for text in (exact, freed)]
    assert all(float(b) > float(a) for a, b in zip(*sigmas, strict=True))
    assert main(["predict", *common, "--poses", str(poses), "--refine-intrinsics", "--intrinsics-sigma", "0",
                 "5"]) == 1
    assert "--intrinsics-sigma FOCAL_FRACTION PX must be two positive numbers" in capsys.readouterr().err
    assert main(["predict", *common, "--poses", str(poses), "--refine-intrinsics", "--intrinsics-sigma", "5",
                 "20"]) == 1  # 5 % typed as 5
    assert "a fraction of the focal length (0.05 for 5 %)" in capsys.readouterr().err
    assert main(["predict", *common, "--poses", str(poses), "--intrinsics-sigma", "0.02", "5"]) == 1
    assert "--intrinsics-sigma applies with --refine-intrinsics only" in capsys.readouterr().err
    # the joint offsets to be refined too: wider still, and said
    assert main(["predict", *common, "--poses", str(poses), "--refine-intrinsics", "--intrinsics-sigma", "0.02",
                 "5", "--joint-offsets", "--joint-offset-sigma-deg", "0.5"]) == 0
    both = capsys.readouterr().out
    assert "joint offsets refined (every joint between the first and the spinning one free under a prior of " \
           "0.5°)" in both
    more = re.search(r"translation ([\d.]+), ([\d.]+), ([\d.]+) mm", both).groups()
    assert all(float(b) > float(a) for a, b in zip(sigmas[1], more, strict=True))
    assert main(["predict", *common, "--poses", str(poses), "--joint-offset-sigma-deg", "0.5"]) == 1
    assert "--joint-offset-sigma-deg applies with --joint-offsets only" in capsys.readouterr().err
    assert main(["predict", *common, "--poses", str(poses), "--joint-offsets", "no_such_joint"]) == 1
    assert "no_such_joint" in capsys.readouterr().err
    # one pose is never enough: plan says so (exit 3), predict calls it degenerate
    assert main(["plan", *common, "-n", "1", "--candidates", "20", "-o", str(tmp_path / "one_planned.csv")]) == 3
    assert "NOT ENOUGH" in capsys.readouterr().out
    # a guess in millimetres is refused at once; a poses file in degrees is named with its hint
    millimetres = ["-450", "250", "950", "125.6", "0", "72.6"]
    assert main(["predict", "--robot", "kinova", "--camera", str(camera), "--camera-guess", *millimetres,
                 "--poses", str(poses)]) == 1
    assert "X Y Z are metres" in capsys.readouterr().err
    panda = Arm.from_robot("panda")
    degrees = tmp_path / "degrees.csv"
    degrees.write_text(",".join(panda.joint_names) + "\n10,-20,30,-100,5,90,45\n")
    assert main(["predict", "--robot", "panda", "--camera", str(camera), "--camera-guess", "1.1", "-0.4", "0.8",
                 "-118", "0", "-60", "--poses", str(degrees)]) == 1
    err = capsys.readouterr().err
    assert "pose 0" in err and "degrees" in err
    assert main(["plan", *common, "--guess-sigma", "-30", "3", "-o", str(tmp_path / "x.csv")]) == 1
    assert "--guess-sigma must be" in capsys.readouterr().err
    # a degenerate set: one pose only
    one = tmp_path / "one.csv"
    one.write_text("\n".join(lines[:2]) + "\n")
    assert main(["predict", *common, "--poses", str(one)]) == 3
    assert "DEGENERATE" in capsys.readouterr().out


def test_report_of_a_single_crossing_gives_the_pose_to_add(kinova):
    from gtsam_rotid.estimate import calibrate
    from gtsam_rotid.report import make_report

    dataset, truth = simulate.single_crossing_scene(seed=1, duration=6.0)
    result = calibrate(dataset)
    assert not result.observability.is_observable
    report = make_report(result, dataset)
    assert report.next_pose is not None and list(report.next_pose) == kinova.joint_names
    assert "the arm pose that helps most" in report.suggestion
    assert report.to_dict()["observability"]["next_pose_rad"] == report.next_pose
    # with that pose added, the poses determine the calibration (predicted at the truth)
    poses = [m.joint_angles for m in truth.measurements] + [np.array(list(report.next_pose.values()))]
    after = predict_accuracy(kinova, dataset.camera, truth.arm_T_camera, poses, QUICK.with_(guess_samples=1))
    assert after.observability.is_observable
    assert make_report(result, dataset, next_pose=False).next_pose is None


def test_cli_plan_next_pose_for_a_recorded_dataset(tmp_path, capsys):
    recorded = tmp_path / "recorded"
    assert main(["simulate", "--scene", "single-crossing", "--duration", "6", "-o", str(recorded)]) == 0
    capsys.readouterr()
    guess = ["-0.45", "0.25", "0.95", "125.6", "0", "72.6"]
    out = tmp_path / "next.csv"
    assert main(["plan", "--dataset", str(recorded), "--camera-guess", *guess, "--candidates", "30",
                 "--no-progress", "-o", str(out), "--plot", str(tmp_path / "next.png")]) == 0
    assert (tmp_path / "next.png").stat().st_size > 10_000
    printed = capsys.readouterr().out
    assert "goes from not determined to" in printed and "all six degrees of freedom" in printed
    assert "PREDICTED 1σ from 1 new pose(s) and what is already recorded" in printed
    assert len(out.read_text().splitlines()) == 2  # header and one pose


def test_spins_of_two_joints_are_predicted_and_planned(kinova, collisions):
    """Spins of joints 5 and 6 at every pose (``PlanOptions.spin_joints``): the prediction against the independent
    bound of a simulated scene with those spins; a plan whose poses the simulator accepts with both spins (the
    hand's whole swing in view); and with the Jaco2's collision hulls, the refusal that names the swing."""
    from accuracy import crlb_rigid

    j5, j6 = kinova.joint_names[4:6]
    config = simulate.SceneConfig(duration=20.0, spin_joints=(j5, j6))
    dataset, truth = simulate.simulate(config, seed=0, arm=kinova)
    bound = np.sqrt(np.diag(crlb_rigid(dataset, truth, 1.5)))
    poses = [truth.measurements[k].joint_angles for k in range(0, len(dataset), 2)]
    both = predict_accuracy(kinova, dataset.camera, truth.arm_T_camera, poses,
                            QUICK.with_(guess_samples=1, spin_joints=(j5, j6)))
    ratio = np.sqrt(np.diag(both.covariance)) / bound
    assert np.all((ratio > 0.85) & (ratio < 1.15)), ratio  # random features against evenly spread ones
    wrist = predict_accuracy(kinova, dataset.camera, truth.arm_T_camera, poses, QUICK.with_(guess_samples=1))
    assert np.all(np.diag(wrist.covariance) > 1.5 * np.diag(both.covariance))

    plan = plan_poses(kinova, dataset.camera, truth.arm_T_camera, 6, QUICK.with_(spin_joints=(j5, j6)),
                      collisions=None)
    recorded, _ = simulate.simulate(config.with_(joint_angles=tuple(tuple(q) for q in plan.joint_angles)), seed=1,
                                    arm=kinova)  # (SimulationError if a swing left the image)
    assert [m.spin_joint for m in recorded] == [j5, j6] * 6
    with pytest.raises(PlanningError, match=f"during the {j5} spin"):
        plan_poses(kinova, dataset.camera, truth.arm_T_camera, 6,
                   QUICK.with_(spin_joints=(j5, j6), max_draws=3000), collisions=collisions)


def test_refusals_are_counted_by_kind_in_words_not_templates():
    """A pose's problem says its numbers in brackets (what was found, what is allowed); the plan counts refusals by
    the words alone, so that "axis at # deg" does not stand for two opposite problems."""
    from gtsam_rotid.planning import _reason
    from gtsam_rotid.simulate import _view_problem

    along, across = _view_problem(12.0, (25.0, 75.0)), _view_problem(80.0, (25.0, 75.0))
    assert along == "nearly along the viewing ray (12 deg; 25-75 deg allowed)"
    assert _reason(f"axis {along}") == "axis nearly along the viewing ray"
    assert _reason(f"axis {across}") == "axis nearly across the viewing ray (its circles seen edge-on)"
    assert _reason("wrist too far from the camera (1.85 m; 0.5-1.6 m allowed)") == "wrist too far from the camera"
    assert _reason("self-collision of link_3 and link_5") == "self-collision of link_3 and link_5"
    assert _reason("something 3 times off") == "something # times off"

"""Poses planned for a calibration that refines the intrinsics (issue 17 item 3's target): the pose's predicted 1σ
with fx, fy, cx, cy free under their prior (5 % / 20 px), against the exact model's.

The Jaco2 scene of ``benchmarks/refinement.py`` (the simulator's camera and placement, 12 s spins, 1.5 px² noise).
References: (a) the usual recording, the exact-model prediction of the first six poses of five simulated scenes
(median per axis: the reference of the refinement benchmark's target); (b) six poses planned for the exact model.
For each pose count: poses planned with ``PlanOptions(refine_intrinsics=True)`` (``plan --refine-intrinsics``) and,
for comparison, the simulator's poses, each predicted with the intrinsics free; printed as ratios to (a) and (b).
``--confirm N --seeds K``: the scene simulated at the N planned poses, calibrated with the camera file 3 % long in
focal length and 10 px off in cx and the intrinsics refined, over K seeds: RMSE against the prediction, and NEES.
``--offsets-deg D``: the joint offsets too (issue 17's target with both): poses planned with
``PlanOptions(joint_offsets=True)`` as well (prior 1°), every prediction with the offsets free, and the confirming
scenes' readings of every joint before the wrist D° off its zero (random signs), calibrated with the offsets refined.

Run: ``python benchmarks/planning_intrinsics.py [--counts 12,24,36] [--confirm 12 --seeds 10] [--offsets-deg 0.5]``
(4 min for the predictions on one core; about 1 min per confirming calibration at 12 poses).
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

AXES = ("rx", "ry", "rz", "tx", "ty", "tz")
UNITS = np.array([math.degrees(1.0)] * 3 + [1000.0] * 3)


def main(argv=None) -> int:
    from ambient import relaxed
    from refinement import offset_readings

    from gtsam_rotid.arm import Arm
    from gtsam_rotid.calibration import CalibrationOptions
    from gtsam_rotid.errors import RotIdError
    from gtsam_rotid.estimate import calibrate
    from gtsam_rotid.geometry import look_at
    from gtsam_rotid.planning import PlanOptions, plan_poses, predict_accuracy
    from gtsam_rotid.simulate import SceneConfig, simulate

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--counts", default="12,24,36", help="pose counts to plan (comma-separated)")
    parser.add_argument("--scenes", type=int, default=5, help="simulated scenes of the usual recording's reference")
    parser.add_argument("--confirm", type=int, default=None, metavar="N", help="simulate and calibrate at N poses")
    parser.add_argument("--seeds", type=int, default=10)
    parser.add_argument("--offsets-deg", type=float, default=0.0,
                        help="plan and predict with the joint offsets free too; the confirming readings this far off")
    args = parser.parse_args(argv)
    with_offsets = args.offsets_deg > 0
    counts = [int(c) for c in args.counts.split(",")]
    if args.confirm is not None and args.confirm not in counts:
        counts.append(args.confirm)
    config = SceneConfig(robot="kinova", duration=12.0, noise_var=1.5)
    truth = look_at(config.camera_eye, config.camera_target, config.camera_up)
    arm = Arm.from_robot("kinova")

    def options(refine: bool) -> PlanOptions:
        return PlanOptions(pixel_sigma=math.sqrt(config.noise_var), axis_floor_px=0.0, depth_range=config.depth_range,
                           radius_range=config.radius_range, offset_range=config.offset_range,
                           respect_wrist_limits=False, spin_seconds=config.duration, jobs=1, search_seconds=None,
                           refine_intrinsics=refine, joint_offsets=refine and with_offsets)

    def sigma(poses, refine: bool) -> np.ndarray:
        return predict_accuracy(arm, config.camera, truth, poses, options(refine)).sigma

    start = time.perf_counter()
    usual = np.median([sigma([simulate(config, seed=s, arm=arm)[0].joint_angles(k) for k in range(6)], False)
                       for s in range(args.scenes)], axis=0)
    planned6 = sigma(plan_poses(arm, config.camera, truth, 6, options(False)).joint_angles, False)
    free_words = "intrinsics free under 5 % / 20 px" + (" and joint offsets under 1 deg" if with_offsets else "")
    freed = "intrinsics and offsets free" if with_offsets else "intrinsics free"
    print(f"Jaco2, 12 s spins, 1.5 px^2; {free_words}; predicted 1 sigma (deg, mm camera frame)")
    print(f"{'(a) usual recording, 6 poses, exact':54s} " + " ".join(f"{x:8.4f}" for x in usual))
    print(f"{'(b) 6 planned poses, exact':54s} " + " ".join(f"{x:8.4f}" for x in planned6))
    print(f"{'':54s} " + " ".join(f"{a:>8s}" for a in AXES))
    plans = {}
    for n in counts:
        plan = plan_poses(arm, config.camera, truth, n, options(True))
        plans[n] = plan.joint_angles
        free = plan.prediction.sigma
        sims = []
        for s in range(args.scenes):
            try:
                sims.append(sigma([simulate(config.with_(n_measurements=n), seed=s, arm=arm)[0].joint_angles(k)
                                   for k in range(n)], True))
            except RotIdError:  # the sampler finds too few poses in view
                pass
        print(f"{n} poses planned, {freed} / (a)".ljust(54) + " " + " ".join(f"{x:8.2f}" for x in free / usual)
              + f"   max {np.max(free / usual):.2f}")
        print(f"{n} poses planned, {freed} / (b)".ljust(54) + " "
              + " ".join(f"{x:8.2f}" for x in free / planned6) + f"   max {np.max(free / planned6):.2f}")
        if sims:
            sim = np.median(sims, axis=0)
            print(f"{n} simulated poses, {freed} / (a)".ljust(54) + " "
                  + " ".join(f"{x:8.2f}" for x in sim / usual) + f"   max {np.max(sim / usual):.2f}")
        print(f"  ({time.perf_counter() - start:.0f} s)", flush=True)
    if args.confirm is None:
        return 0
    n = args.confirm
    poses = plans[n]
    predicted = sigma(poses, True)
    scene = relaxed(config).with_(joint_angles=tuple(tuple(q) for q in poses), n_measurements=len(poses))
    errors, chi2, offsets_chi2, flagged, refused = [], [], [], 0, 0
    for seed in range(args.seeds):
        dataset, scene_truth = simulate(scene, seed=1000 + seed, arm=arm)
        readings, joints, offsets = offset_readings(dataset, dataset.camera.with_intrinsics_changed(1.03, 10.0),
                                                    args.offsets_deg, seed)
        try:
            result = calibrate(readings, options=CalibrationOptions(refine_intrinsics=True,
                                                                    joint_offsets=True if with_offsets else None))
        except RotIdError:
            refused += 1
            continue
        e = result.error_to(scene_truth.arm_T_camera)
        flagged += not result.covariance_usable
        if not result.covariance_usable:
            continue
        errors.append(e * UNITS)
        chi2.append(float(e @ np.linalg.solve(result.covariance, e)))
        if with_offsets:
            miss = np.array(list(result.joint_offsets.values())) - offsets
            offsets_chi2.append(float(miss @ np.linalg.solve(result.joint_offsets_covariance, miss)))
    rmse = np.sqrt(np.mean(np.square(errors), axis=0))
    print(f"\nconfirmed at the {n} planned poses: {len(errors) + flagged} calibrated ({flagged} not usable), {refused} "
          f"refused; camera file focal +3 %, cx +10 px, intrinsics refined"
          + (f"; readings {args.offsets_deg:g} deg off, offsets refined" if with_offsets else ""))
    if not errors:
        return 0
    print(f"{'RMSE':54s} " + " ".join(f"{x:8.4f}" for x in rmse))
    print(f"{'RMSE / predicted':54s} " + " ".join(f"{x:8.2f}" for x in rmse / predicted))
    print(f"{'RMSE / (a)':54s} " + " ".join(f"{x:8.2f}" for x in rmse / usual))
    print(f"NEES pose {np.mean(chi2):.2f} over {len(chi2)} usable"
          + (f"; offsets {np.mean(offsets_chi2):.2f} ({len(joints)} dof)" if offsets_chi2 else "")
          + f"  ({time.perf_counter() - start:.0f} s)")
    return 0


if __name__ == "__main__":
    sys.exit(main())

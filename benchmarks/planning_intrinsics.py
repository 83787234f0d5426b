"""Poses planned for a calibration that refines the intrinsics (issue 17 item 3's target): the pose's predicted 1σ
with fx, fy, cx, cy free under their prior (5 % / 20 px), against the exact model's.

The Jaco2 scene of ``benchmarks/refinement.py`` (the simulator's camera and placement, 12 s spins, 1.5 px² noise).
References: (a) the usual recording, the exact-model prediction of the first six poses of five simulated scenes
(median per axis: the reference of the refinement benchmark's target); (b) six poses planned for the exact model.
For each pose count: poses planned with ``PlanOptions(refine_intrinsics=True)`` (``plan --refine-intrinsics``) and,
for comparison, the simulator's poses, each predicted with the intrinsics free; printed as ratios to (a) and (b).
``--confirm N --seeds K``: the scene simulated at the N planned poses, calibrated with the camera file 3 % long in
focal length and 10 px off in cx and the intrinsics refined, over K seeds: RMSE against the prediction, and NEES.

Run: ``python benchmarks/planning_intrinsics.py [--counts 12,24,36] [--confirm 12 --seeds 10]`` (4 min for the
predictions on one core; about 1 min per confirming calibration at 12 poses).
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

    from gtsam_rotid.arm import Arm
    from gtsam_rotid.calibration import CalibrationOptions
    from gtsam_rotid.dataset import Dataset
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
    args = parser.parse_args(argv)
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
                           refine_intrinsics=refine)

    def sigma(poses, refine: bool) -> np.ndarray:
        return predict_accuracy(arm, config.camera, truth, poses, options(refine)).sigma

    start = time.perf_counter()
    usual = np.median([sigma([simulate(config, seed=s, arm=arm)[0].joint_angles(k) for k in range(6)], False)
                       for s in range(args.scenes)], axis=0)
    planned6 = sigma(plan_poses(arm, config.camera, truth, 6, options(False)).joint_angles, False)
    print("Jaco2, 12 s spins, 1.5 px^2; intrinsics free under 5 % / 20 px; predicted 1 sigma (deg, mm camera frame)")
    print(f"{'(a) usual recording, 6 poses, exact':44s} " + " ".join(f"{x:8.4f}" for x in usual))
    print(f"{'(b) 6 planned poses, exact':44s} " + " ".join(f"{x:8.4f}" for x in planned6))
    print(f"{'':44s} " + " ".join(f"{a:>8s}" for a in AXES))
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
        print(f"{n} poses planned, intrinsics free / (a)".ljust(44) + " " + " ".join(f"{x:8.2f}" for x in free / usual)
              + f"   max {np.max(free / usual):.2f}")
        print(f"{n} poses planned, intrinsics free / (b)".ljust(44) + " "
              + " ".join(f"{x:8.2f}" for x in free / planned6) + f"   max {np.max(free / planned6):.2f}")
        if sims:
            sim = np.median(sims, axis=0)
            print(f"{n} simulated poses, intrinsics free / (a)".ljust(44) + " "
                  + " ".join(f"{x:8.2f}" for x in sim / usual) + f"   max {np.max(sim / usual):.2f}")
        print(f"  ({time.perf_counter() - start:.0f} s)", flush=True)
    if args.confirm is None:
        return 0
    n = args.confirm
    poses = plans[n]
    predicted = sigma(poses, True)
    scene = relaxed(config).with_(joint_angles=tuple(tuple(q) for q in poses), n_measurements=len(poses))
    errors, chi2, flagged, refused = [], [], 0, 0
    for seed in range(args.seeds):
        dataset, scene_truth = simulate(scene, seed=1000 + seed, arm=arm)
        readings = Dataset(arm, dataset.camera.with_intrinsics_changed(1.03, 10.0), list(dataset))
        try:
            result = calibrate(readings, options=CalibrationOptions(refine_intrinsics=True))
        except RotIdError:
            refused += 1
            continue
        e = result.error_to(scene_truth.arm_T_camera)
        errors.append(e * UNITS)
        chi2.append(float(e @ np.linalg.solve(result.covariance, e)))
        flagged += not result.covariance_usable
    rmse = np.sqrt(np.mean(np.square(errors), axis=0))
    print(f"\nconfirmed at the {n} planned poses: {len(errors)} calibrated ({flagged} not usable), {refused} refused; "
          f"camera file focal +3 %, cx +10 px, intrinsics refined")
    print(f"{'RMSE':44s} " + " ".join(f"{x:8.4f}" for x in rmse))
    print(f"{'RMSE / predicted':44s} " + " ".join(f"{x:8.2f}" for x in rmse / predicted))
    print(f"{'RMSE / (a)':44s} " + " ".join(f"{x:8.2f}" for x in rmse / usual))
    print(f"NEES pose {np.mean(chi2):.2f} over {len(chi2)}  ({time.perf_counter() - start:.0f} s)")
    return 0


if __name__ == "__main__":
    sys.exit(main())

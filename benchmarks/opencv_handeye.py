"""Target-free against target-based: ours against OpenCV's hand-eye calibration with a checkerboard (issue 6).

The same arm poses (the reference scene's, ``--scene-seed``) and the same pixel noise (``--noise-var`` px² per
pixel coordinate). Ours: the wrist spins (``--duration`` s per pose) and ``calibrate`` (``joint``) uses the tracks
of the end effector's own features. OpenCV's: a 9x6 checkerboard (15 mm squares) is mounted on the wrist like a
flag (its plane contains the wrist axis, its centre 6 cm from the axis and 5 cm along it); at each arm pose the
wrist angle is chosen to face the board to the camera (the same joint angles otherwise), its corners are
projected and noised, ``cv2.solvePnP`` gives the board pose in the camera, and the camera pose in the arm base
comes from ``cv2.calibrateHandEye`` (eye-to-hand: the base-to-gripper transforms are passed; all five methods)
and ``cv2.calibrateRobotWorldHandEye`` (Shah, Li). ``--board-frames F`` averages F images of the still board per
pose (noise / sqrt(F)): with one image per pose OpenCV sees 6 x 54 corner pixels against our ~56 000 track pixels;
``--board-frames 1800`` gives it as many images per pose as a 60 s spin has frames.

Printed: RMS position error (mm) and rotation error (deg) over ``--trials`` Monte Carlo trials for ours and every
OpenCV method, and our error divided by each OpenCV method's (below 1: the target-free calibration is more
accurate). Run: ``python benchmarks/opencv_handeye.py [--trials 20] [--duration 60] [--noise-var 1.5]
[--board-frames 1] [--scene-seed 0]``.
"""

from __future__ import annotations

import argparse
import time

import cv2
import gtsam
import numpy as np
from tqdm import tqdm

from gtsam_rotid import simulate
from gtsam_rotid.errors import RotIdError
from gtsam_rotid.estimate import calibrate
from gtsam_rotid.geometry import perpendicular_basis

HAND_EYE = {"Tsai": cv2.CALIB_HAND_EYE_TSAI, "Park": cv2.CALIB_HAND_EYE_PARK, "Horaud": cv2.CALIB_HAND_EYE_HORAUD,
            "Andreff": cv2.CALIB_HAND_EYE_ANDREFF, "Daniilidis": cv2.CALIB_HAND_EYE_DANIILIDIS}
ROBOT_WORLD = {"RW-Shah": cv2.CALIB_ROBOT_WORLD_HAND_EYE_SHAH, "RW-Li": cv2.CALIB_ROBOT_WORLD_HAND_EYE_LI}
BOARD_CORNERS = (9, 6)
SQUARE_M = 0.015
#: the board's centre: this far from the wrist axis (m), and this far along it
BOARD_RADIUS_M = 0.06
BOARD_OFFSET_M = 0.05
#: the board must face the camera at least this much (cosine of the angle between its normal and the view ray)
MIN_FACING = 0.3


def board_points() -> np.ndarray:
    """(N, 3) corner coordinates in the board frame (z = 0 plane, centred)."""
    nx, ny = BOARD_CORNERS
    i, j = np.meshgrid(np.arange(nx) - (nx - 1) / 2, np.arange(ny) - (ny - 1) / 2)
    return np.column_stack([i.ravel() * SQUARE_M, j.ravel() * SQUARE_M, np.zeros(nx * ny)])


def wrist_T_board(arm) -> gtsam.Pose3:
    """The board mount in the wrist joint's frame: its plane contains the axis, its normal points outward."""
    a = arm.wrist_axis_local()
    e1, e2 = perpendicular_basis(a)
    x = np.cross(a, e1)  # x = y cross z with y = a, z = e1: a right-handed frame
    R = np.column_stack([x, a, e1])
    return gtsam.Pose3(gtsam.Rot3(R), BOARD_RADIUS_M * e1 + BOARD_OFFSET_M * a)


def facing_pose(arm, camera, arm_T_camera, q, mount) -> tuple[np.ndarray, float] | None:
    """The joint angles ``q`` with the wrist angle that best faces the board to the camera (all corners in the
    image), and that facing; None if no wrist angle shows the whole board."""
    wrist = arm.dof - 1
    lo, hi = arm.lower_limits[wrist], arm.upper_limits[wrist]
    lo, hi = max(lo, -np.pi), min(hi, np.pi)
    camera_T_arm = arm_T_camera.inverse()
    centre = np.asarray(arm_T_camera.translation())
    best = None
    for angle in np.linspace(lo, hi, 145):
        trial = np.array(q, dtype=float)
        trial[wrist] = angle
        arm_T_board = arm.arm_T_wrist(trial).compose(mount)
        normal = arm_T_board.rotation().matrix()[:, 2]
        ray = centre - np.asarray(arm_T_board.translation())
        facing = float(normal @ ray / np.linalg.norm(ray))
        if facing < MIN_FACING or (best is not None and facing <= best[1]):
            continue
        points = np.array([camera_T_arm.transformFrom(arm_T_board.transformFrom(p)) for p in board_points()])
        if np.all(points[:, 2] > 0) and np.all(camera.in_image(camera.project(points), 10.0)):
            best = (trial, facing)
    return best


def opencv_trial(arm, camera, arm_T_camera, poses, mount, sigma_px, rng) -> dict[str, gtsam.Pose3]:
    """arm_T_camera from noisy checkerboard views by every OpenCV method."""
    camera_T_arm = arm_T_camera.inverse()
    object_points = board_points()
    R_base2gripper, t_base2gripper, R_target2cam, t_target2cam = [], [], [], []
    for q in poses:
        arm_T_wrist = arm.arm_T_wrist(q)
        arm_T_board = arm_T_wrist.compose(mount)
        points = np.array([camera_T_arm.transformFrom(arm_T_board.transformFrom(p)) for p in object_points])
        pixels = camera.project(points) + rng.normal(0.0, sigma_px, size=(len(points), 2))
        ok, rvec, tvec = cv2.solvePnP(object_points, pixels, camera.K, camera.dist, flags=cv2.SOLVEPNP_ITERATIVE)
        if not ok:
            raise RuntimeError("solvePnP failed")
        R_target2cam.append(cv2.Rodrigues(rvec)[0])
        t_target2cam.append(tvec.reshape(3))
        wrist_T_arm = arm_T_wrist.inverse()
        R_base2gripper.append(wrist_T_arm.rotation().matrix())
        t_base2gripper.append(np.asarray(wrist_T_arm.translation()))
    out = {}
    for name, method in HAND_EYE.items():  # eye-to-hand: base2gripper in, cam2base out
        R, t = cv2.calibrateHandEye(R_base2gripper, t_base2gripper, R_target2cam, t_target2cam, method=method)
        out[name] = gtsam.Pose3(gtsam.Rot3(R), t.reshape(3))
    # robot-world-hand-eye, with the roles of the fixed camera and the board swapped: OpenCV's "camera" is the
    # board (on the gripper), its "world" is our camera (fixed in the base frame)
    R_board_T_camera = [R.T for R in R_target2cam]
    t_board_T_camera = [-R.T @ t for R, t in zip(R_target2cam, t_target2cam, strict=True)]
    for name, method in ROBOT_WORLD.items():
        R_b2w, t_b2w, _, _ = cv2.calibrateRobotWorldHandEye(R_board_T_camera, t_board_T_camera, R_base2gripper,
                                                            t_base2gripper, method=method)
        out[name] = gtsam.Pose3(gtsam.Rot3(R_b2w), t_b2w.reshape(3)).inverse()  # base2world = camera_T_arm
    return out


def errors(estimate: gtsam.Pose3, truth: gtsam.Pose3) -> tuple[float, float]:
    """(position error mm, rotation error deg)."""
    p = 1000.0 * float(np.linalg.norm(np.asarray(estimate.translation()) - np.asarray(truth.translation())))
    r = float(np.degrees(np.linalg.norm(truth.rotation().localCoordinates(estimate.rotation()))))
    return p, r


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--trials", type=int, default=20)
    parser.add_argument("--duration", type=float, default=60.0, help="seconds of spin per pose (ours)")
    parser.add_argument("--noise-var", type=float, default=1.5, help="pixel noise variance, px^2 (both)")
    parser.add_argument("--board-frames", type=int, default=1, help="images of the still board averaged per pose")
    parser.add_argument("--scene-seed", type=int, default=0, help="seed of the reference scene's arm poses")
    parser.add_argument("--first-seed", type=int, default=1000)
    args = parser.parse_args(argv)

    dataset, scene = simulate.reference_scene(seed=args.scene_seed, duration=1.0, min_track_length=2)
    arm, camera, arm_T_camera = dataset.arm, dataset.camera, scene.arm_T_camera
    joint_angles = [m.joint_angles for m in scene.measurements]
    mount = wrist_T_board(arm)
    board_poses = []
    for k, q in enumerate(joint_angles):
        found = facing_pose(arm, camera, arm_T_camera, q, mount)
        if found is None:
            print(f"pose {k}: no wrist angle shows the whole checkerboard; left out of OpenCV's data")
            continue
        board_poses.append(found[0])
    print(f"reference scene (arm poses of seed {args.scene_seed}): ours {len(joint_angles)} spins of "
          f"{args.duration:g} s; OpenCV {len(board_poses)} views of a {BOARD_CORNERS[0]}x{BOARD_CORNERS[1]} "
          f"checkerboard ({SQUARE_M * 1000:g} mm squares) x {args.board_frames} image(s) each; "
          f"sigma^2 = {args.noise_var} px^2; {args.trials} trials")
    if len(board_poses) < 3:
        print("fewer than 3 board views: OpenCV's hand-eye calibration needs at least 3")
        return 1
    sigma_board = np.sqrt(args.noise_var / args.board_frames)
    results: dict[str, list[tuple[float, float]]] = {"ours (joint)": []}
    failures = 0
    start = time.perf_counter()
    for i in tqdm(range(args.trials), desc="trials", unit="trial"):
        seed = args.first_seed + i
        data, truth = simulate.reference_scene(seed=seed, noise_var=args.noise_var, duration=args.duration,
                                               joint_angles=tuple(tuple(q) for q in joint_angles))
        try:
            results["ours (joint)"].append(errors(calibrate(data).arm_T_camera, truth.arm_T_camera))
        except RotIdError:
            failures += 1
        rng = np.random.default_rng(seed)
        for name, pose in opencv_trial(arm, camera, arm_T_camera, board_poses, mount, sigma_board, rng).items():
            results.setdefault(name, []).append(errors(pose, arm_T_camera))
    print(f"{time.perf_counter() - start:.0f} s" + (f"; ours failed in {failures} trials" if failures else ""))
    rms = {name: np.sqrt(np.mean(np.square(v), axis=0)) for name, v in results.items() if v}
    ours = rms.get("ours (joint)")
    print(f"\n{'method':16}{'RMS pos mm':>12}{'RMS rot deg':>13}{'ours / it: pos':>16}{'rot':>8}")
    for name, (p, r) in rms.items():
        ratio = "" if ours is None else f"{ours[0] / p:16.3f}{ours[1] / r:8.3f}"
        print(f"{name:16}{p:12.3f}{r:13.4f}{ratio}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

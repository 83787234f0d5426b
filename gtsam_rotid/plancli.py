"""Command line of the planner: ``gtsam-rotid plan`` (arm poses that determine the calibration best) and
``gtsam-rotid predict`` (the accuracy of given poses), both before anything is recorded."""

from __future__ import annotations

import argparse
import math
import sys

import gtsam
import numpy as np

from .arm import Arm
from .calibration.options import DEFAULT_INTRINSICS_SIGMA, checked_intrinsics_sigma, checked_offset_sigma_deg
from .camerafiles import load_camera
from .dataset import Dataset
from .errors import InputError
from .files import check_output, write_text
from .planning import PlanOptions, dataset_information, plan_poses, predict_accuracy, predicted_spins
from .recordings import read_joint_file
from .words import plan_words, prediction_words

GUESS_HELP = ("the camera's OpenCV optical frame in the arm's root frame: X Y Z in metres, ROLL PITCH YAW in degrees "
              "with R = Rz(yaw) Ry(pitch) Rx(roll) (gtsam's Rot3.RzRyRx, the report's convention)")


def camera_guess(values) -> gtsam.Pose3:
    """``X Y Z ROLL PITCH YAW`` (m, degrees) -> ``arm_T_camera``."""
    x, y, z, roll, pitch, yaw = (float(v) for v in values)
    if not all(math.isfinite(v) for v in (x, y, z, roll, pitch, yaw)):
        raise InputError("--camera-guess: every value must be a finite number")
    return gtsam.Pose3(gtsam.Rot3.RzRyRx(*np.radians([roll, pitch, yaw])), np.array([x, y, z]))


def _add_common(p: argparse.ArgumentParser, *, dataset: bool) -> None:
    robot = p.add_mutually_exclusive_group(required=not dataset)
    robot.add_argument("--robot", metavar="NAME", help="example-robot-data arm (kinova, ur5, ur10, panda, xarm7)")
    robot.add_argument("--urdf", metavar="FILE", help="the arm's URDF (its <collision> meshes are used)")
    p.add_argument("--package-dir", action="append", default=[], metavar="DIR",
                   help="where the URDF's package:// mesh paths resolve (repeatable)")
    p.add_argument("--wrist-joint", metavar="NAME", help="the spinning joint (default: the last revolute joint)")
    p.add_argument("--spin-joints", nargs="+", default=(), metavar="NAME",
                   help="spin each of these joints at every pose, one spin each (default: the wrist only); a spin "
                        "of another joint must keep the whole swing of the hand in view and clear of the arm")
    p.add_argument("--refine-intrinsics", action="store_true",
                   help="the calibration will refine the intrinsics (calibrate --refine-intrinsics): predict and "
                        "choose for the pose with fx, fy, cx, cy free under the prior of --intrinsics-sigma")
    p.add_argument("--intrinsics-sigma", type=float, nargs=2, default=None, metavar=("FOCAL_FRACTION", "PX"),
                   help="with --refine-intrinsics: their prior 1 sigma about the camera file's, focal length as a "
                        "fraction of it and principal point in px (default {} {}, as calibrate's)".format(
                            *DEFAULT_INTRINSICS_SIGMA))
    p.add_argument("--joint-offsets", nargs="*", default=None, metavar="JOINT",
                   help="the calibration will refine these joints' zero offsets (calibrate --joint-offsets; no "
                        "names: every joint between the first and the spinning one): predict and choose for the "
                        "pose with them free under the prior of --joint-offset-sigma-deg")
    p.add_argument("--joint-offset-sigma-deg", type=float, default=None, metavar="DEG",
                   help="with --joint-offsets: their prior 1 sigma in degrees (default 1, as calibrate's)")
    p.add_argument("--camera", metavar="CAMERA_YAML", required=not dataset,
                   help="OpenCV calibration YAML or ROS camera_info YAML")
    p.add_argument("--camera-guess", nargs=6, type=float, required=True,
                   metavar=("X", "Y", "Z", "ROLL", "PITCH", "YAW"), help=GUESS_HELP)
    p.add_argument("--guess-sigma", nargs=2, type=float, default=(30.0, 3.0), metavar=("MM", "DEG"),
                   help="how far the guess may be off, 1 sigma per axis (default 30 mm, 3 deg): the prediction is "
                        "averaged over camera poses drawn from it and the constraints must hold at them")
    p.add_argument("--spin-seconds", type=float, default=20.0, metavar="S", help="seconds of spin per pose (20)")
    p.add_argument("--fps", type=float, default=30.0, help="camera frame rate (30)")
    p.add_argument("--wrist-speed", type=float, default=0.5, metavar="RAD_S", help="spin speed in rad/s (0.5)")
    p.add_argument("--pixel-sigma", type=float, default=0.5, metavar="PX",
                   help="noise of a tracked point in px (default 0.5)")
    p.add_argument("--axis-floor-px", type=float, default=PlanOptions.axis_floor_px, metavar="PX",
                   help=f"the tracker's floor on each spin's image axis (default {PlanOptions.axis_floor_px:g}: "
                        "the corner tracker's; 0 for simulated tracks)")
    p.add_argument("--features", type=int, default=12, metavar="N",
                   help="features on the end effector assumed (default 12, spread over the spinning links' "
                        "collision meshes)")
    p.add_argument("--floor-height", type=float, default=0.0, metavar="Z",
                   help="height (m, arm frame) of the floor or table no link may pass (default 0)")
    p.add_argument("--no-floor", action="store_true", help="no floor or table plane")
    p.add_argument("--depth-range", nargs=2, type=float, default=(0.5, 1.6), metavar=("NEAR", "FAR"),
                   help="workable camera-to-wrist distances in m (default 0.5 1.6)")
    p.add_argument("--no-collisions", action="store_true",
                   help="skip the collision and occlusion checks (a URDF without <collision> meshes)")
    p.add_argument("--plot", metavar="PNG", help="also draw the poses: axes and camera in 3-D, the predicted arcs")
    p.add_argument("--overwrite", action="store_true", help="replace existing output files")
    p.add_argument("--no-progress", action="store_true", help="no progress bars")


def add_plan_parsers(subparsers) -> None:
    """Add ``plan`` and ``predict`` to an ``argparse`` subparsers object."""
    p = subparsers.add_parser(
        "plan", help="choose the arm poses to record (before touching the robot), with their predicted accuracy",
        description="Choose arm poses that determine arm_T_camera best at a guess of the camera pose, subject to "
                    "the joint limits, no self-collision or floor contact (the robot's collision meshes), the "
                    "end effector inside the image and facing the camera at a workable distance, the spinning axis "
                    "neither end-on nor side-on, and the arm's other links not hiding the end effector. Writes a "
                    "CSV (a header row of the joint names, one row per pose, radians) that `track --joints` and "
                    "`predict --poses` read, and prints the predicted 1 sigma per axis. With --dataset: the next "
                    "best pose(s) to add to an existing recording (robot and camera from it, its spins counted at "
                    "their own pixel noise and its tracker's floor; the guess: its calibration's estimate). Exit "
                    "code 0: the poses determine the calibration; 3: they do not.")
    _add_common(p, dataset=True)
    p.add_argument("-n", type=int, default=None, metavar="N",
                   help="how many poses (default 6; 1 with --dataset: the next best pose)")
    p.add_argument("--dataset", metavar="DIR", help="an existing dataset: plan the pose(s) that most reduce the "
                                                    "worst 1 sigma of its calibration (robot and camera from it)")
    p.add_argument("--candidates", type=int, default=PlanOptions.candidates, metavar="N",
                   help=f"valid random poses to choose from (default {PlanOptions.candidates})")
    p.add_argument("--seed", type=int, default=0, help="random seed of the search (default 0)")
    p.add_argument("-o", "--output", required=True, metavar="POSES_CSV", help="the joint-angle file to write")
    p.set_defaults(func=cmd_plan)

    p = subparsers.add_parser(
        "predict", help="the predicted accuracy of given arm poses, before any recording",
        description="Predict the 1 sigma per axis of a calibration from these arm poses (a joint file: header row "
                    "of joint names, one row per pose, radians unless --degrees) and say whether they determine "
                    "all six degrees of freedom. Exit code 0: determined; 3: degenerate.")
    p.add_argument("--poses", required=True, metavar="FILE", help="joint-angle file (CSV or JSON), one row per pose")
    p.add_argument("--degrees", action="store_true", help="the pose file is in degrees")
    _add_common(p, dataset=False)
    p.set_defaults(func=cmd_predict)


def _options(args, **extra) -> PlanOptions:
    flags = {"--guess-sigma": min(args.guess_sigma), "--spin-seconds": args.spin_seconds, "--fps": args.fps,
             "--pixel-sigma": args.pixel_sigma, "--axis-floor-px": args.axis_floor_px, "--features": args.features}
    for flag, value in flags.items():
        strictly = flag in ("--spin-seconds", "--fps", "--pixel-sigma", "--features")
        if not math.isfinite(value) or value < 0 or (strictly and value == 0):
            raise InputError(f"{flag} must be a {'positive number' if strictly else 'number >= 0'}, got {value:g}")
    if args.intrinsics_sigma is not None and not args.refine_intrinsics:
        raise InputError("--intrinsics-sigma applies with --refine-intrinsics only (without it the camera file's "
                         "intrinsics are taken as exact)")
    if args.joint_offset_sigma_deg is not None and args.joint_offsets is None:
        raise InputError("--joint-offset-sigma-deg applies with --joint-offsets only (without it the joint readings' "
                         "zeros are taken as exact)")
    offset_sigma = checked_offset_sigma_deg(1.0 if args.joint_offset_sigma_deg is None
                                            else args.joint_offset_sigma_deg, "--joint-offset-sigma-deg")
    extra.setdefault("joint_offsets", False if args.joint_offsets is None else (tuple(args.joint_offsets) or True))
    sigma = checked_intrinsics_sigma(DEFAULT_INTRINSICS_SIGMA if args.intrinsics_sigma is None
                                     else tuple(args.intrinsics_sigma), "--intrinsics-sigma FOCAL_FRACTION PX")
    if not 0 <= args.depth_range[0] < args.depth_range[1]:
        raise InputError(f"--depth-range NEAR FAR must have 0 <= NEAR < FAR (m), got {args.depth_range}")
    options = PlanOptions(spin_seconds=args.spin_seconds, fps=args.fps, wrist_speed=args.wrist_speed,
                          pixel_sigma=args.pixel_sigma, axis_floor_px=args.axis_floor_px, n_features=args.features,
                          floor_height=None if args.no_floor else args.floor_height,
                          depth_range=tuple(args.depth_range), guess_sigma_mm=args.guess_sigma[0],
                          guess_sigma_deg=args.guess_sigma[1], spin_joints=tuple(args.spin_joints),
                          refine_intrinsics=bool(args.refine_intrinsics), intrinsics_sigma=sigma,
                          joint_offset_sigma_deg=offset_sigma, **extra)
    options.check()
    return options


def _arm(args) -> Arm:
    if args.urdf:
        return Arm.from_urdf(args.urdf, wrist_joint=args.wrist_joint)
    return Arm.from_robot(args.robot, wrist_joint=args.wrist_joint)


def _collisions(args, arm, options):
    from .collisions import ArmCollisions
    from .errors import ArmError

    if args.no_collisions:
        return None
    try:
        return ArmCollisions(arm, args.package_dir, options.floor_height)
    except ArmError as error:
        raise ArmError(f"{error}; --no-collisions plans without collision and occlusion checks") from None


def _progress(args):
    if args.no_progress:
        return None
    from tqdm import tqdm

    bars: dict = {}

    def update(stage: str, done: int, total: int) -> None:
        bar = bars.get(stage)
        if bar is None:
            bar = bars[stage] = tqdm(total=total, desc=stage, unit="pose", file=sys.stderr, leave=False)
        bar.update(done - bar.n)
        if done >= total:
            bar.close()
    return update


def _plot(args, arm, camera, prediction, recorded=()) -> None:
    from .files import staged
    from .planplots import plot_plan
    from .plots import DPI

    figure = plot_plan(arm, camera, prediction, predicted_spins(arm, camera, prediction.arm_T_camera,
                                                                prediction.joint_angles, prediction.options),
                       recorded)
    with staged(args.plot, args.overwrite) as staging:
        figure.savefig(staging, dpi=DPI, format="png")
    print(f"drew {args.plot}")


def cmd_plan(args) -> int:
    output = check_output(args.output, args.overwrite)
    if args.plot:
        check_output(args.plot, args.overwrite)
    prior, recorded = None, []
    guess = camera_guess(args.camera_guess)
    options = _options(args, candidates=args.candidates, seed=args.seed)
    if args.dataset:
        dataset = Dataset.load(args.dataset)
        arm = dataset.arm
        if args.robot or args.urdf:
            given = _arm(args).description()
            differ = [k for k in ("name", "wrist_joint", "urdf_sha256") if given.get(k) != arm.description().get(k)]
            if differ:
                raise InputError(f"{args.dataset} was recorded with another robot model ("
                                 + ", ".join(f"{k}: {arm.description().get(k)!r}" for k in differ)
                                 + "); leave out --robot/--urdf to plan for the dataset's own")
        camera = load_camera(args.camera) if args.camera else dataset.camera
        prior = dataset_information(dataset, guess, options)
        recorded = [m.joint_angles for m in dataset]
        print(f"{args.dataset}: {len(dataset)} spin(s) recorded; planning what to add")
    else:
        if not (args.robot or args.urdf) or not args.camera:
            raise InputError("plan needs --robot or --urdf and --camera (or --dataset to take them from)")
        arm, camera = _arm(args), load_camera(args.camera)
    n = args.n if args.n is not None else (1 if args.dataset else 6)
    collisions = _collisions(args, arm, options)
    plan = plan_poses(arm, camera, guess, n, options, collisions=collisions, prior_information=prior,
                      progress=_progress(args))
    rows = [",".join(arm.joint_names)] + [",".join(repr(float(v)) for v in q) for q in plan.joint_angles]
    write_text(output, "\n".join(rows) + "\n", args.overwrite)
    print("\n".join(plan_words(plan)))
    print(f"wrote {len(plan.joint_angles)} pose(s) to {output} (radians, one row per pose)")
    if args.no_collisions:
        print("WARNING: no collision or occlusion check was made (--no-collisions)")
    if args.plot:
        _plot(args, arm, camera, plan.prediction, recorded)
    if not plan.prediction.observability.is_observable:
        print(f"NOT ENOUGH: the {n} pose(s) planned do not determine the calibration"
              + ("; one spin determines at most 3 of the 6 directions: plan three or more" if n < 3 and not
                 args.dataset else "; plan more poses (-n)"))
        return 3
    return 0


def cmd_predict(args) -> int:
    if args.plot:
        check_output(args.plot, args.overwrite)
    arm, camera = _arm(args), load_camera(args.camera)
    poses = read_joint_file(args.poses, arm, degrees=args.degrees)
    if poses.is_time_series:
        raise InputError(f"{args.poses}: a time series of joint states; predict reads one row per pose")
    for k, q in enumerate(poses.positions):
        problem = arm.limit_problem(q)
        if problem is not None:
            raise InputError(f"{args.poses}, pose {k}: {problem}")
    options = _options(args)
    collisions = _collisions(args, arm, options)
    prediction = predict_accuracy(arm, camera, camera_guess(args.camera_guess), list(poses.positions), options,
                                  collisions=collisions)
    print("\n".join(prediction_words(prediction)))
    if args.plot:
        _plot(args, arm, camera, prediction)
    return 0 if prediction.observability.is_observable else 3

"""Command line: ``gtsam-rotid {simulate,calibrate,demo,track,report,export,check,plan,predict}``; thin: parses,
calls the library."""

from __future__ import annotations

import argparse
import math
import os
import re
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import gtsam
import numpy as np

from . import __version__
from .arm import Arm
from .bagdataset import dataset_from_bag
from .dataset import Dataset
from .demo import DEMO_COVERING
from .errors import DatasetExistsError, InputError, OutputError, OutputExistsError, RotIdError
from .export import (
    DEFAULT_CHILD,
    JOINT_NAME,
    PARENT_FRAME,
    CameraFrame,
    Format,
    export_problems,
    export_result,
    load_result,
)
from .files import OVERWRITE_HINT, check_output, check_outputs, write_text
from .meshrender import COVERINGS
from .plancli import add_plan_parsers
from .recordings import MIN_SPIN_DEG, STILL_TOLERANCE_DEG, load_tracker_params, make_dataset, videos_in
from .report import ReportFormat, error_vs_truth_lines, make_report
from .words import summary

SCENES = ("reference", "single-crossing")
#: ``gtsam_rotid.estimate.Method`` values (kept literal so that ``--help`` does not import the estimator).
METHODS = ("joint", "weighted", "paper")
#: ``calibration.options.INTRINSICS`` and ``DEFAULT_INTRINSICS_SIGMA`` (literal for the same reason).
INTRINSICS = ("fx", "fy", "cx", "cy")
DEFAULT_INTRINSICS_SIGMA = (0.05, 20.0)
TRUTH_FILE = "truth.json"
DATASET_FILE = "dataset.json"
RESULT_FILE = "result.json"


def _simulate_scene(scene: str, seed: int, **changes):
    from . import simulate

    factory = {"reference": simulate.reference_scene, "single-crossing": simulate.single_crossing_scene}[scene]
    return factory(seed=seed, **changes)


def _scene_changes(args) -> dict:
    changes = {}
    for name in ("noise_var", "duration", "n_measurements", "outlier_fraction", "spin_ramp", "encoder_rate",
                 "encoder_sigma_deg", "encoder_time_offset"):
        value = getattr(args, name, None)
        if value is not None:
            changes[name] = value
    if getattr(args, "spin_joints", None):
        changes["spin_joints"] = tuple(args.spin_joints)
    return changes


def _check_not_input(output: Path, dataset_dir: Path) -> None:
    """Refuse a result path that is one of the dataset's own files (``calibrate`` reads them)."""
    from .dataset import SCHEMA_FILE, TRACKS_FILE, URDF_FILE

    own = (DATASET_FILE, TRACKS_FILE, URDF_FILE, SCHEMA_FILE, TRUTH_FILE)
    if output.resolve().parent == dataset_dir.resolve() and output.name in own:
        raise OutputError(f"{output} is a file of the dataset {dataset_dir} that calibrate reads; write the result "
                          f"elsewhere (e.g. {dataset_dir.parent / RESULT_FILE})")


def _save_result(result, path: Path, overwrite: bool) -> None:
    """``result.save`` (staged: the old file stays intact on failure; errors name the path)."""
    result.save(path, overwrite=overwrite)
    print(f"wrote {path}")


def _calibrate_timed(dataset, method: str, options=None):
    from .calibration import calibrate

    print(f"calibrating ({method})...", flush=True)
    start = time.perf_counter()
    result = calibrate(dataset, method=method, options=options)
    print(f"calibrated in {time.perf_counter() - start:.1f} s")
    return result


def _print_lines(lines) -> None:
    for line in lines:
        print(line)


def _load_truth(dataset_path: Path):
    """The ground truth ``simulate`` wrote next to the dataset, or None (with a warning if it is unreadable)."""
    from .simulate import GroundTruth

    root = dataset_path.parent if dataset_path.name == DATASET_FILE and dataset_path.is_file() else dataset_path
    path = root / TRUTH_FILE
    if not path.is_file():
        return None
    try:
        return GroundTruth.load(path)
    except (OSError, ValueError, KeyError, TypeError) as exc:
        print(f"gtsam-rotid: warning: ignoring {path}, which cannot be read as ground truth: {exc}",
              file=sys.stderr)
        return None


def cmd_simulate(args) -> int:
    dataset, truth = _simulate_scene(args.scene, args.seed, **_scene_changes(args))
    out = Path(args.output)
    dataset.save(out, overwrite=args.overwrite)
    truth.save(out / TRUTH_FILE, overwrite=True)
    print(dataset.summary())
    print(f"wrote {out} (ground truth in {out / TRUTH_FILE})")
    return 0


#: ``calibrate``'s flags by the CalibrationOptions field each sets (its errors name the flag)
CALIBRATE_FLAGS = {"joint_sigma_deg": "--joint-sigma-deg", "axis_floor_px": "--axis-floor-px",
                   "track_offset_px": "--track-offset-px",
                   "joint_offsets": "--joint-offsets", "joint_offset_sigma_deg": "--joint-offset-sigma-deg",
                   "refine_intrinsics": "--refine-intrinsics", "intrinsics_sigma": "--intrinsics-sigma",
                   "sync_encoders": "--no-sync", "encoder_sigma_deg": "--encoder-sigma-deg",
                   "time_offset_s": "--time-offset", "time_offset_sigma_s": "--time-offset-sigma"}


def cmd_calibrate(args) -> int:
    path = Path(args.dataset)
    output = Path(args.output) if args.output else None
    if output is not None:
        check_output(output, args.overwrite)
        _check_not_input(output, path)
    dataset = Dataset.load(path)
    truth = _load_truth(path)
    print(dataset.summary())
    from .calibration import CalibrationOptions

    offsets = None if args.joint_offsets is None else (args.joint_offsets or True)  # no names: every joint
    intrinsics = () if args.refine_intrinsics is None else (tuple(args.refine_intrinsics) or True)
    if args.intrinsics_sigma is not None and args.refine_intrinsics is None:
        raise InputError("--intrinsics-sigma applies with --refine-intrinsics only (without it the camera file's "
                         "intrinsics are taken as exact)")
    if not args.time_offset_sigma >= 0:  # (0 holds the offset: None below)
        raise InputError(f"--time-offset-sigma must be a number of seconds >= 0 (0 holds the offset at "
                         f"--time-offset), got {args.time_offset_sigma:g}")
    try:
        options = CalibrationOptions(
            joint_sigma_deg=args.joint_sigma_deg, axis_floor_px=args.axis_floor_px,
            track_offset_px=args.track_offset_px, joint_offsets=offsets,
            joint_offset_sigma_deg=args.joint_offset_sigma_deg, refine_intrinsics=intrinsics,
            intrinsics_sigma=tuple(args.intrinsics_sigma or DEFAULT_INTRINSICS_SIGMA), sync_encoders=not args.no_sync,
            encoder_sigma_deg=args.encoder_sigma_deg, time_offset_s=args.time_offset,
            time_offset_sigma_s=None if args.time_offset_sigma == 0 else args.time_offset_sigma)
    except InputError as error:  # the flag the user typed, not the option's field
        raise InputError(re.sub(r"CalibrationOptions\.(\w+)", lambda m: CALIBRATE_FLAGS.get(m[1], m[0]),
                                str(error))) from None
    result = _calibrate_timed(dataset, args.method, options)
    print(summary(result))
    if truth is not None:
        _print_lines(error_vs_truth_lines(result, truth.arm_T_camera))
    if output is not None:
        _save_result(result, output, args.overwrite)
    return 0


def cmd_demo(args) -> int:
    """The whole pipeline on the built-in scene: render, track, calibrate (or, with --no-video, calibrate the
    simulated tracks directly)."""
    if args.no_video:
        return _demo_simulated(args)
    if args.noise_var is not None:
        raise InputError("--noise-var sets the pixel noise of simulated tracks: use it with --no-video (the video "
                         "demo's noise is the rendered image noise)")
    if args.outlier_fraction is not None:
        raise InputError("--outlier-fraction plants wrong simulated tracks: use it with --no-video (the video "
                         "demo's tracks are the tracker's)")
    from .demo import DEMO_DURATION, demo_render_config, run_demo

    if args.renderer == "cylinder" and args.covering is not None:
        raise InputError("--covering chooses what covers the hand in the mesh renderer; the cylinder has dots")
    config = demo_render_config(args.renderer, args.covering, args.seed)
    run_demo(args.out, seed=args.seed, duration=args.duration or DEMO_DURATION,
             n_measurements=args.n_measurements or 6, method=args.method, overwrite=args.overwrite,
             render_config=config, spin_joints=tuple(args.spin_joints or ()))
    return 0


def _demo_simulated(args) -> int:
    import numpy as np

    out = Path(args.out) if args.out else None
    if out is not None:  # refuse before simulating and calibrating, not after
        if out.exists() and not out.is_dir():
            raise OutputError(f"{out} exists and is not a directory")
        if (out / "dataset").exists() and not args.overwrite:
            raise OutputExistsError(f"{out / 'dataset'} exists; {OVERWRITE_HINT}")
        check_output(out / RESULT_FILE, args.overwrite, make_parent=True)
    print("gtsam-rotid demo: the paper's reference scene (Kinova Jaco2, Xtion-like camera)")
    print("simulating...", flush=True)
    dataset, truth = _simulate_scene("reference", args.seed, **_scene_changes(args))
    print(dataset.summary())
    T = truth.arm_T_camera
    x, y, z = T.translation() * 1000.0
    r, p, yaw = np.degrees(T.rotation().rpy())
    print(f"true arm_T_camera: t = ({x:.1f}, {y:.1f}, {z:.1f}) mm, rpy = ({r:.2f}, {p:.2f}, {yaw:.2f}) deg")
    if out is not None:
        dataset.save(out / "dataset", overwrite=args.overwrite)
        truth.save(out / "dataset" / TRUTH_FILE, overwrite=True)
        print(f"wrote {out / 'dataset'}")
    result = _calibrate_timed(dataset, args.method)
    print(summary(result))
    _print_lines(error_vs_truth_lines(result, truth.arm_T_camera))
    if out is not None:
        _save_result(result, out / RESULT_FILE, args.overwrite)
    return 0


# ---------------------------------------------------------------------------------------------------
# command line: ``gtsam-rotid export RESULT.json --to FORMAT [-o FILE]``


def _emit(text: str, output, overwrite: bool) -> None:
    """``text`` to standard output, or to the file ``output`` (staged) and "wrote FILE" on standard output."""
    if output is None:
        sys.stdout.write(text)
        sys.stdout.flush()
    else:
        write_text(output, text, overwrite=overwrite)
        print(f"wrote {output}")


def add_export_parser(subparsers) -> argparse.ArgumentParser:
    """Add the ``export`` command to an ``argparse`` subparsers object."""
    p = subparsers.add_parser(
        "export", help="write arm_T_camera (and its covariance) as YAML, JSON, URDF, a ROS 2 command or launch "
                       "file, easy_handeye's YAML or a matrix",
        description="Export a calibration result. yaml/json: pose (position, quaternion x y z w) and the covariance "
                    "in ROS's geometry_msgs/PoseWithCovariance layout (6x6 row-major; x, y, z, rotation about X, Y, "
                    "Z of the parent frame; metres, radians). urdf: a fixed <joint>. ros2: a tf2_ros "
                    "static_transform_publisher command line (Humble+ flags); launch: a ROS 2 launch file "
                    "running it. easy_handeye: its calibration YAML (eye on base). matrix: the 4x4 matrix. The "
                    "parent is the robot's root link recorded in the result. The child frame is the camera's "
                    "OpenCV optical frame (x right, y down, z forward) unless --camera-frame body or --driver.")
    p.add_argument("result", metavar="RESULT_JSON", help="result file written by `calibrate -o`")
    p.add_argument("--to", required=True, choices=[f.value for f in Format], help="output format")
    p.add_argument("-o", "--output", metavar="FILE", help="write to FILE instead of standard output")
    p.add_argument("--overwrite", action="store_true", help="replace an existing output file")
    p.add_argument("--parent", metavar="LINK",
                   help="parent link: the robot's root link recorded in the result (default), or another link fixed "
                        f"to it (results that record no robot: default {PARENT_FRAME})")
    p.add_argument("--child", metavar="FRAME",
                   help=f"child frame / link (default {DEFAULT_CHILD[CameraFrame.OPTICAL]}, or "
                        f"{DEFAULT_CHILD[CameraFrame.BODY]} with --camera-frame body)")
    p.add_argument("--camera-frame", choices=[f.value for f in CameraFrame], default=CameraFrame.OPTICAL.value,
                   help="optical (default): the estimated OpenCV frame, z forward; body: turned to ROS's x-forward "
                        "camera_link convention (REP 103)")
    p.add_argument("--driver", nargs=8, metavar=("LINK", "X", "Y", "Z", "QX", "QY", "QZ", "QW"),
                   help="the camera driver publishes LINK -> the optical frame with this transform (metres, "
                        "quaternion): export parent -> LINK instead, so that the two compose to the calibration")
    p.add_argument("--joint-name", default=JOINT_NAME, help=f"URDF joint name (default {JOINT_NAME})")
    p.add_argument("--force", action="store_true",
                   help="export a result that is not fit to export (undetermined, ambiguous, not trusted, NaN, "
                        "not converged) anyway; the file carries the warning")
    p.set_defaults(func=cmd_export)
    return p


def cmd_export(args) -> int:
    output = None if args.output is None else check_output(args.output, args.overwrite)
    result = load_result(args.result)
    fmt = Format(args.to)
    driver = None
    if args.driver is not None:
        link, *numbers = args.driver
        values = [_parse_float(v, "--driver") for v in numbers]
        quaternion = np.array(values[3:])
        if not np.isclose(np.linalg.norm(quaternion), 1.0, atol=1e-3):
            raise InputError(f"--driver: the quaternion (qx qy qz qw) {values[3:]} is not of unit length "
                             f"({np.linalg.norm(quaternion):.4g})")
        qx, qy, qz, qw = quaternion / np.linalg.norm(quaternion)
        driver = (link, gtsam.Pose3(gtsam.Rot3.Quaternion(qw, qx, qy, qz), np.array(values[:3])))
    text = export_result(result, fmt, parent_frame=args.parent, child_frame=args.child,
                         camera_frame=args.camera_frame, joint_name=args.joint_name, force=args.force, driver=driver)
    for problem in export_problems(result):  # only with --force: export_result refuses otherwise
        print(f"gtsam-rotid export: warning: exported although {problem} (the file says so)", file=sys.stderr)
    _emit(text if text.endswith("\n") else text + "\n", output, args.overwrite)
    return 0


# ---------------------------------------------------------------------------------------------------
# command line: ``gtsam-rotid report RESULT.json [--dataset DIR] [--plots DIR] [--format ...]``


def add_report_parser(subparsers) -> argparse.ArgumentParser:
    """Add the ``report`` command to an ``argparse`` subparsers object."""
    p = subparsers.add_parser(
        "report", help="print the estimate, its uncertainty, consistency and observability (and plots)",
        description="Report a calibration result: the estimate (mm, roll-pitch-yaw in degrees, quaternion), 1σ and "
                    "95 % bounds, correlations, per-measurement residuals, weights, outliers and rejected tracks, the "
                    "χ² consistency of the fit and the observability verdict in words. With --dataset the verdict "
                    "locates the wrist axes' common point and --plots also draws the tracks and residuals.")
    p.add_argument("result", metavar="RESULT_JSON", help="result file written by `calibrate -o`")
    p.add_argument("--dataset", metavar="DIR", help="the dataset directory that was calibrated (optional)")
    p.add_argument("--format", choices=[f.value for f in ReportFormat], default=ReportFormat.TEXT.value,
                   help="text (default), markdown (linking the --plots), json, or html (one page, the plots "
                        "embedded)")
    p.add_argument("-o", "--output", metavar="FILE", help="write the report to FILE instead of standard output")
    p.add_argument("--plots", metavar="DIR", help="write PNG plots into DIR (created if missing)")
    p.add_argument("--overlays", metavar="DIR",
                   help="write the quad view of each measurement on its own recorded frame (the video or bag `track` "
                        "read) into DIR as overlay_m<k>.png")
    p.add_argument("--overwrite", action="store_true", help="replace existing output files")
    p.set_defaults(func=cmd_report)
    return p


def cmd_report(args) -> int:
    output = None if args.output is None else check_output(args.output, args.overwrite)
    plots_dir = None if args.plots is None else Path(args.plots)
    if plots_dir is not None:
        if plots_dir.exists() and not plots_dir.is_dir():
            raise OutputError(f"{plots_dir} exists and is not a directory")
        if not plots_dir.parent.is_dir():
            raise OutputError(f"cannot write plots into {plots_dir}: the directory {plots_dir.parent} does not "
                                  "exist")
    overlays_dir = None if args.overlays is None else Path(args.overlays)
    if overlays_dir is not None and not overlays_dir.parent.is_dir():
        raise OutputError(f"cannot write overlays into {overlays_dir}: the directory {overlays_dir.parent} does not "
                          "exist")
    result = load_result(args.result)
    dataset = Dataset.load(args.dataset) if args.dataset is not None else _recorded_dataset(result)
    if overlays_dir is not None and dataset is None:
        raise InputError("--overlays needs the dataset that was calibrated (--dataset DIR; the result records none "
                         "that is still there)")
    if plots_dir is not None:
        from .plots import plot_files

        if plots_dir.is_dir():  # refuse before writing anything
            check_outputs(plot_files(result, dataset, plots_dir), args.overwrite)
    report = make_report(result, dataset)
    if args.format == ReportFormat.HTML.value:  # one self-contained page: the plots embedded
        from .htmlreport import to_html
        from .plots import report_pngs

        text = to_html(report, report_pngs(result, dataset))
    elif args.format == ReportFormat.MARKDOWN.value and plots_dir is not None:  # linked where they are written
        from .plots import plot_files

        base = Path(output).parent if output is not None else Path.cwd()
        links = [os.path.relpath(p, base.resolve()) for p in plot_files(result, dataset, plots_dir.resolve())]
        text = report.to_markdown(plots=[Path(link).as_posix() for link in links])
    else:
        text = report.render(args.format)
    # with the report on standard output, progress lines go to standard error (the output stays parseable)
    progress = sys.stdout if output is not None else sys.stderr
    _emit(text, output, args.overwrite)
    if plots_dir is not None:
        from .plots import save_plots

        plots_dir.mkdir(exist_ok=True)
        if dataset is None:
            print("gtsam-rotid report: note: only the 3-D view is drawn; give --dataset for the tracks and the "
                  "residual histograms", file=sys.stderr)
        for path in save_plots(result, dataset, plots_dir, overwrite=args.overwrite):
            print(f"wrote {path}", file=progress)
    if overlays_dir is not None:
        from .overlays import recorded_frames
        from .plots import save_overlays

        frames, notes = recorded_frames(dataset)
        for note in notes:
            print(f"gtsam-rotid report: note: no overlay for {note}", file=sys.stderr)
        overlays_dir.mkdir(exist_ok=True)
        for path in save_overlays(result, dataset, frames, overlays_dir, overwrite=args.overwrite):
            print(f"wrote {path}", file=progress)
    return 0


def _recorded_dataset(result) -> Dataset | None:
    """The dataset the result records it was calibrated from, if it is still there and unchanged (a note on
    standard error says which, or why it is not used)."""
    from .dataset import dataset_digest

    path = result.dataset.get("path")
    if not path:
        return None
    if not (Path(path) / "dataset.json").is_file():
        print(f"gtsam-rotid report: note: the dataset the result was calibrated from ({path}) is not there; give "
              "--dataset", file=sys.stderr)
        return None
    if result.dataset.get("sha256") != dataset_digest(path):
        print(f"gtsam-rotid report: note: the dataset at {path} changed since the calibration; not used (give "
              "--dataset to use it anyway)", file=sys.stderr)
        return None
    print(f"gtsam-rotid report: dataset {path} (recorded in the result)", file=sys.stderr)
    return Dataset.load(path)


def add_check_parser(subparsers) -> argparse.ArgumentParser:
    """Add the ``check`` command: re-check a calibration against new spins."""
    p = subparsers.add_parser(
        "check", help="re-check an existing calibration against new spins: still valid, or moved by how much",
        description="Test a calibration (a result of ours, one of our exports, easy_handeye's YAML, or a 4x4 "
                    "matrix of the camera's optical frame in the arm's root frame) against the spins of a dataset "
                    "(one spin is enough). Exit code 0: still valid; 3: moved; 4: the spins disagree among "
                    "themselves (one or more do not fit); 1: an error.")
    p.add_argument("calibration", metavar="CALIBRATION", help="result JSON, export YAML/JSON, easy_handeye YAML or "
                                                             "a 4x4 matrix text file")
    p.add_argument("dataset", metavar="DATASET", help="dataset directory of the new spins (`track` or `simulate`)")
    p.add_argument("--tolerance", nargs=2, type=float, metavar=("MM", "DEG"),
                   help="for a calibration without a covariance (another tool's): its 1 sigma per axis (default "
                        "1 mm, 0.1 deg)")
    p.set_defaults(func=cmd_check)
    return p


def cmd_check(args) -> int:
    from .calibration.check import DEFAULT_TOLERANCE, check_calibration
    from .calibration.options import CalibrationOptions
    from .posefiles import load_pose
    from .words import check_words

    dataset = Dataset.load(args.dataset)
    pose = load_pose(args.calibration, dataset.arm)
    if pose.robot:
        now = dataset.arm.description()
        differ = [key for key in ("name", "root_link", "wrist_joint", "urdf_sha256")
                  if pose.robot.get(key) != now.get(key)]
        if differ:
            raise InputError(f"{args.calibration} was calibrated with another robot model than {args.dataset}'s ("
                             + ", ".join(f"{key}: {pose.robot.get(key)!r} vs {now.get(key)!r}" for key in differ)
                             + ")")
    options = CalibrationOptions(joint_sigma_deg=pose.joint_sigma_deg, axis_floor_px=pose.axis_floor_px,
                                 track_offset_px=pose.track_offset_px)
    if pose.joint_offsets:  # the calibration's kinematics: the readings plus the offsets it refined
        print("joint offsets of the calibration applied to the readings: " + ", ".join(
            f"{name} {np.degrees(v):+.3f} deg" for name, v in pose.joint_offsets.items()))
    tolerance = DEFAULT_TOLERANCE if args.tolerance is None else tuple(args.tolerance)
    print(f"checking {pose.kind} against {len(dataset)} spin(s) of {args.dataset}", flush=True)
    check = check_calibration(pose.arm_T_camera, dataset, covariance=pose.covariance, tolerance=tolerance,
                              options=options, joint_offsets=pose.joint_offsets,
                              offsets_covariance=pose.offsets_covariance,
                              pose_offsets_covariance=pose.pose_offsets_covariance, axis_scale=pose.axis_scale)
    print("\n".join(check_words(check)))
    return 3 if not check.still_valid else 0 if check.consistent and check.odd_spin is None else 4


def add_still_parser(subparsers) -> argparse.ArgumentParser:
    """Add the ``still`` command: did the camera stay still between the videos?"""
    p = subparsers.add_parser(
        "still", help="did the camera stay still between the videos? (each video's shift on the still background)",
        description="Read each video's image shift against the first one's off the scene around the arm (the "
                    "background, the table, the arm's base), which does not move unless the camera does: a turn "
                    "of 0.01 deg is 0.1 px at f = 570 px, and the calibration's own test all but cannot see it; "
                    "and each video's last frame against that frame (a move during it). "
                    "A dataset made from the videos (track) carries the same reading, and calibrate counts what a "
                    "move does to the pose in its covariance. Exit code 0: still; 3: moved; 1: an error.")
    p.add_argument("videos", nargs="+", metavar="VIDEO", help="one video file or image folder per arm pose")
    p.add_argument("--frame", type=int, default=0, help="the frame of each video compared (default 0)")
    p.add_argument("--between-only", action="store_true",
                   help="compare the videos only, not each video's last frame against that frame (the camera's move "
                        "during it): no video is then decoded to its end")
    p.add_argument("--no-progress", action="store_true", help="no progress bar while the videos are decoded")
    p.set_defaults(func=cmd_still)
    return p


def cmd_still(args) -> int:
    from .stillness import camera_motion
    from .words import camera_motion_words

    if args.frame < 0:
        raise InputError(f"--frame must be >= 0, got {args.frame}")
    motion = camera_motion(args.videos, frame=args.frame, names=args.videos,
                           last=None if args.between_only else args.videos, progress=not args.no_progress)
    print("\n".join(camera_motion_words(motion)))
    return 3 if motion.floor_px > 0.0 else 0


# ---------------------------------------------------------------------------------------------------
# ``gtsam-rotid track``

def _parse_float(text: str, what: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise InputError(f"{what}: {text!r} is not a number") from None
    if not np.isfinite(value):
        raise InputError(f"{what}: {text!r} is not a finite number")
    return value


def _parse_pair(text: str, what: str, convert: Callable[[str], Any]) -> tuple[Any, Any]:
    if text.count(":") != 1:
        raise InputError(f"{what} {text!r} must be START:STOP (either may be empty)")
    start, stop = (part.strip() for part in text.split(":"))
    try:
        return (convert(start) if start else None), (convert(stop) if stop else None)
    except ValueError:
        raise InputError(f"{what} {text!r} must be START:STOP with numbers") from None


def cmd_track(args: argparse.Namespace) -> int:
    """``gtsam-rotid track``: videos + joint angles + camera file -> a dataset directory."""
    output = Path(args.output)
    if os.path.lexists(output) and not args.overwrite:
        raise DatasetExistsError(f"{output} exists; {OVERWRITE_HINT}")
    arm = Arm.from_urdf(args.urdf, wrist_joint=args.wrist_joint) if args.urdf else \
        Arm.from_robot(args.robot, wrist_joint=args.wrist_joint)
    settings = dict(features=args.features, max_corners=args.max_corners, min_length=args.min_track_length)
    params = None   # the tracker's defaults
    if args.tracker_params is not None or any(v is not None for v in settings.values()):
        params = load_tracker_params(args.tracker_params, **settings)
    if args.bag is not None:
        dataset = _track_bag(args, arm, params)
    else:
        dataset = _track_videos(args, arm, params)
    dataset.save(output, overwrite=args.overwrite)
    print(dataset.summary())
    starts = dataset.metadata.get("recording", {}).get("video_starts")
    for k, start in enumerate(starts or ()):  # videos on a joint time series: where each was placed
        m = dataset[k]
        if start is None or m.spin_readings is None:
            print(f"measurement {k} ({m.name}): no joint readings attached (not synced)")
        else:
            print(f"measurement {k} ({m.name}): placed at {start['start_s']:.3f} s on the joint series' clock "
                  f"(correlation {start['correlation']:.2f}), frames {start['frames_kept'][0]}-"
                  f"{start['frames_kept'][1]} kept, readings attached on clock {m.spin_readings.clock!r}"
                  + (f" (its spin's frame rate: {start['fps_from_spin']:.3g} fps, {start['fps']:.3g} given)"
                     if start.get("fps_from_spin") is not None else ""))
    print(f"wrote {output}")
    return 0


def _track_bag(args: argparse.Namespace, arm: Arm, params) -> Dataset:
    """``track --bag``: the spins, joints and camera from a ROS bag."""
    given = [flag for flag, value in (("--joints", args.joints), ("--frames", args.frames), ("--spans", args.spans),
                                      ("--degrees", args.degrees), ("--ignore-joints", args.ignore_joints))
             if value]
    for flag, value in (("--time-offset", args.time_offset), ("--max-time-offset", args.max_time_offset)):
        if value is not None and not np.isfinite(value):
            raise InputError(f"{flag} must be a finite number of seconds, got {value}")
    if not args.max_time_offset > 0:
        raise InputError(f"--max-time-offset must be > 0 s, got {args.max_time_offset}")
    if given:
        raise InputError(f"{', '.join(given)} do(es) not apply to --bag: the bag's joint states give the spins and "
                         "the joint angles (radians, matched by name)")
    print(f"bag {args.bag}; {arm!r}" + ("" if params is None else f"; features: {params.features}"), flush=True)
    dataset = dataset_from_bag(args.bag, arm, image_topic=args.image_topic, joint_topic=args.joint_topic,
                               camera_info_topic=args.camera_info_topic, camera=args.camera, tracker_params=params,
                               still_tolerance_deg=args.still_tolerance, min_spin_deg=args.min_spin,
                               max_offset_s=args.max_time_offset, time_offset_s=args.time_offset,
                               progress=not args.no_progress, spin_joints=args.spin_joints)
    recording = dataset.metadata["recording"]
    offset = recording["time_offset_s"]
    applied = ("applied" if recording["time_offset_applied"] else "NOT applied" if args.time_offset is None
               else f"not used: {1000 * args.time_offset:+.1f} ms given")
    print(f"topics: images {recording['topics']['image']}, joint states {recording['topics']['joints']}, camera "
          f"{recording['camera_from']}; {len(dataset)} spin(s)"
          + (" (" + ", ".join(f"{recording['spin_joints'].count(j)} of {j}" for j in dict.fromkeys(
              recording["spin_joints"])) + ")" if recording.get("spin_joints") else "")
          + "; camera-to-joint-state time offset "
          + ("not measured" if offset is None else f"{1000 * offset:+.1f} ms (correlation "
             f"{recording['time_offset_correlation']:.2f}, {applied})"))
    return dataset


def _track_videos(args: argparse.Namespace, arm: Arm, params) -> Dataset:
    """``track --video/--videos-dir``: one video per measurement, a joint file and a camera file."""
    missing = [flag for flag, value in (("--joints", args.joints), ("--camera", args.camera)) if value is None]
    if missing:
        raise InputError(f"videos need {' and '.join(missing)} (a bag gives both: --bag)")
    videos = [Path(v) for v in args.videos] if args.videos else videos_in(Path(args.videos_dir))
    frame_ranges = None
    if args.frames:
        if len(args.frames) != len(videos):
            raise InputError(f"{len(args.frames)} --frames range(s) for {len(videos)} video(s); give one START:STOP "
                             f"per video (':' for all frames)")
        frame_ranges = [_parse_pair(text, "--frames", int) for text in args.frames]
    spans = None
    if args.spans:
        spans = [_parse_pair(text, "--spans", float) for text in args.spans]
        if any(a is None or b is None for a, b in spans):
            raise InputError("each --spans entry needs both its first and last stamp, T0:T1")
    joint_options = {"degrees": bool(args.degrees), "spans": spans, "still_tolerance_deg": args.still_tolerance,
                     "min_spin_deg": args.min_spin, "ignore_joints": list(args.ignore_joints)}
    print(f"{len(videos)} video(s); {arm!r}" + ("" if params is None else f"; features: {params.features}"),
          flush=True)
    if args.spin_joints and len(args.spin_joints) != len(videos):
        raise InputError(f"{len(args.spin_joints)} --spin-joints for {len(videos)} video(s); name the joint that "
                         f"spun in each video (the wrist: {arm.wrist_joint})")
    if args.fps is not None and not (math.isfinite(args.fps) and args.fps > 0):
        raise InputError(f"--fps must be a positive number of frames per second, got {args.fps:g}")
    return make_dataset(videos, args.joints, args.camera, arm, frame_ranges=frame_ranges,
                        progress=not args.no_progress, joint_options=joint_options, tracker_params=params,
                        spin_joints=args.spin_joints, fps=args.fps, readings=not args.no_readings)


def add_track_parser(subparsers) -> argparse.ArgumentParser:
    """Add the ``track`` command to an ``argparse`` subparsers object; returns its parser (func = cmd_track)."""
    p = subparsers.add_parser(
        "track", help="make a dataset from a ROS bag, or from recorded videos, joint angles and a camera file",
        description="Track features in each wrist spin and write a dataset. From a ROS bag (ROS 1 .bag, ROS 2 "
                    "sqlite3 or mcap): the spins are found in the joint states, the camera read from CameraInfo "
                    "and the camera-to-joint-state time offset measured. From videos: one video (or image folder) "
                    "per arm pose; the joint file is CSV or JSON: one row of angles per video, or a time series of "
                    "joint states (a time/stamp column) from which each spin's still joints are read.")
    source = p.add_mutually_exclusive_group(required=True)
    source.add_argument("--video", "--videos", dest="videos", nargs="+", metavar="VIDEO",
                        help="one video file or image folder per measurement, in the joint file's order")
    source.add_argument("--bag", metavar="PATH",
                        help="a ROS 1 .bag file or a ROS 2 bag directory (sqlite3 or mcap): images, joint states "
                             "and CameraInfo")
    source.add_argument("--videos-dir", metavar="DIR",
                        help="a directory whose videos and image folders (sorted by name) are the measurements")
    p.add_argument("--joints", metavar="FILE", help="joint-angle file (CSV or JSON; videos only)")
    p.add_argument("--camera", metavar="CAMERA_YAML",
                   help="OpenCV calibration YAML or ROS camera_info YAML (videos: required; a bag: instead of its "
                        "CameraInfo)")
    p.add_argument("--image-topic", metavar="TOPIC", help="the bag's image topic (default: the only one)")
    p.add_argument("--joint-topic", metavar="TOPIC", help="the bag's JointState topic (default: the only one)")
    p.add_argument("--camera-info-topic", metavar="TOPIC",
                   help="the bag's CameraInfo topic (default: the one beside the images, or the only one)")
    p.add_argument("--time-offset", type=float, metavar="S",
                   help="a bag's camera clock minus its joint-state clock (s), when known (default: measured)")
    p.add_argument("--max-time-offset", type=float, default=1.0, metavar="S",
                   help="the largest camera-to-joint-state offset searched (s, default 1)")
    robot = p.add_mutually_exclusive_group(required=True)
    robot.add_argument("--robot", metavar="NAME", help="example-robot-data arm (kinova, ur5, ur10, panda, xarm7)")
    robot.add_argument("--urdf", metavar="FILE", help="the arm's URDF")
    p.add_argument("--wrist-joint", metavar="NAME", help="the spinning joint (default: the last revolute joint)")
    p.add_argument("--spin-joints", nargs="+", metavar="NAME",
                   help="videos: the joint that spun in each video, one per video, where they differ (default: the "
                        "wrist joint in every video); a bag: the joints whose spins are measurements (default: the "
                        "wrist joint)")
    p.add_argument("--frames", nargs="+", metavar="START:STOP",
                   help="frame range per video (stop exclusive; ':' = all frames)")
    p.add_argument("--spans", nargs="+", metavar="T0:T1",
                   help="time span of each video's spin in the joint time series (default: found automatically)")
    p.add_argument("--degrees", action="store_true", help="the joint file is in degrees (default radians)")
    p.add_argument("--fps", type=float, metavar="HZ",
                   help="videos with a joint time series: the videos' frame rate (default: what each video file "
                        "states; an image folder states none)")
    p.add_argument("--no-readings", action="store_true",
                   help="videos with a joint time series: do not attach each spin's joint readings (synced mode "
                        "places each video on the series' clock by image motion, then estimates what is left of "
                        "its offset, one per video)")
    p.add_argument("--still-tolerance", type=float, default=STILL_TOLERANCE_DEG, metavar="DEG",
                   help=f"largest motion of a non-wrist joint during a spin (default {STILL_TOLERANCE_DEG})")
    p.add_argument("--min-spin", type=float, default=MIN_SPIN_DEG, metavar="DEG",
                   help=f"smallest wrist rotation that counts as a spin (default {MIN_SPIN_DEG:g})")
    p.add_argument("--ignore-joints", nargs="+", default=(), metavar="NAME",
                   help="joint-file columns to ignore (e.g. fingers)")
    p.add_argument("--tracker-params", metavar="FILE",
                   help="YAML or JSON file of tracker settings (gtsam_rotid.tracking.TrackerParams fields)")
    p.add_argument("--features", choices=("auto", "blobs", "corners"),
                   help="what to track: blobs (dots), corners (ambient texture) or auto (both; the default)")
    p.add_argument("--max-corners", type=int, metavar="N", help="most corner tracks at once (default 300)")
    p.add_argument("--min-track-length", type=int, metavar="N", help="shortest track kept, in points (default 10)")
    p.add_argument("-o", "--output", required=True, metavar="DATASET", help="dataset directory to write")
    p.add_argument("--overwrite", action="store_true", help="replace an existing dataset")
    p.add_argument("--no-progress", action="store_true", help="no progress bars")
    p.set_defaults(func=cmd_track)
    return p


# ---------------------------------------------------------------------------------------------------
# the commands' shared options and the parser

def _add_scene_options(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    parser.add_argument("--noise-var", type=float, help="pixel noise variance in px^2 (default 1.5)")
    parser.add_argument("--duration", type=float, help="seconds of each spin (default 60; the demo from video: 20)")
    parser.add_argument("--n-measurements", type=int, help="number of arm poses (default 6)")
    parser.add_argument("--outlier-fraction", type=float, help="fraction of tracks replaced by wrong arcs")
    parser.add_argument("--spin-joints", nargs="+", metavar="JOINT",
                        help="spin each of these joints at every arm pose, one measurement each (default: the "
                             "wrist joint only)")


def _add_method_option(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--method", choices=METHODS, default="joint",
                        help="estimator: joint (default), weighted or paper (the seed paper's two stages)")


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="gtsam-rotid",
        description="Target-free camera-to-arm calibration by rotation identification (GTSAM).",
    )
    parser.add_argument("--version", action="version", version=f"gtsam-rotid {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")

    p = sub.add_parser("simulate", help="write a simulated dataset (with its ground truth)")
    p.add_argument("--scene", choices=SCENES, default="reference", help="which scene (default reference)")
    p.add_argument("-o", "--output", required=True, help="dataset directory to write")
    p.add_argument("--overwrite", action="store_true", help="replace an existing dataset")
    _add_scene_options(p)
    p.add_argument("--spin-ramp", type=float, metavar="S",
                   help="seconds over which each spin speeds up from rest and slows to rest (default 0: one speed)")
    p.add_argument("--encoder-rate", type=float, metavar="HZ",
                   help="readings of the spinning joint per second, stored with each measurement for synced "
                        "calibration (default 0: none)")
    p.add_argument("--encoder-sigma-deg", type=float, metavar="DEG", help="the readings' noise (default 0)")
    p.add_argument("--encoder-time-offset", type=float, metavar="S",
                   help="how far the readings' clock runs ahead of the camera's (s; calibrate reports camera minus "
                        "encoder, the negative)")
    p.set_defaults(func=cmd_simulate)

    p = sub.add_parser("calibrate", help="estimate arm_T_camera from a dataset directory",
                       description="Estimate arm_T_camera from a dataset directory. If the directory holds the "
                                   f"{TRUTH_FILE} that `simulate` writes, also print the error against it.")
    p.add_argument("dataset", metavar="DATASET", help="dataset directory (as written by `simulate`)")
    _add_method_option(p)
    p.add_argument("--joint-sigma-deg", type=float, default=0.0, metavar="DEG",
                   help="standard deviation of each joint-angle reading in degrees, propagated into the "
                        "covariance (default 0: exact kinematics)")
    p.add_argument("--axis-floor-px", type=float, default=None, metavar="PX",
                   help="the image axes' floor: an error in px that all of a spin's tracks share (default: the "
                        "value the tracker wrote into the dataset, 0 for tracks of unknown origin)")
    p.add_argument("--track-offset-px", type=float, default=None, metavar="PX",
                   help="each track's own offset: an error in px that follows one track over its whole arc, "
                        "independent across tracks (default: the value the tracker wrote into the dataset, 0 for "
                        "tracks of unknown origin)")
    p.add_argument("--joint-offsets", nargs="*", default=None, metavar="JOINT",
                   help="refine the zero offsets of these joints (before the spinning one) with the pose; no names: "
                        "every joint between the first and the spinning one (the first joint's offset turns the "
                        "arm as the camera pose does) (joint method)")
    p.add_argument("--joint-offset-sigma-deg", type=float, default=1.0, metavar="DEG",
                   help="prior 1 sigma of each joint offset in degrees (default 1)")
    p.add_argument("--refine-intrinsics", nargs="*", default=None, metavar="NAME", choices=list(INTRINSICS),
                   help="refine these camera intrinsics (fx, fy, cx, cy) with the pose, from the circles' shapes; no "
                        "names: all four (joint method, rigid spin: tracks with frame indices)")
    p.add_argument("--intrinsics-sigma", type=float, nargs=2, default=None, metavar=("FOCAL_FRACTION", "PX"),
                   help="with --refine-intrinsics: prior 1 sigma of the refined intrinsics about the camera file's: "
                        "focal length as a fraction of it, principal point in px (default {} {})".format(
                            *DEFAULT_INTRINSICS_SIGMA))
    p.add_argument("--no-sync", action="store_true",
                   help="ignore the spinning joint's readings that measurements carry (bags: the joint states); by "
                        "default they set each frame's spin angle and the encoder clock's offset is estimated")
    p.add_argument("--encoder-sigma-deg", type=float, default=0.05, metavar="DEG",
                   help="synced: 1 sigma of each frame's spin angle from the readings in degrees (default 0.05)")
    p.add_argument("--time-offset", type=float, default=0.0, metavar="S",
                   help="synced: the clocks' offset, camera minus encoder (s; as track --time-offset), the prior's "
                        "mean (default 0)")
    p.add_argument("--time-offset-sigma", type=float, default=0.1, metavar="S",
                   help="synced: the offset's prior 1 sigma (s; default 0.1; 0: held at --time-offset)")
    p.add_argument("-o", "--output", metavar="RESULT_JSON", help="write the result as JSON to this file")
    p.add_argument("--overwrite", action="store_true", help="replace an existing result file")
    p.set_defaults(func=cmd_calibrate)

    p = sub.add_parser("demo", help="render the reference scene, track it and calibrate it (the whole pipeline)",
                       description="Render the paper's reference scene (6 wrist spins, 20 s each by default), track "
                                   "the features, calibrate, and print the result and its error against the truth. "
                                   "--no-video calibrates the simulated tracks instead (60 s spins by default).")
    p.add_argument("--out", metavar="DIR", help=f"also write DIR/dataset, DIR/{RESULT_FILE} (and, from video, "
                                                 "one overlay picture per measurement)")
    p.add_argument("--no-video", action="store_true", help="skip rendering and tracking: calibrate simulated tracks")
    p.add_argument("--renderer", choices=("mesh", "cylinder"), default="mesh",
                   help="mesh: the robot's own meshes, ray cast (default); cylinder: the dotted stepped cylinder")
    p.add_argument("--covering", choices=COVERINGS, default=None,
                   help=f"what covers the hand (mesh renderer; default {DEMO_COVERING})")
    p.add_argument("--overwrite", action="store_true", help="replace existing output")
    _add_method_option(p)
    _add_scene_options(p)
    p.set_defaults(func=cmd_demo)

    add_track_parser(sub)
    add_report_parser(sub)
    add_export_parser(sub)
    add_check_parser(sub)
    add_still_parser(sub)
    add_plan_parsers(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if not getattr(args, "func", None):
        parser.print_help()
        return 2
    try:
        return args.func(args)
    except RotIdError as exc:
        # the library's words for its keyword, the command line's for its flag
        message = str(exc).replace(OVERWRITE_HINT, "pass --overwrite to replace it").replace(
            "overwrite=True", "--overwrite")
        print(f"gtsam-rotid {args.command}: error: {message}", file=sys.stderr)
        return 1


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())

"""Command line: ``gtsam-rotid {simulate,calibrate,demo,track,report,export}``; thin: parses, calls the library."""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

from . import __version__
from .errors import InputError, OutputError, OutputExistsError, RotIdError
from .export import add_export_parser
from .files import OVERWRITE_HINT, check_output
from .meshrender import COVERINGS
from .pixels import DEMO_COVERING
from .recordings import add_track_parser
from .report import add_report_parser, error_vs_truth_lines

SCENES = ("reference", "single-crossing")
#: ``gtsam_rotid.estimate.Method`` values (kept literal so that ``--help`` does not import the estimator).
METHODS = ("joint", "weighted", "paper")
TRUTH_FILE = "truth.json"
DATASET_FILE = "dataset.json"
RESULT_FILE = "result.json"


def _simulate_scene(scene: str, seed: int, **changes):
    from . import simulate

    factory = {"reference": simulate.reference_scene, "single-crossing": simulate.single_crossing_scene}[scene]
    return factory(seed=seed, **changes)


def _scene_changes(args) -> dict:
    changes = {}
    for name in ("noise_var", "duration", "n_measurements", "outlier_fraction"):
        value = getattr(args, name, None)
        if value is not None:
            changes[name] = value
    return changes


def _check_not_input(output: Path, dataset_dir: Path) -> None:
    """Refuse a result path that is one of the dataset's own files (``calibrate`` reads them)."""
    from .dataset import DATASET_FILE as OWN
    from .dataset import SCHEMA_FILE, TRACKS_FILE, URDF_FILE

    if output.resolve().parent == dataset_dir.resolve() and output.name in (OWN, TRACKS_FILE, URDF_FILE, SCHEMA_FILE,
                                                                           TRUTH_FILE):
        raise OutputError(f"{output} is a file of the dataset {dataset_dir} that calibrate reads; write the result "
                          f"elsewhere (e.g. {dataset_dir.parent / RESULT_FILE})")


def _save_result(result, path: Path, overwrite: bool) -> None:
    """``result.save`` (staged: the old file stays intact on failure; errors name the path)."""
    result.save(path, overwrite=overwrite)
    print(f"wrote {path}")


def _calibrate_timed(dataset, method: str, options=None):
    from .estimate import calibrate

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


def cmd_calibrate(args) -> int:
    from .dataset import Dataset

    path = Path(args.dataset)
    output = Path(args.output) if args.output else None
    if output is not None:
        check_output(output, args.overwrite)
        _check_not_input(output, path)
    dataset = Dataset.load(path)
    truth = _load_truth(path)
    print(dataset.summary())
    from .estimate import CalibrationOptions

    result = _calibrate_timed(dataset, args.method, CalibrationOptions(joint_sigma_deg=args.joint_sigma_deg))
    print(result.summary())
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
    from .pixels import DEMO_DURATION, demo_render_config, run_demo

    if args.renderer == "cylinder" and args.covering is not None:
        raise InputError("--covering chooses what covers the hand in the mesh renderer; the cylinder has dots")
    config = demo_render_config(args.renderer, args.covering, args.seed)
    run_demo(args.out, seed=args.seed, duration=args.duration or DEMO_DURATION,
             n_measurements=args.n_measurements or 6, method=args.method, overwrite=args.overwrite,
             render_config=config)
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
    print(result.summary())
    _print_lines(error_vs_truth_lines(result, truth.arm_T_camera))
    if out is not None:
        _save_result(result, out / RESULT_FILE, args.overwrite)
    return 0


def _add_scene_options(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    parser.add_argument("--noise-var", type=float, help="pixel noise variance in px^2 (default 1.5)")
    parser.add_argument("--duration", type=float, help="seconds of wrist spin per measurement (default 60)")
    parser.add_argument("--n-measurements", type=int, help="number of arm poses (default 6)")
    parser.add_argument("--outlier-fraction", type=float, help="fraction of tracks replaced by wrong arcs")


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
    p.set_defaults(func=cmd_simulate)

    p = sub.add_parser("calibrate", help="estimate arm_T_camera from a dataset directory",
                       description="Estimate arm_T_camera from a dataset directory. If the directory holds the "
                                   f"{TRUTH_FILE} that `simulate` writes, also print the error against it.")
    p.add_argument("dataset", metavar="DATASET", help="dataset directory (as written by `simulate`)")
    _add_method_option(p)
    p.add_argument("--joint-sigma-deg", type=float, default=0.0, metavar="DEG",
                   help="standard deviation of each joint-angle reading in degrees, propagated into the "
                        "covariance (default 0: exact kinematics)")
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

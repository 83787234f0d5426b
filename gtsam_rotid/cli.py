"""Command line: ``gtsam-rotid {simulate,demo} ...``. Thin: it parses and calls library functions."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from . import __version__
from .errors import RotIdError

SCENES = ("reference", "single-crossing")
TRUTH_FILE = "truth.json"


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


def cmd_simulate(args) -> int:
    dataset, truth = _simulate_scene(args.scene, args.seed, **_scene_changes(args))
    out = Path(args.output)
    dataset.save(out, overwrite=args.overwrite)
    truth.save(out / TRUTH_FILE, overwrite=True)
    print(dataset.summary())
    print(f"wrote {out} (ground truth in {out / TRUTH_FILE})")
    return 0


def cmd_demo(args) -> int:
    dataset, truth = _simulate_scene("reference", args.seed, **_scene_changes(args))
    print("gtsam-rotid demo: the paper's reference scene (Kinova Jaco2, Xtion-like camera), simulated")
    print(dataset.summary())
    T = truth.arm_T_camera
    x, y, z = T.translation() * 1000.0
    r, p, yaw = T.rotation().rpy() * 180.0 / 3.141592653589793
    print(f"true arm_T_camera: t = ({x:.1f}, {y:.1f}, {z:.1f}) mm, rpy = ({r:.2f}, {p:.2f}, {yaw:.2f}) deg")
    if args.out:
        out = Path(args.out) / "dataset"
        dataset.save(out, overwrite=args.overwrite)
        truth.save(out / TRUTH_FILE, overwrite=True)
        print(f"wrote {out}")
    return 0


def _add_scene_options(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    parser.add_argument("--noise-var", type=float, help="pixel noise variance in px^2 (default 1.5)")
    parser.add_argument("--duration", type=float, help="seconds of wrist spin per measurement (default 60)")
    parser.add_argument("--n-measurements", type=int, help="number of arm poses (default 6)")
    parser.add_argument("--outlier-fraction", type=float, help="fraction of tracks replaced by wrong arcs")


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

    p = sub.add_parser("demo", help="run the main job on the built-in reference scene")
    p.add_argument("--out", help="also write the dataset into this directory")
    p.add_argument("--overwrite", action="store_true", help="replace existing output")
    _add_scene_options(p)
    p.set_defaults(func=cmd_demo)
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
        print(f"gtsam-rotid {args.command}: error: {exc}", file=sys.stderr)
        return 1


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())

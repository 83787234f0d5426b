"""Tied starts (issue 13): does the answer depend on which of the guess-free start's tied candidates comes first?

The guess-free start (``calibration.initial.guess_free_minima``) refines several pose candidates by LM and sorts
their minima by cost. Where several candidates reach the same minimum their costs tie to rounding (1e-12 relative
on a rendered Jaco2 text scene), so the last digits of the arithmetic pick the one that becomes the start and the
anchor of the gauge prior. This re-runs the calibration of saved ambient scenes (``benchmarks/ambient.py --save
DIR``) once with each tied candidate put first (the others in their order) and prints, per order, the error (worst
axis, position in the arm frame) against the reported 1 sigma, the chi-square of the error and the verdict.

    python benchmarks/tied_starts.py --load DIR [--scenes kinova_text_nominal_seed0] [--tie 1e-9]

``--tie``: candidates whose minimum is within this relative cost of the best count as tied. The calibration uses
``--axis-floor-px 0 --track-offset-px 0.15`` as the ambient table's ``--load`` rows do.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import gtsam
import numpy as np

import gtsam_rotid.calibration.initial as initial
from gtsam_rotid import Dataset
from gtsam_rotid.errors import RotIdError
from gtsam_rotid.estimate import CalibrationOptions, calibrate

ORIGINAL = initial.guess_free_minima


def _first(index: int | None, tie: float, seen: list):
    """``guess_free_minima`` with candidate ``index`` first where it ties with the best (None: as it is); records
    the tied candidates in ``seen``."""

    def minima(*args, **kwargs):
        candidates, graph, found = ORIGINAL(*args, **kwargs)
        if not found:
            return candidates, graph, found
        best = found[0][1]
        tied = [m for m in found if m[1] <= best * (1.0 + tie) + 1e-12]
        if not seen:
            seen.extend((m[3], m[1]) for m in tied)
        chosen = [m for m in tied if m[3] == index]
        if chosen:
            found = chosen + [m for m in found if m is not chosen[0]]
        return candidates, graph, found

    return minima


def _one(tracked: Dataset, truth: gtsam.Pose3, options: CalibrationOptions) -> str:
    try:
        result = calibrate(tracked, options=options)
    except RotIdError as error:
        return f"refused: {type(error).__name__}: {str(error)[:100]}"
    xi = result.error_to(truth)
    mm = 1000.0 * np.abs(truth.rotation().matrix() @ xi[3:]).max()
    sigma = 1000.0 * np.sqrt(np.diag(result.covariance)[3:]).max()
    chi2 = float(xi @ np.linalg.solve(result.covariance, xi))
    verdict = "usable" if result.covariance_usable else "NOT usable (" + ", ".join(
        sorted(result.untrusted) or (["ambiguous"] if result.ambiguous else ["undetermined"])) + ")"
    return f"{mm:8.3f} mm (1σ {sigma:.2f}) | χ² {chi2:8.3g} | {verdict}"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--load", required=True, help="a directory of scenes saved by benchmarks/ambient.py --save")
    parser.add_argument("--scenes", default="kinova_text_nominal_seed0", help="comma-separated scene names")
    parser.add_argument("--tie", type=float, default=1e-9, help="relative cost within which candidates tie")
    args = parser.parse_args()
    options = CalibrationOptions(axis_floor_px=0.0, track_offset_px=0.15)
    for name in args.scenes.split(","):
        root = Path(args.load) / name
        if not (root / "scene.json").is_file():
            raise SystemExit(f"{root}: no scene.json (save scenes with benchmarks/ambient.py --save {args.load})")
        truth = gtsam.Pose3(np.array(json.loads((root / "scene.json").read_text())["arm_T_camera"], dtype=float))
        tracked = Dataset.load(root / "dataset")
        seen: list = []
        initial.guess_free_minima = _first(None, args.tie, seen)
        started = time.perf_counter()
        print(f"{name}: as it is: {_one(tracked, truth, options)} ({time.perf_counter() - started:.0f} s)", flush=True)
        print(f"  tied candidates (index, cost): {[(i, round(c, 9)) for i, c in seen]}", flush=True)
        for index, _ in seen:
            initial.guess_free_minima = _first(index, args.tie, [])
            started = time.perf_counter()
            print(f"  candidate {index} first: {_one(tracked, truth, options)} "
                  f"({time.perf_counter() - started:.0f} s)", flush=True)
        initial.guess_free_minima = ORIGINAL


if __name__ == "__main__":
    main()

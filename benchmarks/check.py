"""Re-checking a calibration (``gtsam-rotid check``): how often an unmoved camera is called moved, and how well a move
is measured.

One calibration (the reference scene, seed 0, six ``--duration`` s spins, 1.5 px² pixel noise) is checked against
``--sessions`` later sessions of the same camera (seeds 10, 11, ...; other arm poses), and against as many sessions
of a camera moved by ``--move-mm`` along the arm's x axis. Printed per session: the move's χ² and its dof, p, the
verdict, and the move reported (mm, deg); then how many unmoved sessions were called moved (at the 0.1 % level: about
none) and the median move reported for the moved camera.

Run: ``python benchmarks/check.py [--sessions 12] [--duration 6] [--move-mm 10]``.
"""

from __future__ import annotations

import argparse
import time
from dataclasses import replace

import numpy as np

from gtsam_rotid.calibration.check import axis_scale_of, check_calibration
from gtsam_rotid.estimate import calibrate
from gtsam_rotid.simulate import SceneConfig, simulate


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sessions", type=int, default=12)
    parser.add_argument("--duration", type=float, default=6.0)
    parser.add_argument("--move-mm", type=float, default=10.0)
    args = parser.parse_args()
    base = SceneConfig(duration=args.duration)
    first, _ = simulate(base, seed=0)
    result = calibrate(first)
    start = time.perf_counter()
    moved_reports = []
    false_alarms = 0
    for label, shift in (("unmoved", 0.0), ("moved", args.move_mm / 1000.0)):
        eye = np.asarray(base.camera_eye, dtype=float) + [shift, 0.0, 0.0]
        target = np.asarray(base.camera_target, dtype=float) + [shift, 0.0, 0.0]
        config = replace(base, camera_eye=tuple(eye), camera_target=tuple(target))
        for seed in range(10, 10 + args.sessions):
            dataset, _ = simulate(config, seed=seed)
            c = check_calibration(result.arm_T_camera, dataset, covariance=result.covariance,
                                  axis_scale=axis_scale_of(result))
            verdict = "valid" if c.still_valid else "MOVED"
            print(f"{label:8} seed {seed:3}: move chi2 {c.chi2:8.2f} for {c.dof} dof, p {c.p_value:8.2g}, {verdict:5}, "
                  f"move {c.move_mm:6.2f} mm {c.move_deg:6.3f} deg")
            if label == "unmoved":
                false_alarms += not c.still_valid
            else:
                moved_reports.append(c.move_mm)
    print(f"\nunmoved sessions called moved: {false_alarms} of {args.sessions}; moved by {args.move_mm:g} mm: median "
          f"move reported {np.median(moved_reports):.2f} mm ({time.perf_counter() - start:.0f} s)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

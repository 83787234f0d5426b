"""Thin ellipses (a wrist axis nearly across the line of sight): does each method's covariance hold there?

The scene of ``tests/calibration/test_thin_ellipses.py`` (six random Panda poses, 20 s spins, 1.5 px² noise; two
measurements' ellipses' ends thinner than the pixel noise: b^2 / a at 0.7 and 0.9 pixel sigma) over ``--draws``
noise draws (seeds 12000, 12001, ...): per draw and method (``weighted``, the free-phase joint fit, the rigid spin's
joint fit, ``paper``) the chi-square of the error under the reported covariance (99.9 % point 22.46), whether the
covariance is called usable, and why not; then, per method, how many draws are beyond the 99.9 % point and how
many of those were called usable.

Run: ``python benchmarks/thin_ellipses.py [--draws 8]`` (about 6 min on one core).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from gtsam_rotid.arm import Arm
from gtsam_rotid.calibration import CalibrationOptions, calibrate
from gtsam_rotid.simulate import simulate

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests" / "calibration"))
from test_thin_ellipses import thin_config  # noqa: E402 (the scene is the test's)

CHI2_999 = 22.46
METHODS = {"weighted": dict(method="weighted"), "free phase": dict(options=CalibrationOptions(spin_model="free")),
           "rigid spin": {}, "paper": dict(method="paper")}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--draws", type=int, default=8)
    args = parser.parse_args(argv)
    config, arm = thin_config(), Arm.from_robot("panda")
    rows = {name: [] for name in METHODS}
    print("| draw | " + " | ".join(METHODS) + " |")
    print("| --- |" + " --- |" * len(METHODS))
    for seed in range(12_000, 12_000 + args.draws):
        dataset, truth = simulate(config, seed=seed, arm=arm)
        cells = []
        for name, kwargs in METHODS.items():
            result = calibrate(dataset, **kwargs)
            e = result.error_to(truth.arm_T_camera)
            try:
                chi2 = float(e @ np.linalg.solve(result.covariance, e))
            except np.linalg.LinAlgError:  # (a singular covariance: an undetermined result)
                chi2 = float("inf")
            rows[name].append((chi2, result.covariance_usable))
            why = ", ".join(result.untrusted) or ("ambiguous" if result.ambiguous else "undetermined"
                                                  if not result.observability.is_observable else "")
            cells.append(f"χ² {chi2:.3g}, " + ("usable" if result.covariance_usable else f"not usable ({why})"))
        print(f"| {seed} | " + " | ".join(cells) + " |", flush=True)
    print()
    for name, values in rows.items():
        beyond = [usable for chi2, usable in values if chi2 > CHI2_999]
        print(f"{name}: {len(beyond)} of {len(values)} beyond the 99.9 % point, {sum(beyond)} of them called usable; "
              f"{sum(usable for _, usable in values)} called usable in all")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

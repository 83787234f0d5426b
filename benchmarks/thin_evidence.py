"""Thin evidence with the default options: what ``calibrate`` says on scenes that barely determine the pose.

1. Ten simulated scenes (``simulate.reference_scene(seed, duration=20, noise_var=0.05)``, seeds 0-9) thinned to at
   most 3 tracks of 20-90 frames per pose, as ``tests/calibration/thin_tracks.py::_thin`` does: refused, or called
   not usable, and why; the error and its chi-square under the reported covariance.
2. Twenty-four arm poses with 2 s spins (``simulate.reference_scene(seed, duration=2, n_measurements=24)``, seeds
   0-2): the same, and the measurements left out.
3. The reference scene (60 s spins), whose measurements are all strong.

Run: ``python benchmarks/thin_evidence.py`` (about 3 minutes on one core).
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests" / "calibration"))

from thin_tracks import _thin  # noqa: E402

from gtsam_rotid import simulate  # noqa: E402
from gtsam_rotid.errors import RotIdError  # noqa: E402
from gtsam_rotid.estimate import calibrate  # noqa: E402


def line(label: str, result, truth) -> str:
    e = result.error_to(truth.arm_T_camera)
    # (an undetermined result's covariance is the observability's, 1e12 along the free directions: no chi-square)
    chi2 = float(e @ np.linalg.solve(result.covariance, e)) if result.covariance is not None \
        and result.observability.is_observable else float("nan")
    verdict = "usable" if result.covariance_usable else "NOT usable " + str(sorted(result.untrusted))
    left = [k for k, m in enumerate(result.measurements) if not m.used]
    return (f"{label}: {verdict}; error {1000 * np.max(np.abs(e[3:])):.2f} mm, chi2 {chi2:.1f}; determined "
            f"{result.observability.is_observable}; measurements left out {left}")


def main() -> int:
    for seed in range(10):
        dataset, truth = simulate.reference_scene(seed=seed, duration=20, noise_var=0.05)
        try:
            print(line(f"thinned seed {seed}", calibrate(_thin(dataset, seed)), truth), flush=True)
        except RotIdError as error:
            print(f"thinned seed {seed}: refused: {type(error).__name__}: {error}"[:240], flush=True)
    for seed in range(3):
        dataset, truth = simulate.reference_scene(seed=seed, duration=2, n_measurements=24)
        print(line(f"24 poses x 2 s, seed {seed}", calibrate(dataset), truth), flush=True)
    dataset, truth = simulate.reference_scene(seed=0)
    print(line("reference scene", calibrate(dataset), truth))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

"""The corner tracker's errors on the image axes, measured on rendered scenes: as a floor shared by every axis
(``trackparams.CORNER_AXIS_FLOOR_PX``), or with ``--track-offsets`` as each track's own offset
(``trackparams.TRACK_OFFSET_PX``).

For each scene saved by ``benchmarks/ambient.py --save DIR``: the calibration (``joint``, no prior floor), and for
each strong measurement it used (not weak: enough tracks and arc), the two test points of its FK axis projected by
the *true* camera pose, their distances from its stage-1 image axis and those distances' covariance at the estimate
(the result's ``MeasurementReport.axis_test_covariance``: pixel noise at the measurement's variance, joint-angle
noise). A ``tau`` (px) added in quadrature to every distance
(``V_k + tau^2 I``) makes the floor ``tau / sqrt(2)`` (a shift and a turn of that much each: the ``axis_floor_px``
convention). Printed, over all scenes, the usable ones only and without each robot in turn: the moment ``tau``,
which makes the mean of the squared errors in units of their 1 sigma 1 (the covariance then holds the errors'
second moment, as a covariance must; DerSimonian and Laird's estimator of a random effect), which
``AXIS_FLOOR_PX["corners"]`` takes; and the Gaussian maximum-likelihood ``tau``, which fits the bulk of a
heavy-tailed error and leaves its tail out; then the RMS and median of the errors in units of their 1 sigma at a
few floors (heavy tails show as an RMS well above 1 where the median sits inside).

With ``--track-offsets`` the same errors are held by each track's own image offset instead: the calibration runs
with ``track_offset_px`` 1 and no floor, and each strong measurement's ``MeasurementReport.axis_offset_covariance``
is ``O_k``, what a 1 px offset per track gives its test points' distances; a ``tau`` makes their covariance
``V_k + tau^2 O_k`` (no sqrt(2): ``tau`` is ``track_offset_px``).

Run: ``python benchmarks/axis_floor.py --load DIR [--track-offsets]`` (one core, about 40 s per scene).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from ambient import DATASET_DIR, SCENE_FILE, true_axis_distances  # noqa: E402  (ambient.py --save's layout)


def scene_rows(root: Path, offsets: bool = False) -> tuple[list[dict], bool] | None:
    """The strong measurements' test-point distances from the truth and their covariance, and whether the
    calibration called its covariance usable; None when the scene has no dataset or is refused."""
    import gtsam

    from gtsam_rotid import CalibrationOptions, Dataset, calibrate
    from gtsam_rotid.errors import RotIdError

    document = json.loads((root / SCENE_FILE).read_text(encoding="utf-8"))
    if not (root / DATASET_DIR).is_dir() or document.get("arm_T_camera") is None:
        return None
    dataset = Dataset.load(root / DATASET_DIR)
    truth = gtsam.Pose3(np.array(document["arm_T_camera"], dtype=float))
    try:
        result = calibrate(dataset, options=CalibrationOptions(axis_floor_px=0.0,
                                                               track_offset_px=1.0 if offsets else 0.0))
    except RotIdError:
        return None
    out = [{"e": e, "cov": np.asarray(m.axis_test_covariance, dtype=float),
            "unit": np.asarray(m.axis_offset_covariance, dtype=float) if offsets else np.eye(2)}
           for m, e in zip(result.measurements, true_axis_distances(result, dataset, truth), strict=True)
           if m.used and not m.weak and m.axis_test_covariance is not None
           and (not offsets or m.axis_offset_covariance is not None)]
    return out, bool(result.covariance_usable)


def _stacked(rows: list[dict]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The rows' distances (k, 2), their covariances (k, 2, 2) and what ``tau^2`` multiplies (k, 2, 2)."""
    return np.array([r["e"] for r in rows]), np.array([r["cov"] for r in rows]), np.array([r["unit"] for r in rows])


def _squared(E: np.ndarray, V: np.ndarray, U: np.ndarray, tau: float) -> np.ndarray:
    """Each row's squared error over its covariance with ``tau^2 U`` added (2 dof per row)."""
    return np.einsum("ki,ki->k", E, np.linalg.solve(V + tau**2 * U, E[..., None])[..., 0])


def ml_tau(rows: list[dict]) -> float:
    """The maximum-likelihood ``tau`` (px) on a grid of 1 000 values up to 1 px."""
    E, V, U = _stacked(rows)
    taus = np.linspace(0.0, 1.0, 1001)
    nll = [np.sum(np.linalg.slogdet(V + tau**2 * U)[1]) + np.sum(_squared(E, V, U, tau)) for tau in taus]
    return float(taus[int(np.argmin(nll))])


def moment_tau(rows: list[dict]) -> float:
    """The common floor (px) at which the errors' mean square in units of their 1 sigma is 1 (0 when it is below
    1 without a floor), by bisection: that mean falls as the floor grows."""
    def excess(tau: float) -> float:
        return z_stats(rows, tau)[0] ** 2 - 1.0

    if excess(0.0) <= 0.0:
        return 0.0
    low, high = 0.0, 1.0
    while excess(high) > 0.0:
        high *= 2.0
    for _ in range(50):
        middle = 0.5 * (low + high)
        low, high = (middle, high) if excess(middle) > 0.0 else (low, middle)
    return high


def z_stats(rows: list[dict], tau: float) -> tuple[float, float]:
    """RMS and median of the errors in units of their 1 sigma (per distance) with floor ``tau``."""
    z2 = _squared(*_stacked(rows), tau) / 2.0
    return float(np.sqrt(np.mean(z2))), float(np.sqrt(np.median(z2)))


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--load", required=True, metavar="DIR", help="scenes saved by benchmarks/ambient.py --save")
    parser.add_argument("--track-offsets", action="store_true",
                        help="measure each track's own offset (track_offset_px) instead of a floor on every axis")
    args = parser.parse_args(argv)
    offsets = args.track_offsets
    as_option = (lambda tau: tau) if offsets else (lambda tau: tau / np.sqrt(2))
    option = "track_offset_px" if offsets else "axis_floor_px"
    scenes = {}
    for root in sorted(p for p in Path(args.load).iterdir() if p.is_dir()):
        got = scene_rows(root, offsets)
        if got is None:
            print(f"{root.name}: no calibration")
            continue
        scenes[root.name] = got
        print(f"{root.name}: {len(got[0])} strong measurements, {'usable' if got[1] else 'not usable'}", flush=True)
    if not scenes:
        print("no scene calibrated")
        return 1
    groups = {"all scenes": list(scenes), "usable scenes": [n for n, (_, u) in scenes.items() if u]}
    for robot in sorted({n.split("_")[0] for n in scenes}):
        groups[f"without {robot}"] = [n for n in scenes if not n.startswith(robot + "_")]
    print()
    for name, members in groups.items():
        rows = [r for n in members for r in scenes[n][0]]
        if not rows:
            continue
        moment, ml = moment_tau(rows), ml_tau(rows)
        rms, median = z_stats(rows, ml)
        print(f"{name}: {len(rows)} strong measurements; moment tau {moment:.3f} px -> {option} "
              f"{as_option(moment):.3f}; Gaussian maximum-likelihood tau {ml:.3f} px -> {as_option(ml):.3f}, "
              f"where |error| / 1 sigma has RMS {rms:.2f}, median {median:.2f} (Gaussian: 1, 0.83)")
    rows = [r for n in groups["all scenes"] for r in scenes[n][0]]
    for tau in (0.0, 0.05, 0.1, 0.15, 0.2):
        rms, median = z_stats(rows, tau)
        print(f"  all scenes at tau {tau:.2f} px ({option} {as_option(tau):.3f}): RMS {rms:.2f}, median {median:.2f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())

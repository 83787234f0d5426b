"""An image shift common to all tracks of a pose: how far it moves the calibration, whether the image axes' test
sees it, and whether the covariance covers it when declared as the axes' floor.

For each shift level (px) and each of ``--scenes`` reference scenes (seeds 200, 201, ...; ``--poses`` spins of
``--duration`` s, 1.5 px² pixel noise, exact kinematics): every pixel of a pose's tracks is moved by one draw of
N(0, level²) per image coordinate, independent across poses (what a camera that turns by level / f rad between
poses gives, 0.01° for 0.1 px at f = 570 px, or a tracker's bias shared by a pose's features), and ``joint``
calibrates it twice: with nothing declared (the default for tracks without tracker metadata) and with
``CalibrationOptions(axis_floor_px=level)`` (the shift declared as a floor on every image axis). Printed per level
and setting: the median camera position error (mm), the median reported 1σ of the position (mm, mean over the arm-frame
axes), the NEES (mean Mahalanobis chi-square of the true error over every result; 6 when the covariance is honest) with
its 99.9 % interval, how many scenes fall outside their 99.9 % region and how many of those were called usable and named
by their words (refused calibrations counted apart), the median P of the axes' test (uniform on (0, 1) where it cannot
see the shift) and how many usable results' words name the shift (``words.image_shift_words``: a shift of 0.1 px per
pose would exceed their 1σ). A third row takes the first setting's covariance plus what each result says a shift of the
level would add (``level² x CalibrationResult.image_shift_covariance``): NEES about 6 where that says how far the shift
moves the estimate.

Run: ``python benchmarks/image_shift.py [--scenes 20] [--duration 12] [--poses 6] [--levels 0.1 0.25] [--jobs 2]``;
``--quick`` (3 scenes of 6 s spins, level 0.25) checks that it runs.
"""

from __future__ import annotations

import argparse
import sys
import time

import numpy as np

from gtsam_rotid import Dataset, Measurement, Track, simulate
from gtsam_rotid.errors import RotIdError
from gtsam_rotid.estimate import CalibrationOptions, calibrate
from gtsam_rotid.uncertainty import chi2_mean_interval
from gtsam_rotid.words import image_shift_words

CHI2_999_6DOF = 22.458
SETTINGS = ("nothing declared", "declared as the axes' floor")
#: the first setting's covariance plus what the result says a shift of the level would add
#: (``level² x CalibrationResult.image_shift_covariance``): does it say how much the shift moves the estimate?
ADDED = "nothing declared, + the result's image shift covariance"


def trial(level: float, index: int, duration: float, poses: int) -> dict:
    dataset, truth = simulate.reference_scene(seed=200 + index, duration=duration, n_measurements=poses)
    rng = np.random.default_rng([2000, index])
    shifted = Dataset(dataset.arm, dataset.camera, [
        Measurement(m.joint_angles, [Track(t.pixels + shift, t.frames) for t in m.tracks], name=m.name)
        for m in dataset for shift in [level * rng.standard_normal(2)]])
    out = {}
    for setting, floor in zip(SETTINGS, (0.0, level), strict=True):
        try:
            result = calibrate(shifted, method="joint", options=CalibrationOptions(axis_floor_px=floor))
        except RotIdError:
            out[setting] = None  # (refused: counted apart)
            continue
        error = result.error_to(truth.arm_T_camera)
        p = float("nan") if result.axis_consistency is None else float(result.axis_consistency.p_value)
        words = image_shift_words(result) is not None
        out[setting] = (float(error @ np.linalg.solve(result.covariance, error)),
                        float(1000 * np.linalg.norm(error[3:])), float(np.mean(result.sigma_mm_arm)),
                        bool(result.covariance_usable), p, words)
        if setting == SETTINGS[0] and result.image_shift_covariance is not None:
            added = result.covariance + level**2 * result.image_shift_covariance
            R = result.arm_T_camera.rotation().matrix()
            out[ADDED] = (float(error @ np.linalg.solve(added, error)), out[setting][1],
                          float(np.mean(1000 * np.sqrt(np.diag(R @ added[3:, 3:] @ R.T)))),
                          bool(result.covariance_usable), p, words)
    return out


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--scenes", type=int, default=20)
    parser.add_argument("--duration", type=float, default=12.0, help="seconds per wrist spin")
    parser.add_argument("--poses", type=int, default=6, help="arm poses (one wrist spin each)")
    parser.add_argument("--levels", type=float, nargs="+", default=[0.1, 0.25], help="px per image coordinate")
    parser.add_argument("--jobs", type=int, default=1, help="trials in parallel (joblib processes)")
    parser.add_argument("--quick", action="store_true", help="3 scenes of 6 s spins, level 0.25")
    args = parser.parse_args(argv)
    if args.quick:
        args.scenes, args.duration, args.levels = 3, 6.0, [0.25]
    if args.scenes < 1 or args.duration <= 0 or args.poses < 3 or any(level <= 0 for level in args.levels):
        parser.error("--scenes must be >= 1, --duration > 0, --poses >= 3 and the levels > 0")
    jobs = [(level, i) for level in args.levels for i in range(args.scenes)]
    start = time.perf_counter()
    if args.jobs > 1:
        from joblib import Parallel, delayed

        results = Parallel(n_jobs=args.jobs)(delayed(trial)(level, i, args.duration, args.poses)
                                             for level, i in jobs)
    else:
        from tqdm import tqdm

        results = [trial(level, i, args.duration, args.poses)
                   for level, i in tqdm(jobs, desc="trials", disable=not sys.stderr.isatty())]
    low, high = chi2_mean_interval(6, args.scenes, 3.29)
    print(f"{args.scenes} reference scenes per level ({args.poses} poses x {args.duration:g} s spins, 1.5 px², "
          f"exact kinematics), joint; {time.perf_counter() - start:.0f} s. NEES 99.9 % interval "
          f"[{low:.2f}, {high:.2f}]\n")
    print("| image shift per pose (px) | covariance | median error (mm) | median 1σ (mm) | NEES | outside 99.9 % "
          "(of them called usable, of those named by their words) | axes' test: median P | usable results whose "
          "words name a shift |")
    print("| --- | --- | --- | --- | --- | --- | --- | --- |")
    for level in args.levels:
        rows = [r for (lv, _), r in zip(jobs, results, strict=True) if lv == level]
        for setting in (SETTINGS[0], ADDED, SETTINGS[1]):
            done = [r[setting] for r in rows if r.get(setting) is not None]
            refused = f" ({len(rows) - len(done)} refused)" if len(done) < len(rows) else ""
            if not done:
                print(f"| {level:g} | {setting} | | | | all {len(rows)} refused | |")
                continue
            chi2, mm, sigma, usable, p, words = (np.array(v) for v in zip(*done, strict=True))
            outside = chi2 > CHI2_999_6DOF
            print(f"| {level:g} | {setting} | {np.median(mm):.2f} | {np.median(sigma):.2f} | {chi2.mean():.2f} | "
                  f"{int(outside.sum())} of {len(done)} ({int(np.sum(outside & usable))}, "
                  f"{int(np.sum(outside & usable & words))}){refused} | "
                  f"{np.nanmedian(p):.2f} | {int(np.sum(words & usable))} of {int(usable.sum())} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""Is the covariance from pixels honest? NEES over several rendered reference scenes (issue 6, ``from_pixels``).

For each seed: the reference scene (``simulate.reference_scene(seed)``: the Jaco2, six spins of ``--duration`` s;
the seed draws the arm poses and the features) is rendered with ``RenderConfig(seed=seed)`` (the dot covering and
the image noise), tracked (``gtsam_rotid.pixels.dataset_from_video``) and calibrated with ``joint`` and
``weighted``. The tracked datasets are cached in ``--cache`` (rendering and tracking take ~80 s per scene of 60 s
spins on one core), so a re-run only calibrates.

Printed per scene and method: the Mahalanobis chi-square of the true error under the reported covariance
(``e^T Sigma^-1 e``, 6 dof: 6 on average when the covariance is honest) and under the same covariance without the
axis-consistency scale (``result.axis_consistency``: the stage-1 image axes tested against the estimate, the
covariance multiplied by chi2/dof when they disagree beyond their pixel noise); then the mean over the scenes
(NEES) with its 99.9 % interval for that many scenes, and how many scenes fall outside the 99.9 % region.

Run: ``python benchmarks/pixels_honesty.py [--scenes 13] [--first-seed 0] [--duration 60] [--cache DIR]
[--jobs 2]``; ``--quick`` (3 scenes of 8 s spins) checks that it runs.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

from gtsam_rotid import simulate
from gtsam_rotid.dataset import Dataset
from gtsam_rotid.estimate import calibrate
from gtsam_rotid.render import RenderConfig
from gtsam_rotid.uncertainty import chi2_mean_interval

METHODS = ("joint", "weighted")
CHI2_999_6DOF = 22.458


def tracked_scene(seed: int, duration: float, cache: Path) -> tuple[Dataset, object, dict]:
    """The tracked dataset of one seed (from the cache, or rendered, tracked and cached), the scene's ground truth
    and its tracking summary."""
    from gtsam_rotid.pixels import dataset_from_video

    folder = cache / f"seed{seed}_{duration:g}s"
    summary_path = folder.with_suffix(".json")
    dataset, truth = simulate.reference_scene(seed=seed, duration=duration)
    if folder.is_dir() and summary_path.is_file():
        return Dataset.load(folder), truth, json.loads(summary_path.read_text())
    start = time.perf_counter()
    scene = dataset_from_video(dataset, truth, RenderConfig(seed=seed), progress=False)
    accuracy = scene.total_accuracy
    summary = {"seed": seed, "duration": duration, "seconds": time.perf_counter() - start,
               "rms_px": accuracy.rms_px, "bias_px": accuracy.bias_px, "n_tracks": scene.dataset.n_tracks}
    scene.dataset.save(folder, overwrite=True)
    summary_path.write_text(json.dumps(summary))
    return scene.dataset, truth, summary


def evaluate(seed: int, duration: float, cache: Path) -> dict:
    tracked, truth, summary = tracked_scene(seed, duration, cache)
    row = {"seed": seed, **summary}
    for method in METHODS:
        result = calibrate(tracked, method=method)
        error = result.error_to(truth.arm_T_camera)
        test = result.axis_consistency
        scale = 1.0 if test is None else test.scale
        row[method] = {"chi2": float(error @ np.linalg.solve(result.covariance, error)),
                       "chi2_unscaled": float(error @ np.linalg.solve(result.covariance / scale, error)),
                       "axes_chi2": None if test is None else test.chi2, "axes_dof": None if test is None else test.dof,
                       "scale": scale, "position_mm": float(1000 * np.linalg.norm(error[3:])),
                       "rotation_deg": float(np.degrees(np.linalg.norm(error[:3])))}
    return row


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--scenes", type=int, default=13)
    parser.add_argument("--first-seed", type=int, default=0)
    parser.add_argument("--duration", type=float, default=60.0, help="seconds per wrist spin")
    parser.add_argument("--cache", type=Path, default=Path("out/pixels_cache"), help="tracked datasets (reused)")
    parser.add_argument("--jobs", type=int, default=1, help="scenes in parallel (joblib processes)")
    parser.add_argument("--quick", action="store_true", help="3 scenes of 8 s spins")
    args = parser.parse_args(argv)
    if args.quick:
        args.scenes, args.duration = 3, 8.0
    if args.scenes < 1 or args.duration <= 0:
        parser.error("--scenes must be >= 1 and --duration > 0")
    args.cache.mkdir(parents=True, exist_ok=True)
    seeds = list(range(args.first_seed, args.first_seed + args.scenes))
    print(f"{len(seeds)} rendered reference scenes (seeds {seeds[0]}-{seeds[-1]}, six {args.duration:g} s spins), "
          f"tracked datasets cached in {args.cache}")
    start = time.perf_counter()
    if args.jobs > 1:
        from joblib import Parallel, delayed

        rows = Parallel(n_jobs=args.jobs)(delayed(evaluate)(s, args.duration, args.cache) for s in seeds)
    else:
        from tqdm import tqdm

        rows = [evaluate(s, args.duration, args.cache)
                for s in tqdm(seeds, desc="scenes", unit="scene", disable=not sys.stderr.isatty())]
    print(f"{time.perf_counter() - start:.0f} s\n")
    header = f"{'seed':>4} {'track px':>8} " + " ".join(
        f"{m + ' axes chi2':>20} {'scale':>6} {'chi2':>7} {'unscaled':>8} {'mm':>6}" for m in METHODS)
    print(header)
    for row in rows:
        cells = []
        for m in METHODS:
            r = row[m]
            axes = "n/a" if r["axes_chi2"] is None else f"{r['axes_chi2']:.1f} ({r['axes_dof']} dof)"
            cells.append(f"{axes:>20} {r['scale']:6.2f} {r['chi2']:7.2f} {r['chi2_unscaled']:8.2f} "
                         f"{r['position_mm']:6.3f}")
        print(f"{row['seed']:>4} {row['rms_px']:8.3f} " + " ".join(cells))
    low, high = chi2_mean_interval(6, len(rows), 3.29)
    print(f"\nNEES (mean chi-square of the true error; 6 when honest, 99.9 % interval for {len(rows)} scenes "
          f"[{low:.2f}, {high:.2f}]); scenes outside the 99.9 % region (chi-square > {CHI2_999_6DOF}):")
    for m in METHODS:
        scaled = np.array([row[m]["chi2"] for row in rows])
        raw = np.array([row[m]["chi2_unscaled"] for row in rows])
        scales = np.array([row[m]["scale"] for row in rows])
        print(f"  {m:>8}: reported covariance NEES {scaled.mean():.2f}, {int(np.sum(scaled > CHI2_999_6DOF))} of "
              f"{len(rows)} outside; without the axis scale NEES {raw.mean():.2f}, "
              f"{int(np.sum(raw > CHI2_999_6DOF))} outside; scale applied in {int(np.sum(scales > 1))} scenes "
              f"(median {np.median(scales):.2f})")
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""Speed (frames/s on one core) and accuracy (RMS px against the exact centres) of ``gtsam_rotid.tracking``.

1. Synthetic frames (the generator of tests/test_tracking.py): dark and bright discs of 2.5–6 px radius
   on ellipses over a static smooth texture, Gaussian noise, 640x480; hidden for part of each turn.
2. When ``gtsam_rotid.render`` is available: the rendered reference scene (``--duration`` s of measurement 0).
   Tracked points are matched to every drawn dot (partly hidden ones too: no point escapes the RMS); the
   coverage counts the frames where the renderer calls a dot visible.

Frames are made before the clock starts; the time is the tracker alone (``Tracker.run``: detection, LK,
re-centring, filtering), best of ``--repeats``, OpenCV on one thread. A tracked point is matched to the
nearest true centre within 3 px; the RMS is over the matched points. Target: >= 150 frames/s at 640x480 on
one core, RMS <= 0.1 px on the rendered reference scene.

Run: ``python benchmarks/tracking_speed.py [--frames 300] [--duration 10] [--repeats 3]``.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

import cv2
import numpy as np

from gtsam_rotid.tracking import Tracker, TrackerParams

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
from test_tracking import coverage, render_dots, rms_error, spin_dots  # noqa: E402


def timed(frames, params: TrackerParams, repeats: int):
    best, result = np.inf, None
    for _ in range(repeats):
        start = time.perf_counter()
        result = Tracker(params).run(frames)
        best = min(best, time.perf_counter() - start)
    return result, best


def report(name: str, frames, truth, params: TrackerParams, repeats: int, drawn=None) -> None:
    """``truth`` (F, n, 2): centres of the visible features (NaN elsewhere), for the coverage; ``drawn``: of
    every feature drawn at all (default ``truth``), which the tracked points are matched to."""
    result, seconds = timed(frames, params, repeats)
    rms, matched = rms_error(result.tracks, truth if drawn is None else drawn)
    height, width = frames[0].shape[:2]
    print(f"{name}: {len(frames)} frames {width}x{height}, {truth.shape[1]} features")
    per_frame = 1e3 * seconds / len(frames)
    print(f"  speed      {len(frames) / seconds:7.0f} frames/s on one core ({per_frame:.2f} ms/frame)")
    print(f"  accuracy   RMS {rms:.3f} px over {sum(len(t) for t in result.tracks)} points "
          f"({100 * matched:.1f} % matched within 3 px)")
    print(f"  coverage   {100 * coverage(result.tracks, truth):.1f} % of the visible frames of every feature "
          f"(runs >= 10 frames)")
    print("  " + result.summary().replace("\n", "\n  "))


def rendered_reference(duration: float, seed: int):
    try:
        from gtsam_rotid import render, simulate
    except ImportError:
        return None
    dataset, truth = simulate.reference_scene(seed=seed, duration=duration)
    spin = render.render_measurement(dataset, truth, 0)
    frames = np.stack(list(spin.frames()))
    visible = np.where(spin.visible[..., None], spin.truth_pixels, np.nan)
    drawn = np.where(spin.facing[..., None] > 0, spin.truth_pixels, np.nan)   # partly hidden ones too
    return frames, visible, drawn


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--frames", type=int, default=300, help="synthetic frames")
    parser.add_argument("--dots", type=int, default=16, help="synthetic discs")
    parser.add_argument("--noise", type=float, default=3.0, help="synthetic image noise (grey levels, 1 sigma)")
    parser.add_argument("--duration", type=float, default=10.0, help="rendered reference scene length (s)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args(argv)
    cv2.setNumThreads(1)
    os.environ.setdefault("OMP_NUM_THREADS", "1")
    params = TrackerParams()

    dots = spin_dots(args.dots, 640, 480, seed=args.seed + 1)
    for j, dot in enumerate(dots):                                  # spread the ellipses over the image
        dot.axes = (dot.axes[0] * 1.3, dot.axes[1] * 1.3)
        dot.speed = 0.015 + 0.002 * (j % 5)
    frames, truth = render_dots(dots, args.frames, 640, 480, noise=args.noise, seed=args.seed)
    report("synthetic discs", frames, truth, params, args.repeats)

    rendered = rendered_reference(args.duration, args.seed)
    if rendered is None:
        print("rendered reference scene: skipped (gtsam_rotid.render is not available)")
    else:
        frames, visible, drawn = rendered
        report(f"rendered reference scene, measurement 0, {args.duration:g} s", frames, visible, params, args.repeats,
               drawn)


if __name__ == "__main__":
    main()

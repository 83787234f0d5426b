"""Did the camera stay still between the videos? How well ``gtsam_rotid.stillness.camera_motion`` reads a pose's
image shift off the still background, against shifts it is not told.

Per scene (``--scenes`` of them, seeds 0, 1, ...): a textured still scene (smooth shading and sharp-edged panels),
seen by the first video as it is and by each of ``len(--levels)`` other videos moved by the level in a random
direction (exactly, by the Fourier shift theorem), an arm (a textured band) standing elsewhere in every video, 2
grey levels of sensor noise; ``--jpeg Q`` stores every frame as a JPEG of quality Q first (as a camera's or a
bag's compressed images), ``--blur S`` blurs it by a Gaussian of S px. Printed per level: the RMS error of the
shift (px), the mean of its squared error in units of the reported standard errors (2 when they are honest, for
the two coordinates), how often it is called moved (beyond 3 standard errors and 0.02 px), and the same two
numbers for Lucas-Kanade's consensus alone (without the floating-point re-alignment of each point's window: its
points share errors, so the standard error of their median understates).

Run: ``python benchmarks/stillness.py [--scenes 20] [--levels 0 0.02 0.05 0.1 0.25 1] [--jpeg 90] [--blur 0]``.
"""

from __future__ import annotations

import argparse
import sys
import time

import cv2
import numpy as np

from gtsam_rotid import stillness
from gtsam_rotid.stillness import camera_motion

W, H, MARGIN = 480, 360, 32


def still_scene(rng, width: int = W, height: int = H, margin: int = MARGIN) -> np.ndarray:
    """A still scene with ``margin`` px on each side (the Fourier shift wraps around): smooth shading and
    sharp-edged panels, slightly blurred (float grey levels)."""
    h, w = height + 2 * margin, width + 2 * margin
    noise = cv2.GaussianBlur(rng.normal(size=(h, w)).astype(np.float32), (0, 0), 8.0)
    image = 70 + 110 * (noise - noise.min()) / (noise.max() - noise.min())
    for _ in range(80):
        x, y = int(rng.integers(0, w)), int(rng.integers(0, h))
        image[y:y + int(rng.integers(5, 25)), x:x + int(rng.integers(5, 25))] = float(rng.uniform(30, 230))
    return cv2.GaussianBlur(image, (0, 0), 1.0).astype(float)


def moved_view(scene: np.ndarray, shift, arm_at: int, rng, margin: int = MARGIN, jpeg: int | None = None,
               blur: float = 0.0) -> np.ndarray:
    """The scene moved by ``shift`` (px, x and y: exactly, by the Fourier shift theorem; OpenCV's warps round
    positions to 1/32 px), an arm (a textured band 90 px wide) standing at column ``arm_at``, 2 grey levels of
    noise; optionally blurred (``blur`` px) and stored as a JPEG of quality ``jpeg``."""
    h, w = scene.shape
    fy, fx = np.fft.fftfreq(h)[:, None], np.fft.fftfreq(w)[None, :]
    moved = np.fft.ifft2(np.fft.fft2(scene) * np.exp(-2j * np.pi * (fx * shift[0] + fy * shift[1]))).real
    image = moved[margin:h - margin, margin:w - margin].copy()
    height, width = image.shape
    arm = cv2.GaussianBlur(rng.uniform(40, 220, size=(height, 90)).astype(np.float32), (0, 0), 1.5)
    image[:, arm_at:arm_at + 90] = arm[:, :min(90, width - arm_at)]
    if blur > 0:
        image = cv2.GaussianBlur(image, (0, 0), blur)
    image = np.clip(np.rint(image + rng.normal(0.0, 2.0, size=image.shape)), 0, 255).astype(np.uint8)
    if jpeg is not None:
        ok, data = cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_QUALITY, int(jpeg)])
        image = cv2.imdecode(data, cv2.IMREAD_GRAYSCALE)
    return image


def lk_consensus(reference: np.ndarray, frame: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Lucas-Kanade's consensus alone (``background_shift`` without the floating-point re-alignment,
    :func:`gtsam_rotid.stillness.lk_consensus`): the median displacement of the corners that agree, and its
    standard error."""
    centre, near, _ = stillness.lk_consensus(reference, frame, stillness.reference_corners(reference))
    return centre, 1.2533 * 1.4826 * np.median(np.abs(near - centre), axis=0) / np.sqrt(len(near))


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--scenes", type=int, default=20)
    parser.add_argument("--levels", type=float, nargs="+", default=[0.0, 0.02, 0.05, 0.1, 0.25, 1.0],
                        help="shifts (px) of the other videos against the first")
    parser.add_argument("--jpeg", type=int, default=None, metavar="Q", help="store every frame as a JPEG of quality Q")
    parser.add_argument("--blur", type=float, default=0.0, metavar="PX", help="Gaussian blur of every frame (px)")
    args = parser.parse_args(argv)
    if args.scenes < 1 or any(level < 0 for level in args.levels) or args.blur < 0 or (
            args.jpeg is not None and not 1 <= args.jpeg <= 100):
        parser.error("--scenes must be >= 1, the levels >= 0, --blur >= 0 and --jpeg in 1..100")
    started = time.perf_counter()
    errors, z2, moved, lk = ({level: [] for level in args.levels} for _ in range(4))
    for seed in range(args.scenes):
        rng = np.random.default_rng([7, seed])
        scene = still_scene(rng)
        angles = rng.uniform(0, 2 * np.pi, len(args.levels))
        shifts = np.array([[0.0, 0.0]] + [[lv * np.cos(a), lv * np.sin(a)] for lv, a in
                                           zip(args.levels, angles, strict=True)])
        columns = rng.permutation(np.arange(20, W - 110, 40))[:len(shifts)]
        frames = [moved_view(scene, s, int(c), rng, jpeg=args.jpeg, blur=args.blur)
                  for s, c in zip(shifts, columns, strict=True)]
        motion = camera_motion(frames)
        for k, level in enumerate(args.levels, start=1):
            e = motion.shifts_px[k] - shifts[k]
            errors[level].append(e)
            z2[level].append(float(np.sum((e / np.maximum(motion.sigma_px[k], 1e-12)) ** 2)))
            moved[level].append(bool(motion.moved[k]))
            shift, sigma = lk_consensus(frames[0], frames[k])
            lk[level].append((shift - shifts[k], float(np.sum(((shift - shifts[k]) / np.maximum(sigma, 1e-12)) ** 2))))
    what = ", ".join(filter(None, [f"JPEG quality {args.jpeg}" if args.jpeg else "",
                                   f"blurred {args.blur:g} px" if args.blur else ""])) or "uncompressed"
    print(f"{args.scenes} scenes ({W}x{H} px, {what}), one video per level against the first; "
          f"{time.perf_counter() - started:.0f} s\n")
    print("| shift (px) | RMS error (px) | mean (error / σ)² (2 if honest) | called moved | Lucas–Kanade's consensus "
          "alone: RMS error (px), mean (error / σ)² |")
    print("| --- | --- | --- | --- | --- |")
    for level in args.levels:
        e = np.array(errors[level])
        lke, lkz = np.array([x for x, _ in lk[level]]), np.array([z for _, z in lk[level]])
        print(f"| {level:g} | {np.sqrt(np.mean(np.sum(e**2, axis=1))):.4f} | {np.mean(z2[level]):.2f} | "
              f"{sum(moved[level])} of {len(moved[level])} | {np.sqrt(np.mean(np.sum(lke**2, axis=1))):.4f}, "
              f"{lkz.mean():.2f} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())

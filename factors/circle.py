"""Circle-point factor: one track's pixels against the projected circle of a coaxial circle variable.

Keys: a ``gtsam.Rot3`` line variable (see :mod:`.geometry`) and a 2-vector circle variable ``(d, r)``.
Residual (length N, one per pixel): the signed geometric pixel distance of each observed pixel to the projected
circle, positive outside. The maths lives in :func:`.circle_track.circle_point_residuals`; the factor evaluates
it with a per-factor :class:`.circle_track.CircleTrack`, which warm-starts each call's closest-phase search from the
previous call's phases (the result does not depend on it: see that class).

Robust kernels: GTSAM's ``noiseModel.Robust`` evaluates its loss on the factor's *whole* Mahalanobis norm
(``Robust.loss(|e|^2) == mEstimator.loss(|e|)``; the default ``ReweightScheme.Block`` reweights the block as one),
so with one factor per track a robust noise model down-weights whole tracks, not single pixels.
"""

from __future__ import annotations

import gtsam
import numpy as np

from .circle_track import CircleTrack


def checked_track(noise, pixels, K, residuals_per_pixel: int = 1) -> tuple[np.ndarray, np.ndarray]:
    """Read-only float copies of a track's (N, 2) pixels and of K, after checking the noise model's dimension."""
    pixels = np.array(pixels, dtype=float).reshape(-1, 2)
    K = np.array(K, dtype=float).reshape(3, 3)
    if noise.dim() != residuals_per_pixel * len(pixels):
        raise ValueError(f"noise model has dimension {noise.dim()} but the track has {len(pixels)} pixels"
                         + (f" ({residuals_per_pixel} residuals each)" if residuals_per_pixel != 1 else ""))
    pixels.setflags(write=False)
    K.setflags(write=False)
    return pixels, K


def make_circle_point_factor(noise, line_key: int, circle_key: int, pixels, K, *,
                             warm_start: bool = True) -> gtsam.CustomFactor:
    """One factor per track, vectorised over its N pixels.

    Args:
        noise: gtsam noise model of dimension N (e.g. ``noiseModel.Isotropic.Sigma(N, sigma_px)`` or
            ``noiseModel.Robust.Create(mEstimator, base)``).
        line_key: key of the ``gtsam.Rot3`` line variable of the measurement.
        circle_key: key of the track's circle variable, a 2-vector ``(d, r)``.
        pixels: (N, 2) observed ideal (undistorted) pixels of the track.
        K: (3, 3) intrinsic matrix.
        warm_start: start each call's closest-phase search from the previous call's phases (faster; same
            results to ~1e-12 px). ``False`` searches from scratch every call.

    Returns:
        ``gtsam.CustomFactor`` with Jacobians (N, 3) wrt the Rot3 tangent and (N, 2) wrt ``(d, r)``.
    """
    pixels, K = checked_track(noise, pixels, K)
    track = CircleTrack(K, pixels, warm_start=warm_start)

    def error_func(this: gtsam.CustomFactor, values: gtsam.Values, H) -> np.ndarray:
        keys = this.keys()
        d, r = values.atVector(keys[1])
        e, H_line, H_circle = track.evaluate(values.atRot3(keys[0]).matrix(), d, r, jacobians=H is not None)
        if H is not None:
            H[0] = H_line
            H[1] = H_circle
        return e

    return gtsam.CustomFactor(noise, [line_key, circle_key], error_func)

"""The original (pre-optimisation) circle-point maths, kept verbatim as a slow reference.

:mod:`gtsam_rotid.factors.circle_track` evaluates the same residuals and Jacobians with a warm-started, closed-form
solver; the tests compare the two, and ``benchmarks/factor_speed.py`` times both. Not used by the library.
"""

from __future__ import annotations

import gtsam
import numpy as np

from gtsam_rotid.factors import circle_coordinates, project

#: Phases on the coarse grid of :func:`closest_phases`.
PHASE_GRID_SIZE = 72
#: Newton iterations after the grid search of :func:`closest_phases`.
PHASE_NEWTON_STEPS = 8


def _matrix(R) -> np.ndarray:
    return np.asarray(R.matrix() if hasattr(R, "matrix") else R, dtype=float)


def projected_circle(K, R, d: float, r: float, phi) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Pixels of the projected circle and their first two derivatives wrt the phase."""
    R = _matrix(R)
    K = np.asarray(K, dtype=float)
    phi = np.atleast_1d(np.asarray(phi, dtype=float))
    s, c = np.sin(phi), np.cos(phi)
    KR = K @ R
    y = circle_coordinates(d, r, phi) @ KR.T
    dy = np.stack([r * c, np.zeros_like(phi), -r * s], axis=-1) @ KR.T
    ddy = np.stack([-r * s, np.zeros_like(phi), -r * c], axis=-1) @ KR.T
    z, dz, ddz = y[:, 2:], dy[:, 2:], ddy[:, 2:]
    u = y[:, :2] / z
    du = (dy[:, :2] - u * dz) / z
    ddu = (ddy[:, :2] - u * ddz - 2.0 * du * dz) / z
    return u, du, ddu


def closest_phases(K, R, d: float, r: float, pixels, grid_size: int = PHASE_GRID_SIZE,
                   newton_steps: int = PHASE_NEWTON_STEPS) -> np.ndarray:
    """Grid search over ``grid_size`` phases, then ``newton_steps`` safeguarded Newton steps."""
    pixels = np.asarray(pixels, dtype=float).reshape(-1, 2)
    if len(pixels) == 0:
        return np.zeros(0)
    grid = np.linspace(-np.pi, np.pi, grid_size, endpoint=False)
    curve, _, _ = projected_circle(K, R, d, r, grid)
    d2 = np.sum((pixels[:, None, :] - curve[None, :, :]) ** 2, axis=-1)  # (N, G)
    phi = grid[np.argmin(d2, axis=1)]
    max_step = 2.0 * np.pi / grid_size
    for _ in range(newton_steps):
        u, du, ddu = projected_circle(K, R, d, r, phi)
        e = u - pixels
        grad = np.sum(du * e, axis=1)
        gn = np.sum(du * du, axis=1)
        hess = gn + np.sum(ddu * e, axis=1)
        hess = np.where(hess > 1e-3 * gn, hess, gn) + 1e-300
        step = np.clip(grad / hess, -max_step, max_step)
        phi = phi - step
        if np.max(np.abs(step)) < 1e-14:
            break
    return np.mod(phi + np.pi, 2.0 * np.pi) - np.pi


def circle_point_residuals(K, R, d: float, r: float, pixels,
                           jacobians: bool = True) -> tuple[np.ndarray, np.ndarray | None, np.ndarray | None]:
    """Signed geometric pixel distances to the projected circle (+ outside), Jacobians with the phase held fixed."""
    R = _matrix(R)
    pixels = np.asarray(pixels, dtype=float).reshape(-1, 2)
    phi = closest_phases(K, R, d, r, pixels)
    u, du, ddu = projected_circle(K, R, d, r, phi)
    perp = np.stack([-du[:, 1], du[:, 0]], axis=-1)
    side = np.where(np.sum(perp * ddu, axis=1) < 0.0, -1.0, 1.0)
    n = perp * (side / np.maximum(np.linalg.norm(perp, axis=1), 1e-300))[:, None]
    e = np.sum(n * (u - pixels), axis=1)
    if not jacobians:
        return e, None, None
    v = circle_coordinates(d, r, phi)
    _, J = project(K, v @ R.T)  # (N, 2, 3)
    g = np.einsum("ni,nij->nj", n, J)  # (N, 3) de/dX
    g_local = g @ R  # (N, 3) de/d(R v)
    H_line = np.cross(v, g_local)
    dX_dr = np.stack([np.sin(phi), np.zeros_like(phi), np.cos(phi)], axis=-1)
    H_circle = np.column_stack([g_local[:, 1], np.sum(g_local * dX_dr, axis=1)])
    return e, H_line, H_circle


def make_reference_circle_factor(noise, line_key: int, circle_key: int, pixels, K) -> gtsam.CustomFactor:
    """The original circle-point factor (fresh grid search on every call)."""
    pixels = np.array(pixels, dtype=float).reshape(-1, 2)
    K = np.array(K, dtype=float).reshape(3, 3)

    def error_func(this: gtsam.CustomFactor, values: gtsam.Values, H) -> np.ndarray:
        keys = this.keys()
        d, r = values.atVector(keys[1])
        e, H_line, H_circle = circle_point_residuals(K, values.atRot3(keys[0]), d, r, pixels,
                                                     jacobians=H is not None)
        if H is not None:
            H[0] = H_line
            H[1] = H_circle
        return e

    return gtsam.CustomFactor(noise, [line_key, circle_key], error_func)

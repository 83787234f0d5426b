"""Pure, vectorised geometry of the line variable, its coaxial circles and their images.

No factors here: every function takes and returns numpy arrays (plus ``gtsam.Rot3`` where a line variable is
built), so the factor wrappers in :mod:`.circle` and :mod:`.axis` stay thin.

Parametrisation (camera frame, stage-1 scene known only up to scale):

- A line variable is a rotation ``R`` with columns ``(c0, c1, c2)``. The line is ``{c0 + s c1}``: ``c0`` is the
  foot of the perpendicular from the camera centre (unit distance: the scale gauge), ``c1`` the direction,
  ``c2 = c0 x c1`` the normal of the plane through the camera centre that contains the line.
- A circle at offset ``d`` along ``c1`` (from the foot) with radius ``r`` has points
  ``X(phi) = R @ (1 + r sin(phi), d, r cos(phi)) = c0 + d c1 + r (cos(phi) c2 + sin(phi) c0)``.
- Perturbations of ``R`` are GTSAM's: ``R * Exp(w)``; all Jacobians wrt ``R`` are wrt ``w``.
- Pixels are ideal (undistorted): ``u = pi(K X)`` with ``pi(y) = (y0 / y2, y1 / y2)``; for an intrinsic matrix
  (last row ``(0, 0, 1)``) this is ``K pi(X)``.
"""

from __future__ import annotations

import gtsam
import numpy as np

#: Phases on the coarse grid of :func:`closest_phases`.
PHASE_GRID_SIZE = 72
#: Newton iterations after the grid search of :func:`closest_phases`.
PHASE_NEWTON_STEPS = 8


def skew(v: np.ndarray) -> np.ndarray:
    """Cross-product matrices: (..., 3) -> (..., 3, 3) with ``skew(a) @ b == cross(a, b)``."""
    v = np.asarray(v, dtype=float)
    out = np.zeros(v.shape[:-1] + (3, 3))
    out[..., 0, 1], out[..., 0, 2] = -v[..., 2], v[..., 1]
    out[..., 1, 0], out[..., 1, 2] = v[..., 2], -v[..., 0]
    out[..., 2, 0], out[..., 2, 1] = -v[..., 1], v[..., 0]
    return out


def _matrix(R) -> np.ndarray:
    """3x3 matrix of a ``gtsam.Rot3`` or of an array-like."""
    return np.asarray(R.matrix() if hasattr(R, "matrix") else R, dtype=float)


# ----------------------------------------------------------------------------------------------------------------
# Points on the line and on its coaxial circles (camera frame, unit scale)
# ----------------------------------------------------------------------------------------------------------------


def line_points(R, s) -> np.ndarray:
    """Points ``c0 + s c1`` of the line variable ``R`` (Rot3 or 3x3): s (N,) -> (N, 3)."""
    R = _matrix(R)
    s = np.atleast_1d(np.asarray(s, dtype=float))
    return R[:, 0][None, :] + s[:, None] * R[:, 1][None, :]


def circle_coordinates(d: float, r: float, phi) -> np.ndarray:
    """Circle points in the line variable's own coordinates: ``v = (1 + r sin(phi), d, r cos(phi))``, (N, 3)."""
    phi = np.atleast_1d(np.asarray(phi, dtype=float))
    return np.stack([1.0 + r * np.sin(phi), np.full_like(phi, d), r * np.cos(phi)], axis=-1)


def circle_points(R, d: float, r: float, phi) -> np.ndarray:
    """Camera-frame points ``X(phi) = R @ (1 + r sin(phi), d, r cos(phi))``: phi (N,) -> (N, 3)."""
    return circle_coordinates(d, r, phi) @ _matrix(R).T


# ----------------------------------------------------------------------------------------------------------------
# Projection and image lines
# ----------------------------------------------------------------------------------------------------------------


def project(K, X) -> tuple[np.ndarray, np.ndarray]:
    """Ideal pixels of camera-frame points and their Jacobian.

    Args:
        K: (3, 3) intrinsic matrix.
        X: (..., 3) camera-frame points (in front of the camera, ``(K X)_2 > 0``).

    Returns:
        u: (..., 2) pixels ``pi(K X)``.
        J: (..., 2, 3) Jacobian ``du/dX``.
    """
    K = np.asarray(K, dtype=float)
    y = np.asarray(X, dtype=float) @ K.T
    inv_z = 1.0 / y[..., 2]
    u = y[..., :2] * inv_z[..., None]
    # du/dy = [I_2 | -u] / y2, then du/dX = du/dy @ K.
    dudy = np.concatenate([np.broadcast_to(np.eye(2), u.shape[:-1] + (2, 2)), -u[..., :, None]], axis=-1)
    J = (dudy * inv_z[..., None, None]) @ K
    return u, J


def image_line_from_rot3(K, R) -> tuple[np.ndarray, np.ndarray]:
    """Homogeneous image line of the projected line variable, and its Jacobian wrt the Rot3 tangent.

    The plane through the camera centre and the line has normal ``c2``, so the image line is ``m = K^-T c2``,
    returned normalised as ``l = m / |m[:2]|`` (``l1^2 + l2^2 = 1``, same sign as ``K^-T c2``). The signed pixel
    distance of pixel ``u`` to the line is ``l . (u, 1)``.

    Derivation: ``R Exp(w) e3 = c2 + w1 c0 - w0 c1 + O(w^2)``, so ``dm/dw = K^-T [-c1, c0, 0]``; normalisation
    gives ``dl = (I - l (l1, l2, 0)^T) dm / |m[:2]|``.

    Args:
        K: (3, 3) intrinsic matrix.
        R: line variable (``gtsam.Rot3`` or (3, 3)).

    Returns:
        l: (3,) normalised homogeneous line.
        J: (3, 3) Jacobian ``dl/dw``.
    """
    R = _matrix(R)
    K_inv_T = np.linalg.inv(np.asarray(K, dtype=float)).T
    m = K_inv_T @ R[:, 2]
    rho = np.hypot(m[0], m[1])
    l = m / rho
    dm = K_inv_T @ np.column_stack([-R[:, 1], R[:, 0], np.zeros(3)])
    J = (np.eye(3) - np.outer(l, [l[0], l[1], 0.0])) @ dm / rho
    return l, J


def line_distances(line, pixels) -> np.ndarray:
    """Signed distances ``l . (u, 1)`` of pixels (M, 2) to a normalised homogeneous line (3,): (M,)."""
    pixels = np.asarray(pixels, dtype=float)
    line = np.asarray(line, dtype=float)
    return pixels @ line[:2] + line[2]


def line_distance_covariance(line_cov, test_pixels) -> np.ndarray:
    """First-order covariance of the distances of M fixed test pixels to an uncertain image line.

    The distance ``e_i = l . (u_i, 1)`` is linear in a perturbation ``dl`` of the normalised line, so
    ``Cov(e) = A Sigma_l A^T`` with rows ``A_i = (u_i, 1)``. A line covariance in a Rot3 line variable's tangent
    converts as ``Sigma_l = J Sigma_R J^T`` with ``J`` from :func:`image_line_from_rot3`.

    Args:
        line_cov: (3, 3) covariance of ``l`` (perturbation in the tangent of the normalised line).
        test_pixels: (M, 2) pixels where the distances are taken.

    Returns:
        (M, M) covariance of the M distances (for ``gtsam.noiseModel.Gaussian.Covariance``).
    """
    pixels = np.asarray(test_pixels, dtype=float).reshape(-1, 2)
    A = np.column_stack([pixels, np.ones(len(pixels))])
    cov = A @ np.asarray(line_cov, dtype=float) @ A.T
    return 0.5 * (cov + cov.T)


def rot3_from_line(point_cam, direction_cam) -> tuple[gtsam.Rot3, float]:
    """Line variable of a metric camera-frame line, and the scale that converts metric lengths to it.

    ``c0`` is the unit vector to the foot of the perpendicular from the camera centre, ``c1`` the unit direction,
    ``c2 = c0 x c1``. With ``distance`` the camera-to-line distance, a circle at metric offset ``d_metric`` from
    ``point_cam`` along ``direction_cam`` with radius ``r_metric`` has ``d = (d_metric + point_cam . c1) / distance``
    and ``r = r_metric / distance``.

    Args:
        point_cam: (3,) a point of the line, camera frame (metres).
        direction_cam: (3,) its direction (any non-zero length).

    Returns:
        R: the ``gtsam.Rot3`` line variable.
        distance: camera-centre-to-line distance (metres), > 0.
    """
    p = np.asarray(point_cam, dtype=float).reshape(3)
    a = np.asarray(direction_cam, dtype=float).reshape(3)
    a = a / np.linalg.norm(a)
    foot = p - (p @ a) * a
    distance = float(np.linalg.norm(foot))
    if not np.isfinite(distance) or distance < 1e-12:
        raise ValueError("the line passes through the camera centre: its image is a point, not a line")
    c0 = foot / distance
    return gtsam.Rot3(np.column_stack([c0, a, np.cross(c0, a)])), distance


# ----------------------------------------------------------------------------------------------------------------
# Projected circles: curve derivatives and closest phases
# ----------------------------------------------------------------------------------------------------------------


def projected_circle(K, R, d: float, r: float, phi) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Pixels of the projected circle and their first two derivatives wrt the phase.

    With ``y = K X(phi)`` and ``u = y[:2] / y2``: ``u' = (y[:2]' - u y2') / y2`` and
    ``u'' = (y[:2]'' - u y2'' - 2 u' y2') / y2``.

    Returns:
        u, du/dphi, d2u/dphi2: each (N, 2) for phi (N,).
    """
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
    """Phase of the projected-circle point closest (in pixels) to each observed pixel.

    A coarse grid of ``grid_size`` phases picks the nearest sample per pixel; then ``newton_steps`` vectorised
    Newton steps on ``f(phi) = |u(phi) - u_obs|^2 / 2`` (gradient ``g = u' . e``, Hessian ``u' . u' + u'' . e``
    with ``e = u - u_obs``; Gauss-Newton where that Hessian is not safely positive; steps clamped to one grid
    cell). No loop over pixels.

    Args:
        K: (3, 3) intrinsic matrix.
        R: line variable (``gtsam.Rot3`` or (3, 3)).
        d, r: circle offset and radius (unit scale).
        pixels: (N, 2) observed ideal pixels.

    Returns:
        (N,) phases in [-pi, pi).
    """
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
    """Signed geometric pixel distances of observed pixels to the projected circle, with Jacobians.

    ``e_i = n_i . (u(phi_i) - u_obs_i)`` with ``phi_i`` the closest phase and ``n_i`` the unit normal of the
    projected curve at ``phi_i`` pointing towards its centre of curvature (inwards for an ellipse), so
    ``e_i > 0`` when ``u_obs_i`` lies outside the projected circle and ``|e_i|`` is its pixel distance.

    Jacobians hold ``phi_i`` and ``n_i`` fixed (envelope theorem: ``de/dphi = 0`` at the closest phase, and
    ``dn`` is orthogonal to ``n`` while ``u - u_obs`` is parallel to it). With ``g_i = (n_i^T du/dX)`` (row) and
    ``v_i = (1 + r sin, d, r cos)``: ``X(R Exp(w)) = X + R (w x v)``, so ``de = (R^T g) . (w x v) = w . (v x R^T g)``,
    i.e. ``de_i/dw = v_i x (R^T g_i)``; ``de/dd = g . c1``; ``de/dr = g . R (sin, 0, cos)``.

    Args:
        K: (3, 3) intrinsic matrix.
        R: line variable (``gtsam.Rot3`` or (3, 3)).
        d, r: circle offset and radius (unit scale).
        pixels: (N, 2) observed ideal pixels.
        jacobians: also return the Jacobians.

    Returns:
        e: (N,) signed distances (px).
        H_line: (N, 3) ``de/dw`` (Rot3 tangent) or None.
        H_circle: (N, 2) ``de/d(d, r)`` or None.
    """
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


# ----------------------------------------------------------------------------------------------------------------
# Projected FK axis test points
# ----------------------------------------------------------------------------------------------------------------


def transform_to_camera(arm_T_camera, points_arm) -> tuple[np.ndarray, np.ndarray]:
    """Arm-frame points mapped to the camera frame, with the Jacobian wrt the Pose3 tangent.

    ``X = camera_T_arm * P = R^T (P - t)``. Perturbing ``arm_T_camera * Exp((w, rho))`` gives
    ``X' = Exp(-w) R^T (P - t - R rho) = X + [X]x w - rho`` to first order (GTSAM: rotation first, translation in
    the camera frame).

    Args:
        arm_T_camera: ``gtsam.Pose3``.
        points_arm: (M, 3) arm-frame points.

    Returns:
        X: (M, 3) camera-frame points.
        J: (M, 3, 6) ``dX/dxi``.
    """
    P = np.asarray(points_arm, dtype=float).reshape(-1, 3)
    R = arm_T_camera.rotation().matrix()
    t = np.asarray(arm_T_camera.translation(), dtype=float)
    X = (P - t) @ R
    J = np.concatenate([skew(X), np.broadcast_to(-np.eye(3), X.shape[:1] + (3, 3))], axis=-1)
    return X, J


def axis_point_residuals(K, arm_T_camera, points_arm, line) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Signed distances of projected arm-frame test points to an image line, with Jacobians.

    ``e_i = l . (u_i, 1)``, ``u_i = pi(K camera_T_arm P_i)``. With ``g_i = l[:2]^T du/dX`` (row):
    ``de_i/dw = g_i [X_i]x = (g_i x X_i)^T``, ``de_i/drho = -g_i``, ``de_i/dl = (u_i, 1)``.

    Args:
        K: (3, 3) intrinsic matrix.
        arm_T_camera: ``gtsam.Pose3``.
        points_arm: (M, 3) FK axis test points, arm frame.
        line: (3,) normalised homogeneous image line.

    Returns:
        e: (M,) signed distances (px).
        H_pose: (M, 6) ``de/dxi``.
        H_line: (M, 3) ``de/dl``.
    """
    line = np.asarray(line, dtype=float)
    X, J_pose = transform_to_camera(arm_T_camera, points_arm)
    u, J_proj = project(K, X)
    e = line_distances(line, u)
    g = J_proj.transpose(0, 2, 1) @ line[:2]  # (M, 3)
    H_pose = np.einsum("mi,mij->mj", g, J_pose)
    H_line = np.column_stack([u, np.ones(len(u))])
    return e, H_pose, H_line

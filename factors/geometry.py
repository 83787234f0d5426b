"""Pure, vectorised geometry of the line variable, its coaxial circles and their images.

No factors here: every function takes and returns numpy arrays (plus ``gtsam.Rot3`` where a line variable is
built), so the factor wrappers in :mod:`.circle` and :mod:`.axis` stay thin. The closest phases of pixels on a
projected circle (the circle-point residuals and their Jacobians) are :mod:`.circle_track`'s, with the image
ellipse's certificates in :mod:`.ellipse`.

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


def skew(v: np.ndarray) -> np.ndarray:
    """Cross-product matrices: (..., 3) -> (..., 3, 3) with ``skew(a) @ b == cross(a, b)``."""
    v = np.asarray(v, dtype=float)
    out = np.zeros(v.shape[:-1] + (3, 3))
    out[..., 0, 1], out[..., 0, 2] = -v[..., 2], v[..., 1]
    out[..., 1, 0], out[..., 1, 2] = v[..., 2], -v[..., 0]
    out[..., 2, 0], out[..., 2, 1] = -v[..., 1], v[..., 0]
    return out


def cal3_s2(K) -> gtsam.Cal3_S2:
    """The ``gtsam.Cal3_S2`` (``fx, fy, s, cx, cy``) of a (3, 3) intrinsic matrix."""
    K = np.asarray(K, dtype=float)
    return gtsam.Cal3_S2(K[0, 0], K[1, 1], K[0, 1], K[0, 2], K[1, 2])


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


def image_line_intrinsics_jacobian(K, R, distances) -> np.ndarray:
    """(M, 5) derivatives of the signed distances ``distances`` (M,) of fixed 3-D points' images to the image of the
    line variable ``R`` (:func:`image_line_from_rot3`) wrt the intrinsics, in ``gtsam.Cal3_S2``'s tangent order
    ``(fx, fy, s, cx, cy)``.

    The distance of the image of a camera-frame point ``X`` is ``e = (c2 . X / X_z) / rho`` with ``rho = |m[:2]|``,
    ``m = K^-T c2``: the numerator is the same for every ``K`` (the plane through the camera centre and the line),
    so ``de = -e drho / rho``. With ``K^T m = c2``: ``m0 = c0/fx``, ``m1 = (c1 - s m0)/fy``; ``cx`` and ``cy`` only
    move ``m2`` and do not change the distances.
    """
    R = _matrix(R)
    K = np.asarray(K, dtype=float)
    fx, s, fy = K[0, 0], K[0, 1], K[1, 1]
    c = R[:, 2]
    m0 = c[0] / fx
    m1 = (c[1] - s * m0) / fy
    rho2 = m0 * m0 + m1 * m1
    dm0 = np.array([-m0 / fx, 0.0, 0.0, 0.0, 0.0])
    dm1 = np.array([s * m0 / (fx * fy), -m1 / fy, -m0 / fy, 0.0, 0.0])
    return -np.outer(np.asarray(distances, dtype=float), m0 * dm0 + m1 * dm1) / rho2


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
# Projected circles: curve derivatives (closest phases: see :mod:`.circle_track`)
# ----------------------------------------------------------------------------------------------------------------


def projected_circle(K, R, d: float, r: float, phi) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Pixels of the projected circle and their first two derivatives wrt the phase.

    With ``y = K X(phi) = A + B sin(phi) + C cos(phi)`` and ``u = y[:2] / y2``: ``u' = (y[:2]' - u y2') / y2`` and
    ``u'' = (y[:2]'' - u y2'' - 2 u' y2') / y2``, where ``y'' = A - y`` gives ``y[:2]'' - u y2'' = A[:2] - u A2``.

    Returns:
        u, du/dphi, d2u/dphi2: each (N, 2) for phi (N,).
    """
    R = _matrix(R)
    K = np.asarray(K, dtype=float)
    phi = np.atleast_1d(np.asarray(phi, dtype=float))
    s, c = np.sin(phi)[:, None], np.cos(phi)[:, None]
    KR = K @ R
    A = KR[:, 0] + d * KR[:, 1]
    B = r * KR[:, 0]
    C = r * KR[:, 2]
    y = A + s * B + c * C  # (N, 3)
    dy = c * B - s * C
    inv_z = 1.0 / y[:, 2:]
    u = y[:, :2] * inv_z
    dz = dy[:, 2:]
    du = (dy[:, :2] - u * dz) * inv_z
    ddu = (A[:2] - u * A[2] - 2.0 * du * dz) * inv_z
    return u, du, ddu


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
    # Written out for speed (this runs in every stage-2 factor call): the same maths as transform_to_camera + project.
    line = np.asarray(line, dtype=float)
    K = np.asarray(K, dtype=float)
    P = np.asarray(points_arm, dtype=float).reshape(-1, 3)
    R = arm_T_camera.rotation().matrix()
    X = (P - arm_T_camera.translation()) @ R
    y = X @ K.T
    inv_z = 1.0 / y[:, 2]
    u = y[:, :2] * inv_z[:, None]
    e = u @ line[:2] + line[2]
    # g = l[:2]^T du/dX with du/dy = [I_2 | -u] / y2
    g = np.empty_like(X)
    g[:, 0], g[:, 1], g[:, 2] = line[0] * inv_z, line[1] * inv_z, (line[2] - e) * inv_z
    g = g @ K
    H_pose = np.empty((len(X), 6))
    H_pose[:, 0] = g[:, 1] * X[:, 2] - g[:, 2] * X[:, 1]  # g x X (np.cross is slow on small arrays)
    H_pose[:, 1] = g[:, 2] * X[:, 0] - g[:, 0] * X[:, 2]
    H_pose[:, 2] = g[:, 0] * X[:, 1] - g[:, 1] * X[:, 0]
    H_pose[:, 3:] = -g
    H_line = np.ones((len(u), 3))
    H_line[:, :2] = u
    return e, H_pose, H_line

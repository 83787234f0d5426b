"""Initial values that need no guess (docs/design.md §5).

1. Per track: a direct least-squares ellipse (``cv2.fitEllipseDirect``) on the undistorted pixels.
2. Per measurement: the projected axis ``l_k`` as the total-least-squares line through the ellipse
   centres (falling back on the mean minor-axis direction when the centres are bunched).
3. For the pose: each image line back-projects to a plane through the camera centre with normal
   ``n_k = K^T l_k`` (camera frame) that must contain the FK wrist axis (point p_k, direction a_k):
   ``(R n_k) . a_k = 0`` and ``(R n_k) . (p_k - t) = 0`` with ``R = arm_R_camera``,
   ``t = arm_t_camera``. Given R the second is linear in t. R is searched over a fixed, deterministic
   grid of SO(3); the best few distinct candidates are returned for refinement.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import gtsam
import numpy as np

from .errors import InputError
from .geometry import Line3

#: Fewest points cv2.fitEllipseDirect accepts; fewer make a track unusable for initialisation.
MIN_ELLIPSE_POINTS = 6


@dataclass(frozen=True)
class Ellipse:
    centre: np.ndarray  # (2,) ideal pixels
    axes: np.ndarray  # (2,) full axis lengths, as OpenCV reports them
    angle_deg: float  # OpenCV's rotation angle of the first axis

    @property
    def minor_direction(self) -> np.ndarray:
        """Unit direction of the minor axis in the image."""
        theta = np.radians(self.angle_deg)
        first = np.array([np.cos(theta), np.sin(theta)])
        second = np.array([-np.sin(theta), np.cos(theta)])
        return first if self.axes[0] <= self.axes[1] else second


def fit_ellipse(pixels: np.ndarray) -> Ellipse | None:
    """Direct least-squares ellipse through (N, 2) ideal pixels, or None when it is degenerate."""
    pixels = np.asarray(pixels, dtype=float)
    if len(pixels) < MIN_ELLIPSE_POINTS:
        return None
    offset = pixels.mean(axis=0)
    try:
        (cx, cy), (w, h), angle = cv2.fitEllipseDirect((pixels - offset).astype(np.float32))
    except cv2.error:
        return None
    axes = np.array([w, h], dtype=float)
    if not np.all(np.isfinite(axes)) or np.min(axes) <= 1e-6 or not np.isfinite(cx + cy):
        return None
    return Ellipse(np.array([cx, cy]) + offset, axes, float(angle))


def normalise_line(line) -> np.ndarray:
    """Homogeneous image line scaled so that l1^2 + l2^2 = 1."""
    line = np.asarray(line, dtype=float)
    norm = np.hypot(line[0], line[1])
    if norm < 1e-15:
        raise InputError(f"not an image line (l1 = l2 = 0): {line.tolist()}")
    return line / norm


def line_through_points(points: np.ndarray, weights=None) -> np.ndarray:
    """Total-least-squares homogeneous line through (M >= 2, 2) points, normalised."""
    points = np.asarray(points, dtype=float)
    w = np.ones(len(points)) if weights is None else np.asarray(weights, dtype=float)
    centroid = (w[:, None] * points).sum(axis=0) / w.sum()
    diff = (points - centroid) * np.sqrt(w)[:, None]
    _, _, vt = np.linalg.svd(diff, full_matrices=False)
    normal = vt[-1]
    return normalise_line([normal[0], normal[1], -normal @ centroid])


def initial_image_axis(ellipses: list[Ellipse]) -> np.ndarray:
    """The projected wrist axis of one measurement from its tracks' ellipses (normalised line)."""
    if len(ellipses) < 2:
        raise InputError(f"need at least 2 fitted ellipses to find the projected axis, got {len(ellipses)}")
    centres = np.array([e.centre for e in ellipses])
    spread = np.linalg.svd(centres - centres.mean(axis=0), compute_uv=False)
    sizes = np.array([np.max(e.axes) for e in ellipses])
    if spread[0] > 0.2 * np.median(sizes) and spread[0] > 3.0 * spread[-1]:
        return line_through_points(centres)
    # bunched centres: use the mean minor-axis direction (the axis' image direction) through them
    directions = np.array([e.minor_direction for e in ellipses])
    directions *= np.sign(directions @ directions[0])[:, None]
    d = directions.mean(axis=0)
    centroid = centres.mean(axis=0)
    return normalise_line([-d[1], d[0], d[1] * centroid[0] - d[0] * centroid[1]])


def plane_normal(K: np.ndarray, line: np.ndarray) -> np.ndarray:
    """Unit normal (camera frame) of the plane through the camera centre that projects to ``line``."""
    n = np.asarray(K).T @ np.asarray(line, dtype=float)
    return n / np.linalg.norm(n)


def so3_grid(n: int = 30000, seed: int = 7) -> np.ndarray:
    """A fixed, deterministic near-uniform set of rotation matrices (n, 3, 3) (uniform quaternions)."""
    rng = np.random.default_rng(seed)
    q = rng.normal(size=(n, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    w, x, y, z = q.T
    return np.stack(
        [
            np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)], axis=-1),
            np.stack([2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)], axis=-1),
            np.stack([2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)], axis=-1),
        ],
        axis=1,
    )


#: Relative weight of the depth regulariser in the batched t-solve.
_DEPTH_WEIGHT = 1e-4
#: Depth (m) at which a camera position is placed along a direction the data leave undetermined.
NOMINAL_DEPTH = 1.0


def _translations(m: np.ndarray, points: np.ndarray, forward: np.ndarray) -> np.ndarray:
    """Batched least-squares t with m_k . t = m_k . p_k; m (G, n, 3), points (n, 3) -> (G, 3).

    When every axis passes through one point P the system is rank-deficient: t slides along the ray through
    P. A weak regulariser (relative weight ``_DEPTH_WEIGHT``) asks for the wrist centroid to be
    ``NOMINAL_DEPTH`` in front of the camera (``forward``: (G, 3) camera z-axes in the arm frame), which picks
    a point on that ray and barely moves a well-determined t (LM refines it without the regulariser; the
    observability analysis reports an undetermined direction).
    """
    rhs = np.einsum("gki,ki->gk", m, points)
    A = m.transpose(0, 2, 1) @ m  # (batched matmul: 5x einsum's speed here)
    b = np.einsum("gki,gk->gi", m, rhs)
    eps = _DEPTH_WEIGHT * np.trace(A, axis1=1, axis2=2)
    target = forward @ points.mean(axis=0) - NOMINAL_DEPTH
    A = A + eps[:, None, None] * np.einsum("gi,gj->gij", forward, forward) + 1e-12 * np.eye(3)
    b = b + (eps * target)[:, None] * forward
    return np.linalg.solve(A, b[..., None])[..., 0]


def pose_candidates(normals_camera: np.ndarray, axes_arm: list[Line3], *, n_best: int = 5,
                    grid: np.ndarray | None = None, min_separation_deg: float = 15.0) -> list[gtsam.Pose3]:
    """Candidate ``arm_T_camera`` poses from back-projected planes and FK axes, best first.

    ``normals_camera`` (n, 3): plane normals ``K^T l_k``; ``axes_arm``: the FK wrist axes. Candidates
    put every wrist point in front of the camera and are at least ``min_separation_deg`` apart.
    """
    normals = np.asarray(normals_camera, dtype=float)
    normals = normals / np.linalg.norm(normals, axis=1, keepdims=True)
    if len(normals) != len(axes_arm):
        raise InputError(f"{len(normals)} plane normals for {len(axes_arm)} axes")
    points = np.array([a.point for a in axes_arm])
    directions = np.array([a.direction for a in axes_arm])
    rotations = so3_grid() if grid is None else grid
    m = normals @ rotations.transpose(0, 2, 1)  # (G, n, 3) plane normals in the arm frame
    t = _translations(m, points, rotations[:, :, 2])
    depth_scale = max(np.median(np.linalg.norm(points - points.mean(axis=0), axis=1)), 0.1)
    rot_cost = np.einsum("gki,ki->gk", m, directions) ** 2
    dist_cost = (np.einsum("gki,gki->gk", m, points[None] - t[:, None]) / depth_scale) ** 2
    cost = rot_cost.sum(axis=1) + dist_cost.sum(axis=1)
    # chirality: wrist points in front of the camera (z_camera = R^T (p - t) . e_z = (p - t) . R[:, 2])
    depth = np.einsum("gki,gi->gk", points[None] - t[:, None], rotations[:, :, 2])
    cost[np.any(depth <= 0.05, axis=1)] = np.inf
    order = np.argsort(cost)
    chosen: list[int] = []
    cos_sep = np.cos(np.radians(min_separation_deg))
    for g in order:
        if not np.isfinite(cost[g]) or len(chosen) == n_best:
            break
        # rotation angle between candidates: trace(Ra^T Rb) = 1 + 2 cos(angle)
        if all((np.trace(rotations[c].T @ rotations[g]) - 1.0) / 2.0 < cos_sep for c in chosen):
            chosen.append(int(g))
    return [gtsam.Pose3(gtsam.Rot3(rotations[g]), t[g]) for g in chosen]

"""Pure geometry helpers on numpy arrays (no GTSAM factors, no I/O).

Frame names follow docs/design.md §2: ``a_T_b`` maps coordinates in frame b to frame a.
"""

from __future__ import annotations

from dataclasses import dataclass

import gtsam
import numpy as np

from .errors import InputError


def unit(vector, what: str = "vector") -> np.ndarray:
    """Return ``vector`` scaled to unit length; raise :class:`InputError` on a zero or non-finite one."""
    v = np.asarray(vector, dtype=float)
    norm = np.linalg.norm(v)
    if not np.isfinite(norm) or norm < 1e-12:
        raise InputError(f"{what} must be a finite non-zero vector, got {v.tolist()}")
    return v / norm


def perpendicular_basis(direction) -> tuple[np.ndarray, np.ndarray]:
    """A fixed right-handed orthonormal pair (e1, e2) perpendicular to ``direction``.

    ``(e1, e2, direction)`` is right handed. The choice is deterministic and continuous except where
    ``direction`` crosses the plane |a_x| = |a_z| boundary of the helper axis switch.
    """
    a = unit(direction, "axis direction")
    helper = np.array([1.0, 0.0, 0.0]) if abs(a[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    e1 = unit(np.cross(helper, a))
    e2 = np.cross(a, e1)
    return e1, e2


def rotation_about_axis(direction, angles) -> np.ndarray:
    """Rodrigues rotation matrices about unit ``direction`` for each angle: (F,) -> (F, 3, 3)."""
    a = unit(direction, "axis direction")
    angles = np.atleast_1d(np.asarray(angles, dtype=float))
    skew = np.array([[0.0, -a[2], a[1]], [a[2], 0.0, -a[0]], [-a[1], a[0], 0.0]])
    s = np.sin(angles)[:, None, None]
    c = np.cos(angles)[:, None, None]
    return np.eye(3)[None] + s * skew[None] + (1.0 - c) * (skew @ skew)[None]


@dataclass(frozen=True, eq=False)
class Line3:
    """An oriented 3-D line: a point on it and a unit direction (both in one named frame)."""

    point: np.ndarray
    direction: np.ndarray

    def __init__(self, point, direction):
        point = np.array(point, dtype=float).reshape(3)
        if not np.all(np.isfinite(point)):
            raise InputError(f"line point must be finite, got {point.tolist()}")
        direction = unit(np.array(direction, dtype=float).reshape(3), "line direction")
        point.setflags(write=False)
        direction.setflags(write=False)
        object.__setattr__(self, "point", point)
        object.__setattr__(self, "direction", direction)

    @classmethod
    def from_point_direction(cls, point, direction) -> Line3:
        return cls(point, direction)

    @classmethod
    def from_plucker(cls, direction, moment) -> Line3:
        """Line from Plücker coordinates (direction d, moment m = p x d); the point is the foot from 0."""
        d = np.asarray(direction, dtype=float)
        m = np.asarray(moment, dtype=float)
        scale = np.dot(d, d)
        return cls(np.cross(d, m) / scale, d)

    @property
    def moment(self) -> np.ndarray:
        """Plücker moment ``point x direction`` (independent of the point chosen on the line)."""
        return np.cross(self.point, self.direction)

    def points_at(self, s) -> np.ndarray:
        """Points ``point + s * direction`` for each ``s``: (M,) -> (M, 3)."""
        s = np.atleast_1d(np.asarray(s, dtype=float))
        return self.point[None, :] + s[:, None] * self.direction[None, :]

    def distance_to(self, points) -> np.ndarray:
        """Perpendicular distance of each 3-D point to the line: (N, 3) -> (N,)."""
        diff = np.atleast_2d(np.asarray(points, dtype=float)) - self.point
        return np.linalg.norm(np.cross(diff, self.direction), axis=1)

    def transformed(self, a_T_b: gtsam.Pose3) -> Line3:
        """This line (given in frame b) expressed in frame a."""
        R = a_T_b.rotation().matrix()
        return Line3(a_T_b.transformFrom(self.point), R @ self.direction)

    def __repr__(self) -> str:
        return (
            f"Line3(point={np.array2string(self.point, precision=4)}, "
            f"direction={np.array2string(self.direction, precision=4)})"
        )


def look_at(eye, target, up=(0.0, 0.0, 1.0)) -> gtsam.Pose3:
    """``world_T_camera`` of an OpenCV camera (x right, y down, z forward) at ``eye`` looking at ``target``.

    ``up`` is the world direction that should appear upwards in the image.
    """
    eye = np.asarray(eye, dtype=float)
    z = unit(np.asarray(target, dtype=float) - eye, "viewing direction (target - eye)")
    x = np.cross(z, -unit(up, "up vector"))
    if np.linalg.norm(x) < 1e-9:
        raise InputError("the up vector is parallel to the viewing direction")
    x = unit(x)
    y = np.cross(z, x)
    return gtsam.Pose3(gtsam.Rot3(np.column_stack([x, y, z])), eye)


def circle_points(center, direction, radius, phases, e1=None, e2=None) -> np.ndarray:
    """Points ``center + r (cos phi e1 + sin phi e2)`` of a 3-D circle with normal ``direction``."""
    if e1 is None or e2 is None:
        e1, e2 = perpendicular_basis(direction)
    phases = np.atleast_1d(np.asarray(phases, dtype=float))
    return (
        np.asarray(center, dtype=float)[None, :]
        + radius * np.cos(phases)[:, None] * np.asarray(e1)[None, :]
        + radius * np.sin(phases)[:, None] * np.asarray(e2)[None, :]
    )


# ---------------------------------------------------------------------------------------------------
# poses, covariances and lines: the maths the report, the exports and the estimator share


def closest_point(axes) -> np.ndarray:
    """The point with the least summed squared distance to all the (non-parallel) lines ``axes``."""
    A, b = np.zeros((3, 3)), np.zeros(3)
    for axis in axes:
        P = np.eye(3) - np.outer(axis.direction, axis.direction)
        A += P
        b += P @ axis.point
    return np.linalg.lstsq(A, b, rcond=None)[0]


#: Wrist axes that all pass within this distance (m) of one point make a single crossing.
CROSSING_TOLERANCE_M = 0.01
#: Wrist axes whose directions all lie within this angle (deg) of each other are parallel.
PARALLEL_TOLERANCE_DEG = 5.0


@dataclass
class AxisGeometry:
    """Where the wrist axes of the measurements used lie (arm frame, metres)."""

    point: np.ndarray  # the point closest to all axes
    miss: np.ndarray  # distance of each axis from it
    spread_deg: float  # largest angle between two axis directions (lines, so at most 90)
    mean_direction: np.ndarray
    indices: list[int]

    @property
    def is_crossing(self) -> bool:
        return bool(np.max(self.miss) <= CROSSING_TOLERANCE_M)

    @property
    def is_parallel(self) -> bool:
        return self.spread_deg <= PARALLEL_TOLERANCE_DEG


def axis_geometry(axes: list[Line3], indices: list[int] | None = None) -> AxisGeometry | None:
    """Common point (least squares), miss distances and angular spread of wrist axes; None for fewer than 2."""
    if len(axes) < 2:
        return None
    point = closest_point(axes)
    miss = np.array([float(a.distance_to(point)[0]) for a in axes])
    directions = np.array([a.direction for a in axes])
    cosines = np.clip(np.abs(directions @ directions.T), 0.0, 1.0)
    spread = float(np.degrees(np.arccos(cosines.min())))
    scatter = directions.T @ directions
    mean_direction = np.linalg.eigh(scatter)[1][:, -1]
    return AxisGeometry(point, miss, spread, mean_direction, list(range(len(axes))) if indices is None else indices)


def correlation(covariance: np.ndarray) -> np.ndarray:
    """Correlation matrix ``D^-1/2 Sigma D^-1/2`` of a covariance."""
    s = np.sqrt(np.diag(covariance))
    out = covariance / np.outer(s, s)
    np.fill_diagonal(out, 1.0)
    return np.clip(out, -1.0, 1.0)


def rpy_jacobian(rotation: gtsam.Rot3, step: float = 1e-6) -> np.ndarray:
    """3x3 derivative of (roll, pitch, yaw) wrt a small rotation about the fixed axes: ``Exp(d) R``."""
    J = np.zeros((3, 3))
    for i in range(3):
        d = np.zeros(3)
        d[i] = step
        plus = np.asarray(gtsam.Rot3.Expmap(d).compose(rotation).rpy())
        minus = np.asarray(gtsam.Rot3.Expmap(-d).compose(rotation).rpy())
        J[:, i] = (np.mod(plus - minus + np.pi, 2 * np.pi) - np.pi) / (2 * step)
    return J


def tangent_to_ros(arm_T_camera: gtsam.Pose3) -> np.ndarray:
    """6x6 ``J`` with ``y_ros = J xi``: GTSAM Pose3 tangent (w, rho; camera frame) to (dt, dtheta; parent)."""
    R = arm_T_camera.rotation().matrix()
    J = np.zeros((6, 6))
    J[:3, 3:] = R
    J[3:, :3] = R
    return J


def ros_covariance(arm_T_camera: gtsam.Pose3, covariance) -> np.ndarray:
    """The GTSAM-tangent covariance of ``arm_T_camera`` in the ROS PoseWithCovariance layout (module doc)."""
    covariance = _checked_covariance(covariance)
    J = tangent_to_ros(arm_T_camera)
    out = J @ covariance @ J.T
    return 0.5 * (out + out.T)


def gtsam_covariance(arm_T_camera: gtsam.Pose3, covariance_ros) -> np.ndarray:
    """Inverse of :func:`ros_covariance` (``J`` is orthogonal)."""
    covariance_ros = _checked_covariance(covariance_ros)
    J = tangent_to_ros(arm_T_camera)
    out = J.T @ covariance_ros @ J
    return 0.5 * (out + out.T)


def _checked_covariance(covariance) -> np.ndarray:
    covariance = np.asarray(covariance, dtype=float)
    if covariance.shape == (36,):
        covariance = covariance.reshape(6, 6)
    if covariance.shape != (6, 6):
        raise InputError(f"a pose covariance must be 6x6 (or 36 values), got shape {covariance.shape}")
    return covariance


def quaternion_xyzw(rotation: gtsam.Rot3) -> np.ndarray:
    """Unit quaternion (x, y, z, w) of a rotation, with w >= 0 (ROS order)."""
    q = rotation.toQuaternion()
    out = np.array([q.x(), q.y(), q.z(), q.w()])
    out /= np.linalg.norm(out)
    return -out if out[3] < 0 else out

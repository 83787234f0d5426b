"""Shared scene and helpers for the factor tests: a tiny hand-built camera/arm scene and Jacobian checks.

A uniquely named module (not conftest.py) so that ``from factor_scene import ...`` cannot collide with other
test directories' conftest modules; the fixtures live in this directory's conftest.py.
"""

from __future__ import annotations

from dataclasses import dataclass

import gtsam
import numpy as np
from gtsam.utils.numerical_derivative import numericalDerivative11

from gtsam_rotid.factors import rot3_from_line

K_NOMINAL = np.array([[570.0, 0.0, 320.0], [0.0, 575.0, 240.0], [0.0, 0.0, 1.0]])


def unit(v) -> np.ndarray:
    v = np.asarray(v, dtype=float)
    return v / np.linalg.norm(v)


def look_at(camera_position_arm, target_arm, up_arm=(0.0, 0.0, 1.0)) -> gtsam.Pose3:
    """``arm_T_camera`` of an OpenCV camera (x right, y down, z forward) at a position looking at a target."""
    z = unit(np.subtract(target_arm, camera_position_arm))
    x = unit(np.cross(-np.asarray(up_arm, dtype=float), z))
    y = np.cross(z, x)
    return gtsam.Pose3(gtsam.Rot3(np.column_stack([x, y, z])), np.asarray(camera_position_arm, dtype=float))


def perpendicular_pair(a) -> tuple[np.ndarray, np.ndarray]:
    """(e1, e2) orthonormal, perpendicular to unit a, with (e1, e2, a) right handed."""
    helper = np.array([1.0, 0.0, 0.0]) if abs(a[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    e1 = unit(np.cross(helper, a))
    return e1, np.cross(a, e1)


@dataclass
class Scene:
    """One measurement: a camera, a wrist axis and coaxial feature circles, all metric, built by hand."""

    K: np.ndarray
    arm_T_camera: gtsam.Pose3
    axis_point_arm: np.ndarray
    axis_direction_arm: np.ndarray
    offsets_m: np.ndarray  # (J,) feature offsets along the axis from axis_point_arm
    radii_m: np.ndarray  # (J,)

    @property
    def camera_T_arm(self) -> gtsam.Pose3:
        return self.arm_T_camera.inverse()

    def axis_in_camera(self) -> tuple[np.ndarray, np.ndarray]:
        camera_T_arm = self.camera_T_arm
        point_cam = camera_T_arm.transformFrom(self.axis_point_arm)
        direction_cam = camera_T_arm.rotation().matrix() @ self.axis_direction_arm
        return point_cam, direction_cam

    def circle_points_arm(self, j: int, phases) -> np.ndarray:
        e1, e2 = perpendicular_pair(self.axis_direction_arm)
        phases = np.asarray(phases, dtype=float)[:, None]
        centre = self.axis_point_arm + self.offsets_m[j] * self.axis_direction_arm
        return centre + self.radii_m[j] * (np.cos(phases) * e1 + np.sin(phases) * e2)

    def pixels(self, points_arm) -> np.ndarray:
        """Ideal pixels of arm-frame points, computed with plain gtsam/numpy (independent of factors/)."""
        X = self.arm_T_camera.transformTo(np.asarray(points_arm, dtype=float).T).T
        y = X @ self.K.T
        return y[:, :2] / y[:, 2:]

    def unit_circles(self) -> tuple[gtsam.Rot3, np.ndarray]:
        """The line variable and the (J, 2) unit-scale circle variables (d, r) of the features."""
        point_cam, direction_cam = self.axis_in_camera()
        line_cam, distance = rot3_from_line(point_cam, direction_cam)
        c1 = line_cam.matrix()[:, 1]
        d_unit = (self.offsets_m + point_cam @ c1) / distance
        return line_cam, np.column_stack([d_unit, self.radii_m / distance])


def make_scene() -> Scene:
    """Camera ~1 m from the wrist over the shoulder; axis ~45 deg to the viewing ray; 4 features 3-6 cm out."""
    arm_T_camera = look_at([0.9, -0.7, 0.8], [0.35, 0.05, 0.25])
    # Axis defined in the camera frame for good conditioning, then expressed in the arm frame.
    point_cam = np.array([0.04, -0.02, 1.0])
    direction_cam = unit([0.35, -0.45, 0.8])
    axis_point_arm = arm_T_camera.transformFrom(point_cam)
    axis_direction_arm = arm_T_camera.rotation().matrix() @ direction_cam
    return Scene(
        K=K_NOMINAL.copy(),
        arm_T_camera=arm_T_camera,
        axis_point_arm=axis_point_arm,
        axis_direction_arm=axis_direction_arm,
        offsets_m=np.array([0.0, 0.03, 0.06, 0.1]),
        radii_m=np.array([0.03, 0.045, 0.06, 0.04]),
    )


def random_line_rot3(rng: np.random.Generator, min_forward: float = 0.75) -> gtsam.Rot3:
    """Random Rot3 (Expmap of a random 3-vector) whose foot c0 lies well in front of the camera."""
    while True:
        R = gtsam.Rot3.Expmap(rng.normal(scale=1.5, size=3))
        if R.matrix()[2, 0] > min_forward:
            return R


def values_with(keys_and_values) -> gtsam.Values:
    values = gtsam.Values()
    for key, value in keys_and_values:
        values.insert(key, value)
    return values


def tangent_dim(value) -> int:
    if isinstance(value, gtsam.Pose3):
        return 6
    if isinstance(value, gtsam.Rot3):
        return 3
    if isinstance(value, gtsam.Cal3_S2):
        return 5
    return len(value)


def analytic_jacobians(factor, keys_and_values) -> list[np.ndarray]:
    """Unwhitened Jacobians of a factor, one block per key in the factor's key order (from its linearisation).

    ``linearize`` returns whitened blocks ``R H`` (R the noise model's square-root information); a CustomFactor
    cannot be cloned with a unit noise model (``cloneWithNewNoiseModel`` raises), so un-whiten with ``R``.
    Gaussian noise models only (a robust model also reweights).
    """
    A_whitened, _ = factor.linearize(values_with(keys_and_values)).jacobian()
    A = np.linalg.solve(factor.noiseModel().R(), A_whitened)
    splits = np.cumsum([tangent_dim(value) for _, value in keys_and_values])[:-1]
    return np.split(A, splits, axis=1)


def numerical_jacobians(factor, keys_and_values, delta: float = 1e-6) -> list[np.ndarray]:
    """Central-difference Jacobians of ``factor.unwhitenedError`` wrt each variable in turn."""
    blocks = []
    for i, (_key, value) in enumerate(keys_and_values):

        def h(x, i=i):
            replaced = [(k, x if j == i else v) for j, (k, v) in enumerate(keys_and_values)]
            return np.asarray(factor.unwhitenedError(values_with(replaced)), dtype=float)

        blocks.append(numericalDerivative11(h, value, delta))
    return blocks


def assert_jacobians_match(factor, keys_and_values, rtol: float = 1e-6, atol: float = 1e-6) -> None:
    analytic = analytic_jacobians(factor, keys_and_values)
    numerical = numerical_jacobians(factor, keys_and_values)
    for key_index, (H, H_num) in enumerate(zip(analytic, numerical, strict=True)):
        scale = max(1.0, float(np.max(np.abs(H_num))))
        np.testing.assert_allclose(H, H_num, rtol=rtol, atol=atol * scale, err_msg=f"Jacobian block {key_index}")

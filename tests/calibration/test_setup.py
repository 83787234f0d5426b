"""calibration.setup: what every stage needs of the measurements: the FK test points' Jacobian by the joint
angles, and declared joint-angle noise propagated into the projected-axis ties."""

import numpy as np
import pytest

from gtsam_rotid import Dataset, Measurement, simulate
from gtsam_rotid.estimate import CalibrationResult, calibrate
from gtsam_rotid.report import make_report
from gtsam_rotid.words import summary


def test_test_point_jacobian_matches_pinocchios_joint_jacobian():
    """The FK test points' derivative by the joint angles (central differences) against Pinocchio's analytic wrist
    Jacobian: the origin moves with its linear part, the point along the axis also with omega x direction."""
    import pinocchio as pin

    from gtsam_rotid.estimate import test_point_jacobian
    from gtsam_rotid.graph import TEST_POINT_SPACING

    dataset, _ = simulate.reference_scene(seed=2, duration=1.0)
    arm = dataset.arm
    q = dataset[0].joint_angles
    wrist = arm.model.getJointId(arm.wrist_joint)
    columns = [arm.model.joints[arm.model.getJointId(name)].idx_v for name in arm.joint_names]
    data = arm.model.createData()
    pin.computeJointJacobians(arm.model, data, arm.configuration(q))
    J = pin.getJointJacobian(arm.model, data, wrist, pin.LOCAL_WORLD_ALIGNED)[:, columns]
    direction = arm.wrist_axis(q).direction
    expected = np.vstack([J[:3], J[:3] + TEST_POINT_SPACING * np.cross(J[3:].T, direction).T])
    np.testing.assert_allclose(test_point_jacobian(arm, q), expected, atol=1e-8)


def with_joint_noise(dataset, sigma_deg: float, seed: int) -> Dataset:
    """The dataset with every joint-angle reading off by N(0, sigma_deg) (the tracks are the true arm's)."""
    rng = np.random.default_rng(seed)
    return Dataset(dataset.arm, dataset.camera, [
        Measurement(np.asarray(m.joint_angles) + np.radians(sigma_deg) * rng.standard_normal(len(m.joint_angles)),
                    m.tracks, name=m.name) for m in dataset])


@pytest.mark.parametrize("method", ["joint", "weighted"])
def test_joint_angle_noise_is_in_the_covariance_when_declared(method):
    """Joint readings 0.1 deg off: with exact kinematics assumed the reported covariance is far too small; declared
    as CalibrationOptions.joint_sigma_deg it is propagated into the ties and the error lies inside its region.
    (Seed 3 of the 20 s scene; the README's table has the NEES over 20 scenes.)"""
    from gtsam_rotid.estimate import CalibrationOptions

    clean, truth = simulate.reference_scene(seed=3, duration=20.0)
    noisy = with_joint_noise(clean, 0.1, seed=103)
    exact = calibrate(noisy, method=method)
    declared = calibrate(noisy, method=method, options=CalibrationOptions(joint_sigma_deg=0.1))

    def chi2(result):
        e = result.error_to(truth.arm_T_camera)
        return float(e @ np.linalg.solve(result.covariance, e))

    # undeclared, the axes' scale and floor (AxisConsistency) grow the covariance, but with six poses the pose
    # absorbs most of the joint errors and the error stays outside its 99.9 % region
    assert chi2(exact) > 22.46
    assert chi2(declared) < 22.46  # chi2(6) 99.9 % point
    # what the covariance assumes is said, and kept through save / load
    assert exact.joint_sigma_deg == 0.0 and "joint readings taken as exact" in summary(exact)
    assert declared.joint_sigma_deg == 0.1 and "uncertain by 0.1 deg" in make_report(declared, noisy).to_text()
    assert CalibrationResult.from_dict(declared.to_dict()).joint_sigma_deg == 0.1
    assert declared.axis_consistency.consistent  # the axes now agree with the pose within their noise
    # millimetres of error, and a covariance that says so
    assert np.all(declared.sigma_mm_arm > 0.5) and np.all(declared.sigma_mm_arm < 10.0)

import re

import numpy as np
import pinocchio as pin
import pytest

from gtsam_rotid import Arm, ArmError, RotIdError


def world_jacobian_axis(arm, joint_angles):
    """Independent computation: the wrist joint's column of the WORLD Jacobian holds the axis'
    Plücker coordinates [moment; direction] (velocity of the point at the world origin)."""
    model = arm.model
    data = model.createData()
    q = arm.configuration(joint_angles)
    pin.computeJointJacobians(model, data, q)
    jid = model.getJointId(arm.wrist_joint)
    column = pin.getJointJacobian(model, data, jid, pin.WORLD)[:, model.joints[jid].idx_v]
    return column[3:], column[:3]


@pytest.mark.parametrize("robot", ["kinova", "ur5"])
def test_wrist_axis_matches_world_jacobian(robot):
    arm = Arm.from_robot(robot)
    rng = np.random.default_rng(3)
    for _ in range(20):
        q = arm.random_joint_angles(rng)
        axis = arm.wrist_axis(q)
        direction, moment = world_jacobian_axis(arm, q)
        np.testing.assert_allclose(np.linalg.norm(axis.direction), 1.0)
        np.testing.assert_allclose(axis.direction, direction, atol=1e-12)
        np.testing.assert_allclose(np.cross(axis.point, axis.direction), moment, atol=1e-12)


def test_wrist_spin_keeps_its_axis():
    arm = Arm.from_robot("kinova")
    q = arm.random_joint_angles(np.random.default_rng(4))
    spun = q.copy()
    spun[arm.wrist_index] += 1.3
    a, b = arm.wrist_axis(q), arm.wrist_axis(spun)
    np.testing.assert_allclose(a.point, b.point, atol=1e-12)
    np.testing.assert_allclose(a.direction, b.direction, atol=1e-12)
    # ...while the end effector does turn about it
    ee_a, ee_b = arm.arm_T_end_effector(q), arm.arm_T_end_effector(spun)
    assert np.linalg.norm(ee_a.rotation().matrix() - ee_b.rotation().matrix()) > 0.5
    np.testing.assert_allclose(a.distance_to([ee_a.translation()]), a.distance_to([ee_b.translation()]))


def test_kinova_is_jaco2_with_continuous_joints():
    arm = Arm.from_robot("kinova")
    assert arm.joint_names == [f"j2s6s200_joint_{i}" for i in range(1, 7)]
    assert arm.wrist_joint == "j2s6s200_joint_6"
    angles = np.array([3.0, 2.0, 1.5, -2.5, 3.0, 0.7])
    q = arm.configuration(angles)
    assert q.shape == (arm.model.nq,) == (9,)
    np.testing.assert_allclose(q[:2], [np.cos(3.0), np.sin(3.0)])
    np.testing.assert_allclose(arm.joint_angles_from_configuration(q), angles)
    # a continuous joint's angle is periodic
    other = angles.copy()
    other[0] += 2 * np.pi
    np.testing.assert_allclose(arm.wrist_axis(other).point, arm.wrist_axis(angles).point, atol=1e-12)


@pytest.mark.parametrize(
    "robot, n, wrist",
    [("ur5", 6, "wrist_3_joint"), ("ur10", 6, "wrist_3_joint"), ("panda", 7, "panda_joint7"),
     ("xarm7", 7, "joint7")],
)
def test_supported_robots(robot, n, wrist):
    arm = Arm.from_robot(robot)
    assert len(arm.joint_names) == n and arm.wrist_joint == wrist
    assert np.all(arm.lower_limits < arm.upper_limits)
    q = arm.random_joint_angles(np.random.default_rng(0))
    assert arm.within_limits(q)
    assert np.isfinite(arm.wrist_axis(q).point).all()


def test_panda_excludes_fingers():
    arm = Arm.from_robot("panda")
    assert arm.joint_names == [f"panda_joint{i}" for i in range(1, 8)]
    assert arm.model.nq == 9  # fingers still in the model, held at neutral
    assert arm.end_effector_frame == "panda_hand_tcp"


def test_dict_angles_and_errors():
    arm = Arm.from_robot("ur5")
    angles = np.linspace(-1, 1, 6)
    as_dict = dict(zip(arm.joint_names, angles, strict=True))
    np.testing.assert_allclose(arm.joint_angle_vector(as_dict), angles)
    with pytest.raises(ArmError, match="expected 6 joint angles"):
        arm.wrist_axis(angles[:5])
    with pytest.raises(ArmError, match="unknown joint name.*'elbow'"):
        arm.wrist_axis({**as_dict, "elbow": 0.1})
    with pytest.raises(ArmError, match="missing for \\['wrist_3_joint'\\]"):
        arm.wrist_axis({k: v for k, v in as_dict.items() if k != "wrist_3_joint"})
    bad = angles.copy()
    bad[2] = np.nan
    with pytest.raises(ArmError, match="elbow_joint is NaN"):
        arm.wrist_axis(bad)
    with pytest.raises(ValueError):  # ArmError is a ValueError and a RotIdError
        arm.wrist_axis("abc")
    assert issubclass(ArmError, RotIdError)


def test_unknown_robot_and_ur3_trap():
    with pytest.raises(ArmError, match="no robot 'not_a_robot'"):
        Arm.from_robot("not_a_robot")
    with pytest.raises(ArmError, match="UR5"):
        Arm.from_robot("ur3")


URDF = """<?xml version="1.0"?>
<robot name="toy">
  <link name="base"/><link name="l1"/><link name="l2"/><link name="hand"/>
  <joint name="j1" type="revolute"><parent link="base"/><child link="l1"/>
    <origin xyz="0 0 0.3"/><axis xyz="0 0 1"/><limit lower="-2" upper="2" effort="1" velocity="1"/></joint>
  <joint name="j2" type="revolute"><parent link="l1"/><child link="l2"/>
    <origin xyz="0 0 0.4"/><axis xyz="0 1 0"/><limit lower="-2" upper="2" effort="1" velocity="1"/></joint>
  <joint name="wrist" type="continuous"><parent link="l2"/><child link="hand"/>
    <origin xyz="0.3 0 0"/><axis xyz="1 0 0"/></joint>
</robot>
"""


def test_from_urdf(tmp_path):
    path = tmp_path / "toy.urdf"
    path.write_text(URDF)
    arm = Arm.from_urdf(path)
    assert arm.joint_names == ["j1", "j2", "wrist"] and arm.wrist_joint == "wrist"
    axis = arm.wrist_axis([0.0, 0.0, 0.0])
    np.testing.assert_allclose(axis.point, [0.3, 0.0, 0.7], atol=1e-12)
    np.testing.assert_allclose(axis.direction, [1.0, 0.0, 0.0], atol=1e-12)
    # j2 pitches the forearm down by 90 deg: the wrist axis turns to -z, its origin to z = 0.4
    axis = arm.wrist_axis([0.0, np.pi / 2, 0.0])
    np.testing.assert_allclose(axis.direction, [0.0, 0.0, -1.0], atol=1e-12)
    np.testing.assert_allclose(axis.point, [0.0, 0.0, 0.4], atol=1e-12)
    assert Arm.from_dict(arm.to_dict()).joint_names == arm.joint_names
    assert Arm.from_urdf(path, wrist_joint="j2").wrist_joint == "j2"
    with pytest.raises(ArmError, match="wrist joint 'nope'"):
        Arm.from_urdf(path, wrist_joint="nope")
    with pytest.raises(ArmError, match="cannot read URDF"):
        Arm.from_urdf(tmp_path / "missing.urdf")


def test_inverse_kinematics_reaches_axis():
    arm = Arm.from_robot("kinova")
    rng = np.random.default_rng(5)
    q_goal = arm.random_joint_angles(rng)
    goal = arm.wrist_axis(q_goal)
    start = q_goal + rng.normal(scale=0.2, size=arm.dof)
    q = arm.solve_wrist_axis(goal.point, goal.direction, start)
    reached = arm.wrist_axis(q)
    np.testing.assert_allclose(reached.point, goal.point, atol=1e-8)
    np.testing.assert_allclose(reached.direction, goal.direction, atol=1e-8)
    assert arm.within_limits(q)


def test_joints_without_limits_in_the_urdf_are_never_refused():
    """A URDF <limit> with effort and velocity only (Pinocchio reads 0 to 0) bounds nothing; real limits do."""
    from urdf_arm import URDF_3_JOINTS

    unlimited = re.sub(r'lower="[^"]*" upper="[^"]*" ', "", URDF_3_JOINTS)
    assert unlimited != URDF_3_JOINTS
    arm = Arm.from_urdf_string(unlimited)
    assert arm.limit_problem([0.5, -2.9, 40.0]) is None
    assert "outside the model's limits" in Arm.from_urdf_string(URDF_3_JOINTS).limit_problem([0.5, -2.9, 40.0])


@pytest.mark.parametrize("robot", ["kinova", "ur5", "panda"])
def test_wrist_axis_offset_derivatives_match_finite_differences(robot):
    """The wrist axis' point and direction turned by each joint's offset: the analytic derivative against central
    differences of the forward kinematics (and the axis at the offsets is the axis at the shifted readings)."""
    arm = Arm.from_robot(robot)
    rng = np.random.default_rng(7)
    angles = arm.random_joint_angles(rng)
    joints = list(range(arm.wrist_index))
    delta = np.radians(rng.normal(scale=0.5, size=len(joints)))
    axis, d_point, d_direction = arm.wrist_axis_offset_derivatives(angles, joints, delta)
    shifted = angles.copy()
    shifted[joints] += delta
    np.testing.assert_allclose(axis.point, arm.wrist_axis(shifted).point, atol=1e-12)
    h = 1e-6
    for c, j in enumerate(joints):
        step = np.zeros(arm.dof)
        step[j] = h
        plus, minus = arm.wrist_axis(shifted + step), arm.wrist_axis(shifted - step)
        np.testing.assert_allclose(d_point[:, c], (plus.point - minus.point) / (2 * h), atol=1e-7)
        np.testing.assert_allclose(d_direction[:, c], (plus.direction - minus.direction) / (2 * h), atol=1e-7)
    assert np.linalg.norm(d_point) > 0.1  # the offsets do move the axis


def test_offset_joints_name_what_cannot_be_refined():
    arm = Arm.from_robot("kinova")
    assert arm.offset_joints(True) == [1, 2, 3, 4]  # the first joint's offset is the camera pose's
    assert arm.offset_joints("j2s6s200_joint_1") == [0]
    assert arm.offset_joints(["j2s6s200_joint_3", "j2s6s200_joint_2"]) == [2, 1]
    with pytest.raises(ArmError, match="'j2s6s200_joint_6' is the spinning joint"):
        arm.offset_joints(["j2s6s200_joint_6"])
    with pytest.raises(ArmError, match="'elbow' is not a revolute joint before the spinning joint"):
        arm.offset_joints("elbow")
    with pytest.raises(ArmError, match="listed twice"):
        arm.offset_joints(["j2s6s200_joint_2", "j2s6s200_joint_2"])
    with pytest.raises(ArmError, match="no joint offset"):
        arm.offset_joints([])


def test_a_joint_origin_corrected_by_its_offset_puts_the_wrist_where_the_reading_plus_the_offset_does():
    """The corrected URDF origins (origin turned by the offset about the joint's axis), written into a copy of the
    model: at the readings they give the wrist axis of the readings plus the offsets."""
    arm = Arm.from_robot("kinova")
    rng = np.random.default_rng(11)
    angles = arm.random_joint_angles(rng)
    joints = arm.offset_joints(True)
    offsets = np.radians(rng.normal(scale=1.0, size=len(joints)))
    model = arm.model.copy()
    for j, d in zip(joints, offsets, strict=True):
        origin = arm.corrected_joint_origin(arm.joint_names[j], d)
        model.jointPlacements[model.getJointId(arm.joint_names[j])] = pin.SE3(origin.rotation().matrix(),
                                                                               origin.translation())
    corrected = Arm(model, wrist_joint=arm.wrist_joint)
    shifted = angles.copy()
    shifted[joints] += offsets
    np.testing.assert_allclose(corrected.wrist_axis(angles).point, arm.wrist_axis(shifted).point, atol=1e-12)
    np.testing.assert_allclose(corrected.wrist_axis(angles).direction, arm.wrist_axis(shifted).direction, atol=1e-12)
    assert np.linalg.norm(arm.wrist_axis(angles).point - arm.wrist_axis(shifted).point) > 1e-3
    with pytest.raises(ArmError, match="'nope' is not a revolute joint"):
        arm.corrected_joint_origin("nope", 0.1)

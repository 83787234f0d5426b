"""Robot arm kinematics through Pinocchio: the wrist axis of each measurement in the arm-base frame.

Joint angles are one value per revolute joint (``Arm.joint_names``), model order, radians; a dict
name -> angle is accepted too. Pinocchio's configuration vector ``q`` is built only by
:meth:`Arm.configuration` (continuous joints are stored there as (cos, sin); other joints, such as
Panda's prismatic fingers, are held at their neutral value).

Pinocchio conventions are converted here and nowhere else (docs/design.md §2): Pinocchio motion vectors
are [linear; angular]; this module returns plain 3-vectors and ``gtsam.Pose3`` placements.
"""

from __future__ import annotations

import hashlib
import math
import os
from collections.abc import Mapping, Sequence

import gtsam
import numpy as np
import pinocchio as pin

from .errors import ArmError
from .geometry import Line3, unit

#: Joint readings may pass a model's limits by this much (encoder noise, soft limits) before they are refused.
LIMIT_TOLERANCE_DEG = 1.0

#: Pinocchio joint models that are 1-DoF revolute joints (bounded or continuous).
_REVOLUTE = {
    "JointModelRX",
    "JointModelRY",
    "JointModelRZ",
    "JointModelRevoluteUnaligned",
}
_CONTINUOUS = {
    "JointModelRUBX",
    "JointModelRUBY",
    "JointModelRUBZ",
    "JointModelRevoluteUnboundedUnaligned",
}

#: example-robot-data names known to work; others are tried as given.
KNOWN_ROBOTS = ("kinova", "ur5", "ur10", "panda", "xarm7")

_END_EFFECTOR_HINTS = ("end_effector", "tool0", "hand_tcp", "tcp", "eef", "ee_link", "flange", "hand")


def _pose3(se3: pin.SE3) -> gtsam.Pose3:
    return gtsam.Pose3(gtsam.Rot3(np.array(se3.rotation)), np.array(se3.translation))


class Arm:
    """A serial arm with known kinematics whose last revolute joint (the wrist) spins.

    Use the named constructors :meth:`from_robot`, :meth:`from_urdf` or :meth:`from_urdf_string`.
    """

    def __init__(self, model: pin.Model, *, wrist_joint: str | None = None, source: dict | None = None):
        self.model = model
        self._data = model.createData()
        self._source = dict(source or {})
        self._joint_ids = []  # pinocchio joint id of each revolute joint, model order
        self._continuous = []
        for jid in range(1, model.njoints):
            kind = model.joints[jid].shortname()
            if kind in _REVOLUTE or kind in _CONTINUOUS:
                self._joint_ids.append(jid)
                self._continuous.append(kind in _CONTINUOUS)
        if not self._joint_ids:
            raise ArmError("the robot model has no revolute joint")
        self.joint_names = [model.names[j] for j in self._joint_ids]
        if wrist_joint is None:
            wrist_joint = self.joint_names[-1]
        if wrist_joint not in self.joint_names:
            raise ArmError(f"wrist joint {wrist_joint!r} is not a revolute joint of the model; "
                           f"revolute joints: {self.joint_names}")
        self.wrist_joint = wrist_joint
        self._wrist_id = self._joint_ids[self.joint_names.index(wrist_joint)]
        self.wrist_index = self.joint_names.index(wrist_joint)
        lower, upper = [], []
        for jid, continuous in zip(self._joint_ids, self._continuous, strict=True):
            iq = model.joints[jid].idx_q
            if continuous:
                lower.append(-np.pi)
                upper.append(np.pi)
            else:
                lower.append(float(model.lowerPositionLimit[iq]))
                upper.append(float(model.upperPositionLimit[iq]))
        self.lower_limits = np.array(lower)
        self.upper_limits = np.array(upper)
        self.end_effector_frame = self._find_end_effector_frame()

    # ------------------------------------------------------------------ constructors
    @classmethod
    def from_robot(cls, name: str, wrist_joint: str | None = None) -> Arm:
        """An arm from example-robot-data (``kinova`` is the paper's Jaco2 j2s6s200, ``ur5``, ...)."""
        try:
            import example_robot_data as erd
        except ImportError as exc:  # pragma: no cover - a hard dependency
            raise ArmError("example-robot-data-loaders is not installed") from exc
        if name == "ur3":
            raise ArmError("example_robot_data.load('ur3') returns a UR5 model; load a UR3 URDF with "
                           "Arm.from_urdf instead")
        try:
            robot = erd.load(name)
        except Exception as exc:
            raise ArmError(f"example-robot-data has no robot {name!r} ({exc}); known to work: "
                           f"{', '.join(KNOWN_ROBOTS)}") from None
        return cls(robot.model, wrist_joint=wrist_joint, source={"robot": name})

    @classmethod
    def from_urdf(cls, path: str | os.PathLike, wrist_joint: str | None = None) -> Arm:
        """An arm from a URDF file (meshes are not needed: only the kinematic tree is read)."""
        try:
            with open(path, encoding="utf-8") as handle:
                xml = handle.read()
        except OSError as exc:
            raise ArmError(f"cannot read URDF {os.fspath(path)!r}: {exc}") from None
        arm = cls.from_urdf_string(xml, wrist_joint=wrist_joint)
        arm._source["urdf_path"] = os.path.abspath(os.fspath(path))
        return arm

    @classmethod
    def from_urdf_string(cls, xml: str, wrist_joint: str | None = None) -> Arm:
        try:
            model = pin.buildModelFromXML(xml)
        except Exception as exc:
            raise ArmError(f"Pinocchio cannot parse the URDF: {exc}") from None
        return cls(model, wrist_joint=wrist_joint, source={"urdf_xml": xml})

    @classmethod
    def from_dict(cls, data: Mapping) -> Arm:
        """Inverse of :meth:`to_dict`."""
        wrist = data.get("wrist_joint")
        if "robot" in data:
            return cls.from_robot(data["robot"], wrist_joint=wrist)
        if "urdf_xml" in data:
            return cls.from_urdf_string(data["urdf_xml"], wrist_joint=wrist)
        raise ArmError("an arm description needs 'robot' (example-robot-data name) or 'urdf_xml'")

    def to_dict(self) -> dict:
        """``{"robot": name}`` or ``{"urdf_xml": text}``, plus ``wrist_joint`` and ``joint_names``."""
        source = {k: v for k, v in self._source.items() if k != "urdf_path"}  # the text makes it self-contained
        return {**source, "wrist_joint": self.wrist_joint, "joint_names": list(self.joint_names)}

    @property
    def name(self) -> str:
        return self._source.get("robot", self.model.name or "urdf")

    @property
    def root_link(self) -> str:
        """The URDF's root link: the arm frame (``arm_T_camera``'s parent) is its frame."""
        for frame in self.model.frames:
            if frame.type == pin.FrameType.BODY and frame.parentJoint == 0:
                return frame.name
        return "universe"

    def static_links(self) -> dict[str, gtsam.Pose3]:
        """``root_T_link`` of every link fixed to the root (no joint between them): the links a camera fixed in the
        arm's base can be given in."""
        return {f.name: _pose3(f.placement) for f in self.model.frames
                if f.type == pin.FrameType.BODY and f.parentJoint == 0}

    def urdf_geometry(self, kind: str, package_dirs=None):
        """The URDF's ``kind`` ("visual" or "collision") geometry as a Pinocchio ``GeometryModel``, mesh paths
        resolved through ``package_dirs``; :class:`ArmError` for an arm without URDF text or meshes that do not
        resolve. (example-robot-data arms: load ``example_robot_data.load(name)``'s models instead.)"""
        if "urdf_xml" not in self._source:
            raise ArmError("the arm has neither an example-robot-data name nor URDF text to read its meshes from")
        geometry_type = pin.GeometryType.VISUAL if kind == "visual" else pin.GeometryType.COLLISION
        dirs = [os.fspath(d) for d in (package_dirs or [])]
        try:
            return pin.buildGeomFromUrdfString(self.model, self._source["urdf_xml"], geometry_type,
                                               package_dirs=dirs)
        except Exception as exc:
            raise ArmError(f"Pinocchio cannot read the URDF's {kind} meshes ({exc}); pass package_dirs so that "
                           f"its mesh paths resolve") from None

    def description(self) -> dict:
        """What a calibration result records of the robot: its name, root link, spinning joint, end effector, the
        links fixed to the root (``root_T_link`` as 4x4 lists), every link's name and, for a URDF, the SHA-256 of its
        text."""
        out = {"name": self.name, "root_link": self.root_link, "wrist_joint": self.wrist_joint,
               "end_effector": self.end_effector_frame,
               "static_links": {name: pose.matrix().tolist() for name, pose in self.static_links().items()},
               "links": [f.name for f in self.model.frames if f.type == pin.FrameType.BODY]}
        if "urdf_xml" in self._source:
            out["urdf_sha256"] = hashlib.sha256(self._source["urdf_xml"].encode("utf-8")).hexdigest()
        if "urdf_path" in self._source:
            out["urdf_path"] = self._source["urdf_path"]
        return out

    def __repr__(self) -> str:
        return f"Arm({self.name!r}, {len(self.joint_names)} revolute joints, wrist={self.wrist_joint!r})"

    # ------------------------------------------------------------------ joint angles
    @property
    def dof(self) -> int:
        return len(self.joint_names)

    def joint_angle_vector(self, joint_angles) -> np.ndarray:
        """Validate joint angles (sequence in ``joint_names`` order, or dict name -> angle) -> (dof,) array."""
        if isinstance(joint_angles, Mapping):
            unknown = sorted(set(joint_angles) - set(self.joint_names))
            if unknown:
                raise ArmError(f"unknown joint name(s) {unknown}; the arm's joints are {self.joint_names}")
            missing = [n for n in self.joint_names if n not in joint_angles]
            if missing:
                raise ArmError(f"joint angle(s) missing for {missing}")
            values = [joint_angles[n] for n in self.joint_names]
        elif isinstance(joint_angles, (Sequence, np.ndarray)) and not isinstance(joint_angles, str):
            values = list(np.asarray(joint_angles).ravel()) if isinstance(joint_angles, np.ndarray) \
                else list(joint_angles)
            if len(values) != self.dof:
                raise ArmError(f"expected {self.dof} joint angles ({', '.join(self.joint_names)}), "
                               f"got {len(values)}")
        else:
            raise ArmError(f"joint angles must be a sequence or a dict, got {type(joint_angles).__name__}")
        try:
            angles = np.array(values, dtype=float)
        except (TypeError, ValueError):
            raise ArmError(f"joint angles must be numbers, got {values}") from None
        bad = [self.joint_names[i] for i in np.flatnonzero(~np.isfinite(angles))]
        if bad:
            raise ArmError(f"joint angle of {', '.join(bad)} is NaN or infinite")
        return angles

    def limit_problem(self, joint_angles, tolerance_deg: float = LIMIT_TOLERANCE_DEG) -> str | None:
        """Words for the joints (bounded ones; continuous joints wrap) outside the model's limits by more than
        ``tolerance_deg``, with a hint when the values read as degrees would fit; None when all are inside."""
        angles = self.joint_angle_vector(joint_angles)
        tolerance = math.radians(tolerance_deg)
        # a URDF <limit> without lower/upper gives 0 to 0 in Pinocchio; absurd spans mean no limit either
        span = self.upper_limits - self.lower_limits
        bounded = ~np.array(self._continuous) & np.isfinite(span) & (span > 0) & (span < 1e3)
        outside = bounded & ((angles < self.lower_limits - tolerance) | (angles > self.upper_limits + tolerance))
        if not np.any(outside):
            return None
        listed = ", ".join(f"{self.joint_names[j]} = {angles[j]:.4g} rad (limits {self.lower_limits[j]:.4g} to "
                           f"{self.upper_limits[j]:.4g})" for j in np.flatnonzero(outside))
        as_radians = np.radians(angles)
        fits = np.all(~bounded | ((as_radians >= self.lower_limits - tolerance)
                                  & (as_radians <= self.upper_limits + tolerance)))
        hint = ("; the values fit the limits if they are degrees: read them as degrees (--degrees, degrees=True)"
                if fits else "; is this the right robot model, and are the angles in radians?")
        return f"joint angle(s) outside the model's limits: {listed}{hint}"

    def within_limits(self, joint_angles, tolerance: float = 1e-9) -> bool:
        q = self.joint_angle_vector(joint_angles)
        return bool(np.all(q >= self.lower_limits - tolerance) and np.all(q <= self.upper_limits + tolerance))

    def configuration(self, joint_angles) -> np.ndarray:
        """Pinocchio's ``q`` (size ``model.nq``) for the given joint angles. The one converter."""
        angles = self.joint_angle_vector(joint_angles)
        q = pin.neutral(self.model)
        for angle, jid, continuous in zip(angles, self._joint_ids, self._continuous, strict=True):
            iq = self.model.joints[jid].idx_q
            if continuous:
                q[iq] = np.cos(angle)
                q[iq + 1] = np.sin(angle)
            else:
                q[iq] = angle
        return q

    def joint_angles_from_configuration(self, q) -> np.ndarray:
        """Inverse of :meth:`configuration` (angles of continuous joints wrapped to (-pi, pi])."""
        q = np.asarray(q, dtype=float)
        out = []
        for jid, continuous in zip(self._joint_ids, self._continuous, strict=True):
            iq = self.model.joints[jid].idx_q
            out.append(np.arctan2(q[iq + 1], q[iq]) if continuous else q[iq])
        return np.array(out)

    def _limit(self, angles: np.ndarray) -> np.ndarray:
        """Clip bounded joints to their limits and wrap continuous ones to [-pi, pi)."""
        wrapped = np.where(self._continuous, (angles + np.pi) % (2 * np.pi) - np.pi, angles)
        return np.clip(wrapped, self.lower_limits, self.upper_limits)

    def wrist_range(self) -> float | None:
        """How far (rad) the spinning joint can turn between its limits; None for a continuous or unbounded one."""
        if self._continuous[self.wrist_index]:
            return None
        span = float(self.upper_limits[self.wrist_index] - self.lower_limits[self.wrist_index])
        return span if np.isfinite(span) and 0.0 < span < 1e3 else None

    def clip_joint_angles(self, joint_angles) -> np.ndarray:
        """Bounded joints clipped to their limits, continuous ones wrapped to [-pi, pi)."""
        return self._limit(self.joint_angle_vector(joint_angles))

    def random_joint_angles(self, rng: np.random.Generator) -> np.ndarray:
        return rng.uniform(self.lower_limits, self.upper_limits)

    # ------------------------------------------------------------------ kinematics
    def _forward(self, joint_angles) -> None:
        pin.forwardKinematics(self.model, self._data, self.configuration(joint_angles))

    def _local_axis(self, jid: int) -> np.ndarray:
        # Motion subspace S of a 1-DoF joint, [linear; angular] in the joint frame.
        S = np.array(self._data.joints[jid].S).reshape(6)
        return unit(S[3:], "joint axis")

    def spin_index(self, joint: str | None = None) -> int:
        """Model-order index of the spinning joint ``joint`` (a revolute joint's name; None: the wrist joint).
        Raises :class:`ArmError` naming the joints it can be."""
        if joint is None:
            return self.wrist_index
        if joint not in self.joint_names:
            raise ArmError(f"spinning joint {joint!r} is not a revolute joint of the model; revolute joints: "
                           f"{self.joint_names}")
        return self.joint_names.index(joint)

    def spins_wrist(self, joint: str | None) -> bool:
        """Whether a spin of ``joint`` (a name; None: the default) is a spin of the wrist joint."""
        return joint is None or joint == self.wrist_joint

    def wrist_axis(self, joint_angles, joint: str | None = None) -> Line3:
        """The rotation axis of the spinning joint (default the wrist) in the arm-base frame: ``.point`` = the joint's
        origin, ``.direction``."""
        jid = self._joint_ids[self.spin_index(joint)]
        self._forward(joint_angles)
        oMi = self._data.oMi[jid]
        return Line3(np.array(oMi.translation), np.array(oMi.rotation) @ self._local_axis(jid))

    def offset_joints(self, names=True, spin_joints=None) -> list[int]:
        """Indices (model order) of the joints whose offsets to refine: ``True`` every revolute joint between the
        first and the last spinning one (the first joint's offset turns the whole arm about an axis fixed in its root
        frame, as ``arm_T_camera`` does: no camera data ever determine it), or the named ones (each a revolute joint
        before the last spinning one; the first may be named, its offset then stays at its prior). ``spin_joints``:
        the measurements' spinning joints (names; None or empty: the wrist joint). Raises :class:`ArmError` naming
        the joint that cannot be one."""
        spins = sorted({self.spin_index(j) for j in (spin_joints or [None])})
        last = spins[-1]
        spinning = self.joint_names[last] if len(spins) == 1 else [self.joint_names[i] for i in spins]
        before = [self.joint_names[i] for i in range(last)]
        if names is True:
            if last < 2:
                raise ArmError(f"no joint offset the poses can determine: only {before} is before the spinning "
                               f"joint {spinning!r}, and its offset turns the arm as the camera pose does")
            return list(range(1, last))
        if isinstance(names, str):
            names = [names]
        out = []
        for name in names:
            if name == self.joint_names[last]:
                which = "the spinning joint" if len(spins) == 1 else "the last spinning joint"
                raise ArmError(f"joint {name!r} is {which}: its offset never shows in its own spin's axis; offsets "
                               f"can be refined for {before}")
            if name not in before:
                raise ArmError(f"joint {name!r} is not a revolute joint before the spinning joint "
                               f"{self.joint_names[last]!r}; offsets can be refined for {before}")
            if self.joint_names.index(name) in out:
                raise ArmError(f"joint {name!r} is listed twice among the offsets")
            out.append(self.joint_names.index(name))
        if not out:
            raise ArmError(f"no joint offset to refine; offsets can be refined for {before}")
        return out

    def corrected_joint_origin(self, name: str, offset: float) -> gtsam.Pose3:
        """The joint's origin (its frame at zero angle in its parent link's frame, a URDF ``<origin>``) turned by
        ``offset`` (rad) about its axis: with it, the reading is the joint's angle (the reading plus the offset was)."""
        if name not in self.joint_names:
            raise ArmError(f"{name!r} is not a revolute joint of the model; revolute joints: {self.joint_names}")
        jid = self._joint_ids[self.joint_names.index(name)]
        pin.forwardKinematics(self.model, self._data, pin.neutral(self.model))
        axis = self._local_axis(jid)
        turn = gtsam.Pose3(gtsam.Rot3.AxisAngle(gtsam.Point3(*axis), float(offset)), np.zeros(3))
        return _pose3(self.model.jointPlacements[jid]).compose(turn)

    def wrist_axis_offset_derivatives(self, joint_angles, joints, offsets=None, joint: str | None = None
                                      ) -> tuple[Line3, np.ndarray, np.ndarray]:
        """The spinning joint's axis (``joint``; default the wrist) at ``joint_angles`` plus ``offsets`` (radians,
        one per index in ``joints``: the reading plus the offset is the joint's angle), and the derivatives of its
        point and direction with respect to those offsets, each (3, len(joints)), arm frame. A revolute joint j
        turns everything after it about its axis (unit w_j through o_j): ``dp/d delta_j = w_j x (p - o_j)``,
        ``dd/d delta_j = w_j x d``; zero for the spinning joint itself, the joints after it and a joint that does
        not carry it (another branch)."""
        joints = [int(j) for j in joints]
        angles = self.joint_angle_vector(joint_angles).copy()
        if offsets is not None:
            offsets = np.asarray(offsets, dtype=float).reshape(len(joints))
            angles[joints] += offsets
        spin = self._joint_ids[self.spin_index(joint)]
        self._forward(angles)
        wrist = self._data.oMi[spin]
        point = np.array(wrist.translation)
        direction = np.array(wrist.rotation) @ self._local_axis(spin)
        ancestors = set(self.model.supports[spin])
        d_point, d_direction = np.zeros((3, len(joints))), np.zeros((3, len(joints)))
        for c, j in enumerate(joints):
            jid = self._joint_ids[j]
            if jid not in ancestors or jid == spin:
                continue
            placement = self._data.oMi[jid]
            w = np.array(placement.rotation) @ self._local_axis(jid)
            d_point[:, c] = np.cross(w, point - np.array(placement.translation))
            d_direction[:, c] = np.cross(w, direction)
        return Line3(point, direction), d_point, d_direction

    def wrist_axis_local(self, joint: str | None = None) -> np.ndarray:
        """Unit axis of the spinning joint (default the wrist) in its own frame (constant)."""
        jid = self._joint_ids[self.spin_index(joint)]
        pin.forwardKinematics(self.model, self._data, pin.neutral(self.model))
        return self._local_axis(jid)

    def arm_T_joint(self, joint_angles, joint: str | None = None) -> gtsam.Pose3:
        """Placement of a joint frame (default the wrist) in the arm-base frame."""
        joint = self.wrist_joint if joint is None else joint
        if not self.model.existJointName(joint):
            raise ArmError(f"unknown joint {joint!r}")
        self._forward(joint_angles)
        return _pose3(self._data.oMi[self.model.getJointId(joint)])

    def arm_T_wrist(self, joint_angles) -> gtsam.Pose3:
        """Placement of the wrist joint frame (its child link moves with it) in the arm-base frame."""
        return self.arm_T_joint(joint_angles, self.wrist_joint)

    def arm_T_frame(self, joint_angles, frame: str) -> gtsam.Pose3:
        """Placement of any Pinocchio frame (link, tool) in the arm-base frame."""
        if not self.model.existFrame(frame):
            raise ArmError(f"unknown frame {frame!r}")
        q = self.configuration(joint_angles)
        pin.framesForwardKinematics(self.model, self._data, q)
        return _pose3(self._data.oMf[self.model.getFrameId(frame)])

    def arm_T_end_effector(self, joint_angles) -> gtsam.Pose3:
        return self.arm_T_frame(joint_angles, self.end_effector_frame)

    def joint_origins(self, joint_angles) -> np.ndarray:
        """Origins of every revolute joint in the arm frame, (dof, 3): the arm's skeleton for plots."""
        self._forward(joint_angles)
        return np.array([np.array(self._data.oMi[j].translation) for j in self._joint_ids])

    def _find_end_effector_frame(self) -> str:
        frames = [f for f in self.model.frames
                  if f.parentJoint == self._wrist_id and f.type == pin.FrameType.BODY]
        for hint in _END_EFFECTOR_HINTS:
            for frame in frames:
                if hint in frame.name:
                    return frame.name
        return frames[-1].name if frames else self.model.names[self._wrist_id]

    # ------------------------------------------------------------------ inverse kinematics
    def solve_wrist_axis(self, point, direction, initial_joint_angles, *, iterations: int = 200,
                         tolerance: float = 1e-10, give_up_after: int | None = None,
                         give_up_distance: float = 0.03) -> np.ndarray:
        """Joint angles that put the wrist joint origin at ``point`` with its axis along ``direction``.

        Damped least squares from ``initial_joint_angles``, inside the joint limits. Raises
        :class:`ArmError` when no such configuration is found from that start. ``give_up_after``: stop after that
        many iterations when the wrist is still more than ``give_up_distance`` (m) from ``point`` (a start that
        rarely converges: for samplers that would rather try another start).
        """
        target_p = np.asarray(point, dtype=float)
        target_a = unit(direction, "target axis direction")
        angles = self._limit(self.joint_angle_vector(initial_joint_angles))
        a_local = self.wrist_axis_local()
        columns = [self.model.joints[j].idx_v for j in self._joint_ids]
        # Pinocchio's q without configuration()'s checks (the angles stay inside _limit's range)
        idx_q = np.array([self.model.joints[j].idx_q for j in self._joint_ids])
        continuous = np.array(self._continuous, dtype=bool)
        q = pin.neutral(self.model)

        def residual_and_jacobian(angles):
            q[idx_q[~continuous]] = angles[~continuous]
            q[idx_q[continuous]] = np.cos(angles[continuous])
            q[idx_q[continuous] + 1] = np.sin(angles[continuous])
            pin.computeJointJacobians(self.model, self._data, q)
            oMi = self._data.oMi[self._wrist_id]
            a = np.array(oMi.rotation) @ a_local
            error = np.concatenate([np.array(oMi.translation) - target_p, a - target_a])
            J = pin.getJointJacobian(self.model, self._data, self._wrist_id, pin.LOCAL_WORLD_ALIGNED)[:, columns]
            skew_a = np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]])
            return error, np.vstack([J[:3], -skew_a @ J[3:]])  # d a / d q = omega x a

        error, J = residual_and_jacobian(angles)
        damping = 1e-3
        identity = np.eye(self.dof)
        for iteration in range(iterations):
            cost = error @ error
            if cost < tolerance**2:
                return angles
            if give_up_after is not None and iteration >= give_up_after and \
                    error[:3] @ error[:3] > give_up_distance**2:
                break
            step = np.linalg.solve(J.T @ J + damping * identity, -J.T @ error)
            trial = self._limit(angles + step)
            trial_error, trial_J = residual_and_jacobian(trial)
            if trial_error @ trial_error < cost:
                angles, error, J = trial, trial_error, trial_J
                damping = max(damping / 3.0, 1e-9)
            else:
                damping *= 10.0
                if damping > 1e6:
                    break
        residual = np.linalg.norm(error[:3])
        raise ArmError(f"inverse kinematics did not reach the wrist target (position error {residual:.3g} m)")

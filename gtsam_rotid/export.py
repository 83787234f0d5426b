"""Export ``arm_T_camera`` and its covariance for other tools: YAML, JSON, a URDF joint, a ROS 2
``static_transform_publisher`` command line, a 4x4 matrix.

**The covariance layout of the exports** is ROS's ``geometry_msgs/PoseWithCovariance``: 6x6, row-major,
order ``(x, y, z, rotation about X, rotation about Y, rotation about Z)``, metres and radians, everything in
the *parent* (arm-base) frame:

- ``(x, y, z)``: the camera origin in the parent frame; its error is ``t_true - t``;
- rotation: the small rotation ``dtheta`` about the parent's fixed X, Y, Z axes that takes the estimate to
  the truth, ``R_true = Exp(dtheta) R`` (a left perturbation; not increments of roll/pitch/yaw angles, which
  differ from it except near the identity).

**Conversion from GTSAM.** The library's covariance is in GTSAM's Pose3 tangent ``xi = (w, rho)``: rotation
first, then translation, perturbation on the right, ``T_true = T Exp(xi)``, both in the *camera* frame. To first
order ``R Exp(w) = Exp(R w) R`` and ``t_true = t + R rho``, so the ROS vector is ``y = J xi`` with::

    J = [[0, R],
         [R, 0]]          (R = arm_R_camera)

and ``Sigma_ros = J Sigma J^T``; ``J`` is orthogonal, so ``Sigma = J^T Sigma_ros J`` converts back
(:func:`ros_covariance`, :func:`gtsam_covariance`; ``tests/test_export.py`` checks both by sampling).

The parent-frame layout does not change when the child frame is turned by a fixed rotation: the camera's
OpenCV *optical* frame (x right, y down, z forward; ROS REP 103's ``*_optical_frame``, the default) and the
ROS *body* convention (x forward, y left, z up; ``camera_link``) share it, only the pose differs.
"""

from __future__ import annotations

import json
import math
import os
import re
import shlex
from dataclasses import dataclass
from enum import StrEnum
from pathlib import Path

import gtsam
import numpy as np

from .calibration.offsets import HELD_BY_PRIOR
from .errors import InputError
from .geometry import gtsam_covariance, quaternion_xyzw, ros_covariance, tangent_to_ros  # noqa: F401 (re-export)

FORMAT_MARKER = "gtsam_rotid.transform"
FORMAT_VERSION = 1
PARENT_FRAME = "base_link"
JOINT_NAME = "camera_joint"
#: ``optical_R_body``: maps ROS body-frame coordinates (x forward, y left, z up) to OpenCV optical-frame
#: coordinates (x right, y down, z forward); its columns are the body axes seen in the optical frame.
OPTICAL_R_BODY = np.array([[0.0, -1.0, 0.0], [0.0, 0.0, -1.0], [1.0, 0.0, 0.0]])
#: ``optical_T_body``: the same turn as a pose (``parent_T_body = parent_T_optical * OPTICAL_T_BODY``).
OPTICAL_T_BODY = gtsam.Pose3(gtsam.Rot3(OPTICAL_R_BODY), np.zeros(3))
COVARIANCE_CONVENTION = (
    "geometry_msgs/PoseWithCovariance: 6x6 row-major, (x, y, z, rotation about X, Y, Z) of the parent frame, "
    "metres and radians; position error t_true - t in the parent frame; rotation error dtheta with "
    "R_true = Exp(dtheta) R about the parent's fixed axes")
#: Frame and link names: ROS-style identifiers (no spaces or quotes, so they are safe in XML and in a shell).
_NAME = re.compile(r"^[A-Za-z0-9_][A-Za-z0-9_./-]*$")


class ExportRefused(InputError):
    """A result not fit to export (:func:`export_problems`) and no ``force``; the message says why."""


class Format(StrEnum):
    YAML = "yaml"
    JSON = "json"
    URDF = "urdf"
    ROS2 = "ros2"
    MATRIX = "matrix"
    #: easy_handeye's calibration YAML (eye on base), which its publisher reads
    EASY_HANDEYE = "easy_handeye"
    #: a ROS 2 Python launch file with a static_transform_publisher node
    LAUNCH = "launch"
    #: the joint offsets a calibration refined (``calibrate --joint-offsets``), YAML
    JOINT_OFFSETS = "joint_offsets"
    #: the camera with the intrinsics a calibration refined (``calibrate --refine-intrinsics``), ROS camera_info YAML
    CAMERA = "camera"


class CameraFrame(StrEnum):
    #: OpenCV optical frame (x right, y down, z forward): the frame the calibration estimates.
    OPTICAL = "optical"
    #: ROS body convention (REP 103: x forward, y left, z up), e.g. a URDF's ``camera_link``.
    BODY = "body"


DEFAULT_CHILD = {CameraFrame.OPTICAL: "camera_optical_frame", CameraFrame.BODY: "camera_link"}


# ---------------------------------------------------------------------------------------------------
# covariance conversion


# ---------------------------------------------------------------------------------------------------
# the exported transform


def _checked_name(name: str, what: str) -> str:
    if not isinstance(name, str) or not _NAME.match(name):
        raise InputError(f"{what} {name!r} is not a valid frame or link name (letters, digits, '_', '/', '.', "
                         "'-'; no spaces or quotes)")
    return name


def _num(value: float) -> str:
    """A float for text formats: 12 significant digits (sub-nanometre, sub-nanoradian)."""
    text = f"{float(value):.12g}"
    return "0" if text == "-0" else text


@dataclass
class Transform:
    """``parent_T_child`` (the calibrated camera in the arm-base frame) with its ROS-layout covariance."""

    parent_T_child: gtsam.Pose3
    covariance: np.ndarray  # 6x6, ROS PoseWithCovariance layout (module docstring)
    parent_frame: str = PARENT_FRAME
    child_frame: str = DEFAULT_CHILD[CameraFrame.OPTICAL]
    camera_frame: CameraFrame = CameraFrame.OPTICAL
    covariance_usable: bool = True
    method: str = ""
    #: why the result was not fit to export, when it was exported anyway (``force``): every format carries them
    warnings: tuple[str, ...] = ()
    #: the robot's end-effector frame (for easy_handeye's file), "" when the result does not record it
    end_effector: str = ""
    #: with a camera driver's transform: its ``link_T_optical`` (4x4), the child being that link
    driver_link_T_optical: np.ndarray | None = None

    @classmethod
    def from_result(cls, result, *, parent_frame: str | None = None, child_frame: str | None = None,
                    camera_frame: str | CameraFrame = CameraFrame.OPTICAL, warnings: tuple[str, ...] = (),
                    driver: tuple[str, gtsam.Pose3] | None = None) -> Transform:
        """From a :class:`gtsam_rotid.estimate.CalibrationResult` (or anything with ``arm_T_camera`` and
        ``covariance``).

        ``parent_frame`` defaults to the robot's root link recorded in the result (``base_link`` for results that
        record none); another link fixed to the root is accepted (the pose is re-expressed in it), a link the
        model lacks or one that moves with a joint is refused. ``camera_frame="body"`` turns the child to ROS's
        x-forward body convention. ``driver = (link, link_T_optical)``: the camera driver already publishes
        ``link -> optical frame``; the export is then ``parent -> link`` (child ``link``), so that the two compose
        to the calibration, with the covariance carried through the driver's transform."""
        try:
            camera_frame = CameraFrame(camera_frame)
        except ValueError:
            raise InputError(f"unknown camera frame {camera_frame!r}; choose one of "
                             f"{[f.value for f in CameraFrame]}") from None
        robot = getattr(result, "robot", None) or {}
        parent_frame = robot.get("root_link", PARENT_FRAME) if parent_frame is None else parent_frame
        _checked_name(parent_frame, "parent frame")
        pose, covariance = result.arm_T_camera, np.asarray(result.covariance, dtype=float)
        static = robot.get("static_links")
        if static:
            if parent_frame not in static:
                raise InputError(
                    f"the robot {robot.get('name', '?')!r} has no link {parent_frame!r} fixed to its root "
                    f"{robot.get('root_link')!r}: the camera's parent must be one of {', '.join(sorted(static))} "
                    "(a link after a joint moves with the arm; --parent)")
            from .calibration.result import _rigid  # a result file's matrices are checked as its pose is

            try:
                root_T_parent = gtsam.Pose3(_rigid(static[parent_frame]))
            except (InputError, TypeError, ValueError) as exc:
                raise InputError(f"the result's record of the link {parent_frame!r} is not a rigid transform "
                                 f"({exc}); the result file is damaged") from None
            pose = root_T_parent.between(pose)
        if driver is not None:
            if camera_frame is CameraFrame.BODY or child_frame is not None:
                raise InputError("with the camera driver's transform the child frame is its link: do not give a "
                                 "child frame or the body convention as well")
            child_frame, link_T_optical = _checked_name(driver[0], "driver link"), driver[1]
            # parent_T_link = parent_T_optical * optical_T_link; a right perturbation of the optical frame is
            # Ad(link_T_optical) of one of the link's
            adjoint = link_T_optical.AdjointMap()
            pose, covariance = pose.compose(link_T_optical.inverse()), adjoint @ covariance @ adjoint.T
        child_frame = DEFAULT_CHILD[camera_frame] if child_frame is None else child_frame
        _checked_name(child_frame, "child frame")
        if child_frame in (robot.get("links") or ()):
            raise InputError(f"the child frame {child_frame!r} is a link of the robot {robot.get('name', '?')!r}: it "
                             "has a parent in the robot's TF tree already; name the camera's own frame (--child, or "
                             "the camera driver's link with --driver)")
        if parent_frame == child_frame:
            raise InputError(f"the parent and child frames must differ, both are {parent_frame!r}")
        ros = ros_covariance(pose, covariance)  # the same for both child conventions
        if camera_frame is CameraFrame.BODY:
            pose = pose.compose(OPTICAL_T_BODY)
        return cls(pose, ros, parent_frame, child_frame, camera_frame,
                   bool(getattr(result, "covariance_usable", True)), str(getattr(result, "method", "")),
                   tuple(warnings), str(robot.get("end_effector", "")),
                   None if driver is None else driver[1].matrix())

    @property
    def translation(self) -> np.ndarray:
        return np.asarray(self.parent_T_child.translation(), dtype=float)

    @property
    def quaternion(self) -> np.ndarray:
        """(x, y, z, w), w >= 0."""
        return quaternion_xyzw(self.parent_T_child.rotation())

    @property
    def rpy(self) -> np.ndarray:
        """Roll, pitch, yaw (rad) as URDF defines them: ``R = Rz(yaw) Ry(pitch) Rx(roll)`` (fixed axes X, Y, Z)."""
        return np.asarray(self.parent_T_child.rotation().rpy(), dtype=float)

    @property
    def matrix(self) -> np.ndarray:
        return self.parent_T_child.matrix()

    def _describe(self) -> str:
        frame = ("the camera driver's link, which its driver places relative to the optical frame"
                 if self.driver_link_T_optical is not None else
                 "OpenCV optical frame: x right, y down, z forward" if self.camera_frame is CameraFrame.OPTICAL
                 else "ROS body convention: x forward, y left, z up")
        method = f" ({self.method})" if self.method else ""
        return (f"gtsam_rotid calibration{method}: pose of {self.child_frame} ({frame}) in {self.parent_frame} "
                "(the arm base)")

    def to_dict(self) -> dict:
        x, y, z = self.translation
        qx, qy, qz, qw = self.quaternion
        return {
            "format": FORMAT_MARKER,
            "version": FORMAT_VERSION,
            "description": self._describe(),
            "parent_frame": self.parent_frame,
            "child_frame": self.child_frame,
            "camera_frame": "driver" if self.driver_link_T_optical is not None else self.camera_frame.value,
            **({} if self.driver_link_T_optical is None else {"driver": {
                "link": self.child_frame, "link_T_optical": self.driver_link_T_optical.tolist()}}),
            "method": self.method,
            "pose": {
                "position": {"x": float(x), "y": float(y), "z": float(z)},
                "orientation": {"x": float(qx), "y": float(qy), "z": float(qz), "w": float(qw)},
            },
            "rpy": [float(v) for v in self.rpy],
            "covariance": [float(v) for v in self.covariance.ravel()],
            "covariance_usable": self.covariance_usable,
            "covariance_convention": COVARIANCE_CONVENTION,
            **({"warnings": self._warning_lines()} if self.warnings else {}),
        }

    def to_json(self) -> str:
        return json.dumps(self.to_dict(), indent=1) + "\n"

    def to_yaml(self) -> str:
        """The :meth:`to_dict` content as YAML (written here: no YAML library needed to write or to read it).

        Floats are written so that YAML 1.1 (PyYAML) and 1.2 loaders both read them as floats; the covariance
        is a flow sequence of 36 numbers, one row per line.
        """
        data = self.to_dict()
        lines = [*self._warning_lines("# "), f"# {data['description']}",
                 f"# covariance: {COVARIANCE_CONVENTION}"]
        for key, value in data.items():
            if key == "covariance":
                rows = [", ".join(_yaml_scalar(v) for v in self.covariance[i]) for i in range(6)]
                lines.append("covariance: [")
                lines.extend(f"  {row}{',' if i < 5 else ']'}" for i, row in enumerate(rows))
            elif key == "pose":
                lines.append("pose:")
                for part, fields in value.items():
                    lines.append(f"  {part}:")
                    lines.extend(f"    {name}: {_yaml_scalar(v)}" for name, v in fields.items())
            elif isinstance(value, list):
                lines.append(f"{key}: [{', '.join(_yaml_scalar(v) for v in value)}]")
            else:
                lines.append(f"{key}: {_yaml_scalar(value)}")
        return "\n".join(lines) + "\n"

    def to_urdf(self, joint_name: str = JOINT_NAME) -> str:
        """A fixed ``<joint>`` from the parent link to the child link (URDF ``rpy``: fixed axes X, Y, Z)."""
        _checked_name(joint_name, "joint name")
        xyz = " ".join(_num(v) for v in self.translation)
        rpy = " ".join(_num(v) for v in self.rpy)
        warnings = "".join(f"<!-- {line.replace('--', '- -')} -->\n" for line in self._warning_lines())
        return (warnings + f"<!-- {self._describe()} -->\n"
                f'<joint name="{joint_name}" type="fixed">\n'
                f'  <parent link="{self.parent_frame}"/>\n'
                f'  <child link="{self.child_frame}"/>\n'
                f'  <origin xyz="{xyz}" rpy="{rpy}"/>\n'
                "</joint>\n")

    def to_ros2_command(self) -> str:
        """``ros2 run tf2_ros static_transform_publisher`` with the flag syntax of ROS 2 Humble and later."""
        x, y, z = self.translation
        qx, qy, qz, qw = self.quaternion
        args = ["ros2", "run", "tf2_ros", "static_transform_publisher",
                "--x", _num(x), "--y", _num(y), "--z", _num(z),
                "--qx", _num(qx), "--qy", _num(qy), "--qz", _num(qz), "--qw", _num(qw),
                "--frame-id", self.parent_frame, "--child-frame-id", self.child_frame]
        warnings = "".join(line + "\n" for line in self._warning_lines("# "))
        return warnings + " ".join(shlex.quote(a) for a in args) + "\n"

    def to_matrix_text(self) -> str:
        """The 4x4 homogeneous matrix (metres), one row per line; ``numpy.loadtxt`` reads it back."""
        rows = "\n".join(" ".join(f"{_num(v):>20}" for v in row) for row in self.matrix)
        return ("".join(line + "\n" for line in self._warning_lines("# ")) + f"# {self._describe()}\n"
                f"# maps {self.child_frame} coordinates to {self.parent_frame} coordinates: "
                f"x_{self.parent_frame} = M x_{self.child_frame} (metres)\n{rows}\n")

    def to_easy_handeye(self) -> str:
        """easy_handeye's calibration YAML for an eye-on-base camera (its ``publish.launch`` reads it from
        ``~/.ros/easy_handeye/<namespace>.yaml``): ``robot_base_frame -> tracking_base_frame``. No marker frame:
        the calibration used none."""
        x, y, z = self.translation
        qx, qy, qz, qw = self.quaternion
        parameters = {"namespace": "/gtsam_rotid_eye_on_base/", "move_group_namespace": "/",
                      "move_group": "manipulator", "eye_on_hand": False, "robot_base_frame": self.parent_frame,
                      "robot_effector_frame": self.end_effector, "tracking_base_frame": self.child_frame,
                      "tracking_marker_frame": ""}
        transformation = {"x": x, "y": y, "z": z, "qx": qx, "qy": qy, "qz": qz, "qw": qw}
        lines = [*self._warning_lines("# "), f"# {self._describe()}", "parameters:"]
        lines.extend(f"  {key}: {_yaml_scalar(value)}" for key, value in parameters.items())
        lines.append("transformation:")
        lines.extend(f"  {key}: {_yaml_scalar(float(value))}" for key, value in transformation.items())
        return "\n".join(lines) + "\n"

    def to_launch(self) -> str:
        """A ROS 2 Python launch file that publishes the transform (``tf2_ros`` static_transform_publisher)."""
        x, y, z = self.translation
        qx, qy, qz, qw = self.quaternion
        args = ["--x", _num(x), "--y", _num(y), "--z", _num(z), "--qx", _num(qx), "--qy", _num(qy),
                "--qz", _num(qz), "--qw", _num(qw), "--frame-id", self.parent_frame,
                "--child-frame-id", self.child_frame]
        listed = ",\n                ".join(json.dumps(a) for a in args)
        return ("".join(line + "\n" for line in self._warning_lines("# ")) + f"# {self._describe()}\n"
                "from launch import LaunchDescription\n"
                "from launch_ros.actions import Node\n\n\n"
                "def generate_launch_description():\n"
                "    return LaunchDescription([\n"
                "        Node(\n"
                '            package="tf2_ros",\n'
                '            executable="static_transform_publisher",\n'
                '            name="gtsam_rotid_camera_tf",\n'
                f"            arguments=[\n                {listed},\n            ],\n"
                "        ),\n"
                "    ])\n")

    def _warning_lines(self, prefix: str = "") -> list[str]:
        return [f"{prefix}WARNING: exported although {w}" for w in self.warnings]

    def to_text(self, fmt: str | Format, joint_name: str = JOINT_NAME) -> str:
        fmt = _format(fmt)
        if fmt is Format.YAML:
            return self.to_yaml()
        if fmt is Format.JSON:
            return self.to_json()
        if fmt is Format.URDF:
            return self.to_urdf(joint_name)
        if fmt is Format.ROS2:
            return self.to_ros2_command()
        if fmt is Format.EASY_HANDEYE:
            return self.to_easy_handeye()
        if fmt is Format.LAUNCH:
            return self.to_launch()
        return self.to_matrix_text()


def _format(fmt) -> Format:
    try:
        return Format(fmt)
    except ValueError:
        raise InputError(f"unknown export format {fmt!r}; choose one of {[f.value for f in Format]}") from None


def _yaml_scalar(value) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, (int, np.integer)):
        return str(int(value))
    if isinstance(value, (float, np.floating)):
        value = float(value)
        if math.isnan(value):
            return ".nan"
        if math.isinf(value):
            return ".inf" if value > 0 else "-.inf"
        text = repr(value)  # shortest text that reads back exactly
        mantissa, _, exponent = text.partition("e")
        if "." not in mantissa:
            mantissa += ".0"  # YAML 1.1 needs the dot (1e-05 would be a string there)
        if exponent and exponent[0] not in "+-":
            exponent = "+" + exponent
        return mantissa + ("e" + exponent if exponent else "")
    return json.dumps(str(value), ensure_ascii=False)  # a double-quoted YAML string


def export_problems(result) -> list[str]:
    """Why ``result`` is not fit to export (empty when it is): a pose or covariance that is not finite, poses that
    do not determine the calibration, another pose that fits nearly as well, a covariance not to be trusted, a
    solver that did not converge. Each is said so that "exported although ..." reads as a sentence."""
    problems = []
    if not np.all(np.isfinite(result.arm_T_camera.matrix())):
        problems.append("the pose is not finite")
    covariance = np.asarray(result.covariance, dtype=float)
    if covariance.shape != (6, 6):
        problems.append(f"the covariance is not 6x6 (shape {covariance.shape})")
    elif not np.all(np.isfinite(covariance)):
        problems.append("the covariance has NaN or infinite entries")
    elif not np.allclose(covariance, covariance.T, rtol=1e-6, atol=1e-15):
        problems.append("the covariance is not symmetric")
    elif np.min(np.linalg.eigvalsh(0.5 * (covariance + covariance.T))) < -1e-12 * max(
            1.0, float(np.max(np.abs(covariance)))):
        problems.append("the covariance is not positive semi-definite (a negative variance)")
    observability = getattr(result, "observability", None)
    if observability is not None and not observability.is_observable:
        problems.append(f"the arm poses do not determine the calibration ({len(observability.unobservable_directions)}"
                        " undetermined direction(s); see `gtsam-rotid report`)")
    if getattr(result, "ambiguous", False):
        problems.append("another pose fits the pixels nearly as well (ambiguous; see `gtsam-rotid report`)")
    untrusted = getattr(result, "untrusted", {})
    if untrusted:
        kinds = "; ".join(f"{kind}: measurement(s) {', '.join(map(str, ks))}" if ks else kind
                          for kind, ks in untrusted.items())
        problems.append(f"its covariance is not to be trusted ({kinds}; see `gtsam-rotid report`)")
    if not getattr(result, "converged", True):
        problems.append("the solver did not converge")
    return problems


def export_result(result, to: str | Format, *, parent_frame: str | None = None, child_frame: str | None = None,
                  camera_frame: str | CameraFrame = CameraFrame.OPTICAL, joint_name: str = JOINT_NAME,
                  force: bool = False, driver: tuple[str, gtsam.Pose3] | None = None) -> str:
    """The result's ``arm_T_camera`` (and covariance where the format has one) as text in format ``to``.

    A result not fit to export (:func:`export_problems`) raises :class:`ExportRefused` naming why, unless
    ``force``: then the text carries each reason as a warning (comments, and a ``warnings`` list in YAML/JSON)."""
    problems = export_problems(result)
    if problems and not force:
        raise ExportRefused("the result is not fit to export: " + "; ".join(problems)
                            + ". Export it anyway with --force (in Python: force=True): the file then says so")
    if _format(to) is Format.JOINT_OFFSETS:
        return joint_offsets_yaml(result, tuple(problems))
    if _format(to) is Format.CAMERA:
        return camera_info_yaml(result, tuple(problems))
    transform = Transform.from_result(result, parent_frame=parent_frame, child_frame=child_frame,
                                      camera_frame=camera_frame, warnings=tuple(problems), driver=driver)
    return transform.to_text(to, joint_name)


def joint_offsets_yaml(result, warnings: tuple[str, ...] = ()) -> str:
    """The joint offsets ``result`` refined, as YAML: per joint the offset (rad and deg; the reading plus it is the
    joint's angle, so a robot's zero position moves by minus it), its 1 sigma and whether these poses determined
    it (else its prior holds it), the corrected URDF ``<origin>`` of each joint (``urdf_origins``), their covariance
    (rad²) in ``joints`` order, the prior. Raises InputError when the result refined none."""
    offsets = getattr(result, "joint_offsets", None)
    if not offsets:
        raise InputError("this result refined no joint offsets (calibrate with --joint-offsets, in Python "
                         "CalibrationOptions(joint_offsets=True))")
    sigma = result.joint_offsets_sigma_deg
    prior = float(result.joint_offset_sigma_deg)
    lines = ["# gtsam_rotid joint offsets: the reading plus the offset is the joint's angle",
             f"format: {_yaml_scalar('gtsam_rotid.joint_offsets')}", "version: 1",
             f"robot: {_yaml_scalar((getattr(result, 'robot', {}) or {}).get('name', ''))}",
             f"prior_sigma_deg: {_yaml_scalar(prior)}", "offsets:"]
    for name, value in offsets.items():
        s = float(sigma.get(name, float("nan")))
        determined = bool(np.isfinite(s) and s <= HELD_BY_PRIOR * prior)
        lines.append(f"  {_yaml_scalar(name)}: {{rad: {_yaml_scalar(float(value))}, deg: "
                     f"{_yaml_scalar(math.degrees(float(value)))}, sigma_deg: {_yaml_scalar(s)}, "
                     f"determined: {_yaml_scalar(determined)}}}")
    origins = getattr(result, "joint_offsets_origins", None) or {}
    if origins:  # a URDF with these origins makes the readings the joints' angles
        lines.append("# corrected URDF joint origins (the joint's <origin> turned by its offset about its axis; put "
                     "them in the robot's URDF and the offsets are zero)")
        lines.append("urdf_origins:")
        for name, origin in origins.items():
            lines.append(f"  {_yaml_scalar(name)}: {{xyz: [" + ", ".join(_yaml_scalar(float(v)) for v in origin["xyz"])
                         + "], rpy: [" + ", ".join(_yaml_scalar(float(v)) for v in origin["rpy"]) + "]}")
    lines.append("joints: [" + ", ".join(_yaml_scalar(n) for n in offsets) + "]")
    covariance = np.asarray(result.joint_offsets_covariance, dtype=float)
    lines.append("covariance_rad2:")
    lines.extend("  - [" + ", ".join(_yaml_scalar(float(v)) for v in row) + "]" for row in covariance)
    if warnings:
        lines.append("warnings:")
        lines.extend(f"  - {_yaml_scalar(w)}" for w in warnings)
    return "\n".join(lines) + "\n"


def camera_info_yaml(result, warnings: tuple[str, ...] = ()) -> str:
    """The camera with the intrinsics ``result`` refined, as a ROS ``camera_info`` YAML (``camera_calibration_parsers``
    reads it, and so does ``gtsam-rotid``'s ``--camera``), the refined intrinsics' 1 sigma and covariance in comments.
    The distortion is the camera file's (not refined). Raises InputError when the result refined none."""
    camera = getattr(result, "camera", None)
    if camera is None or not getattr(result, "refined_intrinsics", ()):
        raise InputError("this result refined no intrinsics (calibrate with --refine-intrinsics, in Python "
                         "CalibrationOptions(refine_intrinsics=True))")
    K = np.asarray(camera.K, dtype=float)
    dist = np.zeros(5) if camera.dist is None else np.asarray(camera.dist, dtype=float).reshape(-1)
    P = np.hstack([K, np.zeros((3, 1))])

    def matrix(name: str, rows: int, cols: int, data) -> list[str]:
        return [f"{name}:", f"  rows: {rows}", f"  cols: {cols}",
                "  data: [" + ", ".join(_num(v) for v in np.asarray(data, dtype=float).reshape(-1)) + "]"]

    sigma, value = result.intrinsics_sigma, result.intrinsics
    lines = ["# gtsam_rotid: the camera with its intrinsics refined with arm_T_camera (the distortion is the camera "
             "file's)",
             "# refined (1 sigma, px): " + ", ".join(f"{n} {value[n]:.3f} +- {sigma.get(n, float('nan')):.3f}"
                                                      for n in result.refined_intrinsics)]
    if getattr(result, "intrinsics_covariance", None) is not None:
        lines.append(f"# covariance (px^2, {', '.join(result.refined_intrinsics)}): "
                     + "; ".join(", ".join(_num(v) for v in row) for row in np.asarray(result.intrinsics_covariance)))
    lines.extend(f"# WARNING: {w}" for w in warnings)
    lines += [f"image_width: {int(camera.width)}", f"image_height: {int(camera.height)}",
              f"camera_name: {_yaml_scalar((getattr(result, 'robot', {}) or {}).get('name', 'camera') + '_camera')}",
              *matrix("camera_matrix", 3, 3, K),
              "distortion_model: plumb_bob" if len(dist) <= 5 else "distortion_model: rational_polynomial",
              *matrix("distortion_coefficients", 1, len(dist), dist),
              *matrix("rectification_matrix", 3, 3, np.eye(3)),
              *matrix("projection_matrix", 3, 4, P)]
    return "\n".join(lines) + "\n"


# ---------------------------------------------------------------------------------------------------
# files (shared with gtsam_rotid.report)


def load_result(path: str | os.PathLike):
    """A :class:`~gtsam_rotid.estimate.CalibrationResult` from the JSON file ``calibrate -o`` writes.

    Raises :class:`InputError` (one line, naming the file) when it is missing or not a result.
    """
    from .calibration import CalibrationResult

    path = Path(path)
    if path.is_dir():
        raise InputError(f"{path} is a directory, not a calibration result JSON file")
    try:
        with open(path, encoding="utf-8") as handle:
            data = json.load(handle)
    except FileNotFoundError:
        raise InputError(f"{path}: no such file") from None
    except OSError as exc:
        raise InputError(f"cannot read {path}: {exc.strerror or exc}") from None
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise InputError(f"{path} is not valid JSON: {exc}") from None
    if not isinstance(data, dict):
        raise InputError(f"{path} is not a gtsam_rotid calibration result (a JSON object was expected)")
    try:
        return CalibrationResult.from_dict(data)
    except InputError as exc:
        raise InputError(f"{path}: {exc}") from None
    except (KeyError, TypeError, ValueError, IndexError) as exc:
        raise InputError(f"{path} is not a readable gtsam_rotid calibration result ({type(exc).__name__}: "
                         f"{exc})") from None

"""A calibration to re-check, read from whatever file holds it: a result of ours (``calibrate -o``), one of our
exports (YAML or JSON, ``gtsam_rotid.transform``), easy_handeye's calibration YAML, or a plain 4x4 matrix (text, as
``numpy.loadtxt`` reads it; another tool's). The pose must be the camera's optical frame in the arm's root frame,
or in a link fixed to it (re-expressed when the arm is given).
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import NamedTuple

import gtsam
import numpy as np
import yaml

from .arm import Arm
from .errors import InputError
from .export import FORMAT_MARKER, OPTICAL_T_BODY, load_result
from .geometry import gtsam_covariance


class PoseFile(NamedTuple):
    """``arm_T_camera`` (optical frame), its covariance (Pose3 tangent) or None, and what the file was."""

    arm_T_camera: gtsam.Pose3
    covariance: np.ndarray | None
    kind: str  # what the file was, with its article ("a 4x4 matrix")
    #: a result of ours: the joint sigma and the tracker's floor its covariance assumed, and the robot it records
    joint_sigma_deg: float = 0.0
    axis_floor_px: float | None = None
    robot: dict | None = None
    #: a result of ours that refined joint offsets: joint name -> rad (the reading plus it is the joint's angle),
    #: their covariance (n x n) and its cross-covariance with the pose (6 x n)
    joint_offsets: dict | None = None
    offsets_covariance: np.ndarray | None = None
    pose_offsets_covariance: np.ndarray | None = None
    #: a result of ours: each track's own offset (px) its covariance assumed
    track_offset_px: float | None = None
    #: a result of ours: the scale of its image axes' noise that its covariance carries (``axis_consistency.scale``,
    #: where their scatter widened it); 1 otherwise
    axis_scale: float = 1.0


def load_pose(path: str | os.PathLike, arm: Arm | None = None) -> PoseFile:
    """Read a calibration from ``path`` (see the module docstring). Raises :class:`InputError` naming the file and
    what it expected."""
    path = Path(path)
    if not path.is_file():
        raise InputError(f"{path}: no such file (a calibration result, an export, easy_handeye's YAML or a 4x4 "
                         "matrix was expected)")
    text = path.read_text(encoding="utf-8", errors="replace")
    document = None
    try:
        document = json.loads(text)
    except json.JSONDecodeError:
        try:
            document = yaml.safe_load(text)
        except yaml.YAMLError:
            document = None
    if isinstance(document, dict) and document.get("format") == "gtsam_rotid.calibration":
        result = load_result(path)
        from .calibration.check import axis_scale_of

        return PoseFile(result.arm_T_camera, result.covariance, "a gtsam_rotid result", result.joint_sigma_deg,
                        result.axis_floor_px, result.robot or None, result.joint_offsets,
                        result.joint_offsets_covariance, result.pose_offsets_covariance, result.track_offset_px,
                        axis_scale_of(result))
    if isinstance(document, dict) and document.get("format") == FORMAT_MARKER:
        return _transform(document, path, arm)
    if isinstance(document, dict) and "transformation" in document:
        return _easy_handeye(document, path, arm)
    try:
        matrix = np.loadtxt(path.open(encoding="utf-8"), ndmin=2)
    except ValueError:
        matrix = None
    if matrix is None or matrix.shape != (4, 4):
        raise InputError(f"{path} is neither a gtsam_rotid result or export, nor easy_handeye's calibration YAML, "
                         "nor a 4x4 matrix of numbers")
    return PoseFile(_rigid_pose(matrix, path), None, "a 4x4 matrix")


def _rigid_pose(matrix: np.ndarray, path: Path) -> gtsam.Pose3:
    from .calibration.result import _rigid  # the result file's own check of a rigid transform

    try:
        return gtsam.Pose3(_rigid(matrix))
    except InputError as exc:
        raise InputError(f"{path}: {exc}") from None


def _in_root(pose: gtsam.Pose3, parent: str, path: Path, arm: Arm | None) -> gtsam.Pose3:
    """``parent_T_camera`` as ``root_T_camera`` when ``parent`` is a link fixed to the arm's root."""
    if arm is None or parent == arm.root_link:
        return pose
    links = arm.static_links()
    if parent not in links:
        raise InputError(f"{path}: the pose is given in {parent!r}, which the robot {arm.name!r} has not fixed to its "
                         f"root {arm.root_link!r} (links fixed to it: {', '.join(sorted(links))})")
    return links[parent].compose(pose)


def _transform(document: dict, path: Path, arm: Arm | None) -> PoseFile:
    try:
        p, q = document["pose"]["position"], document["pose"]["orientation"]
        pose = gtsam.Pose3(gtsam.Rot3.Quaternion(float(q["w"]), float(q["x"]), float(q["y"]), float(q["z"])),
                           np.array([float(p["x"]), float(p["y"]), float(p["z"])]))
        covariance = np.array(document["covariance"], dtype=float).reshape(6, 6)
    except (KeyError, TypeError, ValueError) as exc:
        raise InputError(f"{path}: a gtsam_rotid export without a readable pose and covariance ({exc})") from None
    if document.get("camera_frame") == "body":  # back to the optical frame the calibration estimates
        pose = pose.compose(OPTICAL_T_BODY.inverse())
    elif document.get("camera_frame") == "driver":
        try:
            link_T_optical = gtsam.Pose3(np.array(document["driver"]["link_T_optical"], dtype=float))
        except (KeyError, TypeError, ValueError) as exc:
            raise InputError(f"{path}: a driver-link export without its link_T_optical ({exc})") from None
        pose = pose.compose(link_T_optical)
        return PoseFile(_in_root(pose, str(document.get("parent_frame", "")), path, arm), None,
                        "a gtsam_rotid export (composed with its camera driver's transform)")
    pose = _in_root(pose, str(document.get("parent_frame", "")), path, arm)
    usable = bool(document.get("covariance_usable", True)) and np.all(np.isfinite(covariance))
    return PoseFile(pose, gtsam_covariance(pose, covariance) if usable else None, "a gtsam_rotid export")


def _easy_handeye(document: dict, path: Path, arm: Arm | None) -> PoseFile:
    try:
        t = document["transformation"]
        pose = gtsam.Pose3(gtsam.Rot3.Quaternion(float(t["qw"]), float(t["qx"]), float(t["qy"]), float(t["qz"])),
                           np.array([float(t["x"]), float(t["y"]), float(t["z"])]))
        parameters = document.get("parameters") or {}
    except (KeyError, TypeError, ValueError) as exc:
        raise InputError(f"{path}: easy_handeye's YAML needs transformation x, y, z, qx, qy, qz, qw ({exc})") from None
    if parameters.get("eye_on_hand"):
        raise InputError(f"{path}: an eye-in-hand calibration (the camera on the arm's hand); gtsam_rotid checks a "
                         "camera fixed in the arm's base (eye on base)")
    base = str(parameters.get("robot_base_frame") or (arm.root_link if arm is not None else ""))
    child = str(parameters.get("tracking_base_frame") or "")
    kind = "an easy_handeye YAML"
    if child and "optical" not in child:  # a driver's camera_link: REP 103's x-forward body frame
        pose = pose.compose(OPTICAL_T_BODY.inverse())
        kind += f" ({child} taken as a REP 103 body frame: x forward, z up)"
    return PoseFile(_in_root(pose, base, path, arm), None, kind)

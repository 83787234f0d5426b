"""Simulated calibration scenes with exact ground truth.

A camera is placed by look-at; arm poses are sampled inside the joint limits (or given); features on
the end effector (radius r from the wrist axis, offset d along it, phase phi) spin with the wrist
at ``wrist_speed`` rad/s for ``duration`` s at ``fps`` frames per second. A feature is seen only while
its outward normal faces the camera (the far side of the wrist hides it) and it is inside the image,
so tracks end and new ones start every revolution. Pixels get Gaussian noise of variance
``noise_var`` px²; optional outlier tracks are arcs of wrong circles.

Entry points: :func:`simulate`, :func:`reference_scene` (the paper's Kinova Jaco2 system, docs/design.md
§6) and :func:`single_crossing_scene` (every wrist axis through one point).
"""

from __future__ import annotations

import json
import math
import os
from dataclasses import asdict, dataclass, field, replace

import gtsam
import numpy as np

from .arm import Arm
from .camera import Camera
from .dataset import Dataset, Measurement, SpinReadings, Track
from .errors import ArmError, InputError, SimulationError
from .files import write_json
from .geometry import Line3, circle_points, look_at, perpendicular_basis, unit


@dataclass(frozen=True)
class SceneConfig:
    """Everything that defines a simulated scene. Units: metres, radians, seconds, pixels."""

    robot: str = "kinova"
    camera: Camera = field(default_factory=Camera.xtion)
    #: Camera centre and look-at target in the arm-base frame; ``up`` appears upwards in the image.
    camera_eye: tuple = (-0.45, 0.25, 0.95)
    camera_target: tuple = (0.35, 0.0, 0.35)
    camera_up: tuple = (0.0, 0.0, 1.0)
    n_measurements: int = 6
    #: Explicit arm poses (one joint-angle vector per measurement); sampled when None.
    joint_angles: tuple | None = None
    #: The joints spun at every arm pose, one measurement each, in this order (names; empty: the wrist joint only).
    #: The features stay on the hand (after the wrist joint); a spin of an earlier joint swings them about its axis.
    spin_joints: tuple = ()
    n_features: int = 12
    radius_range: tuple = (0.03, 0.06)
    offset_range: tuple = (0.0, 0.10)
    duration: float = 60.0
    fps: float = 30.0
    wrist_speed: float = 0.5
    #: Seconds over which the spin speeds up from rest at the start and slows to rest at the end (0: the spin turns
    #: at ``wrist_speed`` throughout). A speed that changes lets the spinning joint's readings date the frames.
    spin_ramp: float = 0.0
    #: Readings of the spinning joint per second (0: none). With readings each measurement carries
    #: :class:`~gtsam_rotid.measurements.SpinReadings` (synced mode), stamped on the encoder's clock, which runs
    #: ``encoder_time_offset`` s ahead of the camera's, with Gaussian noise of ``encoder_sigma_deg``.
    encoder_rate: float = 0.0
    encoder_sigma_deg: float = 0.0
    encoder_time_offset: float = 0.0
    noise_var: float = 1.5
    #: A feature is visible while cos(angle between its outward normal and the ray to the camera)
    #: exceeds this (0 = visible up to the silhouette).
    visibility_cos: float = 0.1
    min_track_length: int = 10
    outlier_fraction: float = 0.0
    #: Acceptable angle between the wrist axis and the camera's ray to the wrist (degrees):
    #: neither end-on (0) nor side-on (90).
    axis_view_angle_deg: tuple = (25.0, 75.0)
    #: Wrist distance from the camera (m).
    depth_range: tuple = (0.5, 1.6)
    #: Minimum angle between the wrist axes of two measurements (degrees).
    min_axis_separation_deg: float = 20.0
    #: Feature circles must stay this far (px) inside the image.
    image_margin: float = 12.0
    #: Lowest allowed height (arm-base z, m) of the wrist and of every feature.
    min_height: float = 0.05
    max_pose_samples: int = 200_000

    def with_(self, **changes) -> SceneConfig:
        return replace(self, **changes)


@dataclass
class TrackTruth:
    """Ground truth of one track: which feature (or outlier) and its circle parameters."""

    feature: int  # -1 for an outlier track
    radius: float
    offset: float
    phase: float  # feature phase at spin angle 0 in the measurement's (e1, e2) basis
    is_outlier: bool = False


@dataclass
class MeasurementTruth:
    joint_angles: np.ndarray
    axis_point: np.ndarray  # wrist joint origin, arm frame
    axis_direction: np.ndarray  # unit, arm frame
    e1: np.ndarray  # fixed basis perpendicular to the axis: phase 0 direction
    e2: np.ndarray
    spin_angles: np.ndarray  # spin angle of every frame (rad)
    tracks: list[TrackTruth]
    spin_joint: str | None = None  # the joint that spun (None: the wrist joint); the axis is its axis

    @property
    def axis(self) -> Line3:
        return Line3(self.axis_point, self.axis_direction)

    def circle(self, track: int) -> tuple[np.ndarray, np.ndarray, float]:
        """(centre, unit normal, radius) of a track's circle in the arm frame."""
        t = self.tracks[track]
        return self.axis_point + t.offset * self.axis_direction, self.axis_direction, t.radius

    def feature_points(self, track: int, frames) -> np.ndarray:
        """True 3-D positions (arm frame) of a track's feature at the given frame indices."""
        t = self.tracks[track]
        centre, _, radius = self.circle(track)
        return circle_points(centre, self.axis_direction, radius,
                             t.phase + self.spin_angles[np.asarray(frames)], self.e1, self.e2)


@dataclass
class GroundTruth:
    """The truth behind a simulated dataset. The estimators never see it."""

    arm_T_camera: gtsam.Pose3
    measurements: list[MeasurementTruth]
    config: dict = field(default_factory=dict)

    def to_dict(self) -> dict:
        return {
            "arm_T_camera": self.arm_T_camera.matrix().tolist(),
            "config": self.config,
            "measurements": [
                {
                    "joint_angles": m.joint_angles.tolist(),
                    "axis_point": m.axis_point.tolist(),
                    "axis_direction": m.axis_direction.tolist(),
                    "e1": m.e1.tolist(),
                    "e2": m.e2.tolist(),
                    "spin_angles": m.spin_angles.tolist(),
                    "tracks": [asdict(t) for t in m.tracks],
                    "spin_joint": m.spin_joint,
                }
                for m in self.measurements
            ],
        }

    @classmethod
    def from_dict(cls, data: dict) -> GroundTruth:
        return cls(
            arm_T_camera=gtsam.Pose3(np.array(data["arm_T_camera"])),
            config=data.get("config", {}),
            measurements=[
                MeasurementTruth(
                    joint_angles=np.array(m["joint_angles"]),
                    axis_point=np.array(m["axis_point"]),
                    axis_direction=np.array(m["axis_direction"]),
                    e1=np.array(m["e1"]),
                    e2=np.array(m["e2"]),
                    spin_angles=np.array(m["spin_angles"]),
                    tracks=[TrackTruth(**t) for t in m["tracks"]],
                    spin_joint=m.get("spin_joint"),
                )
                for m in data["measurements"]
            ],
        )

    def save(self, path: str | os.PathLike, overwrite: bool = False) -> None:
        """Write as JSON (atomically; refuses to overwrite unless asked)."""
        write_json(path, self.to_dict(), overwrite)

    @classmethod
    def load(cls, path: str | os.PathLike) -> GroundTruth:
        with open(path, encoding="utf-8") as handle:
            return cls.from_dict(json.load(handle))


# ---------------------------------------------------------------------------------------------------
# Scene construction


def _view_problem(angle: float, allowed) -> str:
    """Why a spinning axis at ``angle`` (deg) to the viewing ray is outside ``allowed`` (deg, deg), in words (the
    numbers in brackets)."""
    side = ("nearly along the viewing ray" if angle < allowed[0]
            else "nearly across the viewing ray (its circles seen edge-on)")
    return f"{side} ({angle:.0f} deg; {allowed[0]:g}-{allowed[1]:g} deg allowed)"


class SpinScene:
    """Camera + arm + features: the checks shared by pose sampling and track generation.

    The camera stands where ``config`` puts it by look-at unless ``arm_T_camera`` is given; the features are drawn
    from ``rng`` unless ``features`` gives their ``(radii, offsets, phases)`` (three arrays of ``n_features``).
    """

    def __init__(self, config: SceneConfig, arm: Arm, rng: np.random.Generator, *,
                 arm_T_camera: gtsam.Pose3 | None = None, features: tuple | None = None):
        self.config = config
        self.arm = arm
        self.camera = config.camera
        if arm_T_camera is None:
            arm_T_camera = look_at(config.camera_eye, config.camera_target, config.camera_up)
        self.arm_T_camera = arm_T_camera
        self.camera_T_arm = self.arm_T_camera.inverse()
        self.camera_centre = np.asarray(arm_T_camera.translation(), dtype=float)
        self.local_axis = arm.wrist_axis_local()
        self.local_e1, self.local_e2 = perpendicular_basis(self.local_axis)
        n = config.n_features
        if features is None:
            self.radii = rng.uniform(*config.radius_range, size=n)
            self.offsets = rng.uniform(*config.offset_range, size=n)
            self.phases = rng.uniform(0.0, 2.0 * np.pi, size=n)
        else:
            self.radii, self.offsets, self.phases = (np.asarray(f, dtype=float).reshape(n) for f in features)

    def basis(self, joint_angles) -> tuple[Line3, np.ndarray, np.ndarray]:
        axis = self.arm.wrist_axis(joint_angles)
        R = self.arm.arm_T_wrist(joint_angles).rotation().matrix()
        return axis, R @ self.local_e1, R @ self.local_e2

    def spin_features(self, joint_angles, joint: str | None = None):
        """The features at ``joint_angles`` as circles about the axis of the spinning ``joint`` (default the
        wrist): ``(axis, e1, e2, radii, offsets, phases, normals)``, the phases at spin angle 0 in the (e1, e2)
        basis and each feature's outward normal at spin 0 as its components along (axis, e1, e2), (n, 3)."""
        axis, e1, e2 = self.basis(joint_angles)
        cos_p, sin_p = np.cos(self.phases), np.sin(self.phases)
        if self.arm.spins_wrist(joint):
            normals = np.stack([np.zeros_like(cos_p), cos_p, sin_p], axis=1)
            return axis, e1, e2, self.radii, self.offsets, self.phases, normals
        radial = cos_p[:, None] * e1 + sin_p[:, None] * e2  # the outward normal, about the wrist axis
        points = axis.point + self.offsets[:, None] * axis.direction + self.radii[:, None] * radial
        spin_axis = self.arm.wrist_axis(joint_angles, joint)
        a = spin_axis.direction
        f1, f2 = perpendicular_basis(a)
        relative = points - spin_axis.point
        offsets = relative @ a
        across = relative - offsets[:, None] * a
        phases = np.arctan2(across @ f2, across @ f1)
        normals = np.stack([radial @ a, radial @ f1, radial @ f2], axis=1)
        return spin_axis, f1, f2, np.linalg.norm(across, axis=1), offsets, phases, normals

    def project(self, points_arm: np.ndarray) -> np.ndarray:
        R = self.camera_T_arm.rotation().matrix()
        t = self.camera_T_arm.translation()
        return self.camera.project(points_arm @ R.T + t)

    def pose_problem(self, joint_angles, joints=()) -> str | None:
        """Why this arm pose is unusable for the scene, or None when it is fine: the wrist's pose checks, and for each
        of ``joints`` (spinning joints' names) other than the wrist, its swing's (:meth:`_swing_problem`)."""
        cfg = self.config
        if not self.arm.within_limits(joint_angles):
            return "outside joint limits"
        axis, e1, e2 = self.basis(joint_angles)
        ray = axis.point - self.camera_centre
        depth = np.linalg.norm(ray)
        if not cfg.depth_range[0] <= depth <= cfg.depth_range[1]:
            return (f"wrist too {'near' if depth < cfg.depth_range[0] else 'far from'} the camera ({depth:.2f} m; "
                    f"{cfg.depth_range[0]:g}-{cfg.depth_range[1]:g} m allowed)")
        angle = np.degrees(np.arccos(min(1.0, abs(ray @ axis.direction) / depth)))
        if not cfg.axis_view_angle_deg[0] <= angle <= cfg.axis_view_angle_deg[1]:
            return f"axis {_view_problem(angle, cfg.axis_view_angle_deg)}"
        phases = np.linspace(0.0, 2.0 * np.pi, 24, endpoint=False)
        rims = []
        for offset in (cfg.offset_range[0], cfg.offset_range[1]):
            rims.append(circle_points(axis.point + offset * axis.direction, axis.direction,
                                      cfg.radius_range[1], phases, e1, e2))
        rims = np.vstack(rims)
        if np.min(rims[:, 2]) < cfg.min_height or axis.point[2] < cfg.min_height:
            return "end effector too low"
        pixels = self.project(rims)
        if not np.all(self.camera.in_image(pixels, cfg.image_margin)):
            return "end effector leaves the image"
        for joint in joints:
            problem = None if self.arm.spins_wrist(joint) else self._swing_problem(joint_angles, joint)
            if problem is not None:
                return problem
        return None

    def _swing_problem(self, joint_angles, joint: str) -> str | None:
        """Why a spin of ``joint`` (not the wrist) at a pose that passes the wrist's checks is unusable: the
        features' whole swing about the joint's axis must stay in view and above ``min_height``."""
        cfg = self.config
        axis = self.arm.wrist_axis(joint_angles, joint)
        ray = axis.point - self.camera_centre
        angle = np.degrees(np.arccos(min(1.0, abs(ray @ axis.direction) / np.linalg.norm(ray))))
        if not cfg.axis_view_angle_deg[0] <= angle <= cfg.axis_view_angle_deg[1]:
            return f"{joint} axis {_view_problem(angle, cfg.axis_view_angle_deg)}"
        wrist, e1, e2 = self.basis(joint_angles)
        phases = np.linspace(0.0, 2.0 * np.pi, 12, endpoint=False)
        rims = np.vstack([circle_points(wrist.point + offset * wrist.direction, wrist.direction,
                                        cfg.radius_range[1], phases, e1, e2)
                          for offset in (cfg.offset_range[0], cfg.offset_range[1])])
        turns = np.array([gtsam.Rot3.AxisAngle(gtsam.Point3(*axis.direction), s).matrix()
                          for s in np.linspace(0.0, 2.0 * np.pi, 24, endpoint=False)])
        swept = axis.point + np.einsum("sij,nj->sni", turns, rims - axis.point).reshape(-1, 3)
        if np.min(swept[:, 2]) < cfg.min_height:
            return f"end effector too low during the {joint} spin"
        if not np.all(self.camera.in_image(self.project(swept), cfg.image_margin)):
            return f"end effector leaves the image during the {joint} spin"
        return None

    def sample_poses(self, rng: np.random.Generator) -> list[np.ndarray]:
        cfg = self.config
        chosen: list[np.ndarray] = []
        directions: list[np.ndarray] = []
        cos_sep = np.cos(np.radians(cfg.min_axis_separation_deg))
        for _ in range(cfg.max_pose_samples):
            q = self.arm.random_joint_angles(rng)
            if self.pose_problem(q, cfg.spin_joints) is not None:
                continue
            a = self.arm.wrist_axis(q).direction
            if any(abs(a @ b) > cos_sep for b in directions):
                continue
            chosen.append(q)
            directions.append(a)
            if len(chosen) == cfg.n_measurements:
                return chosen
        raise SimulationError(
            f"found only {len(chosen)} of {cfg.n_measurements} arm poses with the wrist in view after "
            f"{cfg.max_pose_samples} samples; move the camera target towards the arm's workspace")

    def measurement(self, joint_angles, rng: np.random.Generator, joint: str | None = None
                    ) -> tuple[Measurement, MeasurementTruth]:
        """One spin of ``joint`` (default the wrist) at ``joint_angles``: the tracks and their truth."""
        cfg = self.config
        axis, e1, e2, radii, offsets, phases, normals = self.spin_features(joint_angles, joint)
        n_frames = int(round(cfg.duration * cfg.fps))
        frames = np.arange(n_frames)
        spin = spin_profile(frames / cfg.fps, cfg)
        sigma = np.sqrt(cfg.noise_var)
        tracks: list[Track] = []
        truths: list[TrackTruth] = []
        # (features, frames) arrays: phase, 3-D point, outward normal, visibility
        phase = phases[:, None] + spin[None, :]
        cos_p, sin_p = np.cos(phase)[..., None], np.sin(phase)[..., None]
        radial = cos_p * e1 + sin_p * e2
        points = (axis.point + offsets[:, None, None] * axis.direction + radii[:, None, None] * radial)
        if self.arm.spins_wrist(joint):
            normal = radial
        else:  # the normal turns with the feature: its components along (e1, e2) by the spin, along the axis kept
            cos_s, sin_s = np.cos(spin)[None, :, None], np.sin(spin)[None, :, None]
            n_a, n_1, n_2 = (normals[:, i, None, None] for i in range(3))
            normal = (n_a * axis.direction + (n_1 * cos_s - n_2 * sin_s) * e1 + (n_1 * sin_s + n_2 * cos_s) * e2)
        to_camera = self.camera_centre - points
        facing = np.einsum("fti,fti->ft", normal, to_camera) / np.linalg.norm(to_camera, axis=-1)
        pixels = self.project(points.reshape(-1, 3)).reshape(cfg.n_features, n_frames, 2)
        pixels = pixels + rng.normal(0.0, sigma, size=pixels.shape)
        visible = (facing > cfg.visibility_cos) & self.camera.in_image(
            pixels.reshape(-1, 2)).reshape(cfg.n_features, n_frames)
        for feature in range(cfg.n_features):
            for start, stop in _runs(visible[feature]):
                if stop - start < cfg.min_track_length:
                    continue
                tracks.append(Track(pixels[feature, start:stop], frames[start:stop]))
                truths.append(TrackTruth(feature, float(radii[feature]), float(offsets[feature]),
                                         float(phases[feature])))
        self._plant_outliers(tracks, truths, axis, rng)
        truth = MeasurementTruth(np.asarray(joint_angles, dtype=float), axis.point.copy(),
                                 axis.direction.copy(), e1, e2, spin, truths, spin_joint=joint)
        readings = None
        if cfg.encoder_rate > 0:  # from half a second before the first frame to half a second after the last
            delta = cfg.encoder_time_offset
            times = np.arange(delta - 0.5, delta + cfg.duration + 0.5, 1.0 / cfg.encoder_rate)
            start = float(np.asarray(joint_angles, dtype=float)[self.arm.spin_index(joint)])
            angles = start + spin_profile(times - delta, cfg) + rng.normal(
                0.0, np.radians(cfg.encoder_sigma_deg), size=len(times))
            readings = SpinReadings(frames / cfg.fps, times, angles)
        return Measurement(np.asarray(joint_angles, dtype=float), tracks, spin_joint=joint,
                           spin_readings=readings), truth

    def _plant_outliers(self, tracks, truths, axis: Line3, rng: np.random.Generator) -> None:
        """Replace a fraction of the tracks by arcs of circles about a wrong axis."""
        cfg = self.config
        n_out = int(round(cfg.outlier_fraction * len(tracks)))
        if n_out == 0:
            return
        sigma = np.sqrt(cfg.noise_var)
        for j in rng.choice(len(tracks), size=n_out, replace=False):
            frames = tracks[j].frames
            for _ in range(100):
                wrong_axis = unit(rng.normal(size=3))
                centre = axis.point + rng.uniform(-0.08, 0.08, size=3)
                radius = rng.uniform(*cfg.radius_range)
                phase0 = rng.uniform(0, 2 * np.pi)
                phases = phase0 + cfg.wrist_speed * (frames - frames[0]) / cfg.fps
                pts = circle_points(centre, wrong_axis, radius, phases)
                pixels = self.project(pts) + rng.normal(0.0, sigma, size=(len(frames), 2))
                if np.all(self.camera.in_image(pixels)):
                    tracks[j] = Track(pixels, frames)
                    truths[j] = TrackTruth(-1, float(radius), float("nan"), float(phase0), is_outlier=True)
                    break


def spin_profile(t, config: SceneConfig) -> np.ndarray:
    """The spin's angle (rad) at camera times ``t`` (s from the first frame): ``wrist_speed`` throughout, or with
    ``spin_ramp`` at rest before 0 and after ``duration``, speeding up (and slowing down) at a constant rate over
    ``spin_ramp`` s at each end."""
    t = np.asarray(t, dtype=float)
    speed, ramp, duration = config.wrist_speed, config.spin_ramp, config.duration
    if ramp <= 0:
        return speed * t
    ramp = min(ramp, duration / 2)
    t = np.clip(t, 0.0, duration)
    late = duration - ramp
    angle = np.where(t <= ramp, t * t / (2 * ramp), ramp / 2 + (t - ramp))
    angle = np.where(t > late, ramp / 2 + (late - ramp) + (ramp**2 - (duration - t) ** 2) / (2 * ramp), angle)
    return speed * angle


def _runs(mask: np.ndarray) -> list[tuple[int, int]]:
    """[start, stop) index pairs of the runs of True in a boolean vector."""
    padded = np.concatenate([[False], mask, [False]]).astype(np.int8)
    edges = np.flatnonzero(np.diff(padded))
    return list(zip(edges[0::2].tolist(), edges[1::2].tolist(), strict=True))


def _check_config(config: SceneConfig) -> None:
    """Raise an InputError naming the first field of ``config`` that cannot make a scene (before any work)."""
    def number(name: str, low: float, high: float = math.inf, *, low_open: bool = False, what: str = "") -> None:
        value = getattr(config, name)
        ok = isinstance(value, int | float) and not isinstance(value, bool) and math.isfinite(value)
        ok = ok and (value > low if low_open else value >= low) and value <= high
        if not ok:
            bound = f"{'>' if low_open else '>='} {low:g}" + ("" if high == math.inf else f" and <= {high:g}")
            raise InputError(f"{name} must be a finite number {bound}{what}, got {value!r}")

    number("n_measurements", 1, what=" (arm poses)")
    number("duration", 0.0, low_open=True, what=" (seconds of wrist spin)")
    number("fps", 0.0, low_open=True, what=" (frames per second)")
    number("noise_var", 0.0, what=" (px^2)")
    number("outlier_fraction", 0.0, 1.0)
    number("n_features", 1)
    number("min_track_length", 2, what=" (points)")
    number("spin_ramp", 0.0, what=" (seconds)")
    number("encoder_rate", 0.0, what=" (readings per second)")
    number("encoder_sigma_deg", 0.0, what=" (degrees)")
    number("encoder_time_offset", -1e6, 1e6, what=" (seconds)")
    if isinstance(config.spin_joints, str) or not all(isinstance(j, str) for j in config.spin_joints):
        raise InputError(f"spin_joints must be a tuple of joint names, got {config.spin_joints!r}")
    if not (isinstance(config.wrist_speed, int | float) and math.isfinite(config.wrist_speed)
            and config.wrist_speed != 0):
        raise InputError(f"wrist_speed must be a finite, non-zero number (rad/s), got {config.wrist_speed!r}")


def simulate(config: SceneConfig | None = None, seed: int | None = 0, *, arm: Arm | None = None,
             ) -> tuple[Dataset, GroundTruth]:
    """Simulate a scene: returns the dataset (what a user would record) and its ground truth."""
    config = SceneConfig() if config is None else config
    _check_config(config)
    rng = np.random.default_rng(seed)
    arm = Arm.from_robot(config.robot) if arm is None else arm
    indices = [arm.spin_index(joint) for joint in config.spin_joints]  # (an ArmError names an unknown joint)
    for joint, index in zip(config.spin_joints, indices, strict=True):
        if index > arm.wrist_index:
            raise InputError(f"spin joint {joint!r} comes after the wrist joint {arm.wrist_joint!r}: the simulated "
                             "features sit on the links after the wrist joint, and its spin would not move them all")
        if index == 0:
            raise InputError(f"spin joint {joint!r} is the arm's first joint: its axis is fixed in the arm's base, the "
                             "same at every pose, so its spins cannot locate the camera")
    if len(set(indices)) < len(indices):
        raise InputError(f"spin_joints names a joint twice: {list(config.spin_joints)} (each joint spins once per "
                         "arm pose)")
    scene = SpinScene(config, arm, rng)
    if config.joint_angles is not None:
        poses = [arm.joint_angle_vector(q) for q in config.joint_angles]
        for k, q in enumerate(poses):
            problem = scene.pose_problem(q, config.spin_joints)
            if problem is not None:
                where = f"measurement {k}" if not config.spin_joints else f"arm pose {k}"
                raise SimulationError(f"{where}: the given arm pose is unusable ({problem})")
    else:
        poses = scene.sample_poses(rng)
    measurements, truths = [], []
    for q in poses:
        for joint in config.spin_joints or (None,):
            measurement, truth = scene.measurement(q, rng, joint)
            measurements.append(measurement)
            truths.append(truth)
    config_dict = {k: v for k, v in asdict(config).items() if k != "camera"}
    metadata = {"simulated": True, "seed": seed, "noise_var": config.noise_var, "fps": config.fps}
    dataset = Dataset(arm, config.camera, measurements, metadata=metadata)
    return dataset, GroundTruth(scene.arm_T_camera, truths, config=_jsonable(config_dict))


def _jsonable(value):
    if isinstance(value, dict):
        return {k: _jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_jsonable(v) for v in value]
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, np.generic):
        return value.item()
    return value


def reference_scene(seed: int | None = 0, **changes) -> tuple[Dataset, GroundTruth]:
    """The paper's physical system (docs/design.md §6): Kinova Jaco2, Xtion-like camera ~1 m over the
    shoulder, six 60 s wrist spins at 30 fps and 0.5 rad/s, 12 features 3-6 cm from the axis,
    noise variance 1.5 px². Keyword arguments override :class:`SceneConfig` fields."""
    return simulate(SceneConfig(**changes), seed=seed)


def single_crossing_scene(seed: int | None = 0, **changes) -> tuple[Dataset, GroundTruth]:
    """Every wrist axis passes through one point P (same wrist position, other orientations, by
    inverse kinematics): the paper's degenerate single-crossing case."""
    config = SceneConfig(**changes)
    rng = np.random.default_rng(seed)
    arm = Arm.from_robot(config.robot)
    scene = SpinScene(config, arm, np.random.default_rng(rng.integers(2**63)))
    first = scene.sample_poses(np.random.default_rng(rng.integers(2**63)))[0]
    crossing = arm.wrist_axis(first).point
    poses, directions = [first], [arm.wrist_axis(first).direction]
    cos_sep = np.cos(np.radians(config.min_axis_separation_deg))
    for _ in range(5000):
        if len(poses) == config.n_measurements:
            break
        base = poses[rng.integers(len(poses))]
        direction = unit(directions[0] + rng.normal(scale=0.8, size=3))
        if any(abs(direction @ b) > cos_sep for b in directions):
            continue
        start = base + rng.normal(scale=0.3, size=arm.dof)
        try:
            q = arm.solve_wrist_axis(crossing, direction, start)
        except ArmError:
            continue
        if scene.pose_problem(q) is not None:
            continue
        poses.append(q)
        directions.append(direction)
    if len(poses) < config.n_measurements:
        raise SimulationError(f"found only {len(poses)} of {config.n_measurements} wrist orientations "
                              f"through the crossing point {np.round(crossing, 3).tolist()}")
    config = config.with_(joint_angles=tuple(tuple(q) for q in poses))
    dataset, truth = simulate(config, seed=int(rng.integers(2**31)), arm=arm)
    truth.config["crossing_point"] = crossing.tolist()
    dataset.metadata["scene"] = "single-crossing"
    return dataset, truth

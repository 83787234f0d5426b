"""Estimators of ``arm_T_camera`` (DESIGN.md §4): ``paper``, ``weighted`` and ``joint`` (default).

All three start from the same guess-free initial value (:mod:`gtsam_rotid.initialise`): ellipse
centres give each measurement's projected axis, the back-projected planes and the FK axes give pose
candidates on an SO(3) grid, and LM on the projected-axis distances picks the best candidate.

- ``paper``: stage 1 fits coaxial circles per measurement (Rot3 line + (d, r) per track); its
  projected axis is the measurement z_k. Stage 2: LM on the distances of projected FK test points to
  z_k, unweighted, with random restarts; covariance (JᵀJ)⁻¹ (unit noise), as the seed paper does.
- ``weighted``: the same two stages, stage 2 weighted by each line's stage-1 Marginals covariance
  scaled by the stage-1 residual variance (χ²/dof), with a Huber kernel on whole measurements.
- ``joint``: one graph with every circle-point factor and the projected-axis ties to the Pose3,
  per-measurement noise scale from the residuals, outlier tracks rejected, covariance from
  ``gtsam.Marginals`` of the whole graph.
"""

from __future__ import annotations

import json
import os
from dataclasses import asdict, dataclass, field
from enum import StrEnum

import gtsam
import numpy as np

from .arm import Arm
from .camera import Camera
from .dataset import Dataset, Measurement
from .errors import InputError, RotIdError
from .factors import image_line_from_rot3, line_distance_covariance, make_axis_to_line_factor
from .graph import MIN_ELLIPSE_POINTS, RotIdGraph, axis_test_points
from .initialise import fit_ellipse, initial_image_axis, plane_normal, pose_candidates
from .jsonio import write_json_atomic
from .uncertainty import Observability, analyse_observability, pose_information

MIN_MEASUREMENTS = 3


class Method(StrEnum):
    PAPER = "paper"
    WEIGHTED = "weighted"
    JOINT = "joint"


class CalibrationError(RotIdError, RuntimeError):
    """The optimisation could not produce a trustworthy estimate (e.g. every start ended in a poor minimum)."""


@dataclass
class CalibrationOptions:
    """Solver settings; the defaults suit the reference scene."""

    max_iterations: int = 100
    #: Pose candidates from the SO(3) grid refined by LM.
    n_candidates: int = 5
    #: Extra random restarts around the best start (the paper's method).
    restarts: int = 5
    seed: int = 0
    min_track_points: int = 10
    #: A track whose residual RMS exceeds this multiple of its measurement's median track RMS is rejected.
    outlier_track_ratio: float = 3.0
    #: A measurement whose residual scale exceeds this multiple of the median is reported as an outlier.
    outlier_measurement_ratio: float = 3.0
    #: Initial stage-2 RMS (px) above which the start is declared a poor minimum.
    max_initial_rms_px: float = 25.0
    tie_sigma_px: float = 1e-3
    #: Floor of the estimated pixel noise (px), so noise-free data keeps finite weights.
    min_sigma_px: float = 1e-3


@dataclass
class MeasurementReport:
    index: int
    n_tracks: int
    n_points: int
    residual_rms_px: float
    weight: float  # 1 / sigma^2 applied to its pixels (joint) or its line (two-stage), relative to the median
    outlier: bool
    rejected_tracks: dict[int, str] = field(default_factory=dict)


@dataclass
class CalibrationResult:
    """``arm_T_camera`` (camera pose in the arm-base frame) with its covariance and diagnostics."""

    arm_T_camera: gtsam.Pose3
    covariance: np.ndarray  # 6x6, Pose3 tangent: rotation (rad) then translation (m, camera frame)
    method: str
    converged: bool
    iterations: int
    final_error: float
    measurements: list[MeasurementReport]
    observability: Observability
    sigma_px: float  # pixel noise estimated from the residuals

    @property
    def covariance_usable(self) -> bool:
        return self.observability.is_observable

    @property
    def sigma_deg(self) -> np.ndarray:
        """1σ of the rotation (roll, pitch, yaw about the camera axes), degrees."""
        return np.degrees(np.sqrt(np.diag(self.covariance)[:3]))

    @property
    def sigma_mm(self) -> np.ndarray:
        """1σ of the translation, mm, in the camera frame (GTSAM's tangent)."""
        return 1000.0 * np.sqrt(np.diag(self.covariance)[3:])

    @property
    def sigma_mm_arm(self) -> np.ndarray:
        """1σ of the camera position in the arm-base frame, mm."""
        R = self.arm_T_camera.rotation().matrix()
        return 1000.0 * np.sqrt(np.diag(R @ self.covariance[3:, 3:] @ R.T))

    def error_to(self, arm_T_camera_true: gtsam.Pose3) -> np.ndarray:
        """Tangent-space error (rotation rad, translation m) of this estimate against a reference pose."""
        return arm_T_camera_true.localCoordinates(self.arm_T_camera)

    def summary(self) -> str:
        t = self.arm_T_camera.translation() * 1000.0
        rpy = np.degrees(self.arm_T_camera.rotation().rpy())
        lines = [
            f"arm_T_camera ({self.method}, {'converged' if self.converged else 'NOT converged'}, "
            f"{self.iterations} iterations, pixel sigma {self.sigma_px:.3f} px)",
            f"  translation (mm):  {t[0]:9.2f} {t[1]:9.2f} {t[2]:9.2f}",
            f"  roll/pitch/yaw (deg): {rpy[0]:8.3f} {rpy[1]:8.3f} {rpy[2]:8.3f}",
        ]
        if self.covariance_usable:
            s, r = self.sigma_mm_arm, self.sigma_deg
            lines.append(f"  1-sigma position, arm frame (mm): {s[0]:.3f} {s[1]:.3f} {s[2]:.3f}")
            lines.append(f"  1-sigma rotation (deg):           {r[0]:.4f} {r[1]:.4f} {r[2]:.4f}")
        else:
            lines.append("  COVARIANCE UNUSABLE: the arm poses do not determine the calibration")
        lines.extend("  " + line for line in self.observability.describe())
        for m in self.measurements:
            flag = "  OUTLIER" if m.outlier else ""
            lines.append(f"  measurement {m.index}: {m.n_tracks} tracks, {m.n_points} points, residual RMS "
                         f"{m.residual_rms_px:.3f} px, weight {m.weight:.2f}, {len(m.rejected_tracks)} tracks "
                         f"rejected{flag}")
        return "\n".join(lines)

    def to_dict(self) -> dict:
        return {
            "format": "gtsam_rotid.calibration",
            "version": 1,
            "method": self.method,
            "arm_T_camera": self.arm_T_camera.matrix().tolist(),
            "covariance": self.covariance.tolist(),
            "covariance_order": "Pose3 tangent: rx, ry, rz (rad), tx, ty, tz (m, camera frame)",
            "covariance_usable": self.covariance_usable,
            "sigma_mm_arm": self.sigma_mm_arm.tolist(),
            "sigma_deg": self.sigma_deg.tolist(),
            "converged": self.converged,
            "iterations": self.iterations,
            "final_error": self.final_error,
            "sigma_px": self.sigma_px,
            "measurements": [
                {**asdict(m), "rejected_tracks": {str(k): v for k, v in m.rejected_tracks.items()}}
                for m in self.measurements
            ],
            "observability": self.observability.to_dict(),
        }

    @classmethod
    def from_dict(cls, data: dict) -> CalibrationResult:
        if data.get("format") != "gtsam_rotid.calibration":
            raise InputError("not a gtsam_rotid calibration result (missing format marker)")
        return cls(
            arm_T_camera=gtsam.Pose3(np.array(data["arm_T_camera"])),
            covariance=np.array(data["covariance"]),
            method=data["method"],
            converged=data["converged"],
            iterations=data["iterations"],
            final_error=data["final_error"],
            sigma_px=data["sigma_px"],
            measurements=[
                MeasurementReport(**{**m, "rejected_tracks": {int(k): v for k, v in m["rejected_tracks"].items()}})
                for m in data["measurements"]
            ],
            observability=Observability.from_dict(data["observability"]),
        )

    def save(self, path: str | os.PathLike, overwrite: bool = False) -> None:
        write_json_atomic(path, self.to_dict(), overwrite=overwrite, indent=1)

    @classmethod
    def load(cls, path: str | os.PathLike) -> CalibrationResult:
        with open(path, encoding="utf-8") as handle:
            return cls.from_dict(json.load(handle))


# ---------------------------------------------------------------------------------------------------
# helpers


def _lm(graph: gtsam.NonlinearFactorGraph, values: gtsam.Values, max_iterations: int):
    params = gtsam.LevenbergMarquardtParams()
    params.setMaxIterations(max_iterations)
    params.setDiagonalDamping(True)  # pixel-scale Jacobians: scale-invariant damping
    params.setlambdaUpperBound(1e15)
    params.setRelativeErrorTol(1e-12)
    params.setAbsoluteErrorTol(0.0)
    optimizer = gtsam.LevenbergMarquardtOptimizer(graph, values, params)
    result = optimizer.optimize()
    converged = optimizer.iterations() < max_iterations
    return result, optimizer.iterations(), graph.error(result), converged


def _copy_values(dst: gtsam.Values, src: gtsam.Values) -> None:
    """Overwrite the entries of ``dst`` that ``src`` also holds (Pose3, Rot3 or vector)."""
    for key in dst.keys():
        if not src.exists(key):
            continue
        for getter in (src.atPose3, src.atRot3, src.atVector):
            try:
                dst.update(key, getter(key))
                break
            except RuntimeError:
                continue


@dataclass
class _Prepared:
    axes: list
    lines: list[np.ndarray]  # initial image axes from the ellipse centres
    n_points: list[int]


def _prepare(arm: Arm, camera: Camera, measurements: list[Measurement], options: CalibrationOptions) -> _Prepared:
    if len(measurements) < MIN_MEASUREMENTS:
        raise InputError(f"need at least {MIN_MEASUREMENTS} measurements (arm poses) to calibrate, "
                         f"got {len(measurements)}")
    axes, lines, n_points = [], [], []
    min_points = max(options.min_track_points, MIN_ELLIPSE_POINTS)
    for k, m in enumerate(measurements):
        axes.append(arm.wrist_axis(m.joint_angles))
        ellipses = []
        for track in m.tracks:
            pixels = track.pixels if hasattr(track, "pixels") else np.asarray(track)
            if len(pixels) >= min_points:
                ellipse = fit_ellipse(camera.undistort_pixels(pixels))
                if ellipse is not None:
                    ellipses.append(ellipse)
        if len(ellipses) < 2:
            raise InputError(f"measurement {k}: only {len(ellipses)} usable track(s) (>= {min_points} points "
                             "and an ellipse fit), need at least 2")
        lines.append(initial_image_axis(ellipses))
        n_points.append(sum(len(t) for t in m.tracks))
    return _Prepared(axes, lines, n_points)


def _stage2_graph(pose_key, axes, lines, K, noises) -> gtsam.NonlinearFactorGraph:
    graph = gtsam.NonlinearFactorGraph()
    for axis, line, noise in zip(axes, lines, noises, strict=True):
        graph.add(make_axis_to_line_factor(noise, pose_key, axis_test_points(axis), line, K))
    return graph


def _best_stage2(graph, pose_key, starts, options) -> tuple[gtsam.Pose3, float, int]:
    best = None
    for start in starts:
        values = gtsam.Values()
        values.insert(pose_key, start)
        result, iterations, error, _ = _lm(graph, values, options.max_iterations)
        if best is None or error < best[1]:
            best = (result.atPose3(pose_key), error, iterations)
    return best


def _random_restarts(pose: gtsam.Pose3, n: int, rng: np.random.Generator) -> list[gtsam.Pose3]:
    out = []
    for _ in range(n):
        xi = np.concatenate([rng.normal(scale=np.radians(10.0), size=3), rng.normal(scale=0.1, size=3)])
        out.append(pose.retract(xi))
    return out


def initial_pose(arm: Arm, camera: Camera, measurements: list[Measurement],
                 options: CalibrationOptions | None = None) -> gtsam.Pose3:
    """Guess-free initial ``arm_T_camera`` from ellipse-centre lines and FK axes (DESIGN.md §5)."""
    options = CalibrationOptions() if options is None else options
    return _initial(arm, camera, measurements, options)[0]


def _initial(arm, camera, measurements, options):
    prepared = _prepare(arm, camera, measurements, options)
    K = camera.K
    normals = np.array([plane_normal(K, line) for line in prepared.lines])
    candidates = pose_candidates(normals, prepared.axes, n_best=options.n_candidates)
    if not candidates:
        raise CalibrationError("no pose candidate puts the wrist in front of the camera")
    key = gtsam.symbol("T", 0)
    unit = [gtsam.noiseModel.Isotropic.Sigma(2, 1.0)] * len(prepared.axes)
    graph = _stage2_graph(key, prepared.axes, prepared.lines, K, unit)
    pose, error, _ = _best_stage2(graph, key, candidates, options)
    rms = np.sqrt(2.0 * error / (2 * len(prepared.axes)))
    if rms > options.max_initial_rms_px:
        raise CalibrationError(
            f"initialisation ended in a poor minimum: the FK axes miss the image axes by {rms:.1f} px RMS "
            f"(limit {options.max_initial_rms_px} px); check joint angles, camera intrinsics and tracks")
    return pose, prepared


# ---------------------------------------------------------------------------------------------------
# estimators


def _stage1(arm, camera, measurements, pose, options):
    """Per-measurement coaxial circle fits: image line, its 3x3 covariance, residual scale, reports."""
    builder = RotIdGraph(arm, camera, min_track_points=options.min_track_points)
    out = []
    for k, m in enumerate(measurements):
        graph, values = gtsam.NonlinearFactorGraph(), gtsam.Values()
        keys = builder.add_measurement(graph, values, k, m, arm_T_camera=pose, tie=False)
        result, iterations, error, _ = _lm(graph, values, options.max_iterations)
        n = sum(graph.at(i).dim() for i in keys.circle_factors)
        dof = max(n - 3 - 2 * len(keys.circles), 1)
        sigma2 = max(2.0 * error / dof, options.min_sigma_px**2)
        R = result.atRot3(keys.line)
        line, J = image_line_from_rot3(camera.K, R)
        cov_R = gtsam.Marginals(graph, result).marginalCovariance(keys.line)  # unit pixel noise
        out.append(dict(line=line, line_cov=J @ cov_R @ J.T, sigma2=sigma2, keys=keys, n=n))
    return out


def _two_stage(arm, camera, measurements, method, options, init_pose, prepared):
    K = camera.K
    stage1 = _stage1(arm, camera, measurements, init_pose, options)
    key = gtsam.symbol("T", 0)
    lines = [s["line"] for s in stage1]
    rng = np.random.default_rng(options.seed)
    if method is Method.PAPER:
        noises = [gtsam.noiseModel.Isotropic.Sigma(2, 1.0)] * len(lines)
        graph = _stage2_graph(key, prepared.axes, lines, K, noises)
        starts = [init_pose, *_random_restarts(init_pose, options.restarts, rng)]
        pose, error, iterations = _best_stage2(graph, key, starts, options)
        weights = np.ones(len(lines))
    else:
        pose, iterations = init_pose, 0
        for _ in range(2):  # the distance covariance depends on where the test points project
            camera_T_arm = pose.inverse()
            noises = []
            for axis, s in zip(prepared.axes, stage1, strict=True):
                pts = np.array([camera_T_arm.transformFrom(p) for p in axis_test_points(axis)])
                cov = line_distance_covariance(s["line_cov"] * s["sigma2"], camera.project(pts, distort=False))
                base = gtsam.noiseModel.Gaussian.Covariance(cov + 1e-12 * np.eye(2))
                noises.append(gtsam.noiseModel.Robust.Create(gtsam.noiseModel.mEstimator.Huber.Create(3.0), base))
            graph = _stage2_graph(key, prepared.axes, lines, K, noises)
            pose, error, it = _best_stage2(graph, key, [pose], options)
            iterations += it
        sig = np.array([np.sqrt(s["sigma2"]) for s in stage1])
        weights = np.median(sig) ** 2 / sig**2
    values = gtsam.Values()
    values.insert(key, pose)
    info = pose_information(graph, values, key)
    observability = analyse_observability(info, pose)
    covariance = observability.covariance(info)
    reports, sigmas = [], []
    for k, s in enumerate(stage1):
        sigmas.append(np.sqrt(s["sigma2"]))
        reports.append(MeasurementReport(k, len(s["keys"].circles), s["n"], float(np.sqrt(s["sigma2"])),
                                         float(weights[k]), False, dict(s["keys"].rejected)))
    _flag_outlier_measurements(reports, options)
    return CalibrationResult(pose, covariance, method.value, True, iterations, float(error), reports, observability,
                             float(np.median(sigmas)))


def _flag_outlier_measurements(reports: list[MeasurementReport], options: CalibrationOptions) -> None:
    rms = np.array([r.residual_rms_px for r in reports])
    median = np.median(rms)
    for r in reports:
        r.outlier = bool(r.residual_rms_px > options.outlier_measurement_ratio * median)


def _joint(arm, camera, measurements, options, init_pose):
    pose_key = gtsam.symbol("T", 0)
    builder = RotIdGraph(arm, camera, pose_key=pose_key, tie_sigma_px=options.tie_sigma_px,
                         min_track_points=options.min_track_points)
    skip: list[set] = [set() for _ in measurements]
    outlier_reason: list[dict] = [{} for _ in measurements]
    sigmas: list[dict | None] = [None] * len(measurements)

    def solve(previous):
        """Build the joint graph with the current weights and rejections; LM from ``previous`` if given."""
        graph, values = gtsam.NonlinearFactorGraph(), gtsam.Values()
        values.insert(pose_key, init_pose if previous is None else previous.atPose3(pose_key))
        all_keys = [builder.add_measurement(graph, values, k, m, track_sigmas=sigmas[k], skip_tracks=skip[k])
                    for k, m in enumerate(measurements)]
        if previous is not None:
            _copy_values(values, previous)
        return (graph, all_keys, *_lm(graph, values, options.max_iterations))

    previous = None
    iterations_total = 0
    for _round in range(3):
        graph, all_keys, result, iterations, error, converged = solve(previous)
        iterations_total += iterations
        previous = result
        # residuals per track (in pixels) at the solution
        changed = False
        per_measurement_sigma = []
        for k, keys in enumerate(all_keys):
            track_rms = {}
            for j, fi in zip(keys.tracks, keys.circle_factors, strict=True):
                e = graph.at(fi).unwhitenedError(result)
                track_rms[j] = float(np.sqrt(np.mean(e**2)))
            median = np.median(list(track_rms.values()))
            for j, value in track_rms.items():
                if value > options.outlier_track_ratio * max(median, options.min_sigma_px):
                    skip[k].add(j)
                    outlier_reason[k][j] = f"residual RMS {value:.2f} px > {options.outlier_track_ratio}x the median"
                    changed = True
            n = sum(graph.at(fi).dim() for j, fi in zip(keys.tracks, keys.circle_factors, strict=True)
                    if j not in skip[k])
            sse = sum((track_rms[j] ** 2) * graph.at(fi).dim()
                      for j, fi in zip(keys.tracks, keys.circle_factors, strict=True) if j not in skip[k])
            dof = max(n - 3 - 2 * (len(keys.tracks) - len(skip[k] & set(keys.tracks))), 1)
            per_measurement_sigma.append(max(np.sqrt(sse / dof), options.min_sigma_px))
        new_sigmas = [{j: s for j in keys.tracks} for keys, s in zip(all_keys, per_measurement_sigma, strict=True)]
        rescaled = any(old is None or abs(next(iter(old.values())) / s - 1.0) > 0.05
                       for old, s in zip(sigmas, per_measurement_sigma, strict=True))
        sigmas = new_sigmas
        if not changed and not rescaled:
            break
    # final solve with the last weights and rejections already applied above (loop exits after a stable round)
    if changed or rescaled:
        graph, all_keys, result, iterations, error, converged = solve(previous)
        iterations_total += iterations
    pose = result.atPose3(pose_key)
    info = pose_information(graph, result, pose_key)
    observability = analyse_observability(info, pose)
    if observability.is_observable:
        covariance = gtsam.Marginals(graph, result).marginalCovariance(pose_key)
    else:
        covariance = observability.covariance(info)
    sig = np.array(per_measurement_sigma)
    reports = []
    for k, keys in enumerate(all_keys):
        rejected = {**keys.rejected, **outlier_reason[k]}
        reports.append(MeasurementReport(k, len(keys.tracks), sum(graph.at(fi).dim() for fi in keys.circle_factors),
                                         float(sig[k]), float(np.median(sig) ** 2 / sig[k] ** 2), False, rejected))
    _flag_outlier_measurements(reports, options)
    return CalibrationResult(pose, covariance, Method.JOINT.value, bool(converged), iterations_total, float(error),
                             reports, observability, float(np.median(sig)))


def calibrate(arm: Arm | Dataset, camera: Camera | None = None, measurements: list[Measurement] | None = None,
              method: str | Method = Method.JOINT, options: CalibrationOptions | None = None) -> CalibrationResult:
    """Estimate ``arm_T_camera`` from wrist spins.

    Call as ``calibrate(dataset)`` or ``calibrate(arm, camera, measurements)``.
    """
    if isinstance(arm, Dataset):
        dataset = arm
        arm, camera, measurements = dataset.arm, dataset.camera, list(dataset)
    if camera is None or measurements is None:
        raise InputError("calibrate needs a Dataset, or an Arm, a Camera and a list of Measurements")
    try:
        method = Method(method)
    except ValueError:
        raise InputError(f"unknown method {method!r}; choose one of {[m.value for m in Method]}") from None
    options = CalibrationOptions() if options is None else options
    measurements = [m if isinstance(m, Measurement) else Measurement(*m) for m in measurements]
    init_pose, prepared = _initial(arm, camera, measurements, options)
    if method is Method.JOINT:
        return _joint(arm, camera, measurements, options, init_pose)
    return _two_stage(arm, camera, measurements, method, options, init_pose, prepared)

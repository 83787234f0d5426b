"""The covariance report of a calibration: numbers, words and a pretty printer.

``make_report(result, dataset=None)`` returns a :class:`CalibrationReport`: the estimate (position in mm,
roll-pitch-yaw in degrees, quaternion), its 1σ and 95 % bounds, the correlation matrix with the strong
correlations named, per-measurement residuals, weights, outliers and rejected tracks, the χ² consistency of
the fit, and the observability verdict in plain words with what pose to add. ``to_text()``,
``to_markdown()`` and ``to_dict()`` (JSON) print it.

Frames and layout: the covariance is shown in the layout the exports use (:mod:`gtsam_rotid.export`, ROS
``PoseWithCovariance``): the camera position ``(x, y, z)`` in the arm-base frame and small rotations about
the arm-base axes X, Y, Z (``rX, rY, rZ``). Roll, pitch and yaw are URDF's (``R = Rz(yaw) Ry(pitch)
Rx(roll)``); their 1σ is propagated from the rotation block. The estimated camera frame is OpenCV's optical
frame (x right, y down, z forward).

With the dataset (or a result that carries each measurement's wrist axis) the words locate the common
point of the wrist axes, e.g. for a single crossing: "all 6 wrist axes pass within 0.0 mm of P = (…) mm:
the camera's position along the line through P and the camera is not determined"; the suggestion says what
pose to add.
"""

from __future__ import annotations

import json
import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from enum import StrEnum
from pathlib import Path

import numpy as np

from .diagnosis import (  # noqa: F401 (the constants are re-exported)
    CROSSING_TOLERANCE_M,
    JOINT_REDUCED_TOLERANCE,
    P_LOW,
    PARALLEL_TOLERANCE_DEG,
    AxisGeometry,
    Chi2Check,
    axis_geometry,
    chi2_check,
    wrist_axes,
)
from .errors import InputError, RotIdError
from .geometry import correlation, quaternion_xyzw, ros_covariance, rpy_jacobian
from .uncertainty import UNOBSERVABLE_SIGMA_M, UNOBSERVABLE_SIGMA_RAD, chi2_sf  # noqa: F401 (re-export)
from .words import (
    ambiguity_words,
    axis_consistency_sentence,
    camera_motion_line,
    image_shift_words,
    intrinsics_assumed_words,
    intrinsics_suspected,
    joint_offsets_words,
    kinematics_suspected,
    kinematics_words,
    observability_words,
    outlier_words,
    readings_ignored_words,
    refined_intrinsics_words,
    synced_words,
    tracking_words,
    untrusted_words,
    verdict,
)

#: Two-sided 95 % point of the normal distribution: the 95 % bound of one axis is Z95 σ.
Z95 = 1.959963984540054
#: 95 % point of the χ² distribution with 3 dof: the 95 % position ellipsoid has semi-axes sqrt(this) σ.
CHI2_95_3DOF = 7.814727903251178
#: Correlations with |ρ| above this are called out.
STRONG_CORRELATION = 0.8
#: The suggested pose's wrist axis should miss the crossing point by at least this (m).
SUGGESTED_MISS_M = 0.05
#: The suggested pose's wrist axis should be tilted from parallel ones by at least this (deg).
SUGGESTED_TILT_DEG = 20.0
LABELS = ("x", "y", "z", "rX", "rY", "rZ")
COVARIANCE_ORDER = ("x, y, z: camera position in the arm-base frame (m); rX, rY, rZ: small rotation about the "
                    "arm-base axes X, Y, Z (rad), R_true = Exp(r) R (ROS PoseWithCovariance layout)")


class ReportFormat(StrEnum):
    TEXT = "text"
    MARKDOWN = "markdown"
    JSON = "json"
    #: a self-contained page with the plots embedded (:mod:`gtsam_rotid.htmlreport`)
    HTML = "html"


def _vec(v, fmt: str = "{:.1f}") -> str:
    return "(" + ", ".join(fmt.format(float(x)) for x in v) + ")"


def _direction(v) -> str:
    v = np.asarray(v, dtype=float)
    v = v / np.linalg.norm(v)
    v = v if v[np.argmax(np.abs(v))] > 0 else -v
    return _vec(v, "{:+.3f}")


# ---------------------------------------------------------------------------------------------------
# the report


@dataclass
class CalibrationReport:
    """Everything a user needs to judge a calibration; print with ``to_text()`` / ``to_markdown()``."""

    method: str
    converged: bool
    iterations: int
    sigma_px: float
    arm_T_camera: np.ndarray  # 4x4, camera (OpenCV optical frame) in the arm-base frame, metres
    translation_mm: np.ndarray
    rpy_deg: np.ndarray  # URDF roll, pitch, yaw
    quaternion_xyzw: np.ndarray
    covariance: np.ndarray  # 6x6, COVARIANCE_ORDER (m, rad)
    covariance_usable: bool
    sigma_position_mm: np.ndarray  # arm frame
    sigma_rpy_deg: np.ndarray
    sigma_rotation_arm_deg: np.ndarray  # about the arm axes X, Y, Z
    sigma_rotation_camera_deg: np.ndarray  # about the camera axes x, y, z
    determined: np.ndarray  # (6,) bool per LABELS entry: 1σ within the observability limits
    ellipsoid95_mm: np.ndarray  # semi-axes of the 95 % position ellipsoid, descending
    ellipsoid95_axes: np.ndarray  # 3x3, columns: their arm-frame directions
    correlation: np.ndarray  # 6x6, LABELS order
    strong_correlations: list[tuple[str, str, float]]
    chi2: Chi2Check
    observability: list[str]
    suggestion: str
    condition_number: float
    weakest_position: tuple[np.ndarray, float]  # arm-frame direction, 1σ (mm)
    weakest_rotation: tuple[np.ndarray, float]  # arm-frame axis, 1σ (deg)
    measurements: list = field(default_factory=list)  # MeasurementReport
    crossing_point_mm: np.ndarray | None = None
    crossing_miss_mm: float | None = None
    #: another, distinct pose fits the data almost as well (``result.alternatives``): nothing is determined
    ambiguous: bool = False
    #: weighted, joint: do the measurements' axes agree with one pose (``result.axis_consistency``)? None: no test
    axis_consistency: object | None = None
    #: the joint-angle sigma (deg) the covariance includes; 0: exact kinematics (``result.joint_sigma_deg``)
    joint_sigma_deg: float = 0.0
    #: the image axes' prior floor (px) the covariance includes (``result.axis_floor_px``)
    axis_floor_px: float = 0.0
    #: each track's own offset (px) the covariance includes (``result.track_offset_px``)
    track_offset_px: float = 0.0
    #: the joint offsets refined with the pose (joint name -> deg) and their 1σ (deg); None: kinematics as given
    joint_offsets_deg: dict | None = None
    joint_offsets_sigma_deg: dict = field(default_factory=dict)
    joint_offset_prior_deg: float = 0.0
    #: the intrinsics refined with the pose (name -> px), their 1σ (px), the camera file's values and the prior
    #: (focal fraction, principal point px); {} / None: the camera as given
    intrinsics: dict = field(default_factory=dict)
    intrinsics_sigma: dict = field(default_factory=dict)
    given_intrinsics: dict = field(default_factory=dict)
    intrinsics_prior: tuple | None = None
    #: synced mode: the measurements whose spin readings were used, the encoder clock's offset (s) and its 1σ
    synced: tuple = ()
    time_offset_s: float | None = None
    time_offset_sigma_s: float | None = None
    time_offset_prior_sigma_s: float | None = None
    readings_refused: dict = field(default_factory=dict)
    time_offset_noise_share: float | None = None
    #: synced with named camera clocks: each clock's offset (``CalibrationResult.time_offsets``)
    time_offsets: dict | None = None
    #: the measurements carry joint readings that this method does not use (only joint with the rigid spin)
    readings_ignored: bool = False
    #: intrinsics as given: what the tracks' shapes say of them (``result.intrinsics_shapes``); None: not checked
    intrinsics_shapes: dict | None = None
    #: why a determined calibration's covariance is still not trusted (``result.untrusted``'s kinds)
    untrusted: list = field(default_factory=list)
    #: one line: usable and how well, or why not and what to do (:func:`gtsam_rotid.words.verdict`)
    verdict: str = ""
    #: what the videos' background said of the camera's move between them (:func:`gtsam_rotid.words.camera_motion_line`)
    #: and, where an image shift per pose that the data cannot show would exceed the 1σ, how much and what to do
    #: (:func:`gtsam_rotid.words.image_shift_words`); "" where neither has anything to say
    camera_still: str = ""
    #: for a calibration the poses do not determine: the arm pose (joint name -> rad) that most reduces its worst 1σ
    next_pose: dict | None = None

    @property
    def bound95_position_mm(self) -> np.ndarray:
        return Z95 * self.sigma_position_mm

    @property
    def bound95_rpy_deg(self) -> np.ndarray:
        return Z95 * self.sigma_rpy_deg

    @property
    def bound95_rotation_arm_deg(self) -> np.ndarray:
        return Z95 * self.sigma_rotation_arm_deg

    @property
    def rejected_tracks(self) -> list[tuple[int, int, str]]:
        return [(m.index, j, why) for m in self.measurements for j, why in sorted(m.rejected_tracks.items())]

    # ------------------------------------------------------------------ printing
    def _estimate_rows(self) -> list[tuple[str, str, str, str]]:
        rows = []
        values = [*self.translation_mm, *self.rpy_deg]
        sigmas = [*self.sigma_position_mm, *self.sigma_rpy_deg]
        names = ["x (mm)", "y (mm)", "z (mm)", "roll (deg)", "pitch (deg)", "yaw (deg)"]
        determined = [*self.determined[:3], *([bool(np.all(self.determined[3:]))] * 3)]
        for i, (name, value, sigma, ok) in enumerate(zip(names, values, sigmas, determined, strict=True)):
            digits = 2 if i < 3 else 4
            shown = f"{round(float(value), digits) + 0.0:.{digits}f}"  # + 0.0: no "-0.0000"
            if ok:
                rows.append((name, shown, f"{sigma:.3g}", f"±{Z95 * sigma:.3g}"))
            else:
                rows.append((name, shown, *[self._not_shown] * 2))
        return rows

    @property
    def _not_shown(self) -> str:
        """What the estimate's table says where it gives no 1σ: why."""
        if self.untrusted and not self.ambiguous:  # (result.untrusted is empty where not determined)
            return "not trusted"
        return "not determined"

    def _observability_lines(self) -> list[str]:
        lines = list(self.observability)
        if self.suggestion:
            lines.append(f"SUGGESTION: {self.suggestion}")
        return lines

    def _measurement_rows(self) -> list[tuple[str, ...]]:
        rows = []
        for m in self.measurements:
            why = outlier_words(m, intrinsics_suspected(self.untrusted), kinematics_suspected(self.untrusted))
            status = "OUTLIER: " + why if m.outlier else "ok"
            rows.append((str(m.index), str(m.n_tracks), str(m.n_points), f"{m.residual_rms_px:.3f}",
                         f"{m.weight:.2f}", str(len(m.rejected_tracks)), status))
        return rows

    def _header_lines(self) -> list[str]:
        state = "converged" if self.converged else "NOT converged"
        return [f"method {self.method}, {state} after {self.iterations} iterations, pixel noise {self.sigma_px:.3f} "
                "px (estimated from the residuals)",
                "arm_T_camera: the camera pose (OpenCV optical frame: x right, y down, z forward) in the arm-base "
                "frame", kinematics_words(self.joint_sigma_deg, self.joint_offsets_deg is not None),
                *joint_offsets_words(self.joint_offsets_deg, self.joint_offsets_sigma_deg, self.joint_offset_prior_deg,
                                     all(m.spin_joint is None for m in self.measurements)),
                *refined_intrinsics_words(self.intrinsics, self.intrinsics_sigma, self.given_intrinsics,
                                          self.intrinsics_prior),
                *filter(None, [intrinsics_assumed_words(self.intrinsics_shapes)]),
                *synced_words(self.synced, self.time_offset_s, self.time_offset_sigma_s, len(self.measurements),
                              self.time_offset_prior_sigma_s, self.readings_refused, self.time_offset_noise_share,
                              self.time_offsets),
                *readings_ignored_words(self.readings_ignored, self.method),
                tracking_words(self.axis_floor_px, self.track_offset_px),
                *filter(None, [self.camera_still])]

    def _uncertainty_lines(self) -> list[str]:
        q = self.quaternion_xyzw
        lines = [f"quaternion (x, y, z, w): {_vec(q, '{:.8f}')}"]
        if self.ambiguous:
            lines.append("COVARIANCE UNUSABLE: several camera poses fit the data (see observability); the 1σ below "
                         "describe only the one shown")
        elif not self.covariance_usable and self.untrusted:
            lines.append("COVARIANCE UNUSABLE: the data do not support it (NOT TRUSTED, see observability); the 1σ "
                         "below are not to be relied on")
        elif not self.covariance_usable:
            lines.append("COVARIANCE UNUSABLE: the arm poses do not determine the calibration (see observability); "
                         "the 1σ of undetermined directions is meaningless")
        lines.append(f"rotation 1σ about the arm axes X, Y, Z (deg): {_vec(self.sigma_rotation_arm_deg, '{:.4g}')}; "
                     f"95 % ±{_vec(self.bound95_rotation_arm_deg, '{:.4g}')}")
        lines.append(f"rotation 1σ about the camera axes x, y, z (deg): "
                     f"{_vec(self.sigma_rotation_camera_deg, '{:.4g}')}")
        if self.covariance_usable:
            a = self.ellipsoid95_axes
            lines.append("95 % position ellipsoid: semi-axes " + ", ".join(
                f"{s:.3g} mm along {_direction(a[:, i])}" for i, s in enumerate(self.ellipsoid95_mm)))
        return lines

    def _correlation_lines(self, markdown: bool) -> list[str]:
        strong = [f"{a}–{b} {rho:+.2f}" for a, b, rho in self.strong_correlations]
        summary = (f"strong correlations (|ρ| > {STRONG_CORRELATION:g}): " + (", ".join(strong) if strong else "none"))
        if markdown:
            lines = ["| | " + " | ".join(LABELS) + " |", "|---" * 7 + "|"]
            lines += [f"| **{LABELS[i]}** | " + " | ".join(f"{v:+.2f}" for v in row) + " |"
                      for i, row in enumerate(self.correlation)]
        else:
            lines = ["      " + "".join(f"{name:>7}" for name in LABELS)]
            lines += [f"  {LABELS[i]:<4}" + "".join(f"{v:+7.2f}" for v in row)
                      for i, row in enumerate(self.correlation)]
        if not self.covariance_usable:
            summary += (" (the covariance is not trusted: not meaningful)" if self._not_shown == "not trusted"
                        else " (the undetermined direction dominates: not meaningful)")
        return [*lines, "", summary]

    def to_text(self) -> str:
        out = ["gtsam_rotid calibration report", self.verdict, *self._header_lines(), ""]
        out.append(f"  {'':<12}{'estimate':>14}{'1σ':>16}{'95 % (±1.96σ)':>18}")
        out += [f"  {n:<12}{v:>14}{s:>16}{b:>18}" for n, v, s, b in self._estimate_rows()]
        out += ["  " + line for line in self._uncertainty_lines()]
        out += ["", "correlation (x, y, z: position in the arm frame; rX, rY, rZ: rotation about the arm axes):"]
        out += ["  " + line if line else "" for line in self._correlation_lines(False)]
        out += ["", "fit consistency:", "  " + self.chi2.sentence(), f"  tested: {self.chi2.what}"]
        if self.chi2.note:
            out.append(f"  note: {self.chi2.note}")
        if self.axis_consistency is not None:
            out.append("  " + axis_consistency_sentence(self.axis_consistency))
        out += ["", "observability:"] + ["  " + line for line in self._observability_lines()]
        out += ["", "measurements:",
                f"  {'k':>3} {'tracks':>6} {'points':>7} {'RMS px':>7} {'weight':>6} {'rejected':>8}  status"]
        out += [f"  {k:>3} {t:>6} {p:>7} {r:>7} {w:>6} {n:>8}  {s}" for k, t, p, r, w, n, s in self._measurement_rows()]
        rejected = self.rejected_tracks
        out += ["", "rejected tracks:" + ("" if rejected else " none")]
        out += [f"  measurement {k}, track {j}: {why}" for k, j, why in rejected]
        return "\n".join(out) + "\n"

    def to_markdown(self, plots: Sequence[str] = ()) -> str:
        """Markdown; ``plots`` (paths relative to where the markdown is written) are linked under "Plots"."""
        out = ["# Calibration report", "", f"**{self.verdict}**", "", *[f"{line}  " for line in self._header_lines()],
               "",
               "## Estimate", "", "| | estimate | 1σ | 95 % (±1.96σ) |", "|---|---:|---:|---:|"]
        out += [f"| {n} | {v} | {s} | {b} |" for n, v, s, b in self._estimate_rows()]
        out += [""] + [f"- {line}" for line in self._uncertainty_lines()]
        out += ["", "## Correlation", "",
                "x, y, z: camera position in the arm frame; rX, rY, rZ: rotation about the arm axes.", ""]
        out += self._correlation_lines(True)
        out += ["", "## Fit consistency", "", f"- {self.chi2.sentence()}", f"- tested: {self.chi2.what}"]
        if self.chi2.note:
            out.append(f"- note: {self.chi2.note}")
        if self.axis_consistency is not None:
            out.append(f"- {axis_consistency_sentence(self.axis_consistency)}")
        out += ["", "## Observability", ""] + [f"- {line}" for line in self._observability_lines()]
        out += ["", "## Measurements", "", "| k | tracks | points | RMS (px) | weight | rejected | status |",
                "|---:|---:|---:|---:|---:|---:|---|"]
        out += ["| " + " | ".join(row) + " |" for row in self._measurement_rows()]
        rejected = self.rejected_tracks
        out += ["", "### Rejected tracks", ""]
        out += [f"- measurement {k}, track {j}: {why}" for k, j, why in rejected] if rejected else ["none"]
        if plots:
            out += ["", "## Plots", ""] + [f"![{Path(p).stem}](<{p}>)" for p in plots]  # <>: spaces, parentheses
        return "\n".join(out) + "\n"

    def __str__(self) -> str:
        return self.to_text()

    def to_dict(self) -> dict:
        def f(x):
            x = float(x)
            return x if math.isfinite(x) else None

        def arr(a):
            return np.vectorize(f, otypes=[object])(np.asarray(a, dtype=float)).tolist()

        return {
            "format": "gtsam_rotid.report",
            "version": 1,
            "verdict": self.verdict,
            "camera_still": self.camera_still or None,
            "method": self.method,
            "converged": self.converged,
            "iterations": self.iterations,
            "sigma_px": f(self.sigma_px),
            "arm_T_camera": arr(self.arm_T_camera),
            "translation_mm": arr(self.translation_mm),
            "rpy_deg": arr(self.rpy_deg),
            "quaternion_xyzw": arr(self.quaternion_xyzw),
            "covariance": arr(self.covariance),
            "covariance_order": COVARIANCE_ORDER,
            "covariance_usable": self.covariance_usable,
            "ambiguous": self.ambiguous,
            "sigma": {"position_mm": arr(self.sigma_position_mm), "rpy_deg": arr(self.sigma_rpy_deg),
                      "rotation_arm_deg": arr(self.sigma_rotation_arm_deg),
                      "rotation_camera_deg": arr(self.sigma_rotation_camera_deg)},
            "bound95": {"position_mm": arr(self.bound95_position_mm), "rpy_deg": arr(self.bound95_rpy_deg),
                        "rotation_arm_deg": arr(self.bound95_rotation_arm_deg)},
            "determined": dict(zip(LABELS, (bool(d) for d in self.determined), strict=True)),
            "ellipsoid95_mm": {"semi_axes": arr(self.ellipsoid95_mm), "directions": arr(self.ellipsoid95_axes)},
            "correlation": arr(self.correlation),
            "correlation_labels": list(LABELS),
            "strong_correlations": [{"a": a, "b": b, "rho": f(rho)} for a, b, rho in self.strong_correlations],
            "chi2": {k: (f(v) if isinstance(v, float) else v) for k, v in self.chi2.to_dict().items()},
            "joint_sigma_deg": f(self.joint_sigma_deg),
            "axis_floor_px": f(self.axis_floor_px),
            "track_offset_px": f(self.track_offset_px),
            "joint_offsets_deg": None if self.joint_offsets_deg is None
            else {k: f(v) for k, v in self.joint_offsets_deg.items()},
            "joint_offsets_sigma_deg": {k: f(v) for k, v in self.joint_offsets_sigma_deg.items()},
            "joint_offset_prior_deg": f(self.joint_offset_prior_deg),
            "intrinsics": {k: f(v) for k, v in self.intrinsics.items()},
            "intrinsics_sigma": {k: f(v) for k, v in self.intrinsics_sigma.items()},
            "given_intrinsics": {k: f(v) for k, v in self.given_intrinsics.items()},
            "intrinsics_prior": None if self.intrinsics_prior is None else [f(v) for v in self.intrinsics_prior],
            "intrinsics_shapes": self.intrinsics_shapes,
            "synced": list(self.synced),
            "time_offset_s": None if self.time_offset_s is None else f(self.time_offset_s),
            "time_offset_sigma_s": None if self.time_offset_sigma_s is None else f(self.time_offset_sigma_s),
            "time_offset_prior_sigma_s": None if self.time_offset_prior_sigma_s is None
            else f(self.time_offset_prior_sigma_s),
            "readings_refused": {str(k): dict(v) for k, v in self.readings_refused.items()},
            "time_offset_noise_share": None if self.time_offset_noise_share is None
            else f(self.time_offset_noise_share),
            "time_offsets": None if self.time_offsets is None else {
                c: {"offset_s": f(v["offset_s"]), "sigma_s": None if v.get("sigma_s") is None else f(v["sigma_s"]),
                    "noise_share": None if v.get("noise_share") is None else f(v["noise_share"]),
                    "measurements": list(v.get("measurements") or ())} for c, v in self.time_offsets.items()},
            "readings_ignored": self.readings_ignored,
            "untrusted": list(self.untrusted),
            "axis_consistency": None if self.axis_consistency is None
            else {k: (f(v) if isinstance(v, float) else v) for k, v in self.axis_consistency.to_dict().items()},
            "observability": {
                "words": list(self.observability),
                "suggestion": self.suggestion,
                "next_pose_rad": self.next_pose,
                "condition_number": f(self.condition_number),
                "crossing_point_mm": None if self.crossing_point_mm is None else arr(self.crossing_point_mm),
                "crossing_miss_mm": None if self.crossing_miss_mm is None else f(self.crossing_miss_mm),
                "weakest_position": {"direction": arr(self.weakest_position[0]),
                                     "sigma_mm": f(self.weakest_position[1])},
                "weakest_rotation": {"axis": arr(self.weakest_rotation[0]), "sigma_deg": f(self.weakest_rotation[1])},
            },
            "measurements": [
                {"index": m.index, "n_tracks": m.n_tracks, "n_points": m.n_points,
                 "residual_rms_px": f(m.residual_rms_px), "weight": f(m.weight), "outlier": bool(m.outlier),
                 "outlier_reason": outlier_words(m, intrinsics_suspected(self.untrusted),
                                                 kinematics_suspected(self.untrusted)),
                 "arc_span_deg": None if getattr(m, "arc_span_deg", None) is None else f(m.arc_span_deg),
                 "weak": bool(getattr(m, "weak", False)),
                 "rejected_tracks": {str(j): why for j, why in sorted(m.rejected_tracks.items())}}
                for m in self.measurements
            ],
        }

    def to_json(self) -> str:
        return json.dumps(self.to_dict(), indent=1, ensure_ascii=False) + "\n"

    def render(self, fmt: str | ReportFormat = ReportFormat.TEXT) -> str:
        try:
            fmt = ReportFormat(fmt)
        except ValueError:
            raise InputError(f"unknown report format {fmt!r}; choose one of "
                             f"{[f.value for f in ReportFormat]}") from None
        if fmt is ReportFormat.MARKDOWN:
            return self.to_markdown()
        if fmt is ReportFormat.JSON:
            return self.to_json()
        if fmt is ReportFormat.HTML:
            from .htmlreport import to_html  # (same layer) the page without plots; the CLI embeds them
            return to_html(self)
        return self.to_text()


def _strongest(block: np.ndarray) -> tuple[np.ndarray, float]:
    w, V = np.linalg.eigh(0.5 * (block + block.T))
    v = V[:, -1]
    return (v if v[np.argmax(np.abs(v))] > 0 else -v), float(np.sqrt(max(w[-1], 0.0)))


def _untrusted_suggestion(untrusted: list) -> str:
    """What to do about a calibration that is determined but not trusted, by the reasons it is not."""
    if "swapped" in untrusted:
        return ("give each video with its own arm pose (the order of the videos, or image folders, as the joint "
                "rows') and calibrate again")
    if intrinsics_suspected(untrusted):
        return ("check the camera file (is it this camera's, at this resolution?) and calibrate the intrinsics again, "
                "or refine them with the pose (calibrate --refine-intrinsics), recording more arm poses planned for "
                "that (plan --refine-intrinsics) to keep the precision")
    if kinematics_suspected(untrusted):
        return ("check the robot's zero positions, or refine the joint offsets with the pose (calibrate "
                "--joint-offsets; a spin of the joint before the wrist at each pose makes more of them observable)")
    return "spin the wrist longer (a full turn), give the hand more texture, or add arm poses"


def _observability(result, cov: np.ndarray, geometry: AxisGeometry | None) -> tuple[list[str], str]:
    """(words, suggestion) of the observability verdict; ``cov`` in COVARIANCE_ORDER."""
    obs = result.observability
    undetermined = not obs.is_observable
    camera = np.asarray(result.arm_T_camera.translation(), dtype=float)
    words, suggestion = [], ""
    found_cause = False
    if geometry is not None and geometry.is_crossing:
        P = geometry.point
        ray = P - camera
        where = (f"all {len(geometry.miss)} wrist axes pass within {1000 * np.max(geometry.miss):.1f} mm of "
                 f"P = {_vec(1000 * P)} mm (arm frame)")
        if undetermined:
            found_cause = True
            words.append(f"DEGENERATE: {where}: the camera's position along the line through P and the camera "
                         f"(arm-frame direction {_direction(ray)}) is not determined")
            suggestion = (f"add a pose whose wrist axis misses P = {_vec(1000 * P)} mm by at least "
                          f"{100 * SUGGESTED_MISS_M:.0f} cm")
        else:
            u = ray / np.linalg.norm(ray)
            sigma = 1000.0 * float(np.sqrt(max(u @ cov[:3, :3] @ u, 0.0)))
            words.append(f"{where}: close to a single crossing, which leaves the camera's position along its ray "
                         f"to P undetermined; along that ray (arm-frame direction {_direction(ray)}) the position "
                         f"has 1σ {sigma:.3g} mm")
            suggestion = (f"to determine the position along that ray better, add a pose whose wrist axis misses P by "
                          f"at least {100 * SUGGESTED_MISS_M:.0f} cm")
    elif geometry is not None and geometry.is_parallel and undetermined:
        found_cause = True
        words.append(f"DEGENERATE: all {len(geometry.miss)} wrist axes are parallel within {geometry.spread_deg:.1f}° "
                     f"(arm-frame direction {_direction(geometry.mean_direction)}): the camera's position along that "
                     "direction is not determined")
        suggestion = f"add a pose whose wrist axis is tilted at least {SUGGESTED_TILT_DEG:.0f}° from the others"
    if undetermined:
        details = [w for w in observability_words(obs) if not w.startswith("DEGENERATE")]
        if not found_cause:
            pure = [d for d in obs.unobservable_directions if np.linalg.norm(d[:3]) < 0.1]
            if len(obs.unobservable_directions) == 1 and pure and geometry is None:
                d_arm = obs.arm_R_camera @ pure[0][3:]
                words.append(f"DEGENERATE: the camera's position along the line through the camera centre "
                             f"{_vec(1000 * camera)} mm in arm-frame direction {_direction(d_arm)} is not determined: "
                             "typically every wrist axis passes through one point of that line (a single crossing)")
                suggestion = (f"add a pose whose wrist axis misses that line by at least {100 * SUGGESTED_MISS_M:.0f} "
                              "cm (give the dataset to the report to locate the crossing point)")
            else:
                words.append("DEGENERATE: the chosen arm poses do not determine the calibration")
                suggestion = "add a pose whose wrist axis is not like the others: tilted from them and offset from " \
                             "their common point"
        words.append(f"undetermined directions ({len(obs.unobservable_directions)}, from the information matrix):")
        words.extend(f"  {w}" for w in details)
    else:
        words.append("all six degrees of freedom of arm_T_camera are determined")
    words.append(f"condition number of the information matrix: {obs.condition_number:.3g} (Pose3 tangent, rad and m)")
    if not undetermined:
        pos_dir, pos_sigma = _strongest(cov[:3, :3])
        rot_axis, rot_sigma = _strongest(cov[3:, 3:])
        words.append(f"least determined: position along arm-frame direction {_direction(pos_dir)} "
                     f"(1σ {1000 * pos_sigma:.3g} mm), rotation about arm-frame axis {_direction(rot_axis)} "
                     f"(1σ {np.degrees(rot_sigma):.3g}°)")
    return words, suggestion


#: candidate poses of the report's next-best-pose search (``gtsam-rotid plan --dataset`` searches more)
NEXT_POSE_CANDIDATES = 60


def _spin_seconds(dataset) -> float:
    """The median spin length (s) of a dataset's measurements, from its tracks' frame indices (30 fps unless the
    dataset says otherwise)."""
    fps = float(dataset.metadata.get("fps") or 30.0)
    spans = []
    for m in dataset:
        frames = [t.frames for t in m.tracks if getattr(t, "frames", None) is not None and len(t.frames)]
        if frames:
            spans.append((max(int(f[-1]) for f in frames) - min(int(f[0]) for f in frames) + 1) / fps)
    return float(np.median(spans)) if spans else 20.0


def next_best_pose(result, dataset) -> dict | None:
    """The arm pose (joint name -> rad) that most reduces the worst 1σ of ``result`` (its estimate as the camera
    guess, its information, from ``result.observability``, as what is known): :func:`gtsam_rotid.planning.plan_poses`
    with the result's pixel noise and axis floor and the dataset's spin length. None when no pose satisfies the
    plan's constraints."""
    from .planning import PlanOptions, plan_poses

    options = PlanOptions(candidates=NEXT_POSE_CANDIDATES, guess_samples=2, spin_seconds=_spin_seconds(dataset),
                          pixel_sigma=float(result.sigma_px) if result.sigma_px > 0 else 0.5,
                          axis_floor_px=float(getattr(result, "axis_floor_px", 0.0)))
    # the information from its eigen-analysis: the covariance holds 1e12 on an undetermined direction, which leaves
    # the rest of it with rounding errors of ~1e-4 (m², rad²), far above its real entries
    obs = result.observability
    information = (obs.eigenvectors * np.maximum(obs.eigenvalues, 0.0)) @ obs.eigenvectors.T
    try:
        plan = plan_poses(dataset.arm, dataset.camera, result.arm_T_camera, 1, options,
                          prior_information=information)
    except RotIdError:
        return None
    return {name: float(v) for name, v in zip(dataset.arm.joint_names, plan.joint_angles[0], strict=True)}


def make_report(result, dataset=None, *, strong_correlation: float = STRONG_CORRELATION,
                next_pose: bool = True) -> CalibrationReport:
    """The report of a :class:`~gtsam_rotid.estimate.CalibrationResult`.

    ``dataset`` (the one calibrated) lets the observability words locate the wrist axes' common point; without
    it they use the wrist axes the result carries, if any. With the dataset, a calibration that its poses do not
    determine (or that another pose fits as well) also gets the arm pose to add (:func:`next_best_pose`, a few
    seconds; ``next_pose=False`` skips it).
    """
    pose = result.arm_T_camera
    rotation = pose.rotation()
    cov = ros_covariance(pose, result.covariance)
    sigma = np.sqrt(np.maximum(np.diag(cov), 0.0))
    J = rpy_jacobian(rotation)
    cov_rpy = J @ cov[3:, 3:] @ J.T
    determined = np.array([s <= UNOBSERVABLE_SIGMA_M for s in sigma[:3]]
                          + [s <= UNOBSERVABLE_SIGMA_RAD for s in sigma[3:]])
    w, V = np.linalg.eigh(0.5 * (cov[:3, :3] + cov[:3, :3].T))
    order = np.argsort(w)[::-1]
    ellipsoid = 1000.0 * np.sqrt(CHI2_95_3DOF * np.maximum(w[order], 0.0))
    corr = correlation(cov)
    strong = [(LABELS[i], LABELS[j], float(corr[i, j])) for i in range(6) for j in range(i + 1, 6)
              if abs(corr[i, j]) > strong_correlation]
    axes = wrist_axes(result, dataset)
    geometry = None
    if axes is not None:
        used = [m.index for m in result.measurements if m.weight > 0 and m.index in axes]
        geometry = axis_geometry([axes[k] for k in used], used)
    words, suggestion = _observability(result, cov, geometry)
    ambiguous = bool(getattr(result, "ambiguous", False))
    if ambiguous:  # which of the poses is right is not known: no coordinate of the one shown is determined
        determined = np.zeros(6, dtype=bool)
        words.insert(0, "AMBIGUOUS: " + ambiguity_words(result))
        suggestion = suggestion or ("add arm poses whose wrist axes are tilted from the others and miss their "
                                    "common point")
    untrusted = list(getattr(result, "untrusted", None) or {})
    if untrusted and not ambiguous:  # a wrong minimum or a wrong model: no coordinate is to be relied on
        determined = np.zeros(6, dtype=bool)
        for sentence in reversed(untrusted_words(result)):
            words.insert(0, "NOT TRUSTED: " + sentence)
        suggestion = suggestion or _untrusted_suggestion(untrusted)
    if "swapped" in untrusted:  # the data as given are wrong: put them right before adding a pose
        suggestion = _untrusted_suggestion(untrusted)
    planned = None
    if next_pose and dataset is not None and (ambiguous or not result.observability.is_observable) \
            and "swapped" not in untrusted:
        planned = next_best_pose(result, dataset)
        if planned is not None:
            suggestion = (f"{suggestion}; the arm pose that helps most here (`gtsam-rotid plan --dataset` plans "
                          "more): " + ", ".join(f"{name} = {v:.4f}" for name, v in planned.items()) + " rad")
    pos_dir, pos_sigma = _strongest(cov[:3, :3])
    rot_axis, rot_sigma = _strongest(cov[3:, 3:])
    crossing = geometry is not None and geometry.is_crossing
    return CalibrationReport(
        method=result.method, converged=bool(result.converged), iterations=int(result.iterations),
        sigma_px=float(result.sigma_px), arm_T_camera=pose.matrix(),
        translation_mm=1000.0 * np.asarray(pose.translation(), dtype=float),
        rpy_deg=np.degrees(np.asarray(rotation.rpy(), dtype=float)), quaternion_xyzw=quaternion_xyzw(rotation),
        covariance=cov, covariance_usable=bool(result.covariance_usable),
        sigma_position_mm=1000.0 * sigma[:3], sigma_rpy_deg=np.degrees(np.sqrt(np.maximum(np.diag(cov_rpy), 0.0))),
        sigma_rotation_arm_deg=np.degrees(sigma[3:]),
        sigma_rotation_camera_deg=np.degrees(np.sqrt(np.maximum(np.diag(result.covariance)[:3], 0.0))),
        determined=determined, ellipsoid95_mm=ellipsoid, ellipsoid95_axes=V[:, order], correlation=corr,
        strong_correlations=strong, chi2=chi2_check(result), observability=words, suggestion=suggestion,
        condition_number=float(result.observability.condition_number),
        weakest_position=(pos_dir, 1000.0 * pos_sigma), weakest_rotation=(rot_axis, float(np.degrees(rot_sigma))),
        measurements=list(result.measurements),
        crossing_point_mm=1000.0 * geometry.point if crossing else None,
        crossing_miss_mm=1000.0 * float(np.max(geometry.miss)) if crossing else None, ambiguous=ambiguous,
        axis_consistency=getattr(result, "axis_consistency", None),
        joint_sigma_deg=float(getattr(result, "joint_sigma_deg", 0.0)), untrusted=untrusted,
        axis_floor_px=float(getattr(result, "axis_floor_px", 0.0)),
        track_offset_px=float(getattr(result, "track_offset_px", 0.0)), verdict=verdict(result), next_pose=planned,
        camera_still="; ".join(filter(None, [camera_motion_line(result), image_shift_words(result)]))
        if hasattr(result, "image_shift_excess") else "",
        joint_offsets_deg=None if getattr(result, "joint_offsets", None) is None
        else {k: float(np.degrees(v)) for k, v in result.joint_offsets.items()},
        joint_offsets_sigma_deg=dict(getattr(result, "joint_offsets_sigma_deg", {})),
        joint_offset_prior_deg=float(getattr(result, "joint_offset_sigma_deg", 0.0)),
        intrinsics=dict(getattr(result, "intrinsics", {})),
        intrinsics_sigma=dict(getattr(result, "intrinsics_sigma", {})),
        given_intrinsics=dict(getattr(result, "given_intrinsics", {})),
        intrinsics_prior=getattr(result, "intrinsics_prior_sigma", None),
        intrinsics_shapes=getattr(result, "intrinsics_shapes", None),
        synced=tuple(getattr(result, "synced", ())),
        time_offset_s=getattr(result, "time_offset_s", None),
        time_offset_sigma_s=getattr(result, "time_offset_sigma_s", None),
        time_offset_prior_sigma_s=getattr(result, "time_offset_prior_sigma_s", None),
        readings_refused=dict(getattr(result, "readings_refused", {})),
        time_offset_noise_share=getattr(result, "time_offset_noise_share", None),
        time_offsets=getattr(result, "time_offsets", None),
        readings_ignored=bool(getattr(result, "readings_ignored", False)),
    )



def _in_sigmas(error, sigma) -> str:
    return " ".join(f"{e / s:+7.2f}" if s > 0 else "    n/a" for e, s in zip(error, sigma, strict=True))


def error_vs_truth_lines(result, arm_T_camera_true) -> list[str]:
    """The estimate's error against a known ``arm_T_camera``, per axis and in units of the reported 1σ.

    Rotation and camera-frame translation are ``result.error_to`` (the Pose3 tangent, in which the covariance
    is expressed); the arm-frame position error is the difference of the camera centres, against
    ``result.sigma_mm_arm``.
    """
    error = result.error_to(arm_T_camera_true)
    rot_deg = np.degrees(error[:3])
    trans_mm = 1000.0 * error[3:]
    pos_mm = 1000.0 * (result.arm_T_camera.translation() - arm_T_camera_true.translation())
    usable = result.covariance_usable
    rows = [
        ("rotation, camera axes (deg)", rot_deg, "{:+10.4f}", result.sigma_deg),
        ("translation, camera frame (mm)", trans_mm, "{:+10.3f}", result.sigma_mm),
        ("position, arm frame (mm)", pos_mm, "{:+10.3f}", result.sigma_mm_arm),
    ]
    lines = ["error vs truth (estimate - truth, per axis" + (", and in reported 1-sigma units)" if usable else ")")]
    for label, values, fmt, sigma in rows:
        line = f"  {label:<31}" + "".join(fmt.format(v) for v in values)
        if usable:
            line += f"   = {_in_sigmas(values, sigma)} sigma"
        lines.append(line)
    total = f"  total: rotation {np.linalg.norm(rot_deg):.3g} deg, position {np.linalg.norm(pos_mm):.3g} mm"
    if usable:
        try:
            chi2 = float(error @ np.linalg.solve(result.covariance, error))
        except np.linalg.LinAlgError:
            chi2 = math.nan
        total += f", Mahalanobis chi2 {chi2:.3g} (6 dof: about 6 if the 1-sigma is right)"
    else:
        total += " (covariance unusable: no comparison with a 1-sigma)"
    lines.append(total)
    return lines

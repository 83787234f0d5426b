"""Estimators of ``arm_T_camera`` (docs/design.md §4): ``paper``, ``weighted`` and ``joint`` (default).

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

One module per stage: :mod:`.options` (what is asked), :mod:`.result` (what is returned), :mod:`.tuning`
(thresholds), :mod:`.lm` (the LM loop), :mod:`.setup` (the measurements, prepared once), :mod:`.initial` (the
start), :mod:`.stage1`, :mod:`.stage2`, :mod:`.joint` and :mod:`.run` (``calibrate``: orchestration only).
"""

from .initial import closest_point, initial_pose, twin_pose
from .options import MIN_MEASUREMENTS, CalibrationError, CalibrationOptions, Method, SpinModel
from .result import AMBIGUITY_CHI2, UNTRUSTED_KINDS, Alternative, AxisConsistency, CalibrationResult, MeasurementReport
from .run import calibrate
from .setup import arc_span_deg, circle_arc_span_deg, joint_tie_covariance, test_point_jacobian
from .stage1 import FitRejection

__all__ = [
    "AMBIGUITY_CHI2", "MIN_MEASUREMENTS", "UNTRUSTED_KINDS", "Alternative", "AxisConsistency", "CalibrationError",
    "CalibrationOptions", "CalibrationResult", "FitRejection", "MeasurementReport", "Method", "SpinModel",
    "arc_span_deg", "calibrate", "circle_arc_span_deg", "closest_point", "initial_pose", "joint_tie_covariance",
    "test_point_jacobian", "twin_pose",
]

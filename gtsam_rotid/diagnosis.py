"""The numbers the report's verdicts rest on: the χ² consistency of the fit (:func:`chi2_check`) and where the
wrist axes of the measurements lie (:func:`wrist_axes`, :func:`axis_geometry`: a single crossing, parallel axes).
:mod:`gtsam_rotid.report` turns them into its verdicts and :mod:`gtsam_rotid.plots` draws them.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from .errors import InputError
from .geometry import (  # noqa: F401 (the axes' geometry is re-exported: the calibration needs it too)
    CROSSING_TOLERANCE_M,
    PARALLEL_TOLERANCE_DEG,
    AxisGeometry,
    Line3,
    axis_geometry,
)
from .uncertainty import chi2_sf

#: The χ² test calls the fit consistent when the upper-tail probability lies in [P_LOW, 1 - P_LOW].
P_LOW = 0.005
#: Joint: the pixel noise is estimated from the same residuals, so the test is whether the solve ended where its
#: noise estimate did: χ²/dof within this of 1 (the noise is re-estimated until it changes by less than 5 %, and
#: the Huber kernels shrink χ² a little). A P value over ~1e5 residuals would flag a 1 % difference.
JOINT_REDUCED_TOLERANCE = 0.1


@dataclass
class Chi2Check:
    """χ² of the final fit against its degrees of freedom."""

    chi2: float
    dof: int
    #: upper-tail probability P(χ²_dof >= chi2)
    p_value: float
    #: None when the test does not apply (no redundancy, or the paper's unit-noise fit)
    consistent: bool | None
    what: str
    note: str = ""
    dof_exact: bool = True

    @property
    def reduced(self) -> float:
        return self.chi2 / self.dof if self.dof > 0 else math.nan

    def sentence(self) -> str:
        dof = f"{self.dof} dof" + ("" if self.dof_exact else " (approximate)")
        head = f"χ² = {self.chi2:.4g} for {dof}, χ²/dof = {self.reduced:.3g}, P(χ² ≥ this) = {self.p_value:.3g}"
        if self.consistent is None:
            verdict = "no consistency test"
        elif self.consistent:
            verdict = "consistent with the estimated noise"
        elif self.p_value < P_LOW:
            verdict = "INCONSISTENT: the residuals are larger than the noise model allows"
        else:
            verdict = "INCONSISTENT: the residuals are smaller than the noise model expects"
        return f"{head}: {verdict}"

    def to_dict(self) -> dict:
        return {"chi2": self.chi2, "dof": self.dof, "dof_exact": self.dof_exact, "reduced": self.reduced,
                "p_value": self.p_value, "consistent": self.consistent, "what": self.what, "note": self.note}


def chi2_check(result) -> Chi2Check:
    """The χ² consistency of the fit from ``result.final_error`` (= χ²/2 of the final graph).

    The degrees of freedom are ``result.dof`` when the result carries it (the joint graph's residuals less its
    variables and the parameters its factors project out: each track's circle, with the rigid spin also its phase
    offset and each frame's spin angle); otherwise they are counted from the measurement reports (weighted/paper:
    2 axis distances per measurement used, minus 6; joint: one residual per point and 2 tie residuals per
    measurement, minus 6 pose, 3 line and 2 circle parameters per track).
    """
    used = [m for m in result.measurements if m.weight > 0]
    chi2 = 2.0 * float(result.final_error)
    dof = result.dof
    exact = dof is not None
    method = result.method
    if method == "joint":
        if dof is None:
            dof = sum(m.n_points for m in used) - 2 * sum(m.n_tracks for m in used) - len(used) - 6
        what = "pixel residuals of every track against its circle about the wrist axis (joint graph)"
        note = ("the pixel noise of each measurement was estimated from these residuals, so χ²/dof ≈ 1 by "
                "construction: this checks the solve, not the noise model")
    else:
        if dof is None:
            dof = 2 * len(used) - 6
        what = ("each measurement's image axis against the wrist axis projected by the estimate (2 distances per "
                "measurement)")
        note = ("weighted by each image axis' covariance at its measurement's pixel noise; whole measurements "
                "under a Huber kernel, so χ² is the robust cost") if method == "weighted" else ""
    p = chi2_sf(chi2, dof) if dof > 0 else math.nan
    if method == "paper":
        consistent = None
        note = ("the paper's fit assumes 1 px line errors (unit noise): χ²/dof is the mean squared axis distance "
                "in px², not a consistency test, and its (JᵀJ)⁻¹ covariance is not calibrated")
    elif dof <= 0:
        consistent = None
        note = "no redundancy: as many equations as unknowns"
    elif method == "joint":
        consistent = bool(abs(chi2 / dof - 1.0) <= JOINT_REDUCED_TOLERANCE)
    else:
        consistent = bool(P_LOW <= p <= 1.0 - P_LOW)
    return Chi2Check(chi2, int(dof), float(p), consistent, what, note, exact)


def wrist_axes(result, dataset=None) -> dict[int, Line3] | None:
    """The FK wrist axis (arm frame) of each measurement, from the dataset or from the result when it carries
    them (``MeasurementReport.axis_point`` / ``axis_direction``); None when neither has them."""
    if dataset is not None:
        if len(dataset) != len(result.measurements):
            raise InputError(f"the dataset has {len(dataset)} measurements but the result {len(result.measurements)}: "
                             "it is not the dataset this result was calibrated from")
        return {k: dataset.arm.wrist_axis(dataset.joint_angles(k), dataset[k].spin_joint) for k in range(len(dataset))}
    axes = {}
    for m in result.measurements:
        point, direction = m.axis_point, m.axis_direction
        if point is None or direction is None:
            return None
        axes[m.index] = Line3(point, direction)
    return axes

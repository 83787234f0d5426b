"""What each measurement's stage-1 fit says of its evidence (weak: few tracks or short arcs), the measurements' reports
and the words of a refusal that name them.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from ..camera import Camera
from ..graph import axis_test_points
from .options import CalibrationError, CalibrationOptions
from .result import MeasurementReport, OutlierKind
from .setup import _Setup, circle_arc_span_deg, test_point_distances, test_point_jacobian
from .stage1 import _Stage1
from .tuning import TRACKING_BIAS_PX, WEAK_ARC_DEG, WEAK_MANY_TRACKS, WEAK_TRACKS


class Evidence(NamedTuple):
    """The measurements of thin evidence in one set of stage-1 fits (:func:`classify`), and the weak ones a fit left
    out (``dropped``) because enough strong ones determine the pose without them."""

    #: k -> the evidence in words of measurements whose stage-1 fit is weak (for the words of a refusal)
    weak: dict[int, str]
    #: k -> the longest arc (deg, ``setup.turning``) of measurements with enough tracks but none of WEAK_ARC_DEG: a
    #: tracker's drift along short arcs can put their image axes off (for the words that name a likely cause)
    short: dict[int, float]
    dropped: frozenset[int] = frozenset()


def _evidence(setup: _Setup, s: _Stage1, k: int, tied=None) -> tuple[float | None, bool]:
    """(longest arc in deg, weak) of measurement k's kept tracks. Each arc is measured about its stage-1 circle and,
    when ``tied = (line, circles)`` is given (the circles fitted with the line on the estimate's FK axis), about that
    circle too, and the smaller is taken: a short arc fitted with a circle far too small wraps around it."""
    spans = []
    for j in s.keys.tracks:
        ideal = setup.prepared[k].usable[j].ideal
        span = circle_arc_span_deg(ideal, setup.K, s.rotation, s.circles[j]) if j in s.circles else np.inf
        if tied is not None and j in tied[1]:
            span = min(span, circle_arc_span_deg(ideal, setup.K, tied[0], tied[1][j]))
        if np.isfinite(span):
            spans.append(span)
    longest = max(spans) if spans else None
    n = len(s.keys.tracks)
    return longest, n < WEAK_TRACKS or (n < WEAK_MANY_TRACKS and (longest is None or longest < WEAK_ARC_DEG))


def classify(setup: _Setup, stage1: list[_Stage1]) -> Evidence:
    """The measurements whose stage-1 evidence is weak (k -> its evidence in words) and those with enough tracks but
    only short arcs (k -> the longest arc, deg): what the words of a refusal or a left-out measurement name."""
    weak, short = {}, {}
    for k, s in enumerate(stage1):
        span, is_weak = _evidence(setup, s, k)
        if not is_weak and setup.turning[k] < WEAK_ARC_DEG:
            short[k] = setup.turning[k]
        if is_weak:
            arc = "" if span is None else f", longest arc {span:.0f}° (at most)"
            weak[k] = f"{len(s.keys.tracks)} tracks{arc}"
    return Evidence(weak, short)


def _named(setup: _Setup, ks) -> list[int]:
    """Internal measurement positions -> the caller's measurement indices."""
    return [setup.index[k] for k in ks] if setup.index else list(ks)


def poor_minimum(chi2: np.ndarray, limit: float, what: str, setup: _Setup | None = None,
                 evidence: Evidence | None = None, bad=()) -> CalibrationError:
    names = _named(setup, range(len(chi2))) if setup is not None else list(range(len(chi2)))
    listing = ", ".join(f"{name}: {value:.3g}" if np.isfinite(value) else f"{name}: not measured"
                        for name, value in zip(names, chi2, strict=True))
    return CalibrationError(
        f"the estimate ended in a poor minimum or the data are inconsistent: {what} (chi-square of each "
        f"measurement's image axis against the projected FK axis, 2 dof, limit {limit:g}: {listing}); check "
        "the joint angles, the intrinsics and the spinning joint (if the kinematics are known to be inaccurate, "
        "raise CalibrationOptions.outlier_measurement_chi2)" + weak_words(setup, evidence, bad))


def weak_words(setup: _Setup | None, evidence: Evidence | None, bad=()) -> str:
    """For a refusal: the measurements whose evidence is thin (``evidence.weak``), which come first, and those of
    ``bad`` whose arcs are all short (``evidence.short``)."""
    if setup is None or evidence is None:
        return ""
    out = ""
    if evidence.weak:
        named = "; ".join(f"measurement {_named(setup, [k])[0]}: {why}" for k, why in evidence.weak.items())
        out += (f". But first: these measurements have too little evidence for a reliable image axis ({named}); spin "
                "the wrist longer (a full turn or more) or give the hand more texture: the tracking, more likely than "
                "the joint angles, is at fault")
    short = [k for k in bad if k in evidence.short]
    if short:
        out += ". " + short_words(setup, evidence, short)
    return out


def short_words(setup: _Setup, evidence: Evidence, ks) -> str:
    """Words for measurements of many tracks whose arcs are all short: tracking is as likely a cause as joints."""
    return short_arc_words({_named(setup, [k])[0]: evidence.short[k] for k in ks})


def short_arc_words(longest_deg: dict[int, float]) -> str:
    """The short-arc sentence for measurements (caller's index -> longest arc, deg), shared with the report's
    words (:func:`gtsam_rotid.words.outlier_words`)."""
    arcs = ", ".join(f"{k}: {deg:.0f}°" for k, deg in longest_deg.items())
    return (f"The arcs of measurement(s) {arcs} (longest) are short: a tracker's drift along short arcs can put an "
            "image axis off as far as a wrong joint angle does, so suspect the tracking as much as the joints (spin "
            "longer, a full turn or more, or track features that can be followed further)")


def axis_misses(arm, measurements, setup: _Setup, stage1: list[_Stage1], camera: Camera, pose,
                ks) -> dict[int, tuple[float, float]]:
    """k -> (miss_px, joint_deg) of measurements ``ks``: how far (px, the larger of its two FK test points' distances)
    its stage-1 image axis passes from its FK axis projected by ``pose`` through ``camera`` (undistorted), and the
    smallest joint error (deg, root sum of squares over the joints, to first order) that would move the projected
    axis onto its image axis: what a left-out measurement's words compare with a tracker's bias. A measurement whose
    test points lie at or behind the camera at ``pose`` gets none."""
    out = {}
    for k in ks:
        if not all(pose.transformTo(x)[2] > 0.0 for x in axis_test_points(setup.axes[k])):
            continue  # its FK axis does not project at this pose (a runaway fit): no distance to give
        line = np.asarray(stage1[k].image_axis, dtype=float)
        m = measurements[k]
        J = test_point_jacobian(arm, m.joint_angles, joint=m.spin_joint)  # (6, n): test points by joint angle
        d, D = test_point_distances(camera, setup.axes[k], line / np.hypot(line[0], line[1]), pose, J, 1e-6)
        dq = -np.linalg.pinv(D) @ d  # the least joint change (rad) that puts the projected axis on the image axis
        out[k] = (float(np.max(np.abs(d))), float(np.degrees(np.linalg.norm(dq))))
    return out


def measurement_reports(stage1: list[_Stage1], setup: _Setup, evidence: Evidence, sigmas: dict[int, float],
                        used: list[int], options, chi2: dict[int, float] | None = None,
                        tied: dict | None = None,
                        misses: dict[int, tuple[float, float]] | None = None) -> list[MeasurementReport]:
    """One report per measurement of a fit that used ``used`` (the others are left out, with why; ``misses``:
    :func:`axis_misses` of the left-out ones)."""
    median = float(np.median([sigmas[k] for k in used]))
    reports = []
    for k, s in enumerate(stage1):
        rejected = {**s.keys.rejected, **s.outliers}
        excluded = k not in used
        sigma = sigmas.get(k, np.sqrt(s.sigma2))
        span, weak = _evidence(setup, s, k, None if tied is None else tied.get(k))
        weak = weak or k in evidence.dropped
        kind, values = "", {}
        if excluded and k in evidence.dropped:
            kind, values = OutlierKind.THIN.value, {"used": len(used)}
        elif excluded:
            kind, values = OutlierKind.DISAGREES.value, {"limit": float(options.outlier_measurement_chi2)}
            if not weak and k in evidence.short:
                values["short_arc_deg"] = float(evidence.short[k])
            if misses is not None and k in misses:
                values["miss_px"], values["joint_deg"] = misses[k]
                values["tracking_bias_px"] = TRACKING_BIAS_PX
        axis = setup.axes[k]
        reports.append(MeasurementReport(
            k, len(s.keys.tracks), s.n_points, float(sigma),
            0.0 if excluded else median**2 / sigma**2, excluded, rejected, kind, values,
            axis_point=[float(v) for v in axis.point], axis_direction=[float(v) for v in axis.direction],
            image_axis=[float(v) for v in s.image_axis / np.hypot(s.image_axis[0], s.image_axis[1])],
            axis_chi2=None if chi2 is None else float(chi2[k]), arc_span_deg=span, weak=weak,
            spin_joint=setup.spin_joint(k)))
    _flag_outlier_measurements(reports, options)
    return reports


def _flag_outlier_measurements(reports: list[MeasurementReport], options: CalibrationOptions) -> None:
    median = np.median([r.residual_rms_px for r in reports])
    for r in reports:
        if not r.outlier and r.residual_rms_px > options.outlier_measurement_ratio * median:
            r.outlier = True
            r.outlier_kind = OutlierKind.RESIDUAL.value
            r.outlier_values = {"ratio": float(options.outlier_measurement_ratio), "median": float(median)}

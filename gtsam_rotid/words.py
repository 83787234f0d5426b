"""A calibration result in words (the report layer): the summary, why a covariance is not trusted, what an
ambiguity means, which directions the data do not determine, what the covariance assumes of the kinematics.
:class:`~gtsam_rotid.estimate.CalibrationResult` (and its :class:`~gtsam_rotid.uncertainty.Observability`) holds
the numbers; everything that turns them into sentences is here.
"""

from __future__ import annotations

import numpy as np

from .calibration.check import CheckResult
from .calibration.evidence import short_arc_words
from .calibration.modelcheck import FREED_P
from .calibration.offsets import HELD_BY_PRIOR
from .calibration.options import MIN_MEASUREMENTS
from .calibration.result import (
    AMBIGUITY_CHI2,
    IMAGE_SHIFT_PX,
    AxisConsistency,
    CalibrationResult,
    MeasurementReport,
    OutlierKind,
)
from .calibration.swaps import swap_sentence
from .calibration.tuning import (
    LONG_ARC_CONSISTENCY_P,
    MAX_CONSISTENCY_SCALE,
    MAX_RELATIVE_SIGMA,
    MAX_SCALE_AFTER_OUTLIERS,
    MAX_SIGMA_DEG,
    RESTART_P,
)
from .planning import Plan, Prediction
from .stillness import MIN_MOVE_PX, SIGNIFICANT_Z, CameraMotion
from .trackparams import TRACK_OFFSET_PX
from .uncertainty import Observability


def verdict(result: CalibrationResult) -> str:
    """One line: whether the calibration can be used and how well, or why not and what to do next."""
    if result.swapped is not None:  # (the likelier cause of anything else wrong with it)
        return "NOT USABLE: " + swap_sentence(result.swapped)
    if result.covariance_usable and result.converged:
        return (f"USABLE: 1σ at most {float(np.max(result.sigma_mm_arm)):.2f} mm and "
                f"{float(np.max(result.sigma_deg)):.3f}° on every axis")
    if not result.converged:
        return "NOT USABLE: the solver did not converge; add arm poses or check the data"
    if not result.observability.is_observable:
        return ("NOT USABLE: these arm poses do not determine the calibration; add a pose whose wrist axis is tilted "
                "from the others and misses their common point")
    if result.ambiguous:
        suspects = _suspects(_close(result))
        if suspects:
            return (f"NOT USABLE: another camera pose fits the pixels nearly as well if another measurement is left "
                    f"out: one of {suspects} is wrong; check their joint angles and tracks")
        return ("NOT USABLE: another camera pose fits the pixels nearly as well; add a pose whose wrist axis is "
                "tilted from the others")
    return "NOT USABLE: " + untrusted_words(result)[0]


def summary(result: CalibrationResult) -> str:
    """The result in a few lines: the pose, its 1σ or why the covariance is unusable, the observability, each
    measurement."""
    t = result.arm_T_camera.translation() * 1000.0
    rpy = np.degrees(result.arm_T_camera.rotation().rpy())
    lines = [
        verdict(result),
        f"arm_T_camera ({result.method}, {'converged' if result.converged else 'NOT converged'}, "
        f"{result.iterations} iterations, pixel sigma {result.sigma_px:.3f} px)",
        f"  translation (mm):  {t[0]:9.2f} {t[1]:9.2f} {t[2]:9.2f}",
        f"  roll/pitch/yaw (deg): {rpy[0]:8.3f} {rpy[1]:8.3f} {rpy[2]:8.3f}",
    ]
    if result.ambiguous:
        lines.append("  AMBIGUOUS: " + ambiguity_words(result))
    if result.covariance_usable:
        s, r = result.sigma_mm_arm, result.sigma_deg
        lines.append(f"  1-sigma position, arm frame (mm): {s[0]:.3f} {s[1]:.3f} {s[2]:.3f}")
        lines.append(f"  1-sigma rotation (deg):           {r[0]:.4f} {r[1]:.4f} {r[2]:.4f}")
    elif result.ambiguous:
        lines.append("  COVARIANCE UNUSABLE: it describes one of several poses that fit the data")
    elif result.untrusted:
        lines.extend("  COVARIANCE UNUSABLE: " + w for w in untrusted_words(result))
    else:
        lines.append("  COVARIANCE UNUSABLE: the arm poses do not determine the calibration")
    lines.extend("  " + line for line in observability_words(result.observability))
    if result.axis_consistency is not None and (not result.axis_consistency.consistent
                                                 or result.axis_consistency.scale != 1.0):
        lines.append("  " + axis_consistency_sentence(result.axis_consistency))
    lines.append("  " + kinematics_words(result.joint_sigma_deg, result.joint_offsets is not None))
    lines.extend("  " + line for line in joint_offsets_words(
        None if result.joint_offsets is None else {k: float(np.degrees(v)) for k, v in result.joint_offsets.items()},
        result.joint_offsets_sigma_deg, result.joint_offset_sigma_deg,
        all(m.spin_joint is None for m in result.measurements)))
    lines.extend("  " + line for line in refined_intrinsics_words(
        result.intrinsics, result.intrinsics_sigma, result.given_intrinsics, result.intrinsics_prior_sigma))
    assumed = intrinsics_assumed_words(result.intrinsics_shapes)
    if assumed is not None:
        lines.append("  " + assumed)
    lines.extend("  " + line for line in synced_words(result.synced, result.time_offset_s, result.time_offset_sigma_s,
                                                      len(result.measurements), result.time_offset_prior_sigma_s,
                                                      result.readings_refused, result.time_offset_noise_share,
                                                      result.time_offsets))
    lines.extend("  " + line for line in readings_ignored_words(result.readings_ignored, result.method))
    lines.append("  " + tracking_words(result.axis_floor_px, result.track_offset_px))
    lines.extend("  " + line for line in filter(None, [camera_motion_line(result), image_shift_words(result)]))
    for m in result.measurements:
        why = outlier_words(m, intrinsics_suspected(result.untrusted), kinematics_suspected(result.untrusted))
        flag = f"  OUTLIER ({why})" if m.outlier else ""
        n_rejected = len(m.rejected_tracks)
        lines.append(f"  measurement {m.index}: {m.n_tracks} tracks, {m.n_points} points, residual RMS "
                     f"{m.residual_rms_px:.3f} px, weight {m.weight:.2f}, {n_rejected} "
                     f"track{'' if n_rejected == 1 else 's'} rejected{flag}")
    return "\n".join(lines)


def observability_words(obs: Observability) -> list[str]:
    """The observability verdict in sentences: each direction the data do not determine (in the arm frame), or
    that all six are determined, with the condition number. A direction's 1σ is along its unit vector of the
    Pose3 tangent (rad, m): in mm for a translation, degrees for a rotation, both units named where it mixes
    them."""
    words = []
    for v, sigma in zip(obs.unobservable_directions, obs.unobservable_sigmas, strict=True):
        t_arm = obs.arm_R_camera @ v[3:]
        r_arm = obs.arm_R_camera @ v[:3]
        rotation, translation = np.linalg.norm(v[:3]), np.linalg.norm(v[3:])
        if not np.isfinite(sigma):
            what = "not determined at all"
        elif rotation < 0.1:  # a translation (the sentence below calls it one)
            what = f"poorly determined (1-sigma {1000 * sigma * translation:.3g} mm)"
        elif translation < 0.1:  # a rotation
            what = f"poorly determined (1-sigma {np.degrees(sigma * rotation):.3g}°)"
        else:
            what = (f"poorly determined (1-sigma {np.degrees(sigma * rotation):.3g}° of that turn with its "
                    f"{1000 * sigma * translation:.3g} mm)")
        if rotation < 0.1:
            direction = np.round(t_arm / np.linalg.norm(t_arm), 3)
            words.append(f"the camera position along the arm-frame direction {direction} is {what}")
        elif translation < 0.1:
            axis = np.round(r_arm / np.linalg.norm(r_arm), 3)
            words.append(f"the camera rotation about the arm-frame axis {axis} is {what}")
        else:  # a screw: the turn and the shift that go with it, one sign
            per_degree = 1000.0 * translation / np.degrees(rotation)
            words.append(f"turning the camera about the arm-frame axis {np.round(r_arm / rotation, 3)} while "
                         f"moving it {per_degree:.3g} mm per degree along the arm-frame direction "
                         f"{np.round(t_arm / translation, 3)} is {what}")
    if obs.is_observable:
        return [f"all six degrees of freedom of arm_T_camera are determined (condition number "
                f"{obs.condition_number:.3g})"]
    return ["DEGENERATE: the chosen arm poses do not determine the calibration; add a pose whose wrist axis is not "
            "like the others (e.g. one that misses their common point)"] + words


#: The lowest level ``calibrate`` tests the axes at (``tuning.LONG_ARC_CONSISTENCY_P``): an unscaled result with a
#: smaller P had its test switched off (``CalibrationOptions.axis_consistency_p``).
UNSCALED_BELOW_P = LONG_ARC_CONSISTENCY_P


def axis_consistency_sentence(c: AxisConsistency) -> str:
    """The test of the axes against one pose, and the scale it applied, in one sentence."""
    head = (f"image axes vs the projected FK axes: χ² = {c.chi2:.3g} for {c.dof} dof, "
            f"P(χ² ≥ this) = {c.p_value:.2g}")
    if not np.isfinite(c.chi2):
        return ("image axes vs the projected FK axes: the FK axes do not project at the estimate (their test points "
                "lie at or behind the camera): the estimate has run away from the data, and it has no covariance")
    if c.scale == 1.0 and c.p_value < UNSCALED_BELOW_P:  # only a test switched off leaves such a P unscaled
        return (f"{head}: the axes disagree beyond their pixel noise, but the covariance was not scaled (the test's "
                "level, CalibrationOptions.axis_consistency_p, is below this P)")
    i = c.intrinsics or {}
    # the used axes may agree while the left-out one carries the camera's error
    tail = ("" if not (i.get("likely") and i.get("chi2") is not None) else
            f"; all the measurements' axes, the left-out ones too: χ² = {i['exact_chi2']:.3g} for {i['exact_dof']} "
            f"dof through this camera, {i['chi2']:.3g} for {i['dof']} dof with its focal length and principal point "
            "free (see the verdict)")
    if c.scale == 1.0:
        return f"{head}: consistent with the pixel noise" + tail
    floor = ("" if c.floor_px <= 0.0 else
             f", or, in the directions where that is larger, each axis is given a floor of {c.floor_px:.2g} px "
             "(a bias the tracks of one pose share does not shrink with more tracks)")
    if c.consistent:
        return (f"{head}: consistent with the pixel noise, but above its median: the covariance is scaled by "
                f"{c.scale:.3g} (a share of χ²/(dof − 2), the scale's mean given the scatter, rising to all of it at "
                "the test's level)" + floor + tail)
    return (f"{head}: the axes disagree beyond their pixel noise (errors shared across tracks: a tracker "
            f"bias, joint angles, kinematics or intrinsics); the covariance is scaled by {c.scale:.3g} "
            + ("(χ²/(dof − 2): the scale's mean given the scatter)" if c.dof > 2 else "(χ²/dof)") + floor + tail)


def evidence_words(m: MeasurementReport) -> str:
    """A measurement's evidence in words: tracks, points, the longest arc."""
    arc = "" if m.arc_span_deg is None else f", longest arc {m.arc_span_deg:.0f}°"
    return f"{m.n_tracks} track{'' if m.n_tracks == 1 else 's'}, {m.n_points} points{arc}"


def intrinsics_suspected(untrusted) -> bool:
    """The result suspects the camera's intrinsics (``untrusted["intrinsics"]`` or ``["intrinsics_shapes"]``)."""
    return "intrinsics" in untrusted or "intrinsics_shapes" in untrusted


def kinematics_suspected(untrusted) -> bool:
    """The result suspects joint offsets (``untrusted["kinematics"]``, or ``["kinematics_or_measurement"]``)."""
    return "kinematics" in untrusted or "kinematics_or_measurement" in untrusted


def outlier_words(m: MeasurementReport, camera_suspect: bool = False, kinematics_suspect: bool = False) -> str:
    """Why a measurement is an outlier (its ``outlier_kind`` and ``outlier_values``) and what to do; "" when it is
    not one. ``camera_suspect``: the result suspects the intrinsics (``untrusted["intrinsics"]``), which are then to
    be checked before a disagreeing measurement's joint angles; ``kinematics_suspect``: it suspects joint offsets
    (``untrusted["kinematics"]``), likewise."""
    v = m.outlier_values
    if not m.outlier:
        return ""
    if m.outlier_kind == OutlierKind.FEW_TRACKS:
        return (f"left out: only {m.n_tracks} usable track(s), need at least 2 for an image axis; spin longer or give "
                "the hand more texture")
    if m.outlier_kind == OutlierKind.THIN:
        return (f"left out: too little evidence for a reliable image axis ({evidence_words(m)}); the {v['used']:g} "
                "stronger measurements determine the pose without it")
    if m.outlier_kind == OutlierKind.DISAGREES:
        chi2 = "" if m.axis_chi2 is None else f"chi-square {m.axis_chi2:.3g} > {v['limit']:g}, 2 dof"
        words = f"left out: its image axis disagrees with the FK axis projected by the estimate ({chi2}); "
        if m.weak:
            return words + ("its own evidence is thin (few tracks or short arcs): spin longer or add texture, and "
                            "check its joint angles only if that does not help")
        if "short_arc_deg" in v:
            return words + "its tracks or its joint angles are off. " + short_arc_words({m.index: v["short_arc_deg"]})
        if camera_suspect:
            return words + ("check the camera's intrinsics first (a wrong camera moves every axis), then its joint "
                            "angles")
        if kinematics_suspect:
            return words + ("check the joints' zero offsets first (an offset common to every pose moves every axis), "
                            "then its joint angles")
        if "miss_px" not in v:  # (a result of another version)
            return words + "check its joint angles"
        miss = (f"it passes {v['miss_px']:.2g} px from that axis, where a joint error of {v['joint_deg']:.2g}° "
                "would put it")
        if v["miss_px"] <= v["tracking_bias_px"]:
            return words + (f"{miss}, but a shift its tracks share of that size (a blob's centroid pulled by shading "
                            "or blur, corners drifting together) would put it there too: check its tracking first "
                            "(the overlay: do its tracks follow the surface?), then its joint angles")
        return words + (f"{miss}, farther than a tracker's shared bias (up to {v['tracking_bias_px']:g} px) moves "
                        "an axis: check its joint angles")
    if m.outlier_kind == OutlierKind.RESIDUAL:
        return f"residual RMS {m.residual_rms_px:.2f} px > {v['ratio']:g}x the median {v['median']:.2f} px"
    return str(v.get("text", "")) or "flagged"


def untrusted_words(result: CalibrationResult) -> list[str]:
    """Plain words for each reason in ``result.untrusted``: what is wrong, which measurements, what to do."""
    out = []
    by_index = {m.index: m for m in result.measurements}
    for kind, ks in result.untrusted.items():
        named = "; ".join(f"measurement {k} ({evidence_words(by_index[k])})" for k in ks if k in by_index)
        if kind == "swapped":
            out.append(swap_sentence(result.swapped) if result.swapped is not None else
                       f"measurements {' and '.join(str(k) for k in ks)} look swapped (videos or joint rows in the "
                       "wrong order)")
        elif kind == "thin_evidence":
            c = result.axis_consistency
            strong = sum(not m.weak and m.used for m in result.measurements)
            if c is not None and c.p_value < RESTART_P:
                head = (f"the image axes disagree with the estimate beyond their pixel noise (χ² = {c.chi2:.3g} for "
                        f"{c.dof} dof, P = {c.p_value:.2g}) and")
            elif c is None:
                head = "nothing tests the image axes against each other (too few measurements), and"
            else:
                head = (f"the estimate rests on weak measurements (only {strong} of the measurements used have strong "
                        f"evidence; {MIN_MEASUREMENTS} are needed to determine the pose without the weak ones):")
            # a result that names none of its measurements (another version's file) gets no empty list
            which = (f"these measurements have too little evidence for their axes to be Gaussian: {named}" if named
                     else "some of the measurements used have too little evidence for their axes to be Gaussian (the "
                     "result does not name them)")
            out.append(f"{head} {which}. Few or "
                       "short arcs admit wrong circle fits, so the estimate may be a wrong minimum and no scaling of "
                       "the covariance can be trusted. Spin the wrist longer (a full turn or more), give the hand more "
                       "texture (more tracks), or add arm poses; the tracking, not the joint angles, is the weak part")
        elif kind == "inconsistent" and not np.isfinite(result.axis_consistency.chi2):
            out.append("the FK axes do not even project at the estimate (their test points lie at or behind the "
                       "camera): the fit ran away from the data, a poor minimum; check the joint angles, the "
                       "intrinsics and the spinning joint, and give the hand more texture or the wrist longer spins")
        elif kind == "inconsistent":
            c = result.axis_consistency
            out.append(f"the measurements' axes disagree with one pose by χ²/dof = {c.chi2 / c.dof:.3g}, more than "
                       f"{MAX_CONSISTENCY_SCALE:g}x their pixel noise: the model does not describe the data (wrong "
                       "intrinsics, joint angles or kinematics, a moved camera, or tracks that are not on the hand)")
        elif kind == "intrinsics":
            out.append(intrinsics_words(result))
        elif kind == "intrinsics_shapes":
            out.append(intrinsics_shapes_words(result.intrinsics_shapes, result.axis_floor_px, result.track_offset_px))
        elif kind == "kinematics":
            out.append(joint_offset_words(result))
        elif kind == "camera_or_measurement":
            out.append(camera_or_measurement_words(result, ks))
        elif kind == "kinematics_or_measurement":
            out.append(kinematics_or_measurement_words(result, ks))
        elif kind == "unmeasured_scatter":
            c = result.axis_consistency
            out.append(f"the measurements' axes disagree with one pose beyond their pixel noise (χ² = {c.chi2:.3g} "
                       f"for {c.dof} dof, P = {c.p_value:.2g}), and only {c.dof // 2 + 3} measurements are used: "
                       "too few to measure by how much the noise is understated, so no covariance can be given; add "
                       "arm poses (six or more used), or spin longer where measurements were left out")
        elif kind == "inconsistent_after_outliers":
            c = result.axis_consistency
            which = ", ".join(str(k) for k in ks)
            out.append(f"measurement{'s' if len(ks) > 1 else ''} {which} {'were' if len(ks) > 1 else 'was'} left out "
                       f"as disagreeing, and the others' axes still disagree with one pose (χ² = {c.chi2:.3g} for "
                       f"{c.dof} dof, P = {c.p_value:.2g}: their noise variance scaled by {c.scale:.3g}, more than "
                       f"{MAX_SCALE_AFTER_OUTLIERS:g}): one wrong measurement does not explain the axes, and a scaled "
                       "covariance would not hold the error. More than one measurement is wrong, or the model is off "
                       "in more than one way (the camera's intrinsics and the joints' zero positions together): "
                       "calibrate again with them refined (--refine-intrinsics --joint-offsets), check the joint "
                       "readings, and add arm poses")
        elif kind == "too_uncertain" and not np.all(np.isfinite(result.covariance)):
            out.append("the covariance is not finite: the data do not determine the calibration; add arm poses, "
                       "longer spins or more texture")
        elif kind == "too_uncertain":
            out.append(f"the 1σ ({np.max(result.sigma_mm_arm):.3g} mm, {np.max(result.sigma_deg):.3g}°) exceeds "
                       f"{100 * MAX_RELATIVE_SIGMA:g} % of the camera's distance to the wrist or {MAX_SIGMA_DEG:g}°: "
                       "the data do not determine the calibration in practice, and an error that large changes the "
                       "geometry the covariance was computed in; add arm poses, longer spins or more texture")
        else:  # a reason this version does not know (a newer or edited result file): still said
            out.append(f"not trusted for a reason this version cannot describe ({kind!r}"
                       + (f"; measurements: {named}" if named else "") + ")")
    return out


def intrinsics_words(result: CalibrationResult) -> str:
    """Why the camera's intrinsics are a likely cause of the axes' disagreement (the numbers of
    ``result.axis_consistency.intrinsics``), and what to check."""
    c = result.axis_consistency
    i = None if c is None else c.intrinsics
    then = _then_left_out(result)
    if not i or i.get("chi2") is None:  # a result file that names the reason without its numbers
        return ("the image axes disagree with any one pose seen through this camera and agree once its focal length "
                "and principal point may change: the camera's intrinsics are the likelier cause, and the estimate is "
                "not trusted. Check the intrinsics first (is the camera file this camera's, at this resolution? "
                "recalibrate them)" + then)
    # (a camera that explains the axes where the camera as given failed only the axes' own test, which scaled the
    # covariance, not the model check's: systematic, not ``likely``, yet all the way)
    agree = i.get("likely", True) or i.get("one_out_chi2") is None or i["p_value"] >= FREED_P
    closer = ("" if agree else
              "; a first-order check that keeps the image axes as measured through the camera file, so a wrong "
              "camera is not fitted all the way, but far better than by leaving out any one measurement, whose best "
              f"χ² is {i['one_out_chi2']:.3g}")
    rival = ""
    if _camera_over_offsets(result):
        rival = (f" Offsets of the joints' zero positions explain the axes less well (P = "
                 f"{c.kinematics['p_value']:.2g}); the camera is the likelier cause.")
    return (f"the image axes of all {len(i['measurements'])} measurements (the left-out ones too) disagree with any "
            f"one pose seen through this camera (χ² = {i['exact_chi2']:.3g} for {i['exact_dof']} dof, P = "
            f"{i['exact_p']:.2g}) but {'agree' if agree else 'come far closer'} with a camera whose "
            f"{_camera_change(i)} (χ² = {i['chi2']:.3g} for {i['dof']} dof, P = {i['p_value']:.2g}{closer}; a "
            "first-order reading: the principal point and the focal length trade off). Wrong intrinsics move every "
            "axis together and leave an estimate wrong by far more than its covariance says, so it is not trusted."
            + rival + " Check the intrinsics first (is the camera file this camera's, at this resolution? recalibrate "
            "them), or refine them with the pose (calibrate --refine-intrinsics; it costs precision at these poses: "
            "plan --refine-intrinsics)" + then)


def _camera_over_offsets(result: CalibrationResult) -> bool:
    """Whether both a camera error and joint offsets are flagged (``untrusted["intrinsics"]`` and ``["kinematics"]``)
    and the camera's change explains the axes better (the higher P of the two fits)."""
    c = result.axis_consistency
    i, k = (c.intrinsics or {}, c.kinematics or {}) if c is not None else ({}, {})
    return ("intrinsics" in result.untrusted and "kinematics" in result.untrusted
            and i.get("p_value") is not None and k.get("p_value") is not None and i["p_value"] > k["p_value"])


def _camera_change(i: dict) -> str:
    """The intrinsics' change that a model check reads (``focal_percent``, ``cx_px``, ``cy_px``: new minus the
    camera file's), in words that say which way."""
    focal, cx, cy = i["focal_percent"], i["cx_px"], i["cy_px"]
    across = f"{abs(cx):.3g} px {'left' if cx < 0 else 'right'}"
    down = f"{abs(cy):.3g} px {'up' if cy < 0 else 'down'}"
    return (f"focal length is about {abs(focal):.2g} % {'shorter' if focal < 0 else 'longer'} than the camera "
            f"file's and whose principal point is about {across} and {down} of the file's (cx {cx:+.3g}, cy "
            f"{cy:+.3g} px)")


def intrinsics_shapes_words(shapes: dict | None, floor_px: float | None = None, offset_px: float = 0.0) -> str:
    """Why a result whose tracks' shapes ask for other intrinsics is not trusted (``result.intrinsics_shapes``).
    Two causes read alike: a camera file that is off, and a bias of the tracked pixels that a pose's tracks share
    (features on highlights or silhouette edges that do not move with the surface). ``floor_px`` and ``offset_px``
    (the result's ``axis_floor_px``, ``track_offset_px``): both 0, the calibration took the tracks as unbiased, and
    the words say how to allow for the tracker's bias."""
    advice = ("Calibrate again with the intrinsics refined (calibrate --refine-intrinsics; CalibrationOptions("
              "refine_intrinsics=True)), or check the camera file (is it this camera's, at this resolution?)")
    if floor_px is not None and floor_px <= 0.0 and offset_px <= 0.0:
        corner = TRACK_OFFSET_PX["corners"]
        advice += (". A bias of the tracked pixels that follows a pose's tracks bends the shapes alike, and this "
                   "calibration took the tracks as unbiased (no track offsets and no image-axis floor: the dataset "
                   "does not name its tracker and CalibrationOptions.track_offset_px and axis_floor_px are 0). If "
                   f"the camera is calibrated, calibrate again with the track offsets of a corner tracker "
                   f"(--track-offset-px {corner:g}; CalibrationOptions(track_offset_px={corner:g}))")
    else:
        advice += (", and the tracks (a bias shared by a pose's tracks, such as features on highlights or edges that "
                   "do not move with the surface, reads the same way)")
    if not shapes:
        return "the tracks' shapes ask for other intrinsics than the camera file's. " + advice
    change = (f"focal length {shapes['focal_percent']:+.2g} % (1 sigma {shapes['focal_percent_sigma']:.2g} %), "
              + ", ".join(f"{name} {shapes['change'][name]:+.3g} px (1 sigma {shapes['sigma'][name]:.2g})"
                          for name in ("cx", "cy")))
    return (f"the tracks' shapes ask for other intrinsics than the camera file's (χ² = {shapes['chi2']:.3g} for "
            f"{shapes['dof']} dof, P = {shapes['p_value']:.2g}): {change}, a first-order reading. The pose absorbs "
            f"much of a wrong camera (here {shapes['mm_per_focal_percent']:.2g} mm per 1 % of focal length and "
            f"{shapes['mm_per_centre_px']:.2g} mm per px of principal point), so the estimate would be wrong by far "
            "more than its covariance says. " + advice)


def intrinsics_assumed_words(shapes: dict | None) -> str | None:
    """What a calibration with the intrinsics as given assumes of them, in numbers (None where not known)."""
    if not shapes:
        return None
    return (f"intrinsics: the camera file's taken as exact; their errors are not in this covariance (the pose moves "
            f"{shapes['mm_per_focal_percent']:.2g} mm and {shapes['deg_per_focal_percent']:.2g}° per 1 % of focal "
            f"length, {shapes['mm_per_centre_px']:.2g} mm and {shapes['deg_per_centre_px']:.2g}° per px of principal "
            "point; refine them with CalibrationOptions.refine_intrinsics / --refine-intrinsics)")


def kinematics_or_measurement_words(result: CalibrationResult, ks: list[int]) -> str:
    """Why a result whose axes joint offsets and one wrong measurement explain alike is not trusted
    (``untrusted["kinematics_or_measurement"]``, the numbers of ``result.axis_consistency.kinematics``)."""
    c = result.axis_consistency
    k = None if c is None else c.kinematics
    which = ", ".join(str(i) for i in ks) or "one"
    advice = (f"Calibrate again with the offsets refined (calibrate --joint-offsets; CalibrationOptions("
              f"joint_offsets=True)), or check measurement {which}'s joint readings and tracks and add arm poses")
    if not k or k.get("chi2") is None or k.get("one_out_chi2") is None:  # a file without the numbers
        return (f"the image axes disagree with any one pose; offsets of the joints' zero positions and a wrong "
                f"measurement {which} explain them alike, and they put the camera apart beyond the covariance: the "
                "estimate is not trusted. " + advice)
    offsets = ", ".join(f"{name} {value:+.2f}°" for name, value in (k.get("offsets_deg") or {}).items())
    return (f"the image axes of all {len(k['measurements'])} measurements disagree with any one pose through these "
            f"kinematics (χ² = {k['exact_chi2']:.3g} for {k['exact_dof']} dof, P = {k['exact_p']:.2g}); they agree "
            f"once the joints' zero positions may be off (χ² = {k['chi2']:.3g} for {k['dof']} dof, offsets of about "
            f"{offsets}, a first-order reading), and as well without measurement {which} (χ² = "
            f"{k['one_out_chi2']:.3g} for {k['exact_dof'] - 2} dof). The estimate rests on one of the two, and they "
            "put the camera apart by more than its covariance, so it is not trusted. " + advice)


def camera_or_measurement_words(result: CalibrationResult, ks: list[int]) -> str:
    """Why a result whose axes a camera error and one measurement explain alike is not trusted
    (``untrusted["camera_or_measurement"]``, the numbers of ``result.axis_consistency.intrinsics``): the estimate
    still uses that measurement, or left it out while the camera's explanation puts the camera elsewhere."""
    c = result.axis_consistency
    i = None if c is None else c.intrinsics
    which = ", ".join(str(k) for k in ks) or "one"
    left_out = bool(ks) and all(not m.used for m in result.measurements if m.index in ks)
    advice = (f"Check measurement {which}'s joint readings and tracks, and the intrinsics (is the camera file this "
              "camera's, at this resolution?)")
    if not i or i.get("chi2") is None or i.get("one_out_chi2") is None:  # a file without the numbers
        return (f"the image axes disagree with any one pose; changed intrinsics and a wrong measurement {which} "
                "explain them alike, and the estimate, which still uses that measurement, rests on neither: it is not "
                "trusted. " + advice)
    return (f"the image axes of all {len(i['measurements'])} measurements disagree with any one pose seen through "
            f"this camera (χ² = {i['exact_chi2']:.3g} for {i['exact_dof']} dof, P = {i['exact_p']:.2g}); they agree "
            f"once its focal length and principal point may change (χ² = {i['chi2']:.3g} for {i['dof']} dof, about "
            f"{i['focal_percent']:+.2g} % in focal length, {i['cx_px']:+.3g} px in cx, {i['cy_px']:+.3g} px in cy), "
            f"and as well without measurement {which} (χ² = {i['one_out_chi2']:.3g} for {i['exact_dof'] - 2} dof). "
            + (("The estimate left that measurement out: it rests on that measurement being wrong, and the camera's "
                "explanation puts the camera elsewhere by more than its covariance, so it is not trusted. ")
               if left_out else
               ("The estimate still uses that measurement and only widened its covariance for the scatter: it rests "
                "on neither explanation, and they put the camera apart by more than that covariance, so it is not "
                "trusted. "))
            + advice)


def _then_left_out(result: CalibrationResult) -> str:
    """The words after a model check's advice that name the measurements left out as disagreeing ("" for none)."""
    left_out = [m.index for m in result.measurements if m.outlier_kind == OutlierKind.DISAGREES]
    return (f"; if they are right, look at measurement(s) {', '.join(str(k) for k in left_out)} (left out as "
            "disagreeing): their tracks or joint angles" if left_out else "")


def joint_offset_words(result: CalibrationResult) -> str:
    """Why offsets of the joints' zero positions are a likely cause of the axes' disagreement (the numbers of
    ``result.axis_consistency.kinematics``), and what to do."""
    c = result.axis_consistency
    k = None if c is None else c.kinematics
    then = _then_left_out(result)
    advice = ("Offsets common to every pose bend the estimate by far more than its covariance says, so it is not "
              "trusted. Check the robot's zero positions (mastering, encoder offsets, the URDF's joint origins)"
              + then)
    if not k or k.get("chi2") is None:  # a result file that names the reason without its numbers
        return ("the image axes disagree with any one pose through the kinematics as given and agree once the joints "
                "before the spinning one may be offset: " + advice)
    offsets = ", ".join(f"{name} {deg:+.2f}°" for name, deg in k["offsets_deg"].items())
    # (offsets that explain the axes where the kinematics as given failed only the axes' own test, which scaled the
    # covariance, not the model check's: systematic, not ``likely``, yet all the way)
    agree = "agree" if k.get("likely", True) or k["p_value"] >= FREED_P else \
        "come far closer (not all the way: more is off)"
    if _camera_over_offsets(result):
        advice = (f"A camera error explains the axes better (P = {c.intrinsics['p_value']:.2g}): see the intrinsics "
                  "first. " + advice)
    return (f"the image axes of all {len(k['measurements'])} measurements (the left-out ones too) disagree with any "
            f"one pose through the kinematics as given (χ² = {k['exact_chi2']:.3g} for {k['exact_dof']} dof, P = "
            f"{k['exact_p']:.2g}) but {agree} once the joints before the spinning one may be offset (χ² = "
            f"{k['chi2']:.3g} for {k['dof']} dof, P = {k['p_value']:.2g}; {k['determined']} combinations of the "
            f"offsets determined), by about {offsets} (a first-order reading, added to the readings; the first "
            "joint's turns the whole arm, as the camera pose does, and does not show). " + advice)


def kinematics_words(joint_sigma_deg: float, offsets: bool = False) -> str:
    """What a covariance that includes joint-angle noise of ``joint_sigma_deg`` (0: none) assumes, in words;
    ``offsets``: joint offsets were refined too."""
    but = " (but for the joint offsets below)" if offsets else ""
    if joint_sigma_deg > 0.0:
        return (f"kinematics: joint readings{but} uncertain by {joint_sigma_deg:g} deg (1 sigma, per joint and arm "
                "pose), propagated into the covariance")
    return (f"kinematics: joint readings taken as exact{but}; their errors are not in this covariance (declare "
            "them with CalibrationOptions.joint_sigma_deg / --joint-sigma-deg)")


def joint_offsets_words(offsets_deg: dict[str, float] | None, sigma_deg: dict[str, float],
                        prior_deg: float, wrist_only: bool = False) -> list[str]:
    """The refined joint offsets (deg, the reading plus the offset is the joint's angle) with their 1 sigma, and
    which of them these poses leave at their prior; [] when none was refined. ``wrist_only``: every measurement
    spun the wrist (then how to win back what refining costs)."""
    if offsets_deg is None:
        return []
    lines = [f"joint offsets refined with the pose (prior 1 sigma {prior_deg:g} deg; the reading plus the offset is "
             "the joint's angle), in the covariance:"]
    held = []
    for name, value in offsets_deg.items():
        s = sigma_deg.get(name, float("nan"))
        if not np.isfinite(s) or s > HELD_BY_PRIOR * prior_deg:
            held.append(name)
            lines.append(f"  {name}: {value:+.3f} deg, NOT determined by these poses (1 sigma {s:.3f} deg, its prior)")
        else:
            lines.append(f"  {name}: {value:+.3f} deg +- {s:.3f} deg (1 sigma)")
    if held:
        lines.append("  the offsets left at their prior move arm_T_camera as much as the prior allows (the first "
                     "joint's offset turns the whole arm as the camera pose does: no poses determine it; for the "
                     "others add arm poses that move those joints)")
    if wrist_only:
        lines.append("  refining offsets costs precision at the same poses: spin the joint before the wrist too at "
                     "every pose (Measurement.spin_joint, track --spin-joints) to win it back")
    return lines


def refined_intrinsics_words(intrinsics: dict[str, float], sigma: dict[str, float], given: dict[str, float],
                             prior: tuple | None) -> list[str]:
    """The refined intrinsics (px) with their 1 sigma and their change from the camera file's (``given``); [] when
    none was refined. ``prior``: (focal fraction, principal point px) of the prior."""
    if not intrinsics:
        return []
    head = "intrinsics refined with the pose"
    if prior is not None:
        head += (f" (prior 1 sigma {100.0 * prior[0]:g} % focal, {prior[1]:g} px principal point, about the camera "
                 "file's)")
    lines = [head + ", in the covariance:"]
    for name, value in intrinsics.items():
        s = sigma.get(name, float("nan"))
        change = value - given[name] if name in given else float("nan")
        relative = f", {100.0 * change / given[name]:+.2f} %" if name in ("fx", "fy") and name in given else ""
        lines.append(f"  {name}: {value:.2f} px +- {s:.2f} px (1 sigma; camera file {change:+.2f} px{relative})")
    lines.append("  refining intrinsics costs precision along the camera's depth (a focal length and the distance "
                 "trade off): add arm poses at other distances from the camera to win it back")
    return lines


def readings_ignored_words(ignored: bool, method: str) -> list[str]:
    """The line that says the measurements' joint readings went unused by ``method`` ([] where they did not)."""
    if not ignored:
        return []
    return [f"encoders: the measurements' joint readings are not used by the {method} method (only joint with the "
            "rigid spin syncs them)"]


def synced_words(synced, offset_s: float | None, sigma_s: float | None, n_measurements: int,
                 prior_sigma_s: float | None = None, refused: dict | None = None,
                 noise_share: float | None = None, offsets: dict | None = None) -> list[str]:
    """What synced mode did (``result.synced``, ``time_offset_s``, ``time_offset_sigma_s``, the offset's prior
    1 sigma and the share of its information that the readings' own noise makes; with named camera clocks,
    ``result.time_offsets``: one line per clock), and the readings it did not use (``result.readings_refused``); []
    when no spin carried readings."""
    lines = [(f"encoders: measurement {k}'s readings ({v['readings'][0]:.3f} to {v['readings'][1]:.3f} s) do not "
              f"cover its frames ({v['frames'][0]:.3f} to {v['frames'][1]:.3f} s on the encoder's clock): not used; "
              "give the clocks' offset (CalibrationOptions.time_offset_s, calibrate --time-offset) if they are "
              "stamped on another clock")
             if v.get("why") == "cover" else
             (f"encoders: measurement {k}'s readings disagree with the spin its tracks show (likelihood ratio "
              f"{v['chi2']:.0f} for {v['dof']} frames): not used; check the joint's sense and scale in the readings, "
              "their clock (a video's: its frame rate, track --fps), or their noise "
              "(CalibrationOptions.encoder_sigma_deg)")
             for k, v in sorted((refused or {}).items())]
    if not synced:
        return lines
    which = "every spin" if len(synced) == n_measurements else "measurements " + ", ".join(str(k) for k in synced)
    head = f"encoders: the spinning joint's readings set the spin's angle in every frame of {which} (synced)"
    if offsets:
        lines.append(head + f"; each of the {len(offsets)} camera clocks its own offset from the encoder's (a video "
                     "placed on a joint time series by image motion is a clock of its own: its offset is what that "
                     "placement left):")
        for clock, v in offsets.items():
            ks = ", ".join(str(k) for k in v.get("measurements") or ())
            words = _offset_words(v["offset_s"], v.get("sigma_s"), prior_sigma_s, v.get("noise_share"))
            lines.append(f"  clock {clock!r} (measurement{'s' if ',' in ks else ''} {ks}): {words}")
        return lines
    words = None if offset_s is None else _offset_words(offset_s, sigma_s, prior_sigma_s, noise_share)
    return lines + [head if words is None else f"{head}; {words}"]


def _offset_words(offset_s: float, sigma_s: float | None, prior_sigma_s: float | None,
                  noise_share: float | None) -> str:
    """One clock offset (camera minus encoder, s) with its 1 sigma (None: held), in words."""
    if sigma_s is None:
        return f"the clocks' offset (camera minus encoder) taken as {1000.0 * offset_s:+.1f} ms (held)"
    if noise_share is not None and noise_share > 0.25:
        prior = "" if prior_sigma_s is None else f" ({1000.0 * prior_sigma_s:g} ms)"
        return (f"the readings cannot date the frames: their own noise makes {100.0 * noise_share:.0f} % of what "
                "looks like the clocks' offset's information (a spin at one speed, or noisy readings), so the "
                f"offset keeps its prior's 1 sigma{prior}; start and stop the spin within the video to measure it")
    line = (f"the clocks' offset (camera minus encoder) {1000.0 * offset_s:+.2f} ms +- {1000.0 * sigma_s:.2f} ms "
            "(1 sigma)")
    if prior_sigma_s is not None and sigma_s > 0.5 * prior_sigma_s:
        line += (f" (mostly its prior's {1000.0 * prior_sigma_s:g} ms: the spins' changes of speed hardly date the "
                 "frames; start and stop the spin within the video to measure it)")
    return line


def tracking_words(axis_floor_px: float, track_offset_px: float = 0.0) -> str:
    """What a covariance with the image axes' prior floor ``axis_floor_px`` and each track's own offset
    ``track_offset_px`` (px; 0: none) assumes, in words."""
    offset = (f"each track taken as shifted by an image offset of its own, {track_offset_px:g} px 1σ per coordinate "
              "(a tracker's error that follows a feature over its whole arc: a centroid pulled by shading, a corner "
              "drifting on a turning surface; CalibrationOptions.track_offset_px / --track-offset-px)"
              if track_offset_px > 0.0 else "")
    if axis_floor_px > 0.0:
        return (f"tracking: each image axis taken as uncertain by at least {axis_floor_px:g} px (an error all of a "
                "spin's tracks share, the tracker's), in the covariance (CalibrationOptions.axis_floor_px / "
                "--axis-floor-px)" + (f"; {offset}" if offset else ""))
    if offset:
        return f"tracking: {offset}, in the covariance; no floor on the image axes"
    return ("tracking: the tracks' errors taken as independent, no floor on the image axes (tracks of unknown "
            "origin or simulated; declare a tracker's shared error with CalibrationOptions.axis_floor_px / "
            "--axis-floor-px, one that follows each track with --track-offset-px)")


def image_shift_words(result: CalibrationResult, px: float | None = None) -> str | None:
    """Where an image shift per pose (a camera that turns or moves a little between poses), which the data all but
    cannot show, would move a usable pose by more than its 1σ along some direction
    (``CalibrationResult.image_shift_excess`` at least 1): how much, and what to do; None otherwise. The shift is
    ``px``, by default what the videos' still background leaves room for where it was measured
    (``result.camera_motion["bound_px"]``), else :data:`IMAGE_SHIFT_PX`."""
    measured = isinstance(result.camera_motion, dict) and result.camera_motion.get("bound_px") is not None
    if px is None:
        px = float(result.camera_motion["bound_px"]) if measured else IMAGE_SHIFT_PX
    excess = result.image_shift_excess(px)
    if not result.covariance_usable or excess is None or excess < 1.0:
        return None
    mm, deg = result.image_shift_sigma(px)
    what = (f"the videos' still background leaves room for an image shift of {px:.2g} px per pose (the camera "
            "turning or moving between poses)" if measured else
            f"an image shift of {px:g} px per pose (the camera turning about 0.01° between poses, or a tracker's "
            "error shared by a pose's tracks)")
    return (f"camera still? {what}, which the axes' test all but cannot see, would add up to "
            f"{np.max(mm):.2g} mm and {np.max(deg):.2g}° (1σ) to this pose's error, {np.sqrt(excess):.1f}x its 1σ "
            "along some direction: keep the camera fixed relative to the arm's base while recording (`gtsam-rotid "
            "still VIDEO...` measures it on the videos), or declare such a move as the image axes' floor "
            f"(CalibrationOptions.axis_floor_px / --axis-floor-px {px:.2g})")


def camera_motion_line(result: CalibrationResult) -> str | None:
    """What the videos' still background said of the camera's move between them (``result.camera_motion``); None
    where it was not measured."""
    motion = result.camera_motion
    if not isinstance(motion, dict) or motion.get("floor_px") is None:
        return None
    floor, bound = float(motion["floor_px"]), float(motion.get("bound_px") or 0.0)
    if floor <= 0.0:
        during = " and during" if motion.get("drift_px") is not None else ""
        return (f"camera motion: the videos' still background shows the camera still between{during} them (any shift "
                f"below {bound:.2g} px)")
    level = float(motion.get("level_px") or 0.0)
    drifted = [name for name, d in zip(motion.get("names") or [], motion.get("drifted") or [], strict=False) if d]
    between = motion.get("moved") is None or any(motion["moved"])  # (written before "moved" was: between them)
    when = " and ".join(filter(None, ["between them" if between else "",
                                      f"during {_listed(drifted, 'and')}" if drifted else ""]))
    return (f"camera motion: the videos' still background shows the camera moved {when}, by up to "
            f"{floor:.3g} px ({level:.2g} px per pose, 1σ per coordinate): what that moves the pose by is in the "
            "covariance")


def camera_motion_words(motion: CameraMotion) -> list[str]:
    """Each video's shift on the still background (:func:`gtsam_rotid.stillness.camera_motion`) and what to do."""
    drift = motion.drift_px is not None
    lines = [f"image shift of each video against {motion.names[0]}, on the still background (px, x y; 1 sigma)"
             + ("; and during it, its last frame against its first:" if drift else ":")]
    for k in range(len(motion.names)):
        line = f"  {motion.names[k]}: "
        if k:
            x, y = motion.shifts_px[k]
            sx, sy = motion.sigma_px[k]
            line += (f"{x:+.3f} {y:+.3f} (± {sx:.3f} {sy:.3f}; {int(motion.n_points[k])} points)"
                     f"{'  MOVED' if motion.moved[k] else ''}")
        elif not drift:
            continue
        else:
            line += "(the reference)"
        if drift:
            x, y = motion.drift_px[k]
            sx, sy = motion.drift_sigma_px[k]
            line += (f"; during it {x:+.3f} {y:+.3f} (± {sx:.3f} {sy:.3f})"
                     f"{'  MOVED DURING IT' if motion.drifted[k] else ''}")
        lines.append(line)
    if motion.drift_error is not None:
        lines.append(f"the camera's move during each video could not be read: {motion.drift_error}")
    if motion.floor_px > 0.0:
        when = ("between the videos" if not np.any(motion.drifted) else "during a video" if not np.any(motion.moved)
                else "between and during the videos")
        lines.append(f"the camera moved {when} (beyond {SIGNIFICANT_Z:g} sigma and {MIN_MOVE_PX:g} px), "
                     f"up to {motion.floor_px:.3f} px: a shift common to a pose's tracks, which the calibration's "
                     "test all but cannot see; a dataset made from these videos (`gtsam-rotid track`, make_dataset) "
                     f"carries it ({motion.level_px:.3f} px per pose, 1 sigma per coordinate) and calibrate counts "
                     "what it moves the pose by in the covariance (elsewhere, more cautiously: --axis-floor-px "
                     f"{motion.floor_px:.3f}); or record again with the camera fixed")
    else:
        lines.append(f"the camera stayed still between{' and during' if drift else ''} the videos (no shift beyond "
                     f"{SIGNIFICANT_Z:g} sigma and {MIN_MOVE_PX:g} px)")
    return lines


def _listed(items, conjunction: str) -> str:
    """"1", "1 or 2", "1, 2 or 3"."""
    items = [str(i) for i in items]
    return items[0] if len(items) == 1 else f"{', '.join(items[:-1])} {conjunction} {items[-1]}"


def _close(result: CalibrationResult) -> list:
    """The alternatives that make the result ambiguous, best fit first."""
    return sorted((a for a in result.alternatives if a.delta_chi2 < AMBIGUITY_CHI2), key=lambda a: a.delta_chi2)


def _suspects(close) -> str:
    """The measurements one of which is wrong, by the alternatives reached by leaving out another one: "measurement
    4, 2 or 1" (the estimate's left-out one first, then the others best fit first; several groups joined by "; ");
    "" when no alternative left out another measurement."""
    swaps: dict[int, list[int]] = {}
    for a in close:
        if a.left_out is not None and a.left_out not in swaps.setdefault(a.instead_of, []):
            swaps[a.instead_of].append(a.left_out)
    return "; ".join(f"measurement {_listed([k, *others], 'or')}" for k, others in swaps.items())


def ambiguity_words(result: CalibrationResult) -> str:
    """Plain words for an ambiguous result: which other poses fit, and what to do; none ("") when the result is not
    ambiguous."""
    close = _close(result)
    if not close:
        return ""
    t = np.asarray(result.arm_T_camera.translation(), dtype=float)

    def fit(delta: float) -> str:  # an alternative may fit better than the estimate (delta < 0)
        if delta > 0.0:
            return f"chi-square only {delta:.3g} worse"
        if delta == 0.0:
            return "the same chi-square: it fits as well as this estimate"
        return f"chi-square {-delta:.3g} lower: it fits better than this estimate"

    def swap(a) -> str:
        return ("" if a.left_out is None else
                f" (leaving out measurement {a.left_out} instead of measurement {a.instead_of})")

    where = "; ".join(
        f"camera at {np.round(1000 * np.asarray(a.arm_T_camera.translation(), dtype=float), 1).tolist()} mm, "
        f"{1000 * np.linalg.norm(np.asarray(a.arm_T_camera.translation(), dtype=float) - t):.0f} mm and "
        f"{np.degrees(np.linalg.norm(result.arm_T_camera.rotation().localCoordinates(a.arm_T_camera.rotation()))):.1f}"
        f"° from this estimate{swap(a)}, {fit(a.delta_chi2)}" for a in close)
    how = ("almost as well" if close[0].delta_chi2 > 0.0 else
           "as well or better" if close[-1].delta_chi2 <= 0.0 else "almost as well or better")
    used = sum(m.used for m in result.measurements)
    suspects = _suspects(close)
    advice = []
    if suspects:
        advice.append(f"One measurement disagrees with the rest, and the data do not say which ({suspects}): check "
                      "those measurements' joint angles and tracks, or record them again; another arm pose also "
                      "tells them apart")
    if any(a.left_out is None for a in close):
        advice.append(("With three arm poses the wrist axes give exactly as many equations as the six unknowns, and "
                       "those have several exact solutions" if used == MIN_MEASUREMENTS else
                       "The chosen wrist axes do not single one out")
                      + "; add arm poses whose wrist axes are tilted from the others and miss their common point")
    return (f"{len(close)} other pose{'s' if len(close) > 1 else ''} of the camera fit the pixels {how} "
            f"({where}; a difference below {AMBIGUITY_CHI2:.1f} is a likelihood ratio under 1000:1): the data cannot "
            f"tell them apart, so neither this estimate nor its covariance can be trusted. " + ". ".join(advice))


def check_words(check: CheckResult) -> list[str]:
    """A calibration re-checked against new spins (:func:`gtsam_rotid.calibration.check.check_calibration`): the
    verdict first, then each spin."""
    n = len(check.spins)
    spins, verb = (f"{n} new spin", "agrees") if n == 1 else (f"{n} new spins", "agree")
    test = (f"the move's χ² {check.chi2:.3g} for the {check.dof} direction(s) they determine, p = "
            f"{check.p_value:.2g}")
    mm, deg = check.move_mm, check.move_deg
    sigma_mm, sigma_deg = check.move_sigma
    basis = ("" if check.tolerance is None else f" (the calibration came without a covariance: taken as good to "
             f"{check.tolerance[0]:g} mm and {check.tolerance[1]:g}° per axis, 1σ; --tolerance)")
    if check.image_shift_px > 0.0:
        basis += (f" (the camera shook between the new videos, as their background measured: each spin's image "
                  f"taken to shift by {check.image_shift_px:.3f} px of its own, 1σ)")
    recalibrate = ("Recalibrate: spin the wrist at three or more poses whose axes do not meet in one point (or check "
                   "that the camera mount, the joint readings and the intrinsics are as they were).")
    odd = ("" if check.odd_spin is None else f"Spin {check.odd_spin} alone does not fit: check its joint readings "
           "and tracks, or record it again; what follows is without it. ")
    if not check.still_valid and check.fully_determined:
        lines = [f"MOVED: {odd}the {spins} disagree with the calibration ({test}){basis}: the camera moved by about "
                 f"{mm:.2f} mm and {deg:.3f}° (1σ {sigma_mm:.2f} mm, {sigma_deg:.3f}°, the calibration's own "
                 f"uncertainty included). {recalibrate}"]
    elif not check.still_valid:
        lines = [f"MOVED: {odd}the {spins} {'disagrees' if n == 1 else 'disagree'} with the calibration ({test})"
                 f"{basis}, but {'it determines' if n == 1 else 'they determine'} only {check.dof} of the pose's 6 "
                 "directions, so how far the camera moved cannot be read from them"
                 + ("; one spin cannot tell a shift of the camera from a turn" if n == 1 else "") + f". {recalibrate}"]
    elif not check.consistent:
        lines = [f"THE SPINS DISAGREE: they do not fit one camera pose (χ² {check.residual_chi2:.3g} for "
                 f"{check.residual_dof} dof at the pose that fits them best), and no one spin alone explains it; the "
                 f"calibration is not shown to have moved ({test}). Check the joint readings and the tracks, or "
                 "record the spins again."]
    elif check.odd_spin is not None:
        lines = [f"ONE SPIN DISAGREES: spin {check.odd_spin} alone does not fit (check its joint readings and tracks, "
                 f"or record it again); without it the others agree with the calibration ({test}){basis}."]
    else:
        size = (f" They would place the camera {mm:.2f} mm and {deg:.3f}° from it (1σ {sigma_mm:.2f} mm, "
                f"{sigma_deg:.3f}°, the calibration's own uncertainty included): within the noise."
                if check.fully_determined else "")
        lines = [f"STILL VALID: the {spins} {verb} with the calibration ({test}){basis}.{size}"]
    lines.extend(f"  spin {s.index}{f' ({s.name})' if s.name else ''}: {s.n_tracks} tracks, χ² {s.chi2:.3g} (2 dof "
                 "at the calibration)" for s in check.spins)
    return lines


def prediction_words(prediction: Prediction) -> list[str]:
    """The predicted accuracy of a set of arm poses: the 1σ per axis, the observability verdict, what it assumes,
    and the poses that break a constraint."""
    p, o = prediction, prediction.options
    s = p.sigma
    lines = []
    poses = f"{len(p.joint_angles)} {'new ' if p.with_prior else ''}pose(s)"
    poses += " and what is already recorded" if p.with_prior else ""
    if p.observability.is_observable:
        lines.append(f"PREDICTED 1σ from {poses}: rotation {s[0]:.3f}, {s[1]:.3f}, {s[2]:.3f}° "
                     f"(about the camera's x, y, z), translation {s[3]:.2f}, {s[4]:.2f}, {s[5]:.2f} mm (camera "
                     f"frame); camera position along the arm's x, y, z: "
                     + ", ".join(f"{v:.2f}" for v in p.sigma_mm_arm) + " mm")
    else:
        lines.append(f"DEGENERATE: {poses} would not determine the calibration, whatever the recording:")
    lines.extend(observability_words(p.observability)[0 if p.observability.is_observable else 1:])
    floor = (f", each spin's image axis off by {o.axis_floor_px:g} px more (the tracker's floor)"
             if o.axis_floor_px > 0 else "")
    spin = (f"{o.spin_seconds:g} s spins at {o.wrist_speed:g} rad/s (back and forth over the spinning joint's "
            f"{p.spin_range_deg:.0f}° range)" if p.spin_range_deg is not None else
            f"{o.spin_seconds:g} s spins at {o.wrist_speed:g} rad/s")
    lines.append(f"assumes {spin} and {o.fps:g} fps, {o.n_features} "
                 f"features {100 * o.radius_range[0]:.1f}-{100 * o.radius_range[1]:.1f} cm from the spinning axis and "
                 f"{100 * o.offset_range[0]:.1f} to {100 * o.offset_range[1]:.1f} cm along it from the joint, "
                 f"{o.pixel_sigma:g} px noise per tracked point{floor}, and the camera about where the guess puts "
                 f"it (the 1σ is averaged over {o.guess_samples} camera poses drawn around the guess with 1σ "
                 f"{o.guess_sigma_mm:g} mm and {o.guess_sigma_deg:g}°, each with its own texture)"
                 + (f"; the intrinsics refined with the pose (fx, fy, cx, cy free under a prior of "
                    f"{100 * o.intrinsics_sigma[0]:g} % and {o.intrinsics_sigma[1]:g} px)"
                    if o.refine_intrinsics else "; the camera file's intrinsics exact")
                 + (f"; joint offsets refined ({_offset_joints_words(o.joint_offsets)} free under a prior of "
                    f"{o.joint_offset_sigma_deg:g}°)" if o.joint_offsets is not False else ""))
    for k, problem in enumerate(p.problems):
        if problem is not None:
            lines.append(f"pose {k}: {problem}")
    return lines


def _offset_joints_words(joints) -> str:
    return "every joint between the first and the spinning one" if joints is True else ", ".join(joints)


def plan_words(plan: Plan) -> list[str]:
    """A plan: what was searched, the predicted accuracy, and (next best poses) the gain over the calibration."""
    refused = ", ".join(f"{reason} ({count})" for reason, count in
                        sorted(plan.refused.items(), key=lambda item: -item[1])[:4])
    lines = [f"planned {len(plan.joint_angles)} pose(s) from {plan.candidates} that satisfy every constraint "
             f"({plan.draws} arm poses tried; refused most often: {refused or 'none'}) in {plan.seconds:.1f} s"]
    if plan.sigma_before is not None:
        b, a = plan.sigma_before, plan.prediction.sigma

        def worst(s: np.ndarray) -> str:
            if s.max() > 1e5:  # an undetermined direction (σ = 1000 km)
                return "not determined"
            return f"{s[:3].max():.3g}° and {s[3:].max():.3g} mm"
        lines.append(f"with the new pose{'s' if len(plan.joint_angles) > 1 else ''} the worst 1σ goes from "
                     f"{worst(b)} to {worst(a)}")
    return lines + prediction_words(plan.prediction)

"""``calibrate``: the orchestration of the stages for each method, several starts and the choice between them,
and the reasons not to trust a result.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from ..arm import Arm
from ..camera import Camera
from ..dataset import Dataset, Measurement
from ..errors import InputError, RotIdError
from ..geometry import axis_geometry
from ..graph import chi2_quantile
from .choice import checked_joint, choose_start
from .initial import _initial, axis_miss_rms, poor_start
from .joint import Fitted, _judged, _weighted
from .lm import _builder
from .modelcheck import IMPROVEMENT_Z, SYSTEMATIC_Z, intrinsics_check, kinematics_check
from .offsets import MAX_OFFSET_SIGMAS, OffsetsPrior, offsets_from_axes, shifted
from .options import (
    MIN_MEASUREMENTS,
    CalibrationError,
    CalibrationOptions,
    Method,
    camera_motion_level_px,
    with_tracker_defaults,
)
from .result import CalibrationResult, MeasurementReport, OutlierKind
from .setup import _Setup, _setup, arc_span_deg
from .stage2 import _check_scale, _paper, _refined_stage1, _settled
from .swaps import exchange_candidates, exchanged, swap_sentence
from .tuning import (
    INITIAL_TOLERANCE,
    INTRINSICS_PASSES,
    INTRINSICS_SETTLED,
    LONG_ARC_CONSISTENCY_P,
    MAX_CONSISTENCY_SCALE,
    MAX_RELATIVE_SIGMA,
    MAX_SCALE_AFTER_OUTLIERS,
    MAX_SIGMA_DEG,
    RESTART_P,
    SHORT_ARC_CONSISTENCY_P,
)


def calibrate(arm: Arm | Dataset, camera: Camera | None = None, measurements: list[Measurement] | None = None, *,
              method: str | Method = Method.JOINT, options: CalibrationOptions | None = None) -> CalibrationResult:
    """Estimate ``arm_T_camera`` from wrist spins.

    Call as ``calibrate(dataset)`` or ``calibrate(arm, camera, measurements)``; ``method`` and ``options`` are
    keywords (``calibrate(dataset, options=CalibrationOptions(...))``).
    """
    metadata, source = {}, {}
    if isinstance(arm, Dataset):
        if camera is not None or measurements is not None:
            given = type(camera if camera is not None else measurements).__name__
            raise InputError(f"calibrate(dataset, ...) takes its camera and measurements from the dataset, but a "
                             f"{given} was also passed by position; pass options and method as keywords: "
                             "calibrate(dataset, options=CalibrationOptions(...), method='joint')")
        dataset = arm
        arm, camera, measurements, metadata = dataset.arm, dataset.camera, list(dataset), dataset.metadata
        source = dict(dataset.source or {})
    if camera is None or measurements is None:
        raise InputError("calibrate needs a Dataset, or an Arm, a Camera and a list of Measurements")
    try:
        method = Method(method)
    except ValueError:
        raise InputError(f"unknown method {method!r}; choose one of {[m.value for m in Method]}") from None
    options = CalibrationOptions() if options is None else options
    options = with_tracker_defaults(options, metadata)
    measurements = [m if isinstance(m, Measurement) else Measurement(*m) for m in measurements]
    for k, m in enumerate(measurements):  # as a Dataset checks them (a Dataset's are checked already)
        problem = arm.limit_problem(m.joint_angles)
        if problem is not None:
            raise InputError(f"measurement {k}: {problem}")
    # a measurement with fewer than two usable tracks has no image axis: it is left out and named, not fatal
    builder = _builder(arm, camera, options)
    prepared = [builder.prepare(m, k) for k, m in enumerate(measurements)]
    kept = [k for k, p in enumerate(prepared) if len(p.usable) >= 2]
    if len(kept) < MIN_MEASUREMENTS:
        bad = "; ".join(f"measurement {k}: only {len(p.usable)} usable track(s) (rejected: "
                        + ", ".join(f"track {j}: {why}" for j, why in p.rejected.items()) + ")"
                        for k, p in enumerate(prepared) if len(p.usable) < 2)
        raise InputError(f"need at least {MIN_MEASUREMENTS} measurements (arm poses) with at least 2 usable tracks "
                         f"each, got {len(kept)} of {len(measurements)}" + (f" ({bad})" if bad else "")
                         + "; spin the wrist longer or give the hand more texture")
    if options.refine_intrinsics and method is not Method.JOINT:
        raise InputError(f"intrinsics are refined by the joint method only, not {method.value!r}")
    used = [measurements[k] for k in kept]
    try:
        result, setup, started = _passes(arm, camera, used, method, options, kept)
    except ValueError as error:  # the maths met a degenerate geometry (e.g. an axis through the camera centre)
        if isinstance(error, RotIdError):  # (an InputError is a ValueError too: ours pass as they are)
            raise
        raise CalibrationError(f"the calibration failed on a degenerate geometry: {error}; check that the spinning "
                               "joints' axes differ from pose to pose and pass beside the camera") from error
    if _troubled(result) and not _undetermined_by_the_axes(result, setup):
        # (with refined intrinsics, at the camera the last pass started from, as its setup)
        swap = _confirmed_swap(arm, started, used, method, options, kept, setup, given_usable=_sound(result, setup))
        if swap is not None:
            result = replace(result, swapped=swap)
    reports = [replace(r, index=kept[r.index]) for r in result.measurements]
    for k, p in enumerate(prepared):
        if k in kept:
            continue
        axis = arm.wrist_axis(measurements[k].joint_angles, measurements[k].spin_joint)
        spans = [arc_span_deg(t.ideal, t.ellipse) for t in p.usable.values()]
        reports.append(MeasurementReport(
            k, len(p.usable), sum(len(t.ideal) for t in p.usable.values()), float("nan"), 0.0, True,
            dict(p.rejected), OutlierKind.FEW_TRACKS.value, axis_point=[float(v) for v in axis.point],
            axis_direction=[float(v) for v in axis.direction], arc_span_deg=max(spans) if spans else None, weak=True,
            spin_joint=measurements[k].spin_joint))
    # (the synced measurements' indices back to the caller's, as the reports'; readings that only the joint method
    # with the rigid spin uses are said to be unused by the others)
    ignored = (options.sync_encoders and any(m.spin_readings is not None for m in measurements)
               and (method is not Method.JOINT or options.spin_model != "rigid"))
    result = replace(result, measurements=sorted(reports, key=lambda r: r.index), robot=arm.description(),
                     dataset=source, synced=tuple(kept[k] for k in result.synced),
                     readings_refused={kept[k]: v for k, v in result.readings_refused.items()},
                     time_offsets=None if result.time_offsets is None else {
                         c: {**v, "measurements": [kept[k] for k in v["measurements"]]}
                         for c, v in result.time_offsets.items()},
                     readings_ignored=bool(ignored),
                     camera_motion=dict(metadata["camera_motion"]) if isinstance(metadata.get("camera_motion"), dict)
                     else None)
    level = camera_motion_level_px(metadata)
    if level > 0.0 and result.image_shift_covariance is not None:  # the camera moved between the videos
        result = replace(result, covariance=result.covariance + level**2 * result.image_shift_covariance)
        blocks = result.image_shift_nuisance or {}  # (and the refined offsets and intrinsics with it)
        if result.joint_offsets_covariance is not None and "offsets" in blocks:
            result = replace(result,
                             joint_offsets_covariance=result.joint_offsets_covariance + level**2 * blocks["offsets"],
                             pose_offsets_covariance=result.pose_offsets_covariance + level**2 * blocks["cross"])
        if result.intrinsics_covariance is not None and "intrinsics" in blocks:
            result = replace(result,
                             intrinsics_covariance=result.intrinsics_covariance + level**2 * blocks["intrinsics"])
    return replace(result, untrusted=_untrusted(result, setup))


def _troubled(result: CalibrationResult, scaled: bool = False) -> bool:
    """Something is wrong with the result: not converged or determined, ambiguous, its axes disagreeing, or a
    measurement called an outlier. With ``scaled``, axes that disagree are no trouble where their scatter scaled a
    covariance that is still usable (short arcs' image axes are far from Gaussian: six 6 s spins as recorded
    disagree at P 1e-7 and are usable)."""
    c = result.axis_consistency
    disagree = c is not None and not c.consistent and not (scaled and result.covariance_usable)
    return (not result.converged or not result.observability.is_observable or result.ambiguous
            or disagree or any(m.outlier for m in result.measurements))


def _undetermined_by_the_axes(result: CalibrationResult, setup: _Setup) -> bool:
    """The result is undetermined and its FK axes make it so (all through one point or parallel): two measurements
    exchanged keep those axes, so no exchange can make the calibration sound, and its calibration is not tried (on a
    single crossing, 10 s spins, it took 150 s of the 155)."""
    if result.observability.is_observable:
        return False
    geometry = axis_geometry(list(setup.axes))
    return geometry is not None and (geometry.is_crossing or geometry.is_parallel)


def _confirmed_swap(arm, camera, measurements, method, options, index, setup: _Setup | None = None,
                    given_usable: bool = False) -> dict | None:
    """Two measurements given in each other's place (:mod:`.swaps`): the first screened exchange
    (:func:`.swaps.exchange_candidates`, best first) where a calibration with the two exchanged is sound
    (converged, determined, not ambiguous, its axes agreeing, no measurement an outlier, nothing untrusted):
    ``{"measurements": [a, b]`` (the caller's indices), ``"miss_px"``, ``"swapped_miss_px"``, ``"next_miss_px"``
    (the screen's), ``"sigma_mm"`` (that calibration's largest 1 sigma)``}``; None otherwise. ``setup``: the
    calibration's (built here for a refusal). Where the calibration as given is refused or not usable
    (``given_usable`` False), the exchanged one's axes may disagree if their scatter leaves its covariance usable
    (:func:`_troubled`): on six 6 s spins the calibration as recorded does, and exchanges the screen found were not
    named for it."""
    if setup is None:
        try:
            setup = _setup(arm, camera, measurements, options, index)
        except RotIdError:
            return None
    for candidate in exchange_candidates(camera, setup, options):
        a, b = candidate.pop("positions")
        try:
            other, other_setup = _calibrate(arm, camera, exchanged(measurements, a, b), method, options, index)
        except RotIdError:
            continue
        if _troubled(other, scaled=not given_usable) or _untrusted(other, other_setup):
            continue
        return {"measurements": [int(index[a]), int(index[b])], **candidate,
                "sigma_mm": float(np.max(other.sigma_mm_arm))}
    return None


def _untrusted(result: CalibrationResult, setup: _Setup) -> dict[str, list[int]]:
    """The reasons (see :data:`UNTRUSTED_KINDS`) not to trust a determined result's covariance; two measurements
    that look swapped first and whether or not the result is determined (their exchange is the likelier cause of
    anything else found)."""
    out = {} if result.swapped is None else {"swapped": [int(k) for k in result.swapped["measurements"]]}
    if not result.observability.is_observable or result.ambiguous:
        return out
    c = result.axis_consistency
    strong = [m.index for m in result.measurements if not m.weak and m.used]
    # weak measurements are trusted only where strong ones determine the pose without them and the axes agree
    # (without redundancy, three measurements used, nothing tests them); the ones named are those the estimate
    # rests on (never none: the flag needs one), not the weak ones left out (weight 0); one called an outlier for its
    # residual RMS alone is still used
    weak_used = [m.index for m in result.measurements if m.weak and m.used]
    if weak_used and (c is None or c.p_value < RESTART_P or len(strong) < MIN_MEASUREMENTS):
        out["thin_evidence"] = weak_used
    if c is not None and c.intrinsics is not None and (c.intrinsics.get("likely") or _camera_systematic(result)):
        out["intrinsics"] = [int(k) for k in c.intrinsics.get("measurements", [])]
    elif c is not None and c.intrinsics is not None and c.intrinsics.get("undecided"):
        # a plausible camera error explains the axes, and so does one wrong measurement: where the estimate left
        # that measurement out it acted on the rival (the rest agree, its covariance holds); where it still uses it
        # (the scatter only scaled its covariance) it rests on neither explanation, and they differ beyond it
        j = c.intrinsics.get("one_out_measurement")
        if j is not None and any(m.index == j and m.used for m in result.measurements):
            out["camera_or_measurement"] = [int(j)]
    if c is not None and c.intrinsics is not None and c.intrinsics.get("rival") and "camera_or_measurement" not in out:
        # ... and where it left that measurement out, it rests on the measurement being wrong: where the camera's
        # explanation puts the camera elsewhere beyond the covariance, that is no more trusted (reference scene seed
        # 0, focal +5 %: measurement 1 left out, the rest agreeing, 29 mm off at chi-square 59 000)
        j = c.intrinsics.get("one_out_measurement")
        if j is not None and not any(m.index == j and m.used for m in result.measurements):
            out["camera_or_measurement"] = [int(j)]
    shapes = result.intrinsics_shapes
    if shapes is not None and shapes.get("flagged") and "intrinsics" not in out:
        # the circles' shapes (all of the tracks, not only their axes) ask for another camera: the pose absorbs much
        # of a wrong camera (focal -2 %, 20 s spins: 17 mm off at chi-square 1 700, the axes agreeing)
        out["intrinsics_shapes"] = [m.index for m in result.measurements if m.used]
    if c is not None and c.kinematics is not None and (
            c.kinematics.get("likely") or (c.kinematics.get("systematic") and not c.consistent)):
        # offsets explain the axes (likely), or explain more than one wrong measurement and beyond chance while the
        # axes the estimate rests on still disagree (its scale would treat a systematic error as scatter: Panda,
        # offsets of 0.5 degrees, two spins per pose, four of twelve measurements left out, the rest scaled by 7.7,
        # 16 mm off at chi-square 312 "usable"; the offsets' fit P = 0.002, below FREED_P)
        out["kinematics"] = [int(k) for k in c.kinematics.get("measurements", [])]
    elif c is not None and c.kinematics is not None and c.kinematics.get("undecided"):
        # joint offsets explain every axis, and so does one wrong measurement: the estimate rests on one of them
        # (left out or only down-weighted), and they put the camera apart beyond its covariance
        out["kinematics_or_measurement"] = [int(c.kinematics["one_out_measurement"])]
    dropped = [m.index for m in result.measurements if not m.used and m.outlier_kind == OutlierKind.DISAGREES.value]
    if c is not None and c.dof > 0 and c.chi2 / c.dof > MAX_CONSISTENCY_SCALE:
        out["inconsistent"] = [m.index for m in result.measurements if m.used]
    elif c is not None and not c.consistent and c.dof <= 2:
        out["unmeasured_scatter"] = [m.index for m in result.measurements if m.used]
    elif c is not None and dropped and not c.consistent and c.scale > MAX_SCALE_AFTER_OUTLIERS \
            and not out.keys() & {"intrinsics", "kinematics", "camera_or_measurement", "kinematics_or_measurement"}:
        # one wrong measurement left out does not explain the axes: the rest still disagree far beyond the
        # scatter a scaled covariance covers (a camera and joint offsets both off, neither alone explaining them)
        out["inconsistent_after_outliers"] = dropped
    distance = float(np.median([np.linalg.norm(result.arm_T_camera.transformTo(a.point)) for a in setup.axes]))
    limit_mm = 1000.0 * MAX_RELATIVE_SIGMA * distance
    if (not np.all(np.isfinite(result.covariance)) or np.max(result.sigma_mm_arm) > limit_mm
            or np.max(result.sigma_deg) > MAX_SIGMA_DEG):
        out["too_uncertain"] = []
    return out


def _camera_systematic(result: CalibrationResult) -> bool:
    """Whether a plausible camera error explains the axes beyond chance and better than one wrong measurement, not
    all of it (``systematic``: the axes are held as stage 1 fitted them through the camera given), while the axes
    the estimate rests on still disagree (its scale would treat a systematic error as scatter: Jaco2, 12 poses, focal
    +3 % and cx +10 px, 19 mm off at chi-square 15 000 "usable") and the camera's explanation puts the camera
    beyond the 99 % point of the estimate's covariance (``estimate_moved_chi2``), or they agree only with
    measurements left out whose being wrong the camera's explanation contradicts beyond the covariance (the same,
    seed 9: two left out, 23 mm off at chi-square 120 000)."""
    c = result.axis_consistency
    if not c.intrinsics.get("systematic"):
        return False
    left_out = any(m.outlier_kind == OutlierKind.DISAGREES for m in result.measurements)
    moved = c.intrinsics.get("estimate_moved_chi2")
    if not c.consistent:
        # ... and puts the camera elsewhere beyond the 99 % point of the (scaled) covariance: where the camera's
        # explanation lies inside it, the result holds whichever is right (a rendered photo-covered Jaco2 scene,
        # exact intrinsics, the axes at P = 0.006: its tracks' shared errors read as cx -15 px, cy +20 px, moving the
        # pose by 15.2 for 6 dof; the estimate was 0.26 mm off at chi-square 0.36)
        return moved is None or moved > chi2_quantile(6, SYSTEMATIC_Z)
    return left_out and moved is not None and moved > chi2_quantile(6, IMPROVEMENT_Z)


def _intrinsics_settled(result: CalibrationResult, started: Camera) -> bool:
    """Whether the refined intrinsics moved from those the pass ``result`` came from started (``started``) by less
    than ``INTRINSICS_SETTLED`` of their 1 sigma (a pass from them would change nothing that matters)."""
    sigma = result.intrinsics_sigma
    before = started.intrinsics
    return bool(sigma) and all(abs(value - before[name]) <= INTRINSICS_SETTLED * sigma[name]
                               for name, value in result.intrinsics.items())


def _calibrate(arm, camera, measurements, method, options, index, given_camera: Camera | None = None,
               camera_pass: bool = False) -> tuple[CalibrationResult, _Setup]:
    """One calibration from ``camera``; with refined intrinsics ``given_camera`` is the camera as given (the
    prior's mean) when ``camera`` is an earlier pass' refinement, and ``camera_pass`` asks only for the refined
    camera (:attr:`_Setup.camera_pass`)."""
    offsets = None
    if options.joint_offsets is not None:  # the readings shifted by the offsets the image axes give, then refined
        measurements, offsets = _offsets_start(arm, camera, measurements, method, options, index)
    starts, setup, anchors = _initial(arm, camera, measurements, options, index, INITIAL_TOLERANCE)
    setup = replace(setup, offsets=offsets, thin_check=method is Method.WEIGHTED
                    or (method is Method.JOINT and options.spin_model == "free"), given_camera=given_camera,
                    camera_pass=camera_pass)
    # Short arcs (each track's smooth drift, which a short arc turns into a wrong circle and which neither the
    # per-track scores nor the jackknife see) lower the level at which the axes' scatter scales the covariance: the
    # test has 2 n - 6 dof, little power with six poses (18 rendered corner-tracked scenes: at 0.01 three of nine
    # usable results were outside their 99.9 % region, 11 mm off with a 1 sigma of 4-8 mm; at 0.2 none). They also
    # make stage 1 refit itself from its own estimate (``_refined_stage1``: the axis through short arcs' ellipse
    # centres, which starts it, is unreliable).
    if options.axis_consistency_p is None:
        options = replace(options, axis_consistency_p=SHORT_ARC_CONSISTENCY_P if setup.short_arcs
                          else LONG_ARC_CONSISTENCY_P)
    runs, anchors = _paths(arm, camera, measurements, starts, anchors, setup, options)
    memo = {}  # (the joint fits from the runs, which the second path's choice among more runs takes again)
    try:
        result, failure = _from_runs(arm, camera, measurements, method, setup, runs, anchors, options, memo), None
    except CalibrationError as error:
        result, failure = None, error
    if setup.short_arcs and not setup.camera_pass and (result is None or not _sound(result, setup)):
        # from the guess-free start, 20-30 degrees off on short arcs, the standard path can end in a wrong minimum
        # by the chaos of its first fit (``_refined_stage1``'s ``placing``): the paths whose first fit only places
        # the pose are a second chance, and the joint fit chooses among all ends
        placed, placed_anchors = _paths(arm, camera, measurements, starts, anchors, setup, options, placing=True,
                                        after=runs)
        if placed:
            try:
                second = _from_runs(arm, camera, measurements, method, setup, [*runs, *placed],
                                    [*anchors, *placed_anchors], options, memo)
                if result is None or _sound(second, setup):
                    result = second
            except CalibrationError:
                pass
    if result is None:
        raise failure
    return result, setup


def _sound(result: CalibrationResult, setup: _Setup) -> bool:
    """``result``'s covariance is usable as ``calibrate`` will judge it (its reasons not to trust are set there)."""
    return result.covariance_usable and not _untrusted(result, setup)


def _from_runs(arm, camera, measurements, method, setup: _Setup, runs, anchors, options,
               memo: dict | None = None) -> CalibrationResult:
    """The result from the stage-1 runs ``(pose, stage1)`` close enough to their FK axes (:func:`_close_enough`):
    the joint fit chooses between several (:func:`choose_start`), then the method's estimate and the model checks.
    ``memo`` keeps the runs' joint fits for a later call with more runs (:func:`checked_joint`)."""
    runs, anchors = _close_enough(camera, setup, runs, anchors, options)
    alternatives = []
    if len(runs) > 1:  # the image axes cannot choose between the starts: the joint fit of the circles does
        choice = choose_start(arm, camera, measurements, setup, runs, anchors, options, memo)
        if method is Method.JOINT:
            return replace(_checked_model(arm, camera, measurements, setup, choice.stage1, choice.joint),
                           alternatives=[*choice.alternatives, *choice.joint.alternatives],
                           joint_sigma_deg=options.joint_sigma_deg, axis_floor_px=setup.floor_px,
                           track_offset_px=setup.track_offset_px)
        runs, anchors = [(runs[choice.best][0], choice.stage1)], [anchors[choice.best]]
        alternatives = choice.alternatives
    init_pose, stage1 = runs[0]
    if method is Method.JOINT:
        fitted = checked_joint(arm, camera, measurements, setup, runs[0], options, anchors[0], memo)
    else:
        fitted = _estimate(arm, camera, measurements, method, setup, stage1, init_pose, options, anchors[0])
        _check_scale(fitted.result, setup, fitted.stage1, options)
    return replace(_checked_model(arm, camera, measurements, setup, fitted.stage1, fitted.result),
                   alternatives=[*alternatives, *fitted.result.alternatives],
                   joint_sigma_deg=0.0 if method is Method.PAPER else options.joint_sigma_deg,
                   axis_floor_px=0.0 if method is Method.PAPER else setup.floor_px,
                   track_offset_px=0.0 if method is Method.PAPER else setup.track_offset_px)


def _passes(arm, camera, used, method, options, kept):
    """The calibration of the ``used`` measurements (their indices ``kept``): (result, its setup, the camera the
    last pass started from). With refined intrinsics a first pass refines the camera only (the joint fit from the
    best start); the full calibration then runs from it (its stages, starts and outlier tests see it), again while
    it moves. A refusal that two measurements in each other's place explain says so first."""
    try:
        result, setup = _calibrate(arm, camera, used, method, options, kept,
                                   camera_pass=bool(options.refine_intrinsics))
    except CalibrationError as error:
        swap = _confirmed_swap(arm, camera, used, method, options, kept)
        if swap is None:
            raise
        raise CalibrationError(f"{swap_sentence(swap)}. The calibration itself said: {error}") from error
    started = camera
    for _ in range(INTRINSICS_PASSES - 1):
        if result.camera is None or (_intrinsics_settled(result, started) and not setup.camera_pass):
            break
        started = result.camera
        result, setup = _calibrate(arm, started, used, method, options, kept, given_camera=camera)
    return result, setup, started


def _offsets_start(arm, camera, measurements, method, options, index) -> tuple[list, OffsetsPrior]:
    """The measurements with their readings shifted by the joint offsets that stage 1's image axes give
    (:func:`offsets_from_axes`, from the first start), and the :class:`OffsetsPrior` the joint fit refines."""
    if method is not Method.JOINT:
        raise InputError(f"joint offsets are refined by the joint method only, not {method.value!r}")
    names = options.joint_offsets
    joints = arm.offset_joints(True if names is True else list(names), [m.spin_joint for m in measurements])
    sigma = np.full(len(joints), np.radians(options.joint_offset_sigma_deg))
    starts, setup, anchors = _initial(arm, camera, measurements, options, index, INITIAL_TOLERANCE)
    pose, stage1 = _refined_stage1(arm, camera, measurements, starts[0], setup, options, anchors[0])
    delta, _ = offsets_from_axes(arm, camera, setup, stage1, pose, measurements, joints, sigma)
    if not np.all(np.isfinite(delta)) or np.any(np.abs(delta) > MAX_OFFSET_SIGMAS * sigma):
        named = ", ".join(f"{arm.joint_names[j]} {np.degrees(d):+.3g}°" for j, d in zip(joints, delta, strict=True))
        raise CalibrationError(f"the joint offsets that the image axes give ({named}) lie beyond "
                               f"{MAX_OFFSET_SIGMAS:g} times their prior ({options.joint_offset_sigma_deg:g}°): "
                               "check the joint angles, the intrinsics and the spinning joint, or widen "
                               "CalibrationOptions.joint_offset_sigma_deg (--joint-offset-sigma-deg) if the robot's "
                               "zero positions may be that far off")
    return shifted(arm, measurements, joints, delta), OffsetsPrior(tuple(joints), delta, sigma)


def _shapes_scale(c, explained: bool = False) -> float:
    """The scale the tracks' shapes' reading of the camera is judged at (:func:`_checked_model`): the axes' where
    their test fails and no camera change explains their scatter (``explained``), else 1."""
    return 1.0 if c is None or c.consistent or explained else max(c.scale, 1.0)


def _checked_model(arm, camera, measurements, setup: _Setup, stage1, result: CalibrationResult) -> CalibrationResult:
    """The result with its axes' test extended by :func:`modelcheck.intrinsics_check` and
    :func:`modelcheck.kinematics_check` (every measurement's axis, each at the pixel noise its report gives);
    unchanged where the axes are not tested (the paper's method, fewer than four measurements used) or a check cannot
    run. With refined intrinsics the offsets' check sees the refined camera and the intrinsics' check is not made.
    The tracks' shapes' reading of the camera (``result.intrinsics_shapes``, from the joint fit) is judged here
    (:func:`.joint._judged`), at the axes' scale where their test fails, unless a camera change explains their
    scatter. Where the axes pass, their scale is a share of their reading (``stage2.axis_excess``), not evidence that
    the tracks share errors that a camera the shapes reject would come from: judged at it, two wrong cameras of the
    intrinsics-check benchmark (focal +5 %, cy -10 px; the axes at P 0.022 and 0.013, scale 2.2 and 3.4) were called
    usable with their errors at chi-square 2.6e4 and 3.5e4."""
    c = result.axis_consistency
    shapes = result.intrinsics_shapes
    if c is None or not result.observability.is_observable:
        return result if shapes is None else replace(result, intrinsics_shapes=_judged(
            shapes, _shapes_scale(c)))
    camera = camera if result.camera is None else result.camera  # (refined intrinsics: the camera the fit found)
    sigma2 = {r.index: float(r.residual_rms_px) ** 2 for r in result.measurements
              if np.isfinite(r.residual_rms_px) and r.residual_rms_px > 0.0}
    intrinsics = None
    try:  # (refined intrinsics are in the covariance: the axes' coarser reading of them has nothing to add)
        if result.camera is None:
            intrinsics = intrinsics_check(camera, setup, stage1, result.arm_T_camera, sigma2, result.covariance,
                                          scaled=not c.consistent)
    except (np.linalg.LinAlgError, ValueError):
        intrinsics = None
    try:
        kinematics = kinematics_check(arm, camera, setup, stage1, result.arm_T_camera, sigma2,
                                      [arm.joint_angle_vector(m.joint_angles) for m in measurements],
                                      result.covariance, scaled=not c.consistent)
    except (np.linalg.LinAlgError, ValueError):
        kinematics = None
    if shapes is not None:
        # the shapes' reading at the axes' scatter that a camera change leaves: a wrong camera makes the axes
        # disagree too (focal -2 %: scale 10), and that scale would hide it
        explained = intrinsics is not None and intrinsics.get("p_value") is not None and intrinsics["dof"] > 0 \
            and intrinsics["p_value"] >= LONG_ARC_CONSISTENCY_P
        shapes = _judged(shapes, _shapes_scale(c, explained))
    return replace(result, axis_consistency=replace(c, intrinsics=intrinsics, kinematics=kinematics),
                   intrinsics_shapes=shapes)


def _paths(arm, camera, measurements, starts, anchors, setup: _Setup, options, placing: bool = False,
           after=()) -> tuple[list, list]:
    """Stage 1 refined from each start (:func:`_refined_stage1`), as runs ``(pose, stage1)`` with their anchors.
    With ``placing``, the paths whose first fit only places the pose, dropping one that ends where another or a run
    in ``after`` did (:func:`_settled`: the same minimum again)."""
    runs, kept = [], []
    for start, anchor in zip(starts, anchors, strict=True):
        pose, stage1 = _refined_stage1(arm, camera, measurements, start, setup, options, anchor, placing)
        if placing and any(_settled(pose, other) for other, _ in [*after, *runs]):
            continue
        runs.append((pose, stage1))
        kept.append(anchor)
    return runs, kept


def _close_enough(camera, setup: _Setup, runs, anchors, options) -> tuple[list, list]:
    """The runs (start, stage 1) whose FK axes, fitted to stage 1's image axes, miss them by at most
    ``max_initial_rms_px`` (RMS), with their anchors; refused (:func:`poor_start`) when none does.

    Where arcs are short, stage 1's last fit started from a pose fitted to its own earlier lines, so this check is
    partly self-consistent: it catches starts whose circles cannot be fitted near any pose (a plain hand: 41 px;
    a runaway start: 337 px), not a consistent wrong solution, which the axes' test and the evidence flags judge.
    Stage 1's first fit (from the axes through the ellipse centres) is no judge: on a rendered Jaco2 text scene
    whose result is 0.64 mm off and usable, its axes missed by 59 px."""
    misses = [axis_miss_rms(camera, setup, [s.image_axis for s in stage1], start, options)[1] for start, stage1 in runs]
    keep = [i for i, miss in enumerate(misses) if miss <= options.max_initial_rms_px]
    if not keep:
        raise poor_start(setup, min(misses, key=lambda m: m if np.isfinite(m) else np.inf), options,
                         "stage-1 image axes (coaxial circles fitted to the tracks)")
    return [runs[i] for i in keep], [anchors[i] for i in keep]


def _estimate(arm, camera, measurements, method, setup, stage1, init_pose, options, anchor) -> Fitted:
    """The paper's or the weighted estimate (the joint one is :func:`checked_joint`'s)."""
    if method is Method.PAPER:
        return Fitted(_paper(camera, setup, stage1, init_pose, options, anchor), stage1)
    return _weighted(arm, camera, measurements, setup, stage1, init_pose, options, anchor)

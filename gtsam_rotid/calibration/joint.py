"""The joint estimator: every track's circle factors and the projected-axis ties in one graph on the pose, its
sandwich covariance, and restarts. With the rigid spin (``CalibrationOptions.spin_model``) the builder gives each
measurement a rigid-spin factor instead of the free-phase one (:class:`gtsam_rotid.graph.SpinModel`).
"""

from __future__ import annotations

from dataclasses import replace
from typing import NamedTuple

import gtsam
import numpy as np

from ..camera import Camera
from ..errors import RotIdError
from ..factors import (
    RigidLineFactor,
    axis_point_residuals,
    cal3_s2,
    image_line_from_rot3,
    readings_cover,
    rot3_from_line,
)
from ..graph import (
    Model,
    SpinModel,
    align_line,
    axis_in_camera,
    axis_test_points,
    chi2_quantile,
    track_huber,
)
from ..uncertainty import (
    chi2_sf,
    joint_marginal_covariance,
    meat_marginals,
    pose_information,
    sandwich_marginal,
)
from .evidence import axis_misses, measurement_reports
from .lm import _builder, _graph_dof, _lm, _turned
from .modelcheck import MIN_CENTRE_PX, MIN_FOCAL_PERCENT
from .offsets import determined_offsets
from .opinion import _second_opinion
from .options import INTRINSICS, CalibrationError, Method
from .result import CalibrationResult
from .stage1 import (
    FitRejection,
    _circles,
    _noise_variance,
    _Stage1,
    _track_correlation,
    _track_offset_meat,
    _track_stats,
    _without_tracks,
)
from .stage2 import (
    _axis_consistency,
    _axis_floors,
    _axis_offsets,
    _axis_rows,
    _finish,
    _prior_floor_covariance,
    _robust_weighted,
    _shift_covariance,
    _Solved,
    _Stage2,
    _tied_circles,
    _weighted_stage2,
    _with_axis_covariances,
)
from .tuning import (
    DATING_NOISE_MAX,
    DISTINCT_Z,
    FK_START_TILT_DEG,
    HELD_INTRINSIC_PX,
    INTRINSICS_KEY,
    MIN_STRONG,
    NOT_TURNING_RATIO,
    POSE_KEY,
    READINGS_OFFSET_SIGMAS,
    READINGS_OFFSET_STEP_S,
    READINGS_START_Z,
    READINGS_Z,
    RESTART_LEAVE_OUT,
    RESTART_P,
    RESTART_SAME_M,
    SAME_ANGLE_DEG,
    SHAPES_Z,
    TIME_KEY,
    WATCH_POSE,
)


class Fitted(NamedTuple):
    """A result and the stage-1 fits it was made from (second opinions may have replaced some of the fits passed in):
    the scale check reads their circles, and with several starts the chosen start's fits go on to the paper's or the
    weighted method."""

    result: CalibrationResult
    stage1: list[_Stage1]


def _disagreeing(stage1, used, evidence) -> list[int]:
    """The measurements a fit left out because their axes disagree (not thin ones it dropped)."""
    return [k for k in range(len(stage1)) if k not in used and k not in evidence.dropped]


def _opinion(arm, camera, measurements, setup, options):
    return lambda k, pose, stage1: _second_opinion(arm, camera, measurements, setup, stage1, k, pose, options)


def _weighted(arm, camera, measurements, setup, stage1, init_pose, options, anchor) -> Fitted:
    fit = _robust_weighted(camera, setup, stage1, init_pose, options, anchor,
                           _opinion(arm, camera, measurements, setup, options))
    stage1, used = fit.stage1, fit.used
    values = gtsam.Values()
    values.insert(POSE_KEY, fit.pose)
    sigmas = {k: float(np.sqrt(s.sigma2)) for k, s in enumerate(stage1)}
    tied = _tied_circles(arm, camera, measurements, setup, stage1, fit.pose, options, range(len(stage1)))
    misses = axis_misses(arm, measurements, setup, stage1, camera, fit.pose, _disagreeing(stage1, used, fit.evidence))
    reports = measurement_reports(stage1, setup, fit.evidence, sigmas, used, options, fit.chi2, tied, misses)
    variances = {k: stage1[k].sigma2 for k in used}
    rows = _axis_rows(camera, setup, stage1, used, fit.pose, variances)  # (one pass for the three below)
    axis_offsets = _axis_offsets(camera, setup, stage1, used, fit.pose)
    floors = _axis_floors(setup, axis_offsets, len(used))
    _with_axis_covariances(reports, used, rows, axis_offsets)
    consistency = _axis_consistency(rows, floors, options)
    solved = _Solved(fit.pose, None, pose_information(fit.graph, values, POSE_KEY), Method.WEIGHTED, True,
                     fit.iterations, fit.graph.error(values))
    result = _finish(solved, reports, np.median([sigmas[k] for k in used]), dof=_graph_dof(fit.graph, values),
                     consistency=consistency, prior=_prior_floor_covariance(rows, floors),
                     shift=_shift_covariance(rows))
    return Fitted(replace(result, alternatives=_outside(fit.alternatives, result)), stage1)


def _joint(arm, camera, measurements, setup, stage1, init_pose, options, anchor) -> Fitted:
    """One graph: every circle-point factor (Huber per track) tied to the pose; Marginals of the whole graph.

    It starts from the weighted two-stage pose, within the joint problem's basin (from a few degrees off,
    circles of short arcs can run off to degenerate solutions that LM cannot leave), with the circles
    fitted at that pose (``"line"`` model: the stage-1 lines and circles, see RotIdGraph.add_measurement).
    """
    opinion = _opinion(arm, camera, measurements, setup, options)
    fit = _robust_weighted(camera, setup, stage1, init_pose, options, anchor, opinion)
    result = _joint_fit(arm, camera, measurements, setup, fit, options)
    if setup.camera_pass:  # (only the refined camera is wanted: the next pass starts from it)
        return Fitted(result, fit.stage1)
    c = result.axis_consistency
    weak = fit.evidence.weak
    weak_used = [k for k in fit.used if k in weak]
    strong_enough = bool(weak_used) and len([k for k in fit.used if k not in weak]) >= MIN_STRONG
    if c is None or (c.p_value >= RESTART_P and (c.consistent or not strong_enough)):
        return Fitted(result, fit.stage1)
    if strong_enough:
        # the axes disagree and weak measurements take part: fit the strong ones alone (the weak are named). A
        # weak axis far off its own wide 1 sigma would otherwise set the scale or the common floor of them all
        # (one 3-track pose 70 px off made a floor of 21 px and a 1 sigma of 158 mm on a good estimate)
        strong_fit = _robust_weighted(camera, setup, fit.stage1, fit.pose, options, anchor, opinion, drop_weak=True)
        strong_fit = strong_fit._replace(iterations=result.iterations + strong_fit.iterations)
        strong = _joint_fit(arm, camera, measurements, setup, strong_fit, options)
        # (unless most of the weak ones refute the strong ones' pose: then it is no answer nor a place to restart)
        supported = _weak_agree(opinion, strong_fit, strong.arm_T_camera, options)
        if supported and (strong.axis_consistency is None or strong.axis_consistency.p_value >= RESTART_P):
            return Fitted(strong, strong_fit.stage1)
        if result.axis_consistency.p_value >= RESTART_P:  # the strong ones alone disagree no less
            return Fitted(result, fit.stage1)
        if supported:
            result, fit = strong, strong_fit
    return _restarted(arm, camera, measurements, setup, fit, result, options, anchor)


def _weak_agree(opinion, strong_fit: _Stage2, pose: gtsam.Pose3, options) -> bool:
    """Whether the weak measurements a strong-only fit left out mostly agree with its pose ``pose``: at most half of
    them beyond the outlier limit by their second ``opinion`` (:func:`_opinion`, :func:`_second_opinion`: the
    likelihood ratio of the measurement's circles with the line tied to the FK axis seen from ``pose`` against free,
    which holds where their short arcs make the linearised test meaningless).

    Few strong measurements (four determine the pose with two to spare) can agree on a wrong pose: 24 poses of 2 s
    spins, where 20 were weak and three of the four strong ones had image axes 29-53 chi-square off the truth
    (circles of short arcs fitted too small read as long arcs), were answered 366 mm and 22 degrees off, with all
    twenty weak measurements called outliers; the fit of all of them was 2.6 mm off. Outliers are a minority: when
    most of the evidence refutes the strong ones' pose, that pose is no answer.
    """
    dropped = sorted(strong_fit.evidence.dropped)
    if not dropped:
        return True
    limit = options.outlier_measurement_chi2
    refuted = [k for k in dropped if not opinion(k, pose, strong_fit.stage1)[1] <= limit]
    return 2 * len(refuted) <= len(dropped)


def _restarted(arm, camera, measurements, setup, fit: _Stage2, result: CalibrationResult, options,
               anchor) -> Fitted:
    """When the measurements disagree with the joint estimate ``result`` (of ``fit``) far beyond their noise, the
    estimate may be a local minimum that weak measurements (few tracks, short arcs) led stage 2 into: fit again from
    the stage-2 pose without each measurement in turn, and keep the fit of lowest chi-square on the same tracks (then
    re-test the measurements left out, which a wrong estimate blames)."""
    candidates = [result]
    used, chi2, stage1 = fit.used, fit.chi2, fit.stage1
    worst = sorted(used, key=lambda k: -chi2.get(k, 0.0))[:RESTART_LEAVE_OUT]
    for k in worst:
        rest = [i for i in used if i != k]
        start, _, _ = _weighted_stage2(camera, setup, stage1, rest, result.arm_T_camera, options, anchor)
        if _turned(start, result.arm_T_camera) < np.radians(SAME_ANGLE_DEG) and np.linalg.norm(
                start.translation() - result.arm_T_camera.translation()) < RESTART_SAME_M:
            continue
        try:
            candidates.append(_joint_fit(arm, camera, measurements, setup, fit._replace(pose=start, iterations=0),
                                         options))
        except (CalibrationError, RotIdError, RuntimeError):
            continue
    if len(candidates) > 1:
        costs = common_chi2(arm, camera, measurements, setup, candidates, options)[0]
        best = candidates[int(np.argmin(costs))]
    else:
        best = candidates[0]
    iterations = sum(c.iterations for c in candidates)
    left_out = [k for k in range(len(stage1)) if k not in used and k not in fit.evidence.dropped]
    opinions = {k: _second_opinion(arm, camera, measurements, setup, stage1, k, best.arm_T_camera, options)
                for k in left_out}
    back = [k for k, (_, statistic) in opinions.items() if statistic <= options.outlier_measurement_chi2]
    if back:
        chi2, stage1 = dict(chi2), list(stage1)
        for k in back:
            refit, chi2[k] = opinions[k]
            if refit is not None:
                stage1[k] = refit
        try:
            best = _joint_fit(arm, camera, measurements, setup, fit._replace(
                pose=best.arm_T_camera, iterations=0, used=sorted(used + back), chi2=chi2, stage1=stage1), options)
        except (CalibrationError, RotIdError, RuntimeError):
            stage1 = fit.stage1
        iterations += best.iterations
    return Fitted(replace(best, iterations=iterations), stage1)


def _joint_fit(arm, camera, measurements, setup, fit: _Stage2, options) -> CalibrationResult:
    """The joint graph of the measurements ``fit.used`` from ``fit.pose``, with ``fit.stage1``'s lines and circles
    and their pixel noise to start (see :func:`_joint`)."""
    pose, iterations, used, chi2, stage1 = fit.pose, fit.iterations, fit.used, fit.chi2, fit.stage1
    offsets = setup.offsets
    intrinsics = _IntrinsicsPrior.of(camera, setup, options)
    sync = _Sync.of(measurements, used, options)
    uncovered = {} if sync is None else _uncovered_readings(measurements, sync)
    if uncovered:  # readings that do not cover a spin's frames: that spin fitted without them
        return _without_readings(arm, camera, measurements, setup, fit, options, uncovered)
    builder = _builder(arm, camera, options, robust=track_huber, model=options.joint_model,
                       spin_model=options.spin_model, joint_offsets=None if offsets is None else offsets.names(arm),
                       intrinsics_key=None if intrinsics is None else INTRINSICS_KEY, **_sync_kwargs(sync))
    rest = None if offsets is None else np.zeros(len(offsets.joints))  # the offsets beyond offsets.start (rad)
    sigmas = {k: float(np.sqrt(stage1[k].sigma2)) for k in used}
    circles = {k: None if builder.model is Model.POSE else dict(stage1[k].circles) for k in used}
    lines = {k: stage1[k].rotation for k in used}
    converged, solved = True, None
    # Rigid spins start about the FK axis seen from the stage-2 pose (their circles from their tracks' rays) where
    # that fits them better than stage 1's line and circles: the line's tilt within its projection plane, which the
    # tie leaves to the circles alone, is where stage 1's free phases and the rigid spin differ most (2-11
    # degrees on simulated poses seen obliquely, where a first step from stage 1's tilt overshot until LM had
    # damped it: five tries of every measurement's inner solve at 48 poses), while a stage-2 pose far off (short
    # arcs) puts the FK axis where no spin fits. Not synced: the readings' tests at the start (READINGS_START_Z) read
    # stage 1's line and circles (readings that never move pull a spin started about the FK axis less).
    start = [k for k in used if sync is None and builder.spin_model is SpinModel.RIGID and lines[k] is not None
             and all(t.frames is not None for t in setup.prepared[k].usable.values())
             and _tilt_apart_deg(arm, measurements[k], pose, lines[k]) > FK_START_TILT_DEG]
    if start:
        _, fk_values, fk_keys = _joint_graph(builder, camera, measurements, setup, stage1, start, pose, sigmas,
                                             circles, lines, fk_start=start, rest=rest, intrinsics=intrinsics,
                                             sync=sync)
        _, s1_values, s1_keys = _joint_graph(builder, camera, measurements, setup, stage1, start, pose, sigmas,
                                             circles, lines, rest=rest, intrinsics=intrinsics, sync=sync)
        kept = [k for k in start if not fk_keys[k].coaxial.error(fk_values) < s1_keys[k].coaxial.error(s1_values)]
        start = [k for k in start if k not in kept]
        # each starts from its solution in the graph it fitted better in (the others as stage 1 left them)
        solved = {**_solved(s1_keys, s1_values, kept), **_solved(fk_keys, fk_values, start)}
    for _round in range(3):
        graph, values, keys = _joint_graph(builder, camera, measurements, setup, stage1, used, pose, sigmas, circles,
                                           lines, fk_start=start, rest=rest, intrinsics=intrinsics, sync=sync,
                                           solved=solved)
        # A rigid spin whose inner solve does not converge about its start line (stage 1's or the last round's) is
        # started again about the FK axis seen from the pose where that fits it better. Stage 1's free phases can
        # fit thin ellipses (minor semi-axes of 2-4 px at 1.2 px noise) about a line whose tilt is far off (14
        # degrees on a Panda pose), where no rigid spin fits: its residuals ran to hundreds of px, its weight (their
        # variance) vanished, and the pose was left wherever LM stalled, between the stage-2 pose and the other
        # measurements' fit, under a covariance that no longer counted it (8.5 sigma off, "usable").
        unfit = [k for k in used if lines[k] is not None and k not in start
                 and isinstance(keys[k].coaxial, RigidLineFactor) and not np.all(keys[k].coaxial.converged(values))]
        if unfit:
            _, fk_values, fk_keys = _joint_graph(builder, camera, measurements, setup, stage1, unfit, pose, sigmas,
                                                 circles, lines, fk_start=unfit, rest=rest, intrinsics=intrinsics,
                                                 sync=sync)
            better = [k for k in unfit if fk_keys[k].coaxial.error(fk_values) < keys[k].coaxial.error(values)]
            for k in better:
                lines[k] = circles[k] = None
            if better:
                # their spins start from the solutions just found about the FK axis, not from scratch; synced, from
                # scratch (those solutions followed the readings, which the readings' test at the start would read)
                solved = {k: v for k, v in (solved or {}).items() if k not in better}
                if sync is None:
                    solved.update(_solved(fk_keys, fk_values, better))
                graph, values, keys = _joint_graph(builder, camera, measurements, setup, stage1, used, pose, sigmas,
                                                   circles, lines, fk_start=start, rest=rest, intrinsics=intrinsics,
                                                   sync=sync, solved=solved)
        turning = _not_turning(keys, values)
        if turning:  # tracks the rigid spin cannot fit: left out (named), the round's graph built again without them
            stage1 = [s if k not in turning else _without_tracks(s, turning[k]) for k, s in enumerate(stage1)]
            graph, values, keys = _joint_graph(builder, camera, measurements, setup, stage1, used, pose, sigmas,
                                               circles, lines, fk_start=start, rest=rest, intrinsics=intrinsics,
                                               sync=sync, solved=solved)
        start, solved = (), None
        if _round == 0 and sync is not None:  # grossly wrong readings (see below), where the fit starts
            refused = _disagreeing_readings(keys, values, sync, READINGS_START_Z, profile_offset=True)
            if refused:
                return _without_readings(arm, camera, measurements, setup, fit, options, refused)
        start_pose = pose
        result, it, error, converged = _lm(
            graph, values, options.max_iterations, anchor=True, watch_tolerance=WATCH_POSE,
            watch=lambda v, start_pose=start_pose: start_pose.localCoordinates(v.atPose3(POSE_KEY)))
        if _round == 0 and sync is not None:
            # readings that disagree with the spin the tracks show, tested at the first synced fit against free
            # angles started from stage 1's circles (which no reading moved: readings that never move drag the
            # synced circles where no spin fits): those spins fitted without them
            refused = _disagreeing_readings(keys, result, sync, READINGS_Z)
            if refused:
                return _without_readings(arm, camera, measurements, setup, fit, options, refused)
        iterations += it
        pose = result.atPose3(POSE_KEY)
        if offsets is not None:
            rest = np.asarray(result.atVector(builder.offsets_key), dtype=float)
        if intrinsics is not None:
            intrinsics = intrinsics._replace(now=result.atCal3_S2(INTRINSICS_KEY))
        if sync is not None and sync.sigma is not None:
            sync = sync._replace(now=tuple(float(result.atVector(sync.key(i))[0]) for i in range(len(sync.clocks))))
        new_sigmas = {k: float(np.sqrt(_joint_variance(graph, keys[k], result, options))) for k in used}
        failed = [setup.index[k] if setup.index else k for k in used if not np.isfinite(new_sigmas[k])]
        if failed:
            raise CalibrationError(f"the joint fit failed: the circles of measurement(s) {failed} have no finite "
                                   "residuals at the estimate (too little evidence: few tracks or short arcs)")
        circles = {k: dict(zip(keys[k].tracks, _circles(keys[k], result), strict=True)) for k in used}
        lines = {k: None if keys[k].line_key is None else result.atRot3(keys[k].line_key) for k in used}
        solved = _solved(keys, result)  # a next round's spins start from their solutions here (its noise is new)
        stable = all(abs(new_sigmas[k] / sigmas[k] - 1.0) < 0.05 for k in used)
        sigmas = new_sigmas
        if stable:
            break
    info = pose_information(graph, result, POSE_KEY)
    if intrinsics is not None:  # everything after the fit sees the refined camera (the others exactly as given)
        refined = Camera(intrinsics.now.K(), camera.width, camera.height).intrinsics
        camera = intrinsics.given.with_intrinsics({n: refined[n] for n in options.refine_intrinsics})
    tied = _tied_circles(arm, camera, measurements, setup, stage1, pose, options, range(len(stage1)))
    misses = axis_misses(arm, measurements, setup, stage1, camera, pose, _disagreeing(stage1, used, fit.evidence))
    reports = measurement_reports(stage1, setup, fit.evidence, sigmas, used, options, chi2, tied, misses)
    variances = {k: sigmas[k] ** 2 for k in used}
    rows = _axis_rows(camera, setup, stage1, used, pose, variances)  # (one pass for the three below)
    axis_offsets = _axis_offsets(camera, setup, stage1, used, pose)
    _with_axis_covariances(reports, used, rows, axis_offsets)
    try:
        covariance = gtsam.Marginals(graph, result).marginalCovariance(POSE_KEY)
    except RuntimeError:
        # GTSAM's Cholesky also gives up on a nuisance variable that is only nearly indeterminate (an offset that
        # turns the arm as the pose does, held by its prior alone: the intrinsics' covariance and the sandwich were
        # then lost on 6 poses planned for offsets and intrinsics); the dense marginal is None where the pose
        # itself is indeterminate, which the observability analysis of ``info`` then says
        covariance = joint_marginal_covariance(graph, result, [POSE_KEY], 6)
    correlated = _meats(keys, result, stage1, sigmas, used, setup.track_offset_px)
    if covariance is not None and correlated:  # errors shared along a track: the cluster-robust covariance
        robust = sandwich_marginal(graph, result, POSE_KEY, 6, correlated)
        covariance = covariance if robust is None else robust
    intrinsics_covariance = None
    if intrinsics is not None and covariance is not None:  # (the image axes' prior floor moves them too)
        full = sandwich_marginal(graph, result, INTRINSICS_KEY, 5,
                                 _with_floor(correlated, camera, setup, keys, used, result))
        if full is not None:
            chosen = intrinsics.indices
            intrinsics_covariance = full[np.ix_(chosen, chosen)]
    shapes = None
    if intrinsics is None and covariance is not None:
        shapes = _intrinsics_shapes(arm, camera, measurements, setup, stage1, used, result, keys, sigmas, circles,
                                    lines, options, rest, sync)
    solved = _Solved(pose, covariance, info, Method.JOINT, converged, iterations, error)
    projected = sum(keys[k].coaxial.inner_dof for k in used if keys[k].coaxial is not None)
    offsets_covariance, cross, determined = None, None, 0
    if offsets is not None:
        both = joint_marginal_covariance(graph, result, [POSE_KEY, builder.offsets_key], 6 + len(offsets.joints))
        if both is not None:  # (None: indeterminate; the offsets then count as undetermined)
            offsets_covariance, cross = both[6:, 6:], both[:6, 6:]
            robust = sandwich_marginal(graph, result, builder.offsets_key, len(offsets.joints), correlated) \
                if correlated else None
            if robust is not None:  # cluster-robust, as the pose's
                offsets_covariance = robust
        determined = determined_offsets(offsets_covariance, offsets.sigma)
    prior, shift = _prior_floor_covariance(rows, _axis_floors(setup, None, len(used))), _shift_covariance(rows)
    nuisance = _nuisance_blocks(graph, result, camera, setup, keys, used, builder, offsets, intrinsics) \
        if covariance is not None else None
    if nuisance is not None:  # the refined offsets or intrinsics take up part of the floor and of a shift too
        shift, floor = nuisance["shift"][0], nuisance.get("floor")
        if floor is not None:
            prior = floor[0]
            if offsets_covariance is not None and "offsets" in floor[1]:
                offsets_covariance, cross = offsets_covariance + floor[1]["offsets"], cross + floor[1]["cross"]
    out = _finish(solved, reports, np.median(list(sigmas.values())), dof=_graph_dof(graph, result) - projected,
                  consistency=_axis_consistency(rows, _axis_floors(setup, axis_offsets, len(used)), options,
                                                fitted=determined),
                  prior=prior, shift=shift)
    if nuisance is not None:
        blocks = nuisance["shift"][1]
        if intrinsics is not None and "intrinsics" in blocks:
            chosen = intrinsics.indices
            blocks["intrinsics"] = blocks["intrinsics"][np.ix_(chosen, chosen)]
        out = replace(out, image_shift_nuisance=dict(blocks))
    if shapes is not None:  # (judged, at the axes' scale that a camera change leaves, by run._checked_model)
        out = replace(out, intrinsics_shapes=shapes)
    if intrinsics is not None:
        c = out.axis_consistency
        if intrinsics_covariance is not None and c is not None:
            intrinsics_covariance = intrinsics_covariance * max(c.scale, 1.0)  # the axes' scatter scales them too
        given = intrinsics.given.intrinsics
        out = replace(out, refined_intrinsics=options.refine_intrinsics, camera=camera,
                      intrinsics_covariance=intrinsics_covariance, intrinsics_prior_sigma=options.intrinsics_sigma,
                      given_intrinsics={n: given[n] for n in options.refine_intrinsics})
    if sync is not None:
        clocks = [_time_offset_sigma(graph, result, sync, i, correlated, out, keys) for i in range(len(sync.clocks))]
        out = replace(out, synced=sync.measurements, time_offset_prior_sigma_s=sync.sigma)
        if len(clocks) == 1:  # (one clock: the offset of every synced spin)
            out = replace(out, time_offset_s=-sync.now[0], **clocks[0])
        if sync.clocks != (None,):  # named clocks (videos placed one by one): each its offset
            out = replace(out, time_offsets={
                str(c): {"offset_s": -now, "sigma_s": d["time_offset_sigma_s"],
                         "noise_share": d.get("time_offset_noise_share"),
                         "measurements": [k for k, i in zip(sync.measurements, sync.clock_of, strict=True) if i == n]}
                for n, (c, now, d) in enumerate(zip(sync.clocks, sync.now, clocks, strict=True))})
    if offsets is not None:
        c = out.axis_consistency
        if offsets_covariance is not None and c is not None:
            offsets_covariance = offsets_covariance * max(c.scale, 1.0)  # the axes' scatter scales them too
            cross = cross * max(c.scale, 1.0)
        values = dict(zip(offsets.names(arm), (offsets.start + rest).tolist(), strict=True))
        origins = {}
        for name, value in values.items():  # the URDF <origin> that makes the reading the joint's angle
            origin = arm.corrected_joint_origin(name, value)
            origins[name] = {"xyz": np.asarray(origin.translation(), dtype=float).tolist(),
                             "rpy": np.asarray(origin.rotation().rpy(), dtype=float).tolist()}
        out = replace(out, joint_offsets=values, joint_offsets_origins=origins,
                      joint_offsets_covariance=offsets_covariance, pose_offsets_covariance=cross,
                      joint_offset_sigma_deg=float(np.degrees(offsets.sigma[0])))
    return replace(out, alternatives=_outside(fit.alternatives, out))


def _without_readings(arm, camera, measurements, setup, fit: _Stage2, options, refused: dict) -> CalibrationResult:
    """:func:`_joint_fit` again with the readings of the measurements ``refused`` (measurement -> why) left out, and
    those named in ``readings_refused``."""
    kept = [m if k not in refused else m.replace(spin_readings=None) for k, m in enumerate(measurements)]
    out = _joint_fit(arm, camera, kept, setup, fit, options)
    return replace(out, readings_refused={**refused, **out.readings_refused})


def _uncovered_readings(measurements, sync: _Sync) -> dict[int, dict]:
    """The synced measurements whose readings do not cover their tracks' frames at the offset ``sync.now``:
    measurement -> {"why": "cover", "readings": [first, last] (s, encoder's clock), "frames": [first, last] (s, on
    the encoder's clock at that offset)}."""
    out = {}
    for k in sync.measurements:
        m = measurements[k]
        frames = np.concatenate([t.frames for t in m.tracks if t.frames is not None])
        times = m.spin_readings.frame_times[frames] + sync.offset(k)
        first, last = float(m.spin_readings.times[0]), float(m.spin_readings.times[-1])
        if not readings_cover(times, m.spin_readings.times):
            out[k] = {"why": "cover", "readings": [first, last], "frames": [float(times.min()), float(times.max())]}
    return out


def _disagreeing_readings(keys, result: gtsam.Values, sync: _Sync, z: float,
                          profile_offset: bool = False) -> dict[int, dict]:
    """The synced measurements whose readings disagree with their tracks' spin at ``result``: the
    likelihood ratio of the readings' prior (``RigidLineFactor.readings_test``) beyond its chi-square's point at
    the normal's ``z``. measurement -> {"chi2", "dof"}. With ``profile_offset`` (the start, where no offset has been
    estimated), a measurement beyond that point is tested again at its clock's best offset
    (:func:`_best_offset_chi2`)."""
    out = {}
    for k in sync.measurements:
        factor = keys[k].coaxial if k in keys else None
        measured = factor.readings_test(result) if isinstance(factor, RigidLineFactor) else None
        if measured is None:
            continue
        chi2, dof = measured
        limit = chi2_quantile(max(dof, 1), z)
        if chi2 > limit and profile_offset:
            chi2 = min(chi2, _best_offset_chi2(factor, result, sync))
        if chi2 > limit:
            out[k] = {"chi2": chi2, "dof": dof}
    return out


def _best_offset_chi2(factor: RigidLineFactor, values: gtsam.Values, sync: _Sync) -> float:
    """The readings' test (``readings_test``) at the offset of the factor's clock that reconciles them best within
    READINGS_OFFSET_SIGMAS prior sigmas of its value in ``values`` (a grid of READINGS_OFFSET_STEP_S, then a tenth
    of it about the best); inf where the offset is held or the factor has none. At the start the offset is where the
    recording put the frames: a video placed 24 ms off (a third of a frame at 15 fps) tested at chi-square 1 660 for
    65 frames there, beyond the start's point (1 353), and at 4.7e2 20 ms on; after the first synced fit, 16."""
    if sync.sigma is None or factor.time_key is None:
        return float("inf")
    now = float(values.atVector(factor.time_key)[0])

    def tested(offsets) -> list[tuple[float, float]]:
        out = []
        for offset in offsets:
            shifted = gtsam.Values(values)
            shifted.update(factor.time_key, np.array([offset]))
            measured = factor.readings_test(shifted)
            value = float("inf") if measured is None else float(measured[0])
            out.append((value if np.isfinite(value) else float("inf"), float(offset)))
        return out

    reach = READINGS_OFFSET_SIGMAS * sync.sigma
    best = min(tested(now + np.arange(-reach, reach + 0.5 * READINGS_OFFSET_STEP_S, READINGS_OFFSET_STEP_S)))
    fine = 0.1 * READINGS_OFFSET_STEP_S
    return min(best, *tested(best[1] + fine * np.arange(-9, 10)))[0]


def _time_offset_sigma(graph, result: gtsam.Values, sync: _Sync, i: int, correlated: dict, out: CalibrationResult,
                       keys) -> dict:
    """Clock ``i``'s estimated time offset's 1 sigma (s, ``time_offset_sigma_s``) and the share of its information
    that its readings' own noise makes (``time_offset_noise_share``): its cluster-robust marginal (as the pose's),
    scaled as the pose's where the axes' scatter scaled it; where the noise makes more than DATING_NOISE_MAX of the
    information (or nothing measures it), the prior's sigma (the readings cannot date the frames), else widened for
    the pull towards the prior's mean that noise in the offset's column gives (errors in variables: the estimate
    moves from the mean by 1 - share of the true offset's distance). None where held or indeterminate."""
    if sync.sigma is None:
        return {"time_offset_sigma_s": None}
    try:
        variance = sandwich_marginal(graph, result, sync.key(i), 1, correlated) if correlated else None
        if variance is None:
            variance = gtsam.Marginals(graph, result).marginalCovariance(sync.key(i))
    except RuntimeError:
        return {"time_offset_sigma_s": None}
    c = out.axis_consistency
    scale = max(c.scale, 1.0) if c is not None else 1.0
    variance = float(np.asarray(variance).reshape(-1)[0]) * scale
    dated = [keys[k].coaxial.dating(result) for k, n in zip(sync.measurements, sync.clock_of, strict=True)
             if n == i and k in keys and isinstance(keys[k].coaxial, RigidLineFactor)]
    dated = [d for d in dated if d is not None]
    information = sum(d[0] for d in dated)
    share = min(sum(d[1] for d in dated) / information, 1.0) if information > 0 else 1.0
    if not (np.isfinite(share) and np.isfinite(variance)):
        share = 1.0  # (no measure of what dates the frames: they are not taken as dated)
    if share > DATING_NOISE_MAX:
        return {"time_offset_sigma_s": float(sync.sigma), "time_offset_noise_share": share}
    pull = share / (1.0 - share) * (sync.now[i] - sync.mean)
    return {"time_offset_sigma_s": float(np.sqrt(variance / (1.0 - share) + pull**2)),
            "time_offset_noise_share": share}


def _intrinsics_shapes(arm, camera, measurements, setup, stage1, used, result: gtsam.Values, keys, sigmas, circles,
                       lines, options, rest, sync: _Sync | None = None) -> dict | None:
    """What the tracks' shapes say of the camera as given, at the joint estimate ``result`` (fixed intrinsics): the
    same graph with the intrinsics free under their prior (``options.intrinsics_sigma`` about the camera's),
    linearised at the estimate (its ``circles`` and ``lines`` there). Its Gauss-Newton step's intrinsics
    (``change``, px) and their cluster-robust 1 sigma there (with the image axes' prior floor, :func:`_floor_meat`),
    restricted to one focal length (``fx`` and ``fy`` in proportion: ``focal_percent`` and its sigma), ``cx`` and
    ``cy`` (``change`` and ``sigma`` per name, px), its Wald ``chi2`` (``dof`` 3) and ``p_value`` (``flagged`` and
    the scale by :func:`_judged`); and what the pose assumes (``mm_per_focal_percent``, ``deg_per_focal_percent``:
    the pose's change, given the data, with both focal lengths 1 % larger; ``mm_per_centre_px``,
    ``deg_per_centre_px``: the larger of cx's and cy's per px). None where it cannot be made (free-phase
    measurements: the intrinsics need the rigid spin; or a singular system)."""
    if not all(isinstance(keys[k].coaxial, RigidLineFactor) for k in used):
        return None
    free = replace(options, refine_intrinsics=INTRINSICS)
    prior = _IntrinsicsPrior.of(camera, setup, free)
    offsets = setup.offsets
    builder = _builder(arm, camera, free, robust=track_huber, model=free.joint_model, spin_model=free.spin_model,
                       joint_offsets=None if offsets is None else offsets.names(arm), intrinsics_key=INTRINSICS_KEY,
                       **_sync_kwargs(sync))
    pose = result.atPose3(POSE_KEY)
    try:
        graph, values, free_keys = _joint_graph(builder, camera, measurements, setup, stage1, used, pose, sigmas,
                                                circles, lines, rest=rest, intrinsics=prior, sync=sync,
                                                solved=_solved(keys, result))
        # the meats again, in this graph: where a factor has the intrinsics, its meat spans them too
        extra = _with_floor(_meats(free_keys, values, stage1, sigmas, used, setup.track_offset_px), camera, setup,
                            free_keys, used, values)
        step = np.asarray(graph.linearize(values).optimize().at(INTRINSICS_KEY))
        covariance = sandwich_marginal(graph, values, INTRINSICS_KEY, 5, extra)
        both = joint_marginal_covariance(graph, values, [POSE_KEY, INTRINSICS_KEY], 11)
    except (RuntimeError, RotIdError):
        return None
    if covariance is None or both is None:
        return None
    chosen = prior.indices  # fx, fy, cx, cy in Cal3_S2's tangent
    change, covariance = step[chosen], covariance[np.ix_(chosen, chosen)]
    K = camera.K
    # tested along one focal length (fx and fy in proportion), cx and cy: the aspect ratio, which the ellipses'
    # shapes pin far more tightly than the focal length, is left out (on a rendered text-covered Jaco2 scene a 0.15 %
    # difference between fx and fy, 0.05 sigma of either, made a 4-dof chi-square of 16.6)
    A = np.array([[K[0, 0], 0.0, 0.0], [K[1, 1], 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]])
    try:
        W = np.linalg.solve(covariance, A)
        information = A.T @ W
        restricted = np.linalg.solve(information, W.T @ change)  # (focal fraction, cx, cy)
        chi2 = float(restricted @ information @ restricted)
        # the pose's change given the data per change of the intrinsics (the prior on them does not enter)
        response = both[:6, 6:][:, chosen] @ np.linalg.inv(both[6:, 6:][np.ix_(chosen, chosen)])
        sigma = np.sqrt(np.diag(np.linalg.inv(information)))
    except np.linalg.LinAlgError:
        return None
    if not np.isfinite(chi2) or not np.all(np.isfinite(response)):
        return None
    change = A @ restricted
    focal = response @ np.array([0.01 * K[0, 0], 0.01 * K[1, 1], 0.0, 0.0])
    centre = [response[:, 2], response[:, 3]]
    return {"chi2": chi2, "dof": 3, "p_value": float(chi2_sf(chi2, 3)), "flagged": False, "scale": 1.0,
            "change": dict(zip(INTRINSICS, change.tolist(), strict=True)),
            "sigma": dict(zip(INTRINSICS, [sigma[0] * K[0, 0], sigma[0] * K[1, 1], sigma[1], sigma[2]], strict=True)),
            "focal_percent": 100.0 * float(restricted[0]), "focal_percent_sigma": 100.0 * float(sigma[0]),
            "mm_per_focal_percent": 1000.0 * float(np.linalg.norm(focal[3:])),
            "deg_per_focal_percent": float(np.degrees(np.linalg.norm(focal[:3]))),
            "mm_per_centre_px": 1000.0 * max(float(np.linalg.norm(c[3:])) for c in centre),
            "deg_per_centre_px": float(np.degrees(max(float(np.linalg.norm(c[:3])) for c in centre)))}


def _judged(shapes: dict, scale: float) -> dict:
    """:func:`_intrinsics_shapes`' reading with its covariance scaled by ``scale`` instead of its own ``scale`` (the
    axes' scatter that a camera change does not explain, see ``run._checked_model``: errors that a measurement's
    tracks share, which the shapes' covariance does not count, move the intrinsics' reading too: four measurements
    each shifted by 4 px had asked for another camera), and ``flagged``: beyond the ``SHAPES_Z`` point and a change
    that matters (``MIN_FOCAL_PERCENT``, ``MIN_CENTRE_PX``)."""
    ratio = scale / shapes["scale"]
    out = dict(shapes, scale=scale, chi2=shapes["chi2"] / ratio,
               sigma={k: v * np.sqrt(ratio) for k, v in shapes["sigma"].items()},
               focal_percent_sigma=shapes["focal_percent_sigma"] * np.sqrt(ratio))
    out["p_value"] = float(chi2_sf(out["chi2"], out["dof"]))
    size = (abs(out["focal_percent"]) >= MIN_FOCAL_PERCENT
            or max(abs(out["change"]["cx"]), abs(out["change"]["cy"])) >= MIN_CENTRE_PX)
    out["flagged"] = bool(out["chi2"] > chi2_quantile(out["dof"], SHAPES_Z) and size)
    return out


def _meats(keys, values: gtsam.Values, stage1, sigmas, used, track_offset_px: float = 0.0) -> dict:
    """Each measurement's extra meat for :func:`sandwich_marginal` (a variance in units of its pixel noise,
    information ``H E H``): its tracks' correlation (:func:`_track_correlation`) plus stage 1's jackknife excess of
    its line, plus each track's own offset of ``track_offset_px`` (:func:`_track_offset_meat`), keyed by the line
    variable, or by ``(line, intrinsics)`` where its factor has the intrinsics variable.

    A meat on the line alone would then understate its bound: the factor ties the line to the intrinsics (a focal
    length and a line's tilt trade within one measurement), so ``D`` confined to the line's block is not below a
    multiple of ``H`` and ``H^-1 D H^-1`` grows along those trades without bound (a simulated 12-pose scene, camera
    exact: 1 sigma of 30 mm and fx +-25 px, above the prior's 28.5, from one line's 64 % excess; the error 3.9 mm,
    the plain covariance 3.2-3.8 mm). So the correlation is measured over both, and the line's other meats are
    carried to the intrinsics as the scores that a line shift makes there (:func:`_lifted`)."""
    out = {}
    for k in used:
        factor = keys[k].coaxial
        if factor is None:
            continue
        line = stage1[k].rotation_info @ stage1[k].excess @ stage1[k].rotation_info / sigmas[k] ** 2
        both = getattr(factor, "intrinsics_key", None) is not None
        meat = (_track_correlation(factor, values, intrinsics=both)
                + (_lifted(factor, values, line) if both else line))
        if track_offset_px > 0.0:
            meat = meat + _track_offset_meat(factor, values, track_offset_px, intrinsics=both)
        out[(keys[k].line_key, factor.intrinsics_key) if both else keys[k].line_key] = meat
    return out


def _lifted(factor, values: gtsam.Values, meat: np.ndarray) -> np.ndarray:
    """(8, 8) a line's meat ``M`` (3x3: scores ``s = H_ll dl`` of errors that move the line by ``dl``) at the line
    and the intrinsics of ``factor``: those errors score ``H_Kl dl`` on the intrinsics, so ``G M G^T`` with
    ``G = [I; H_Kl H_ll^-1]`` (``H`` the factor's information over both)."""
    H = factor.track_information(values, intrinsics=True).sum(axis=0)
    try:
        G = np.vstack([np.eye(3), np.linalg.solve(H[:3, :3], H[:3, 3:]).T])
    except np.linalg.LinAlgError:
        G = np.vstack([np.eye(3), np.zeros((len(H) - 3, 3))])
    lifted = G @ meat @ G.T
    return 0.5 * (lifted + lifted.T)


def _nuisance_blocks(graph, values, camera, setup, keys, used, builder, offsets, intrinsics) -> dict | None:
    """Where joint offsets or intrinsics are refined, what the image axes' prior floor and an image shift per pose
    (per px², :func:`stage2._shift_covariance`) add to the covariance of the pose and of them together, through the
    joint graph (:func:`_axis_meats`; through the axes alone, the pose's would leave out what the offsets or the
    intrinsics take up): ``{"shift": (pose 6x6, blocks), "floor": (pose, blocks)}`` (the floor's where there is
    one), ``blocks`` holding ``"offsets"`` (n x n rad²), ``"cross"`` (6 x n, pose by offsets) and
    ``"intrinsics"`` (5x5 px², fx fy s cx cy). None where neither is refined or the graph is singular."""
    parts = []
    if offsets is not None:
        parts.append(("offsets", builder.offsets_key, len(offsets.joints)))
    if intrinsics is not None:
        parts.append(("intrinsics", INTRINSICS_KEY, 5))
    if not parts:
        return None
    dim = 6 + sum(d for _, _, d in parts)
    errors = [("shift", np.ones((2, 2)))] + ([] if setup.floor_covariance is None else
                                             [("floor", setup.floor_covariance)])
    covariances = meat_marginals(graph, values, [POSE_KEY, *[key for _, key, _ in parts]], dim,
                                 [_axis_meats(camera, setup, keys, used, values, F) for _, F in errors])
    if covariances is None or not all(np.all(np.isfinite(S)) for S in covariances):
        return None
    out = {}
    for (name, _), S in zip(errors, covariances, strict=True):
        blocks, start = {}, 6
        for part, _, d in parts:
            blocks[part] = S[start:start + d, start:start + d]
            if part == "offsets":
                blocks["cross"] = S[:6, start:start + d]
            start += d
        out[name] = (S[:6, :6], blocks)
    return out


def _with_floor(correlated: dict, camera, setup, keys, used, values: gtsam.Values) -> dict:
    """The measurements' extra meat ``correlated`` (:func:`_meats`) plus the image axes' prior floor's
    (:func:`_axis_meats`), where the setup has a floor."""
    extra = dict(correlated)
    if setup.floor_covariance is None:
        return extra
    for key, meat in _axis_meats(camera, setup, keys, used, values, setup.floor_covariance).items():
        extra[key] = extra.get(key, np.zeros(meat.shape)) + meat
    return extra


def _axis_meats(camera, setup, keys, used, values: gtsam.Values, F: np.ndarray) -> dict:
    """Per used measurement's line variable, the meat of an error ``F`` (2x2 px², on its image axis' test-point
    distances) that the graph does not model (:func:`_floor_meat`), carried to the intrinsics as :func:`_meats`
    does where they are refined: the prior floor's (``setup.floor_covariance``), or an image shift per pose's
    (``[[1, 1], [1, 1]]`` per px²)."""
    pose = values.atPose3(POSE_KEY)
    extra = {}
    for k in used:
        meat = _floor_meat(camera, keys[k], values, pose, setup.axes[k], F)
        factor = keys[k].coaxial
        if getattr(factor, "intrinsics_key", None) is None:
            key = keys[k].line_key
        else:
            key, meat = (keys[k].line_key, factor.intrinsics_key), _lifted(factor, values, meat)
        extra[key] = extra.get(key, np.zeros(meat.shape)) + meat
    return extra


def _floor_meat(camera, keys, values: gtsam.Values, pose: gtsam.Pose3, axis, F: np.ndarray) -> np.ndarray:
    """(3, 3) what an error ``F`` on the image axis' test points' distances (the prior floor,
    :attr:`_Setup.floor_covariance`, or an image shift) adds to the meat of a measurement's line variable in the
    joint graph: a shift ``b`` of its image axis is what its tracks say of a line moved by the least (in its own
    information ``H``) that moves the test points' distances by ``b``, whose score is ``A^T L b`` (``A`` the
    distances' Jacobian by the line, ``L = (A H^-1 A^T)^-1`` their information): ``A^T L F L A``."""
    factor = keys.coaxial
    H = factor.track_information(values).sum(axis=0)
    line, J_line = image_line_from_rot3(camera.K, values.atRot3(keys.line_key))
    A = axis_point_residuals(camera.K, pose, axis_test_points(axis), line)[2] @ J_line  # as the tie's
    try:
        L = np.linalg.inv(A @ np.linalg.solve(H, A.T))
    except np.linalg.LinAlgError:
        return np.zeros((3, 3))
    meat = A.T @ L @ F @ L @ A
    return 0.5 * (meat + meat.T) if np.all(np.isfinite(meat)) else np.zeros((3, 3))


def _outside(alternatives, result: CalibrationResult) -> list:
    """The poses the robust fit could have reached by leaving out another measurement (``_Stage2.alternatives``)
    that lie outside the result's 99.9 % region: inside it, the covariance already covers them (a rendered UR5
    scene 0.9 mm off, chi2 of its error 0.9, was otherwise called ambiguous for a pose its stage-2 information put
    apart)."""
    if result.covariance is None or not np.all(np.isfinite(result.covariance)):
        return list(alternatives)
    information = np.linalg.pinv(result.covariance)
    limit = chi2_quantile(6, DISTINCT_Z)
    return [a for a in alternatives
            if (d := result.arm_T_camera.localCoordinates(a.arm_T_camera)) @ information @ d > limit]


class _IntrinsicsPrior(NamedTuple):
    """The intrinsics the joint fit refines: the prior (mean: the camera file's, ``gtsam.Cal3_S2``), its sigmas (5,
    the ones not refined held), the refined ones' indices in Cal3_S2's tangent, the current value and the camera
    given."""

    mean: gtsam.Cal3_S2
    sigmas: np.ndarray
    indices: list[int]
    now: gtsam.Cal3_S2
    given: Camera

    @classmethod
    def of(cls, camera: Camera, setup, options) -> _IntrinsicsPrior | None:
        """The prior about ``setup.given_camera`` (else ``camera``), starting at ``camera``; None without
        refinement."""
        names = options.refine_intrinsics
        if not names:
            return None
        given = camera if setup.given_camera is None else setup.given_camera
        return cls(cal3_s2(given.K), intrinsics_prior_sigmas(given.K, names, options.intrinsics_sigma),
                   [CAL3_S2_ORDER.index(n) for n in INTRINSICS if n in names], cal3_s2(camera.K), given)


class _Sync(NamedTuple):
    """Synced mode (``CalibrationOptions.sync_encoders``): the measurements with spin readings among those fitted,
    the readings' sigma, and per camera clock (``SpinReadings.clock``: ``clocks``, first seen first; ``clock_of``
    the index of each measurement's) the encoder clock's offset from that camera clock (encoder minus camera, the
    graph's variables: the options' and the result's offsets with the other sign): their prior (mean, sigma; sigma
    None: held at the mean) and their current values (s, ``now``, one per clock)."""

    measurements: tuple
    encoder_sigma_deg: float
    mean: float
    sigma: float | None
    now: tuple
    clocks: tuple = (None,)
    clock_of: tuple = ()

    @classmethod
    def of(cls, measurements, used, options) -> _Sync | None:
        """None unless some measurement of ``used`` has spin readings, the options sync them and the joint fit has
        the rigid spin on the projected model."""
        synced = tuple(k for k in used if measurements[k].spin_readings is not None)
        if (not synced or not options.sync_encoders or options.spin_model != "rigid"
                or options.joint_model is not Model.PROJECTED):
            return None
        named = [measurements[k].spin_readings.clock for k in synced]
        clocks = tuple(dict.fromkeys(named))
        return cls(synced, options.encoder_sigma_deg, -options.time_offset_s, options.time_offset_sigma_s,
                   (-options.time_offset_s,) * len(clocks), clocks, tuple(clocks.index(c) for c in named))

    def key(self, i: int) -> int:
        """Clock ``i``'s offset variable (the first's is TIME_KEY)."""
        return TIME_KEY if i == 0 else gtsam.symbol(chr(gtsam.Symbol(TIME_KEY).chr()), i)

    def offset(self, k: int) -> float:
        """The current offset (s, encoder minus camera) of synced measurement ``k``'s clock."""
        return self.now[self.clock_of[self.measurements.index(k)]]

    def builder_kwargs(self) -> dict:
        keys = TIME_KEY if self.clocks == (None,) else {c: self.key(i) for i, c in enumerate(self.clocks)}
        return {"encoder_sigma_deg": self.encoder_sigma_deg, "time_offset_s": self.now[0],
                "time_offset_key": None if self.sigma is None else keys}


def _sync_kwargs(sync: _Sync | None) -> dict:
    return {} if sync is None else sync.builder_kwargs()


#: Cal3_S2's tangent order
CAL3_S2_ORDER = ("fx", "fy", "s", "cx", "cy")


def intrinsics_prior_sigmas(K: np.ndarray, names, sigma: tuple[float, float]) -> np.ndarray:
    """(5,) the intrinsics' prior 1 sigma in Cal3_S2's tangent order (fx, fy, s, cx, cy) for refining ``names``
    (of ``INTRINSICS``) of the camera matrix ``K`` at ``sigma`` = (focal lengths' fraction, principal point px,
    ``CalibrationOptions.intrinsics_sigma``): the others (and the skew) held at ``HELD_INTRINSIC_PX``."""
    focal, principal = sigma
    free = {"fx": focal * K[0, 0], "fy": focal * K[1, 1], "cx": principal, "cy": principal}
    return np.array([free[n] if n in names else HELD_INTRINSIC_PX for n in CAL3_S2_ORDER])


def _tilt_apart_deg(arm, measurement, pose: gtsam.Pose3, line: gtsam.Rot3) -> float:
    """How far (deg) a line variable, turned minimally onto the image of the FK axis seen from ``pose``, lies from
    that FK axis (its tilt within the projection plane, which the tie leaves free)."""
    fk, _ = rot3_from_line(*axis_in_camera(arm.wrist_axis(measurement.joint_angles, measurement.spin_joint), pose))
    return float(np.degrees(np.linalg.norm(fk.localCoordinates(align_line(line, fk.matrix()[:, 2])))))


def _solved(keys: dict, values: gtsam.Values, ks=None) -> dict:
    """:func:`_joint_graph`'s ``solved`` for measurements ``ks`` (default all) of a graph's ``keys`` at ``values``."""
    return {k: (keys[k], values) for k in (keys if ks is None else ks)}


def _not_turning(keys, values) -> dict[int, dict[int, FitRejection]]:
    """measurement -> {track: why} for the tracks whose residual RMS under the rigid spin, at ``values``, is beyond
    NOT_TURNING_RATIO times the median of their measurement's tracks (at least two tracks kept).

    Stage 1's free phases fit any short arc to some circle, so a track that does not turn with the spin (a highlight,
    a point sliding along an outline) can pass it; under the rigid spin its residuals ramp along the track (UR5 photo
    seed 2: two tracks of 12-13 points from +55 to -87 px, the others' median 0.41 px). Its inner solution then makes
    the joint fit's cost rough: the first round of LM accepted no step (a step of 1e-15 along the gradient raised the
    cost the gradient said would fall) and where the next rounds stopped hung on the rounding (0.33 or 0.78 mm by the
    BLAS threads)."""
    out = {}
    for k, kk in keys.items():
        f = kk.coaxial
        if not isinstance(f, RigidLineFactor) or len(kk.tracks) < 3:
            continue
        rms = f.track_rms(values)
        median = float(np.median(rms))
        far = [j for j in np.argsort(-rms)[:len(kk.tracks) - 2] if rms[j] > NOT_TURNING_RATIO * median]
        if far and median > 0.0:
            out[k] = {int(kk.tracks[j]): FitRejection(
                f"does not turn with the spin: residual RMS {rms[j]:.3g} px per coordinate under the rigid spin, "
                f"{rms[j] / median:.3g}x the median of its pose's tracks") for j in far}
    return out


def _joint_graph(builder, camera, measurements, setup, stage1, ks, pose, sigmas, circles, lines, fk_start=(),
                 rest=None, intrinsics: _IntrinsicsPrior | None = None, sync: _Sync | None = None,
                 solved: dict | None = None):
    """The joint graph of measurements ``ks`` at ``pose`` (each at its pixel sigma): those in ``fk_start`` started
    about the FK axis seen from it (their circles from their tracks' rays), the others from ``lines`` and ``circles``
    (stage 1's or the last round's). With ``setup.offsets``, the offsets beyond those the readings were shifted by
    are a variable starting at ``rest`` (rad) under the prior of the total offsets; with ``intrinsics`` the camera's
    intrinsics are a variable too (at ``intrinsics.now``); synced (``sync``, its offset estimated), the encoder clock's
    offset too (at ``sync.now``, under its prior). ``solved``: measurement -> (its keys, values) in a graph of the same
    tracks solved where this one is built: those rigid spins start from their solutions there. Returns (graph,
    values, keys by measurement)."""
    graph, values = gtsam.NonlinearFactorGraph(), gtsam.Values()
    values.insert(POSE_KEY, pose)
    if setup.offsets is not None:
        builder.add_offsets_prior(graph, values, np.degrees(setup.offsets.sigma), mean_deg=-np.degrees(
            setup.offsets.start), initial_deg=np.degrees(rest))
    if intrinsics is not None:
        builder.add_intrinsics_prior(graph, values, intrinsics.sigmas, intrinsics.mean, intrinsics.now)
    if builder.time_offset_key is not None:
        for clock, now in zip(sync.clocks, sync.now, strict=True):
            builder.add_time_offset_prior(graph, values, sync.sigma, sync.mean, now, clock=clock)
    keys = {k: builder.add_measurement(graph, values, k, measurements[k], track_sigmas=dict.fromkeys(
                setup.prepared[k].usable, sigmas[k]), skip_tracks=stage1[k].outliers,
                prepared=setup.prepared[k], initial_circles=None if k in fk_start else circles[k],
                initial_line=None if k in fk_start else lines[k],
                refine_circles=k in fk_start or circles[k] is None, tie_covariance=setup.tie_covariance(
                    camera, k, stage1[k].image_axis, pose),
                spin_start=None if solved is None or k not in solved else (solved[k][0].coaxial, solved[k][1]))
            for k in ks}
    return graph, values, keys


def _joint_variance(graph, keys, values, options) -> float:
    """A measurement's pixel noise variance (px^2 per image coordinate) from its residuals in the joint graph: the
    free phase's point-to-circle distances, or the rigid spin's 2-D errors (their degrees of freedom: two per
    pixel less each track's circle and phase offset, each frame's angle (synced: by the pixels' share of it), and
    one gauge per group of tracks linked by shared frames)."""
    factor = keys.coaxial
    if isinstance(factor, RigidLineFactor):
        dof = factor.pixel_dof(values) - 1
        return max(float(factor.track_sse(values).sum()) / max(dof, 1), options.min_sigma_px**2)
    return _noise_variance(_track_stats(graph, keys, values), 1, options)


def common_chi2(arm, camera, measurements, setup, results: list[CalibrationResult],
                 options) -> tuple[np.ndarray, list[gtsam.Pose3]]:
    """Chi-square and pose of each result re-solved (from its pose) on one joint graph: the measurements and tracks
    that none of ``results`` rejected, each measurement at the smallest of their pixel sigmas (with refined
    intrinsics, from each result's camera under the same prior; the chi-square includes the prior's term)."""
    used = [k for k in range(len(measurements)) if all(r.measurements[k].used for r in results)]
    sigmas = {k: max(min(r.measurements[k].residual_rms_px for r in results), options.min_sigma_px) for k in used}
    skip = {k: set().union(*(r.measurements[k].rejected_tracks for r in results)) for k in used}
    intrinsics = _IntrinsicsPrior.of(camera, setup, options)
    builder = _builder(arm, camera, options, robust=track_huber, model=options.joint_model,
                       spin_model=options.spin_model, intrinsics_key=None if intrinsics is None else INTRINSICS_KEY)
    chi2, poses = [], []
    for r in results:
        graph, values = gtsam.NonlinearFactorGraph(), gtsam.Values()
        values.insert(POSE_KEY, r.arm_T_camera)
        if intrinsics is not None:  # each from its own refined camera, under the one prior
            builder.add_intrinsics_prior(graph, values, intrinsics.sigmas, intrinsics.mean,
                                         cal3_s2((camera if r.camera is None else r.camera).K))
        try:
            for k in used:
                builder.add_measurement(graph, values, k, measurements[k], skip_tracks=skip[k],
                                        track_sigmas=dict.fromkeys(setup.prepared[k].usable, sigmas[k]),
                                        prepared=setup.prepared[k], tie_covariance=setup.tie_covariance(
                                            camera, k, None, r.arm_T_camera))
        except RotIdError:  # this pose cannot carry those tracks (e.g. an ellipse behind the camera)
            chi2.append(np.inf)
            poses.append(r.arm_T_camera)
            continue
        start = r.arm_T_camera
        solved, _, error, _ = _lm(graph, values, options.max_iterations, anchor=True, watch_tolerance=WATCH_POSE,
                                  watch=lambda v, start=start: start.localCoordinates(v.atPose3(POSE_KEY)))
        chi2.append(2.0 * error)
        poses.append(solved.atPose3(POSE_KEY))
    return np.array(chi2), poses

"""Stage 2: the projected-axis distances of the FK axes to the stage-1 image axes, weighted and robust (a
:class:`_Stage2` record), the axes' consistency test and its covariance scale, the refits of stage 1 at the estimate
(short arcs), the result's assembly (:func:`_finish`) and the paper's method.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import gtsam
import numpy as np

from ..camera import Camera
from ..factors import (
    axis_point_residuals,
    line_distance_covariance,
    line_distances,
)
from ..graph import (
    Model,
    axis_test_points,
    chi2_quantile,
    track_huber,
)
from ..uncertainty import (
    analyse_observability,
    chi2_isf,
    chi2_sf,
    loewner_max,
    pose_information,
)
from .evidence import Evidence, _named, classify, measurement_reports, poor_minimum
from .initial import _best_stage2, _random_restarts, _stage2_graph, _stage2_minima
from .lm import _builder, _graph_dof, _turned
from .opinion import _tied_fit
from .options import MIN_MEASUREMENTS, CalibrationError, CalibrationOptions, Method
from .result import AMBIGUITY_CHI2, Alternative, AxisConsistency, CalibrationResult
from .setup import _Setup
from .stage1 import (
    _checked,
    _offset_of,
    _Stage1,
    _stage1,
    _test_pixels,
)
from .tuning import (
    AXIS_SCALE_RAMP,
    DISTINCT_Z,
    MIN_STRONG,
    POSE_KEY,
    REFINE_DEG,
    REFINE_M,
    REFINE_PASSES,
    STAGE1_ROUNDS,
    TIE_PX2,
    WEAK_MANY_TRACKS,
)


def _refined_stage1(arm, camera, measurements, start: gtsam.Pose3, setup: _Setup, options,
                    anchor, placing: bool = False) -> tuple[gtsam.Pose3, list[_Stage1]]:
    """Stage 1 from ``start``; where some measurement has only short arcs (``setup.short_arcs``), again from the
    pose its lines give (weighted stage 2, Huber on whole measurements) while that pose moves more than REFINE_DEG
    or REFINE_M (at most REFINE_PASSES fits), and the last fit jackknifed (:func:`_checked`; so are thin ellipses'
    fits where ``setup.thin_check``). Returns the pose stage 1 last started from and its fit. Where every
    measurement has a long arc: one fit from the start.

    Each measurement's fit starts from the FK axis seen from the start. With long arcs it finds the same circles
    from anywhere near; with short ones (corner tracks of 25 degrees) it stays in a minimum near the start, and
    the initialisation from ellipse centres can be 20 degrees off: on one rendered scene three of six lines fitted
    from there were 100-13 000 chi-square off the truth, and 0-4 when fitted from the truth.

    ``placing``: where refits follow, the first fit only places the pose (one round, no track rejected: its
    tests are against lines fitted from a start far off). From a start that far off the path is chaotic: which
    tracks the first fit's rounds reject, and where the refits go, hang on LM's path through the circles' inner
    minima (which of the guess-free start's five tied candidates came first, one minimum at costs equal to 1e-12,
    took one rendered Jaco2 scene 0.44 mm or 490 mm off); where arcs are short and the standard path's result is
    refused or not usable, ``calibrate`` runs this one too and lets the joint fit choose among all ends
    (``run._calibrate``).
    """
    pose = start
    builder = _builder(arm, camera, options, model=Model.PROJECTED, robust=track_huber)
    everything = list(range(len(measurements)))
    refits = REFINE_PASSES - 1 if setup.short_arcs else 0  # long arcs: the first fit stands
    placing = placing and refits > 0
    stage1 = _stage1(arm, camera, measurements, pose, setup, options, max_rounds=1 if placing else STAGE1_ROUNDS)
    for i in range(refits):
        moved, _, _ = _weighted_stage2(camera, setup, stage1, everything, pose, options, anchor)
        if _settled(moved, pose):
            if i == 0 and placing:  # the first fit stands: with its tracks tested
                stage1 = _stage1(arm, camera, measurements, pose, setup, options)
            break
        pose = moved
        stage1 = _stage1(arm, camera, measurements, pose, setup, options, image_axes=False)
    return pose, [_checked(builder, measurements[k], k, pose, setup.prepared[k], s, options, setup)
                  for k, s in enumerate(stage1)]


def _settled(a: gtsam.Pose3, b: gtsam.Pose3) -> bool:
    """``a`` lies within REFINE_DEG and REFINE_M of ``b``: stage 1's refits have settled, or two paths through them
    ended in the same place."""
    return _turned(a, b) < np.radians(REFINE_DEG) and np.linalg.norm(a.translation() - b.translation()) < REFINE_M


# ---------------------------------------------------------------------------------------------------
# stage 2 and the estimators


def _axis_distances(camera: Camera, axis, stage1: _Stage1, pose: gtsam.Pose3, sigma2: float | None = None,
                    setup: _Setup | None = None, k: int | None = None,
                    floor: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """Distances of the projected FK test points to the stage-1 image axis, and their covariance (at the
    measurement's own pixel noise variance unless ``sigma2`` is given; with ``setup`` plus the joint-angle noise'
    of measurement ``k``, :meth:`_Setup.tie_covariance`; with ``floor`` too the prior floor's, :func:`_floor_of`)."""
    points = np.array([pose.transformTo(p) for p in axis_test_points(axis)])
    pixels = camera.project(points, distort=False)
    e = line_distances(stage1.image_axis, pixels)
    sigma2 = stage1.sigma2 if sigma2 is None else sigma2
    cov = line_distance_covariance(stage1.image_axis_cov * sigma2, pixels) + 1e-12 * np.eye(len(e))
    extra = None if setup is None else setup.tie_covariance(camera, k, stage1.image_axis, pose)
    if extra is not None:
        cov = cov + extra
    F = _floor_of(setup, stage1, pixels) if floor else None
    if F is not None:
        cov = cov + F
    return e, cov


def _floor_of(setup: _Setup, stage1: _Stage1, pixels: np.ndarray) -> np.ndarray | None:
    """(2, 2) the prior floor on a measurement's test-point distances (``pixels``: the test points' images): the
    floor all image axes share (:attr:`_Setup.floor_covariance`) plus what its tracks' own offsets give its axis
    (``stage1.offset_axis_cov``, ``CalibrationOptions.track_offset_px``); None with neither. Like the floor, the
    offsets are not in the fit's weights: what they pass into the estimate is added to its covariance
    (:func:`_prior_floor_covariance`), and they are in the axes' test."""
    F, offset = setup.floor_covariance, _offset_of(stage1, pixels)
    if offset is not None:
        F = offset if F is None else F + offset
    return F


def _axis_offsets(camera: Camera, setup: _Setup, stage1, used: list[int], pose: gtsam.Pose3) -> list | None:
    """Per used measurement, :func:`_offset_of` at ``pose``; None where no measurement has track offsets."""
    out = [_offset_of(stage1[k], _test_pixels(camera, setup.axes[k], pose)) for k in used]
    return out if any(o is not None for o in out) else None


def _axis_floors(setup: _Setup, offsets: list | None, n: int) -> list | None:
    """Per used measurement (``n`` of them), the prior floor on its test-point distances: the floor all axes share
    plus its tracks' own ``offsets`` (:func:`_axis_offsets`; None: only the shared floor, as the joint fit's
    covariance carries the offsets in its sandwich, :func:`.joint._meats`); None where neither is there. As
    :func:`_floor_of`, per measurement."""
    F = setup.floor_covariance
    if offsets is None:
        return None if F is None else [F] * n
    return [O if F is None else (F if O is None else F + O) for O in offsets]


def _with_axis_covariances(reports, used: list[int], rows, offsets: list | None = None) -> None:
    """Each used measurement's report (``reports[k]``) gains its test points' distance covariance, from its row of
    :func:`_axis_rows` (without the floor) at the estimate (:attr:`MeasurementReport.axis_test_covariance`), and
    what its tracks' own offsets add there (``offsets``, :func:`_axis_offsets`)."""
    for i, (k, (_, cov, _)) in enumerate(zip(used, rows, strict=True)):
        reports[k].axis_test_covariance = np.asarray(cov, dtype=float).tolist()
        if offsets is not None and offsets[i] is not None:
            reports[k].axis_offset_covariance = np.asarray(offsets[i], dtype=float).tolist()


def _chi2(camera, setup: _Setup, stage1, pose, sigma2: dict[int, float] | None = None) -> np.ndarray:
    """Per measurement: chi-square (2 dof) of its stage-1 image axis against the FK axis projected by ``pose``.

    The line covariance is at ``sigma2[k]`` when given; otherwise at the larger of the measurement's and the
    median pixel noise variance: the geometric distance to a strongly curved (near edge-on) projected circle
    absorbs part of the noise, so a measurement's own residuals can understate it, and a test at that scale
    would reject good data. Measurements missing from ``sigma2`` get NaN.
    """
    median = float(np.median([s.sigma2 for s in stage1]))
    out = []
    for k, (axis, s) in enumerate(zip(setup.axes, stage1, strict=True)):
        if sigma2 is not None and k not in sigma2:
            out.append(np.nan)
            continue
        variance = max(s.sigma2, median) if sigma2 is None else sigma2[k]
        e, cov = _axis_distances(camera, axis, s, pose, variance, setup, k)
        out.append(float(e @ np.linalg.pinv(cov, hermitian=True) @ e))  # pinv: test points may project badly
    return np.array(out)


def _axis_consistency(rows, floors: list | None, options, fitted: int = 0) -> AxisConsistency | None:
    """The test of :class:`AxisConsistency` about the estimate ``pose`` on the used measurements' ``rows`` there
    (:func:`_axis_rows` at ``pose`` without the floor, each measurement's line at the pixel noise variance the fit
    weighted it by; the prior floor, ``floors`` of :func:`_axis_floors`, is added here); None without redundancy
    (fewer than 4 measurements).

    The chi-square is the axes' own minimum: at the pose that fits them best with those weights (linearised about
    ``pose``), which is what has ``2 n - 6`` dof. At ``pose`` itself (the joint fit's, which weights the
    measurements by their tracks, not by these line covariances) it is larger by the two estimates' difference,
    about 6 more dof under the model: tested against ``2 n - 6`` that rejected consistent axes (four measurements
    of a rendered UR5 scene: 8.7 at the joint pose, 1.4 at the axes' own). ``fitted``: parameters beyond the pose
    that were fitted to the same axes (the joint offsets the data determine), each one dof less."""
    dof = 2 * len(rows) - 6 - fitted
    if dof <= 0:
        return None
    if floors is not None:
        rows = [(e, cov if F is None else cov + F, J) for (e, cov, J), F in zip(rows, floors, strict=True)]
    chi2 = _refitted_chi2(rows, 0.0)
    if not np.isfinite(chi2):  # the FK axes do not even project: no agreement to measure
        return AxisConsistency(np.inf, dof, 0.0, np.inf)
    p = chi2_sf(chi2, dof)
    passed = bool(p >= options.axis_consistency_p)
    if dof <= 2:  # k's mean is unbounded with 2 dof: the Birge ratio (and the result is not trusted)
        return AxisConsistency(chi2, dof, p, 1.0 if passed else chi2 / dof, passed=passed)
    excess = axis_excess(chi2, dof, options.axis_consistency_p)
    if excess <= 0.0:
        return AxisConsistency(chi2, dof, p, 1.0, passed=passed)
    scale = 1.0 + excess / (dof - 2)
    if (options.track_offset_px or 0.0) > 0.0:
        # the tracks' own offsets are declared: the shared errors the floor stands for are in the covariance, and
        # the scatter is read as them understated (the scale). Read as a floor besides, it widened the rendered
        # ambient scenes' covariances up to 4x in sigma where the scale alone held them (UR5 text seed 0, the axes at
        # P = 0.057: a floor of 0.58 px, the error at chi-square 0.12 against 1.9 scaled and 5.8 bare; NEES over
        # the 15 usable 2.97, 4.23 by the scale alone, its 95 % interval 4.38-7.88)
        return AxisConsistency(chi2, dof, p, scale, passed=passed)
    floor, increment = _axis_floor(rows, chi2 - excess)
    return AxisConsistency(chi2, dof, p, scale, floor, increment, passed=passed)


def axis_excess(chi2: float, dof: int, level: float) -> float:
    """The part of the axes' chi-square that :class:`AxisConsistency` reads as their noise understated: of the excess
    ``chi2 - (dof - 2)`` over k's mean of 1, a share rising linearly from 0 at the chi-square of upper-tail probability
    min(0.5, AXIS_SCALE_RAMP x ``level``) to all of it at the test's threshold (the chi-square at ``level``; none at
    ``level`` 0, the test switched off), so that the scale and the floor grow continuously with the scatter
    (dof > 2)."""
    if level <= 0.0 or not np.isfinite(chi2):
        return 0.0
    start, threshold = chi2_isf(min(0.5, AXIS_SCALE_RAMP * level), dof), chi2_isf(level, dof)
    if chi2 <= start:
        return 0.0
    share = min((chi2 - start) / (threshold - start), 1.0) if threshold > start else 1.0
    return float(share * max(chi2 - (dof - 2), 0.0))


def _axis_rows(camera, setup: _Setup, stage1, used: list[int], pose: gtsam.Pose3,
               sigma2: dict[int, float], floor: bool = False,
               axes: dict | None = None) -> list[tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """Per used measurement: its test points' distances to its image axis, their covariance (pixel noise at
    ``sigma2[k]`` and joint-angle noise, :func:`_axis_distances`; with ``floor`` the prior floor's, :func:`_floor_of`,
    too) and their (2, 6) Jacobian by the pose. ``axes`` (k -> FK axis) replaces
    ``setup.axes`` (other kinematics, :func:`.modelcheck.kinematics_check`)."""
    rows = []
    for k in used:
        axis = setup.axes[k] if axes is None else axes[k]
        e, cov = _axis_distances(camera, axis, stage1[k], pose, sigma2[k], setup, k, floor=floor)
        J = axis_point_residuals(camera.K, pose, axis_test_points(axis), stage1[k].image_axis)[1]
        rows.append((e, cov, J))
    return rows


def _floored_weights(rows, tau2: float) -> list[np.ndarray]:
    """The inverse covariances of :func:`_axis_rows`' distances with ``tau2`` (px^2) added to each."""
    return [np.linalg.inv(cov + tau2 * np.eye(len(e))) for e, cov, _ in rows]


def _refitted_chi2(rows, tau2: float) -> float:
    """The axes' chi-square (rows of :func:`_axis_rows`, each distance's variance plus ``tau2``) at the pose these
    weights fit best, to first order: distances ``e_k + J_k x`` minimised over the pose tangent ``x``. Infinite
    where some test point has no finite distance (it projects at or behind the camera: a runaway pose)."""
    if not all(np.all(np.isfinite(e)) and np.all(np.isfinite(cov)) and np.all(np.isfinite(J)) for e, cov, J in rows):
        return np.inf
    W_k = _floored_weights(rows, tau2)
    H = sum(J.T @ W @ J for (_, _, J), W in zip(rows, W_k, strict=True))
    g = sum(J.T @ W @ e for (e, _, J), W in zip(rows, W_k, strict=True))
    return float(sum(e @ W @ e for (e, _, _), W in zip(rows, W_k, strict=True))
                 - g @ np.linalg.lstsq(H, g, rcond=None)[0])


def _axis_floor(rows, target: float) -> tuple[float, np.ndarray | None]:
    """The axes' common floor (see :class:`AxisConsistency`) on the test's rows (:func:`_axis_rows`, with the prior
    floor): ``tau`` (px) such that, with ``tau^2`` added to the variance ``V_k`` of every projected test point's
    distance, the axes' chi-square falls to ``target`` at the pose those weights fit best (:func:`_refitted_chi2`),
    and the pose covariance that floor adds (6x6, the Pose3 tangent: ``(sum_k J_k^T (V_k + tau^2 I)^-1 J_k)^-1``
    minus the same at ``tau = 0``; None when the axes alone do not determine the pose)."""

    def information(tau2: float) -> np.ndarray:
        return sum(J.T @ W @ J for (_, _, J), W in zip(rows, _floored_weights(rows, tau2), strict=True))

    def chi2(tau2: float) -> float:
        return _refitted_chi2(rows, tau2)

    if chi2(0.0) <= target:
        return 0.0, None
    low, high = 0.0, max(float(np.max([np.max(np.abs(e)) for e, _, _ in rows])) ** 2, 1e-12)
    for _ in range(40):  # the chi-square falls in tau^2 (towards 0 as the floor swamps every V_k)
        if chi2(high) <= target:
            break
        high *= 4.0
    for _ in range(40):
        middle = 0.5 * (low + high)
        low, high = (middle, high) if chi2(middle) > target else (low, middle)
    tau2 = high

    try:
        increment = np.linalg.inv(information(tau2)) - np.linalg.inv(information(0.0))
    except np.linalg.LinAlgError:
        return float(np.sqrt(tau2)), None
    increment = 0.5 * (increment + increment.T)
    return float(np.sqrt(tau2)), increment if np.all(np.isfinite(increment)) else None


def _prior_floor_covariance(rows, floors: list | None) -> np.ndarray | None:
    """The pose covariance (6x6, Pose3 tangent) that the prior floor's errors (``floors`` of :func:`_axis_floors`,
    ``F_k`` on each used axis' test-point distances) pass into an estimate fitted without them, to first order:
    ``H^-1 (sum_k J_k^T W_k F_k W_k J_k) H^-1`` with the fit's own weights ``W_k = V_k^-1`` (``rows``: the used
    measurements' :func:`_axis_rows` at the estimate without the floor: the pixel noise at the fit's variance and
    the joint-angle noise) and ``H = sum_k J_k^T W_k J_k``: the sandwich's part that the floor adds. None without a
    floor or when the axes alone do not determine the pose."""
    if floors is None:
        return None
    H, meat = np.zeros((6, 6)), np.zeros((6, 6))
    for (_, cov, J), F in zip(rows, floors, strict=True):
        WJ = np.linalg.solve(cov, J)
        H += J.T @ WJ
        if F is not None:
            meat += WJ.T @ F @ WJ
    try:
        H_inv = np.linalg.inv(H)
    except np.linalg.LinAlgError:
        return None
    out = H_inv @ meat @ H_inv
    out = 0.5 * (out + out.T)
    return out if np.all(np.isfinite(out)) else None


def _shift_covariance(rows) -> np.ndarray | None:
    """The pose covariance (6x6, Pose3 tangent) per px² of an image shift common to each pose's tracks (independent
    across poses, px² per image coordinate), to first order through the image axes (``rows``: the used
    measurements' :func:`_axis_rows` at the estimate): a shift moves a measurement's image axis across itself, both
    test points' distances alike, so it is :func:`_prior_floor_covariance` with the floor ``[[1, 1], [1, 1]]`` on
    every axis. The fit's weights cancel in it: a common scale of the axes' noise leaves it as it is. None where the
    axes alone do not determine the pose."""
    return _prior_floor_covariance(rows, [np.ones((len(e), len(e))) for e, _, _ in rows])


def _weighted_stage2(camera, setup: _Setup, stage1, used: list[int], start: gtsam.Pose3, options, anchor):
    """Stage 2 weighted by the stage-1 line covariances, Huber on whole measurements; returns (pose, its, graph)."""
    pose, iterations, graph = start, 0, None
    for _round in range(3):  # the distance covariance depends on where the test points project
        noises = []
        for k in used:
            _, cov = _axis_distances(camera, setup.axes[k], stage1[k], pose, setup=setup, k=k)
            base = gtsam.noiseModel.Gaussian.Covariance(cov)
            noises.append(gtsam.noiseModel.Robust.Create(gtsam.noiseModel.mEstimator.Huber.Create(3.0), base))
        graph = _stage2_graph([setup.axes[k] for k in used], [stage1[k].image_axis for k in used], camera.K, noises)
        previous = pose
        pose, _, it, _ = _best_stage2(graph, [pose], options, anchor=anchor)
        iterations += it
        step = previous.localCoordinates(pose)
        if np.max(np.abs(step[:3])) < 1e-9 and np.max(np.abs(step[3:])) < 1e-9:
            break
    return pose, iterations, graph


def _tied_circles(arm, camera, measurements, setup: _Setup, stage1, pose: gtsam.Pose3, options, ks) -> dict:
    """k -> (line, circles) of measurement k fitted with its line on the FK axis seen from ``pose``, for those of
    ``ks`` with fewer than WEAK_MANY_TRACKS kept tracks: with that many a measurement is not weak whatever its arcs
    (:func:`.evidence._evidence`), and its arc span is measured about stage 1's circles only (the tied fits took a
    third of the reference scene's joint calibration)."""
    builder = _builder(arm, camera, options, model=Model.PROJECTED, robust=track_huber)
    out = {}
    for k in ks:
        if len(stage1[k].keys.tracks) >= WEAK_MANY_TRACKS:
            continue
        fit = _tied_fit(builder, measurements[k], k, setup.prepared[k], stage1[k], pose, options, setup, fresh=True)
        if fit is not None:
            out[k] = fit[1], fit[2]
    return out


class _Stage2(NamedTuple):
    """The robust weighted stage 2 (:func:`_robust_weighted`): its pose and graph, the measurements it used, every
    measurement's chi-square against the pose (2 dof), the evidence it judged them by, and the stage-1 fits it ended
    with (second opinions may have replaced some)."""

    pose: gtsam.Pose3
    iterations: int
    graph: gtsam.NonlinearFactorGraph
    used: list[int]
    chi2: dict[int, float]
    evidence: Evidence
    stage1: list[_Stage1]
    #: other measurements whose leaving out reconciled the rest almost as well (see :func:`_robust_weighted`)
    alternatives: tuple = ()


def _robust_weighted(camera, setup, stage1, start, options, anchor, second_opinion=None,
                     drop_weak: bool = False) -> _Stage2:
    """Weighted stage 2 that leaves out measurements whose image axis disagrees with the FK axis.

    At most ``(n - 3) // 2`` measurements are left out, so that the rest still over-determine the pose and
    the test stays meaningful; more disagreement than that is reported as a poor minimum. A measurement whose
    linearised chi-square exceeds the limit gets a ``second_opinion(k, pose, stage1) -> (refit or None,
    statistic)`` (:func:`_second_opinion`) before it can be left out: a better stage-1 fit found from the estimate
    replaces its own (in the returned ``stage1``; the one passed in is not changed) and the likelihood-ratio
    statistic decides instead of the linearised one. With ``drop_weak``, weak measurements (their image axes need
    not be Gaussian) are left out when enough strong ones remain.

    A measurement is left out by leave-one-out: the one whose absence best reconciles the others. Where leaving out
    another instead reconciles them almost as well (the two axes' chi-squares less than AMBIGUITY_CHI2 apart: both
    hypotheses free one measurement's two distances, so the difference is 2 ln of their likelihood ratio) at a
    distinct pose, the data cannot tell which measurement is wrong: that pose is returned as an alternative (the
    result is then ambiguous). One shoulder reading 1 degree off on a pose of the reference scene (20 s spins) pulled
    the pose until a good measurement disagreed most; leaving that one out, the wrong one fitted: 17 mm off with the
    error's chi-square 3672, called usable.
    """
    n = len(stage1)
    stage1 = list(stage1)
    limit = options.outlier_measurement_chi2
    iterations = 0
    refitted: set[int] = set()
    alternatives: list[Alternative] = []
    evidence = classify(setup, stage1)
    strong = [k for k in range(n) if k not in evidence.weak]
    if drop_weak and evidence.weak and len(strong) >= MIN_STRONG:
        evidence = evidence._replace(dropped=frozenset(evidence.weak))
    used = [k for k in range(n) if k not in evidence.dropped]
    max_excluded = max(0, (len(used) - MIN_MEASUREMENTS) // 2) + len(evidence.dropped)
    while True:
        pose, it, graph = _weighted_stage2(camera, setup, stage1, used, start, options, anchor)
        iterations += it
        chi2 = _chi2(camera, setup, stage1, pose)
        bad = [k for k in used if chi2[k] > limit]
        if bad and second_opinion is not None:
            opinions = {k: second_opinion(k, pose, stage1) for k in bad}
            new = [k for k, (refit, _) in opinions.items() if refit is not None and k not in refitted]
            for k in new:
                stage1[k] = opinions[k][0]
                refitted.add(k)
            if new:  # better stage-1 fits: estimate again with them
                start = pose
                continue
            for k, (_, statistic) in opinions.items():
                if not np.isnan(statistic):
                    chi2[k] = statistic
            bad = [k for k in used if chi2[k] > limit]
        if not bad:
            break
        if n - len(used) >= max_excluded:
            gone = _named(setup, sorted(set(range(n)) - set(used)))
            left_out = f", after leaving out {gone}" if len(used) < n else ""
            raise poor_minimum(chi2, limit, f"measurement(s) {_named(setup, bad)} disagree{left_out}", setup,
                               evidence, bad)
        # One at a time, by leave-one-out: a wrong measurement drags the pose, so the largest chi-square may
        # belong to a good one; leave out the one whose absence best reconciles the others.
        candidates = []
        for k in used:
            rest = [i for i in used if i != k]
            rest_pose, it, rest_graph = _weighted_stage2(camera, setup, stage1, rest, pose, options, anchor)
            iterations += it
            rest_chi2 = _chi2(camera, setup, stage1, rest_pose)
            candidates.append((float(sum(rest_chi2[i] for i in rest)), k, rest_pose, rest_graph))
        best = min(candidates, key=lambda c: c[0])
        instead_of = _named(setup, [best[1]])[0]
        alternatives.extend(Alternative(other, score - best[0], _named(setup, [k])[0], instead_of)
                            for score, k, other, _ in candidates
                            if score - best[0] < AMBIGUITY_CHI2 and _distinct(other, best[2], best[3]))
        used.remove(best[1])
        start = best[2]
    return _Stage2(pose, iterations, graph, used, {k: float(chi2[k]) for k in range(n)}, evidence, stage1,
                   tuple(alternatives))


def _distinct(other: gtsam.Pose3, pose: gtsam.Pose3, graph: gtsam.NonlinearFactorGraph) -> bool:
    """Whether ``other`` is a pose distinct from ``pose`` (the solution of the weighted stage-2 ``graph``): beyond the
    99.9 % point of the latter's uncertainty (the chi-square of their difference under its information, 6 dof)."""
    values = gtsam.Values()
    values.insert(POSE_KEY, pose)
    d = pose.localCoordinates(other)
    return bool(d @ pose_information(graph, values, POSE_KEY) @ d > chi2_quantile(6, DISTINCT_Z))


def _check_scale(result: CalibrationResult, setup: _Setup, stage1: list[_Stage1], options: CalibrationOptions) -> None:
    """Raise if the estimate implies features implausibly far from the wrist axis (metric scale check).

    The stage-1 circles are known in units of the camera-to-axis distance; the estimate fixes that distance
    (unless it is degenerate: then the report already says the position is not determined).
    """
    if not result.covariance_usable:
        return
    pose = result.arm_T_camera
    radii = []
    centre = pose.translation()
    for axis, s in zip(setup.axes, stage1, strict=True):
        distance = float(axis.distance_to(centre)[0])  # camera centre to the wrist axis
        radii.extend(abs(c[1]) * distance for c in s.circles.values())
    median = float(np.median(radii))
    if median > options.max_feature_radius_m:
        distance_to_wrist = np.median([np.linalg.norm(pose.transformTo(a.point)) for a in setup.axes])
        raise CalibrationError(
            f"the estimate ended in a poor minimum: it puts the camera {distance_to_wrist:.2f} m from the wrist, "
            f"so the tracked features would lie {median:.2f} m from the wrist axis (median; limit "
            f"{options.max_feature_radius_m} m); check the joint angles, the intrinsics and the spinning joint")


@dataclass(frozen=True)
class _Solved:
    """A method's solution, before its result is assembled (:func:`_finish`)."""

    pose: gtsam.Pose3
    covariance: np.ndarray | None     # None: from the observability analysis of ``info``
    info: np.ndarray                  # the pose's information (6x6)
    method: Method
    converged: bool
    iterations: int
    error: float


def _finish(solved: _Solved, reports, sigma_px, *, info_scale: float = 1.0, dof: int | None = None,
            consistency: AxisConsistency | None = None, prior: np.ndarray | None = None,
            shift: np.ndarray | None = None) -> CalibrationResult:
    """Result with the observability of ``info * info_scale`` (the scale makes it a real information); the
    covariance (of the pose, or the observability's when it is undetermined) gains ``prior`` (the prior floor's,
    :func:`_prior_floor_covariance`) and is then multiplied by ``consistency.scale`` or floored, whichever is larger
    (the test that sets them weighted each axis with the prior floor too). ``shift``: the pose covariance per px² of
    an image shift per pose (:func:`_shift_covariance`), kept as ``CalibrationResult.image_shift_covariance``."""
    pose, covariance, info, method = solved.pose, solved.covariance, solved.info, solved.method
    converged, iterations, error = solved.converged, solved.iterations, solved.error
    if not np.all(np.isfinite(info)):
        raise CalibrationError("the estimate ended in a poor minimum: the pose's information there is not finite "
                               "(the FK axes' test points project at or behind the camera); check the joint angles, "
                               "the intrinsics and the spinning joint")
    observability = analyse_observability(info * info_scale, pose)
    if covariance is None or not observability.is_observable:
        covariance = observability.covariance(info)
    if prior is not None and observability.is_observable:  # what the axes' test cannot see
        covariance = covariance + prior
    if consistency is not None and observability.is_observable:
        scaled = covariance * consistency.scale
        # the larger, direction by direction, of the two readings of the axes' scatter (AxisConsistency)
        covariance = scaled if consistency.floor_covariance is None else loewner_max(
            scaled, covariance + consistency.floor_covariance)
    return CalibrationResult(pose, covariance, method.value, bool(converged), int(iterations), float(error),
                             reports, observability, float(sigma_px), dof, axis_consistency=consistency,
                             image_shift_covariance=shift if observability.is_observable else None)


def _paper(camera, setup, stage1, init_pose, options, anchor) -> CalibrationResult:
    """The seed's stage 2: unweighted, random restarts, covariance (J^T J)^-1 at unit noise."""
    evidence = classify(setup, stage1)  # it leaves nothing out
    rng = np.random.default_rng(options.seed)
    noises = [gtsam.noiseModel.Isotropic.Sigma(2, 1.0)] * len(stage1)
    graph = _stage2_graph(setup.axes, [s.image_axis for s in stage1], camera.K, noises)
    starts = [init_pose, *_random_restarts(init_pose, options.restarts, rng)]
    # the unit line noise stands for the lines' real noise: the gauge prior is scaled to match (a prior of
    # GAUGE_SIGMA against 1 px lines would drag a weakly determined direction to the anchor)
    line_var = float(np.median([np.mean(np.diag(_axis_distances(camera, axis, s, init_pose)[1]))
                                for axis, s in zip(setup.axes, stage1, strict=True)]))
    minima = _stage2_minima(graph, starts, options, anchor=anchor, gauge_scale=line_var)
    # Minima within TIE_PX2 of the lowest fit the lines equally well (three measurements: several exact
    # solutions); the start was chosen by the circles, so the one nearest it is taken.
    lowest = min(m[1] for m in minima)
    pose, error, iterations, _ = min((m for m in minima if m[1] <= lowest + TIE_PX2),
                                     key=lambda m: _turned(m[0], init_pose))
    chi2 = _chi2(camera, setup, stage1, pose)
    if np.median(chi2) > options.outlier_measurement_chi2:  # the unweighted fit is suboptimal: judge loosely
        raise poor_minimum(chi2, options.outlier_measurement_chi2, "most measurements disagree", setup, evidence)
    values = gtsam.Values()
    values.insert(POSE_KEY, pose)
    sigmas = {k: float(np.sqrt(s.sigma2)) for k, s in enumerate(stage1)}
    reports = measurement_reports(stage1, setup, evidence, sigmas, list(range(len(stage1))), options)
    for r in reports:
        r.weight = 1.0
    # The paper's covariance assumes 1 px line errors; judge what is determined with the residual scale.
    dof = 2 * len(stage1) - 6
    line_var = max(2.0 * error / dof, options.min_sigma_px**2) if dof > 0 else 1.0
    solved = _Solved(pose, None, pose_information(graph, values, POSE_KEY), Method.PAPER, True, iterations, error)
    return _finish(solved, reports, np.median(list(sigmas.values())), info_scale=1.0 / line_var,
                   dof=_graph_dof(graph, values))

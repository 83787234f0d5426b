"""A second opinion on a measurement that disagrees with the estimate: its circles fitted with the line tied to
the estimate's FK axis and freed from there, its tracks chosen again at that axis, and the likelihood ratio of tied
against free that decides whether it is an outlier (stage 2's linearised chi-square assumes a Gaussian image axis,
which few tracks or short arcs do not give).
"""

from __future__ import annotations

import gtsam
import numpy as np

from ..errors import RotIdError
from ..graph import Model, RotIdGraph, chi2_quantile, track_huber
from .lm import _builder, _lm
from .setup import _Setup
from .stage1 import (
    FitRejection,
    _checked,
    _circles,
    _outlier_tracks,
    _Stage1,
    _stage1_measurement,
    _stage1_result,
    _stage1_round,
    _start_line,
    _track_stats,
    circles_about,
)
from .tuning import POSE_KEY, STAGE1_MAX_ITERATIONS


def _tied_fit(builder: RotIdGraph, measurement, k: int, prepared, s: _Stage1, pose: gtsam.Pose3, options,
              setup: _Setup, fresh: bool = False):
    """Measurement k's circles with its line held on the FK axis projected by ``pose`` (its tilt within the
    projection plane free; the tie as soft as the joint-angle noise makes the FK axis): (residual sum of squares in
    px^2, line variable, circles, the tie's chi-square), or None if it fails. The circles start from stage 1's, or
    with ``fresh`` from each track's rays about the FK axis (a short arc's stage-1 circle can be far too small)."""
    graph, values = gtsam.NonlinearFactorGraph(), gtsam.Values()
    values.insert(POSE_KEY, pose)
    try:
        keys = builder.add_measurement(graph, values, k, measurement, prepared=prepared, skip_tracks=s.outliers,
                                       initial_line=None if fresh else s.rotation,
                                       initial_circles=None if fresh else dict(s.circles),
                                       refine_circles=fresh, track_sigmas=dict.fromkeys(prepared.usable, 1.0),
                                       tie_covariance=setup.tie_covariance(builder.camera, k, s.image_axis, pose))
    except RotIdError:
        return None
    graph.add(gtsam.NonlinearEqualityPose3(POSE_KEY, pose))
    result, _, _, _ = _lm(graph, values, min(options.max_iterations, STAGE1_MAX_ITERATIONS),
                          relative_tolerance=options.stage1_tolerance)
    sse = sum(v[0] for v in _track_stats(graph, keys, result).values())
    if not np.isfinite(sse):
        return None
    tie = 2.0 * graph.at(keys.tie_factor).error(result) if keys.tie_factor >= 0 else 0.0
    return sse, result.atRot3(keys.line_key), dict(zip(keys.tracks, _circles(keys, result), strict=True)), tie


def _sse(s: _Stage1) -> float:
    return float(sum(v[0] for v in s.stats.values()))


def _stats_at(builder: RotIdGraph, measurement, k: int, prepared, pose: gtsam.Pose3, line: gtsam.Rot3,
              skip: dict[int, str], circles: dict[int, np.ndarray]) -> dict[int, tuple[float, int]]:
    """Every track's (residual sum of squares, points) at ``line``, its circle solved there, but those in ``skip``.

    Each circle's solve starts from ``circles[j]`` (the fit's own), or from the track's rays about ``line``
    (:func:`circles_about`)."""
    tracks = [j for j in prepared.usable if j not in skip]
    start = circles_about(builder.camera.K, prepared, line, {j: c for j, c in circles.items() if j in tracks}, tracks)
    graph, values = gtsam.NonlinearFactorGraph(), gtsam.Values()
    keys = builder.add_measurement(graph, values, k, measurement, arm_T_camera=pose, tie=False, prepared=prepared,
                                   skip_tracks=skip, refine_circles=False, initial_line=line, initial_circles=start)
    return _track_stats(graph, keys, values)


def _truncated_cost(stats: dict[int, tuple[float, int]], variance: float, options) -> float:
    """Sum over tracks of ``min(sse / variance, chi-square 99.9 % point of its points)``: a truncated least-squares
    cost, in which a track that does not fit costs a fixed limit (stage 1's own test is relative to the tracks'
    median, not this absolute one), comparable between two fits that keep different tracks when both are evaluated
    on the same tracks at the same variance."""
    return float(sum(min(sse / variance, chi2_quantile(n, options.outlier_track_z)) for sse, n in stats.values()))


def _reselected(builder: RotIdGraph, measurement, k: int, prepared, s: _Stage1, pose: gtsam.Pose3, options,
                setup: _Setup, variance: float) -> _Stage1 | None:
    """Measurement k's stage 1 again with its tracks chosen at the FK axis seen from ``pose``, if that keeps more
    of its points than ``s`` and fits its tracks better (lower :func:`_truncated_cost` over the same tracks); else
    None.

    Stage 1 chooses its tracks at its own line. With many wrong arcs (30 % of the tracks) the first rounds can settle
    where some wrong arcs fit and good tracks do not, and from there every round keeps that choice: on the outlier
    scenario one measurement's line sat 10 px off with 11 good tracks rejected and 2 wrong arcs kept, was left out as
    an outlier, and the estimate was 2 mm off instead of 0.4. At the FK axis of an estimate from the other
    measurements the good tracks fit and the wrong arcs do not. A fit that keeps fewer points is not taken: what this
    repairs is good tracks rejected, and on a rendered scene a weak measurement's fit of one track fewer (its axis as
    far from the truth as before) turned the likelihood-ratio test against it."""
    others = {j: why for j, why in s.outliers.items() if not isinstance(why, FitRejection)}
    line = _start_line(builder.camera, setup.axes[k], None, pose)
    try:
        at_fk = _stats_at(builder, measurement, k, prepared, pose, line, others, {})
        if len(at_fk) < 3:
            return None
        chosen = {**others, **_outlier_tracks(at_fk, options)}
        if len(at_fk) - (len(chosen) - len(others)) < 2:
            return None
        new = _stage1_measurement([builder], measurement, k, pose, prepared, options, line, settle=True, skip=chosen)
        if new.n_points <= s.n_points or not np.isfinite(new.sigma2):
            return None
        cost_new = _truncated_cost(_stats_at(builder, measurement, k, prepared, pose, new.rotation, others,
                                             new.circles), variance, options)
        cost_old = _truncated_cost(_stats_at(builder, measurement, k, prepared, pose, s.rotation, others, s.circles),
                                   variance, options)
    except (RotIdError, np.linalg.LinAlgError, RuntimeError, ValueError):  # no better fit found: stage 1's stays
        return None
    if not (np.isfinite(cost_new) and cost_new < cost_old):
        return None
    try:  # as stage 1's own fits (``_refined_stage1``)
        return _checked(builder, measurement, k, pose, prepared, new, options, setup)
    except (np.linalg.LinAlgError, RuntimeError, ValueError):
        return new


def _second_opinion(arm, camera, measurements, setup: _Setup, stage1: list[_Stage1], k: int, pose: gtsam.Pose3,
                    options) -> tuple[_Stage1 | None, float]:
    """Measurement k's disagreement with ``pose`` as a likelihood ratio, and a better stage-1 fit if there is one.

    The linearised chi-square of an image axis (:func:`_chi2`) assumes the axis is Gaussian about the stage-1 fit.
    With few tracks or short arcs it is not: the fit can sit in a local minimum of its own (two arcs of 60 degrees
    admit several coaxial circle pairs), or the cost can rise far more slowly than its curvature says, and a good
    measurement then looks like an outlier (and gets blamed on its joint angles). This fits the measurement's
    circles with its line tied to the FK axis seen from ``pose``, then frees the line from there: if that free fit is
    better than stage 1's, stage 1 was in a local minimum and the new fit replaces it. The returned statistic is
    ``(sse_tied - sse_free) / sigma^2`` (2 dof under the model), at the larger of the measurement's and the median
    pixel noise variance as in :func:`_chi2`; inf if the tied fit fails.
    """
    s = stage1[k]
    if s.keys.coaxial is None:  # a circle-variable stage 1 (its projected fit stalled): no second opinion
        return None, np.nan
    builder = _builder(arm, camera, options, model=Model.PROJECTED, robust=track_huber)
    median = float(np.median([t.sigma2 for t in stage1]))
    refit = _reselected(builder, measurements[k], k, setup.prepared[k], s, pose, options, setup, max(s.sigma2, median))
    if refit is not None:
        s = refit
    tied = _tied_fit(builder, measurements[k], k, setup.prepared[k], s, pose, options, setup)
    if tied is None:
        return refit, np.inf
    sse_tied, line, circles, tie = tied
    r = _stage1_round(builder, measurements[k], k, pose, setup.prepared[k], s.outliers, line, circles, options)
    graph, keys, result, it = r.graph, r.keys, r.values, r.iterations
    stats = _track_stats(graph, keys, result)
    free = _sse(s)
    new_free = float(sum(v[0] for v in stats.values()))
    if np.isfinite(new_free) and new_free < free * (1.0 - 1e-9):
        refit = _stage1_result(builder, graph, keys, result, stats, dict(s.outliers), s.iterations + it, options)
        # as stage 1's own fits (``_refined_stage1``)
        refit = _checked(builder, measurements[k], k, pose, setup.prepared[k], refit, options, setup)
        free = new_free
    variance = max(s.sigma2 if refit is None else refit.sigma2, median)
    return refit, max(sse_tied - free, 0.0) / variance + tie

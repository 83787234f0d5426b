"""Stage 1, per measurement: coaxial circles on one line variable, outlier tracks out and back in at the final line,
the track-correlated (CR2) covariance of the line and, with short arcs, its jackknife.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import NamedTuple

import gtsam
import numpy as np

from ..camera import Camera
from ..errors import RotIdError
from ..factors import (
    image_line_from_rot3,
    line_distance_covariance,
    line_distances,
    rot3_from_line,
)
from ..graph import (
    MeasurementKeys,
    Model,
    RotIdGraph,
    align_line,
    axis_in_camera,
    axis_test_points,
    chi2_quantile,
    initial_circle,
    track_huber,
)
from ..initialise import plane_normal
from ..uncertainty import (
    marginal_information,
)
from .lm import _builder, _lm
from .options import MIN_TRACKS_FOR_SPREAD, CalibrationOptions
from .setup import _Setup, _setup
from .tuning import (
    ALT_SIGMA_RATIO,
    ALT_START_DEG,
    HOLD_SIGMA_RAD,
    JACKKNIFE_GROUPS,
    JACKKNIFE_MIN_GROUPS,
    JACKKNIFE_Z,
    MAX_TRACK_LEVERAGE,
    POOR_FIT_SIGMA_RATIO,
    STAGE1_MAX_ITERATIONS,
    STAGE1_ROUNDS,
    STALL_DECREASE,
    THIN_CURVATURE_SIGMAS,
    WATCH_LINE_PX,
)

# ---------------------------------------------------------------------------------------------------
# stage 1: coaxial circles per measurement


@dataclass
class _Stage1:
    keys: MeasurementKeys
    rotation: gtsam.Rot3  # the line variable at the solution
    circles: dict[int, np.ndarray]  # track -> (d, r) at the solution
    image_axis: np.ndarray  # (3,) the image of the axis (a homogeneous image line, docs/design.md §2)
    image_axis_cov: np.ndarray  # (3, 3) its covariance at unit pixel noise
    sigma2: float  # pixel noise variance from the residuals (chi2 / dof)
    n_points: int
    outliers: dict[int, str]  # track -> reason
    iterations: int
    #: per kept track: (residual sum of squares in px^2, number of points) at the solution
    stats: dict[int, tuple[float, int]] = field(default_factory=dict)
    #: (3, 3) the line variable's information from the pixels at unit pixel noise (its tangent), and its covariance
    #: there at unit noise (with the tracks' correlation and the jackknife's excess, see :func:`_jackknife`)
    rotation_info: np.ndarray | None = None
    rotation_cov: np.ndarray | None = None
    #: (3, 3) the jackknife's excess over the linearised line covariance (tangent, in units of the pixel noise
    #: variance ``sigma2``); zero where the linearisation holds
    excess: np.ndarray = field(default_factory=lambda: np.zeros((3, 3)))
    #: (3, 3) the image axis' covariance (px, not scaled by the pixel noise) that the tracks' own offsets
    #: (``CalibrationOptions.track_offset_px``, :func:`_track_offset_meat`) give; None without them
    offset_axis_cov: np.ndarray | None = None


def _without_tracks(s: _Stage1, why: dict[int, str]) -> _Stage1:
    """``s`` with the tracks ``why`` names (track -> reason) among its outliers and out of its kept tracks, circles,
    statistics and point count (what a measurement's report counts); its line, noise and graph as they were."""
    keys = s.keys
    kept = [j for j in keys.tracks if j not in why]
    parallel = len(keys.circles) == len(keys.tracks)  # (one circle variable per track; none in the projected model)
    keys = replace(keys, tracks=kept,
                   circles=[c for c, j in zip(keys.circles, keys.tracks, strict=True) if j not in why] if parallel
                   else keys.circles,
                   circle_factors=[f for f, j in zip(keys.circle_factors, keys.tracks, strict=True) if j not in why]
                   if len(keys.circle_factors) == len(keys.tracks) else keys.circle_factors)
    stats = {j: v for j, v in s.stats.items() if j not in why}
    return replace(s, keys=keys, circles={j: c for j, c in s.circles.items() if j not in why}, stats=stats,
                   n_points=sum(n for _, n in stats.values()), outliers={**s.outliers, **why})


def _circles(keys: MeasurementKeys, values) -> list[np.ndarray]:
    """(d, r) of each of a measurement's tracks (in ``keys.tracks`` order) at the values."""
    if keys.coaxial is not None:
        return list(keys.coaxial.circles(values))
    return [values.atVector(c) for c in keys.circles]


def _track_stats(graph, keys: MeasurementKeys, values) -> dict[int, tuple[float, int]]:
    """Per track: (residual sum of squares in px^2, number of points)."""
    if keys.coaxial is not None:
        sse = keys.coaxial.track_sse(values)
        return {j: (float(sse[i]), int(keys.coaxial.counts[i])) for i, j in enumerate(keys.tracks)}
    out = {}
    for j, fi in zip(keys.tracks, keys.circle_factors, strict=True):
        e = graph.at(fi).unwhitenedError(values)
        out[j] = (float(e @ e), len(e))
    return out


def _cube_root_variances(stats: dict[int, tuple[float, int]], options: CalibrationOptions
                         ) -> tuple[np.ndarray, np.ndarray]:
    """Per track (in ``stats`` order): ``y = v^(1/3) / (1 - h)`` of its residual variance ``v = sse / (n - 2)``,
    ``h = 2 / (9 (n - 2))`` (Wilson-Hilferty: nearly normal, mean ``sigma^(2/3)``), and its relative sampling
    variance ``h / (1 - h)^2`` at white noise of one variance ``sigma^2``."""
    sse = np.array([v[0] for v in stats.values()], dtype=float)
    dof = np.array([max(v[1] - 2, 1) for v in stats.values()], dtype=float)
    h = 2.0 / (9.0 * dof)
    return np.cbrt(np.maximum(sse / dof, options.min_sigma_px**2)) / (1.0 - h), h / (1.0 - h) ** 2


class FitRejection(str):
    """The reason a track is rejected for not fitting its circle (a ``str``: what the result reports). Stage 1
    re-tests these, and only these, at its final line (see :func:`_retest`); other reasons (too short, an
    outlier of the graph builder, a jackknife group) are plain strings."""

    __slots__ = ()


def _outlier_tracks(stats: dict[int, tuple[float, int]], options: CalibrationOptions,
                    spread: float = 0.0) -> dict[int, FitRejection]:
    """Tracks that do not fit: a residual RMS far above the measurement's median, or a residual variance beyond the
    99.9 % point (``outlier_track_z``) about the tracks' median (an arc of a wrong circle fits a coaxial one only
    roughly).

    The second is a chi-square test in Wilson-Hilferty form (:func:`_cube_root_variances`). ``spread``: relative
    variance, on that scale, of the good tracks' noise levels beyond chi-square sampling (a tracker measures small
    or faint dots less precisely than large, contrasty ones; see :func:`_noise_spread`); 0 tests every track at
    the one median noise level.
    """
    rms = {j: np.sqrt(sse / n) for j, (sse, n) in stats.items()}
    median = max(float(np.median(list(rms.values()))), options.min_sigma_px)
    y, sampling = _cube_root_variances(stats, options)
    centre = float(np.median(y))
    z = (y / centre - 1.0) / np.sqrt(sampling + spread)
    sigma = centre**1.5  # the median track's noise (px)
    out = {}
    for i, (j, (sse, n)) in enumerate(stats.items()):
        if rms[j] > options.outlier_track_ratio * median:
            out[j] = FitRejection(f"residual RMS {rms[j]:.2f} px > {options.outlier_track_ratio:g}x the median "
                                  f"{median:.2f} px")
        elif z[i] > options.outlier_track_z:
            limit = (1.0 + options.outlier_track_z * np.sqrt(sampling[i] + spread)) ** 1.5
            rms_j = np.sqrt(sse / max(n - 2, 1))
            levels = f" and a spread of the tracks' noise levels of {150.0 * np.sqrt(spread):.0f} %" if spread else ""
            out[j] = FitRejection(f"does not fit a circle about the axis: residual RMS {rms_j:.3f} px is "
                                  f"{rms_j / sigma:.2f}x the median track's {sigma:.3f} px, beyond the 99.9 % point "
                                  f"{limit:.2f}x for {n} points{levels}")
    return out


def _noise_spread(stats_per_measurement: list[dict[int, tuple[float, int]]], options: CalibrationOptions) -> float:
    """How much the noise level differs between good tracks, beyond chi-square sampling: the relative variance on
    the scale of :func:`_cube_root_variances`, pooled over the measurements (each track against its measurement's
    median), from the lower half of the tracks only (median to 10 % point), which wrong arcs (that only add residual)
    hardly reach: with 30 % of them it comes out ~1.4x too large, where a full-spread estimate would let them all in.

    ~0 for white pixel noise of one variance (the simulator); tracked dots differ (on the rendered reference scene the
    tracks' residual RMS spread 0.79-1.30x their measurement's median, 5-95 %, where sampling allows 0.90-1.11x).
    """
    u, sampling = [], []
    for stats in stats_per_measurement:
        if len(stats) < 3:
            continue
        y, s = _cube_root_variances(stats, options)
        u.extend(y / np.median(y) - 1.0)
        sampling.extend(s)
    if len(u) < MIN_TRACKS_FOR_SPREAD:
        return 0.0
    u, sampling = np.asarray(u), np.asarray(sampling)

    def lower_spread(spread: float) -> float:  # of the standardised values, from their lower tail (normal: 1)
        z = u / np.sqrt(sampling + spread)
        return float(np.median(z) - np.quantile(z, 0.1)) / 1.2816  # the normal's 10 % point

    if lower_spread(0.0) <= 1.0:
        return 0.0
    low, high = 0.0, 1.0
    for _ in range(40):  # bisection: the spread at which the standardised values' lower half is a unit normal's
        mid = 0.5 * (low + high)
        low, high = (mid, high) if lower_spread(mid) > 1.0 else (low, mid)
    return high


def _noise_variance(stats: dict[int, tuple[float, int]], line_dof: int, options: CalibrationOptions) -> float:
    sse = sum(v[0] for v in stats.values())
    n = sum(v[1] for v in stats.values())
    dof = max(n - line_dof - 2 * len(stats), 1)
    return max(sse / dof, options.min_sigma_px**2)


def _track_correlation(factor, values, sigma2: float = 1.0, intrinsics: bool = False) -> np.ndarray:
    """(3, 3) information ``D`` that the line's pixels lack when their errors are correlated within a track; with
    ``intrinsics`` (8, 8), at the line and the factor's intrinsics variable together, where it has one.

    ``H = sum_j H_j`` (the factor's information, per track) assumes independent pixel errors of the factor's
    sigma. The per-track scores ``s_j`` give the cluster-robust meat ``B = sum_j s_j s_j^T`` (independent tracks,
    any correlation inside a track: a tracker's sub-pixel bias that follows its dot), with two corrections:

    - the scores are taken at the measurement's own optimum, ``s_j - H_j H^-1 sum s`` (in the joint graph the
      pose holds the line away from it, and the summed score is that pull, not noise);
    - each is corrected for its track's leverage ``A_j = H^-1/2 H_j H^-1/2`` (CR2: ``(I - A_j)^-1/2`` on the
      whitened score), so that under white noise of variance ``sigma2`` (in the factor's units) the whitened
      meat ``M = H^-1/2 B H^-1/2`` has expectation ``sigma2 I`` exactly (leverages capped at
      ``MAX_TRACK_LEVERAGE``).

    An eigenvalue of ``M / sigma2`` counts as correlation only beyond ``1 + 3 sd`` (``sd^2 = 2 sum_j h_j^2``,
    ``h_j`` the tracks' leverages along it: its scatter under white noise; a few long arcs carry most of a
    line's information). ``D = H^1/2 (M / sigma2 - (1 + 3 sd))_+ H^1/2``, so that the covariance becomes
    ``H^-1 (H + D) H^-1``; it only grows (the noise model is the floor).
    """
    per_track = factor.track_information(values, intrinsics=intrinsics)
    H = per_track.sum(axis=0)
    S = factor.track_scores(values, intrinsics=intrinsics)
    S = S - per_track @ np.linalg.lstsq(H, S.sum(axis=0), rcond=None)[0]
    w, V = np.linalg.eigh(0.5 * (H + H.T))
    keep = w > 1e-12 * max(w.max(), 1e-300)
    root = V[:, keep] * np.sqrt(w[keep])  # H = root root^T
    W = (V[:, keep] / np.sqrt(w[keep])).T  # whitening: W H W^T = I
    Z = S @ W.T
    A = np.einsum("ab,jbc,dc->jad", W, per_track, W)
    a, Q = np.linalg.eigh(0.5 * (A + np.swapaxes(A, 1, 2)))
    # a track whose leverage nears 1 holds a direction alone: its score there is rounding noise, which CR2 would
    # amplify without bound (and a per-track information that is not positive semi-definite gives leverages above
    # 1: a Jaco2 dot scene with corner tracks, leverage 1.6, clipped to 1 - 1e-9, made a 0.3 mm 1 sigma 500 mm)
    unshrink = 1.0 / np.sqrt(1.0 - np.clip(a, 0.0, MAX_TRACK_LEVERAGE))
    Z = np.einsum("jab,jb,jcb,jc->ja", Q, unshrink, Q, Z)
    m, U = np.linalg.eigh(Z.T @ Z)
    h = np.einsum("ai,jab,bi->ji", U, A, U)  # leverage of each track along each eigenvector
    allowance = 3.0 * np.sqrt(2.0 * np.sum(h**2, axis=0))
    excess = np.maximum(m / sigma2 - 1.0 - allowance, 0.0)
    return root @ ((U * excess) @ U.T) @ root.T


def _track_offset_meat(factor, values, tau_px: float, intrinsics: bool = False) -> np.ndarray:
    """(3, 3) (with ``intrinsics`` (8, 8), where the factor has them) the meat that each track's own image translation
    ``t_j ~ N(0, tau_px^2 I)``, independent across tracks, adds to the factor's variable(s): ``tau^2 sum_j V_j
    V_j^T`` (``V_j`` the factor's ``track_translation_scores``: how the gradient moves with the translation), in
    the factor's own units (its information's). A shift that follows a track over its whole arc moves the image
    axis through that track's leverage, more for the few long arcs that carry a line, which no number of other
    tracks averages out (the ambient scenes' blob centroids pulled by shading, corners drifting on turning
    surfaces: 0.1-0.3 px)."""
    V = factor.track_translation_scores(values, intrinsics=intrinsics)
    meat = tau_px**2 * np.einsum("jau,jbu->ab", V, V)
    return 0.5 * (meat + meat.T)


def _axis_watch(builder: RotIdGraph, k: int, prepared):
    """What stage 1's LM watches: the image axis at the corners of the tracks' bounding box."""
    corners = np.array([np.min([t.ideal.min(axis=0) for t in prepared.usable.values()], axis=0),
                        np.max([t.ideal.max(axis=0) for t in prepared.usable.values()], axis=0)])

    def image_axis_at_corners(v):
        line, _ = image_line_from_rot3(builder.camera.K, v.atRot3(builder.line_key(k)))
        return line_distances(line, corners)

    return image_axis_at_corners


class _Round(NamedTuple):
    """One LM round of a measurement's stage-1 graph."""

    graph: gtsam.NonlinearFactorGraph
    keys: MeasurementKeys
    values: gtsam.Values          # the solution
    iterations: int
    start_error: float
    error: float


def _stage1_round(builder, measurement, k, pose, prepared, skip, line_start, circles_start, options,
                  settle: bool = False) -> _Round:
    graph, values = gtsam.NonlinearFactorGraph(), gtsam.Values()
    keys = builder.add_measurement(graph, values, k, measurement, arm_T_camera=pose, tie=False,
                                   prepared=prepared, skip_tracks=skip, refine_circles=False,
                                   initial_line=line_start, initial_circles=circles_start)
    warm = 0
    if settle and circles_start is None and keys.coaxial is not None:
        # circles started from each track's rays about the start line: let them settle with the line held first
        held = gtsam.NonlinearFactorGraph()
        held.push_back(graph)
        held.add(gtsam.PriorFactorRot3(keys.line_key, values.atRot3(keys.line_key),
                                       gtsam.noiseModel.Isotropic.Sigma(3, HOLD_SIGMA_RAD)))
        values, warm, _, _ = _lm(held, values, min(options.max_iterations, STAGE1_MAX_ITERATIONS),
                                 relative_tolerance=options.stage1_tolerance)
    start_error = graph.error(values)
    result, it, error, _ = _lm(graph, values, min(options.max_iterations, STAGE1_MAX_ITERATIONS),
                               relative_tolerance=options.stage1_tolerance, watch=_axis_watch(builder, k, prepared),
                               watch_tolerance=WATCH_LINE_PX)
    return _Round(graph, keys, result, it + warm, start_error, error)


def _stage1_result(builder, graph, keys, result, stats, skip, iterations, options) -> _Stage1:
    R = result.atRot3(keys.line_key)
    line, J = image_line_from_rot3(builder.camera.K, R)
    info = marginal_information(graph, result, keys.line_key, 3)  # unit pixel noise
    w, V = np.linalg.eigh(info)
    cov_R = (V / np.maximum(w, 1e-12 * max(w.max(), 1e-300))) @ V.T
    circles = dict(zip(keys.tracks, _circles(keys, result), strict=True))
    sigma2 = _noise_variance(stats, 3, options)
    offset = None
    if keys.coaxial is not None and (options.track_offset_px or 0.0) > 0.0:  # (the graph is at unit pixel noise)
        plain = cov_R @ _track_offset_meat(keys.coaxial, result, options.track_offset_px) @ cov_R
        offset = J @ plain @ J.T
    if keys.coaxial is not None:  # errors shared along a track: the cluster-robust line covariance
        cov_R = cov_R + cov_R @ _track_correlation(keys.coaxial, result, sigma2) @ cov_R
    return _Stage1(keys, R, circles, line, J @ cov_R @ J.T, sigma2, sum(n for _, n in stats.values()), skip,
                   iterations, stats, info, cov_R, offset_axis_cov=offset)


def _jackknife(builder: RotIdGraph, measurement, k: int, pose: gtsam.Pose3, prepared, s: _Stage1,
               options) -> _Stage1:
    """Measurement k's line covariance checked by a delete-a-group jackknife over its tracks; where the jackknife
    exceeds the linearised covariance beyond its own sampling scatter, the jackknife's is taken.

    The linearised covariance (with the tracks' correlation, :func:`_track_correlation`) is the curvature of the
    cost at the fit. Where the line rests on a few tracks whose arcs are short, the cost is far from quadratic
    and one or two tracks can hold a direction alone; the fit then moves far more when they are left out than
    the curvature says (6 poses of 25 degree corner arcs: one line 1-1.5 px off at its test points, 7 sigma of its
    linearised covariance, 1 sigma of this jackknife's). The tracks are split into ``JACKKNIFE_GROUPS`` groups (one
    track each up to that many; else round robin over the measurement's usable tracks, kept or not, so that a track
    kept or left out changes one group only), the line refitted without each group from the fit, and ``C_j = (G - 1)
    / G sum (t_g - t)(t_g - t)^T`` of the tangent offsets ``t_g``. Whitened by the linearised covariance, an
    eigenvalue ``m`` of ``C_j`` counts only near or beyond the 99.9 % point ``l`` of its scatter under the model (a
    chi-square of G - 1 dof over G - 1, Bonferroni over 3 directions: ``JACKKNIFE_Z``), so that the jackknife's
    noise does not inflate a good measurement's covariance: that direction's variance grows by ``m - 1`` from ``l``
    on, by a share of it rising from none at ``m - 1 = (l - 1) / 2`` (:func:`jackknife_growth`). A threshold alone
    made the covariance jump by ``l - 1`` times as ``m`` crossed it, and with it verdicts: one track more or fewer
    in a rendered Jaco2 photo scene (its pixels moved by 1e-6 px) left a measurement out or kept it, and called the
    result usable or not.
    """
    tracks = list(s.keys.tracks)
    if len(tracks) <= JACKKNIFE_GROUPS:  # one track per group
        members = [[j] for j in tracks]
    else:
        rank = {j: i for i, j in enumerate(sorted(set(prepared.usable) | set(tracks)))}
        members = [[j for j in tracks if rank[j] % JACKKNIFE_GROUPS == g] for g in range(JACKKNIFE_GROUPS)]
        members = [group for group in members if group]
    groups = len(members)
    if groups < JACKKNIFE_MIN_GROUPS or s.keys.coaxial is None or s.rotation_cov is None:
        return s
    offsets = []
    for left_out in members:
        skip = {**s.outliers, **{j: "jackknife" for j in left_out}}
        try:
            graph, keys, result = _stage1_round(builder, measurement, k, pose, prepared, skip, s.rotation,
                                                dict(s.circles), options)[:3]
        except RotIdError:
            return s
        offsets.append(gtsam.Rot3.Logmap(s.rotation.between(result.atRot3(keys.line_key))))
    t = np.asarray(offsets)
    if not np.all(np.isfinite(t)):
        return s
    deviation = t - t.mean(axis=0)
    jack = (groups - 1) / groups * deviation.T @ deviation / s.sigma2  # at unit pixel noise, as rotation_cov
    w, V = np.linalg.eigh(0.5 * (s.rotation_cov + s.rotation_cov.T))
    if w.min() <= 0.0:
        return s
    root = V * np.sqrt(w)  # rotation_cov = root root^T
    inverse_root = (V / np.sqrt(w)).T
    m, U = np.linalg.eigh(inverse_root @ jack @ inverse_root.T)
    grow = jackknife_growth(m, chi2_quantile(groups - 1, JACKKNIFE_Z) / (groups - 1))
    if not grow.any():
        return s
    excess = root @ ((U * grow) @ U.T) @ root.T
    cov_R = s.rotation_cov + excess
    _, J = image_line_from_rot3(builder.camera.K, s.rotation)
    return replace(s, image_axis_cov=J @ cov_R @ J.T, rotation_cov=cov_R, excess=excess)


def jackknife_growth(m: np.ndarray, limit: float) -> np.ndarray:
    """How much :func:`_jackknife` grows each whitened direction's variance, from the jackknife's eigenvalue ``m``
    there and the 99.9 % point ``limit`` of its scatter under the model: ``m - 1`` from ``limit`` on, ``(m - 1)``
    times a share rising linearly from 0 at ``m - 1 = (limit - 1) / 2`` to 1 at ``limit`` (continuous in ``m``), none
    below."""
    excess, half = np.maximum(np.asarray(m, dtype=float) - 1.0, 0.0), 0.5 * (limit - 1.0)
    return excess * np.clip((excess - half) / half, 0.0, 1.0)


def _thin(prepared, s: _Stage1) -> bool:
    """Whether measurement ``s``'s kept tracks' ellipses are thin against its pixel noise: their median radius of
    curvature at the ellipse's ends (b^2 / a) below THIN_CURVATURE_SIGMAS pixel sigmas."""
    tracks = [prepared.usable[j] for j in s.keys.tracks if j in prepared.usable]
    if not tracks or not np.isfinite(s.sigma2) or s.sigma2 <= 0.0:
        return False
    semi = np.array([t.ellipse.axes for t in tracks], dtype=float) / 2.0
    curvature_radius = semi.min(axis=1) ** 2 / np.maximum(semi.max(axis=1), 1e-12)
    return bool(np.median(curvature_radius) < THIN_CURVATURE_SIGMAS * np.sqrt(s.sigma2))


def _checked(builder: RotIdGraph, measurement, k: int, pose: gtsam.Pose3, prepared, s: _Stage1, options,
             setup: _Setup) -> _Stage1:
    """Measurement k's fit, its line covariance checked by the jackknife (:func:`_jackknife`) where the linearised
    one is in doubt: some measurement has short arcs (``setup.short_arcs``), or, where the estimate rests on these
    free-phase lines (``setup.thin_check``), this one's ellipses are thin against its noise (:func:`_thin`)."""
    if setup.short_arcs or (setup.thin_check and _thin(prepared, s)):
        return _jackknife(builder, measurement, k, pose, prepared, s, options)
    return s


def _stage1_measurement(builders: list[RotIdGraph], measurement, k, pose, prepared, options,
                        start_line: gtsam.Rot3 | None = None, settle: bool = False,
                        skip: dict[int, str] | None = None, max_rounds: int = STAGE1_ROUNDS) -> _Stage1:
    """Coaxial circles of one measurement, rejecting outlier tracks round by round.

    ``builders``: the projected model first (fast); if LM cannot lower its error at all (wrong arcs far from
    any coaxial circle can make the projected-out circles jump between solutions from one line to the next),
    the measurement is redone with the next builder's model (circle variables that move continuously).
    ``skip``: tracks left out from the first round (default none).
    """
    builder, *fallbacks = builders
    skip = dict(skip or {})
    iterations = 0
    line_start, circles_start = start_line, None
    rounds = 0
    while True:
        r = _stage1_round(builder, measurement, k, pose, prepared, skip, line_start, circles_start, options, settle)
        graph, keys, result, start_error, error = r.graph, r.keys, r.values, r.start_error, r.error
        iterations += r.iterations
        # (a later round starts at the previous round's solution: a small decrease there is convergence)
        if fallbacks and rounds == 0 and error >= (1.0 - STALL_DECREASE) * start_error and start_error > 0.0:
            builder, *fallbacks = fallbacks  # stalled from the start: redo this round with the next model
            continue
        rounds += 1
        stats = _track_stats(graph, keys, result)
        new = _outlier_tracks(stats, options)
        # the last round's fit is the result: a track it flags stays in (rejecting it without a new fit would
        # report it rejected while the line and the counts still include it)
        if not new or len(stats) - len(new) < 2 or rounds >= max_rounds:
            break
        skip.update(new)
        line_start = result.atRot3(keys.line_key)  # the next round starts where this one ended
        circles_start = dict(zip(keys.tracks, _circles(keys, result), strict=True))
    return _stage1_result(builder, graph, keys, result, stats, skip, iterations, options)


def circles_about(K: np.ndarray, prepared, line: gtsam.Rot3, known: dict[int, np.ndarray], tracks) -> dict:
    """``known`` plus, for each of ``tracks`` not in it, a start ``(d, r)`` about the line variable ``line`` from the
    track's rays and its ellipse centre (a circle solve is local: one started about another axis can end in a worse
    minimum)."""
    R = line.matrix()
    K_inv = np.linalg.inv(K)
    circles = dict(known)
    for j in tracks:
        if j not in circles:
            track = prepared.usable[j]
            rays = np.column_stack([track.ideal, np.ones(len(track.ideal))]) @ K_inv.T
            centre_ray = K_inv @ np.append(track.ellipse.centre, 1.0)
            circles[j] = np.array(initial_circle(R[:, 0], R[:, 1], rays, centre_ray))
    return circles


#: Reasons of stage 1's fit tests (the tracks that :func:`_readmit_tracks` re-tests).
def _retest(builder: RotIdGraph, measurement, k, pose, prepared, s: _Stage1, options):
    """Every track stage 1 kept or rejected for its fit, at its final line: (stats, circles) with the rejected
    tracks' circles solved there (started from their rays about that line: the builder's start is about the FK axis
    seen from ``pose``, which can be degrees off the line of a measurement of short arcs)."""
    circles = circles_about(builder.camera.K, prepared, s.rotation, s.circles,
                            [j for j, why in s.outliers.items() if isinstance(why, FitRejection)])
    others = {j: why for j, why in s.outliers.items() if not isinstance(why, FitRejection)}
    graph, values = gtsam.NonlinearFactorGraph(), gtsam.Values()
    keys = builder.add_measurement(graph, values, k, measurement, arm_T_camera=pose, tie=False, prepared=prepared,
                                   skip_tracks=others, refine_circles=False, initial_line=s.rotation,
                                   initial_circles=circles)
    # each rejected track's pull on the line: its score at the line fitted without it, against the score's
    # white-noise covariance (sigma2 times its information)
    pull = {}
    if keys.coaxial is not None:
        factor = keys.coaxial
        scores, informations = factor.track_scores(values), factor.track_information(values)
        for i, j in enumerate(keys.tracks):
            if j in s.outliers:
                pull[j] = float(scores[i] @ np.linalg.pinv(informations[i]) @ scores[i]) * factor.sigma_px**2 / s.sigma2
    return _track_stats(graph, keys, values), dict(zip(keys.tracks, _circles(keys, values), strict=True)), pull


def _readmit_tracks(builders, measurements, pose, setup: _Setup, stage1: list[_Stage1], options,
                    only=None) -> list[_Stage1]:
    """Re-test at each measurement's final line the tracks stage 1 rejected for their fit, allowing for the spread
    of the tracks' noise levels (:func:`_noise_spread`, over every measurement), and fit again with those that pass;
    ``only``: the measurements to re-test (default all; the others are already re-tested fits).

    Stage 1's rounds test every track at the one median noise level, against a line that the outliers may still
    pull: that cleans wrong arcs out, but also rejects good tracks of a tracker's noisier dots (10-20 % of the
    rendered reference scene's tracks) and, in a measurement of short arcs, tracks whose circles ran off to degenerate
    ones while LM's first round was still far from the final line. A track must also pass a score test: its
    gradient on the line (fitted without it) within the 99.9 % point of its white-noise distribution; an arc of a
    wrong circle can fit its own circle within the spread and still drag the line (30 % wrong arcs: 1.8 mm error
    instead of 0.4 mm without this test).
    """
    tested = {k: _retest(builders[0], measurements[k], k, pose, setup.prepared[k], s, options)
              for k, s in enumerate(stage1) if (only is None or k in only)
              and any(isinstance(why, FitRejection) for why in s.outliers.values())}
    if not tested:
        return stage1
    spread = _noise_spread([tested[k][0] if k in tested else s.stats for k, s in enumerate(stage1)], options)
    out = list(stage1)
    limit = chi2_quantile(3, options.outlier_track_z)
    for k, (stats, circles, pull) in tested.items():
        s = stage1[k]
        flagged = _outlier_tracks(stats, options, spread)
        # a wrong arc can fit its own circle within the noise spread and still drag the line: it is not taken back
        flagged.update({j: FitRejection(f"pulls the axis away from the other tracks' (score test {value:.3g} > "
                                        f"{limit:.3g}, 3 dof, at the line fitted without it)")
                        for j, value in pull.items() if j not in flagged and value > limit})
        back = [j for j, why in s.outliers.items() if isinstance(why, FitRejection) and j not in flagged]
        s.outliers.update({j: why for j, why in flagged.items() if j in s.outliers})  # the reasons at the final line
        if not back:
            continue
        builder = builders[0] if s.keys.coaxial is not None else builders[-1]
        skip = {j: why for j, why in s.outliers.items() if j not in back}
        line_start, circles_start, iterations = s.rotation, {**s.circles, **{j: circles[j] for j in back}}, s.iterations
        for rounds in range(1, 3):
            r = _stage1_round(builder, measurements[k], k, pose, setup.prepared[k], skip, line_start, circles_start,
                              options)
            graph, keys, result = r.graph, r.keys, r.values
            iterations += r.iterations
            stats = _track_stats(graph, keys, result)
            new = _outlier_tracks(stats, options, spread)
            if not new or len(stats) - len(new) < 2 or rounds == 2:
                break
            skip.update(new)
            line_start = result.atRot3(keys.line_key)
            circles_start = dict(zip(keys.tracks, _circles(keys, result), strict=True))
        out[k] = _stage1_result(builder, graph, keys, result, stats, skip, iterations, options)
    return out


def stage1_builders(arm, camera, options) -> list:
    """Stage 1's graph builders: the projected circles' model, then the full one. Huber per whole track (at its
    chi-square 99.9 % point): a wrong arc that the tests let through has a bounded pull; a good track is
    untouched."""
    return [_builder(arm, camera, options, model=Model.PROJECTED, robust=track_huber),
            _builder(arm, camera, options, robust=track_huber)]


def _rank(s: _Stage1) -> tuple[int, float]:
    cost = float(sum(v[0] for v in s.stats.values()))
    return -len(s.stats), cost if np.isfinite(cost) else np.inf


def _better(s: _Stage1, than: _Stage1) -> bool:
    """Whether stage-1 fit ``s`` of a measurement is better than ``than``: a fit whose residual sigma is beyond
    POOR_FIT_SIGMA_RATIO times the other's loses (a poor minimum); else the most tracks kept, then the lowest cost."""
    ratio = POOR_FIT_SIGMA_RATIO**2
    if np.isfinite(s.sigma2) and not than.sigma2 <= ratio * s.sigma2:
        return True
    if np.isfinite(than.sigma2) and not s.sigma2 <= ratio * than.sigma2:
        return False
    return _rank(s) < _rank(than)


def _stage1(arm, camera, measurements, pose, setup: _Setup, options, image_axes: bool = True,
            max_rounds: int = STAGE1_ROUNDS, alternatives: bool = True) -> list[_Stage1]:
    """Each measurement's stage-1 fit from ``pose``: from its FK axis turned onto the image axis through its
    ellipses' centres (``image_axes``), or from the FK axis itself with the circles settled first; the tracks a fit
    rejected re-tested at its final line (:func:`_readmit_tracks`). From the image axes with ``alternatives``, a
    measurement whose fit's residual sigma stands out (beyond ALT_SIGMA_RATIO times the median of the others') and
    whose two starts lie more than ALT_START_DEG apart is fitted from the FK axis too, and the better fit kept
    (:func:`_better`): a spin seen nearly end-on, whose image axis only its circles' perspective orients, has minima
    apart, and its ellipses' centres can start it in a poor one whose inflated noise widens its axis until it agrees
    with anything. Six 6 s spins of 7-11 tracks, measurements 1 and 3 given each other's tracks: from the centres
    the exchanged measurement 1 kept 7 of its 11 tracks at 2.75 px (the others 1.2-1.3 px), and ``weighted`` called
    the result usable 80 mm off (the error's chi-square 38.7); from the FK axis it keeps all 11 at 1.3 px, and the
    exchange is refused. (Fitting every measurement from both starts where they lie 3 degrees apart also found
    better fits of good measurements, about half of those of six 6 s spins, but took the synced reference scene's
    calibration from 1.1 to 1.35 s.)"""
    builders = stage1_builders(arm, camera, options)
    starts = [_start_line(camera, setup.axes[k], setup.centre_axes[k] if image_axes else None, pose)
              for k in range(len(measurements))]
    stage1 = [_stage1_measurement(builders, m, k, pose, setup.prepared[k], options, starts[k], settle=not image_axes,
                                  max_rounds=max_rounds)
              for k, m in enumerate(measurements)]
    stage1 = _readmit_tracks(builders, measurements, pose, setup, stage1, options)
    if not (image_axes and alternatives):
        return stage1
    sigmas = np.sqrt([s.sigma2 for s in stage1])
    ks = []
    for k in range(len(measurements)):
        others = np.delete(sigmas, k)
        others = others[np.isfinite(others)]
        if not (others.size and sigmas[k] > ALT_SIGMA_RATIO * np.median(others)):
            continue  # (not standing out; NaN never does)
        line = _start_line(camera, setup.axes[k], None, pose)
        if np.degrees(np.linalg.norm(starts[k].localCoordinates(line))) > ALT_START_DEG:  # (else the same fit)
            ks.append(k)
    if not ks:
        return stage1
    trial, fitted = _refit(builders, camera, measurements, pose, setup, options, stage1, ks, image_axes=False,
                           max_rounds=max_rounds)
    return [trial[k] if k in fitted and _better(trial[k], s) else s for k, s in enumerate(stage1)]


def _refit(builders, camera, measurements, start, setup: _Setup, options, fits, ks, image_axes: bool = True,
           max_rounds: int = STAGE1_ROUNDS):
    """``fits`` with each measurement of ``ks`` fitted again alone from ``start``: its FK axis turned onto the image
    axis through the ellipses' centres, or (``image_axes`` false) the FK axis itself with the circles settled first;
    the tracks a refit rejected for their fit re-tested at its final line, as ``_stage1`` does for every fit.
    Returns (the fits, the measurements refitted); one whose refit fails keeps its fit."""
    trial, fitted = list(fits), []
    for k in ks:
        try:
            trial[k] = _stage1_measurement(
                builders, measurements[k], k, start, setup.prepared[k], options,
                _start_line(camera, setup.axes[k], setup.centre_axes[k] if image_axes else None, start),
                settle=not image_axes, max_rounds=max_rounds)
        except (RotIdError, RuntimeError, np.linalg.LinAlgError):
            continue
        fitted.append(k)
    return _readmit_tracks(builders, measurements, start, setup, trial, options, only=fitted), fitted


def _start_line(camera: Camera, axis, image_axis: np.ndarray, pose: gtsam.Pose3) -> gtsam.Rot3:
    """Stage 1's start: the FK axis seen from ``pose``, turned onto the image axis through the ellipse centres.

    The image decides the projection plane and the pose only the tilt within it, so a poor pose (wrong joint
    angles) does not start the circles far from their tracks. Without ``image_axis`` (None), the FK axis as the
    pose sees it (a pose fitted to stage 1's lines: the axis through the centres of short arcs' ellipses can be
    far off).
    """
    line, _ = rot3_from_line(*axis_in_camera(axis, pose))
    return line if image_axis is None else align_line(line, plane_normal(camera.K, image_axis))


def _test_pixels(camera: Camera, axis, pose: gtsam.Pose3) -> np.ndarray:
    """(2, 2) the images of an FK axis' two test points under ``pose``."""
    return camera.project(np.array([pose.transformTo(p) for p in axis_test_points(axis)]), distort=False)


def _offset_of(stage1: _Stage1, pixels: np.ndarray) -> np.ndarray | None:
    """(2, 2) what a measurement's tracks' own offsets give its test-point distances (``pixels``: the test points'
    images, :func:`_test_pixels`); None without them."""
    return None if stage1.offset_axis_cov is None else line_distance_covariance(stage1.offset_axis_cov, pixels)


class MeasuredNoise(NamedTuple):
    """A measurement's pixel noise (px per image coordinate), the tracks stage 1 leaves out (track -> reason), and
    the (2, 2) covariance (px²) that its tracks' own offsets (``CalibrationOptions.track_offset_px``) give its image
    axis' test-point distances at the pose (None without them)."""

    sigma: float
    outliers: dict[int, str]
    offset_covariance: np.ndarray | None = None


def measured_noise(arm, camera: Camera, measurements, pose: gtsam.Pose3, options: CalibrationOptions | None = None
                   ) -> list[MeasuredNoise | None]:
    """Each measurement's :class:`MeasuredNoise` as ``calibrate`` measures it: its line fitted alone to its tracks,
    started about the FK axis seen from ``pose``. None for a measurement that cannot be fitted alone (too few usable
    tracks, no finite residuals). For counting what a recording already knows at its own noise (the planner)."""
    options = CalibrationOptions() if options is None else options
    out = []
    for m in measurements:
        try:
            setup = _setup(arm, camera, [m], options, minimum=1)
            s = _stage1(arm, camera, [m], pose, setup, options)[0]
        except (RotIdError, np.linalg.LinAlgError, RuntimeError):
            out.append(None)
            continue
        if not (np.isfinite(s.sigma2) and s.sigma2 > 0):
            out.append(None)
            continue
        offset = _offset_of(s, _test_pixels(camera, setup.axes[0], pose))
        out.append(MeasuredNoise(float(np.sqrt(s.sigma2)), dict(s.outliers), offset))
    return out

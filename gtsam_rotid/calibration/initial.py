"""The guess-free start: pose candidates from the image axes (:mod:`gtsam_rotid.initialise`), refined by LM on
the stage-2 distances, the twin of a pose about the axes' common point, random restarts.
"""

from __future__ import annotations

import gtsam
import numpy as np

from ..arm import Arm
from ..camera import Camera
from ..dataset import Measurement
from ..factors import (
    make_axis_to_line_factor,
)
from ..geometry import closest_point
from ..graph import (
    axis_test_points,
)
from ..initialise import plane_normal, pose_candidates
from ..uncertainty import (
    pose_information,
)
from .lm import _lm, _turned
from .options import CalibrationError, CalibrationOptions
from .setup import _Setup, _setup
from .tuning import (
    GAUGE_FLOOR,
    GAUGE_SIGMA,
    MAX_STARTS,
    POSE_KEY,
    TWIN_ERROR_RATIO,
    TWIN_ITERATIONS,
    TWIN_MIN_ANGLE_DEG,
    WEAK_ARC_DEG,
    WEAK_MANY_TRACKS,
    WEAK_RELATIVE,
)


def _stage2_graph(axes, lines, K, noises) -> gtsam.NonlinearFactorGraph:
    graph = gtsam.NonlinearFactorGraph()
    for axis, line, noise in zip(axes, lines, noises, strict=True):
        graph.add(make_axis_to_line_factor(noise, POSE_KEY, axis_test_points(axis), line, K))
    return graph


def _gauge_prior(graph: gtsam.NonlinearFactorGraph, anchor: gtsam.Pose3,
                 scale: float = 1.0) -> gtsam.PriorFactorPose3 | None:
    """A prior at ``anchor`` along the pose directions the image-axis graph leaves (nearly) undetermined there.

    Pixel noise tilts the cost along such a direction (single crossing: the camera's ray to the crossing point,
    where the noisy image axes fit better the farther the camera) and LM would slide the camera metres, even
    kilometres, along it. Directions whose information is below ``WEAK_RELATIVE`` of the largest get a prior of
    sigma ``GAUGE_SIGMA`` (rad, m); the others one of information ``GAUGE_FLOOR`` (it moves nothing there: the
    data's information is >= 1e5 times larger), so that the prior is a full-rank Gaussian. None when nothing is
    weak. ``scale`` multiplies the prior's information: a graph whose noise models are not the data's (the paper's
    unit line noise) passes the variance those units stand for, so that the prior pulls as hard, relative to the
    data, as in a graph weighted by the real noise.
    """
    values = gtsam.Values()
    values.insert(POSE_KEY, anchor)
    information = pose_information(graph, values, POSE_KEY)
    if not np.all(np.isfinite(information)):  # e.g. test points behind the camera: no sensible gauge there
        return None
    w, V = np.linalg.eigh(information)
    weak = w < WEAK_RELATIVE * max(w.max(), 1e-300)
    if not weak.any():
        return None
    prior = scale * np.where(weak, GAUGE_SIGMA**-2, GAUGE_FLOOR)
    return gtsam.PriorFactorPose3(POSE_KEY, anchor, gtsam.noiseModel.Gaussian.Information((V * prior) @ V.T))


def _stage2_minima(graph, starts, options, max_iterations: int | None = None, anchor: gtsam.Pose3 | None = None,
                   gauge_scale: float = 1.0) -> list[tuple[gtsam.Pose3, float, int, int]]:
    """LM from each start, with the :func:`_gauge_prior` at ``anchor`` (default: at the start); (pose, error,
    iterations, index of the start) per start, in the order of ``starts``."""
    out = []
    for i, start in enumerate(starts):
        values = gtsam.Values()
        values.insert(POSE_KEY, start)
        gauged = graph
        prior = _gauge_prior(graph, start if anchor is None else anchor, gauge_scale)
        if prior is not None:
            gauged = gtsam.NonlinearFactorGraph()
            gauged.push_back(graph)
            gauged.add(prior)
        result, iterations, _, _ = _lm(gauged, values, max_iterations or options.max_iterations,
                                       diagonal_damping=False)
        out.append((result.atPose3(POSE_KEY), graph.error(result), iterations, i))
    return out


def _best_stage2(graph, starts, options, max_iterations: int | None = None,
                 anchor: gtsam.Pose3 | None = None) -> tuple[gtsam.Pose3, float, int, int]:
    """(pose, error, iterations, index of the start) of the lowest error of :func:`_stage2_minima`."""
    return min(_stage2_minima(graph, starts, options, max_iterations, anchor), key=lambda m: m[1])


def guess_free_minima(K: np.ndarray, axes, lines, options) -> tuple[list, gtsam.NonlinearFactorGraph, list]:
    """The guess-free fit of the FK ``axes`` to the image ``lines`` (one homogeneous line per axis): the pose
    candidates from the back-projected planes (:func:`pose_candidates`), the unweighted stage-2 graph, and LM's minima
    from every candidate (as :func:`_stage2_minima`), best first; no minima where no candidate puts the wrist in
    front of the camera."""
    normals = np.array([plane_normal(K, line) for line in lines])
    candidates = pose_candidates(normals, axes, n_best=options.n_candidates)
    graph = _stage2_graph(axes, lines, K, [gtsam.noiseModel.Isotropic.Sigma(2, 1.0)] * len(axes))
    minima = sorted(_stage2_minima(graph, candidates, options), key=lambda m: m[1]) if candidates else []
    return candidates, graph, minima


def _distinct(pose: gtsam.Pose3, others) -> bool:
    """``pose`` is turned more than TWIN_MIN_ANGLE_DEG from each of ``others`` (positions are not compared: along
    an undetermined direction they differ arbitrarily between starts of the same solution)."""
    return all(_turned(other, pose) > np.radians(TWIN_MIN_ANGLE_DEG) for other in others)


def _random_restarts(pose: gtsam.Pose3, n: int, rng: np.random.Generator) -> list[gtsam.Pose3]:
    out = []
    for _ in range(n):
        xi = np.concatenate([rng.normal(scale=np.radians(10.0), size=3), rng.normal(scale=0.1, size=3)])
        out.append(pose.retract(xi))
    return out


def twin_pose(arm_T_camera: gtsam.Pose3, point) -> gtsam.Pose3:
    """The camera turned half a turn about its ray to ``point`` (centre fixed).

    When every wrist axis passes through ``point`` the two see the same image lines: image axes alone
    cannot tell them apart, the circles can.
    """
    t = np.asarray(arm_T_camera.translation(), dtype=float)
    ray = np.asarray(point, dtype=float) - t
    half_turn = gtsam.Rot3.AxisAngle(gtsam.Point3(ray / np.linalg.norm(ray)), np.pi)
    return gtsam.Pose3(half_turn.compose(arm_T_camera.rotation()), t)


def initial_pose(arm: Arm, camera: Camera, measurements: list[Measurement],
                 options: CalibrationOptions | None = None) -> gtsam.Pose3:
    """Guess-free initial ``arm_T_camera`` from ellipse-centre lines and FK axes (docs/design.md §5)."""
    options = CalibrationOptions() if options is None else options
    return _initial(arm, camera, measurements, options)[0][0]


def axis_miss_rms(camera: Camera, setup: _Setup, lines, pose: gtsam.Pose3, options) -> tuple[gtsam.Pose3, float]:
    """The pose (LM from ``pose``) that fits the FK axes to the image ``lines`` unweighted, and how far they miss
    there (px RMS over the test points)."""
    unit = [gtsam.noiseModel.Isotropic.Sigma(2, 1.0)] * len(setup.axes)
    fitted, error, _, _ = _best_stage2(_stage2_graph(setup.axes, lines, camera.K, unit), [pose], options)
    return fitted, float(np.sqrt(2.0 * error / (2 * len(setup.axes))))


def poor_start(setup: _Setup, rms: float, options, what: str = "image axes") -> CalibrationError:
    """The refusal of a start whose FK axes miss the ``what`` by ``rms`` px RMS: the tracking named first where
    measurements have few tracks of short arcs."""
    thin = [f"measurement {setup.index[k]}: {len(p.usable)} tracks, longest arc {setup.turning[k]:.0f}°"
            for k, p in enumerate(setup.prepared) if len(p.usable) < WEAK_MANY_TRACKS
            and setup.turning[k] < WEAK_ARC_DEG]
    first = ("; the tracking is the likelier cause: these measurements have few tracks and short arcs ("
             + "; ".join(thin) + "), so their image axes can be far off: "
             "spin the wrist longer (a full turn or more) or give the hand more texture, then check joint "
             "angles and camera intrinsics") if thin else "; check joint angles, camera intrinsics and tracks"
    return CalibrationError(f"initialisation ended in a poor minimum: the FK axes miss the {what} by {rms:.1f} px "
                            f"RMS (limit {options.max_initial_rms_px} px)" + first)


def _initial(arm, camera, measurements, options, index=None, tolerance: float = 1.0
             ) -> tuple[list[gtsam.Pose3], _Setup, list[gtsam.Pose3]]:
    """Starting poses (one, or a pose and its twin when the image axes cannot tell them apart), the setup, and
    per start the candidate it came from (before LM: the anchor of :func:`_gauge_prior`). A start whose FK axes
    miss the image axes through the ellipse centres by more than ``tolerance`` times ``max_initial_rms_px`` is
    refused (:func:`poor_start`); ``calibrate`` allows more here and checks again against stage 1's coaxial fits,
    which are far better where arcs are short."""
    setup = _setup(arm, camera, measurements, options, index)
    candidates, graph, minima = guess_free_minima(camera.K, setup.axes, setup.centre_axes, options)
    if not candidates:
        raise CalibrationError("no pose candidate puts the wrist in front of the camera; check the joint angles "
                               "and that the tracks belong to the wrist")
    pose, error, _, best = minima[0]
    rms = np.sqrt(2.0 * error / (2 * len(setup.axes)))
    if rms > tolerance * options.max_initial_rms_px:
        raise poor_start(setup, rms, options, "image axes (through the ellipses' centres)")
    # Other minima that explain the image axes about as well are kept for the circles to decide: with three
    # measurements the image axes give exactly six equations, which have several exact solutions.
    starts, anchors = [pose], [candidates[best]]
    for other, other_error, _, i in minima[1:]:
        if len(starts) < MAX_STARTS and other_error < TWIN_ERROR_RATIO * error + 1.0 and _distinct(other, starts):
            starts.append(other)
            anchors.append(candidates[i])
    # Near a single crossing the half-turned twin explains the image axes as well: keep it for the circles
    # to decide (elsewhere LM takes the twin back to ``pose``).
    # A genuine twin is a minimum next to its start; elsewhere LM would crawl back to ``pose`` for many
    # iterations, so it gets few.
    crossing = closest_point(setup.axes)
    twin, twin_error, _, _ = _best_stage2(graph, [twin_pose(pose, crossing)], options,
                                          max_iterations=TWIN_ITERATIONS)
    if len(starts) < MAX_STARTS and twin_error < TWIN_ERROR_RATIO * error + 1.0 and _distinct(twin, starts):
        starts.append(twin)
        anchors.append(twin_pose(candidates[best], crossing))
    return starts, setup, anchors

"""The Levenberg-Marquardt loop the stages share (with stop rules on what moves), the graph builder with the
options' settings, and small pose comparisons.
"""

from __future__ import annotations

import gtsam
import numpy as np

from ..arm import Arm
from ..camera import Camera
from ..graph import (
    RotIdGraph,
    lm_params,
)
from .options import CalibrationOptions
from .tuning import ANCHOR_SIGMA, POSE_KEY


def _lm(graph: gtsam.NonlinearFactorGraph, values: gtsam.Values, max_iterations: int, anchor: bool = False,
        diagonal_damping: bool = True, relative_tolerance: float = 1e-8, watch=None, watch_tolerance: float = 0.0):
    """LM; with ``anchor`` a weak prior at the start of ``POSE_KEY`` keeps undetermined directions still.

    Diagonal damping suits the graphs with line and circle variables (their Jacobians differ in scale by
    orders of magnitude); isotropic damping never steps along a direction of exactly zero information,
    which keeps a degenerate stage 2 where it started. ``watch(values) -> vector`` names what the solve is
    for (an image line, the pose): LM also stops once two successive iterations change it by less than
    ``watch_tolerance`` (each axis' tilt within its projection plane, a nuisance, can otherwise crawl on
    for tens of iterations); the tolerance is scaled by the residual RMS in pixels. The returned error is that
    of ``graph`` alone.
    """
    if anchor:
        anchored = gtsam.NonlinearFactorGraph()
        anchored.push_back(graph)
        anchored.add(gtsam.PriorFactorPose3(POSE_KEY, values.atPose3(POSE_KEY),
                                            gtsam.noiseModel.Isotropic.Sigma(6, ANCHOR_SIGMA)))
        result, iterations, _, converged = _lm(anchored, values, max_iterations,
                                               diagonal_damping=diagonal_damping,
                                               relative_tolerance=relative_tolerance, watch=watch,
                                               watch_tolerance=watch_tolerance)
        return result, iterations, graph.error(result), converged
    params = lm_params(max_iterations, relative_tolerance, diagonal_damping)
    optimizer = gtsam.LevenbergMarquardtOptimizer(graph, values, params)
    if watch is None:
        result = optimizer.optimize()
        converged = optimizer.iterations() < max_iterations
        return result, optimizer.iterations(), graph.error(result), converged
    error, watched, quiet = optimizer.error(), watch(values), 0
    n_residuals = sum(graph.at(i).dim() for i in range(graph.size()))
    converged = False
    while optimizer.iterations() < max_iterations:
        optimizer.iterate()
        new_error, new_watched = optimizer.error(), watch(optimizer.values())
        # the tolerance is per pixel of residual RMS, so noise-free data converge to noise-free precision
        rms = np.sqrt(2.0 * new_error / max(n_residuals, 1))
        quiet = quiet + 1 if np.max(np.abs(new_watched - watched)) < watch_tolerance * rms else 0
        small_decrease = error - new_error <= relative_tolerance * max(error, 1e-300)
        error, watched = new_error, new_watched
        if quiet >= 2 or small_decrease or optimizer.lambda_() >= params.getlambdaUpperBound():
            converged = True
            break
    result = optimizer.values()
    return result, optimizer.iterations(), graph.error(result), converged


def _builder(arm: Arm, camera: Camera, options: CalibrationOptions, **kwargs) -> RotIdGraph:
    return RotIdGraph(arm, camera, pose_key=POSE_KEY, tie_sigma_px=options.tie_sigma_px,
                      min_track_points=options.min_track_points, min_track_extent_px=options.min_track_extent_px,
                      **kwargs)


def _graph_dof(graph: gtsam.NonlinearFactorGraph, values: gtsam.Values) -> int:
    """Residuals minus parameters of a graph at its values."""
    residuals = sum(graph.at(i).dim() for i in range(graph.size()))
    return int(residuals - values.dim())


def _turned(a: gtsam.Pose3, b: gtsam.Pose3) -> float:
    """Rotation angle (rad) between two poses."""
    return float(np.linalg.norm(a.localCoordinates(b)[:3]))

"""Circles fitted about the estimate's wrist axes, for drawing and residual plots (the calibration layer: the
plots draw these fits and never solve themselves).

:func:`fit_tracks` holds measurement ``k``'s FK wrist axis fixed where ``result.arm_T_camera`` puts it and solves
each kept track's circle ``(d, r)`` about it; :class:`TrackFit` holds the circles and each track's signed pixel
residuals.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import gtsam
import numpy as np

from .errors import InputError
from .factors import circle_point_residuals
from .graph import RotIdGraph, lm_params


@dataclass
class TrackFit:
    """One measurement's tracks fitted with circles about its FK wrist axis mapped into the camera by the estimate.

    ``line`` is the wrist axis as a line variable (camera frame, unit camera-to-axis distance, see
    :mod:`gtsam_rotid.factors`); ``circles[j]`` is track j's ``(d, r)``; ``residuals[j]`` its signed pixel
    distances to its projected circle (ideal pixels).
    """

    index: int
    line: gtsam.Rot3 | None
    circles: dict[int, np.ndarray] = field(default_factory=dict)
    residuals: dict[int, np.ndarray] = field(default_factory=dict)
    problem: str = ""

    @property
    def all_residuals(self) -> np.ndarray:
        return np.concatenate(list(self.residuals.values())) if self.residuals else np.zeros(0)


def fit_tracks(result, dataset, k: int, max_iterations: int = 30) -> TrackFit:
    """Fit measurement ``k``'s kept tracks (those the result did not reject) with circles about the wrist axis
    projected by ``result.arm_T_camera``; the axis is held fixed, only each track's ``(d, r)`` moves."""
    measurement = dataset[k]
    skip = set(result.measurements[k].rejected_tracks) if k < len(result.measurements) else set()
    builder = RotIdGraph(dataset.arm, dataset.camera)
    graph, values = gtsam.NonlinearFactorGraph(), gtsam.Values()
    try:
        keys = builder.add_measurement(graph, values, k, measurement, arm_T_camera=result.arm_T_camera, tie=False,
                                       skip_tracks=skip)
    except (InputError, ValueError) as exc:  # too few tracks, or the axis through the camera centre
        return TrackFit(k, None, problem=str(exc))
    line = values.atRot3(keys.line_key)
    graph.add(gtsam.NonlinearEqualityRot3(keys.line_key, line))
    fitted = gtsam.LevenbergMarquardtOptimizer(graph, values, lm_params(max_iterations, 1e-6)).optimize()
    fit = TrackFit(k, line)
    prepared = builder.prepare(measurement, k)
    for j, circle_key in zip(keys.tracks, keys.circles, strict=True):
        d, r = fitted.atVector(circle_key)
        fit.circles[j] = np.array([d, r])
        fit.residuals[j] = circle_point_residuals(dataset.camera.K, line, d, r, prepared.usable[j].ideal,
                                                  jacobians=False)[0]
    return fit

"""The choice between starts. Where the image axes cannot tell two starting poses apart (a pose and its twin), the
joint fit of the circles from each decides, whatever the method: each start's joint result is re-solved on one common
graph and the lowest chi-square wins; the other distinct solutions become :class:`Alternative`.
"""

from __future__ import annotations

from typing import NamedTuple

import gtsam
import numpy as np

from .joint import Fitted, _joint, common_chi2
from .lm import _turned
from .options import CalibrationError
from .result import Alternative, CalibrationResult
from .stage1 import _Stage1
from .stage2 import _check_scale
from .tuning import CHI2_6_999, SAME_ANGLE_DEG


class Choice(NamedTuple):
    """The chosen start (its position in the runs), its joint result and the stage-1 fits that result was made
    from, and the other distinct solutions."""

    best: int
    joint: CalibrationResult
    stage1: list[_Stage1]
    alternatives: list[Alternative]


def choose_start(arm, camera, measurements, setup, runs, anchors, options, memo: dict | None = None) -> Choice:
    """The joint fit from each run ``(start, stage1)`` and the best of them (:func:`_choose`); raises the first
    run's failure when every one fails (a wrong start's circles may not fit at all). ``memo`` keeps each run's
    joint fit (:func:`checked_joint`) for a later choice among more runs."""
    joints, fits, failures = [], [], []
    for run, anchor in zip(runs, anchors, strict=True):
        try:
            fitted = checked_joint(arm, camera, measurements, setup, run, options, anchor, memo)
            joints.append(fitted.result)
            fits.append(fitted.stage1)
        except CalibrationError as failure:
            joints.append(None)
            fits.append(None)
            failures.append(failure)
    if len(failures) == len(runs):
        raise failures[0]
    best, alternatives = _choose(arm, camera, measurements, setup, joints, options)
    return Choice(best, joints[best], fits[best], alternatives)


def checked_joint(arm, camera, measurements, setup, run, options, anchor, memo: dict | None = None) -> Fitted:
    """The joint fit from the run ``(start, stage1)`` with its scale checked (:func:`_check_scale`), or its
    CalibrationError; kept in ``memo`` (by the run's stage-1 fits, which the caller keeps) and taken from it again:
    the same run gives the same fit."""
    start, stage1 = run
    key = id(stage1)
    if memo is None or key not in memo:
        try:
            fitted = _joint(arm, camera, measurements, setup, stage1, start, options, anchor)
            _check_scale(fitted.result, setup, fitted.stage1, options)
            outcome = fitted
        except CalibrationError as failure:
            outcome = failure
        if memo is None:
            memo = {}
        memo[key] = (stage1, outcome)  # (the stage-1 fits held, so that their id is not reused)
    outcome = memo[key][1]
    if isinstance(outcome, CalibrationError):
        raise outcome
    return outcome


def _same_solution(result: CalibrationResult, pose: gtsam.Pose3) -> bool:
    """``pose`` is ``result``'s solution again: inside its 99.9 % region when the covariance is usable, else
    turned less than SAME_ANGLE_DEG from it (positions differ arbitrarily along undetermined directions)."""
    xi = result.arm_T_camera.localCoordinates(pose)
    if result.observability.is_observable:
        try:
            return float(xi @ np.linalg.solve(result.covariance, xi)) <= CHI2_6_999
        except np.linalg.LinAlgError:
            pass
    return float(np.linalg.norm(xi[:3])) < np.radians(SAME_ANGLE_DEG)


def _choose(arm, camera, measurements, setup, joints: list[CalibrationResult | None],
            options) -> tuple[int, list[Alternative]]:
    """The joint result that fits best and the other distinct ones as :class:`Alternative`.

    The results may have rejected different tracks and estimated different pixel noise, so their own errors are
    not comparable: each pose is re-solved on one graph (the tracks and measurements none of them rejected, one
    pixel sigma per measurement) and the chi-squares of that graph compared.
    """
    ok = [i for i, r in enumerate(joints) if r is not None]
    if len(ok) == 1:
        return ok[0], []
    results = [joints[i] for i in ok]
    chi2, poses = common_chi2(arm, camera, measurements, setup, results, options)
    order = [int(j) for j in np.argsort(chi2)]
    best = results[order[0]]
    alternatives: list[Alternative] = []
    for j in order[1:]:
        if not np.isfinite(chi2[j]) or _same_solution(best, poses[j]) or any(
                _turned(a.arm_T_camera, poses[j]) < np.radians(SAME_ANGLE_DEG) for a in alternatives):
            continue
        alternatives.append(Alternative(poses[j], float(chi2[j] - chi2[order[0]])))
    return ok[order[0]], alternatives

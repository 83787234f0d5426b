"""Joint offsets refined with the pose (``CalibrationOptions(joint_offsets=...)``): zero-position errors of the joints
before the spinning one, common to every pose (the reading plus the offset is the joint's angle).

First the image axes of stage 1 (every measurement's coaxial circles, which do not depend on the kinematics) are
fitted by a pose and the offsets, each offset under its Gaussian prior (mean 0, ``joint_offset_sigma_deg``), each
measurement down-weighted by Huber on its axis' chi-square (a wrong reading on one pose must not become an offset of
every pose): :func:`offsets_from_axes`. The readings shifted by those offsets then go through the whole calibration
(stage 1 again, the robust stage 2, the joint fit); the joint graph keeps the offsets as a variable (the rest of the
offset, under the same prior), so the pose's covariance includes the offsets' uncertainty and the offsets get
theirs (``CalibrationResult.joint_offsets``, ``.joint_offsets_covariance``).

The first joint's offset turns the whole arm as the pose does: no camera data determine it (``True`` leaves it out;
named, it stays at its prior). Other combinations may be undetermined by the poses at hand; their posterior then
equals their prior, which :func:`determined_offsets` counts.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..arm import Arm
from ..dataset import Measurement
from ..graph import chi2_quantile
from .modelcheck import _gauss_newton, _offset_rows

#: Gauss-Newton iterations of the axes' fit, and its Huber threshold on a measurement's axis chi-square (2 dof).
ITERATIONS = 30
HUBER_Z = 3.09
#: Offsets the image axes give beyond this many prior sigmas are refused (a wrong model, not zero offsets).
MAX_OFFSET_SIGMAS = 5.0
#: An offset whose posterior 1 sigma exceeds this fraction of its prior's is reported as not determined (its prior
#: holds it).
HELD_BY_PRIOR = 0.7
#: An offsets direction whose posterior variance is below this fraction of its prior variance is determined.
DETERMINED_FRACTION = 0.25


@dataclass(frozen=True)
class OffsetsPrior:
    """The offsets the calibration refines: joint indices (model order), the axes' estimate the readings were
    shifted by (rad), and the prior 1 sigma of each total offset (rad, mean 0)."""

    joints: tuple[int, ...]
    start: np.ndarray
    sigma: np.ndarray

    def names(self, arm: Arm) -> list[str]:
        return [arm.joint_names[j] for j in self.joints]


def shifted(arm: Arm, measurements: list[Measurement], joints, delta) -> list[Measurement]:
    """The measurements with ``delta`` (rad) added to the readings of ``joints``."""
    out = []
    for m in measurements:
        q = arm.joint_angle_vector(m.joint_angles).copy()
        q[list(joints)] += delta
        out.append(m.replace(joint_angles=q))
    return out


def offsets_from_axes(arm: Arm, camera, setup, stage1, pose, measurements, joints, sigma) -> tuple[np.ndarray, object]:
    """Pose and offsets (rad) fitted to stage 1's image axes (every measurement with a finite one) by Gauss-Newton,
    the offsets under their prior N(0, sigma^2), each measurement Huber-weighted on its axis' chi-square. Returns
    (offsets, pose)."""
    ks = [k for k in range(len(stage1)) if np.all(np.isfinite(stage1[k].image_axis))]
    sigma2 = {k: float(stage1[k].sigma2) for k in ks}
    angles = [arm.joint_angle_vector(m.joint_angles) for m in measurements]
    joints = np.asarray(joints, dtype=int)

    def rows_of(delta, pose):
        return _offset_rows(arm, camera, setup, stage1, ks, angles, joints, pose, sigma2, delta, True)
    _, delta, pose, _ = _gauss_newton(rows_of, np.zeros(len(joints)), pose, True,
                                      prior_sigma=np.asarray(sigma, dtype=float),
                                      huber=float(np.sqrt(chi2_quantile(2, HUBER_Z))), iterations=ITERATIONS,
                                      tol=1e-10)
    return delta, pose


def determined_offsets(covariance: np.ndarray | None, sigma: np.ndarray) -> int:
    """How many directions of the offsets the data determine: those whose posterior variance (``covariance``,
    rad^2) is below DETERMINED_FRACTION of the prior's (``sigma``, rad)."""
    if covariance is None or not np.all(np.isfinite(covariance)):
        return 0
    scaled = covariance / np.outer(sigma, sigma)
    return int(np.sum(np.linalg.eigvalsh(0.5 * (scaled + scaled.T)) < DETERMINED_FRACTION))

"""Re-checking a calibration against new spins: does an ``arm_T_camera`` (ours, with its covariance, or another
tool's, without) still explain spins recorded later, and if not, by about how much has the camera moved?

Each spin's image axis is fitted as in stage 1, starting from the FK axis that the pose to check projects. The
distances of the projected FK test points from it are tested (χ², 2 dof per spin) under the axis' own covariance,
the tracker's prior floor and what the pose's covariance passes into them. The move is the pose correction that
best explains the axes (Gauss-Newton, with a weak prior about the old pose: the old covariance is no prior for a
camera that moved): only the directions the new spins determine move; one spin determines two, and cannot tell a
shift of the camera from a turn.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import gtsam
import numpy as np

from ..arm import Arm
from ..camera import Camera
from ..dataset import Dataset, Measurement
from ..errors import InputError
from ..factors import line_distances
from ..graph import Model, axis_test_points, track_huber
from ..uncertainty import chi2_sf
from .lm import _builder
from .options import CalibrationOptions
from .setup import _setup
from .stage1 import _jackknife, _stage1
from .stage2 import _axis_distances

#: The calibration still holds unless the new spins' χ² is beyond this P value (the 99.9 % point).
CHECK_P = 1e-3
#: The prior on the move: 1 rad and 1 m (1 sigma), i.e. hardly any (it holds only the undetermined directions).
WEAK_PRIOR = np.array([1.0, 1.0, 1.0, 1.0, 1.0, 1.0])
#: A direction of the move counts as determined by the new spins when their information there is at least this
#: fraction of the total (prior included): the prior then no longer holds it where it was.
DETERMINED_FRACTION = 0.5


@dataclass
class SpinCheck:
    """One new spin against the calibration: its tracks, and its image axis' χ² (2 dof) against the FK axis."""

    index: int
    n_tracks: int
    chi2: float
    name: str = ""


@dataclass
class CheckResult:
    """A calibration re-checked against new spins (data only; :func:`gtsam_rotid.words.check_words` says it)."""

    arm_T_camera: gtsam.Pose3           # the calibration checked
    had_covariance: bool                # False: another tool's pose, taken as exact for the test
    spins: list[SpinCheck]
    chi2: float
    dof: int
    p_value: float
    still_valid: bool
    #: the correction that best explains the new spins (Pose3 tangent, camera frame: rotation rad, translation m):
    #: the camera now sits at ``arm_T_camera.retract(move)``; its covariance: the new spins' (a weak prior holds
    #: the directions they do not determine) plus the calibration's own, when it has one
    move: np.ndarray
    move_covariance: np.ndarray
    #: unit directions (Pose3 tangent) that the new spins determine (the move is read along these)
    determined: list[np.ndarray] = field(default_factory=list)

    @property
    def moved_camera(self) -> gtsam.Pose3:
        return self.arm_T_camera.retract(self.move)

    @property
    def move_mm(self) -> float:
        """How far the camera centre moves (mm, arm frame)."""
        return 1000.0 * float(np.linalg.norm(self.moved_camera.translation() - self.arm_T_camera.translation()))

    @property
    def move_deg(self) -> float:
        return float(np.degrees(np.linalg.norm(self.move[:3])))

    @property
    def move_sigma(self) -> tuple[float, float]:
        """1 sigma of the move's size (mm, deg): the largest standard deviation among its translation and among its
        rotation components."""
        sd = np.sqrt(np.maximum(np.diag(self.move_covariance), 0.0))
        return 1000.0 * float(np.max(sd[3:])), float(np.degrees(np.max(sd[:3])))


def check_calibration(arm_T_camera: gtsam.Pose3, dataset: Dataset | tuple[Arm, Camera, list[Measurement]], *,
                      covariance: np.ndarray | None = None,
                      options: CalibrationOptions | None = None) -> CheckResult:
    """Test ``arm_T_camera`` (the camera's optical frame in the arm's root frame) against the spins of
    ``dataset`` (one or more): see the module docstring. ``covariance`` is the calibration's (6x6, Pose3 tangent,
    as ``CalibrationResult.covariance``), or None for a pose from another tool."""
    if isinstance(dataset, Dataset):
        arm, camera, measurements, metadata = dataset.arm, dataset.camera, list(dataset), dataset.metadata
    else:
        (arm, camera, measurements), metadata = dataset, {}
    if not isinstance(arm_T_camera, gtsam.Pose3):
        raise InputError(f"arm_T_camera must be a gtsam.Pose3, got {type(arm_T_camera).__name__}")
    had_covariance = covariance is not None
    if had_covariance:
        covariance = np.asarray(covariance, dtype=float)
        if covariance.shape != (6, 6) or not np.all(np.isfinite(covariance)):
            raise InputError(f"the calibration's covariance must be a finite 6x6 matrix, got shape "
                             f"{covariance.shape}{'' if np.all(np.isfinite(covariance)) else ' with NaN'}")
        covariance = 0.5 * (covariance + covariance.T)
    prior = np.diag(WEAK_PRIOR**2)
    options = CalibrationOptions() if options is None else options
    if options.axis_floor_px is None:
        from .run import _tracker_floor_px  # the same floor calibrate takes from the dataset's tracker
        options = replace(options, axis_floor_px=_tracker_floor_px(metadata))
    measurements = [m if isinstance(m, Measurement) else Measurement(*m) for m in measurements]
    setup = _setup(arm, camera, measurements, options, minimum=1)
    stage1 = _stage1(arm, camera, measurements, arm_T_camera, setup, options)
    if setup.short_arcs:
        builder = _builder(arm, camera, options, model=Model.PROJECTED, robust=track_huber)
        stage1 = [_jackknife(builder, measurements[k], k, arm_T_camera, setup.prepared[k], s, options)
                  for k, s in enumerate(stage1)]
    floor = setup.floor_covariance
    variance = [max(s.sigma2, float(np.median([t.sigma2 for t in stage1]))) for s in stage1]

    def rows(pose: gtsam.Pose3):
        """Per spin: distances (2,), their Jacobian by the pose's tangent (2, 6), their covariance (2, 2)."""
        out = []
        for k, s in enumerate(stage1):
            points = axis_test_points(setup.axes[k])

            def distances(xi, points=points, s=s):
                moved = pose.retract(xi)
                return line_distances(s.image_axis, camera.project(
                    np.array([moved.transformTo(p) for p in points]), distort=False))

            e = distances(np.zeros(6))
            J = np.empty((len(e), 6))
            for i in range(6):
                step = np.zeros(6)
                step[i] = 1e-6
                J[:, i] = (distances(step) - distances(-step)) / 2e-6
            _, cov = _axis_distances(camera, setup.axes[k], s, pose, variance[k], setup, k)
            out.append((e, J, cov if floor is None else cov + floor))
        return out

    at_pose = rows(arm_T_camera)
    chi2 = []
    for e, J, cov in at_pose:
        total = cov + (J @ covariance @ J.T if had_covariance else 0.0)
        chi2.append(float(e @ np.linalg.pinv(total, hermitian=True) @ e))
    dof = 2 * len(stage1)
    p_value = chi2_sf(float(np.sum(chi2)), dof)
    move, move_covariance, information = _move(arm_T_camera, rows, at_pose, prior)
    if had_covariance:
        move_covariance = move_covariance + covariance
    total_information = information + np.linalg.inv(prior)
    w, V = np.linalg.eigh(np.linalg.solve(total_information, information))  # the data's share, per direction
    determined = [V[:, i] for i in range(6) if w[i] >= DETERMINED_FRACTION]
    spins = [SpinCheck(k, len(s.keys.tracks), chi2[k], getattr(measurements[k], "name", "") or "")
             for k, s in enumerate(stage1)]
    return CheckResult(arm_T_camera, had_covariance, spins, float(np.sum(chi2)), dof, float(p_value),
                       bool(p_value >= CHECK_P), move, move_covariance, determined)


def _move(pose: gtsam.Pose3, rows, at_pose, prior: np.ndarray, steps: int = 8):
    """The correction ``xi`` (tangent at ``pose``) that best explains the spins' axes with ``prior`` on it
    (Gauss-Newton, relinearised at each step), its covariance, and the spins' information at the solution."""
    prior_information = np.linalg.inv(prior)
    current, xi, linearised = pose, np.zeros(6), at_pose
    for _ in range(steps):
        information, gradient = np.zeros((6, 6)), prior_information @ xi
        for e, J, cov in linearised:
            W = np.linalg.pinv(cov, hermitian=True)
            information += J.T @ W @ J
            gradient += J.T @ W @ e
        step = -np.linalg.solve(information + prior_information, gradient)
        current = current.retract(step)
        xi = pose.localCoordinates(current)
        if np.max(np.abs(step)) < 1e-10:
            break
        linearised = rows(current)
    return xi, np.linalg.inv(information + prior_information), information

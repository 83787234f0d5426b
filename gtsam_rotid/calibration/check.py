"""Re-checking a calibration against new spins: does an ``arm_T_camera`` (ours, with its covariance, or another
tool's, without) still explain spins recorded later, and if not, by about how much has the camera moved?

Each spin's image axis is fitted as in stage 1 (free phases, from the image axis through its ellipses' centres and
from the FK axis that the pose to check projects), then, where its tracks carry frame indices, with the rigid spin
as the joint calibration fits it, from each of those fits, the lower cost kept. The distances of the projected FK
test points from it are tested (χ², 2 dof per spin) under the axis' own covariance, the tracker's prior floor and
what the pose's covariance passes into them. The move is the pose correction that best explains the axes
(Gauss-Newton, with a weak prior about the old pose: the old covariance is no prior for a camera that moved): only
the directions the new spins determine move; one spin determines two, and cannot tell a shift of the camera from a
turn.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import NamedTuple

import gtsam
import numpy as np

from ..arm import Arm
from ..camera import Camera
from ..dataset import Dataset, Measurement
from ..errors import InputError, RotIdError
from ..factors import RigidLineFactor, axis_offsets_residuals, axis_point_residuals, image_line_from_rot3
from ..graph import Model, SpinModel, axis_test_points, offset_axis_test_points, track_huber
from ..uncertainty import chi2_sf, marginal_information
from .joint import _joint_variance
from .lm import _builder, _lm
from .options import CalibrationError, CalibrationOptions, camera_motion_level_px, with_tracker_defaults
from .setup import _setup
from .stage1 import (
    _better,
    _checked,
    _refit,
    _stage1,
    _track_correlation,
    _track_offset_meat,
    circles_about,
    stage1_builders,
)
from .stage2 import _axis_distances
from .tuning import STAGE1_MAX_ITERATIONS

#: The calibration still holds unless the new spins' χ² is beyond this P value (the 99.9 % point).
CHECK_P = 1e-3
#: The prior on the move: 1 rad and 1 m (1 sigma), i.e. hardly any (it holds only the undetermined directions).
WEAK_PRIOR = np.array([1.0, 1.0, 1.0, 1.0, 1.0, 1.0])
#: A pose from another tool (no covariance) is taken as good to this, 1 sigma per axis (mm, deg), unless told.
DEFAULT_TOLERANCE = (1.0, 0.1)
#: Stage 1 of each spin starts from the FK axis of the pose checked and of poses turned by these angles (deg) about
#: the camera's x and y axes; the fit of lowest cost is kept, so that where a spin's fit lands does not depend on
#: the pose being checked (from one start a short spin can settle in a minimum of its own).
START_TURNS_DEG = (8.0, 20.0)
#: Halvings of a step of the move's Gauss-Newton that puts some spin's axis behind the camera, before it stops.
MOVE_HALVINGS = 10
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
    had_covariance: bool                # False: another tool's pose, taken as good to ``tolerance``
    spins: list[SpinCheck]
    #: the test of a move: the move's χ² under its covariance (the calibration's included) along the ``dof``
    #: directions the spins determine
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
    #: a spin that alone disagrees (the others agree without it): one spin's tracks or joints, not a move
    odd_spin: int | None = None
    #: for a pose without covariance, the 1 sigma it was taken to have (mm, deg)
    tolerance: tuple[float, float] | None = None
    #: the spins' own agreement once the move is made: their χ² at the moved pose, with 2 n - dof degrees of freedom
    residual_chi2: float = 0.0
    residual_dof: int = 0
    residual_p: float = 1.0
    #: each spin's own image shift counted (px, 1 sigma per coordinate): the camera's shake between the new videos
    #: that their background measured (``metadata["camera_motion"]["level_px"]``); 0 where none was
    image_shift_px: float = 0.0

    @property
    def consistent(self) -> bool:
        """The new spins agree among themselves (with some pose); False: one spin's (or more) tracks or joints."""
        return self.residual_p >= CHECK_P
    @property
    def fully_determined(self) -> bool:
        """The new spins determine every direction of the pose: the move's size can be read."""
        return len(self.determined) == 6

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


def axis_scale_of(result) -> float:
    """A calibration result's scale of its image axes' noise for :func:`check_calibration` (``axis_scale``): its
    ``axis_consistency.scale`` (1 where its axes' scatter did not widen its covariance)."""
    c = getattr(result, "axis_consistency", None)
    return float(c.scale) if c is not None and np.isfinite(c.scale) and c.scale > 1 else 1.0


def check_calibration(arm_T_camera: gtsam.Pose3, dataset: Dataset | tuple[Arm, Camera, list[Measurement]], *,
                      covariance: np.ndarray | None = None, tolerance: tuple[float, float] = DEFAULT_TOLERANCE,
                      options: CalibrationOptions | None = None, joint_offsets: dict[str, float] | None = None,
                      offsets_covariance: np.ndarray | None = None,
                      pose_offsets_covariance: np.ndarray | None = None, axis_scale: float = 1.0) -> CheckResult:
    """Test ``arm_T_camera`` (the camera's optical frame in the arm's root frame) against the spins of
    ``dataset`` (one or more): see the module docstring. ``covariance`` is the calibration's (6x6, Pose3 tangent,
    as ``CalibrationResult.covariance``), or None for a pose from another tool, which is then taken as good to
    ``tolerance`` = (mm, deg), 1 sigma per axis. ``options``: the calibration's own (its joint sigma and the
    tracker's floor).

    ``joint_offsets`` (joint name -> rad, ``CalibrationResult.joint_offsets``): the calibration refined them; the new
    readings are taken plus them, and their uncertainty (``offsets_covariance``, n x n rad², and its cross-covariance
    with the pose, ``pose_offsets_covariance``, 6 x n) moves every new spin's FK axis: it is in each spin's χ², in
    the move's covariance (the part of the offsets' error the move takes up) and in the spins' agreement at the
    moved pose (the rest, which they share: tested on all spins together, by generalised least squares).

    ``axis_scale``: the calibration's scale of its image axes' noise (``CalibrationResult.axis_consistency.scale``
    where its axes disagreed beyond their noise: its covariance carries it): the new spins' axes, tracked the same
    way, are taken to scatter as much (a calibration checked against its own spins had one spin flagged at
    chi-square 14 that its scale of 2.3 counted as noise).

    A dataset whose metadata measured the camera's move between its videos (``metadata["camera_motion"]``,
    :func:`gtsam_rotid.stillness.camera_motion`) counts the moves' scatter (``level_px``, px per image coordinate)
    as an image shift of each spin's own: it moves the spin's axis across itself, both test points' distances alike
    (``level_px² [[1, 1], [1, 1]]`` on each spin's covariance); the moves' mean is a move of the camera, tested."""
    if isinstance(dataset, Dataset):
        arm, camera, measurements, metadata = dataset.arm, dataset.camera, list(dataset), dataset.metadata
    else:
        (arm, camera, measurements), metadata = dataset, {}
    offsets = None
    if joint_offsets:
        joints = arm.offset_joints(list(joint_offsets))
        n = len(joints)
        values = np.array([float(v) for v in joint_offsets.values()])
        C = np.zeros((n, n)) if offsets_covariance is None else np.asarray(offsets_covariance, dtype=float)
        X = np.zeros((6, n)) if pose_offsets_covariance is None else np.asarray(pose_offsets_covariance, dtype=float)
        if C.shape != (n, n) or X.shape != (6, n) or not (np.all(np.isfinite(C)) and np.all(np.isfinite(X))):
            raise InputError(f"the joint offsets' covariance must be finite {n}x{n} (and its cross-covariance with "
                             f"the pose 6x{n}), got {C.shape} and {X.shape}")
        from .offsets import shifted  # the calibration's kinematics: the readings plus its offsets
        measurements = shifted(arm, [m if isinstance(m, Measurement) else Measurement(*m) for m in measurements],
                               joints, values)
        offsets = (joints, C, X)
    if not isinstance(arm_T_camera, gtsam.Pose3):
        raise InputError(f"arm_T_camera must be a gtsam.Pose3, got {type(arm_T_camera).__name__}")
    if not (isinstance(axis_scale, int | float) and np.isfinite(axis_scale) and axis_scale >= 1.0):
        raise InputError(f"axis_scale must be a finite number >= 1, got {axis_scale!r}")
    had_covariance = covariance is not None
    if had_covariance:
        covariance = np.asarray(covariance, dtype=float)
        if covariance.shape != (6, 6) or not np.all(np.isfinite(covariance)):
            raise InputError(f"the calibration's covariance must be a finite 6x6 matrix, got shape "
                             f"{covariance.shape}{'' if np.all(np.isfinite(covariance)) else ' with NaN'}")
        covariance = 0.5 * (covariance + covariance.T)
    else:
        mm, deg = tolerance
        if not (np.isfinite(mm) and np.isfinite(deg) and mm >= 0 and deg >= 0):
            raise InputError(f"the tolerance must be two finite numbers >= 0 (mm, deg), got {tolerance!r}")
        covariance = np.diag([np.radians(deg)] * 3 + [mm / 1000.0] * 3) ** 2
    prior = np.diag(WEAK_PRIOR**2)
    options = CalibrationOptions() if options is None else options
    options = with_tracker_defaults(options, metadata)  # (the floor and offsets calibrate takes)
    measurements = [m if isinstance(m, Measurement) else Measurement(*m) for m in measurements]
    # stage 1's free-phase lines start the rigid spins (and are the test where tracks have no frames): where a spin's
    # ellipses are thin their linearised covariance understates the line's scatter, so they are jackknifed
    # (stage1._thin), as for `weighted` (random Panda poses at 1.5 px^2: the true pose was called changed,
    # chi-square 31 for 6 dof; 8.2 with it); the rigid spin's covariance takes the jackknife's excess as the joint
    # fit's does
    setup = replace(_setup(arm, camera, measurements, options, minimum=1), thin_check=True)
    stage1, candidates = _pose_free_stage1(arm, camera, measurements, arm_T_camera, setup, options)
    stage1 = _rigid_spins(arm, camera, measurements, arm_T_camera, setup, options, stage1, candidates)
    variance = [max(s.sigma2, float(np.median([t.sigma2 for t in stage1]))) for s in stage1]
    level = camera_motion_level_px(metadata)  # each spin's own image shift (px per coordinate)
    level2 = level**2

    def rows(pose: gtsam.Pose3):
        """Per spin: distances (2,), their Jacobian by the pose's tangent (2, 6), their covariance (2, 2)."""
        out = []
        for k, s in enumerate(stage1):  # the projected-axis factor's own distances and Jacobian
            e, J, _ = axis_point_residuals(camera.K, pose, axis_test_points(setup.axes[k]), s.image_axis)
            _, cov = _axis_distances(camera, setup.axes[k], s, pose, axis_scale * variance[k], setup, k, floor=True)
            cov = cov + level2 * np.ones((len(e), len(e)))
            if not (np.all(np.isfinite(e)) and np.all(np.isfinite(J)) and np.all(np.isfinite(cov))):
                raise CalibrationError(f"spin {k}: the calibration puts its wrist axis behind the camera or out of "
                                       "the image; is the pose the camera's optical frame in the arm's root frame "
                                       "(x right, y down, z forward)?")
            out.append((e, J, cov))
        return out

    at_pose = rows(arm_T_camera)
    G = None if offsets is None else [_offsets_jacobian(arm, camera, measurements[k], offsets[0], arm_T_camera,
                                                        s.image_axis) for k, s in enumerate(stage1)]
    if offsets is None:
        chi2_each = [float(e @ np.linalg.pinv(cov + J @ covariance @ J.T, hermitian=True) @ e)
                     for e, J, cov in at_pose]
    else:
        _, C, X = offsets
        joint = np.block([[covariance, X], [X.T, C]])
        chi2_each = [float(e @ np.linalg.pinv(cov + np.hstack([J, g]) @ joint @ np.hstack([J, g]).T, hermitian=True)
                           @ e) for (e, J, cov), g in zip(at_pose, G, strict=True)]
    test = _test(arm_T_camera, rows, at_pose, prior, covariance, G, None if offsets is None else offsets[1:])
    odd = None
    if test.residual_p < CHECK_P and len(stage1) >= 2:  # the spins disagree among themselves: one of them alone?
        # leave each out in turn (a wrong spin drags the fit, so the largest residual need not be its own)
        best = None
        for left in range(len(stage1)):
            keep = [k for k in range(len(stage1)) if k != left]
            rest = _test(arm_T_camera, lambda pose, keep=keep: [rows(pose)[k] for k in keep],
                         [at_pose[k] for k in keep], prior, covariance, None if G is None else [G[k] for k in keep],
                         None if offsets is None else offsets[1:])
            if rest.residual_p >= CHECK_P and (best is None or rest.residual < best[1].residual):
                best = (left, rest)
        if best is not None:
            odd, test = best  # the move is judged without it
    spins = [SpinCheck(k, len(s.keys.tracks), chi2_each[k], getattr(measurements[k], "name", "") or "")
             for k, s in enumerate(stage1)]
    return CheckResult(arm_T_camera, had_covariance, spins, test.chi2, test.dof, test.p_value,
                       bool(test.p_value >= CHECK_P), test.move, test.move_covariance, test.determined, odd,
                       None if had_covariance else (float(tolerance[0]), float(tolerance[1])),
                       test.residual, test.residual_dof, test.residual_p, level)


class _Test(NamedTuple):
    move: np.ndarray
    move_covariance: np.ndarray
    determined: list[np.ndarray]
    chi2: float
    dof: int
    p_value: float
    residual: float
    residual_dof: int
    residual_p: float
    residuals: list[float]


def _block_diagonal(blocks) -> np.ndarray:
    size = sum(len(b) for b in blocks)
    out, i = np.zeros((size, size)), 0
    for b in blocks:
        out[i:i + len(b), i:i + len(b)] = b
        i += len(b)
    return out


def _offsets_jacobian(arm: Arm, camera: Camera, measurement: Measurement, joints, pose: gtsam.Pose3,
                      line: np.ndarray) -> np.ndarray:
    """(2, n): a spin's axis distances by the joint offsets (at the readings given): the offsets' factor's Jacobian
    (:func:`gtsam_rotid.factors.axis_offsets_residuals`)."""
    axis_of = offset_axis_test_points(arm, measurement.joint_angles, joints, measurement.spin_joint)
    return axis_offsets_residuals(camera.K, pose, axis_of, np.zeros(len(joints)), line)[3]


def _test(pose: gtsam.Pose3, rows, at_pose, prior: np.ndarray, covariance: np.ndarray, G=None,
          offsets=None) -> _Test:
    """The move that best explains the spins of ``rows`` and its test against ``covariance`` (the calibration's),
    along the directions they determine; then their own agreement at the moved pose. With the offsets' Jacobians
    ``G`` (per spin) and their (covariance, cross-covariance with the pose) ``offsets``, the calibration's error
    is that of the pose and the offsets: the move takes up ``B`` times the offsets' error (``B``: the move's
    least-squares response to the axes' shifts ``G``), the spins keep ``G - J B`` of it."""
    move, move_covariance, information = _move(pose, rows, at_pose, prior)
    shared = None
    if G is not None:
        C, X = offsets
        Js, Gs = np.vstack([J for _, J, _ in at_pose]), np.vstack(G)
        W = _block_diagonal([np.linalg.pinv(cov, hermitian=True) for _, _, cov in at_pose])
        B = np.linalg.solve(information + np.linalg.inv(prior), Js.T @ W @ Gs)
        covariance = covariance + X @ B.T + B @ X.T + B @ C @ B.T
        shared = Gs @ C @ Gs.T  # the offsets' error, shared by the spins (stacked distances, px^2)
    move_covariance = move_covariance + covariance  # the calibration's own uncertainty too
    # the data's share of the information per direction (the prior is isotropic, so the two commute)
    w, V = np.linalg.eigh(information)
    determined = [V[:, i] for i in range(6) if w[i] >= DETERMINED_FRACTION / (1.0 - DETERMINED_FRACTION)
                  / float(WEAK_PRIOR[0]) ** 2]
    D = np.array(determined).T if determined else np.zeros((6, 0))
    move = D @ (D.T @ move)  # read only along what the spins determine
    dof = len(determined)
    m = D.T @ move
    chi2 = float(m @ np.linalg.pinv(D.T @ move_covariance @ D, hermitian=True) @ m) if dof else 0.0
    moved = rows(pose.retract(move))
    residuals = [float(e @ np.linalg.pinv(cov, hermitian=True) @ e) for e, _, cov in moved]
    residual_dof = 2 * len(at_pose) - dof
    residual = float(sum(residuals))
    if shared is not None:  # the spins' agreement with the offsets' shared error: the generalised least-squares
        # residual of the stacked distances at the moved pose (what one more move would still leave)
        r, Jm = np.concatenate([e for e, _, _ in moved]), np.vstack([J for _, J, _ in moved])
        S_inv = np.linalg.inv(shared + _block_diagonal([cov for _, _, cov in moved]))
        a = Jm.T @ S_inv @ r
        residual = float(r @ S_inv @ r - a @ np.linalg.solve(Jm.T @ S_inv @ Jm + np.linalg.inv(prior), a))
    return _Test(move, move_covariance, determined, chi2, dof, float(chi2_sf(chi2, dof)) if dof else 1.0, residual,
                 residual_dof, float(chi2_sf(residual, residual_dof)) if residual_dof > 0 else 1.0, residuals)


def _pose_free_stage1(arm, camera, measurements, pose, setup, options):
    """Each spin's stage-1 fit from the FK axis of ``pose`` turned onto the image axis through its ellipses' centres
    and, for each spin with only short arcs (no track turning by WEAK_ARC_DEG), from poses turned by START_TURNS_DEG:
    the best fit of each spin kept (:func:`_better`; short arcs jackknifed). A spin with a long arc lands on the same
    circles from the image axis whatever the pose's tilt (``stage1._start_line``): one start (8 starts took 25 s on a
    12 s reference session for the same answer; turning only the short spins took 1.3-1.8x less time on rendered ambient
    sessions with one to three long-arc spins of six, their chi-squares alike). Every spin is fitted again from the FK
    axis itself, and the better fit kept (:func:`_better`): its ellipses' centres can start it in a poor minimum, which
    need not look poor against the others' (6 s spins of ~10 tracks at 1.5 px², one pose set, 40 noise draws checked at
    the true pose: 8 of the 222 spins checked ended beyond the 99.9 % point of their 2-dof chi-square, up to 581, one
    with 2 of its 10 tracks rejected at 1.73 px² where the FK axis' start keeps all ten at 1.49 px², its axis 32 px off;
    three draws stopped with "behind the camera" (:func:`_move`); the seed-0 calibration of ``benchmarks/check.py``
    checked against one draw was called moved at chi-square 4.9e6. With both starts: 4 of 240, three in one draw whose
    spins fit two minima alike, called moved at 33: see :func:`_rigid_spins`).

    Returns (the best fit of each spin, jackknifed where its covariance is in doubt; each spin's fits, the best of the
    starts from the image axis first and the FK axis' second where it could be made)."""
    turned = [pose.compose(gtsam.Pose3(gtsam.Rot3.AxisAngle(axis, float(sign * np.radians(deg))), np.zeros(3)))
              for deg in START_TURNS_DEG for sign in (-1.0, 1.0)
              for axis in (np.array([1.0, 0.0, 0.0]), np.array([0.0, 1.0, 0.0]))]
    best, failure = None, None
    for start in [pose, *turned]:  # (a turned pose's fit of every spin only where the pose's own fails)
        try:
            best = list(_stage1(arm, camera, measurements, start, setup, options, alternatives=False))
        except (RotIdError, RuntimeError, np.linalg.LinAlgError) as error:
            failure = error
            continue
        break
    if best is None:
        raise CalibrationError("no spin's circles could be fitted from the pose checked (few or short tracks?): "
                               f"{failure}") from failure
    builders = stage1_builders(arm, camera, options)
    # the turned starts only for the spins with only short arcs (a spin with a long arc lands on the same circles
    # from any of them)
    short = setup.short_arc_measurements
    for start in turned if short else ():
        try:
            trial, fitted = _refit(builders, camera, measurements, start, setup, options, best, short)
        except (RotIdError, RuntimeError, np.linalg.LinAlgError):
            continue
        for k in fitted:
            if _better(trial[k], best[k]):
                best[k] = trial[k]
    candidates = [[s] for s in best]
    trial, refitted = _refit(builders, camera, measurements, pose, setup, options, best, range(len(best)),
                             image_axes=False)
    for k in refitted:
        candidates[k].append(trial[k])
        if _better(trial[k], best[k]):
            best[k] = trial[k]
    builder = _builder(arm, camera, options, model=Model.PROJECTED, robust=track_huber)
    return [_checked(builder, measurements[k], k, pose, setup.prepared[k], s, options, setup)
            for k, s in enumerate(best)], candidates


def _rigid_spins(arm, camera, measurements, pose, setup, options, fits, candidates):
    """Each spin whose tracks all have frame indices fitted again with the rigid spin (one angle per frame and one
    phase per track, the joint calibration's model) on the tracks its free-phase fit ``fits[k]`` kept, started from
    each of its free-phase fits ``candidates[k]`` (from the image axis, from the FK axis), the one of lowest cost
    kept: its image axis, noise and covariance (cluster-robust, with the free fit's jackknife excess as the joint
    fit counts it, and its tracks' own offsets) replace the free phase's. A short spin of few tracks can have two
    free-phase minima of nearly equal cost some pixels apart, the wrong one lower (40 noise draws of 6 s spins of
    6-12 tracks checked at the true pose: 4 of 240 spins beyond their 99.9 % point, three in one draw, which called
    the unmoved camera moved at chi-square 33); the rigid spin puts them where they belong. Spins without frames, or
    whose rigid fit fails, keep their free-phase fit."""
    builder = _builder(arm, camera, options, model=Model.PROJECTED, spin_model=SpinModel.RIGID, robust=track_huber)
    out = []
    for k, s in enumerate(fits):
        prepared = setup.prepared[k]
        if not s.sigma2 > 0.0 or any(t.frames is None for t in prepared.usable.values()):
            out.append(s)
            continue
        sigma = float(np.sqrt(s.sigma2))
        kept = [j for j in prepared.usable if j not in s.outliers]
        best = None
        for c in candidates[k]:
            graph, values = gtsam.NonlinearFactorGraph(), gtsam.Values()
            try:
                keys = builder.add_measurement(
                    graph, values, k, measurements[k], arm_T_camera=pose, tie=False, prepared=prepared,
                    skip_tracks=s.outliers, refine_circles=False, initial_line=c.rotation,
                    initial_circles=circles_about(camera.K, prepared, c.rotation,
                                                  {j: v for j, v in c.circles.items() if j in kept}, kept),
                    track_sigmas=dict.fromkeys(prepared.usable, sigma))
                result, _, error, _ = _lm(graph, values, min(options.max_iterations, STAGE1_MAX_ITERATIONS),
                                          relative_tolerance=options.stage1_tolerance)
            except (RotIdError, RuntimeError, np.linalg.LinAlgError):
                continue
            factor = keys.coaxial
            if (isinstance(factor, RigidLineFactor) and np.isfinite(error) and np.all(factor.converged(result))
                    and (best is None or error < best[0])):
                best = (error, graph, keys, result)
        if best is None:
            out.append(s)
            continue
        _, graph, keys, result = best
        factor = keys.coaxial
        sigma2 = _joint_variance(graph, keys, result, options)  # (the rigid spin's noise, as the joint fit reads it)
        info = marginal_information(graph, result, keys.line_key, 3)  # (at the free fit's noise sigma)
        try:
            bread = np.linalg.inv(info)
        except np.linalg.LinAlgError:
            out.append(s)
            continue
        meat = _track_correlation(factor, result)
        if s.rotation_info is not None:  # the free fit's jackknife excess, as the joint fit's sandwich takes it
            meat = meat + s.rotation_info @ s.excess @ s.rotation_info / s.sigma2
        cov_R = bread + bread @ meat @ bread
        R = result.atRot3(keys.line_key)
        line, J = image_line_from_rot3(camera.K, R)
        offset = None
        if (options.track_offset_px or 0.0) > 0.0:
            offset = J @ bread @ _track_offset_meat(factor, result, options.track_offset_px) @ bread @ J.T
        out.append(replace(s, rotation=R, image_axis=line, image_axis_cov=J @ cov_R @ J.T / s.sigma2, sigma2=sigma2,
                           rotation_cov=cov_R / s.sigma2, offset_axis_cov=offset,
                           circles=dict(zip(keys.tracks, factor.circles(result), strict=True))))
    return out


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
        if np.max(np.abs(step)) < 1e-10:
            current = current.retract(step)
            xi = pose.localCoordinates(current)
            break
        # a step that puts some spin's axis behind the camera (a direction the spins hold weakly, under the weak
        # prior) is halved until none does; if none of MOVE_HALVINGS does, the move stays where it is
        for _ in range(MOVE_HALVINGS):
            trial = current.retract(step)
            try:
                linearised = rows(trial)
            except CalibrationError:
                step = 0.5 * step
                continue
            break
        else:
            break
        current = trial
        xi = pose.localCoordinates(current)
    return xi, np.linalg.inv(information + prior_information), information

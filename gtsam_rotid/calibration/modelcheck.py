"""Would wrong intrinsics, or joint offsets, explain the image axes better than the exact model does? Tests on the
axes of every measurement, the left-out ones too (:func:`intrinsics_check`, :func:`kinematics_check`), whose numbers
the result keeps (``AxisConsistency.intrinsics``, ``.kinematics``) and whose verdicts make the covariance untrusted
(``untrusted["intrinsics"]``, ``untrusted["kinematics"]``).

A focal length a few percent off, or a principal point some pixels off, moves every projected FK axis by a pattern
that the pose cannot absorb: one measurement then disagrees far beyond its noise and is left out as if its joint
angles were wrong, while the others, fitted by a pose that took up the rest, agree (the reference scene with fx and fy
5 % off: 33 mm off with a 1 sigma of 0.3 mm, covariance called usable). A wrong joint reading on one pose moves one
axis; a wrong camera moves all of them together, in a way three intrinsics describe. Joint offsets (zero-position
errors of the joints before the spinning one, common to every pose) move every FK axis too, each by its own pose's
kinematics: the reference scene with 0.5 degree offsets ended 8-16 mm off with the error's chi-square 145-705 under a
covariance called usable (the axes' scatter had only scaled it), one good measurement left out as an outlier.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from ..arm import Arm
from ..camera import Camera
from ..graph import chi2_quantile
from ..uncertainty import chi2_sf
from .evidence import classify
from .setup import _Setup
from .stage2 import _axis_distances, _axis_rows, _refitted_chi2

#: The intrinsics freed: the focal length (fx and fy together, relative) and the principal point (px).
INTRINSICS = ("focal", "cx", "cy")
#: The exact camera must fail the test of all axes below this P ...
EXACT_P = 1e-3
#: ... and the freed intrinsics pass it at this P ...
FREED_P = 0.01
#: An explanation that passes at this P (the level at which the model as given failed) is a rival of another that
#: puts the camera elsewhere (``undecided``, ``rival``), even where it does not pass at FREED_P (Jaco2, 0.5 degree
#: offsets and a camera 3 % / 10 px off: offsets explain the six axes at P = 0.009, leaving out measurement 5 at P =
#: 0.058; the estimate, on the second, was 10 mm off at chi-square 1.6e5 "usable")
RIVAL_P = EXACT_P
#: ... and improve the chi-square by more than its 99.9 % point (the normal's z) for the intrinsics' dof ...
IMPROVEMENT_Z = 3.09
#: ... and explain the axes better than one wrong measurement does (the others exact, its two distances free), by
#: Akaike's criterion: the intrinsics have one parameter more, worth this much chi-square. A wrong shoulder reading
#: of 1 degree on one pose was otherwise read as a camera error on 3 of 10 reference scenes.
AIC_PER_PARAMETER = 2.0
#: ... and the change be one a calibrated camera could be off by: the focal length within MAX_FOCAL_PERCENT, the
#: principal point within MAX_CENTRE_FRACTION of the image's width and height. Larger changes fit a tracker's shared
#: errors, not a camera (two rendered scenes with exact intrinsics: focal -34 %, cx +163 px; cx -196 px, cy +81 px)
MAX_FOCAL_PERCENT, MAX_CENTRE_FRACTION = 10.0, 0.06
#: ... and larger than a camera calibration's own uncertainty in one of them (OpenCV's: a few tenths of a percent of
#: the focal length, a pixel or two of the principal point): the tracker's shared errors fit changes that small (the
#: rendered dot scene of scenarios/from_pixels.py, intrinsics exact: focal +0.008 %, cx +0.18 px, cy -0.47 px took
#: the axes' chi-square from 35 to 2.6 for 3 dof, and was flagged)
MIN_FOCAL_PERCENT, MIN_CENTRE_PX = 0.5, 2.0
#: Gauss-Newton iterations of the axes' fit (pose, and intrinsics when free).
ITERATIONS = 8
#: Finite-difference steps of the test points' distances by each (relative focal change, px, px).
STEPS = (1e-5, 1e-2, 1e-2)
#: Relative singular value below which a direction of the freed fit counts as undetermined (the first joint's
#: offset turns the whole arm about the base's vertical, which the pose takes up).
RANK_RCOND = 1e-8
#: Joint offsets a robot's zero positions could be off by, and more than its encoders' and mastering's own
#: uncertainty (degrees, the largest offset of the fit): outside, a fit of the tracker's shared errors.
MAX_OFFSET_DEG, MIN_OFFSET_DEG = 3.0, 0.05
#: ... and where the free fit's offsets exceed MAX_OFFSET_DEG, they are fitted again under a prior of this sigma (deg)
PLAUSIBLE_OFFSET_DEG = 1.0
#: Finite-difference step of the FK axes by a joint offset (rad).
OFFSET_STEP = 1e-6
#: Offsets explain the axes beyond chance (``systematic``) where they improve the exact kinematics' chi-square by
#: more than its 99 % point (the normal's z) for their dof: read only where the axes' test failed and their
#: covariance was scaled (``run``), which takes a systematic error for scatter. At 99.9 % (IMPROVEMENT_Z) a Panda's
#: six axes with 0.5 degree offsets on its joints (exact kinematics at P = 0.004, the axes' test failed at 0.01)
#: could never be read so (offsets took chi-square 19.2 to 0.7 for 5 dof; 99.9 % point 20.5) and the estimate was
#: called usable 31 mm off at chi-square 289.
SYSTEMATIC_Z = 2.326


def _camera(camera: Camera, theta) -> Camera:
    return camera.with_intrinsics_changed(1.0 + theta[0], theta[1], theta[2])


def _rows(camera: Camera, setup: _Setup, stage1, ks, pose, sigma2, theta, free: bool):
    """The axes' rows (:func:`stage2._axis_rows`) through the camera changed by ``theta``, their Jacobians extended
    by the intrinsics' (central differences) when ``free``."""
    changed = _camera(camera, theta)
    rows = _axis_rows(changed, setup, stage1, ks, pose, sigma2, floor=True)
    if not free:
        return rows
    out = []
    for k, (e, cov, J) in zip(ks, rows, strict=True):
        G = np.empty((len(e), len(INTRINSICS)))
        for i, step in enumerate(STEPS):
            delta = np.zeros(len(INTRINSICS))
            delta[i] = step
            plus = _axis_distances(_camera(camera, theta + delta), setup.axes[k], stage1[k], pose)[0]
            minus = _axis_distances(_camera(camera, theta - delta), setup.axes[k], stage1[k], pose)[0]
            G[:, i] = (plus - minus) / (2.0 * step)
        out.append((e, cov, np.hstack([J, G])))
    return out


def _fitted(camera: Camera, setup: _Setup, stage1, ks, pose, sigma2, free: bool, theta=None):
    """Gauss-Newton on the axes' chi-square over the pose (and the intrinsics when ``free``) from ``pose`` and the
    camera changed by ``theta``: (chi-square at the last linearisation's minimum, intrinsics change, pose)."""
    theta = np.zeros(len(INTRINSICS)) if theta is None else np.array(theta, dtype=float)
    chi2, theta, pose, _ = _gauss_newton(
        lambda theta, pose: _rows(camera, setup, stage1, ks, pose, sigma2, theta, free), theta, pose, free)
    return chi2, theta, pose


def _apart(a, b, covariance, rows=None, prior_sigma=None) -> float | None:
    """How far pose ``b`` is from pose ``a``: a chi-square under ``covariance`` (the estimate's) plus, with ``rows``
    (the freed fit's, Jacobians extended by its parameters), that fit's own pose covariance with its parameters under
    a Gaussian prior of ``prior_sigma`` each (a vector, their units): an explanation whose pose its parameters leave
    uncertain puts the camera nowhere in particular. None without a finite covariance."""
    if covariance is None or not np.all(np.isfinite(covariance)):
        return None
    total = np.asarray(covariance, dtype=float)
    if rows is not None:
        H = sum(A.T @ np.linalg.inv(cov) @ A for _, cov, A in rows)
        H[6:, 6:] += np.diag(1.0 / np.asarray(prior_sigma, dtype=float) ** 2)
        try:
            total = total + np.linalg.inv(H)[:6, :6]
        except np.linalg.LinAlgError:
            return None
    d = a.localCoordinates(b)
    return float(d @ np.linalg.solve(total, d))


def _gauss_newton(rows_of: Callable, theta: np.ndarray, pose, free: bool, rcond: float | None = None,
                  prior_sigma=None, huber: float | None = None, iterations: int = ITERATIONS, tol: float = 1e-9):
    """Gauss-Newton on the axes' chi-square over the pose (and the model's parameters ``theta`` when ``free``):
    ``rows_of(theta, pose)`` gives the rows of :func:`stage2._axis_rows` (Jacobians extended by theta's when free).
    Returns (chi-square at the last linearisation's minimum, theta, pose, the rank of the last normal matrix at
    ``rcond``). ``prior_sigma`` (a scalar or one per parameter): theta under a zero-mean Gaussian prior of that sigma
    (not in the chi-square). ``huber``: each row weighted down by Huber's rule where the square root of its
    chi-square exceeds this threshold."""
    chi2, rank = np.inf, 0
    for _ in range(iterations):
        rows = rows_of(theta, pose)
        if not all(np.all(np.isfinite(e)) and np.all(np.isfinite(A)) for e, _, A in rows):
            break
        W = [np.linalg.inv(cov) for _, cov, _ in rows]
        if huber is not None:
            norms = [float(np.sqrt(max(e @ w @ e, 0.0))) for (e, _, _), w in zip(rows, W, strict=True)]
            W = [w if norm <= huber else w * (huber / norm) for w, norm in zip(W, norms, strict=True)]
        H = sum(A.T @ w @ A for (_, _, A), w in zip(rows, W, strict=True))
        g = sum(A.T @ w @ e for (e, _, A), w in zip(rows, W, strict=True))
        if free and prior_sigma is not None:
            information = np.broadcast_to(1.0 / np.asarray(prior_sigma, dtype=float) ** 2, theta.shape)
            H[6:, 6:] += np.diag(information)
            g[6:] += information * theta
        step, _, rank, _ = np.linalg.lstsq(H, g, rcond=rcond)
        step = -step
        chi2 = _refitted_chi2(rows, 0.0)
        pose = pose.retract(step[:6])
        if free:
            theta = theta + step[6:]
        if np.linalg.norm(step) < tol:
            break
    return chi2, theta, pose, int(rank)


def intrinsics_check(camera: Camera, setup: _Setup, stage1, pose, sigma2: dict[int, float],
                     covariance: np.ndarray | None = None, scaled: bool = False) -> dict | None:
    """The axes of every measurement with a finite stage-1 fit (the left-out ones too), fitted by a pose through the
    camera as given and, where that fails (P < EXACT_P) or the axes' own test failed (``scaled``: their scatter
    scaled the estimate's covariance), by a pose and the camera's focal length and principal point
    (Gauss-Newton from ``pose``; each line at pixel noise ``sigma2[k]``, with the joint-angle noise and the prior floor
    as in the axes' test); None with fewer than 5 measurements (no dof left with three intrinsics free).

    The image axes are held as stage 1 fitted them through the camera given, although they depend on it a little
    (stage 1 fits 3-D coaxial circles through it): the freed fit then leaves part of a large error unexplained (the
    reference scene, fx 5 % off: chi-square 2 for 3 dof on one seed, 14 on another, which is then not flagged).
    Refitting stage 1 through the changed camera in turn (alternating with this fit) did not converge: that needs
    the intrinsics in the circles' graph (intrinsics refinement).

    Returns ``exact_chi2``/``exact_dof``/``exact_p`` (the pose alone), ``chi2``/``dof``/``p_value`` (pose and
    intrinsics), the intrinsics' change that fits (``focal_percent``, ``cx_px``, ``cy_px``), ``one_out_chi2`` (the
    exact camera without the measurement whose absence fits best, 2 n - 8 dof), ``one_out_measurement`` (that
    measurement, the caller's index) and ``one_out_moved_chi2`` (how far leaving it out moves the axes' pose from
    their exact fit's, a chi-square under ``covariance``, the estimate's; None without it; all these None where not
    fitted: the exact camera passed, or the freed fit failed), the measurements tested and ``likely``: the exact
    camera fails, the freed one passes (P >= FREED_P), the improvement exceeds the 99.9 % point of its 3 dof, the
    intrinsics explain the axes better than one wrong measurement (AIC_PER_PARAMETER), and the change is one a
    calibrated camera could be off by (MAX_FOCAL_PERCENT, MAX_CENTRE_FRACTION) but more than its calibration's own
    uncertainty (MIN_FOCAL_PERCENT, MIN_CENTRE_PX). ``systematic``: all of these but the freed camera's passing and
    the exact camera's failing, the improvement beyond its 99 % point (SYSTEMATIC_Z; the camera explains the
    disagreement beyond chance and better than one wrong measurement, not necessarily all of it).
    ``undecided``: every one of these holds but the comparison with
    one wrong measurement, and the two explanations' poses differ beyond the 99.9 % point of 6 dof of
    ``covariance``: the axes cannot tell the camera from that measurement, and the estimate depends on which.
    ``rival``: the same, the poses compared being the one-out fit's and the freed camera's (``freed_moved_chi2``):
    what matters where the estimate left that measurement out and so rests on the one-out explanation.
    """
    ks = [k for k in sigma2 if np.all(np.isfinite(stage1[k].image_axis))]
    if len(ks) < 5:
        return None
    exact, _, exact_pose = _fitted(camera, setup, stage1, ks, pose, sigma2, free=False)
    exact_dof, dof = 2 * len(ks) - 6, 2 * len(ks) - 6 - len(INTRINSICS)
    if not np.isfinite(exact):
        return None
    exact_p = float(chi2_sf(exact, exact_dof))
    out = {"exact_chi2": float(exact), "exact_dof": exact_dof, "exact_p": exact_p, "chi2": None, "dof": dof,
           "p_value": None, "focal_percent": None, "cx_px": None, "cy_px": None, "one_out_chi2": None,
           "one_out_measurement": None, "one_out_moved_chi2": None, "freed_moved_chi2": None,
           "estimate_moved_chi2": None, "undecided": False, "rival": False, "systematic": False,
           "measurements": [setup.index[k] if setup.index else k for k in ks], "likely": False}
    if exact_p >= EXACT_P and not scaled:
        return out
    freed, theta, freed_pose = _fitted(camera, setup, stage1, ks, pose, sigma2, free=True)
    if not np.isfinite(freed):
        return out
    # the rival explanation: one measurement wrong (its joints or tracks), the others exact
    one_outs = [_fitted(camera, setup, stage1, [k for k in ks if k != j], pose, sigma2, free=False) for j in ks]
    best = int(np.argmin([fit[0] for fit in one_outs]))
    one_out = float(one_outs[best][0])
    # how far that explanation moves the axes' pose (from their fit through the camera given), under the estimate's
    # covariance
    shift = exact_pose.localCoordinates(one_outs[best][2])
    moved = (float(shift @ np.linalg.solve(covariance, shift))
             if covariance is not None and np.all(np.isfinite(covariance)) else None)
    # and how far the camera's explanation puts the pose from that one's
    freed_rows = _rows(camera, setup, stage1, ks, freed_pose, sigma2, theta, True)
    prior_sigma = [MAX_FOCAL_PERCENT / 100.0, MAX_CENTRE_FRACTION * camera.width, MAX_CENTRE_FRACTION * camera.height]
    freed_moved = _apart(one_outs[best][2], freed_pose, covariance, freed_rows, prior_sigma)
    # and from the estimate's (which may rest on several measurements left out)
    estimate_moved = _apart(pose, freed_pose, covariance, freed_rows, prior_sigma)
    p = float(chi2_sf(freed, dof))
    # a change one a calibrated camera could be off by ...
    camera_sized = bool(abs(100.0 * theta[0]) <= MAX_FOCAL_PERCENT
                        and abs(theta[1]) <= MAX_CENTRE_FRACTION * camera.width
                        and abs(theta[2]) <= MAX_CENTRE_FRACTION * camera.height
                        and (abs(100.0 * theta[0]) >= MIN_FOCAL_PERCENT or abs(theta[1]) >= MIN_CENTRE_PX
                             or abs(theta[2]) >= MIN_CENTRE_PX))
    # ... where the camera as given fails the model check, explaining the axes beyond its 99.9 % point
    plausible = bool(camera_sized and exact_p < EXACT_P
                     and exact - freed > chi2_quantile(len(INTRINSICS), IMPROVEMENT_Z))
    camera_like = plausible and p >= FREED_P
    likely = camera_like and freed + AIC_PER_PARAMETER < one_out
    viable = plausible and p >= RIVAL_P  # (a rival explanation)
    # ... better than one wrong measurement and beyond chance (the 99 % point), whether or not it explains all of
    # the disagreement: the axes are held as stage 1 fitted them through the camera given, so a wrong camera's freed
    # fit keeps part of the error (Jaco2, 12 poses, focal +3 % and cx +10 px: the freed fit reads -2.7 %, -7 px and
    # takes the chi-square from 469 to 31 for 15 dof, P = 0.0097, where one wrong measurement leaves 68), and read
    # where the axes' own test failed too, not only the model check (``scaled``): the scale takes a systematic error
    # for scatter (reference scene seed 0, focal -2 %: the camera as given at P = 0.008, the covariance scaled by
    # 4.4, 15 mm off at chi-square 1 700 "usable")
    systematic = bool(camera_sized and exact - freed > chi2_quantile(len(INTRINSICS), SYSTEMATIC_Z)
                      and freed + AIC_PER_PARAMETER < one_out)
    out.update(chi2=float(freed), p_value=p, focal_percent=float(100.0 * theta[0]), cx_px=float(theta[1]),
               cy_px=float(theta[2]), one_out_chi2=one_out,
               one_out_measurement=setup.index[ks[best]] if setup.index else ks[best], one_out_moved_chi2=moved,
               freed_moved_chi2=freed_moved, estimate_moved_chi2=estimate_moved,
               undecided=bool(viable and not likely and moved is not None
                              and moved > chi2_quantile(6, IMPROVEMENT_Z)),
               rival=bool(viable and not likely and freed_moved is not None
                          and freed_moved > chi2_quantile(6, IMPROVEMENT_Z)),
               likely=bool(likely), systematic=bool(systematic))
    return out


def _offset_rows(arm: Arm, camera: Camera, setup: _Setup, stage1, ks, joint_angles, joints: np.ndarray, pose, sigma2,
                 delta, free: bool):
    """The axes' rows (:func:`stage2._axis_rows`, with the prior floor) of the FK axes with the offsets ``delta``
    (rad) added to the readings of ``joints``, their Jacobians extended by the offsets' (central differences) when
    ``free``."""

    def axis(k, d):
        q = np.array(joint_angles[k], dtype=float)
        q[joints] += d
        return arm.wrist_axis(q, setup.spin_joint(k))

    rows = _axis_rows(camera, setup, stage1, ks, pose, sigma2, floor=True, axes={k: axis(k, delta) for k in ks})
    if not free:
        return rows
    out = []
    for k, (e, cov, J) in zip(ks, rows, strict=True):
        G = np.empty((len(e), len(joints)))
        for i in range(len(joints)):
            step = np.zeros(len(joints))
            step[i] = OFFSET_STEP
            plus = _axis_distances(camera, axis(k, delta + step), stage1[k], pose)[0]
            minus = _axis_distances(camera, axis(k, delta - step), stage1[k], pose)[0]
            G[:, i] = (plus - minus) / (2.0 * OFFSET_STEP)
        out.append((e, cov, np.hstack([J, G])))
    return out


def kinematics_check(arm: Arm, camera: Camera, setup: _Setup, stage1, pose, sigma2: dict[int, float],
                     joint_angles, covariance: np.ndarray | None = None, scaled: bool = False) -> dict | None:
    """The axes of every measurement with a finite stage-1 fit (the left-out ones too), fitted by a pose with the
    kinematics as given and, where that fails (P < EXACT_P) or the axes' own test failed (``scaled``: their scatter
    scaled the estimate's covariance), by a pose and an offset of each joint before the spinning one, common to all
    poses (Gauss-Newton from ``pose``, the axes as :func:`intrinsics_check` holds them); ``joint_angles[k]`` the
    readings of measurement k. The offsets' combinations the poses do not determine (the
    first joint's turns the whole arm, as the pose does) are left at zero and not counted: the freed fit's dof are
    ``2 n - 6 - r``, ``r`` the offsets' determined directions. None where no dof would be left.

    Returns ``exact_chi2``/``exact_dof``/``exact_p``, ``chi2``/``dof``/``p_value`` (pose and offsets),
    ``offsets_deg`` (joint name -> the fitted offset, degrees; the reading plus it is the joint's angle),
    ``determined`` (r), ``one_out_chi2`` (the exact kinematics without the measurement whose absence fits best), the
    measurements tested and ``likely``: the exact kinematics fail, the offsets pass (P >= FREED_P), improve the
    chi-square beyond the 99.9 % point of their r dof, explain the axes better than one wrong measurement by Akaike's
    criterion (AIC_PER_PARAMETER per parameter beyond that measurement's two), and are offsets a robot could have
    (the largest between MIN_OFFSET_DEG and MAX_OFFSET_DEG); ``systematic``: all of these but the offsets' passing and
    the exact kinematics' failing, the improvement beyond its 99 % point (SYSTEMATIC_Z; they explain the disagreement
    beyond chance and better than one wrong measurement, not necessarily all of it). Neither
    where that one measurement is weak (few tracks or short arcs: its image axis is the likelier to be wrong than the
    robot's zero positions) and leaving it out explains the axes (P >= FREED_P; ``weak_one_out``). The
    check reads a first-order fit: it names a likely
    cause, it does not calibrate the offsets (``CalibrationOptions(joint_offsets=...)`` does).

    ``undecided``: every one of these holds but the comparison with one wrong measurement
    (``one_out_measurement``), and the two explanations' poses differ beyond the 99.9 % point of 6 dof of
    ``covariance`` (the estimate's; ``moved_chi2``): the axes cannot tell offsets from that measurement, and the
    estimate depends on which. Unlike a camera error (:func:`intrinsics_check`), this holds whether or not the
    estimate left that measurement out: left out, the estimate rests on the measurement being wrong, and offsets
    that explain every measurement put the camera elsewhere (Jaco2, 0.5 degree offsets on joints 2-5: one
    measurement left out, the rest agreeing, 13 mm off at chi-square 2 700 under a covariance called usable).
    """
    ks = [k for k in sigma2 if np.all(np.isfinite(stage1[k].image_axis))]
    joints = np.arange(max(arm.spin_index(setup.spin_joint(k)) for k in ks) if ks else 0)
    if len(ks) < 4 or len(joints) == 0:
        return None

    def rows_of(free, tested=ks):
        return lambda delta, pose: _offset_rows(arm, camera, setup, stage1, tested, joint_angles, joints, pose,
                                                sigma2, delta, free)

    zero = np.zeros(len(joints))
    exact, _, _, _ = _gauss_newton(rows_of(False), zero, pose, False)
    exact_dof = 2 * len(ks) - 6
    if not np.isfinite(exact):
        return None
    exact_p = float(chi2_sf(exact, exact_dof))
    out = {"exact_chi2": float(exact), "exact_dof": exact_dof, "exact_p": exact_p, "chi2": None, "dof": None,
           "p_value": None, "offsets_deg": None, "determined": None, "one_out_chi2": None,
           "one_out_measurement": None, "moved_chi2": None, "undecided": False, "systematic": False,
           "weak_one_out": False,
           "measurements": [setup.index[k] if setup.index else k for k in ks], "likely": False}
    if exact_p >= EXACT_P and not scaled:
        return out
    freed, delta, freed_pose, rank = _gauss_newton(rows_of(True), zero, pose, True, RANK_RCOND)
    determined = rank - 6
    dof = exact_dof - determined
    if not np.isfinite(freed) or determined < 1 or dof < 1:
        return out
    one_outs = [_gauss_newton(rows_of(False, [k for k in ks if k != j]), zero, pose, False) for j in ks]
    best = int(np.argmin([fit[0] for fit in one_outs]))
    one_out = float(one_outs[best][0])
    # a thin measurement's axis (few tracks or short arcs, far from Gaussian) is the likelier wrong one: where leaving
    # it out explains the axes, offsets are no likelier (a blurred photo-textured Jaco2 scene: offsets explained its
    # six axes at P = 0.08, leaving out its measurement of 18 tracks at P = 0.035, and the words sent the user to the
    # robot's zero positions; the estimate, which left that measurement out, was 0.4 sigma off)
    weak_out = bool(ks[best] in classify(setup, stage1).weak and chi2_sf(one_out, exact_dof - 2) >= FREED_P)
    plausible = np.full(len(joints), np.radians(PLAUSIBLE_OFFSET_DEG))
    p = float(chi2_sf(freed, dof))
    largest = float(np.degrees(np.max(np.abs(delta))))
    if largest > MAX_OFFSET_DEG:
        # combinations the poses barely determine can run far in the free fit: fitted under a prior of plausible
        # offsets instead, do they explain the axes as well? (Panda, 0.5 degree offsets on joints 2-6, six poses:
        # the free fit read 3.7 degrees and the check passed over an estimate 11 mm off at chi-square 350)
        held, held_delta, held_pose, _ = _gauss_newton(rows_of(True), zero, pose, True, RANK_RCOND,
                                                       prior_sigma=np.radians(PLAUSIBLE_OFFSET_DEG))
        if np.isfinite(held) and chi2_sf(held, dof) >= FREED_P:
            freed, delta, freed_pose, p = float(held), held_delta, held_pose, float(chi2_sf(held, dof))
            largest = float(np.degrees(np.max(np.abs(delta))))
    moved = _apart(one_outs[best][2], freed_pose, covariance, rows_of(True)(delta, freed_pose), plausible)
    # offsets explain the axes beyond chance and better than one wrong measurement, whether or not they explain
    # all of it: the disagreement is systematic, not scatter that a scaled covariance covers
    systematic = bool(exact - freed > chi2_quantile(determined, SYSTEMATIC_Z)
                      and MIN_OFFSET_DEG <= largest <= MAX_OFFSET_DEG
                      and freed + AIC_PER_PARAMETER * (determined - 2) < one_out and not weak_out)
    # the exact kinematics fail the model check and plausible offsets improve on them beyond its 99.9 % point
    beyond = bool(exact_p < EXACT_P and exact - freed > chi2_quantile(determined, IMPROVEMENT_Z)
                  and MIN_OFFSET_DEG <= largest <= MAX_OFFSET_DEG)
    likely = beyond and p >= FREED_P and freed + AIC_PER_PARAMETER * (determined - 2) < one_out and not weak_out
    viable = beyond and p >= RIVAL_P  # (a rival explanation)
    out.update(chi2=float(freed), dof=dof, p_value=p, determined=determined, one_out_chi2=one_out,
               one_out_measurement=setup.index[ks[best]] if setup.index else ks[best], moved_chi2=moved,
               offsets_deg={arm.joint_names[j]: float(np.degrees(d)) for j, d in zip(joints, delta, strict=True)},
               undecided=bool(viable and not likely and moved is not None
                              and moved > chi2_quantile(6, IMPROVEMENT_Z)),
               likely=bool(likely), systematic=systematic, weak_one_out=weak_out)
    return out

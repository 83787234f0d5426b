"""Ambient features (issue 13): the robot's own meshes, a covered hand, no calibration target, from pixels.

For each scene (a robot, a covering, a variant, a seed): the scene's arm poses and camera come from the simulator
(``simulate.simulate``, six arm poses kept of up to ``CANDIDATES`` drawn), every spin is rendered by
:mod:`gtsam_rotid.meshrender` (the robot's visual meshes, the hand covered by ``--coverings``: photo, text, fabric,
stickers, dots or plain; a photographed background; shading, 2x2 anti-aliasing and sensor noise), tracked with the
given tracker settings (``--features``; default ``TrackerParams()``), and calibrated (``joint``).

Variants (``--variants``, default ``nominal``): ``nominal`` (``--duration`` s spins, the hand fully covered, no
motion blur), ``short`` (5 s spins), ``half`` (only half of the hand's circumference covered:
``MeshRenderConfig(covered_fraction=0.5)``, the rest plain plastic) and ``blur`` (motion blur over the whole frame
interval: ``exposure=1``, 4 spin angles averaged per frame; at the simulator's 0.5 rad/s and 30 fps a point 4 cm
off the axis moves 0.7 mm in a frame, about 0.5-1 px at these distances, so this is mild).

Printed per scene:

- the pixels the spinning links cover in the first frame (median over the kept poses), tracks kept per arm pose,
  and the tracker's frames per second on one core (rendering excluded);
- the tracked points against the renderer's ground truth (each track's surface point located from its first points
  and projected in the track's frames; ``meshrender.track_errors``): pooled RMS and median (px), and how many kept
  tracks do not lie on the spinning links at all; and the RMS about each track's best rigid point (the link-frame
  point that fits the whole track: the first points locate a point first seen at a grazing angle far along the
  surface, and that error grows as the surface turns; this column is what a calibration sees);
- the arc the kept tracks span (deg of true spin between a track's first and last frame; median and maximum over
  the scene's tracks), and the longest arc per pose the calibration measured about its fitted circles
  (``MeasurementReport.arc_span_deg``; median and maximum over the poses);
- the calibration error (worst axis, mm and deg) against the reported 1 sigma, the Mahalanobis chi-square of the
  true error under the reported covariance (6 dof), and whether the result calls its covariance usable (with the
  reasons when not).

Then the NEES over the scenes whose covariance is called usable, with its 95 % interval, and the number of usable
scenes outside their 99.9 % region (the "confident wrong numbers"; the target is none); and what an image shift of
0.1 px per pose, which the data cannot show, would add to the usable scenes' errors
(``CalibrationResult.image_shift_sigma``), with how many of them say so in their words.

``--save DIR`` writes, per scene, ``DIR/<robot>_<covering>_<variant>_seed<seed>/``: ``dataset/`` (the tracked
dataset the calibration saw, :meth:`Dataset.save`) and ``scene.json`` (the true ``arm_T_camera`` as a 4x4 matrix
and the tracker's numbers). ``--load DIR`` re-runs only the calibration on every saved scene and prints the same
table (tracker columns as saved), in seconds: for re-evaluating an estimator change without rendering.
``--spin-model free|rigid``, ``--axis-floor-px PX`` and ``--track-offset-px PX`` calibrate with those
``CalibrationOptions``, ``--method
weighted|paper`` with that estimator (default ``joint``); ``--json FILE``
also writes every row's numbers. ``--load DIR --synced`` adds each spin's joint readings (:func:`with_readings`)
and calibrates synced; ``--load DIR --jitter-px 1e-6`` adds that much noise to every tracked pixel
(:func:`jittered`): an answer that changes with it hangs on rounding.

``--poses planned`` takes the arm poses from :func:`gtsam_rotid.planning.plan_poses` at a guess of the camera (the
true pose moved by a random 30 mm and 3 degrees per axis, as ``benchmarks/planning.py``) instead of the simulator's
sampler; the first six the renderer accepts are kept (two spares are planned).

Run: ``python benchmarks/ambient.py [--robots kinova,ur5,panda] [--coverings photo,text,dots] [--seeds 0,1]
[--variants nominal,short,half,blur] [--duration 20] [--features blobs|corners|auto] [--poses sampled|planned]
[--jobs 2] [--save DIR]``,
or ``python benchmarks/ambient.py --load DIR``; ``--quick`` (one 3 s scene) checks that it runs.
"""

from __future__ import annotations

import argparse
import itertools
import json
import os
import sys
import time
from pathlib import Path

import cv2
import gtsam
import numpy as np

from gtsam_rotid import meshrender as mr
from gtsam_rotid import simulate
from gtsam_rotid.calibration.result import IMAGE_SHIFT_PX
from gtsam_rotid.camera import Camera
from gtsam_rotid.dataset import Dataset, Measurement, SpinReadings, Track
from gtsam_rotid.errors import InputError, RotIdError
from gtsam_rotid.estimate import CalibrationOptions, calibrate
from gtsam_rotid.factors import axis_point_residuals
from gtsam_rotid.graph import axis_test_points
from gtsam_rotid.simulate import SceneConfig
from gtsam_rotid.stillness import motion_metadata
from gtsam_rotid.tracking import Tracker, TrackerParams, tracker_metadata
from gtsam_rotid.uncertainty import chi2_mean_interval
from gtsam_rotid.words import image_shift_words, untrusted_words

CHI2_999_6DOF = 22.458
#: arm poses per scene, drawn from up to this many candidates of the simulator (the sampler knows no meshes;
#: the first candidates are the same whatever the number drawn, so more candidates only add spares)
POSES, CANDIDATES = 6, 20
#: robot -> scene placement (the cameras of scenarios/other_arms.py, at 640x480 here). The UR5 of
#: example-robot-data has no gripper: only its wrist-3 link (a disc 75 mm across and 35 mm long) spins, and from
#: the other arms' 60 deg camera 0.8-1.6 m away it covered 700-2200 pixels and gave no tracks. Its camera stands
#: closer (0.72 m from the target instead of 1.04 m), with a 45 deg lens, and its wrist is kept 0.3-0.6 m from the
#: camera (the simulator's default is 0.5-1.6 m): the flange then covers about 8 000-16 000 pixels.
PLACEMENTS = {
    "kinova": {},
    "ur5": dict(camera=Camera.from_fov(640, 480, 45.0), camera_eye=(0.7, 0.5, 0.75), camera_target=(0.3, 0.1, 0.3),
                depth_range=(0.3, 0.6)),
    "panda": dict(camera=Camera.from_fov(640, 480, 60.0), camera_eye=(1.1, -0.4, 0.8),
                  camera_target=(0.4, 0.0, 0.4)),
}
#: variant -> (spin length in s, or None for --duration; MeshRenderConfig changes)
VARIANTS = {
    "nominal": (None, {}),
    "short": (5.0, {}),
    "half": (None, {"covered_fraction": 0.5}),
    "blur": (None, {"exposure": 1.0, "blur_samples": 4}),
}
SCENE_FILE, DATASET_DIR = "scene.json", "dataset"


#: ``--poses planned``: the camera guess given to the planner is the true pose moved by a random GUESS_MM and
#: GUESS_DEG (1 sigma per axis, seeded by the scene's seed), as ``benchmarks/planning.py`` does; PLANNED_SPARES more
#: poses are planned than kept, in case the mesh renderer finds the hand hidden on some (the plan's first are kept)
GUESS_MM, GUESS_DEG, PLANNED_SPARES = 30.0, 3.0, 2


def scene_name(robot: str, covering: str, variant: str, seed: int, poses: str = "sampled") -> str:
    return f"{robot}_{covering}_{variant}_seed{seed}" + ("" if poses == "sampled" else f"_{poses}")


def perturbed_guess(truth_pose, seed: int, mm: float = GUESS_MM, deg: float = GUESS_DEG):
    """The camera guess a user would give: ``truth_pose`` moved by a random ``mm`` and ``deg`` (1 sigma per axis),
    seeded by the scene's seed (``benchmarks/planning.py`` uses the same)."""
    sigma = np.array([np.radians(deg)] * 3 + [mm / 1000.0] * 3)
    return truth_pose.retract(np.random.default_rng(10_000 + seed).normal(size=6) * sigma)


def relaxed(config: SceneConfig) -> SceneConfig:
    """``config`` with the simulator's own pose checks (made for sampling) off: given poses are recorded wherever the
    true camera sees, and its visibility model drops what leaves the image."""
    return config.with_(image_margin=-1e6, axis_view_angle_deg=(0.0, 90.0), depth_range=(0.0, 1e6), min_height=-1e6)


def scene_spins(robot: str, seed: int, duration: float, poses: str = "sampled"):
    """The scene's simulated dataset and truth: the simulator's sampled poses (CANDIDATES of them), or poses that
    ``planning.plan_poses`` chose at a perturbed guess of the camera (POSES + PLANNED_SPARES; the simulator's own
    pose checks off, as in ``benchmarks/planning.py``: the recording happens wherever the true camera sees)."""
    config = SceneConfig(robot=robot, duration=duration, n_measurements=CANDIDATES, **PLACEMENTS[robot])
    if poses == "sampled":
        return simulate.simulate(config, seed)
    from gtsam_rotid.arm import Arm
    from gtsam_rotid.geometry import look_at
    from gtsam_rotid.planning import PlanOptions, plan_poses

    guess = perturbed_guess(look_at(config.camera_eye, config.camera_target, config.camera_up), seed)
    arm = Arm.from_robot(robot)
    options = PlanOptions(depth_range=config.depth_range, guess_sigma_mm=GUESS_MM, guess_sigma_deg=GUESS_DEG,
                          respect_wrist_limits=False, spin_seconds=duration, seed=seed)
    plan = plan_poses(arm, config.camera, guess, POSES + PLANNED_SPARES, options)
    recorded = relaxed(config).with_(joint_angles=tuple(tuple(float(x) for x in q) for q in plan.joint_angles),
                                     n_measurements=len(plan.joint_angles))
    return simulate.simulate(recorded, seed, arm=arm)


def camera_turn(seed: int, k: int, turn_deg: float):
    """Pose ``k``'s camera turn (``gtsam.Pose3`` in the camera frame) for ``--camera-turn-deg``: about the camera's
    x and y axes, each N(0, turn_deg²), independent across poses; None for no turn."""
    if turn_deg <= 0.0:
        return None
    import gtsam

    a, b = np.radians(turn_deg) * np.random.default_rng([31, seed, k]).standard_normal(2)
    return gtsam.Pose3(gtsam.Rot3.Rx(a) * gtsam.Rot3.Ry(b), np.zeros(3))


def drifting(images: list, camera, seed: int, k: int, drift_deg: float) -> list:
    """Pose ``k``'s frames as a camera that turns steadily during the video would see them (``--camera-drift-deg``):
    by the last frame, about the camera's x and y axes by N(0, drift_deg²) each, independent across poses; frame
    ``i`` of ``n`` turned by ``i / (n - 1)`` of that. A turn about the camera's centre maps the image by the
    homography ``K R K^-1`` at every depth, nearly a shift for turns this small (0.099-0.117 px over the view for
    0.01° about x at f = 570 px): each rendered frame is shifted by the homography's move of the principal point,
    bilinearly in floating point (OpenCV's warps place their samples to 1/32 px, a third of a 0.1 px drift; the
    interpolation smooths the noise a little)."""
    if drift_deg <= 0.0:
        return images
    a, b = np.radians(drift_deg) * np.random.default_rng([37, seed, k]).standard_normal(2)
    K = np.asarray(camera.K, dtype=float)
    n, out = len(images), []
    for i, image in enumerate(images):
        f = i / max(n - 1, 1)
        ca, sa, cb, sb = np.cos(f * a), np.sin(f * a), np.cos(f * b), np.sin(f * b)
        R = np.array([[1, 0, 0], [0, ca, -sa], [0, sa, ca]]) @ np.array([[cb, 0, sb], [0, 1, 0], [-sb, 0, cb]])
        # (the turned camera sees at pixel x' what the still one saw at K R K^-1 x')
        source = K @ R @ np.array([0.0, 0.0, 1.0])
        out.append(_shifted(image, source[:2] / source[2] - K[:2, 2]))
    return out


def _shifted(image: np.ndarray, offset: np.ndarray) -> np.ndarray:
    """``image`` (uint8) sampled bilinearly at ``(x, y) + offset`` for each pixel (edges replicated)."""
    whole = np.floor(offset).astype(int)
    fx, fy = offset - whole
    pad = int(np.max(np.abs(whole))) + 2
    f = cv2.copyMakeBorder(image, pad, pad, pad, pad, cv2.BORDER_REPLICATE).astype(np.float32)
    h, w = image.shape[:2]
    y, x = pad + whole[1], pad + whole[0]

    def at(dy, dx):
        return f[y + dy:y + dy + h, x + dx:x + dx + w]

    value = (1 - fy) * ((1 - fx) * at(0, 0) + fx * at(0, 1)) + fy * ((1 - fx) * at(1, 0) + fx * at(1, 1))
    return np.clip(np.rint(value), 0, 255).astype(np.uint8)


def run_scene(robot: str, covering: str, seed: int, variant: str, duration: float, params: TrackerParams,
              save: str | None = None, options: CalibrationOptions | None = None, poses: str = "sampled",
              method: str = "joint", turn_deg: float = 0.0, drift_deg: float = 0.0) -> dict:
    """Render, track and calibrate one scene; a dict of the measured numbers (or why it could not run). With
    ``save``, the tracked dataset and the scene's numbers are written under that directory first. With
    ``turn_deg``, each pose's camera is turned (:func:`camera_turn`; the room stays), the turns are measured on the
    videos' first frames (``stillness.motion_metadata``, as ``make_dataset`` does) and the scene is calibrated with
    that reading and without it (``*_unmeasured``). With ``drift_deg``, the camera turns during each video instead
    (:func:`drifting`), read on each video's first and last frames."""
    cv2.setNumThreads(1)
    length, changes = VARIANTS[variant]
    duration = duration if length is None else length
    out = {"robot": robot, "covering": covering, "variant": variant, "seed": seed, "duration": duration,
           "poses": poses}
    dataset = truth = None
    try:
        # the simulator's pose sampler knows no meshes: draw spare poses and keep the first POSES the mesh
        # renderer accepts (the hand in the image and not hidden behind the arm for most of the spin)
        dataset, truth = scene_spins(robot, seed, duration, poses)
        meshes = mr.load_arm_meshes(dataset.arm)
        config = mr.MeshRenderConfig(covering=covering, seed=seed, **changes)
        measurements, kept, errors, track_time, frames, off, skipped = [], [], [], 0.0, 0, 0, []
        hand_px, arcs, corner_tracks, first_frames, last_frames = [], [], 0, [], []
        for k in range(len(dataset)):
            if len(kept) == POSES:
                break
            try:  # a pose whose hand is hidden behind the arm (or outside the image) is not rendered
                spin = mr.render_mesh_measurement(dataset, truth, k, config, meshes=meshes,
                                                  camera_moved=camera_turn(seed, k, turn_deg))
            except InputError as why:
                skipped.append(f"{k}: {why}")
                continue
            hand_px.append(int(spin.moving_mask(int(spin.frame_indices[0])).sum()))
            images = drifting(list(spin.frames()), dataset.camera, seed, k, drift_deg)
            first_frames.append(images[0])
            last_frames.append(images[-1])
            start = time.perf_counter()
            result = Tracker(params).run(images)
            corner_tracks += result.n_corner_tracks
            track_time += time.perf_counter() - start
            frames += len(images)
            tracks = result.tracks
            kept.append(len(tracks))
            angles = truth.measurements[k].spin_angles
            for t in tracks:  # the true spin between a track's first and last frame
                f = np.asarray(t.frames)
                arcs.append(min(float(np.degrees(abs(angles[f.max()] - angles[f.min()]))), 360.0))
            if tracks:
                e = mr.track_errors(tracks, spin)
                off += len(e.off_links)
                ok = np.isfinite(e.rms_px)
                errors.append((np.sum(e.rms_px[ok] ** 2 * e.n_compared[ok]), np.sum(e.n_compared[ok]),
                               np.median(e.rms_px[ok]) if ok.any() else np.nan,
                               np.sum(e.rigid_rms_px[ok] ** 2 * e.n_compared[ok])))
            measurements.append(Measurement(dataset[k].joint_angles, tracks) if tracks else None)
    except RotIdError as error:
        out["failed"] = f"{type(error).__name__}: {error}"
        if save is not None:
            _save_scene(save, out, None, truth)
        return out
    out.update(kept=kept, fps=frames / max(track_time, 1e-9), off_links=off, skipped=skipped,
               hand_px=float(np.median(hand_px)) if hand_px else float("nan"), hand_px_per_pose=hand_px,
               arc_median_deg=float(np.median(arcs)) if arcs else float("nan"),
               arc_max_deg=float(np.max(arcs)) if arcs else float("nan"))
    n_compared = sum(e[1] for e in errors)
    out["track_rms_px"] = float(np.sqrt(sum(e[0] for e in errors) / n_compared)) if n_compared else float("nan")
    out["track_median_px"] = float(np.nanmedian([e[2] for e in errors])) if errors else float("nan")
    out["track_rigid_rms_px"] = float(np.sqrt(sum(e[3] for e in errors) / n_compared)) if n_compared else float("nan")
    usable_measurements = [m for m in measurements if m is not None]
    motion = None
    if turn_deg > 0.0 or drift_deg > 0.0:  # the turns as the videos' background shows them (poses with tracks)
        motion = motion_metadata([f for f, m in zip(first_frames, measurements, strict=True) if m is not None],
                                 [f"pose {k}" for k, m in enumerate(measurements) if m is not None],
                                 last=[f for f, m in zip(last_frames, measurements, strict=True) if m is not None])
    tracked = None
    try:
        tracked = Dataset(dataset.arm, dataset.camera, usable_measurements,
                          metadata={**dataset.metadata, "scene": scene_name(robot, covering, variant, seed, poses),
                                    "tracker": tracker_metadata(params, corner_tracks),
                                    **({} if motion is None else {"camera_motion": motion})})
    except RotIdError as error:
        out["refused"] = f"{type(error).__name__}: {error}"
    if save is not None:
        _save_scene(save, out, tracked, truth)
    if tracked is None:
        return out
    out = calibrate_scene(out, tracked, truth.arm_T_camera, options, method)
    if motion is not None:
        out["camera_motion"] = motion
        unmeasured = Dataset(tracked.arm, tracked.camera, list(tracked),
                             metadata={k: v for k, v in tracked.metadata.items() if k != "camera_motion"})
        bare = calibrate_scene({}, unmeasured, truth.arm_T_camera, options, method)
        out.update({f"{k}_unmeasured": bare.get(k) for k in ("chi2", "usable", "err_mm", "sigma_mm", "refused")})
    return out


def _save_scene(directory: str, row: dict, tracked: Dataset | None, truth) -> None:
    root = Path(directory) / scene_name(row["robot"], row["covering"], row["variant"], row["seed"],
                                        row.get("poses", "sampled"))
    root.mkdir(parents=True, exist_ok=True)
    if tracked is not None:
        tracked.save(root / DATASET_DIR, overwrite=True)
    document = {"tracking": row, "arm_T_camera": None if truth is None else truth.arm_T_camera.matrix().tolist()}
    staging = root / (SCENE_FILE + ".tmp")
    staging.write_text(json.dumps(document, indent=1, allow_nan=True) + "\n", encoding="utf-8")
    os.replace(staging, root / SCENE_FILE)


def with_readings(tracked: Dataset, seed: int, config: SceneConfig | None = None) -> Dataset:
    """The dataset with each spin's joint readings (synced mode) as a recording of the joint states would give
    them: the simulator's spin (its ``wrist_speed`` from the measurement's wrist angle, ``fps`` frames per second),
    read 100 times a second with 0.02 degrees of noise, from half a second before the first frame to half a second
    after the last. The renders spin at one speed: the clocks' offset is left to its prior."""
    config = SceneConfig() if config is None else config
    rng = np.random.default_rng(seed)
    measurements = []
    for m in tracked:
        last = max(int(t.frames[-1]) for t in m.tracks)
        times = np.arange(-0.5, (last + 1) / config.fps + 0.5, 0.01)
        start = float(tracked.arm.joint_angle_vector(m.joint_angles)[tracked.arm.spin_index(m.spin_joint)])
        angles = start + config.wrist_speed * times + rng.normal(0.0, np.radians(0.02), len(times))
        measurements.append(m.replace(spin_readings=SpinReadings(np.arange(last + 1) / config.fps, times, angles)))
    return Dataset(tracked.arm, tracked.camera, measurements, metadata=tracked.metadata)


def jittered(tracked: Dataset, sigma_px: float) -> Dataset:
    """The dataset with Gaussian noise of ``sigma_px`` added to every track's pixels (measurement k's track j from
    the generator seeded ``1000 k + j``): with a tiny sigma, whether an answer hangs on rounding."""
    measurements = [m.replace(tracks=[Track(np.asarray(t.pixels) + np.random.default_rng(1000 * k + j).normal(
        0.0, sigma_px, np.shape(t.pixels)), t.frames) for j, t in enumerate(m.tracks)]) for k, m in enumerate(tracked)]
    return Dataset(tracked.arm, tracked.camera, measurements, metadata=tracked.metadata)


def load_scene(root: str, options: CalibrationOptions | None = None, method: str = "joint",
               synced: bool = False, jitter_px: float = 0.0) -> dict:
    """Re-run the calibration of one scene written by ``--save``: the row as :func:`run_scene` gives it (with
    ``synced``, the spins' joint readings added, :func:`with_readings`; with ``jitter_px``, its pixels
    :func:`jittered`)."""
    root = Path(root)
    document = json.loads((root / SCENE_FILE).read_text(encoding="utf-8"))
    row = {k: v for k, v in document["tracking"].items() if k not in ("refused", "err_mm")}
    if "failed" in row or not (root / DATASET_DIR).is_dir():
        if "failed" not in row:
            row["refused"] = document["tracking"].get("refused", "no tracked dataset saved")
        return row
    try:
        tracked = Dataset.load(root / DATASET_DIR)
    except RotIdError as error:
        row["refused"] = f"cannot load the saved dataset: {type(error).__name__}: {error}"
        return row
    if "tracker" not in tracked.metadata:  # saved before datasets named their tracker: the default's
        tracked.metadata["tracker"] = tracker_metadata(TrackerParams())
    if jitter_px > 0.0:
        tracked = jittered(tracked, jitter_px)
    if synced:
        tracked = with_readings(tracked, int(row.get("seed", 0)))
    return calibrate_scene(row, tracked, gtsam.Pose3(np.array(document["arm_T_camera"], dtype=float)), options,
                           method)


def calibrate_scene(out: dict, tracked: Dataset, arm_T_camera, options: CalibrationOptions | None = None,
                    method: str = "joint") -> dict:
    """Calibrate a tracked dataset (by ``method``) and add to ``out`` its error against the true ``arm_T_camera``."""
    out = dict(out)
    try:
        result = calibrate(tracked, method=method, options=options)
    except RotIdError as error:
        out["refused"] = f"{type(error).__name__}: {error}"
        return out
    e = result.error_to(arm_T_camera)
    R = arm_T_camera.rotation().matrix()
    spans = [m.arc_span_deg for m in result.measurements if getattr(m, "arc_span_deg", None) is not None]
    out.update(err_mm=float(np.max(np.abs(R @ e[3:]))) * 1000.0, err_deg=float(np.degrees(np.max(np.abs(e[:3])))),
               sigma_mm=float(np.max(result.sigma_mm_arm)), sigma_deg=float(np.max(result.sigma_deg)),
               usable=bool(result.covariance_usable), untrusted=list(result.untrusted),
               ambiguous=bool(result.ambiguous),
               words=untrusted_words(result) if result.untrusted else [],
               pose_arc_median_deg=float(np.median(spans)) if spans else float("nan"),
               pose_arc_max_deg=float(np.max(spans)) if spans else float("nan"))
    try:
        out["chi2"] = float(e @ np.linalg.solve(result.covariance, e))
    except np.linalg.LinAlgError:
        out["chi2"] = float("inf")
    axis_errors = pose_axis_errors_px(result, tracked, arm_T_camera)
    out.update(axis_rms_px=float(np.sqrt(np.mean(axis_errors**2))) if len(axis_errors) else float("nan"),
               axis_max_px=float(np.max(axis_errors)) if len(axis_errors) else float("nan"),
               floor_px=result.axis_consistency.floor_px if result.axis_consistency is not None else 0.0)
    shift = result.image_shift_sigma(IMAGE_SHIFT_PX)  # what a shift per pose (a camera turning 0.01°) would add
    if shift is not None:
        out.update(shift_mm=float(np.max(shift[0])), shift_deg=float(np.max(shift[1])),
                   shift_excess=result.image_shift_excess(IMAGE_SHIFT_PX),
                   shift_named=image_shift_words(result) is not None)
    return out


def pose_axis_errors_px(result, tracked: Dataset, arm_T_camera) -> np.ndarray:
    """Per measurement with a stage-1 image axis: the RMS distance (px) of its FK axis' two test points, projected
    by the true ``arm_T_camera``, from that image axis. What a measurement's tracks share (a bias no number of
    tracks averages out) shows here; white pixel noise on many tracks leaves it near zero."""
    return np.asarray([float(np.sqrt(np.mean(d**2))) for d in true_axis_distances(result, tracked, arm_T_camera)
                       if d is not None])


def true_axis_distances(result, tracked: Dataset, arm_T_camera) -> list[np.ndarray | None]:
    """Per measurement of ``result``: the signed distances (px, 2) from its stage-1 image axis of its FK axis' two
    test points projected by ``arm_T_camera`` (None without an image axis): the distances whose covariance at the
    estimate is the measurement's ``axis_test_covariance``."""
    out = []
    for m in result.measurements:
        if m.image_axis is None or m.axis_point is None:
            out.append(None)
            continue
        axis = tracked.arm.wrist_axis(tracked[m.index].joint_angles, tracked[m.index].spin_joint)
        out.append(axis_point_residuals(tracked.camera.K, arm_T_camera, axis_test_points(axis), m.image_axis)[0])
    return out


def _number(row: dict, key: str, fmt: str) -> str:
    value = row.get(key)
    return "" if value is None else format(value, fmt)


def print_table(rows: list[dict]) -> None:
    print("| robot | covering | variant | seed | hand px | tracks kept per pose | tracker fps | tracks off the hand | "
          "tracked RMS px (median track) | about each track's best rigid point, RMS px | track arc ° median / max | "
          "calibration's longest arc per pose ° median "
          "/ max | the poses' image axes vs truth, px RMS / max (floor applied) | error mm (1σ) | error ° (1σ) | "
          "χ² of the error | covariance |")
    print("|" + " --- |" * 17)
    usable_chi2 = []
    for row in rows:
        planned = " (planned poses)" if row.get("poses", "sampled") != "sampled" else ""
        head = f"| {row['robot']} | {row['covering']} | {row['variant']}{planned} | {row['seed']} |"
        if "failed" in row:
            print(f"{head} not rendered: {row['failed'][:120]} |" + " |" * 12)
            continue
        kept = ", ".join(str(k) for k in row["kept"]) + (f" ({len(row['skipped'])} poses skipped: not renderable)"
                                                          if row["skipped"] else "")
        track = (f" {_number(row, 'hand_px', '.0f')} | {kept} | {_number(row, 'fps', '.0f')} | {row['off_links']} | "
                 f"{row['track_rms_px']:.3f} ({row['track_median_px']:.3f}) | "
                 f"{_number(row, 'track_rigid_rms_px', '.3f')} | "
                 f"{_number(row, 'arc_median_deg', '.0f')} / {_number(row, 'arc_max_deg', '.0f')} |")
        if "refused" in row:
            print(f"{head}{track} refused: {row['refused'][:160]} | | | | | |")
            continue
        reasons = row["untrusted"] + (["ambiguous"] if row.get("ambiguous") else [])
        verdict = "usable" if row["usable"] else "NOT usable (" + (", ".join(reasons) or "undetermined") + ")"
        print(f"{head}{track} {row['pose_arc_median_deg']:.0f} / {row['pose_arc_max_deg']:.0f} | "
              f"{_number(row, 'axis_rms_px', '.3f')} / {_number(row, 'axis_max_px', '.3f')} "
              f"({_number(row, 'floor_px', '.3f')}) | {row['err_mm']:.2f} ({row['sigma_mm']:.2f}) | "
              f"{row['err_deg']:.3f} ({row['sigma_deg']:.3f}) | "
              f"{row['chi2']:.3g} | {verdict} |")
        if row["usable"]:
            usable_chi2.append(row["chi2"])
    if usable_chi2:
        low, high = chi2_mean_interval(6, len(usable_chi2))
        outside = sum(c > CHI2_999_6DOF for c in usable_chi2)
        nees = float(np.mean(usable_chi2))
        print(f"\nNEES over the {len(usable_chi2)} scenes called usable: {nees:.2f} (95 % interval [{low:.2f}, "
              f"{high:.2f}]: {'inside' if low <= nees <= high else 'OUTSIDE'}); {outside} outside their 99.9 % region")
        turned = [row for row in rows if "camera_motion" in row and row.get("usable") and row.get("usable_unmeasured")]
        if turned:
            levels = [row["camera_motion"]["level_px"] for row in turned]
            drifts = [float(np.max(np.linalg.norm(row["camera_motion"]["drift_px"], axis=1))) for row in turned
                      if row["camera_motion"].get("drift_px") is not None]
            drifted = f" (the largest drift during a video {min(drifts):.3f}-{max(drifts):.3f} px)" if drifts else ""
            print(f"cameras turned between or during the videos: the background read a level of {min(levels):.3f}-"
                  f"{max(levels):.3f} px per pose (1σ per coordinate){drifted}; NEES over the {len(turned)} scenes "
                  "usable both ways: "
                  f"{np.mean([r['chi2'] for r in turned]):.2f} with the reading, "
                  f"{np.mean([r['chi2_unmeasured'] for r in turned]):.2f} without it (each scene's χ² without: "
                  + ", ".join(f"{r['chi2_unmeasured']:.3g}" for r in turned) + ")")
        shifted = [row for row in rows if row.get("usable") and "shift_mm" in row]
        if shifted:
            named = sum(bool(row["shift_named"]) for row in shifted)
            print(f"an image shift of {IMAGE_SHIFT_PX:g} px per pose (a camera turning about 0.01° between poses) "
                  f"would add a median of {np.median([r['shift_mm'] for r in shifted]):.2f} mm / "
                  f"{np.median([r['shift_deg'] for r in shifted]):.3f}° (1σ, largest axis) to the usable scenes' "
                  f"errors; their words name it (more than the 1σ along some direction) on {named} of {len(shifted)}")
    else:
        print("\nno scene's covariance is called usable")


def _report(rows: list[dict], json_path: str | None, started: float) -> None:
    print_table(rows)
    if json_path is not None:
        Path(json_path).write_text(json.dumps(rows, indent=1, allow_nan=True) + "\n", encoding="utf-8")
    print(f"{time.perf_counter() - started:.0f} s")


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--robots", default="kinova,ur5,panda")
    parser.add_argument("--coverings", default="photo,text,dots")
    parser.add_argument("--seeds", default="0")
    parser.add_argument("--variants", default="nominal", help=f"comma-separated, of {', '.join(VARIANTS)}")
    parser.add_argument("--duration", type=float, default=20.0, help="spin length per arm pose (s)")
    parser.add_argument("--features", default=None, help="TrackerParams.features (default: the tracker's default)")
    parser.add_argument("--corner-max-anisotropy", type=float, default=None,
                        help="TrackerParams.corner_max_anisotropy (default: the tracker's default, every corner kept)")
    parser.add_argument("--jobs", type=int, default=1)
    parser.add_argument("--save", default=None, metavar="DIR", help="write each scene's tracked dataset under DIR")
    parser.add_argument("--load", default=None, metavar="DIR",
                        help="re-run only the calibration on the scenes saved under DIR (no rendering, no tracking)")
    parser.add_argument("--quick", action="store_true", help="one 3 s scene: checks that it runs")
    parser.add_argument("--spin-model", default=None, choices=("free", "rigid"),
                        help="CalibrationOptions.spin_model (default: the calibration's default)")
    parser.add_argument("--method", default="joint", choices=("joint", "weighted", "paper"),
                        help="the calibration's estimator (default: joint)")
    parser.add_argument("--axis-floor-px", type=float, default=None,
                        help="CalibrationOptions.axis_floor_px (default: what the tracker wrote into the dataset)")
    parser.add_argument("--track-offset-px", type=float, default=None,
                        help="CalibrationOptions.track_offset_px (default: what the tracker wrote into the dataset)")
    parser.add_argument("--json", default=None, metavar="FILE", help="also write the rows (every number) to FILE")
    parser.add_argument("--synced", action="store_true", help="with --load: add each spin's joint readings (the "
                        "simulator's spin read at 100/s, 0.02 deg noise) and calibrate synced")
    parser.add_argument("--jitter-px", type=float, default=0.0, metavar="SIGMA",
                        help="with --load: add Gaussian noise of SIGMA px to every tracked pixel (1e-6: does an "
                        "answer hang on rounding?)")
    parser.add_argument("--camera-turn-deg", type=float, default=0.0, metavar="DEG",
                        help="turn each pose's camera by N(0, DEG²) about its x and y axes (the room stays), read the "
                        "turns off the videos' background and calibrate with and without that reading")
    parser.add_argument("--camera-drift-deg", type=float, default=0.0, metavar="DEG",
                        help="turn each pose's camera steadily during its video, by N(0, DEG²) about its x and y axes "
                        "by the last frame (each frame warped), read it off the videos' background and calibrate "
                        "with and without that reading")
    parser.add_argument("--poses", default="sampled", choices=("sampled", "planned"),
                        help="the simulator's sampled arm poses, or gtsam_rotid.planning's at a perturbed guess")
    args = parser.parse_args(argv)
    options = CalibrationOptions(axis_floor_px=args.axis_floor_px, track_offset_px=args.track_offset_px,
                                 **({} if args.spin_model is None else {"spin_model": args.spin_model}))
    started = time.perf_counter()
    if not args.jitter_px >= 0.0:
        parser.error(f"--jitter-px must be a noise sigma >= 0 px, got {args.jitter_px}")
    if (args.synced or args.jitter_px) and args.load is None:
        parser.error("--synced and --jitter-px re-calibrate saved scenes: give --load DIR")
    if args.load is not None:
        roots = sorted(p.parent for p in Path(args.load).glob(f"*/{SCENE_FILE}"))
        if not roots:
            parser.error(f"no saved scene ({SCENE_FILE}) under {args.load}")
        print(f"{len(roots)} saved scenes from {args.load}: calibration only", flush=True)
        if args.jobs > 1:
            from joblib import Parallel, delayed
            rows = Parallel(n_jobs=args.jobs)(delayed(load_scene)(str(r), options, args.method, args.synced,
                                                                  args.jitter_px)
                                              for r in roots)
        else:
            rows = [load_scene(str(r), options, args.method, args.synced, args.jitter_px) for r in roots]
        _report(rows, args.json, started)
        return 0
    if args.quick:
        args.robots, args.coverings, args.seeds, args.duration = "kinova", "photo", "0", 3.0
    variants = args.variants.split(",")
    unknown = [v for v in variants if v not in VARIANTS]
    if unknown:
        parser.error(f"unknown variant(s) {unknown}; choose of {list(VARIANTS)}")
    settings = {} if args.features is None else {"features": args.features}
    if args.corner_max_anisotropy is not None:
        settings["corner_max_anisotropy"] = args.corner_max_anisotropy
    params = TrackerParams(**settings)
    scenes = list(itertools.product(args.robots.split(","), args.coverings.split(","), variants,
                                    [int(s) for s in args.seeds.split(",")]))
    print(f"{len(scenes)} scenes, {args.duration:g} s spins (short: {VARIANTS['short'][0]:g} s), tracker "
          f"features={params.features!r}", flush=True)
    if args.jobs > 1:
        from joblib import Parallel, delayed
        rows = Parallel(n_jobs=args.jobs)(delayed(run_scene)(r, c, s, v, args.duration, params, args.save, options,
                                                             args.poses, args.method, args.camera_turn_deg,
                                                             args.camera_drift_deg)
                                          for r, c, v, s in scenes)
    else:
        rows = [run_scene(r, c, s, v, args.duration, params, args.save, options, args.poses, args.method,
                          args.camera_turn_deg, args.camera_drift_deg) for r, c, v, s in scenes]
    _report(rows, args.json, started)
    return 0


if __name__ == "__main__":
    sys.exit(main())

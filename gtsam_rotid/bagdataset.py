"""A :class:`Dataset` from a ROS bag (:mod:`gtsam_rotid.bags`): the spins found in the joint states (only the
spinning joint moves), each spin's still joints, the camera from ``CameraInfo`` (or a camera file), the
camera-to-joint-state time offset measured and applied, and the tracker run on each spin's images.
"""

from __future__ import annotations

import os
import sys
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
from tqdm import tqdm

from .arm import Arm
from .bags import MIN_OFFSET_CORRELATION, Bag, BagError, estimate_time_offset, is_rectified
from .camera import Camera
from .camerafiles import load_camera
from .dataset import Dataset, Measurement, SpinReadings
from .errors import ArmError, InputError, ValidationError
from .frames import with_ends
from .recordings import (
    MIN_SPIN_DEG,
    READINGS_MARGIN_S,
    SPIN_MARGIN_S,
    STILL_TOLERANCE_DEG,
    JointFile,
    _spin_runs,
    _still_pose,
)
from .trackrun import default_tracker, tracked_frames, tracker_description


def dataset_from_bag(path: str | os.PathLike, arm: Arm, *, image_topic: str | None = None,
                     joint_topic: str | None = None, camera_info_topic: str | None = None,
                     camera: Camera | str | os.PathLike | None = None, tracker: Callable | None = None,
                     tracker_params: Any = None, still_tolerance_deg: float = STILL_TOLERANCE_DEG,
                     min_spin_deg: float = MIN_SPIN_DEG, max_offset_s: float = 1.0,
                     time_offset_s: float | None = None, progress: bool = True,
                     metadata: Mapping | None = None, spin_joints: Sequence[str] | None = None) -> Dataset:
    """One measurement per spin of ``arm.wrist_joint`` (or of each of ``spin_joints``) found in the bag's joint
    states.

    Args:
        path: a ROS 1 ``.bag`` file or a ROS 2 bag directory (sqlite3 or mcap storage; its storage file works too).
        arm: the robot; its joint names must appear in the joint states.
        image_topic, joint_topic, camera_info_topic: found by message type when not given and unambiguous.
        camera: a :class:`Camera` or camera file, used instead of the bag's ``CameraInfo``.
        tracker, tracker_params: as :func:`gtsam_rotid.recordings.make_dataset`.
        still_tolerance_deg, min_spin_deg: what counts as a spin (:func:`gtsam_rotid.recordings.find_spins`).
        max_offset_s: the largest camera-to-joint-state time offset searched.
        time_offset_s: the offset (camera clock minus joint-state clock, s) when it is known: then it is applied as
            given, and only measured for the record.
        spin_joints: the joints whose spins are measurements (names; default the wrist alone): a spin of another
            joint (the one before the wrist, at the same arm pose) swings the hand about that joint's axis and makes
            the offsets of more joints observable (``Measurement.spin_joint``).

    The offset is read off when the images start and stop moving against when the joints do
    (:func:`gtsam_rotid.bags.estimate_time_offset`); it is applied, and recorded with its score in
    ``metadata["recording"]``, when its score is at least MIN_OFFSET_CORRELATION, no other offset scores nearly as
    well and it is not at the edge of the search (else it is recorded, not applied, and a warning printed). Track
    frame indices are the images' positions on the topic. Each measurement carries the spinning joint's states
    around its spin as its spin readings (synced mode, ``CalibrationOptions.sync_encoders``), its frames' times the
    images' stamps less the offset applied (the calibration then estimates what remains). Images of
    ``image_rect*`` topics get CameraInfo's projection matrix without distortion. Raises :class:`BagError` naming
    the bag and topic: no spin, a spin without images, images of another size.
    """
    joints = _spin_joints(arm, spin_joints)
    with Bag(path) as bag:
        topics = bag.choose_topics(image_topic, joint_topic, camera_info_topic, with_camera_info=camera is None)
        where = f"{bag.path}, topic {topics.image}"
        camera_from = "given"
        if camera is None:
            if topics.camera_info is None:
                raise BagError(f"the bag {bag.path} has no CameraInfo topic: give the camera (--camera FILE)")
            rectified = is_rectified(topics.image)
            camera = bag.camera(topics.camera_info, rectified=rectified)
            camera_from = topics.camera_info + (" (P, rectified images)" if rectified else "")
        elif not isinstance(camera, Camera):
            camera_from = os.fspath(camera)
            camera = load_camera(camera)
        stamps, positions = bag.joint_states(topics.joints, arm.joint_names)
        unwrapped = np.unwrap(positions, axis=0)
        found = {joint: _spin_runs(unwrapped, arm.spin_index(joint), still_tolerance_deg, min_spin_deg)
                 for joint in arm.joint_names}
        runs = sorted((a, b, joint) for joint in joints for a, b in found[joint])
        others = {joint: len(r) for joint, r in found.items() if joint not in joints and r}
        if not runs:
            also = ("; " + ", ".join(f"{j!r} turned alone {n} time(s)" for j, n in others.items())
                    + ": name the joints that spun with --spin-joints") if others else ""
            raise BagError(f"{bag.path}, topic {topics.joints}: no spin of {' or '.join(map(repr, joints))} (at "
                           f"least {min_spin_deg:g} deg while no other joint moves by more than "
                           f"{still_tolerance_deg:g} deg) in the joint states{also}")
        missing = [joint for joint in joints if not found[joint]]
        if missing:  # (asked for, e.g. to make more offsets observable: say so rather than leave them out quietly)
            print(f"warning: {bag.path}, topic {topics.joints}: no spin of " + ", ".join(map(repr, missing))
                  + f" (at least {min_spin_deg:g} deg while no other joint moves by more than "
                  f"{still_tolerance_deg:g} deg): the dataset holds the spins of "
                  + ", ".join(repr(j) for j in joints if found[j]) + " only", file=sys.stderr)
        if others:  # (a move between poses may turn one joint alone too)
            print(f"note: {bag.path}, topic {topics.joints}: " + ", ".join(f"{j!r} turned alone {n} time(s)"
                                                                          for j, n in others.items())
                  + f" by at least {min_spin_deg:g} deg: not measurements (only the spins of "
                  + ", ".join(repr(j) for j in joints if found[j]) + " are; name the joints to use with --spin-joints)",
                  file=sys.stderr)
        image_stamps, motion = bag.image_motion(topics.image)
        offset, correlation, rival = estimate_time_offset(image_stamps, motion, stamps, positions, max_offset_s)
        at_edge = bool(np.isfinite(offset) and abs(offset) > max_offset_s - 0.5 * _period(image_stamps))
        applied = bool(np.isfinite(offset) and correlation >= MIN_OFFSET_CORRELATION and not at_edge
                       and rival is None)
        if time_offset_s is not None:
            shift = float(time_offset_s)
        else:
            shift = offset if applied else 0.0
            if not applied:
                why = (f"the best offset, {offset:+.3f} s, is at the edge of the search (+-{max_offset_s:g} s): the "
                       "clocks may differ by more (--max-time-offset)" if at_edge else
                       f"{offset:+.3f} s and {rival:+.3f} s fit about as well: the spins repeat with one rhythm"
                       if rival is not None else f"image motion and joint motion correlate only {correlation:.2f}")
                print(f"warning: {where}: the camera-to-joint-state time offset could not be measured ({why}); the "
                      "stamps are taken as they are (give it with --time-offset if known)", file=sys.stderr)
        joint_file = JointFile(Path(f"{bag.path}:{topics.joints}"), positions, stamps)
        tracker, described, corner_tracks = default_tracker(tracker, tracker_params)
        measurements, spans, first_images, last_images = [], [], [], []
        with tqdm(total=len(runs), desc="spins", unit="spin", disable=not progress, file=sys.stderr) as bar:
            for k, (a, b, joint) in enumerate(runs):
                spin_joint = None if arm.spins_wrist(joint) else joint
                label = (f"spin {k}" + ("" if spin_joint is None else f" of {joint!r}")
                         + f" (joint stamps {stamps[a]:.3f} to {stamps[b - 1]:.3f} s)")
                angles = _still_pose(joint_file, unwrapped, np.arange(a, b), arm, label, still_tolerance_deg,
                                     min_spin_deg, spin_joint)
                start, stop = stamps[a] + shift + SPIN_MARGIN_S, stamps[b - 1] + shift - SPIN_MARGIN_S
                inside = np.flatnonzero((image_stamps >= start) & (image_stamps <= stop))
                if len(inside) < 2:
                    raise BagError(f"{label}: {len(inside)} image(s) on {topics.image} between the camera stamps "
                                   f"{start:.3f} and {stop:.3f} s (images span {image_stamps.min():.3f} to "
                                   f"{image_stamps.max():.3f} s): if the camera's and the joint states' clocks "
                                   "differ by more than the search (--max-time-offset), give the offset "
                                   "(--time-offset)")
                first, last = int(inside[0]), int(inside[-1])  # every image between, in the bag's order
                ends: list = []  # (kept: the camera's stillness is read on each spin's first and last image)
                frames = with_ends((image for _, _, image in bag.images(topics.image, first, last)), ends)
                tracks = tracked_frames(frames, last - first + 1, first, Path(where), camera, tracker,
                                        tracker_params, k, label, progress)
                first_images.append(ends[0])
                last_images.append(ends[1])
                readings = _spin_readings(image_stamps - shift, stamps, unwrapped[:, arm.spin_index(spin_joint)], a,
                                          b, label)
                measurements.append(Measurement(angles, tracks, name=f"spin {k}", spin_readings=readings,
                                                spin_joint=spin_joint))
                spans.append([float(stamps[a]), float(stamps[b - 1])])
                bar.update(1)
    recording = {
        "bag": os.path.abspath(path),
        "topics": {"image": topics.image, "joints": topics.joints, "camera_info": topics.camera_info},
        "camera_from": camera_from,
        "spans": spans,
        "spin_joints": [run[2] for run in runs],
        "time_offset_s": None if not np.isfinite(offset) else float(offset),
        "time_offset_correlation": float(correlation),
        "time_offset_rival_s": rival,
        "time_offset_applied": bool(time_offset_s is None and applied),
        "time_offset_given_s": None if time_offset_s is None else float(time_offset_s),
        "tracker": tracker_description(described, tracker_params),
    }
    extra: dict[str, Any] = {"recording": recording}
    if corner_tracks is not None:
        from .trackparams import tracker_metadata
        extra["tracker"] = tracker_metadata(tracker_params, sum(corner_tracks))
    if len(first_images) > 1:  # did the camera stay still between and during the spins? (their images' background)
        from .stillness import motion_metadata

        motion = motion_metadata(first_images, [m.name for m in measurements], f"the spins of {path}",
                                 last=last_images)
        if motion is not None:
            extra["camera_motion"] = motion
    return Dataset(arm, camera, measurements, metadata={**extra, **dict(metadata or {})})


def _spin_joints(arm: Arm, spin_joints: Sequence[str] | None) -> list[str]:
    """The names of the joints whose spins are measurements (default the wrist), each once; an InputError naming
    one the arm cannot spin."""
    if spin_joints is None:
        return [arm.wrist_joint]
    if isinstance(spin_joints, str) or not len(spin_joints):
        raise InputError(f"spin_joints must be a list of joint names (at least one), got {spin_joints!r}")
    for joint in spin_joints:
        try:
            arm.spin_index(joint)
        except ArmError as exc:
            raise InputError(f"spin_joints: {exc}") from None
    if len(set(spin_joints)) < len(spin_joints):
        raise InputError(f"spin_joints names a joint more than once: {list(spin_joints)} (a bag's spins of each "
                         "joint named are found once)")
    return list(spin_joints)


def _spin_readings(frame_times: np.ndarray, stamps: np.ndarray, wrist: np.ndarray, a: int, b: int,
                   label: str) -> SpinReadings | None:
    """The spin's joint states ``a:b`` (with READINGS_MARGIN_S of rest on each side) as its readings, the images'
    stamps moved onto the joint states' clock as its frame times; None (with a warning) where the stamps are not
    in order (the readings then are not used)."""
    window = (stamps >= stamps[a] - READINGS_MARGIN_S) & (stamps <= stamps[b - 1] + READINGS_MARGIN_S)
    try:
        return SpinReadings(frame_times, stamps[window], wrist[window])
    except ValidationError as error:
        print(f"warning: {label}: its joint readings are not attached (no synced mode): {error}", file=sys.stderr)
        return None


def _period(stamps: np.ndarray) -> float:
    steps = np.diff(stamps)
    return float(np.median(steps)) if steps.size else 0.0

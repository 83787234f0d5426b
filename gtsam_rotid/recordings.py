"""Real recordings: videos (or image folders), a joint-angle file and a camera file -> a :class:`Dataset`.

One video file or one folder of images per measurement (one wrist spin at a fixed arm pose), plus:

* a **camera file**: OpenCV's calibration YAML (as written by ``cv2.FileStorage``; also its XML and JSON) or a
  ROS ``camera_info`` YAML (``camera_calibration`` output, or a ``CameraInfo`` message echoed by ``rostopic`` /
  ``ros2 topic``), read by :func:`load_camera` (in :mod:`gtsam_rotid.camerafiles`);
* a **joint-angle file** (CSV or JSON), read by :func:`load_joints`: either one row of joint angles per
  measurement, or a time series of joint states from which each spin's still joints are read, after checking
  that only the spinning joint moved (the wrist, or the joint each video names: ``spin_joints``).

:func:`make_dataset` runs a feature tracker (by default :func:`gtsam_rotid.tracking.track`) on every video and
builds the dataset; :func:`add_track_parser` / :func:`cmd_track` are the ``gtsam-rotid track`` command.

Angles in files are radians unless ``degrees=True``; the arrays returned are radians, ``arm.joint_names`` order.
Track frame indices are the video's own frame numbers (a frame range ``(100, 900)`` gives tracks whose frames
start at 100 or later).
"""

from __future__ import annotations

import csv
import dataclasses
import io
import json
import math
import os
import sys
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from tqdm import tqdm

from .arm import Arm
from .bags import estimate_time_offset
from .camera import Camera
from .camerafiles import load_camera, parse_yaml  # noqa: F401 (parse_yaml: re-export)
from .dataset import Dataset, Measurement, SpinReadings, Track
from .errors import ArmError, InputError, RecordingError, ValidationError
from .files import VIDEO_SUFFIXES, image_files, natural_key
from .frames import (  # noqa: F401 (read_frames: re-export)
    _range_text,
    checked_range,
    frames_of,
    open_source,
    read_frames,
    video_fps,
    with_ends,
    with_motion,
)
from .trackrun import default_tracker, tracked_frames, tracker_description

#: Column names (case-insensitive) that make a joint CSV a time series.
TIME_COLUMNS = ("time", "stamp", "stamps", "timestamp", "t", "%time")
#: Default largest motion (peak to peak, degrees) of a non-wrist joint during a spin.
STILL_TOLERANCE_DEG = 0.2
#: Default smallest wrist rotation (peak to peak, degrees) that counts as a spin.
MIN_SPIN_DEG = 45.0


# ---------------------------------------------------------------------------------------------- joint files
@dataclass(frozen=True, eq=False)
class JointFile:
    """The content of a joint-angle file, in the arm's model order and radians.

    ``positions`` is (N, dof); ``stamps`` is (N,) for a time series of joint states, ``None`` for a file of one
    row per measurement. ``path`` is the file it came from (for messages).
    """

    path: Path
    positions: np.ndarray
    stamps: np.ndarray | None = None

    @property
    def is_time_series(self) -> bool:
        return self.stamps is not None


def _parse_number(text: str, where: str) -> float:
    try:
        return float(text)
    except ValueError:
        raise RecordingError(f"{where}: {text!r} is not a number") from None


def _is_number(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


def _read_joint_csv(path: Path, text: str) -> tuple[list[str] | None, list[list[float]], list[float] | None]:
    lines = [(n, line) for n, line in enumerate(text.splitlines(), 1)
             if line.strip() and not line.lstrip().startswith("#")]
    if not lines:
        raise RecordingError(f"the joint file {path} is empty")
    first = lines[0][1]
    delimiter = next((d for d in (",", ";", "\t") if d in first), None)
    if delimiter is None:
        rows = [(n, line.split()) for n, line in lines]
    else:
        rows = [(n, [cell.strip() for cell in cells])
                for (n, _), cells in zip(lines, csv.reader(io.StringIO("\n".join(line for _, line in lines)),
                                                           delimiter=delimiter), strict=True)]
    header = None
    if not all(_is_number(cell) for cell in rows[0][1]):
        header = rows.pop(0)[1]
        if any(not cell for cell in header):
            raise RecordingError(f"{path}: the header row has an empty column name: {header}")
    if not rows:
        raise RecordingError(f"the joint file {path} has a header but no rows of joint angles")
    width = len(header) if header is not None else len(rows[0][1])
    values = []
    for n, cells in rows:
        if len(cells) != width:
            raise RecordingError(f"{path}, line {n}: {len(cells)} values, expected {width}"
                                 + (f" (one per column of the header {header})" if header else ""))
        values.append([_parse_number(cell, f"{path}, line {n}") for cell in cells])
    stamps = None
    if header is not None:
        time_columns = [i for i, name in enumerate(header) if name.lower() in TIME_COLUMNS]
        if len(time_columns) > 1:
            raise RecordingError(f"{path}: more than one time column: {[header[i] for i in time_columns]}")
        if time_columns:
            column = time_columns[0]
            stamps = [row.pop(column) for row in values]
            header = header[:column] + header[column + 1:]
    return header, values, stamps


def _json_rows(rows: Any, path: Path, what: str) -> tuple[list[str] | None, list]:
    """Rows of a JSON file: lists of numbers (model order) or dicts name -> angle."""
    if not isinstance(rows, list) or not rows:
        raise RecordingError(f"{path}: {what} must be a non-empty list of rows")
    if all(isinstance(row, Mapping) for row in rows):
        names = list(rows[0])
        for i, row in enumerate(rows):
            if set(row) != set(names):
                raise RecordingError(f"{path}: {what} row {i} names the joints {sorted(row)}, but row 0 names "
                                     f"{sorted(names)}")
        return names, [[row[name] for name in names] for row in rows]
    if not all(isinstance(row, list) for row in rows):
        raise RecordingError(f"{path}: {what} must be a list of rows (lists of numbers or dicts name -> angle)")
    return None, rows


def _read_joint_json(path: Path, text: str) -> tuple[list[str] | None, list, list | None]:
    try:
        document = json.loads(text)
    except json.JSONDecodeError as exc:
        raise RecordingError(f"the joint file {path} is not valid JSON: {exc.msg} (line {exc.lineno})") from None
    if isinstance(document, list):
        names, rows = _json_rows(document, path, "the file")
        return names, rows, None
    if not isinstance(document, Mapping):
        raise RecordingError(f"{path}: expected a list of rows or an object with 'joint_names', got "
                             f"{type(document).__name__}")
    names = document.get("joint_names")
    if names is not None and (not isinstance(names, list) or not all(isinstance(n, str) for n in names)):
        raise RecordingError(f"{path}: 'joint_names' must be a list of strings")
    if "positions" in document or "stamps" in document:
        for key in ("stamps", "positions"):
            if key not in document:
                raise RecordingError(f"{path}: a time series needs both 'stamps' and 'positions'; '{key}' is missing")
        row_names, rows = _json_rows(document["positions"], path, "'positions'")
        stamps = document["stamps"]
        if not isinstance(stamps, list):
            raise RecordingError(f"{path}: 'stamps' must be a list of numbers")
        return names if row_names is None else row_names, rows, stamps
    if "measurements" in document:
        row_names, rows = _json_rows(document["measurements"], path, "'measurements'")
        return names if row_names is None else row_names, rows, None
    raise RecordingError(f"{path}: expected the key 'measurements' (one row per measurement) or 'stamps' and "
                         f"'positions' (a time series); found {sorted(document)}")


def _model_order(names: list[str] | None, values: np.ndarray, arm: Arm, path: Path,
                 ignore_joints: Sequence[str]) -> np.ndarray:
    """Columns of ``values`` (named ``names``, or model order when None) as (N, dof) in ``arm.joint_names`` order."""
    if names is None:
        if values.shape[1] != arm.dof:
            raise RecordingError(f"{path}: rows have {values.shape[1]} values but the arm {arm.name!r} has "
                                 f"{arm.dof} joints ({', '.join(arm.joint_names)}); add a header row naming the "
                                 f"columns, or give one value per joint in this order")
        return values
    if len(names) != values.shape[1]:
        raise RecordingError(f"{path}: {len(names)} joint names but rows have {values.shape[1]} values")
    duplicates = sorted({n for n in names if names.count(n) > 1})
    if duplicates:
        raise RecordingError(f"{path}: joint name(s) {duplicates} appear more than once")
    ignored = set(ignore_joints)
    unknown = [n for n in names if n not in arm.joint_names and n not in ignored]
    missing = [n for n in arm.joint_names if n not in names]
    if unknown or missing:
        parts = []
        if unknown:
            parts.append(f"unknown joint name(s) {unknown}")
        if missing:
            parts.append(f"missing joint(s) {missing}")
        raise RecordingError(f"{path}: {' and '.join(parts)}; the arm {arm.name!r} has the joints "
                             f"{arm.joint_names}" + (" (pass ignore_joints / --ignore-joints for extra columns "
                                                     "such as fingers)" if unknown and not missing else ""))
    return values[:, [names.index(n) for n in arm.joint_names]]


def read_joint_file(path: str | os.PathLike, arm: Arm, *, degrees: bool = False,
                    ignore_joints: Sequence[str] = ()) -> JointFile:
    """Read a joint-angle file (CSV or JSON; the format is told by the ``.json`` ending or a leading ``[`` / ``{``).

    CSV: a header row naming the columns (joint names, and a ``time`` / ``stamp`` column for a time series), or
    no header (one value per joint, ``arm.joint_names`` order). JSON: a list of rows (lists in model order or
    dicts name -> angle), ``{"joint_names": [...], "measurements": [[...], ...]}``, or a time series
    ``{"joint_names": [...], "stamps": [...], "positions": [[...], ...]}``.

    Columns named in ``ignore_joints`` are dropped; any other name that is not one of ``arm.joint_names``, or a
    joint without a column, is a :class:`RecordingError` listing them.
    """
    path = Path(path)
    if not path.is_file():
        raise RecordingError(f"no joint-angle file at {path}" if not path.exists() else
                             f"the joint-angle file {path} is not a file")
    try:
        text = path.read_bytes().decode("utf-8-sig")
    except OSError as exc:
        raise RecordingError(f"cannot read the joint-angle file {path}: {exc.strerror or exc}") from None
    except UnicodeDecodeError:
        raise RecordingError(f"the joint-angle file {path} is not a text file (not UTF-8)") from None
    if path.suffix.lower() == ".json" or text.lstrip()[:1] in ("[", "{"):
        names, rows, stamps = _read_joint_json(path, text)
    else:
        names, rows, stamps = _read_joint_csv(path, text)
    widths = {len(row) for row in rows}
    if len(widths) != 1:
        raise RecordingError(f"{path}: rows have different numbers of values ({sorted(widths)})")
    try:
        values = np.array(rows, dtype=float)
    except (TypeError, ValueError):
        raise RecordingError(f"{path}: joint angles must be numbers") from None
    bad = np.argwhere(~np.isfinite(values))
    if bad.size:
        row, column = bad[0]
        name = names[column] if names is not None else f"column {column}"
        raise RecordingError(f"{path}: row {row}: the angle of {name} is NaN or infinite")
    positions = _model_order(names, values, arm, path, ignore_joints)
    if degrees:
        positions = np.radians(positions)
    stamp_array = None
    if stamps is not None:
        try:
            stamp_array = np.array(stamps, dtype=float)
        except (TypeError, ValueError):
            raise RecordingError(f"{path}: time stamps must be numbers") from None
        if stamp_array.shape != (len(positions),):
            raise RecordingError(f"{path}: {stamp_array.size} time stamps for {len(positions)} rows of positions")
        if not np.all(np.isfinite(stamp_array)):
            raise RecordingError(f"{path}: a time stamp is NaN or infinite")
        backwards = np.flatnonzero(np.diff(stamp_array) < 0)
        if backwards.size:
            i = backwards[0]
            raise RecordingError(f"{path}: time stamps must not decrease; row {i + 1} has {stamp_array[i + 1]:g} "
                                 f"after {stamp_array[i]:g}")
    return JointFile(path, positions, stamp_array)


def _spin_runs(positions: np.ndarray, wrist_index: int, still_tolerance_deg: float,
               min_spin_deg: float) -> list[tuple[int, int]]:
    """Index ranges [a, b) of the spins in unwrapped (N, dof) positions (see :func:`find_spins`)."""
    others = np.delete(positions, wrist_index, axis=1).tolist()
    tolerance = math.radians(still_tolerance_deg)
    runs = []
    start = 0
    low, high = list(others[0]), list(others[0])
    for i in range(1, len(others)):
        row = others[i]
        new_low = [min(a, b) for a, b in zip(low, row, strict=True)]
        new_high = [max(a, b) for a, b in zip(high, row, strict=True)]
        if any(h - lo > tolerance for lo, h in zip(new_low, new_high, strict=True)):
            runs.append((start, i))
            start, low, high = i, list(row), list(row)
        else:
            low, high = new_low, new_high
    runs.append((start, len(others)))
    wrist = positions[:, wrist_index]
    min_spin = math.radians(min_spin_deg)
    return [(a, b) for a, b in runs if b - a >= 2 and np.ptp(wrist[a:b]) >= min_spin]


def find_spins(stamps, positions, wrist_index: int, *, still_tolerance_deg: float = STILL_TOLERANCE_DEG,
               min_spin_deg: float = MIN_SPIN_DEG) -> list[tuple[float, float]]:
    """The (first, last) stamps of each spin in a time series of joint states.

    The series is split, greedily in time, into the longest runs in which no joint but the wrist moves by more
    than ``still_tolerance_deg`` (peak to peak); runs in which the wrist turns by at least ``min_spin_deg`` are
    the spins. ``positions`` is (N, dof) radians; continuous joints may wrap at +-pi.
    """
    stamps = np.asarray(stamps, dtype=float)
    unwrapped = np.unwrap(np.asarray(positions, dtype=float), axis=0)
    return [(float(stamps[a]), float(stamps[b - 1]))
            for a, b in _spin_runs(unwrapped, wrist_index, still_tolerance_deg, min_spin_deg)]


def _label(k: int, labels: Sequence[str] | None) -> str:
    return f"measurement {k}" + (f" ({labels[k]})" if labels is not None and k < len(labels) else "")


def _still_pose(joint_file: JointFile, unwrapped: np.ndarray, inside: np.ndarray, arm: Arm, label: str,
                still_tolerance_deg: float, min_spin_deg: float, spin_joint: str | None = None) -> np.ndarray:
    """The arm pose held during one spin (samples ``inside``): median of the still joints, the spinning joint
    (``spin_joint``, default the wrist) at its start."""
    stamps = joint_file.stamps
    t0, t1 = stamps[inside[0]], stamps[inside[-1]]
    segment = unwrapped[inside]
    motion = np.degrees(np.ptp(segment, axis=0))
    wrist = arm.spin_index(spin_joint)
    what = "the wrist" if spin_joint is None else f"the spinning joint {spin_joint!r}"
    moved = [(arm.joint_names[j], motion[j]) for j in range(arm.dof) if j != wrist and motion[j] > still_tolerance_deg]
    if moved:
        listed = ", ".join(f"{name!r} by {deg:.3g} deg" for name, deg in moved)
        raise RecordingError(f"{label}: only {what} may move during a spin, but between the stamps {t0:g} and "
                             f"{t1:g} the joint(s) {listed} moved (tolerance {still_tolerance_deg:g} deg, peak to "
                             f"peak) in {joint_file.path}")
    if motion[wrist] < min_spin_deg:
        what = f"the wrist {arm.wrist_joint!r}" if spin_joint is None else what
        raise RecordingError(f"{label}: {what} turned by only {motion[wrist]:.3g} deg between "
                             f"the stamps {t0:g} and {t1:g} (a spin needs at least {min_spin_deg:g} deg) in "
                             f"{joint_file.path}")
    # the medians of the unwrapped series, taken back by the turns the unwrapping added (a continuous wrist that
    # wrapped during earlier spins, still while another joint spins, is read as its own reading, not 2 pi off)
    pose = np.median(segment, axis=0) + (joint_file.positions[inside[0]] - segment[0])
    pose[wrist] = joint_file.positions[inside[0], wrist]
    return pose


def load_joints(path: str | os.PathLike, arm: Arm, n_measurements: int | None = None, *, degrees: bool = False,
                spans: Sequence[tuple[float, float]] | None = None,
                still_tolerance_deg: float = STILL_TOLERANCE_DEG, min_spin_deg: float = MIN_SPIN_DEG,
                ignore_joints: Sequence[str] = (), labels: Sequence[str] | None = None,
                spin_joints: Sequence[str | None] | None = None) -> np.ndarray:
    """The joint angles of each measurement, (n_measurements, dof) radians in ``arm.joint_names`` order.

    ``path`` is read by :func:`read_joint_file`. A file of one row per measurement must have
    ``n_measurements`` rows (when given). For a time series, each measurement's span of stamps is ``spans[k]``
    = (first, last) (inclusive, in the file's time unit), or, when ``spans`` is None, found by
    :func:`find_spins`; the still joints are the median over the span, the wrist is its angle at the span's
    start. Every non-wrist joint must stay within ``still_tolerance_deg`` (peak to peak) and the wrist must
    turn by at least ``min_spin_deg``, else a :class:`RecordingError` names the measurement (with its
    ``labels[k]``, e.g. the video), the joint and how much it moved. ``spin_joints`` (one joint name or None per
    measurement): the joint that spun in each, in the wrist's place; spins of different joints need ``spans``.
    """
    return _load_joints(path, arm, n_measurements, degrees=degrees, spans=spans,
                        still_tolerance_deg=still_tolerance_deg, min_spin_deg=min_spin_deg,
                        ignore_joints=ignore_joints, labels=labels, spin_joints=spin_joints).angles


@dataclass(frozen=True)
class _LoadedJoints:
    """:func:`load_joints`' angles, and for a time series the file, its unwrapped positions and each measurement's
    rows (indices into the series)."""

    angles: np.ndarray
    joint_file: JointFile
    unwrapped: np.ndarray | None = None
    selections: tuple = ()


def _load_joints(path, arm: Arm, n_measurements: int | None = None, *, degrees: bool = False, spans=None,
                 still_tolerance_deg: float = STILL_TOLERANCE_DEG, min_spin_deg: float = MIN_SPIN_DEG,
                 ignore_joints: Sequence[str] = (), labels: Sequence[str] | None = None,
                 spin_joints: Sequence[str | None] | None = None) -> _LoadedJoints:
    joint_file = read_joint_file(path, arm, degrees=degrees, ignore_joints=ignore_joints)
    if n_measurements is not None and (isinstance(n_measurements, bool) or not isinstance(n_measurements, int)
                                       or n_measurements < 1):
        raise InputError(f"n_measurements must be a positive integer, got {n_measurements!r}")
    if not joint_file.is_time_series:
        if spans is not None:
            raise RecordingError(f"{joint_file.path} has one row per measurement (no time column); spans apply "
                                 f"only to a time series of joint states")
        rows = len(joint_file.positions)
        if n_measurements is not None and rows != n_measurements:
            raise RecordingError(f"{joint_file.path} has {rows} row(s) of joint angles (one per measurement) but "
                                 f"there are {n_measurements} measurements (videos)")
        return _LoadedJoints(_within_limits(joint_file.positions.copy(), arm, joint_file.path, labels), joint_file)
    unwrapped = np.unwrap(joint_file.positions, axis=0)
    stamps = joint_file.stamps
    spinning = list(spin_joints) if spin_joints is not None else None
    if spinning is not None and n_measurements is not None and len(spinning) != n_measurements:
        raise InputError(f"{len(spinning)} spin joint(s) for {n_measurements} measurements; give one per video")
    for joint in spinning or ():
        arm.spin_index(joint)  # ArmError (an InputError) names a joint the arm does not have
    if spans is None and spinning is not None and len({arm.spin_index(j) for j in spinning}) > 1:
        raise RecordingError(f"{joint_file.path}: the videos spin different joints ({sorted(set(map(str, spinning)))})"
                             "; give each video's time span explicitly (spans / --spans)")
    if spans is None:
        spin = arm.spin_index(spinning[0]) if spinning else arm.wrist_index
        runs = _spin_runs(unwrapped, spin, still_tolerance_deg, min_spin_deg)
        if not runs or (n_measurements is not None and len(runs) != n_measurements):
            found = "; ".join(f"{stamps[a]:g} to {stamps[b - 1]:g}" for a, b in runs) or "none"
            expected = f", expected {n_measurements} (one per video)" if n_measurements is not None else ""
            raise RecordingError(f"{joint_file.path}: found {len(runs)} spin(s) (time spans in which only the "
                                 f"joint {arm.joint_names[spin]!r} moved, by at least {min_spin_deg:g} deg, the other "
                                 f"joints within {still_tolerance_deg:g} deg){expected}: {found}. Give each video's "
                                 f"time span explicitly (spans / --spans), or adjust still_tolerance_deg / "
                                 f"min_spin_deg")
        selections = [np.arange(a, b) for a, b in runs]
    else:
        spans = [tuple(span) for span in spans]
        if any(len(span) != 2 for span in spans):
            raise InputError("each span must be a pair (first stamp, last stamp)")
        if n_measurements is not None and len(spans) != n_measurements:
            raise RecordingError(f"{len(spans)} time span(s) given for {n_measurements} measurements (videos)")
        selections = []
        for k, (t0, t1) in enumerate(spans):
            t0, t1 = float(t0), float(t1)
            if not t0 <= t1:
                raise RecordingError(f"{_label(k, labels)}: its time span starts at {t0:g} after it ends at {t1:g}")
            inside = np.flatnonzero((stamps >= t0) & (stamps <= t1))
            if inside.size < 2:
                raise RecordingError(f"{_label(k, labels)}: the joint time series in {joint_file.path} has "
                                     f"{inside.size} sample(s) between the stamps {t0:g} and {t1:g} (it spans "
                                     f"{stamps[0]:g} to {stamps[-1]:g}); a spin needs at least 2")
            selections.append(inside)
    angles = _within_limits(np.array([_still_pose(joint_file, unwrapped, inside, arm, _label(k, labels),
                                                  still_tolerance_deg, min_spin_deg,
                                                  None if spinning is None else spinning[k])
                                      for k, inside in enumerate(selections)]), arm, joint_file.path, labels)
    return _LoadedJoints(angles, joint_file, unwrapped, tuple(selections))


def _within_limits(angles: np.ndarray, arm: Arm, path: Path, labels: Sequence[str] | None) -> np.ndarray:
    """``angles`` (one row per measurement), or a RecordingError naming the file and the measurement whose joints
    pass the model's limits (with a hint when the file reads as degrees)."""
    for k, row in enumerate(angles):
        problem = arm.limit_problem(row)
        if problem is not None:
            raise RecordingError(f"{path}, {_label(k, labels)}: {problem}")
    return angles


# ---------------------------------------------------------------------------------------------- dataset
def _joint_rows(joints, arm: Arm, labels: list[str], joint_options: Mapping | None,
                spin_joints: list[str | None] | None = None) -> tuple[list[np.ndarray], _LoadedJoints | None]:
    """One joint-angle vector per video (``joints``: rows, or a joint-angle file read with ``joint_options``), and
    the file as read (None for rows)."""
    n = len(labels)
    loaded = None
    if isinstance(joints, (str, os.PathLike)):
        loaded = _load_joints(joints, arm, n, labels=labels, spin_joints=spin_joints, **dict(joint_options or {}))
        joints = loaded.angles
    elif joint_options:
        raise InputError("joint_options apply only when joints is the path of a joint-angle file")
    if isinstance(joints, np.ndarray) and joints.ndim != 2:
        raise InputError(f"joints must be (n, dof) joint angles, one row per video, got shape {joints.shape}")
    joints = list(joints)
    if len(joints) != n:
        raise InputError(f"{len(joints)} row(s) of joint angles for {n} video(s); give one per video")
    angles = []
    for k, row in enumerate(joints):
        try:
            angles.append(arm.joint_angle_vector(row))
        except ArmError as exc:
            raise InputError(f"{_label(k, labels)}: {exc}") from None
    return angles, loaded


def _tracked(source, frame_range, camera: Camera, tracker: Callable, tracker_params, k: int, label: str,
             progress: bool, motion: list | None = None, ends: list | None = None) -> tuple[list[Track], int]:
    """The tracks of one video (frame indices the video's own), at least 2, or a RecordingError naming it; and the
    index of its first frame. ``motion``: filled with each frame's change from the one before (see
    :func:`gtsam_rotid.frames.with_motion`); ``ends``: with its first and last frame (:func:`~.frames.with_ends`)."""
    frames, expected, first = frames_of(source, frame_range)
    if motion is not None:
        frames = with_motion(frames, motion)
    if ends is not None:
        frames = with_ends(frames, ends)
    return tracked_frames(frames, expected, first, source.path, camera, tracker, tracker_params, k, label,
                          progress), first


#: A spin's readings (Measurement.spin_readings, synced mode: a video's, or a bag's spin's) reach this far (s) beyond
#: its frames' span (a bag: beyond its first and last joint state), so that the estimated clocks' offset can move
#: the frames within them.
READINGS_MARGIN_S = 1.0
#: A video's frames must come to rest at its start or its end (the spin starts or stops within it) for its place on
#: a joint time series to be measured: its first or its last REST_PAIRS frame-to-frame motions at most
#: STILL_MOTION_RATIO of the ninetieth percentile of them (three still frames). Image motion is far from linear in
#: the joint's speed (a textured hand's frame difference is 0.8-0.95 of its steady value one frame into a half-second
#: ramp), so a video cut inside its spin has no frame at rest, and its place is not measured: one cut at the end of
#: its ramp was placed a third of a second off at a correlation of 0.85. (It was the tenth percentile, which refused
#: videos trimmed to three still frames at each end, placed to within 24 ms.)
STILL_MOTION_RATIO = 0.3
REST_PAIRS = 2
#: A video whose placement scores below this (:class:`gtsam_rotid.bags.TimeOffset`) gets no readings. A video is
#: searched only where it overlaps its own pose's span, so the repeating recording's one-spin-later minimum, which
#: sets a bag's MIN_OFFSET_CORRELATION (0.8), does not arise; its frames at rest are what make the placement
#: (above). Six videos trimmed to three still frames at each end score 0.70-0.84 at placements within 24 ms; with
#: their nine still frames, 0.86-0.91. A placement still wrong makes the readings disagree with the tracks, and the
#: calibration refuses them.
MIN_VIDEO_CORRELATION = 0.65
#: A video whose spin starts and stops within it gives its frame rate: the frame pairs from its first to its last
#: moving pair, and half a pair at each end (the spin starts and stops within the pairs on either side, whose motion
#: is too small to count), against the time its spinning joint takes in the series from leaving its rest angle to
#: reaching its final one. The angle lags the image's first moving frame by the time it takes to turn FPS_CHECK_DEG
#: (above the readings' noise): the times it passes FPS_CHECK_DEG and four times that are extrapolated back to rest
#: as under a constant acceleration (the first alone read the rate 2-6 % high on 4 s spins with half-second and
#: one-second ramps, and without the half pairs 1.3 % low; now 0.2-0.4 % high on 4 and 8 s spins). Where the
#: videos' median differs from the rate given (or stated by the files) by more than FPS_CHECK_RATIO, make_dataset
#: says so: a rate off by half (15 fps given for a 30 fps recording) leaves every video unplaced or its readings
#: refused, with nothing naming the frame rate before. At 8 % a rate 10 % off either way is named (16.5 fps given
#: for 15 fps videos was not, at 15 % with the rate read 4 % high); 5 % off is left to the placement and the
#: calibration (5 % high places every video, whose readings then disagree with the tracks; 5 % low two of six). (A
#: ramp whose acceleration itself ramps up leaves part of the lag: about 0.4 of it where the angle grows as the cube
#: of the time.)
FPS_CHECK_DEG = 0.25
FPS_CHECK_RATIO = 1.08
#: With readings, a video's frames (a bag's images) this close (s) to the ends of its pose's span in the joint
#: series (where the other joints start or stop moving) are left out: the readings' smoothing there mixes in the
#: arm's move, and the stamps have their own jitter.
SPIN_MARGIN_S = 0.1


def _spin_rate(loaded: _LoadedJoints, k: int, motion: list, spin: int) -> tuple[float, int, float] | None:
    """Video ``k``'s frame rate as its spin gives it (see FPS_CHECK_DEG): (frames per second, the frames its spin
    takes, the seconds it takes in the joint series); None where the spin does not both start and stop within the
    video (REST_PAIRS frames at rest at each end) or does not turn by four times FPS_CHECK_DEG in the series."""
    moving = np.asarray(motion[1:], dtype=float)
    if len(moving) <= 2 * REST_PAIRS:
        return None
    still = STILL_MOTION_RATIO * np.percentile(moving, 90)
    if moving[:REST_PAIRS].max() > still or moving[-REST_PAIRS:].max() > still:
        return None
    on = np.flatnonzero(moving > still)
    rows = loaded.selections[k]
    q, t = loaded.unwrapped[rows, spin], loaded.joint_file.stamps[rows]
    eps = np.radians(FPS_CHECK_DEG)
    start, end = _onset(t, np.abs(q - q[0]), eps), _onset(-t[::-1], np.abs(q - q[-1])[::-1], eps)
    if not len(on) or start is None or end is None or -end <= start:
        return None
    # the spin starts within the pair before its first moving one and stops within the pair after its last moving
    # one (their motion is too small to count as moving): half a frame each, on average
    pairs, seconds = int(on[-1] - on[0] + 2), float(-end - start)
    return pairs / seconds, pairs, seconds


def _onset(t: np.ndarray, turned: np.ndarray, eps: float) -> float | None:
    """When a joint that ``turned`` (rad from its rest angle, at the times ``t``) left its rest: the times it first
    passes ``eps`` and ``4 eps`` (linear between samples), extrapolated back as a constant acceleration would
    (the angle grows as the square of the time from rest: ``2 t(eps) - t(4 eps)``), no later than ``t(eps)``;
    None where it never turns ``4 eps``."""
    times = []
    for level in (eps, 4.0 * eps):
        above = np.flatnonzero(turned > level)
        if not len(above):
            return None
        i = int(above[0])
        if i == 0:
            times.append(float(t[0]))
            continue
        a, b = turned[i - 1], turned[i]
        times.append(float(t[i - 1] + (level - a) / (b - a) * (t[i] - t[i - 1])))
    return min(times[0], 2.0 * times[0] - times[1])


def _checked_rate(spins: list, rate_of: list, stated: bool) -> None:
    """Says on stderr where the videos' spins give a frame rate (:func:`_spin_rate`, per video or None) that differs
    from the one each was given (``rate_of``) by more than FPS_CHECK_RATIO over their median; ``stated``: the rate
    came from the video files, not fps / --fps."""
    ratios = [m[0] / r for m, r in zip(spins, rate_of, strict=True) if m is not None and r]
    if not ratios:
        return
    ratio = float(np.median(ratios))
    if 1.0 / FPS_CHECK_RATIO <= ratio <= FPS_CHECK_RATIO:
        return
    given = float(np.median([r for m, r in zip(spins, rate_of, strict=True) if m is not None and r]))
    example = next(m for m in spins if m is not None)
    source = "their files state" if stated else "given (fps / --fps)"
    print(f"warning: the videos' frame rate looks like about {ratio * given:.3g} fps, not the {given:.3g} fps "
          f"{source}: their spins take {example[1]} frames where the joint series takes {example[2]:.2f} s (the "
          f"first of {len(ratios)} video(s) that start and stop their spin; median ratio {ratio:.2f}); the "
          "readings are placed on the joint series at the rate given (where they could be placed at all): give the "
          "right one with fps / --fps", file=sys.stderr)


def _video_readings(loaded: _LoadedJoints, k: int, motion: list, first: int, fps: float, arm: Arm,
                    spin_joint: str | None, label: str, clock: str) -> tuple[SpinReadings | None, dict]:
    """Video ``k``'s spin readings from a joint time series: where its first frame falls on the series' clock is
    found by lining up how much each frame differs from the one before (``motion``) with how far the joints moved
    between the two frames' times (:func:`gtsam_rotid.bags.estimate_time_offset`), searched over every start at
    which the video overlaps its spin's span of the series; each frame index ``i`` is then at ``start + (i - first)
    / fps``, on the camera clock named ``clock`` (the video's own: the calibration estimates what is left of its
    offset, one per video). (None, what was found) with a warning where that cannot be measured (a steady spin
    throughout the video: no start or stop to line up) or two starts fit alike; what was found holds
    ``held_s``, the first and last stamps of the pose's span in the series."""
    stamps, rows = loaded.joint_file.stamps, loaded.selections[k]
    t0, t1 = float(stamps[rows[0]]), float(stamps[rows[-1]])
    n = len(motion)
    length = (n - 1) / fps
    # the video's clock shifted so that every start at which it overlaps [t0, t1] lies within +-half of zero
    centre, half = 0.5 * (t0 + t1 - length), 0.5 * (t1 - t0 + length) + 1.0 / fps
    found = estimate_time_offset(centre + np.arange(n) / fps, np.asarray(motion), stamps, loaded.unwrapped, half)
    start = centre - found.offset  # the series' time of frame ``first``
    info = {"start_s": None if not np.isfinite(start) else float(start), "correlation": float(found.score),
            "rival_start_s": None if found.rival is None else float(centre - found.rival), "held_s": [t0, t1]}
    moving = np.asarray(motion[1:], dtype=float)
    still = STILL_MOTION_RATIO * np.percentile(moving, 90) if len(moving) else 0.0
    resting = len(moving) > 2 * REST_PAIRS and (moving[:REST_PAIRS].max() <= still
                                                 or moving[-REST_PAIRS:].max() <= still)
    if not np.isfinite(start) or not resting or found.rival is not None or found.score < MIN_VIDEO_CORRELATION:
        # (a video whose images never come to rest has no start or stop to line up: a steady spin's motion is
        # flat, and a placement found in it was a third of a second off at a correlation of 0.85)
        why = ("the spin never starts or stops within the video: it neither begins nor ends with three frames at "
               "rest, or the images never change" if not
               np.isfinite(start) or not resting else f"another start ({info['rival_start_s']:.3f} s) fits as well"
               if found.rival is not None else f"image and joint motion correlate only {found.score:.2f}")
        print(f"warning: {label}: where its frames fall on the joint time series' clock could not be measured "
              f"({why}); its spin readings are not attached (no synced mode for it)", file=sys.stderr)
        return None, info
    frame_times = start + (np.arange(first + n) - first) / fps
    window = (stamps >= frame_times[first] - READINGS_MARGIN_S) & (stamps <= frame_times[-1] + READINGS_MARGIN_S)
    window[1:] &= np.diff(stamps) > 0  # (of rows with one stamp, the first)
    spin = arm.spin_index(spin_joint)
    try:
        return SpinReadings(frame_times, stamps[window], loaded.unwrapped[window, spin], clock=clock), info
    except ValidationError as error:
        print(f"warning: {label}: its spin readings are not attached (no synced mode for it): {error}",
              file=sys.stderr)
        return None, info


def _held_frames(tracks: list[Track], frame_times: np.ndarray, held_s, label: str) -> tuple[list[Track], list]:
    """The tracks cut to the frames that lie within the pose's span of the joint series ``held_s`` (first, last
    stamp) by SPIN_MARGIN_S, and [first, last] frame index kept; tracks with no frame left are dropped. Unchanged
    (with a warning) where fewer than 2 tracks would be left."""
    inside = (frame_times >= held_s[0] + SPIN_MARGIN_S) & (frame_times <= held_s[1] - SPIN_MARGIN_S)
    kept = []
    for track in tracks:
        mask = inside[track.frames]
        if np.any(mask):
            kept.append(track if np.all(mask) else Track(track.pixels[mask], track.frames[mask]))
    if len(kept) < 2:
        print(f"warning: {label}: fewer than 2 tracks within its pose's span of the joint series; its frames are "
              "kept whole", file=sys.stderr)
        return tracks, [int(np.min([t.frames[0] for t in tracks])), int(np.max([t.frames[-1] for t in tracks]))]
    return kept, [int(min(t.frames[0] for t in kept)), int(max(t.frames[-1] for t in kept))]


def _check_distinct_frames(videos: list[Path], ranges: list[tuple[int, int | None]], labels: list[str]) -> None:
    """Two measurements whose frames overlap in the same video (the same file given twice, for the same spin) would
    each take the other's spin under their own arm pose: an :class:`InputError` naming both."""
    seen: dict[str, list[int]] = {}
    for k, video in enumerate(videos):
        seen.setdefault(os.path.realpath(video), []).append(k)
    for same in seen.values():
        for a, i in enumerate(same):
            for j in same[a + 1:]:
                (s_i, e_i), (s_j, e_j) = ranges[i], ranges[j]
                if s_i < (math.inf if e_j is None else e_j) and s_j < (math.inf if e_i is None else e_i):
                    raise InputError(f"{_label(i, labels)} and {_label(j, labels)} are the same video "
                                     f"({videos[i]}) with overlapping frames (frames {_range_text(*ranges[i])} and "
                                     f"frames {_range_text(*ranges[j])}): each measurement needs its own spin, at "
                                     "its own arm pose (a video that holds several spins: give each its frame range)")


def make_dataset(videos: Sequence[str | os.PathLike], joints, camera: Camera | str | os.PathLike, arm: Arm, *,
                 tracker: Callable | None = None, tracker_params: Any = None,
                 frame_ranges: Sequence[tuple[int | None, int | None] | None] | None = None,
                 progress: bool = True, joint_options: Mapping | None = None,
                 metadata: Mapping | None = None, spin_joints: Sequence[str | None] | None = None,
                 fps: float | None = None, readings: bool = True) -> Dataset:
    """A :class:`Dataset` from one video (file or image folder) per measurement.

    Args:
        videos: one video file or image folder per measurement (the measurement is named after it).
        joints: (n, dof) joint angles in radians, ``arm.joint_names`` order (or a list of dicts name -> angle),
            or the path of a joint-angle file read by :func:`load_joints` with ``joint_options`` (e.g.
            ``{"degrees": True}``).
        camera: a :class:`Camera`, or the path of a camera file read by :func:`load_camera`.
        arm: the robot arm.
        tracker: ``tracker(frames, params=tracker_params) -> list of Track`` (or of (N, 2) pixel arrays); frames
            is an iterator of uint8 images. Default :func:`gtsam_rotid.tracking.track`.
        frame_ranges: one (start, stop) or None per video (frames ``start <= i < stop``); track frame indices
            are the video's own frame numbers.
        progress: show tqdm progress bars (over videos, and over each video's frames).
        joint_options: keyword arguments of :func:`load_joints` when ``joints`` is a path (``degrees``,
            ``spans``, ``still_tolerance_deg``, ``min_spin_deg``, ``ignore_joints``).
        metadata: extra dataset metadata (merged with a ``"recording"`` entry naming the sources).
        spin_joints: the joint that spun in each video (one name or None per video; None: the wrist), each
            measurement's ``spin_joint``; a joint time series then checks that joint moved and the others did not.
        fps: the videos' frame rate (frames per second); default: what each video file's container states (an image
            folder states none).
        readings: with a joint time series, attach each video's spin readings (``Measurement.spin_readings``: the
            spinning joint's series about its spin, and each frame's time on the series' clock, found by lining up
            image motion with joint motion), so that ``calibrate`` syncs the spin with them. A video whose frames
            cannot be placed on the series' clock (no frame rate, a spin that never starts or stops within it,
            two places that fit alike) gets none, with a warning.

    Every video is checked before any tracking (missing, unreadable, empty, a range beyond a folder's end, the same
    video's frames given to two measurements);
    a range beyond a video's end, frames of another size than the camera's, or fewer than 2 tracks in a video
    raise a :class:`RecordingError` naming the video.
    """
    if isinstance(videos, (str, os.PathLike)):
        videos = [videos]
    videos = [Path(v) for v in videos]
    if not videos:
        raise InputError("no videos given: a dataset needs one video or image folder per measurement")
    if not isinstance(arm, Arm):
        raise InputError(f"arm must be a gtsam_rotid.arm.Arm, got {type(arm).__name__}")
    n = len(videos)
    if frame_ranges is None:
        frame_ranges = [None] * n
    frame_ranges = list(frame_ranges)
    if len(frame_ranges) != n:
        raise InputError(f"{len(frame_ranges)} frame range(s) for {n} video(s); give one per video (None for all "
                         f"frames)")
    camera_file = None
    if not isinstance(camera, Camera):
        camera_file = os.fspath(camera)
        camera = load_camera(camera)
    labels = [v.name for v in videos]
    if spin_joints is not None:
        spin_joints = [None if arm.spins_wrist(j) else j for j in spin_joints]
        if len(spin_joints) != n:
            raise InputError(f"{len(spin_joints)} spin joint(s) for {n} video(s); give one per video")
        for k, joint in enumerate(spin_joints):
            try:
                arm.spin_index(joint)
            except ArmError as exc:
                raise InputError(f"{_label(k, labels)}: {exc}") from None
    joints_file = os.fspath(joints) if isinstance(joints, (str, os.PathLike)) else None
    if fps is not None and (isinstance(fps, bool) or not isinstance(fps, (int, float, np.number))
                            or not math.isfinite(fps) or fps <= 0):
        raise InputError(f"fps must be a positive number of frames per second, got {fps!r}")
    angles, loaded = _joint_rows(joints, arm, labels, joint_options, spin_joints)
    series = readings and loaded is not None and loaded.unwrapped is not None
    sources = [open_source(v) for v in videos]  # fail fast, before the slow tracking
    checked_ranges = [checked_range(r, v) for r, v in zip(frame_ranges, videos, strict=True)]
    _check_distinct_frames(videos, checked_ranges, labels)
    from .trackparams import tracker_metadata
    tracker, described, corner_tracks = default_tracker(tracker, tracker_params)
    measurements, placed, video_ends, spin_rates, rates = [], [], [], [], []
    # each video's camera clock: its path from the videos' common folder (the same video twice, for two of its
    # spins: numbered)
    paths = [os.path.abspath(v) for v in videos]
    common = os.path.commonpath(paths) if len(paths) > 1 else os.path.dirname(paths[0])
    clocks = [os.path.relpath(path, common) if path != common else os.path.basename(path) for path in paths]
    clocks = [c if clocks.count(c) == 1 else f"{k}:{c}" for k, c in enumerate(clocks)]
    with tqdm(total=n, desc="videos", unit="video", disable=not progress, file=sys.stderr) as bar:
        for k, (source, frame_range) in enumerate(zip(sources, checked_ranges, strict=True)):
            spin_joint = None if spin_joints is None else spin_joints[k]
            rate = fps if fps is not None else video_fps(source)
            motion = [] if series and rate is not None else None
            ends: list = []
            tracks, first = _tracked(source, frame_range, camera, tracker, tracker_params, k, _label(k, labels),
                                     progress, motion, ends)
            video_ends.append(ends)
            spin_readings = None
            if motion is not None:
                clock = clocks[k]
                spin_rates.append(_spin_rate(loaded, k, motion, arm.spin_index(spin_joint)))
                rates.append(rate)
                spin_readings, found = _video_readings(loaded, k, motion, first, rate, arm, spin_joint,
                                                       _label(k, labels), clock)
                if spin_rates[-1] is not None:
                    found["fps_from_spin"] = spin_rates[-1][0]
                if spin_readings is not None:
                    tracks, found["frames_kept"] = _held_frames(tracks, spin_readings.frame_times, found["held_s"],
                                                                _label(k, labels))
                placed.append({**found, "fps": rate})
            elif series:
                print(f"warning: {_label(k, labels)}: an image folder states no frame rate; its spin readings are "
                      "not attached (give the frame rate: fps / --fps)", file=sys.stderr)
                placed.append(None)
            measurements.append(Measurement(angles[k], tracks, name=source.path.name, spin_joint=spin_joint,
                                            spin_readings=spin_readings))
            bar.update(1)
    if spin_rates:  # (a frame rate far from the spins' says so)
        _checked_rate(spin_rates, rates, fps is None)
    recording = {
        "videos": [os.path.abspath(v) for v in videos],
        "frame_ranges": [None if given is None else list(checked)
                         for given, checked in zip(frame_ranges, checked_ranges, strict=True)],
        "joints_file": joints_file,
        "joint_options": dict(joint_options or {}),
        "camera_file": camera_file,
        "tracker": tracker_description(described, tracker_params),
    }
    if series:  # each video's first frame on the joint series' clock (s), and the score it was found at
        recording["video_starts"] = placed
    extra = {"recording": recording}
    if corner_tracks is not None:
        extra["tracker"] = tracker_metadata(tracker_params, sum(corner_tracks))
    if n > 1:  # did the camera stay still between and during the videos? (the first and last frame of each range)
        from .stillness import motion_metadata

        motion = motion_metadata([e[0] for e in video_ends], [v.name for v in videos], last=[e[1] for e in video_ends])
        if motion is not None:
            extra["camera_motion"] = motion
    return Dataset(arm, camera, measurements, metadata={**extra, **dict(metadata or {})})


# ---------------------------------------------------------------------------------------------- command line


def videos_in(folder: Path) -> list[Path]:
    if not folder.is_dir():
        raise RecordingError(f"--videos-dir {folder} is not a directory")
    entries = sorted((p for p in folder.iterdir() if not p.name.startswith(".") and
                      (p.is_dir() or p.suffix.lower() in VIDEO_SUFFIXES)), key=natural_key)
    if not entries:
        hint = " (it holds images: pass it with --video as one image folder)" if image_files(folder) else ""
        raise RecordingError(f"--videos-dir {folder} holds no videos ({', '.join(VIDEO_SUFFIXES)}) and no image "
                             f"folders{hint}")
    return entries


def load_tracker_params(path: str | os.PathLike | None = None, **overrides):
    """:class:`~gtsam_rotid.tracking.TrackerParams` from a YAML or JSON file of its fields (a mapping), with
    ``overrides`` (None values ignored) on top. An unknown field, a file that is not a mapping or a bad value
    raises an :class:`InputError` naming the field and the file."""
    from .tracking import TrackerParams

    names = {f.name for f in dataclasses.fields(TrackerParams)}
    values: dict[str, Any] = {}
    where = "the command line"
    if path is not None:
        path = Path(path)
        where = str(path)
        try:
            text = path.read_text()
        except OSError as exc:
            raise InputError(f"cannot read the tracker settings file {path}: {exc.strerror or exc}") from None
        try:
            document = json.loads(text) if path.suffix.lower() == ".json" else parse_yaml(text)
        except ValueError as exc:
            raise InputError(f"the tracker settings file {path} is not valid "
                             f"{'JSON' if path.suffix.lower() == '.json' else 'YAML'}: {exc}") from None
        if document is None:
            document = {}
        if not isinstance(document, Mapping):
            raise InputError(f"the tracker settings file {path} must hold a mapping of TrackerParams fields "
                             f"(name: value), got {type(document).__name__}")
        for key, value in document.items():
            if key not in names:
                raise InputError(f"{path}: unknown tracker setting {key!r} (not a TrackerParams field; known: "
                                 f"{', '.join(sorted(names))})")
            values[key] = value
    for key, value in overrides.items():
        if value is None:
            continue
        if key not in names:
            raise InputError(f"unknown tracker setting {key!r}")
        values[key] = value
    # whole numbers given for float fields are fine; ints stay ints
    for f in dataclasses.fields(TrackerParams):
        if f.name in values and f.type == "float" and isinstance(values[f.name], int) \
                and not isinstance(values[f.name], bool):
            values[f.name] = float(values[f.name])
    try:
        return TrackerParams(**values)
    except InputError as exc:
        raise InputError(f"{where}: {exc}") from None

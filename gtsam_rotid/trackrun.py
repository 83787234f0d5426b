"""Running a feature tracker over one measurement's frames: the tracks (frame indices the recording's own), the
default tracker's corner-track counts for the dataset's metadata, and the tracker's description. Shared by the
recordings of videos (:mod:`gtsam_rotid.recordings`) and of ROS bags (:mod:`gtsam_rotid.bagdataset`).
"""

from __future__ import annotations

import dataclasses
import json
import sys
from collections.abc import Callable, Iterable, Iterator
from pathlib import Path
from typing import Any

import numpy as np
from tqdm import tqdm

from .camera import Camera
from .dataset import Track
from .errors import InputError, RecordingError


def checked_size(frames: Iterable[np.ndarray], camera: Camera, path: Path) -> Iterator[np.ndarray]:
    for i, frame in enumerate(frames):
        if i == 0 and (frame.shape[1], frame.shape[0]) != (camera.width, camera.height):
            raise RecordingError(f"{path}: the frames are {frame.shape[1]}x{frame.shape[0]} pixels but the camera "
                                 f"is {camera.width}x{camera.height}; the camera (file or CameraInfo) must describe "
                                 "these frames")
        yield frame


def counted(frames: Iterable[np.ndarray], bar: tqdm) -> Iterator[np.ndarray]:
    """``frames``, advancing ``bar`` by one per frame (a plain generator: no ``len``, as a tracker may ask)."""
    for frame in frames:
        yield frame
        bar.update(1)


def tracker_description(tracker: Callable, params: Any) -> dict:
    description: dict[str, Any] = {"function": f"{getattr(tracker, '__module__', '?')}."
                                               f"{getattr(tracker, '__qualname__', type(tracker).__name__)}"}
    if params is not None:
        value = dataclasses.asdict(params) if dataclasses.is_dataclass(params) and not isinstance(params, type) \
            else params
        try:
            json.dumps(value, allow_nan=False)
        except (TypeError, ValueError):
            value = repr(params)
        description["params"] = value
    return description


def tracked_frames(frames: Iterable[np.ndarray], expected: int | None, first: int, where: Path, camera: Camera,
                    tracker: Callable, tracker_params, k: int, label: str, progress: bool) -> list[Track]:
    """The tracks of one measurement's frames (their indices start at ``first``), at least 2, or a RecordingError
    naming ``where`` (a video, or a bag and its topic)."""
    frames = checked_size(frames, camera, where)
    with tqdm(total=expected, desc=where.name, unit="frame", leave=False, disable=not progress,
              file=sys.stderr) as frame_bar:
        found = tracker(counted(frames, frame_bar), params=tracker_params)
    if found is None or isinstance(found, (Track, np.ndarray)):
        raise InputError(f"the tracker must return a list of Track for {where}, got {type(found).__name__}")
    tracks = []
    for j, item in enumerate(found):
        track = Track.from_any(item, measurement=k, track=j)
        if track.frames is not None and first:
            track = Track(track.pixels, track.frames + first)
        tracks.append(track)
    if len(tracks) < 2:
        raise RecordingError(f"{label}: the tracker found {len(tracks)} track(s) in {where}; a measurement "
                             f"needs at least 2 (are features on the spinning end effector visible and in focus?)")
    return tracks


def default_tracker(tracker: Callable | None, tracker_params) -> tuple[Callable, Callable, list[int] | None]:
    """(the tracker to run, the one to describe in the metadata, and the default tracker's corner-track counts, one
    per measurement as it runs, or None for another tracker): the default tracker's dataset states its features'
    image axes' floor (:func:`gtsam_rotid.trackparams.tracker_metadata`)."""
    from .tracking import Tracker, track
    from .trackparams import TrackerParams
    tracker = track if tracker is None else tracker
    if tracker is not track or not (tracker_params is None or isinstance(tracker_params, TrackerParams)):
        return tracker, tracker, None
    corner_tracks: list[int] = []

    def run(frames, params=None):
        result = Tracker(params).run(frames)
        corner_tracks.append(result.n_corner_tracks)
        return result.tracks
    return run, track, corner_tracks

"""The quad view (:func:`gtsam_rotid.plots.plot_overlay`) on the user's own recording: for each measurement, the frame
of its video (or bag) in which the most of its tracks are seen, read back from where ``track`` recorded it
(``dataset.metadata["recording"]``).
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from .dataset import Dataset, Track
from .errors import RotIdError


def busiest_frame(dataset: Dataset, k: int) -> int | None:
    """The frame number in which the most of measurement ``k``'s tracks have a point (None: no frame numbers)."""
    frames = [Track.from_any(t).frames for t in dataset[k].tracks]
    frames = [f for f in frames if f is not None and len(f)]
    if not frames:
        return None
    numbers, counts = np.unique(np.concatenate(frames), return_counts=True)
    return int(numbers[int(np.argmax(counts))])


def recorded_frames(dataset: Dataset) -> tuple[dict[int, tuple[int, np.ndarray]], list[str]]:
    """``k -> (frame number, image)`` for the measurements whose recording can be read again, and a note for each
    that cannot (no recording in the metadata, a file moved, no frame numbers)."""
    recording = dataset.metadata.get("recording") or {}
    frames, notes = {}, []
    videos, bag = recording.get("videos"), recording.get("bag")
    if not videos and not bag:
        return {}, ["the dataset records no video or bag (it was not made by `gtsam-rotid track`)"]
    for k in range(len(dataset)):
        number = busiest_frame(dataset, k)
        if number is None:
            notes.append(f"measurement {k}: its tracks carry no frame numbers")
            continue
        try:
            image = _bag_frame(bag, recording, number) if bag else _video_frame(videos[k], number)
        except (RotIdError, OSError, IndexError, KeyError, StopIteration) as exc:
            notes.append(f"measurement {k}: its frame {number} cannot be read again ({exc})")
            continue
        if image.shape[:2] != (dataset.camera.height, dataset.camera.width):
            notes.append(f"measurement {k}: the recording's frame is {image.shape[1]}x{image.shape[0]}, not the "
                         f"camera's {dataset.camera.width}x{dataset.camera.height} (another recording?)")
            continue
        frames[k] = (number, image)
    return frames, notes


def _video_frame(video: str, number: int) -> np.ndarray:
    from .frames import read_frames

    path = Path(video)
    if not path.exists():
        raise OSError(f"{os.fspath(path)} is not there any more")
    return next(iter(read_frames(path, (number, number + 1))))


def _bag_frame(bag_path: str, recording: dict, number: int) -> np.ndarray:
    from .bags import Bag

    with Bag(bag_path) as bag:
        return next(bag.images(recording["topics"]["image"], number, number))[2]

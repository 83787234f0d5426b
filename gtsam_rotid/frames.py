"""The one frame reader (the I/O layer): the frames of a video file or an image folder, checked at once.

:func:`read_frames` (and :func:`open_source` / :func:`frames_of` for a reader that needs the frame count first)
reads a folder's images in natural order (:func:`gtsam_rotid.files.image_files`) and a video through OpenCV, with
an optional frame range; 16-bit images are scaled to 8 bits and an alpha channel is dropped. Both the tracker
(``track(path)``) and the recordings (``gtsam-rotid track``) read through here.
"""

from __future__ import annotations

import os
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from .errors import InputError, RecordingError
from .files import IMAGE_SUFFIXES, image_files

__all__ = ["Source", "checked_range", "frames_of", "open_source", "read_frames", "small_grey", "with_ends",
           "with_motion", "video_fps"]


def checked_range(frame_range, path: Path) -> tuple[int, int | None]:
    if frame_range is None:
        return 0, None
    if isinstance(frame_range, slice):
        if frame_range.step not in (None, 1):
            raise InputError(f"{path}: a frame range cannot have a step, got {frame_range}")
        frame_range = (frame_range.start, frame_range.stop)
    try:
        start, stop = frame_range
    except (TypeError, ValueError):
        raise InputError(f"{path}: a frame range must be (start, stop), got {frame_range!r}") from None
    start = 0 if start is None else start
    for name, value in (("start", start), ("stop", stop)):
        if value is not None and (isinstance(value, bool) or not float(value).is_integer() or value < 0):
            raise InputError(f"{path}: frame range {name} must be a non-negative integer, got {value!r}")
    start, stop = int(start), None if stop is None else int(stop)
    if stop is not None and stop <= start:
        raise InputError(f"{path}: the frame range {start}:{stop} is empty (stop must exceed start)")
    return start, stop


def _range_text(start: int, stop: int | None) -> str:
    return f"{start}:{'' if stop is None else stop}"


def _as_uint8(image: np.ndarray, where: str) -> np.ndarray:
    if image.dtype == np.uint16:
        image = (image >> 8).astype(np.uint8)
    elif image.dtype != np.uint8:
        raise RecordingError(f"{where}: images must be 8- or 16-bit, got {image.dtype}")
    if image.ndim == 3 and image.shape[2] == 4:
        image = cv2.cvtColor(image, cv2.COLOR_BGRA2BGR)
    return image


def _folder_frames(files: list[Path], start: int, stop: int | None) -> Iterator[np.ndarray]:
    shape = None
    for index, file in enumerate(files[start:stop], start):
        image = cv2.imread(os.fspath(file), cv2.IMREAD_UNCHANGED)
        if image is None:
            raise RecordingError(f"frame {index}: cannot read the image {file} (not an image OpenCV can decode)")
        image = _as_uint8(image, os.fspath(file))
        if shape is None:
            shape = image.shape
        elif image.shape != shape:
            raise RecordingError(f"the image {file} is {image.shape[1]}x{image.shape[0]} with shape {image.shape}, "
                                 f"but the folder's first image has shape {shape}")
        yield image


#: A video whose container reports more frames than decode by this factor (or more) is truncated or damaged.
TRUNCATED_FRACTION = 0.9


def _video_frames(path: Path, start: int, stop: int | None, reported: int | None = None) -> Iterator[np.ndarray]:
    capture = cv2.VideoCapture(os.fspath(path))
    try:
        if not capture.isOpened():
            raise RecordingError(f"cannot open the video {path}")
        index = 0
        while stop is None or index < stop:
            if not capture.grab():
                break
            if index >= start:
                ok, frame = capture.retrieve()
                if not ok or frame is None:
                    raise RecordingError(f"the video {path}: frame {index} cannot be decoded")
                yield _as_uint8(frame, f"the video {path}, frame {index}")
            index += 1
    finally:
        capture.release()
    if index == 0:
        raise RecordingError(f"the video {path} has no frames (OpenCV decodes none)")
    if (stop is not None and index < stop) or index <= start:
        raise RecordingError(f"the video {path} has {index} frames (0 to {index - 1}); the frame range "
                             f"{_range_text(start, stop)} goes beyond its end")
    if stop is None and reported is not None and index < TRUNCATED_FRACTION * reported:
        raise RecordingError(f"the video {path} reports {reported} frames but only {index} decode: it is truncated "
                             f"or damaged. Record or export it again, or give the frame range 0:{index} (--frames) to "
                             "use the frames that decode")


@dataclass(frozen=True)
class Source:
    """A checked video or image folder; ``count`` is exact for a folder, OpenCV's estimate (or None) for a video."""

    path: Path
    is_folder: bool
    count: int | None
    files: tuple[Path, ...] = ()


def open_source(path: str | os.PathLike) -> Source:
    """Check that ``path`` is a readable video with a frame, or a folder holding images."""
    path = Path(path)
    if not path.exists():
        raise RecordingError(f"no video or image folder at {path}: it does not exist")
    if path.is_dir():
        files = image_files(path)
        if not files:
            raise RecordingError(f"the image folder {path} holds no image files ({', '.join(IMAGE_SUFFIXES)})")
        return Source(path, True, len(files), tuple(files))
    capture = cv2.VideoCapture(os.fspath(path))
    try:
        if not capture.isOpened():
            raise RecordingError(f"cannot open the video {path}: OpenCV cannot decode it (not a video, a damaged "
                                 f"file, or a codec this OpenCV build lacks)")
        if not capture.grab():
            raise RecordingError(f"the video {path} has no frames (OpenCV decodes none)")
        reported = int(capture.get(cv2.CAP_PROP_FRAME_COUNT))
    finally:
        capture.release()
    return Source(path, False, reported if reported > 0 else None)


def frames_of(source: Source, frame_range) -> tuple[Iterator[np.ndarray], int | None, int]:
    """(frame iterator, expected number of frames or None, first frame index) of a checked source."""
    start, stop = checked_range(frame_range, source.path)
    if source.is_folder:
        n = source.count
        if start >= n or (stop is not None and stop > n):
            raise RecordingError(f"the image folder {source.path} has {n} images (frames 0 to {n - 1}); the frame "
                                 f"range {_range_text(start, stop)} goes beyond its end")
        return _folder_frames(list(source.files), start, stop), (n if stop is None else stop) - start, start
    expected = None
    if source.count is not None:
        end = source.count if stop is None else min(stop, source.count)
        expected = max(end - start, 0) or None
    elif stop is not None:
        expected = stop - start
    return _video_frames(source.path, start, stop, source.count), expected, start


def read_frames(path: str | os.PathLike, frame_range: tuple[int | None, int | None] | None = None
                ) -> Iterator[np.ndarray]:
    """The uint8 frames of a video file or of an image folder (images sorted by name, numbers in natural order).

    ``frame_range`` = (start, stop) keeps frames ``start <= i < stop`` (either may be None). The path is checked
    at once (missing, not a video OpenCV can open, no frames, an empty folder, a range beyond a folder's end:
    :class:`RecordingError`); a range beyond a video's end is found when reading reaches it. Video frames are
    BGR as OpenCV decodes them; images are read unchanged (grey stays grey; 16-bit is scaled to 8-bit; an
    alpha channel is dropped).
    """
    frames, _, _ = frames_of(open_source(path), frame_range)
    return frames


def small_grey(image: np.ndarray, size: int = 64) -> np.ndarray:
    """``image`` in grey levels (float32) at ``size`` pixels across: what frame-to-frame motion is measured on."""
    grey = image if image.ndim == 2 else cv2.cvtColor(image, cv2.COLOR_BGR2GRAY)
    return cv2.resize(grey, (size, max(1, round(size * grey.shape[0] / grey.shape[1]))),
                      interpolation=cv2.INTER_AREA).astype(np.float32)


def with_motion(frames: Iterator[np.ndarray], motion: list, size: int = 64) -> Iterator[np.ndarray]:
    """The frames unchanged, appending to ``motion`` how much each differs from the one before (the mean absolute
    difference in grey levels at ``size`` pixels across; 0 for the first) as it passes."""
    previous = None
    for image in frames:
        small = small_grey(image, size)
        motion.append(0.0 if previous is None or previous.shape != small.shape
                      else float(np.mean(np.abs(small - previous))))
        previous = small
        yield image


def with_ends(frames: Iterator[np.ndarray], ends: list) -> Iterator[np.ndarray]:
    """The frames unchanged, keeping the first and the last that pass in ``ends`` (``[first, last]``; one frame:
    the same twice): what the camera's stillness is read on (:mod:`gtsam_rotid.stillness`), without a second
    decoding."""
    for image in frames:
        if not ends:
            ends.extend([image, image])
        ends[1] = image
        yield image


def video_fps(source: Source) -> float | None:
    """The frame rate a video file's container states (None for an image folder, or where it states none)."""
    if source.is_folder:
        return None
    capture = cv2.VideoCapture(os.fspath(source.path))
    try:
        fps = float(capture.get(cv2.CAP_PROP_FPS)) if capture.isOpened() else 0.0
    finally:
        capture.release()
    return fps if np.isfinite(fps) and 0.0 < fps < 10_000.0 else None

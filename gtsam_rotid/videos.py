"""Writing frames as a video file (mp4, or lossless mkv / avi) or a folder of PNG images: built next to the
target and renamed into place, never replacing anything but its own kind of output (:func:`write_video`).
"""

from __future__ import annotations

import os
import re
from collections.abc import Iterable
from pathlib import Path

import cv2
import numpy as np

from .errors import InputError, OutputExistsError, VideoWriteError
from .files import staged, staged_directory

#: Video suffixes :func:`write_video` writes, with their OpenCV fourcc: MPEG-4 part 2 is lossy (about 3 grey
#: levels mean error on a noise-free frame, and it smooths the image noise away); FFV1 is lossless.
VIDEO_FOURCC = {".mp4": "mp4v", ".mkv": "FFV1", ".avi": "FFV1"}
_FRAME_FILE = re.compile(r"^frame_\d{6,}\.png$")


# --------------------------------------------------------------------------------------------- output
def _is_frame_folder(path: Path) -> bool:
    return path.is_dir() and all(_FRAME_FILE.match(entry.name) for entry in path.iterdir())


def _checked_frame(frame, index: int, shape: tuple | None) -> np.ndarray:
    frame = np.asarray(frame)
    if frame.dtype != np.uint8 or not (frame.ndim == 2 or (frame.ndim == 3 and frame.shape[2] == 3)):
        raise InputError(f"frame {index}: expected a uint8 (H, W) grey or (H, W, 3) BGR image, got "
                         f"{frame.dtype} {frame.shape}")
    if shape is not None and frame.shape != shape:
        raise InputError(f"frame {index}: shape {frame.shape} differs from the first frame's {shape}")
    return frame


def write_video(frames: Iterable[np.ndarray], path: str | os.PathLike, fps: float, *,
                overwrite: bool = False) -> Path:
    """Write 8-bit frames to ``path``: a video when it ends in ``.mp4`` ('mp4v', lossy) or ``.mkv`` / ``.avi``
    ('FFV1', lossless), otherwise (no suffix) a folder of lossless ``frame_000000.png`` ... files.
    Returns the path.

    Frames may be grey (H, W) or BGR (H, W, 3), all of one shape; grey frames are stored as BGR in a video.
    The output is built next to the target and renamed into place. An existing target raises
    :class:`OutputExistsError` unless ``overwrite`` is true, and even then only a file with the same video
    suffix, an empty folder or a folder holding nothing but ``frame_*.png`` files is replaced, after the new
    one is complete.
    """
    target = Path(os.path.abspath(os.fspath(path)))
    suffix = target.suffix.lower()
    if suffix and suffix not in VIDEO_FOURCC:
        raise InputError(f"{target}: unknown video suffix {target.suffix!r}; use one of {sorted(VIDEO_FOURCC)} or "
                         f"a path without a suffix for a folder of PNG images")
    if isinstance(fps, bool) or not isinstance(fps, (int, float, np.number)) or not np.isfinite(fps) or fps <= 0:
        raise InputError(f"fps must be a positive finite number, got {fps!r}")
    _check_output_target(target, overwrite, folder=not suffix)
    target.parent.mkdir(parents=True, exist_ok=True)
    if suffix:
        with staged(target, overwrite) as staging:
            _write_video_file(frames, staging, float(fps), VIDEO_FOURCC[suffix])
        return target
    with staged_directory(target, lambda: _check_output_target(target, overwrite, folder=True),
                          what="frame folder") as staging:
        _write_png_folder(frames, staging)
    return target


def _check_output_target(target: Path, overwrite: bool, *, folder: bool) -> None:
    if not os.path.lexists(target):
        return
    if target.is_symlink():
        raise OutputExistsError(f"{target} is a symbolic link; refusing to replace it")
    if folder:
        if not target.is_dir():
            raise OutputExistsError(f"{target} exists and is not a folder; refusing to replace it, even with "
                                    f"overwrite=True")
        if not any(target.iterdir()):
            return
        if not _is_frame_folder(target):
            raise OutputExistsError(f"{target} holds files other than frame_*.png; refusing to replace it, even "
                                    f"with overwrite=True, so as not to delete unrelated files")
        if not overwrite:
            raise OutputExistsError(f"{target} already holds frames; pass overwrite=True to replace them")
        return
    if target.is_dir():
        raise OutputExistsError(f"{target} is a directory; refusing to replace it with a video file")
    if not overwrite:
        raise OutputExistsError(f"{target} exists; pass overwrite=True to replace it")


def _write_video_file(frames: Iterable[np.ndarray], path: Path, fps: float, fourcc: str) -> None:
    writer = None
    shape = None
    count = 0
    try:
        for frame in frames:
            frame = _checked_frame(frame, count, shape)
            count += 1
            if writer is None:
                shape = frame.shape
                writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*fourcc), fps,
                                         (frame.shape[1], frame.shape[0]), True)
                if not writer.isOpened():
                    raise VideoWriteError(f"OpenCV cannot open a {fourcc!r} video writer for {path} "
                                          f"({frame.shape[1]}x{frame.shape[0]} at {fps:g} fps)")
            writer.write(cv2.cvtColor(frame, cv2.COLOR_GRAY2BGR) if frame.ndim == 2 else frame)
    finally:
        if writer is not None:
            writer.release()
    if writer is None:
        raise InputError("no frames to write")
    if not path.is_file() or path.stat().st_size == 0:
        raise VideoWriteError(f"OpenCV wrote nothing to {path} ({count} frames given)")


def _write_png_folder(frames: Iterable[np.ndarray], folder: Path) -> None:
    shape = None
    for index, frame in enumerate(frames):
        frame = _checked_frame(frame, index, shape)
        shape = frame.shape
        name = folder / f"frame_{index:06d}.png"
        if not cv2.imwrite(str(name), frame):
            raise VideoWriteError(f"OpenCV could not write {name}")
    if shape is None:
        raise InputError("no frames to write")

"""Package exceptions.

Every error that gtsam_rotid raises on purpose derives from :class:`RotIdError`, so callers can catch
the whole family with one ``except``. Errors about bad input also derive from ``ValueError`` (or
``FileExistsError`` / ``FileNotFoundError``) so that generic handlers keep working.
"""

from __future__ import annotations


class RotIdError(Exception):
    """Base class of every gtsam_rotid error."""


class InputError(RotIdError, ValueError):
    """An argument is malformed: wrong shape, length, type, NaN, out of range or unknown name."""


class CameraError(InputError):
    """Malformed camera intrinsics, image size or distortion coefficients."""


class ArmError(InputError):
    """A robot model that cannot be loaded or used, or joint angles that do not fit it."""


class ValidationError(InputError):
    """A measurement, track or dataset file that fails validation.

    ``measurement`` and ``track`` name the item at fault (indices), when known.
    """

    def __init__(self, message: str, *, measurement: int | None = None, track: int | None = None):
        where = []
        if measurement is not None:
            where.append(f"measurement {measurement}")
        if track is not None:
            where.append(f"track {track}")
        prefix = (", ".join(where) + ": ") if where else ""
        super().__init__(prefix + message)
        self.measurement = measurement
        self.track = track


class SimulationError(RotIdError, RuntimeError):
    """The simulator could not build the requested scene (e.g. no arm pose satisfies the constraints)."""


class DatasetNotFoundError(RotIdError, FileNotFoundError):
    """No dataset at the given path (the directory or one of its files is missing)."""


class OutputError(RotIdError, OSError):
    """An output file cannot be written (a directory in the way, a missing folder, a full disk); the message
    names the path."""


class RecordingError(InputError):
    """A video, image folder, frame range or joint-angle file that cannot be used (the message names it)."""


class OutputExistsError(OutputError, FileExistsError):
    """Refusing to overwrite an existing file or folder (pass ``overwrite=True``, ``--overwrite``): the one
    "exists" error of every writer."""


class DatasetExistsError(OutputExistsError):
    """Refusing to overwrite an existing dataset (pass ``overwrite=True`` to replace it)."""


class VideoWriteError(RotIdError, OSError):
    """OpenCV could not open or write the video or an image file."""

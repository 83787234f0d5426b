"""One feature's track (:class:`Track`: pixels, optional frame indices) and one wrist spin's measurement
(:class:`Measurement`: the arm's joint angles and its tracks), validated on construction with errors that name the
measurement and track. :mod:`gtsam_rotid.dataset` gathers them into a dataset and its files.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from numbers import Real

import numpy as np

from .errors import ValidationError

#: The most frames one measurement's tracks may span (9 hours of video at 30 fps): more are time stamps, and the
#: rigid spin would allocate an angle per frame between them.
MAX_FRAME_SPAN = 1_000_000
_INT64_MAX = np.iinfo(np.int64).max


# ---------------------------------------------------------------------------------------------- helpers
def _located(err: ValidationError, *, measurement: int | None = None, track: int | None = None) -> ValidationError:
    """The same validation error, re-addressed to ``measurement`` / ``track`` (kept where not given)."""
    prefix = str(ValidationError("", measurement=err.measurement, track=err.track))
    message = str(err)[len(prefix):]
    return ValidationError(
        message,
        measurement=err.measurement if measurement is None else measurement,
        track=err.track if track is None else track,
    )


def _plural(count: int, noun: str) -> str:
    return f"{count} {noun}" if count == 1 else f"{count} {noun}s"


# ---------------------------------------------------------------------------------------------- Track
class Track:
    """One feature tracked through (part of) a wrist spin.

    Args:
        pixels: (N, 2) raw (distorted) pixel coordinates (u, v), N >= 1, all finite.
        frames: optional (N,) integer frame indices of the pixels, strictly increasing and >= 0. When
            given, the estimators tie the feature's phase to the shared per-frame wrist angle.

    Attributes ``pixels`` (float64) and ``frames`` (int64 or ``None``) are read-only copies.
    """

    __slots__ = ("_pixels", "_frames")

    def __init__(self, pixels, frames=None):
        self._pixels = self._checked_pixels(pixels)
        self._frames = None if frames is None else self._checked_frames(frames, len(self._pixels))

    @staticmethod
    def _checked_pixels(pixels) -> np.ndarray:
        try:
            array = np.asarray(pixels)
        except (TypeError, ValueError):
            raise ValidationError("pixels must be a numeric (N, 2) array (got a ragged or non-numeric "
                                  f"{type(pixels).__name__})") from None
        if array.dtype.kind not in "iuf":
            raise ValidationError(f"pixels must be real numbers, got dtype {array.dtype}")
        if array.ndim != 2 or array.shape[1] != 2:
            raise ValidationError(f"pixels must have shape (N, 2), got shape {array.shape}")
        if array.shape[0] == 0:
            raise ValidationError("the track is empty (0 pixels); a track needs at least one pixel")
        pixels_uv = np.array(array, dtype=np.float64)
        bad = np.flatnonzero(~np.all(np.isfinite(pixels_uv), axis=1))
        if bad.size:
            raise ValidationError(f"{bad.size} of {len(pixels_uv)} pixels are NaN or infinite (first: pixel "
                                  f"{bad[0]} = {pixels_uv[bad[0]].tolist()})")
        pixels_uv.setflags(write=False)
        return pixels_uv

    @staticmethod
    def _checked_frames(frames, n: int) -> np.ndarray:
        try:
            array = np.asarray(frames)
        except (TypeError, ValueError):
            raise ValidationError(f"frames must be a 1-D integer array, got {type(frames).__name__}") from None
        if array.dtype.kind not in "iuf":
            raise ValidationError(f"frames must be integers, got dtype {array.dtype}")
        if array.shape != (n,):
            raise ValidationError(f"frames must have shape ({n},), one per pixel, got shape {array.shape}")
        if array.dtype.kind == "f":
            bad = np.flatnonzero(~np.isfinite(array) | (array != np.round(array)) | (np.abs(array) >= 2.0**62))
            if bad.size:
                raise ValidationError(f"frames must be integers; frame {bad[0]} is {array[bad[0]].item()!r}")
        elif array.dtype.kind == "u" and array.size and array.max() > _INT64_MAX:
            raise ValidationError(f"frame index {array.max()} is too large")
        frames_int = np.array(array, dtype=np.int64)
        negative = np.flatnonzero(frames_int < 0)
        if negative.size:
            raise ValidationError(f"frames must be >= 0; frame {negative[0]} is {frames_int[negative[0]]}")
        not_increasing = np.flatnonzero(np.diff(frames_int) <= 0)
        if not_increasing.size:
            i = not_increasing[0]
            raise ValidationError(f"frames must be strictly increasing; frame {i + 1} is {frames_int[i + 1]} "
                                  f"after frame {i} = {frames_int[i]}")
        if frames_int.size and frames_int[-1] - frames_int[0] > MAX_FRAME_SPAN:
            raise ValidationError(f"frames must be frame numbers of one spin's video: they span "
                                  f"{frames_int[-1] - frames_int[0]} frames (at most {MAX_FRAME_SPAN}; time stamps "
                                  "in nanoseconds or microseconds are not frame numbers)")
        frames_int.setflags(write=False)
        return frames_int

    @classmethod
    def from_any(cls, obj, *, measurement: int | None = None, track: int | None = None) -> Track:
        """``obj`` if it is a Track, else ``Track(obj)``; errors name ``measurement`` and ``track``."""
        if isinstance(obj, Track):
            return obj
        try:
            return cls(obj)
        except ValidationError as err:
            raise _located(err, measurement=measurement, track=track) from None

    @property
    def pixels(self) -> np.ndarray:
        """(N, 2) raw pixels (u, v), float64, read-only."""
        return self._pixels

    @property
    def frames(self) -> np.ndarray | None:
        """(N,) frame indices, int64, read-only, or ``None`` when unknown."""
        return self._frames

    @property
    def has_frames(self) -> bool:
        return self._frames is not None

    def __len__(self) -> int:
        return len(self._pixels)

    def __eq__(self, other) -> bool:
        if not isinstance(other, Track):
            return NotImplemented
        if (self._frames is None) != (other._frames is None):
            return False
        return np.array_equal(self._pixels, other._pixels) and (
            self._frames is None or np.array_equal(self._frames, other._frames)
        )

    __hash__ = None

    def __repr__(self) -> str:
        frames = "no frames" if self._frames is None else f"frames {self._frames[0]}..{self._frames[-1]}"
        return f"Track({_plural(len(self), 'pixel')}, {frames})"


# ---------------------------------------------------------------------------------------------- Measurement
class SpinReadings:
    """The spinning joint's own readings during one spin (synced mode): the encoder's time-stamped angles and the
    video's frame times.

    Args:
        frame_times: (n,) each frame index's time (s) on the camera's clock (index i at ``frame_times[i]``), never
            decreasing (two images may share a stamp); it must cover every frame index of the measurement's tracks.
        times: (K,) the readings' times (s) on the encoder's clock, K >= 2, strictly increasing. The two clocks may
            differ by a constant offset (the calibration can estimate it).
        angles: (K,) the spinning joint's readings (rad), in the arm model's sense of the joint (a joint reported
            in [-pi, pi) is unwrapped).
        clock: the name of the clock ``frame_times`` are on: spins whose readings name the same clock share one
            offset from the encoder's clock in the calibration, spins of different clocks have one each (videos
            placed on a joint time series one by one: each video its own). Default None: one clock for every spin
            that names none (the images of one bag).

    Attributes are read-only float64 copies (``clock``: a string or None).
    """

    __slots__ = ("frame_times", "times", "angles", "clock")

    def __init__(self, frame_times, times, angles, clock: str | None = None):
        self.frame_times = self._checked("frame_times", frame_times, 1)
        self.times = self._checked("times", times, 2)
        self.angles = self._checked("angles", angles, 2)
        if len(self.angles) != len(self.times):
            raise ValidationError(f"spin readings need one angle per time, got {len(self.angles)} angles for "
                                  f"{len(self.times)} times")
        if clock is not None and (not isinstance(clock, str) or not clock):
            raise ValidationError(f"spin readings' clock must be a non-empty string or None, got {clock!r}")
        self.clock = clock

    @staticmethod
    def _checked(name: str, values, least: int) -> np.ndarray:
        try:
            array = np.array(values, dtype=np.float64)
        except (TypeError, ValueError):
            raise ValidationError(f"spin readings' {name} must be numbers, got {type(values).__name__}") from None
        if array.ndim != 1 or len(array) < least:
            raise ValidationError(f"spin readings' {name} must be a 1-D array of at least {least} values, got shape "
                                  f"{array.shape}")
        bad = np.flatnonzero(~np.isfinite(array))
        if len(bad):
            raise ValidationError(f"spin readings' {name}[{bad[0]}] is not finite ({array[bad[0]]})")
        if name != "angles":  # (two images may share a stamp; two readings may not)
            back = np.flatnonzero(np.diff(array) < 0 if name == "frame_times" else np.diff(array) <= 0)
            if len(back):
                i = int(back[0])
                order = "never decrease" if name == "frame_times" else "be strictly increasing"
                raise ValidationError(f"spin readings' {name} must {order}: {name}[{i + 1}] = {array[i + 1]} s "
                                      f"follows {array[i]} s")
        array.setflags(write=False)
        return array

    def __eq__(self, other) -> bool:
        if not isinstance(other, SpinReadings):
            return NotImplemented
        return self.clock == other.clock and all(np.array_equal(getattr(self, a), getattr(other, a))
                                                 for a in ("frame_times", "times", "angles"))

    __hash__ = None

    def __repr__(self) -> str:
        return (f"SpinReadings({len(self.times)} readings over {self.times[-1] - self.times[0]:.3g} s, "
                f"{len(self.frame_times)} frame times" + ("" if self.clock is None else f", clock {self.clock!r}")
                + ")")


def _checked_joint_angles(joint_angles) -> np.ndarray | dict[str, float]:
    """A copy of the joint angles: a float64 vector, or a dict name -> float (arm-independent checks only)."""
    if isinstance(joint_angles, Mapping):
        if not joint_angles:
            raise ValidationError("joint angles are empty")
        checked = {}
        for name, value in joint_angles.items():
            if not isinstance(name, str):
                raise ValidationError(f"joint names must be strings, got {name!r}")
            if isinstance(value, bool) or not isinstance(value, Real):
                raise ValidationError(f"joint angle of {name!r} must be a number, got {value!r}")
            if not np.isfinite(float(value)):
                raise ValidationError(f"joint angle of {name!r} is NaN or infinite")
            checked[name] = float(value)
        return checked
    if isinstance(joint_angles, (str, bytes)) or not isinstance(joint_angles, (Sequence, np.ndarray)):
        raise ValidationError("joint angles must be a sequence of numbers or a dict name -> angle, got "
                              f"{type(joint_angles).__name__}")
    try:
        array = np.asarray(joint_angles)
    except (TypeError, ValueError):
        raise ValidationError("joint angles must be a flat sequence of numbers") from None
    if array.dtype.kind not in "iuf" or array.ndim != 1:
        raise ValidationError(f"joint angles must be a flat sequence of numbers, got shape {array.shape} "
                              f"and dtype {array.dtype}")
    if array.size == 0:
        raise ValidationError("joint angles are empty")
    angles = np.array(array, dtype=np.float64)
    bad = np.flatnonzero(~np.isfinite(angles))
    if bad.size:
        raise ValidationError(f"joint angle {bad[0]} is NaN or infinite")
    angles.setflags(write=False)
    return angles


class Measurement:
    """One wrist spin at a fixed arm pose.

    Args:
        joint_angles: radians, one per revolute joint of the arm in model order (stored as a read-only
            float64 vector), or a dict joint name -> angle (stored as a dict of floats). Checked against the
            arm by :class:`Dataset`.
        tracks: non-empty list of :class:`Track` or (N, 2) pixel arrays (converted with
            :meth:`Track.from_any`; errors name the track index).
        name: optional label.
        spin_joint: the name of the joint that spun (its features trace circles about its axis); None (default):
            the arm's wrist joint (:attr:`gtsam_rotid.arm.Arm.wrist_joint`, the last revolute joint unless the arm
            names another). Checked against the arm by :class:`Dataset`.
        spin_readings: optional :class:`SpinReadings` of the spinning joint (synced mode: the rigid spin's
            per-frame angles then follow them, with the clocks' offset estimated); needs tracks with frame indices,
            each within ``spin_readings.frame_times``.
    """

    __slots__ = ("joint_angles", "tracks", "name", "spin_joint", "spin_readings")

    def __init__(self, joint_angles, tracks, *, name: str | None = None, spin_joint: str | None = None,
                 spin_readings: SpinReadings | None = None):
        if name is not None and not isinstance(name, str):
            raise ValidationError(f"measurement name must be a string or None, got {type(name).__name__}")
        if spin_joint is not None and (not isinstance(spin_joint, str) or not spin_joint):
            raise ValidationError(f"spin_joint must be a joint name or None, got {spin_joint!r}")
        self.name = name
        self.spin_joint = spin_joint
        self.joint_angles = _checked_joint_angles(joint_angles)
        if isinstance(tracks, (Track, str, bytes, Mapping)) or (isinstance(tracks, np.ndarray) and tracks.ndim < 3):
            raise ValidationError(f"tracks must be a list of Track or (N, 2) arrays, got a single "
                                  f"{type(tracks).__name__}; wrap it in a list")
        try:
            items = list(tracks)
        except TypeError:
            raise ValidationError(f"tracks must be a list of Track or (N, 2) arrays, got "
                                  f"{type(tracks).__name__}") from None
        if not items:
            raise ValidationError("a measurement needs at least one track, got none")
        self.tracks: tuple[Track, ...] = tuple(Track.from_any(t, track=j) for j, t in enumerate(items))
        if spin_readings is not None and not isinstance(spin_readings, SpinReadings):
            raise ValidationError(f"spin_readings must be SpinReadings or None, got {type(spin_readings).__name__}")
        if spin_readings is not None:
            for j, track in enumerate(self.tracks):
                if track.frames is None:
                    raise ValidationError(f"track {j}: spin readings need every track's frame indices; it has none")
                if len(track.frames) and track.frames[-1] >= len(spin_readings.frame_times):
                    raise ValidationError(f"track {j}: frame {int(track.frames[-1])} has no time in the spin "
                                          f"readings' frame_times ({len(spin_readings.frame_times)} frames)")
        self.spin_readings = spin_readings

    def replace(self, **changes) -> Measurement:
        """This measurement with ``changes`` (any of ``joint_angles``, ``tracks``, ``name``, ``spin_joint``,
        ``spin_readings``), everything else kept."""
        fields = {"joint_angles": self.joint_angles, "tracks": self.tracks, "name": self.name,
                  "spin_joint": self.spin_joint, "spin_readings": self.spin_readings}
        unknown = set(changes) - set(fields)
        if unknown:
            raise ValidationError(f"a Measurement has no field(s) {sorted(unknown)}; it has {sorted(fields)}")
        fields.update(changes)
        return Measurement(fields.pop("joint_angles"), fields.pop("tracks"), **fields)

    @property
    def n_tracks(self) -> int:
        return len(self.tracks)

    @property
    def n_observations(self) -> int:
        """Total number of pixels over all tracks."""
        return sum(len(t) for t in self.tracks)

    def frame_span(self) -> tuple[int, int] | None:
        """(first, last) frame index over the tracks that carry frames, or ``None`` if none does."""
        spans = [(int(t.frames[0]), int(t.frames[-1])) for t in self.tracks if t.frames is not None]
        if not spans:
            return None
        return min(s[0] for s in spans), max(s[1] for s in spans)

    def __eq__(self, other) -> bool:
        if not isinstance(other, Measurement):
            return NotImplemented
        a, b = self.joint_angles, other.joint_angles
        if isinstance(a, dict) or isinstance(b, dict):
            same_angles = isinstance(a, dict) and isinstance(b, dict) and a == b
        else:
            same_angles = np.array_equal(a, b)
        return (self.name == other.name and self.spin_joint == other.spin_joint and same_angles
                and self.tracks == other.tracks and self.spin_readings == other.spin_readings)

    __hash__ = None

    def __repr__(self) -> str:
        label = "" if self.name is None else f"{self.name!r}, "
        label += "" if self.spin_joint is None else f"spinning {self.spin_joint!r}, "
        return f"Measurement({label}{_plural(self.n_tracks, 'track')}, {_plural(self.n_observations, 'point')})"

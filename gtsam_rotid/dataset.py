"""Recorded data: tracks of features on the spinning wrist, grouped by arm pose, and their files.

A :class:`Dataset` holds the arm, the camera and a list of :class:`Measurement` (one wrist spin at a fixed
arm pose: its joint angles and the :class:`Track` of every feature seen during the spin). Tracks are raw
(distorted) pixels, OpenCV convention (origin at the centre of the top-left pixel, docs/design.md §2), with
optional frame indices that let the estimators model the rigid spin (docs/design.md §4).

On disk a dataset is a directory (format version :data:`FORMAT_VERSION`, or 1 where no measurement names a
``spin_joint`` or carries ``spin_readings``: version 1 files are written and read as before)::

    dataset.json   arm, camera, measurements (joint angles, track array names), metadata
    tracks.npz     one (N, 2) float array of pixels and, when known, one (N,) int array of frames per track; a
                   measurement's spin readings as three float arrays (frame times, reading times, angles)
    arm.urdf       the arm's URDF text, only for arms built from a URDF

``dataset.json`` is checked against ``gtsam_rotid/schemas/dataset-v2.schema.json`` (JSON Schema 2020-12; a
version-1 file against ``dataset-v1.schema.json``) when loading. :meth:`Dataset.save` writes atomically: a crash
leaves either the old dataset or the new one, never a half-written directory, and an unrelated file or directory is
never replaced.
"""

from __future__ import annotations

import hashlib
import json
import os
import re
import reprlib
import zipfile
from collections.abc import Iterator, Mapping, Sequence
from functools import lru_cache
from importlib import resources
from pathlib import Path
from typing import Any

import jsonschema
import numpy as np

from .arm import Arm
from .camera import Camera
from .errors import (
    ArmError,
    CameraError,
    DatasetExistsError,
    DatasetNotFoundError,
    OutputError,
    RotIdError,
    ValidationError,
)
from .files import staged_directory
from .measurements import MAX_FRAME_SPAN, Measurement, SpinReadings, Track, _located, _plural

#: ``"format"`` marker of ``dataset.json``.
FORMAT = "gtsam_rotid.dataset"
#: Newest on-disk format version this module reads, and the one it writes where a measurement names a spin joint.
FORMAT_VERSION = 2
DATASET_FILE = "dataset.json"
TRACKS_FILE = "tracks.npz"
URDF_FILE = "arm.urdf"
SCHEMA_FILE = "dataset-v2.schema.json"
#: The schema of each format version this module reads.
SCHEMA_FILES = {1: "dataset-v1.schema.json", 2: SCHEMA_FILE}
_TRACK_KEY = re.compile(r"^m(\d+)_t(\d+)_")
_SHORT_REPR = reprlib.Repr()  # keyword arguments need Python 3.12
_SHORT_REPR.maxlevel, _SHORT_REPR.maxdict, _SHORT_REPR.maxlist = 2, 4, 4
_SHORT_REPR.maxstring = _SHORT_REPR.maxother = 40


def _json_default(value: Any) -> Any:
    """``json.dumps`` hook: numpy scalars and arrays become plain Python values."""
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, np.ndarray):
        return value.tolist()
    raise TypeError(f"object of type {type(value).__name__} is not JSON serialisable")


def _normalised_metadata(metadata: Any) -> dict:
    """A deep copy of ``metadata`` in its JSON form (tuples -> lists, numpy -> Python, keys -> str)."""
    if not isinstance(metadata, Mapping):
        raise ValidationError(f"metadata must be a dict, got {type(metadata).__name__}")
    try:
        return json.loads(json.dumps(dict(metadata), allow_nan=False, default=_json_default))
    except (TypeError, ValueError) as exc:
        raise ValidationError(f"metadata must be JSON-serialisable (no NaN or infinity): {exc}") from None


def _reject_json_constant(name: str) -> float:
    raise ValueError(f"{name} is not valid JSON")


@lru_cache(maxsize=len(SCHEMA_FILES))
def _schema_validator(version: int = FORMAT_VERSION) -> jsonschema.protocols.Validator:
    text = (resources.files("gtsam_rotid") / "schemas" / SCHEMA_FILES[version]).read_text(encoding="utf-8")
    schema = json.loads(text)
    validator_class = jsonschema.validators.validator_for(schema)
    validator_class.check_schema(schema)
    return validator_class(schema)


def dataset_schema() -> dict:
    """The JSON Schema of ``dataset.json`` (format version :data:`FORMAT_VERSION`)."""
    return json.loads(json.dumps(_schema_validator().schema))


def _validate_document(document: Any) -> None:
    """Check the format marker and version of a parsed ``dataset.json``, then its schema."""
    if not isinstance(document, dict):
        raise ValidationError(f"{DATASET_FILE} must hold a JSON object, got {type(document).__name__}")
    fmt = document.get("format")
    if fmt != FORMAT:
        raise ValidationError(f"{DATASET_FILE} is not a gtsam_rotid dataset: its \"format\" is {fmt!r}, "
                              f"expected {FORMAT!r}")
    version = document.get("version")
    if isinstance(version, int) and not isinstance(version, bool) and version > FORMAT_VERSION:
        raise ValidationError(f"dataset format version {version} is newer than this gtsam_rotid supports "
                              f"({FORMAT_VERSION}); upgrade gtsam_rotid to read it")
    version = version if version in SCHEMA_FILES else FORMAT_VERSION  # (the schema then names what is wrong)
    error = jsonschema.exceptions.best_match(_schema_validator(version).iter_errors(document))
    if error is None:
        return
    where = list(error.absolute_path)
    measurement = track = None
    if len(where) >= 2 and where[0] == "measurements" and isinstance(where[1], int):
        measurement = where[1]
        if len(where) >= 4 and where[2] == "tracks" and isinstance(where[3], int):
            track = where[3]
    message = error.message.replace(repr(error.instance), _SHORT_REPR.repr(error.instance))
    message = message if len(message) <= 300 else message[:300] + "..."
    raise ValidationError(f"{DATASET_FILE} does not match the format-{version} schema at "
                          f"{error.json_path}: {message}", measurement=measurement, track=track)


def _write_file(path: Path, data: bytes | None = None, *, arrays: dict[str, np.ndarray] | None = None) -> None:
    """Create ``path`` (it must not exist), write bytes or an npz archive, and fsync it."""
    with open(path, "xb") as handle:
        if arrays is not None:
            np.savez_compressed(handle, **arrays)
        else:
            handle.write(data)
        handle.flush()
        os.fsync(handle.fileno())


def _is_dataset_directory(path: Path) -> bool:
    """True if ``path`` is a directory holding a ``dataset.json`` written by gtsam_rotid (even if corrupt)."""
    marker = path / DATASET_FILE
    if not path.is_dir() or not marker.is_file():
        return False
    try:
        raw = marker.read_bytes()
    except OSError:
        return False
    try:
        document = json.loads(raw)
    except ValueError:
        return FORMAT.encode() in raw
    return isinstance(document, dict) and document.get("format") == FORMAT


#: The files a dataset directory may hold (the simulator adds its ground truth); anything else is the user's.
_DATASET_FILES = frozenset({DATASET_FILE, TRACKS_FILE, URDF_FILE, "truth.json",
                            ".DS_Store", "Thumbs.db", "desktop.ini"})  # (and the file browsers' own)


def _check_save_target(target: Path, overwrite: bool) -> bool:
    """Raise unless ``target`` may be written; True when an existing dataset is to be replaced."""
    if not os.path.lexists(target):
        return False
    if target.is_symlink():
        raise DatasetExistsError(f"{target} is a symbolic link; refusing to replace it (save to the directory "
                                 f"it points to, or remove the link)")
    if not target.is_dir():
        raise DatasetExistsError(f"{target} exists and is a file, not a gtsam_rotid dataset directory; refusing "
                                 f"to replace it, even with overwrite=True")
    if not _is_dataset_directory(target):
        raise DatasetExistsError(f"{target} exists and is not a gtsam_rotid dataset (no {DATASET_FILE} with "
                                 f"format {FORMAT!r}); refusing to replace it, even with overwrite=True, so as "
                                 f"not to delete unrelated files")
    if not overwrite:
        raise DatasetExistsError(f"a dataset already exists at {target}; pass overwrite=True to replace it")
    foreign = sorted(entry.name for entry in target.iterdir() if entry.name not in _DATASET_FILES)
    if foreign:
        raise DatasetExistsError(f"{target} holds files that are not part of the dataset ({', '.join(foreign)}); "
                                 "replacing the dataset would delete them, so it is refused even with "
                                 "overwrite=True: move them out, or save to another directory")
    return True


# ---------------------------------------------------------------------------------------------- Dataset
class Dataset:
    """Arm, camera and measurements of one calibration session, validated together.

    Args:
        arm: the robot arm (:class:`gtsam_rotid.arm.Arm`).
        camera: the intrinsically calibrated camera (:class:`gtsam_rotid.camera.Camera`).
        measurements: at least one :class:`Measurement`.
        metadata: JSON-serialisable dict (stored as a deep copy in JSON form; default empty).

    Raises :class:`ValidationError` naming the measurement (and track) when joint angles do not fit the arm
    or a pixel lies outside the image (``-0.5 <= u <= width - 0.5``, same for v).
    """

    def __init__(self, arm: Arm, camera: Camera, measurements: Sequence[Measurement],
                 metadata: Mapping | None = None):
        if not isinstance(arm, Arm):
            raise ValidationError(f"arm must be a gtsam_rotid.arm.Arm, got {type(arm).__name__}")
        if not isinstance(camera, Camera):
            raise ValidationError(f"camera must be a gtsam_rotid.camera.Camera, got {type(camera).__name__}")
        if isinstance(measurements, Measurement):
            raise ValidationError("measurements must be a list of Measurement, got a single Measurement; "
                                  "wrap it in a list")
        measurements = tuple(measurements)
        if not measurements:
            raise ValidationError("a dataset needs at least one measurement, got none")
        self.arm = arm
        self.camera = camera
        self.measurements: tuple[Measurement, ...] = measurements
        self.metadata: dict = _normalised_metadata({} if metadata is None else metadata)
        #: where the dataset was read from (:meth:`load`): ``{"path", "sha256"}`` (:func:`dataset_digest`); None
        #: for one made in memory. A calibration result records it.
        self.source: dict | None = None
        self._joint_angle_vectors = tuple(self._validated(k, m) for k, m in enumerate(measurements))

    def _validated(self, k: int, measurement: Measurement) -> np.ndarray:
        """Check measurement ``k`` against the arm and camera; its joint angle vector."""
        if not isinstance(measurement, Measurement):
            raise ValidationError(f"expected a Measurement, got {type(measurement).__name__}", measurement=k)
        try:
            angles = self.arm.joint_angle_vector(measurement.joint_angles)
        except ArmError as err:
            raise ValidationError(f"joint angles do not fit the arm {self.arm.name!r}: {err}",
                                  measurement=k) from None
        if measurement.spin_joint is not None and measurement.spin_joint not in self.arm.joint_names:
            raise ValidationError(f"spin_joint {measurement.spin_joint!r} is not a revolute joint of the arm "
                                  f"{self.arm.name!r}; revolute joints: {self.arm.joint_names}", measurement=k)
        problem = self.arm.limit_problem(angles)
        if problem is not None:
            raise ValidationError(problem, measurement=k)
        angles.setflags(write=False)
        width, height = self.camera.width, self.camera.height
        for j, track in enumerate(measurement.tracks):
            outside = np.flatnonzero(~self.camera.in_image(track.pixels))
            if outside.size:
                u, v = track.pixels[outside[0]]
                raise ValidationError(
                    f"pixel {outside[0]} (u={u:g}, v={v:g}) lies outside the {width}x{height} image "
                    f"(-0.5 <= u <= {width - 0.5:g}, -0.5 <= v <= {height - 0.5:g}); {outside.size} of "
                    f"{len(track)} pixels of the track are outside",
                    measurement=k, track=j)
        firsts = [int(t.frames[0]) for t in measurement.tracks if t.frames is not None and len(t.frames)]
        lasts = [int(t.frames[-1]) for t in measurement.tracks if t.frames is not None and len(t.frames)]
        if firsts and max(lasts) - min(firsts) > MAX_FRAME_SPAN:
            raise ValidationError(f"the tracks' frame indices span {max(lasts) - min(firsts)} frames (from "
                                  f"{min(firsts)} to {max(lasts)}; at most {MAX_FRAME_SPAN}): frame indices must "
                                  "be frame numbers of one spin's video, not time stamps", measurement=k)
        return angles

    # ------------------------------------------------------------------ access
    def joint_angles(self, k: int) -> np.ndarray:
        """Validated joint angle vector (radians, ``arm.joint_names`` order) of measurement ``k``."""
        n = len(self.measurements)
        if not -n <= k < n:
            raise IndexError(f"measurement index {k} out of range for {n} measurements")
        return self._joint_angle_vectors[k].copy()

    def __len__(self) -> int:
        return len(self.measurements)

    def __iter__(self) -> Iterator[Measurement]:
        return iter(self.measurements)

    def __getitem__(self, k: int) -> Measurement:
        return self.measurements[k]

    @property
    def n_tracks(self) -> int:
        return sum(m.n_tracks for m in self.measurements)

    @property
    def n_observations(self) -> int:
        """Total number of pixels over all measurements and tracks."""
        return sum(m.n_observations for m in self.measurements)

    def summary(self) -> str:
        """Multi-line human-readable description."""
        lines = [
            f"Dataset: {_plural(len(self), 'measurement')}, {_plural(self.n_tracks, 'track')}, "
            f"{_plural(self.n_observations, 'point')}",
            f"  arm:    {self.arm!r}",
            f"  camera: {self.camera!r}",
        ]
        if self.metadata:
            lines.append(f"  metadata: {', '.join(sorted(self.metadata))}")
        for k, m in enumerate(self.measurements):
            label = "" if m.name is None else f" {m.name!r}"
            label += "" if m.spin_joint is None else f" (spin of {m.spin_joint})"
            span = m.frame_span()
            without = sum(t.frames is None for t in m.tracks)
            if span is None:
                frames = "no frame indices"
            else:
                frames = f"frames {span[0]}..{span[1]}"
                if without:
                    frames += f" ({_plural(without, 'track')} without frame indices)"
            lines.append(f"  measurement {k}{label}: {_plural(m.n_tracks, 'track')}, "
                         f"{_plural(m.n_observations, 'point')}, {frames}")
        return "\n".join(lines)

    def __repr__(self) -> str:
        return (f"Dataset({self.arm!r}, {self.camera!r}, {len(self)} measurements, "
                f"{self.n_observations} points)")

    def __eq__(self, other) -> bool:
        if not isinstance(other, Dataset):
            return NotImplemented
        try:
            same_metadata = _normalised_metadata(self.metadata) == _normalised_metadata(other.metadata)
        except ValidationError:
            same_metadata = self.metadata == other.metadata
        return (
            self.arm.to_dict() == other.arm.to_dict()
            and self.camera == other.camera
            and self.measurements == other.measurements
            and same_metadata
        )

    __hash__ = None

    # ------------------------------------------------------------------ files
    def _serialised(self) -> tuple[dict, dict[str, np.ndarray], str | None]:
        """(dataset.json document, tracks.npz arrays, URDF text or None), checked against the schema."""
        arm = self.arm.to_dict()
        urdf_text = arm.pop("urdf_xml", None)
        if urdf_text is not None:
            arm["urdf_file"] = URDF_FILE
        elif "robot" not in arm:
            raise ValidationError("the arm cannot be saved: it was built from neither a URDF nor an "
                                  "example-robot-data name (use Arm.from_urdf / Arm.from_robot)")
        arrays: dict[str, np.ndarray] = {}
        entries = []
        for k, m in enumerate(self.measurements):
            tracks = []
            for j, track in enumerate(m.tracks):
                pixels_key = f"m{k}_t{j}_pixels"
                arrays[pixels_key] = track.pixels
                frames_key = None
                if track.frames is not None:
                    frames_key = f"m{k}_t{j}_frames"
                    arrays[frames_key] = track.frames
                tracks.append({"pixels": pixels_key, "frames": frames_key, "n": len(track)})
            angles = dict(m.joint_angles) if isinstance(m.joint_angles, dict) else m.joint_angles.tolist()
            entry = {"name": m.name, "joint_angles": angles, "tracks": tracks}
            if m.spin_joint is not None:
                entry["spin_joint"] = m.spin_joint
            if m.spin_readings is not None:
                entry["spin_readings"] = {}
                for name in ("frame_times", "times", "angles"):
                    entry["spin_readings"][name] = key = f"m{k}_spin_{name}"
                    arrays[key] = getattr(m.spin_readings, name)
                if m.spin_readings.clock is not None:
                    entry["spin_readings"]["clock"] = m.spin_readings.clock
            entries.append(entry)
        document = {
            "format": FORMAT,
            # version 1 where it holds everything (no spin of another joint): earlier gtsam_rotid reads it
            "version": FORMAT_VERSION if any(m.spin_joint is not None or m.spin_readings is not None
                                             for m in self.measurements) else 1,
            "arm": arm,
            "camera": self.camera.to_dict(),
            "measurements": entries,
            "metadata": _normalised_metadata(self.metadata),
        }
        _validate_document(document)
        return document, arrays, urdf_text

    def save(self, path: str | os.PathLike, overwrite: bool = False) -> Path:
        """Write the dataset to the directory ``path`` (see the module docstring); returns its path.

        The files are built in a hidden sibling directory, then renamed into place. If ``path`` exists,
        :class:`DatasetExistsError` is raised and nothing is touched, unless ``overwrite`` is true and
        ``path`` is a gtsam_rotid dataset directory: the old one is then renamed aside, the new one renamed
        in, and only then is the old one deleted. A file, a symbolic link or a directory that is not a
        dataset is never replaced.
        """
        target = Path(os.path.abspath(os.fspath(path)))
        document, arrays, urdf_text = self._serialised()
        text = json.dumps(document, indent=2, allow_nan=False) + "\n"
        replace = _check_save_target(target, overwrite)
        try:
            return self._save_staged(target, replace, overwrite, text, arrays, urdf_text)
        except RotIdError:
            raise
        except OSError as exc:   # a full disk, no permission: the old dataset (if any) is still in place
            raise OutputError(f"cannot write the dataset {target}: {exc.strerror or exc}") from None

    @staticmethod
    def _save_staged(target: Path, replace: bool, overwrite: bool, text: str, arrays, urdf_text) -> Path:
        def check() -> None:  # the target may have changed while the files were written
            if replace:
                _check_save_target(target, overwrite)
            elif os.path.lexists(target):
                raise DatasetExistsError(f"{target} appeared while the dataset was being written; not replacing it")

        with staged_directory(target, check, what="dataset") as staging:
            _write_file(staging / TRACKS_FILE, arrays=arrays)
            if urdf_text is not None:
                _write_file(staging / URDF_FILE, urdf_text.encode("utf-8"))
            _write_file(staging / DATASET_FILE, text.encode("utf-8"))
        return target

    @classmethod
    def load(cls, path: str | os.PathLike) -> Dataset:
        """Read a dataset directory written by :meth:`save` (``path`` may also name its dataset.json).

        Raises :class:`DatasetNotFoundError` when the directory or one of its files is missing, and
        :class:`ValidationError` (naming the measurement and track when it can) for anything malformed.
        """
        root = Path(path)
        if root.is_file() and root.name == DATASET_FILE:
            root = root.parent
        if not root.exists():
            left = sorted(root.parent.glob(f".{root.name}.old-*")) if root.parent.is_dir() else []
            hint = (f"; an interrupted save left the previous dataset at {left[-1]}: rename it to {root.name} to "
                    "recover it") if left else ""
            raise DatasetNotFoundError(f"no dataset at {root}: the directory does not exist{hint}")
        if not root.is_dir():
            raise DatasetNotFoundError(f"{root} is a file, not a dataset directory")
        for name in (DATASET_FILE, TRACKS_FILE):
            if not (root / name).is_file():
                raise DatasetNotFoundError(f"{root} is not a complete gtsam_rotid dataset: {name} is missing")
        try:
            document = json.loads((root / DATASET_FILE).read_bytes(), parse_constant=_reject_json_constant)
        except json.JSONDecodeError as exc:
            raise ValidationError(f"{root / DATASET_FILE} is not valid JSON: {exc.msg} (line {exc.lineno}, "
                                  f"column {exc.colno})") from None
        except ValueError as exc:  # NaN / Infinity, or not UTF-8
            raise ValidationError(f"{root / DATASET_FILE} is not valid JSON: {exc}") from None
        _validate_document(document)
        arm = _load_arm(root, document["arm"])
        try:
            camera = Camera.from_dict(document["camera"])
        except CameraError as exc:
            raise ValidationError(f"camera in {DATASET_FILE}: {exc}") from None
        measurements = _load_measurements(root / TRACKS_FILE, document["measurements"])
        dataset = cls(arm, camera, measurements, metadata=document["metadata"])
        dataset.source = {"path": os.fspath(root.resolve()), "sha256": dataset_digest(root)}
        return dataset


def dataset_digest(root: str | os.PathLike) -> str:
    """SHA-256 over a dataset directory's files (dataset.json, tracks.npz and, if there, the arm's URDF), in that
    order: whether a dataset is still the one a result was calibrated from."""
    digest = hashlib.sha256()
    for name in (DATASET_FILE, TRACKS_FILE, URDF_FILE):
        path = Path(root) / name
        if path.is_file():
            digest.update(name.encode("utf-8") + b"\0")
            with open(path, "rb") as handle:
                for block in iter(lambda handle=handle: handle.read(1 << 20), b""):
                    digest.update(block)
    return digest.hexdigest()


def _load_arm(root: Path, description: dict) -> Arm:
    description = dict(description)
    if "urdf_file" in description:
        urdf_path = root / description.pop("urdf_file")
        if not urdf_path.is_file():
            raise DatasetNotFoundError(f"{root} is not a complete gtsam_rotid dataset: the arm's URDF "
                                       f"{urdf_path.name} is missing")
        try:
            description["urdf_xml"] = urdf_path.read_bytes().decode("utf-8")
        except UnicodeDecodeError as exc:
            raise ValidationError(f"the arm's URDF {urdf_path.name} is not UTF-8 text: {exc}") from None
    try:
        arm = Arm.from_dict(description)
    except ArmError as exc:
        raise ValidationError(f"cannot rebuild the arm from {DATASET_FILE}: {exc}") from None
    stored = list(description["joint_names"])
    if list(arm.joint_names) != stored:
        raise ValidationError(f"the arm's revolute joints {arm.joint_names} differ from the joint_names stored "
                              f"in {DATASET_FILE} {stored}: the robot model changed since the dataset was saved")
    return arm


def _npz_array(npz, key: str, kind: str, k: int, j: int) -> np.ndarray:
    if key not in npz.files:
        raise ValidationError(f"the {kind} array {key!r} named in {DATASET_FILE} is missing from {TRACKS_FILE}",
                              measurement=k, track=j)
    try:
        return npz[key]
    except (OSError, ValueError, zipfile.BadZipFile, EOFError) as exc:
        raise ValidationError(f"cannot read the {kind} array {key!r} from {TRACKS_FILE}: {exc}",
                              measurement=k, track=j) from None


def _load_measurements(npz_path: Path, entries: list[dict]) -> list[Measurement]:
    try:
        npz = np.load(npz_path, allow_pickle=False)
    except (OSError, ValueError, zipfile.BadZipFile, EOFError) as exc:
        raise ValidationError(f"{npz_path} is not a readable npz archive: {exc}") from None
    if not isinstance(npz, np.lib.npyio.NpzFile):
        raise ValidationError(f"{npz_path} is a single .npy array, not an npz archive of tracks")
    measurements = []
    used: set[str] = set()
    with npz:
        for k, entry in enumerate(entries):
            tracks = []
            for j, spec in enumerate(entry["tracks"]):
                n = spec["n"]
                pixels = _npz_array(npz, spec["pixels"], "pixels", k, j)
                if pixels.shape != (n, 2):
                    raise ValidationError(f"the pixels array {spec['pixels']!r} has shape {pixels.shape}, "
                                          f"expected ({n}, 2) (n = {n} in {DATASET_FILE})", measurement=k, track=j)
                used.add(spec["pixels"])
                frames = None
                if spec["frames"] is not None:
                    frames = _npz_array(npz, spec["frames"], "frames", k, j)
                    if frames.shape != (n,):
                        raise ValidationError(f"the frames array {spec['frames']!r} has shape {frames.shape}, "
                                              f"expected ({n},) (n = {n} in {DATASET_FILE})",
                                              measurement=k, track=j)
                    used.add(spec["frames"])
                try:
                    tracks.append(Track(pixels, frames))
                except ValidationError as err:
                    raise _located(err, measurement=k, track=j) from None
            readings = None
            if entry.get("spin_readings") is not None:
                spec = entry["spin_readings"]
                arrays = {name: _npz_array(npz, spec[name], "spin readings", k, None)
                          for name in ("frame_times", "times", "angles")}
                used.update(spec[name] for name in ("frame_times", "times", "angles"))
                try:
                    readings = SpinReadings(**arrays, clock=spec.get("clock"))
                except ValidationError as err:
                    raise _located(err, measurement=k) from None
            try:
                measurements.append(Measurement(entry["joint_angles"], tracks, name=entry["name"],
                                                spin_joint=entry.get("spin_joint"), spin_readings=readings))
            except ValidationError as err:
                raise _located(err, measurement=k) from None
        extra = sorted(set(npz.files) - used)
    if extra:
        match = _TRACK_KEY.match(extra[0])
        k, j = (int(match[1]), int(match[2])) if match else (None, None)
        listed = f"; {DATASET_FILE} lists {len(entries[k]['tracks'])} tracks here" \
            if k is not None and k < len(entries) else ""
        raise ValidationError(f"{TRACKS_FILE} holds {len(extra)} array(s) that {DATASET_FILE} does not list, "
                              f"e.g. {extra[0]!r} (track count mismatch{listed})", measurement=k, track=j)
    return measurements

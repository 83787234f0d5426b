"""Camera files: OpenCV calibration YAML or XML (``cv2.FileStorage``), ROS ``camera_info`` YAML (PyYAML, see
:class:`_YamlLoader`) or JSON, read into a :class:`~gtsam_rotid.camera.Camera` with errors that name the file and
the key.
"""

from __future__ import annotations

import json
import os
import re
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import yaml

from .camera import Camera
from .errors import CameraError

_CAMERA_MATRIX_KEYS = ("camera_matrix", "cameraMatrix", "K", "k")
_DISTORTION_KEYS = ("distortion_coefficients", "distCoeffs", "dist_coeffs", "D", "d")
_WIDTH_KEYS = ("image_width", "width", "imageWidth")
_HEIGHT_KEYS = ("image_height", "height", "imageHeight")
_SIZE_KEYS = ("image_size", "imageSize")
_SUPPORTED_DISTORTION_MODELS = ("plumb_bob", "rational_polynomial", "")


# ---------------------------------------------------------------------------------------------- YAML
class _YamlLoader(yaml.SafeLoader):
    """PyYAML's safe loader, with YAML 1.2's floats (``1e-5``, which YAML 1.1 reads as a string; camera files
    written by other tools use them), tags ignored (``!!opencv-matrix`` reads as its mapping) and a key given
    twice refused (a camera file with two ``camera_matrix`` entries is ambiguous)."""


_YamlLoader.add_implicit_resolver(
    "tag:yaml.org,2002:float",
    re.compile(r"^(?:[-+]?[0-9][0-9_]*(?:\.[0-9_]*)?[eE][-+]?[0-9]+|[-+]?\.[0-9_]+(?:[eE][-+]?[0-9]+)?)$"),
    list("-+0123456789."))


def _ignore_tag(loader: yaml.SafeLoader, suffix: str, node: yaml.Node) -> Any:
    if isinstance(node, yaml.MappingNode):
        return _mapping(loader, node)
    if isinstance(node, yaml.SequenceNode):
        return loader.construct_sequence(node, deep=True)
    return loader.construct_object(yaml.ScalarNode(loader.resolve(yaml.ScalarNode, node.value, (True, False)),
                                                   node.value, node.start_mark, node.end_mark))


def _mapping(loader: yaml.SafeLoader, node: yaml.MappingNode) -> dict:
    out = {}
    for key_node, value_node in node.value:
        key = loader.construct_object(key_node, deep=True)
        if key in out:
            raise yaml.constructor.ConstructorError(None, None, f"the key {key!r} is given twice",
                                                    key_node.start_mark)
        out[key] = loader.construct_object(value_node, deep=True)
    return out


_YamlLoader.add_multi_constructor("tag:yaml.org,2002:", _ignore_tag)
_YamlLoader.add_multi_constructor("!", _ignore_tag)
_YamlLoader.add_constructor(yaml.resolver.BaseResolver.DEFAULT_MAPPING_TAG, _mapping)


def parse_yaml(text: str) -> Any:
    """The first document of a YAML text (PyYAML, see :class:`_YamlLoader`). Raises ``ValueError`` naming the
    line on text it cannot read."""
    try:
        documents = yaml.load_all(text, Loader=_YamlLoader)
        return next(documents, None)
    except yaml.YAMLError as exc:
        parts = []
        for text, mark in ((getattr(exc, "context", None), getattr(exc, "context_mark", None)),
                           (getattr(exc, "problem", None), getattr(exc, "problem_mark", None))):
            if text:
                parts.append(f"line {mark.line + 1}: {text}" if mark is not None else text)
        raise ValueError("; ".join(parts) or str(exc)) from None


# ---------------------------------------------------------------------------------------------- camera files
def _filenode_to_python(node) -> Any:
    """A ``cv2.FileNode`` as plain Python: dicts, lists, numbers and strings (matrices stay {rows, cols, data})."""
    if node.isMap():
        return {key: _filenode_to_python(node.getNode(key)) for key in node.keys()}
    if node.isSeq():
        return [_filenode_to_python(node.at(i)) for i in range(node.size())]
    if node.isInt():
        return int(node.real())
    if node.isReal():
        return float(node.real())
    if node.isString():
        return node.string()
    return None


def _read_opencv_storage(path: Path) -> Any:
    if not path.is_file():
        raise CameraError(f"no camera file at {path}")
    try:
        storage = cv2.FileStorage(os.fspath(path), cv2.FILE_STORAGE_READ)
    except (cv2.error, SystemError) as exc:
        cause = exc.__cause__ if isinstance(exc, SystemError) and exc.__cause__ is not None else exc
        detail = str(cause).strip().splitlines()[-1] if str(cause).strip() else type(cause).__name__
        raise CameraError(f"cannot parse the camera file {path} with cv2.FileStorage: {detail}") from None
    try:
        if not storage.isOpened():
            raise CameraError(f"cv2.FileStorage cannot open the camera file {path}")
        return _filenode_to_python(storage.root())
    finally:
        storage.release()


def _read_camera_document(path: Path) -> Any:
    """The camera file's content as plain Python (dicts, lists, numbers, strings)."""
    if not path.exists():
        raise CameraError(f"no camera file at {path}")
    if not path.is_file():
        raise CameraError(f"the camera file {path} is a directory, not a file")
    try:
        raw = path.read_bytes()
    except OSError as exc:
        raise CameraError(f"cannot read the camera file {path}: {exc.strerror or exc}") from None
    try:
        text = raw.decode("utf-8-sig")
    except UnicodeDecodeError:
        raise CameraError(f"the camera file {path} is not a text file (not UTF-8)") from None
    head = text.lstrip()
    if path.suffix.lower() == ".json" or head.startswith("{"):
        try:
            return json.loads(text)
        except json.JSONDecodeError as exc:
            raise CameraError(f"the camera file {path} is not valid JSON: {exc.msg} (line {exc.lineno})") from None
    if head.startswith("%YAML:") or head.startswith("<?xml") or head.startswith("<opencv_storage"):
        return _read_opencv_storage(path)  # OpenCV's own YAML 1.0 dialect or its XML
    try:
        return parse_yaml(text)
    except ValueError as exc:
        raise CameraError(f"the camera file {path} is not YAML that gtsam_rotid can read: {exc}") from None


def _first_key(document: Mapping, keys: Sequence[str]) -> str | None:
    return next((key for key in keys if key in document and document[key] is not None), None)


def _numeric_array(value: Any, path: Path, key: str) -> np.ndarray:
    try:
        array = np.array(value, dtype=float)
    except (TypeError, ValueError):
        raise CameraError(f"{path}: {key} must hold numbers, got {value!r}") from None
    if not np.all(np.isfinite(array)):
        raise CameraError(f"{path}: {key} contains NaN or infinite entries")
    return array


def _matrix(value: Any, path: Path, key: str) -> np.ndarray:
    """A matrix given as {rows, cols, data} (OpenCV / ROS), a flat list or a nested list."""
    if isinstance(value, Mapping):
        if "data" not in value:
            raise CameraError(f"{path}: {key} has no 'data' entry (found {', '.join(map(str, value)) or 'nothing'})")
        data = _numeric_array(value["data"], path, f"{key}.data").ravel()
        rows, cols = value.get("rows"), value.get("cols")
        if rows is None and cols is None:
            return data
        for name, count in (("rows", rows), ("cols", cols)):
            if isinstance(count, bool) or not isinstance(count, int) or count < 0:
                raise CameraError(f"{path}: {key}.{name} must be a non-negative integer, got {count!r}")
        if rows * cols != data.size:
            raise CameraError(f"{path}: {key} says {rows}x{cols} but its data holds {data.size} numbers")
        return data.reshape(rows, cols)
    if isinstance(value, (list, tuple)):
        if value and all(isinstance(row, (list, tuple)) for row in value):
            if len({len(row) for row in value}) != 1:
                raise CameraError(f"{path}: {key} has rows of different lengths")
        return _numeric_array(value, path, key)
    raise CameraError(f"{path}: {key} must be a matrix ({{rows, cols, data}} or a list of numbers), got {value!r}")


def _image_size(document: Mapping, path: Path) -> tuple[Any, Any]:
    width_key, height_key = _first_key(document, _WIDTH_KEYS), _first_key(document, _HEIGHT_KEYS)
    if width_key and height_key:
        return document[width_key], document[height_key]
    size_key = _first_key(document, _SIZE_KEYS)
    if size_key:
        size = _matrix(document[size_key], path, size_key).ravel()
        if size.size != 2:
            raise CameraError(f"{path}: {size_key} must be [width, height], got {size.size} numbers")
        return tuple(int(v) if float(v).is_integer() else float(v) for v in size)
    missing = [keys[0] for keys, key in ((_WIDTH_KEYS, width_key), (_HEIGHT_KEYS, height_key)) if key is None]
    raise CameraError(f"{path}: the image size is missing: no {' or '.join(repr(m) for m in missing)} "
                      f"(also accepted: {', '.join(_WIDTH_KEYS[1:] + _HEIGHT_KEYS[1:] + _SIZE_KEYS)})")


def _distortion(document: Mapping, path: Path) -> np.ndarray | None:
    model_key = _first_key(document, ("distortion_model",))
    model = document[model_key] if model_key else None
    if model is not None and (not isinstance(model, str) or model not in _SUPPORTED_DISTORTION_MODELS):
        raise CameraError(f"{path}: distortion_model {model!r} is not supported; gtsam_rotid uses OpenCV's "
                          f"plumb_bob model (k1, k2, p1, p2, k3). Recalibrate with that model (ROS "
                          f"camera_calibration's default, OpenCV's calibrateCamera without fisheye flags)")
    key = _first_key(document, _DISTORTION_KEYS)
    if key is None:
        return None
    dist = _matrix(document[key], path, key).ravel()
    if dist.size in (0, 4, 5):
        return dist if dist.size else None
    if dist.size in (8, 12, 14) and not np.any(dist[5:]):
        return dist[:5]
    if dist.size in (8, 12, 14):
        raise CameraError(f"{path}: {key} has {dist.size} coefficients with non-zero k4 and beyond "
                          f"({dist[5:].tolist()}); gtsam_rotid supports the 5-coefficient model "
                          f"(k1, k2, p1, p2, k3) only")
    raise CameraError(f"{path}: {key} must hold 4 or 5 coefficients (k1, k2, p1, p2[, k3]), got {dist.size}")


def load_camera(path: str | os.PathLike) -> Camera:
    """A :class:`Camera` from an OpenCV calibration file or a ROS ``camera_info`` YAML.

    Accepted: OpenCV's ``cv2.FileStorage`` YAML (``%YAML:1.0``; also its XML and JSON) with ``camera_matrix``
    (or ``cameraMatrix`` / ``K``), ``distortion_coefficients`` (or ``distCoeffs`` / ``D``; absent means no
    distortion), ``image_width`` and ``image_height`` (or ``image_size`` / ``imageSize`` = [w, h]); and ROS
    ``camera_info`` YAML (``camera_matrix: {rows, cols, data}``, ``distortion_model: plumb_bob``, ...) or an
    echoed ``CameraInfo`` message (``width``, ``height``, ``K`` / ``k``, ``D`` / ``d`` as flat lists).
    Rectification and projection matrices are ignored (a monocular camera's raw image is used).

    Raises :class:`CameraError` naming the file and the key at fault: a missing image size or camera matrix,
    a matrix that is not 3x3, a distortion model other than plumb_bob (a rational model is accepted when its
    extra coefficients are zero), unreadable or malformed files.
    """
    path = Path(path)
    return camera_from_document(_read_camera_document(path), path)


def camera_from_document(document: Any, path: Path | str) -> Camera:
    """A :class:`Camera` from a camera file's parsed contents (or a ``CameraInfo`` message's fields as a mapping:
    ``width``, ``height``, ``k``, ``d``, ``distortion_model``); ``path`` names where it came from in errors."""
    if not isinstance(document, Mapping):
        raise CameraError(f"{path}: a camera file must hold a mapping of keys (camera_matrix, image_width, ...), "
                          f"got {type(document).__name__}")
    k_key = _first_key(document, _CAMERA_MATRIX_KEYS)
    if k_key is None:
        raise CameraError(f"{path}: no camera matrix: expected the key 'camera_matrix' (or "
                          f"{', '.join(repr(k) for k in _CAMERA_MATRIX_KEYS[1:])}); the file has "
                          f"{', '.join(repr(str(k)) for k in document) or 'no keys'}")
    K = _matrix(document[k_key], path, k_key)
    if K.size == 9 and K.ndim == 1:
        K = K.reshape(3, 3)
    if K.shape != (3, 3):
        raise CameraError(f"{path}: {k_key} must be a 3x3 matrix, got shape {K.shape}")
    width, height = _image_size(document, path)
    dist = _distortion(document, path)
    try:
        return Camera(K, width, height, dist)
    except CameraError as exc:
        raise CameraError(f"{path}: {exc}") from None

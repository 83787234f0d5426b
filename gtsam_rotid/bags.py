"""ROS bags as recordings: ROS 1 ``.bag`` and ROS 2 bags (sqlite3 ``.db3`` and ``.mcap``), read through the
pure-Python ``rosbags`` package (no ROS installation). What calibration needs of them: the topics (found by message
type when that is unambiguous), the joint states as a time series in the model's joint order, the camera from
``CameraInfo``, the images (``Image`` in the common encodings and ``CompressedImage``) as uint8 arrays with their
stamps, and the camera-to-joint-state time offset, read off when the image starts and stops moving.

Times are the messages' header stamps (seconds), or the bag's receive time where a header stamp is zero.
"""

from __future__ import annotations

import os
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, NamedTuple

import cv2
import numpy as np

from .camera import Camera
from .camerafiles import camera_from_document
from .errors import CameraError, RecordingError
from .frames import with_motion

IMAGE = "sensor_msgs/msg/Image"
COMPRESSED_IMAGE = "sensor_msgs/msg/CompressedImage"
JOINT_STATE = "sensor_msgs/msg/JointState"
CAMERA_INFO = "sensor_msgs/msg/CameraInfo"
#: the suffixes of bag files (a ROS 2 bag is also a directory with ``metadata.yaml``)
BAG_SUFFIXES = (".bag", ".db3", ".mcap")

#: ROS image encodings -> (channels, OpenCV conversion to BGR or None); 16-bit ones are scaled to 8 bits
_ENCODINGS: dict[str, tuple[int, int | None]] = {
    "mono8": (1, None), "8uc1": (1, None), "mono16": (1, None),
    "bgr8": (3, None), "8uc3": (3, None), "rgb8": (3, cv2.COLOR_RGB2BGR),
    "bgra8": (4, cv2.COLOR_BGRA2BGR), "8uc4": (4, cv2.COLOR_BGRA2BGR), "rgba8": (4, cv2.COLOR_RGBA2BGR),
    # as cv_bridge converts them (OpenCV names a Bayer pattern by its second row)
    "bayer_rggb8": (1, cv2.COLOR_BayerBG2BGR), "bayer_bggr8": (1, cv2.COLOR_BayerRG2BGR),
    "bayer_gbrg8": (1, cv2.COLOR_BayerGR2BGR), "bayer_grbg8": (1, cv2.COLOR_BayerGB2BGR),
}


class BagError(RecordingError):
    """A bag that cannot be read or used: missing, unreadable, without the topics calibration needs, or with
    messages it cannot decode (the message names the bag and the topic)."""


@dataclass(frozen=True)
class BagTopics:
    """The topics a recording is read from: images, joint states, and the camera's ``CameraInfo`` (None: none)."""

    image: str
    joints: str
    camera_info: str | None


def _seconds(stamp) -> float:
    return float(stamp.sec) + 1e-9 * float(stamp.nanosec)


def _time(message, bag_time_ns: int) -> float:
    """The message's header stamp in seconds, or the bag's receive time where there is none (or it is zero)."""
    header = getattr(message, "header", None)
    if header is not None:
        stamp = _seconds(header.stamp)
        if stamp > 0.0:
            return stamp
    return 1e-9 * bag_time_ns


def decode_image(message, msgtype: str, where: str, bits: int | None = None) -> np.ndarray:
    """A ``sensor_msgs`` Image or CompressedImage as a uint8 array: (H, W) grey or (H, W, 3) BGR. 16-bit images
    are shifted down from ``bits`` (the sensor's depth, one for a topic: :meth:`Bag.image_motion` finds it), or
    from the image's own when None."""
    image, conversion = _native(message, msgtype, where)
    if image.dtype == np.uint16:
        image = _to_8_bits(image, bits)
    return image if conversion is None else cv2.cvtColor(image, conversion)


def _native(message, msgtype: str, where: str) -> tuple[np.ndarray, int | None]:
    """The image as stored (uint8, or uint16 for mono16 and 16-bit PNG), and the OpenCV conversion to BGR or grey
    that :func:`decode_image` applies after scaling it to 8 bits (None: none)."""
    data = np.frombuffer(message.data, dtype=np.uint8)
    if msgtype == COMPRESSED_IMAGE:
        image = cv2.imdecode(data, cv2.IMREAD_UNCHANGED) if data.size else None
        if image is None:
            raise BagError(f"{where}: a CompressedImage ({message.format!r}) that OpenCV cannot decode")
        return image, cv2.COLOR_BGRA2BGR if image.ndim == 3 and image.shape[2] == 4 else None
    encoding = str(message.encoding).lower()
    if encoding in ("16uc1", "32fc1"):
        raise BagError(f"{where}: {message.encoding} images are depth images, not intensity: give the colour or "
                       "grey image topic (--image-topic)")
    if encoding not in _ENCODINGS:
        raise BagError(f"{where}: the image encoding {message.encoding!r} is not supported (supported: "
                       f"{', '.join(_ENCODINGS)}, and CompressedImage)")
    channels, conversion = _ENCODINGS[encoding]
    height, width, step = int(message.height), int(message.width), int(message.step)
    wide = encoding == "mono16"
    row_bytes = width * channels * (2 if wide else 1)
    if height <= 0 or width <= 0 or step < row_bytes or data.size < height * step:
        raise BagError(f"{where}: an Image of {width}x{height} ({message.encoding}, step {step}) holds "
                       f"{data.size} bytes; expected at least {height * max(step, row_bytes)}")
    rows = data[:height * step].reshape(height, step)[:, :row_bytes]
    if wide:
        order = ">" if message.is_bigendian else "<"
        return np.ascontiguousarray(rows).view(f"{order}u2").reshape(height, width), None
    return (np.ascontiguousarray(rows).reshape(height, width, channels) if channels > 1 else rows.copy()), conversion


def _bit_depth(top: int) -> int:
    """The even bit depth (10, 12, 14, 16) that holds ``top``."""
    return top.bit_length() + top.bit_length() % 2


def _to_8_bits(image: np.ndarray, bits: int | None = None) -> np.ndarray:
    """A 16-bit image as 8 bits, shifted down from ``bits`` (else the image's own depth): 10- and 12-bit sensors
    write mono16 images whose values stay below 1024 or 4096, which a fixed shift by 8 bits would turn almost
    black. One depth for all of a topic's frames, so that one bright pixel does not change a frame's brightness."""
    if bits is None:
        bits = _bit_depth(int(image.max()) if image.size else 0)
    return np.clip(image >> max(0, bits - 8), 0, 255).astype(np.uint8)


class Bag:
    """An open bag (a context manager): its topics, joint states, camera and images.

    Raises :class:`BagError` naming the bag when it is missing or cannot be read.
    """

    def __init__(self, path: str | os.PathLike):
        from rosbags.highlevel import AnyReader, AnyReaderError  # imported here: only bag users pay for it
        from rosbags.typesys import Stores, get_typestore

        self.path = Path(path)
        if not self.path.exists():
            raise BagError(f"no bag at {self.path}")
        self._receive: dict[str, np.ndarray] = {}  # per image topic, each image's receive time (ns), bag order
        self._bits: dict[str, int | None] = {}  # per 16-bit image topic, the sensor's bit depth
        if self.path.is_file() and self.path.suffix.lower() in (".db3", ".mcap"):
            self.path = self.path.parent  # a ROS 2 bag is its directory (metadata.yaml beside the storage file)
        try:
            self._reader = AnyReader([self.path], default_typestore=get_typestore(Stores.LATEST))
            self._reader.open()
        except (AnyReaderError, OSError, ValueError, KeyError) as exc:
            raise BagError(f"cannot read the bag {path}: {exc} (ROS 1 .bag files and ROS 2 bag directories with "
                           "sqlite3 or mcap storage are supported)") from None

    def __enter__(self) -> Bag:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def close(self) -> None:
        self._reader.close()

    @property
    def topics(self) -> dict[str, str]:
        """Topic -> message type (ROS 2 style names, e.g. ``sensor_msgs/msg/Image``, for ROS 1 bags too)."""
        return {c.topic: c.msgtype for c in self._reader.connections}

    def count(self, topic: str) -> int:
        return sum(c.msgcount for c in self._reader.connections if c.topic == topic)

    def messages(self, topic: str, start_ns: int | None = None, stop_ns: int | None = None,
                 ) -> Iterator[tuple[float, Any, str, int]]:
        """(time in seconds, message, message type, receive time in ns) of the messages on ``topic``, in the bag's
        order (received in ``[start_ns, stop_ns)`` when given)."""
        connections = [c for c in self._reader.connections if c.topic == topic]
        if not connections:
            raise BagError(f"the bag {self.path} has no topic {topic!r} (it has: {_listing(self.topics)})")
        raw_messages = self._reader.messages(connections=connections, start=start_ns, stop=stop_ns)
        while True:
            try:
                connection, bag_time_ns, raw = next(raw_messages)
            except StopIteration:
                return
            except Exception as exc:  # rosbags raises several types for a damaged chunk or index
                raise BagError(f"{self.path}, topic {topic}: the bag is damaged ({type(exc).__name__}: {exc}); "
                               "`rosbag reindex` (ROS 1) or `ros2 bag reindex` (ROS 2) may repair it") from None
            try:
                message = self._reader.deserialize(raw, connection.msgtype)
            except Exception as exc:  # rosbags raises several types for a corrupt message
                raise BagError(f"{self.path}, topic {topic}: a message that cannot be read ({exc})") from None
            yield _time(message, bag_time_ns), message, connection.msgtype, bag_time_ns

    def choose_topics(self, image: str | None = None, joints: str | None = None,
                      camera_info: str | None = None, *, with_camera_info: bool = True) -> BagTopics:
        """The topics to read: each one given is checked, each one not given is found by its message type when
        exactly one topic has it (the camera's ``CameraInfo`` beside the image topic first; the bag's only one
        when its frame is the images'). No CameraInfo is looked for without ``with_camera_info`` (a camera file is
        given). Raises :class:`BagError` naming the candidates when a choice is needed."""
        image = self._topic(image, (IMAGE, COMPRESSED_IMAGE), "image", "--image-topic")
        joints = self._topic(joints, (JOINT_STATE,), "joint state", "--joint-topic")
        if not with_camera_info:
            return BagTopics(image, joints, None)
        if camera_info is None:
            infos = [t for t, kind in self.topics.items() if kind == CAMERA_INFO]
            beside = _camera_namespace(image) + "/camera_info"
            if beside in infos:
                camera_info = beside
            elif len(infos) == 1:
                camera_info = infos[0]
                self._same_camera(image, camera_info)
            elif infos:
                raise BagError(f"the bag {self.path} has several CameraInfo topics ({', '.join(infos)}) and none "
                               f"beside the images ({beside}): choose one with --camera-info-topic, or give "
                               "--camera")
        else:
            camera_info = self._topic(camera_info, (CAMERA_INFO,), "CameraInfo", "--camera-info-topic")
        return BagTopics(image, joints, camera_info)

    def _same_camera(self, image: str, camera_info: str) -> None:
        """Refuse a CameraInfo topic found only because it is the bag's one, when its frame is not the images'."""
        frames = []
        for topic in (image, camera_info):
            first = next(self.messages(topic), None)
            frames.append("" if first is None else str(getattr(first[1].header, "frame_id", "")))
        if frames[0] and frames[1] and frames[0] != frames[1]:
            raise BagError(f"the bag's only CameraInfo topic {camera_info} is for the frame {frames[1]!r}, the images "
                           f"on {image} for {frames[0]!r}: it may be another camera's. Give --camera-info-topic "
                           f"{camera_info} to use it anyway, or --camera FILE")

    def _topic(self, given: str | None, kinds: tuple[str, ...], what: str, flag: str) -> str:
        topics = self.topics
        if given is not None:
            if given not in topics:
                raise BagError(f"the bag {self.path} has no topic {given!r} ({flag}); it has: {_listing(topics)}")
            if topics[given] not in kinds:
                raise BagError(f"{flag} {given} in {self.path} carries {topics[given]}, not {' or '.join(kinds)}")
            return given
        found = [t for t, kind in topics.items() if kind in kinds]
        if not found:
            raise BagError(f"the bag {self.path} has no {what} topic ({' or '.join(kinds)}); it has: "
                           f"{_listing(topics)}")
        if len(found) > 1:
            raise BagError(f"the bag {self.path} has several {what} topics ({', '.join(sorted(found))}): choose one "
                           f"with {flag}")
        return found[0]

    def joint_states(self, topic: str, names: Sequence[str]) -> tuple[np.ndarray, np.ndarray]:
        """(stamps (N,), positions (N, len(names)) radians in ``names`` order) from a JointState topic.

        Messages may carry other joints (grippers) or only some joints (several publishers on one topic): each
        joint's positions are interpolated on its own stamps at every stamp that carries one of ``names``, within
        the span where every joint has been seen. Raises :class:`BagError` naming joints that never appear."""
        index = {name: i for i, name in enumerate(names)}
        series: list[list[tuple[float, float]]] = [[] for _ in names]
        stamps, seen = [], set()
        for stamp, message, _, _ in self.messages(topic):
            carried = False
            for name, value in zip(message.name, np.asarray(message.position, dtype=float), strict=False):
                seen.add(name)
                if name in index and np.isfinite(value):
                    series[index[name]].append((stamp, float(value)))
                    carried = True
            if carried:
                stamps.append(stamp)
        missing = [name for name, s in zip(names, series, strict=True) if not s]
        if missing:
            raise BagError(f"{self.path}, topic {topic}: the joint state never names the model's joint(s) "
                           f"{', '.join(missing)} (it names: {', '.join(sorted(seen)) or 'nothing'}); is this the "
                           "right robot model?")
        stamps = np.unique(np.asarray(stamps))
        first = max(min(t for t, _ in s) for s in series)
        last = min(max(t for t, _ in s) for s in series)
        stamps = stamps[(stamps >= first) & (stamps <= last)]
        if len(stamps) < 2:
            raise BagError(f"{self.path}, topic {topic}: {len(stamps)} joint state(s) in which every joint of the "
                           "model is known; need a time series")
        columns = []
        for s in series:
            t, v = np.array(sorted(s)).T
            columns.append(np.interp(stamps, t, np.unwrap(v)))
        return stamps, np.stack(columns, axis=1)

    def camera(self, topic: str, *, rectified: bool = False) -> Camera:
        """The camera of the first ``CameraInfo`` message on ``topic`` (plumb_bob distortion, as a camera file).
        For ``rectified`` images (``image_rect``) the projection matrix P without distortion: K and D describe
        the raw images."""
        where = f"{self.path}, topic {topic}"
        for _, message, _, _ in self.messages(topic):
            K = [float(v) for v in (message.k if hasattr(message, "k") else message.K)]
            D = [float(v) for v in (message.d if hasattr(message, "d") else message.D)]
            if rectified:
                P = np.array([float(v) for v in (message.p if hasattr(message, "p") else message.P)]).reshape(3, 4)
                K, D = P[:, :3].ravel().tolist(), []
            document = {"width": int(message.width), "height": int(message.height), "k": K, "d": D,
                        "distortion_model": "plumb_bob" if rectified else str(message.distortion_model)}
            try:
                return camera_from_document(document, where)
            except CameraError as exc:
                raise BagError(f"{exc} (an uncalibrated camera publishes zeros: give --camera)") from None
        raise BagError(f"{where}: no CameraInfo message")

    def images(self, topic: str, first: int = 0, last: int | None = None,
               ) -> Iterator[tuple[int, float, np.ndarray]]:
        """(index on the topic, stamp, uint8 image) of the images ``first`` to ``last`` (inclusive; None: to the
        end) in the bag's order. After :meth:`image_motion` only that stretch of the bag is read."""
        receive = self._receive.get(topic)
        start_ns = stop_ns = None
        offset = 0
        if receive is not None and len(receive):
            offset = int(np.searchsorted(receive, receive[first], side="left"))
            start_ns = int(receive[first])
            stop_ns = None if last is None or last + 1 >= len(receive) else int(receive[last]) + 1
        bits = self._bits.get(topic)
        for i, (stamp, message, msgtype, _) in enumerate(self.messages(topic, start_ns, stop_ns), start=offset):
            if i < first:
                continue
            if last is not None and i > last:
                return
            yield i, stamp, decode_image(message, msgtype, f"{self.path}, topic {topic}, image {i}", bits)

    def _topic_bits(self, topic: str) -> int | None:
        """The bit depth of a 16-bit image topic (the largest value over all its images); None for 8-bit ones."""
        first = next(self.messages(topic), None)
        if first is None or (first[2] == IMAGE and str(first[1].encoding).lower() != "mono16"):
            return None
        top = 0
        for i, (_, message, msgtype, _) in enumerate(self.messages(topic)):
            values, _ = _native(message, msgtype, f"{self.path}, topic {topic}, image {i}")
            if values.dtype != np.uint16:
                return None
            top = max(top, int(values.max()) if values.size else 0)
        return _bit_depth(top)

    def image_motion(self, topic: str, size: int = 64) -> tuple[np.ndarray, np.ndarray]:
        """(stamps, motion) of every image on ``topic``, in the bag's order: motion is the mean absolute difference
        (grey levels) of each image from the one before, at ``size`` pixels across (0 for the first)."""
        stamps, motion, receive = [], [], []
        self._bits[topic] = bits = self._topic_bits(topic)

        def images():
            for i, (stamp, message, msgtype, received) in enumerate(self.messages(topic)):
                stamps.append(stamp)
                receive.append(received)
                yield decode_image(message, msgtype, f"{self.path}, topic {topic}, image {i}", bits)

        for _ in with_motion(images(), motion, size):
            pass
        self._receive[topic] = np.asarray(receive, dtype=np.int64)
        return np.asarray(stamps), np.asarray(motion)


def _camera_namespace(image_topic: str) -> str:
    """The camera's namespace of an image topic: ``/cam`` of ``/cam/image_raw`` and of
    ``/cam/image_raw/compressed`` (image_transport's sub-topic)."""
    parts = image_topic.rstrip("/").split("/")
    if parts and parts[-1] in ("compressed", "theora", "compressedDepth"):
        parts = parts[:-1]
    return "/".join(parts[:-1])


def is_rectified(image_topic: str) -> bool:
    """``image_rect``, ``image_rect_color``, ...: images that image_proc already undistorted."""
    return any(part.startswith("image_rect") for part in image_topic.split("/"))


def _listing(topics: dict[str, str]) -> str:
    return ", ".join(f"{t} ({kind})" for t, kind in sorted(topics.items())) or "no topics"


class TimeOffset(NamedTuple):
    """The camera clock minus the joint-state clock (s), the score it was found at (the correlation of image change
    and joint travel times the fraction of image pairs inside the joint states, 0-1), and another offset, at least
    AMBIGUOUS_S away, that scores within AMBIGUOUS_RATIO of it (None when there is none): recordings whose spins
    repeat with one rhythm and no images between them line up as well one spin later."""

    offset: float
    score: float
    rival: float | None = None


#: Below this score (the correlation of image change and joint travel times the fraction of the recording it lines
#: up, :class:`TimeOffset`) the time offset is not trusted (and not applied): one spin later, a repeating recording
#: scores about (n - 1) / n of the true offset's (0.66 of 0.98 with three spins).
MIN_OFFSET_CORRELATION = 0.8
#: Offsets this far apart (s) are distinct answers; a second one within this ratio of the best score makes it ambiguous.
AMBIGUOUS_S = 0.5
AMBIGUOUS_RATIO = 0.9


def estimate_time_offset(image_stamps: np.ndarray, motion: np.ndarray, joint_stamps: np.ndarray,
                         positions: np.ndarray, max_offset_s: float = 1.0) -> TimeOffset:
    """The camera-to-joint-state time offset (:class:`TimeOffset`): the offset that best lines up how much each
    image differs from the one before (``motion``, :meth:`Bag.image_motion`) with how far the joints moved between
    the two images' times, searched within ``max_offset_s`` at a quarter of the frame period, then at 1/64 of it
    about the best. NaN with a score of 0 when the joints never move or the images never change."""
    stamps = np.asarray(joint_stamps, dtype=float)
    q = np.unwrap(np.asarray(positions, dtype=float), axis=0)
    image_stamps = np.asarray(image_stamps, dtype=float)
    if len(stamps) < 2 or len(image_stamps) < 3:
        return TimeOffset(float("nan"), 0.0)
    period = float(np.median(np.diff(image_stamps)))
    moving = np.asarray(motion, dtype=float)[1:]
    if not np.isfinite(period) or period <= 0 or np.ptp(moving) <= 0 or not np.any(np.ptp(q, axis=0) > 0):
        return TimeOffset(float("nan"), 0.0)

    # pairs of images further apart than 1.5 frame periods (the camera stopped, frames dropped) are not compared:
    # the arm may have moved far in between, and one such pair would outweigh every spin's start and stop
    paired = np.diff(image_stamps) <= 1.5 * period

    def score(offset: float) -> float:
        times = image_stamps - offset  # each image's instant on the joint clock
        inside = (times >= stamps[0]) & (times <= stamps[-1])
        at = np.stack([np.interp(times, stamps, q[:, j]) for j in range(q.shape[1])], axis=1)
        travel = np.linalg.norm(np.diff(at, axis=0), axis=1)
        used = inside[1:] & inside[:-1] & paired
        # weighted by the pairs it can compare: an offset that leaves a spin's images outside the joint states
        # lines up less of the recording
        return _correlation(moving, np.where(used, travel, np.nan)) * used.sum() / max(paired.sum(), 1)

    coarse = np.arange(-max_offset_s, max_offset_s + 0.125 * period, 0.25 * period)
    scores = np.array([score(offset) for offset in coarse])
    if not np.any(np.isfinite(scores)):
        return TimeOffset(float("nan"), 0.0)
    # the peak is a kink (a spin's start or stop falls between two frames), steep on one side: search it finely
    # about the best coarse offset rather than fit a parabola, which the gentle side drags
    top = int(np.nanargmax(scores))
    centre = float(coarse[top])
    fine = centre + np.linspace(-0.25 * period, 0.25 * period, 33)
    fine_scores = np.array([score(offset) for offset in fine])
    best = int(np.nanargmax(fine_scores))
    far = np.abs(coarse - centre) >= AMBIGUOUS_S
    rival = None
    if np.any(far & np.isfinite(scores)):
        other = int(np.nanargmax(np.where(far, scores, -np.inf)))
        if scores[other] >= AMBIGUOUS_RATIO * scores[top]:
            rival = float(coarse[other])
    return TimeOffset(float(fine[best]), float(max(fine_scores[best], 0.0)), rival)


def _correlation(a: np.ndarray, b: np.ndarray) -> float:
    ok = np.isfinite(b)
    if ok.sum() < 3 or np.ptp(a[ok]) <= 0 or np.ptp(b[ok]) <= 0:
        return float("nan")
    return float(np.corrcoef(a[ok], b[ok])[0, 1])

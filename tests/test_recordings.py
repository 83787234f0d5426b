"""Tests of gtsam_rotid.recordings: camera and joint files, frames of videos and image folders, datasets, CLI."""

from __future__ import annotations

import argparse
import json
import re
import sys
import types
from pathlib import Path

import cv2
import numpy as np
import pytest
from urdf_arm import URDF_3_JOINTS

from gtsam_rotid import recordings
from gtsam_rotid.arm import Arm
from gtsam_rotid.camera import Camera
from gtsam_rotid.cli import add_track_parser, cmd_track
from gtsam_rotid.dataset import Dataset, Track
from gtsam_rotid.errors import CameraError, DatasetExistsError, InputError, RotIdError
from gtsam_rotid.recordings import (
    RecordingError,
    find_spins,
    load_camera,
    load_joints,
    make_dataset,
    parse_yaml,
    read_frames,
    read_joint_file,
)
from gtsam_rotid.trackparams import AXIS_FLOOR_PX, TRACK_OFFSET_PX

K = np.array([[520.5, 0.0, 31.25], [0.0, 522.0, 23.75], [0.0, 0.0, 1.0]])
DIST = np.array([0.11, -0.21, 0.0012, -0.0008, 0.031])
WIDTH, HEIGHT = 64, 48

ROS_CAMERA_INFO = """image_width: 64
image_height: 48
camera_name: narrow_stereo   # a comment
camera_matrix:
  rows: 3
  cols: 3
  data: [520.5, 0, 31.25,
         0, 522.0, 23.75,
         0, 0, 1]
distortion_model: plumb_bob
distortion_coefficients:
  rows: 1
  cols: 5
  data: [0.11, -0.21, 0.0012, -0.0008, 0.031]
rectification_matrix:
  rows: 3
  cols: 3
  data: [1, 0, 0, 0, 1, 0, 0, 0, 1]
projection_matrix:
  rows: 3
  cols: 4
  data: [520.5, 0, 31.25, 0, 0, 522.0, 23.75, 0, 0, 0, 1, 0]
"""

# `ros2 topic echo --once /camera_info`: block sequences at the key's indentation, a trailing document marker.
ROS2_CAMERA_INFO_MESSAGE = """header:
  stamp:
    sec: 17
    nanosec: 5
  frame_id: camera_optical
height: 48
width: 64
distortion_model: plumb_bob
d:
- 0.11
- -0.21
- 0.0012
- -0.0008
- 0.031
k:
""" + "".join(f"- {float(v)!r}\n" for v in K.ravel()) + """binning_x: 0
roi:
  x_offset: 0
  do_rectify: false
---
"""


@pytest.fixture(scope="module")
def arm() -> Arm:
    return Arm.from_urdf_string(URDF_3_JOINTS)


@pytest.fixture
def camera() -> Camera:
    return Camera(K, WIDTH, HEIGHT, DIST)


def write(path: Path, text: str) -> Path:
    path.write_text(text, encoding="utf-8")
    return path


def write_opencv_camera(path: Path, k_key="camera_matrix", d_key="distortion_coefficients", size=True,
                        K_matrix=K) -> Path:
    storage = cv2.FileStorage(str(path), cv2.FILE_STORAGE_WRITE)
    if size:
        storage.write("image_width", WIDTH)
        storage.write("image_height", HEIGHT)
    storage.write(k_key, K_matrix)
    if d_key:
        storage.write(d_key, DIST.reshape(1, 5))
    storage.release()
    return path


def csv_row(values) -> str:
    return ",".join(repr(float(v)) for v in values)


def assert_camera(camera: Camera, dist=DIST) -> None:
    np.testing.assert_array_equal(camera.K, K)
    assert (camera.width, camera.height) == (WIDTH, HEIGHT)
    if dist is None:
        assert camera.dist is None
    else:
        np.testing.assert_array_equal(camera.dist, dist)


# ---------------------------------------------------------------------------------------------- camera files
@pytest.mark.parametrize(("k_key", "d_key"), [("camera_matrix", "distortion_coefficients"),
                                              ("K", "D"), ("cameraMatrix", "distCoeffs")])
def test_opencv_camera_yaml(tmp_path, k_key, d_key):
    path = write_opencv_camera(tmp_path / "camera.yaml", k_key, d_key)
    assert path.read_text().startswith("%YAML:1.0")
    assert_camera(load_camera(path))


@pytest.mark.parametrize("suffix", [".xml", ".json"])
def test_opencv_camera_xml_and_json(tmp_path, suffix):
    assert_camera(load_camera(write_opencv_camera(tmp_path / f"camera{suffix}")))


def test_opencv_camera_without_distortion_and_image_size_key(tmp_path):
    path = tmp_path / "camera.yaml"
    storage = cv2.FileStorage(str(path), cv2.FILE_STORAGE_WRITE)
    storage.write("imageSize", np.array([[WIDTH, HEIGHT]]))
    storage.write("cameraMatrix", K)
    storage.release()
    assert_camera(load_camera(path), dist=None)


def test_ros_camera_info_yaml(tmp_path):
    assert_camera(load_camera(write(tmp_path / "camera_info.yaml", ROS_CAMERA_INFO)))


def test_ros2_camera_info_message(tmp_path):
    assert_camera(load_camera(write(tmp_path / "info.yaml", ROS2_CAMERA_INFO_MESSAGE)))


def test_rational_model_with_zero_extra_coefficients_is_plumb_bob(tmp_path):
    text = ROS_CAMERA_INFO.replace("plumb_bob", "rational_polynomial").replace(
        "cols: 5\n  data: [0.11, -0.21, 0.0012, -0.0008, 0.031]",
        "cols: 8\n  data: [0.11, -0.21, 0.0012, -0.0008, 0.031, 0, 0, 0]")
    assert_camera(load_camera(write(tmp_path / "camera.yaml", text)))


@pytest.mark.parametrize(("text", "words"), [
    (ROS_CAMERA_INFO.replace("image_width: 64\n", ""), ["image_width", "missing"]),
    (ROS_CAMERA_INFO.replace("rows: 3\n  cols: 3\n  data: [520.5", "rows: 2\n  cols: 3\n  data: [520.5")
     .replace("0, 522.0, 23.75,\n         0, 0, 1]", "0, 522.0, 23.75]"), ["camera_matrix", "3x3", "(2, 3)"]),
    (ROS_CAMERA_INFO.replace("rows: 3\n  cols: 3\n  data: [520.5", "rows: 3\n  cols: 2\n  data: [520.5"),
     ["camera_matrix", "3x2", "9 numbers"]),
    (ROS_CAMERA_INFO.replace("plumb_bob", "equidistant"), ["distortion_model", "'equidistant'", "not supported"]),
    (ROS_CAMERA_INFO.replace("plumb_bob", "rational_polynomial").replace(
        "cols: 5\n  data: [0.11, -0.21, 0.0012, -0.0008, 0.031]",
        "cols: 8\n  data: [0.11, -0.21, 0.0012, -0.0008, 0.031, 0.5, 0, 0]"),
     ["distortion_coefficients", "8 coefficients", "k4"]),
    (ROS_CAMERA_INFO.replace("camera_matrix:", "intrinsics:"), ["no camera matrix", "camera_matrix"]),
    (ROS_CAMERA_INFO.replace("data: [520.5, 0, 31.25,", "data: [520.5, 0, 31.25"),
     ["camera_matrix.data", "must hold numbers", "'31.25 0'"]),
    (ROS_CAMERA_INFO.replace("0, 0, 1]\ndistortion_model", "0, 0, 1\ndistortion_model"),
     ["not YAML", "line 7: while parsing a flow sequence", "expected ',' or ']'"]),
    (ROS_CAMERA_INFO.replace("image_height: 48", "image_height: 48.5"), ["height", "48.5"]),
    ("just some words\n", ["must hold a mapping of keys", "got str"]),
    ("- 1\n- 2\n", ["mapping"]),
])
def test_bad_camera_files_name_the_file_and_key(tmp_path, text, words):
    path = write(tmp_path / "bad_camera.yaml", text)
    with pytest.raises(CameraError) as info:
        load_camera(path)
    message = str(info.value)
    assert str(path) in message
    for word in words:
        assert word in message


def test_bad_opencv_files(tmp_path):
    with pytest.raises(CameraError, match="no camera file"):
        load_camera(tmp_path / "missing.yaml")
    broken = write(tmp_path / "broken.yaml", "%YAML:1.0\n---\ncamera_matrix: [1, 2\n  oops: :\n")
    with pytest.raises(CameraError, match="broken.yaml"):
        load_camera(broken)
    no_size = write_opencv_camera(tmp_path / "nosize.yaml", size=False)
    with pytest.raises(CameraError, match="image_width"):
        load_camera(no_size)
    wrong_shape = write_opencv_camera(tmp_path / "shape.yaml", K_matrix=K[:2])
    with pytest.raises(CameraError, match=r"camera_matrix must be a 3x3 matrix, got shape \(2, 3\)"):
        load_camera(wrong_shape)
    assert issubclass(CameraError, InputError)


def test_parse_yaml_subset():
    text = ("%YAML 1.2\n---\na: 'it''s'  # comment\nb: \"x # y\"\nc: [1, [2.5, -3e-2], {p: ~}]\n"
            "d:\n  - e: 1\n    f: true\n  - .inf\nname: it's a, b\nm: !!opencv-matrix\n  rows: 1\n  data: [7]\n"
            "...\nignored: 1\n")
    assert parse_yaml(text) == {"a": "it's", "b": "x # y", "c": [1, [2.5, -0.03], {"p": None}],
                                "d": [{"e": 1, "f": True}, float("inf")], "name": "it's a, b",
                                "m": {"rows": 1, "data": [7]}}
    for bad in ("a: [1, 2\n", "a: 1\n  b: 2\n", "a: 1\na: 2\n", "a:\n\tb: 1\n"):
        with pytest.raises(ValueError, match="line"):
            parse_yaml(bad)


# ---------------------------------------------------------------------------------------------- joint files
POSES = np.array([[0.1, -0.2, 0.3], [0.4, 0.5, -0.6], [-0.7, 0.8, 0.9]])


def test_csv_with_header_in_any_order(tmp_path, arm):
    rows = "\n".join(f"{float(e)!r},{float(w)!r},{float(s)!r}" for s, e, w in POSES)
    path = write(tmp_path / "joints.csv", f"# comment\nelbow,wrist,shoulder\n{rows}\n")
    np.testing.assert_array_equal(load_joints(path, arm, 3), POSES)


def test_csv_without_header_and_degrees(tmp_path, arm):
    path = write(tmp_path / "joints.csv", "\n".join(" ; ".join(repr(float(v)) for v in np.degrees(q)) for q in POSES))
    np.testing.assert_allclose(load_joints(path, arm, degrees=True), POSES, rtol=0, atol=1e-15)
    spaces = write(tmp_path / "joints.txt", "\n".join(" ".join(repr(float(v)) for v in q) for q in POSES))
    np.testing.assert_array_equal(load_joints(spaces, arm), POSES)


@pytest.mark.parametrize("document", [
    POSES.tolist(),
    [dict(zip(["wrist", "shoulder", "elbow"], [q[2], q[0], q[1]], strict=True)) for q in POSES],
    {"joint_names": ["elbow", "shoulder", "wrist"], "measurements": POSES[:, [1, 0, 2]].tolist()},
])
def test_json_formats(tmp_path, arm, document):
    path = write(tmp_path / "joints.json", json.dumps(document))
    np.testing.assert_array_equal(load_joints(path, arm, 3), POSES)


def test_joint_file_errors(tmp_path, arm):
    csv_path = write(tmp_path / "joints.csv", "shoulder,elbow,wrist\n" + "\n".join(csv_row(q) for q in POSES))
    with pytest.raises(RecordingError, match=r"3 row\(s\) of joint angles .* there are 4 measurements"):
        load_joints(csv_path, arm, 4)
    unknown = write(tmp_path / "unknown.csv", "shoulder,elbow,wrist,finger_1\n1,2,3,4\n")
    with pytest.raises(RecordingError, match=r"unknown joint name\(s\) \['finger_1'\].*ignore"):
        load_joints(unknown, arm)
    np.testing.assert_array_equal(load_joints(unknown, arm, ignore_joints=["finger_1"]), [[1, 2, 3]])
    renamed = write(tmp_path / "renamed.json", json.dumps({"joint_names": ["joint_1", "elbow", "wrist"],
                                                           "measurements": [[1, 2, 3]]}))
    with pytest.raises(RecordingError) as info:
        load_joints(renamed, arm)
    assert "['joint_1']" in str(info.value) and "missing joint(s) ['shoulder']" in str(info.value)
    short = write(tmp_path / "short.csv", "1,2\n3,4\n")
    with pytest.raises(RecordingError, match="rows have 2 values but the arm 'tri_arm' has 3 joints"):
        load_joints(short, arm)
    ragged = write(tmp_path / "ragged.csv", "shoulder,elbow,wrist\n1,2,3\n1,2\n")
    with pytest.raises(RecordingError, match="line 3: 2 values, expected 3"):
        load_joints(ragged, arm)
    nan = write(tmp_path / "nan.json", json.dumps({"joint_names": ["shoulder", "elbow", "wrist"],
                                                   "measurements": [[1, "x", 3]]}))
    with pytest.raises(RecordingError, match="must be numbers"):
        load_joints(nan, arm)
    with pytest.raises(RecordingError, match="no joint-angle file"):
        load_joints(tmp_path / "missing.csv", arm)
    with pytest.raises(RecordingError, match="spans apply only to a time series"):
        load_joints(csv_path, arm, spans=[(0, 1)])


# ---------------------------------------------------------------------------------------------- time series
def joint_series(rng: np.random.Generator, poses=POSES, noise_deg=0.03):
    """A joint-state series: rest, spin, rest at each pose, with moves of all joints between poses.

    Returns stamps, positions (wrist wrapped to (-pi, pi]) and the sample indices held at each pose.
    """
    stamps, rows, held = [], [], []
    t = 0.0
    previous = None
    for q in poses:
        if previous is not None:  # a move: every joint travels in steps of at least 0.5 deg
            for s in np.linspace(0.0, 1.0, 40)[1:-1]:
                rows.append(previous + s * (q - previous))
                stamps.append(t)
                t += 0.01
        indices = []
        wrist = np.concatenate([np.full(20, q[2]), q[2] + np.linspace(0.0, np.radians(400.0), 200),
                                np.full(20, q[2] + np.radians(400.0))])
        for w in wrist:
            row = q + rng.uniform(-1, 1, 3) * np.radians(noise_deg)
            row[2] = np.angle(np.exp(1j * w))
            indices.append(len(rows))
            rows.append(row)
            stamps.append(t)
            t += 0.01
        held.append(np.array(indices))
        previous = np.array([q[0], q[1], np.angle(np.exp(1j * wrist[-1]))])
    return np.array(stamps), np.array(rows), held


def expected_poses(positions, held):
    """Independent expectation: median of each still joint over the samples held at the pose, wrist at the start."""
    return np.array([[np.median(positions[idx, 0]), np.median(positions[idx, 1]), positions[idx[0], 2]]
                     for idx in held])


def write_series_csv(path, stamps, positions, degrees=False):
    values = np.degrees(positions) if degrees else positions
    lines = ["stamp,wrist,elbow,shoulder"] + [csv_row([t, q[2], q[1], q[0]]) for t, q in
                                                 zip(stamps, values, strict=True)]
    return write(path, "\n".join(lines) + "\n")


def test_time_series_still_joints_found_automatically(tmp_path, arm):
    stamps, positions, held = joint_series(np.random.default_rng(1))
    path = write_series_csv(tmp_path / "states.csv", stamps, positions)
    joints = load_joints(path, arm, 3)
    np.testing.assert_allclose(joints, expected_poses(positions, held), rtol=0, atol=1e-12)
    assert np.max(np.abs(joints - POSES)) < np.radians(0.05)
    spins = find_spins(stamps, positions, arm.wrist_index)
    assert spins == [(stamps[idx[0]], stamps[idx[-1]]) for idx in held]


def test_time_series_json_with_explicit_spans_in_degrees(tmp_path, arm):
    stamps, positions, held = joint_series(np.random.default_rng(2))
    path = write(tmp_path / "states.json", json.dumps({
        "joint_names": ["shoulder", "elbow", "wrist"], "stamps": stamps.tolist(),
        "positions": np.degrees(positions).tolist()}))
    spans = [(stamps[idx[10]], stamps[idx[-5]]) for idx in held]
    joints = load_joints(path, arm, 3, degrees=True, spans=spans)
    inner = [idx[10:-4] for idx in held]
    np.testing.assert_allclose(joints, expected_poses(positions, inner), rtol=0, atol=1e-12)
    assert read_joint_file(path, arm, degrees=True).is_time_series


def test_time_series_with_spins_of_another_joint(tmp_path, arm):
    """Pose 1 spins the elbow (by 60 deg), the others the wrist: each pose's spinning joint is read at its start, the
    others are the medians; whichever joint moved must be the one each video names."""
    stamps, positions, held = joint_series(np.random.default_rng(4))
    idx = held[1]
    positions[idx, 2] = POSES[1, 2] + np.random.default_rng(5).uniform(-1, 1, len(idx)) * np.radians(0.03)
    positions[idx[20:220], 1] = POSES[1, 1] + np.linspace(0.0, np.radians(60.0), 200)
    positions[idx[220:], 1] = POSES[1, 1] + np.radians(60.0)
    path = write_series_csv(tmp_path / "states.csv", stamps, positions)
    spans = [(stamps[i[0]], stamps[i[-1]]) for i in held]
    joints = load_joints(path, arm, 3, spans=spans, spin_joints=[None, "elbow", "wrist"])
    expected = expected_poses(positions, held)
    expected[1, 1:] = positions[idx[0], 1], np.median(positions[idx, 2])
    np.testing.assert_allclose(joints, expected, rtol=0, atol=1e-12)
    with pytest.raises(RecordingError, match=r"measurement 1: only the wrist may move .* 'elbow' by 60"):
        load_joints(path, arm, 3, spans=spans)
    with pytest.raises(RecordingError, match=r"the videos spin different joints .*give each video's time span"):
        load_joints(path, arm, 3, spin_joints=[None, "elbow", None])
    with pytest.raises(InputError, match="'knee' is not a revolute joint"):
        load_joints(path, arm, 3, spans=spans, spin_joints=[None, "knee", None])


def test_time_series_errors(tmp_path, arm):
    stamps, positions, held = joint_series(np.random.default_rng(3))
    path = write_series_csv(tmp_path / "states.csv", stamps, positions)
    # A span that includes the move to the next pose: the elbow moved, and the message says by how much.
    moving = [(stamps[held[0][0]], stamps[held[1][0] - 5])] + [(stamps[i[0]], stamps[i[-1]]) for i in held[1:]]
    with pytest.raises(RecordingError) as info:
        load_joints(path, arm, 3, spans=moving, labels=["a.mp4", "b.mp4", "c.mp4"])
    message = str(info.value)
    assert "measurement 0 (a.mp4)" in message and "'elbow' by" in message and "'shoulder' by" in message
    assert "'wrist'" not in message.split("moved")[0].split("joint(s)")[1]
    moved_deg = float(message.split("'elbow' by ")[1].split(" deg")[0])
    assert moved_deg == pytest.approx(np.degrees(abs(POSES[1, 1] - POSES[0, 1])) * 34 / 39, rel=0.02)
    # A span in the rest before the spin: the wrist did not turn.
    rest = [(stamps[i[0]], stamps[i[15]]) for i in held]
    with pytest.raises(RecordingError, match=r"measurement 0: the wrist 'wrist' turned by only 0 deg"):
        load_joints(path, arm, 3, spans=rest)
    with pytest.raises(RecordingError, match=r"found 3 spin\(s\).*expected 4 \(one per video\)"):
        load_joints(path, arm, 4)
    with pytest.raises(RecordingError, match=r"found 0 spin\(s\)"):
        load_joints(path, arm, 3, min_spin_deg=500.0)
    with pytest.raises(RecordingError, match="0 sample"):
        load_joints(path, arm, 1, spans=[(stamps[-1] + 1.0, stamps[-1] + 2.0)])
    with pytest.raises(RecordingError, match=r"2 time span\(s\) given for 3"):
        load_joints(path, arm, 3, spans=[(0, 1), (1, 2)])
    # Joint noise above the tolerance: the series no longer splits into 3 spins.
    noisy = write_series_csv(tmp_path / "noisy.csv", *joint_series(np.random.default_rng(4), noise_deg=0.3)[:2])
    with pytest.raises(RecordingError, match="still_tolerance_deg"):
        load_joints(noisy, arm, 3)
    np.testing.assert_allclose(load_joints(noisy, arm, 3, still_tolerance_deg=0.7), POSES, atol=np.radians(0.3))


# ---------------------------------------------------------------------------------------------- frames
def frame(i: int, color=True) -> np.ndarray:
    image = np.full((HEIGHT, WIDTH, 3) if color else (HEIGHT, WIDTH), 10 + 20 * i, np.uint8)
    image[:4, :4] = 255
    return image


def write_video(path: Path, n: int) -> Path:
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"mp4v"), 10.0, (WIDTH, HEIGHT))
    assert writer.isOpened()
    for i in range(n):
        writer.write(frame(i))
    writer.release()
    return path


def write_folder(path: Path, n: int) -> Path:
    path.mkdir()
    for i in range(n):  # frame_2 must come before frame_10
        cv2.imwrite(str(path / f"frame_{i}.png"), frame(i, color=False))
    (path / "notes.txt").write_text("not an image")
    return path


def brightness(frames) -> list[int]:
    return [int(round(np.median(f))) for f in frames]


def test_read_frames_video_and_folder(tmp_path):
    video = write_video(tmp_path / "spin.mp4", 12)
    frames = list(read_frames(video))
    assert len(frames) == 12 and all(f.dtype == np.uint8 and f.shape == (HEIGHT, WIDTH, 3) for f in frames)
    assert np.allclose(brightness(frames), [10 + 20 * i for i in range(12)], atol=5)  # mp4v is lossy
    assert np.allclose(brightness(read_frames(video, (3, 7))), [70, 90, 110, 130], atol=5)
    assert len(list(read_frames(video, (9, None)))) == 3
    folder = write_folder(tmp_path / "images", 12)
    frames = list(read_frames(folder, (1, None)))
    assert brightness(frames) == [10 + 20 * i for i in range(1, 12)]
    assert frames[0].shape == (HEIGHT, WIDTH)


def test_read_frames_16_bit_alpha_and_mixed_shapes(tmp_path):
    folder = tmp_path / "deep"
    folder.mkdir()
    cv2.imwrite(str(folder / "a.png"), np.full((4, 5), 0x1234, np.uint16))
    (deep,) = read_frames(folder)
    assert deep.dtype == np.uint8 and deep.shape == (4, 5) and deep[0, 0] == 0x12
    alpha = tmp_path / "alpha"
    alpha.mkdir()
    cv2.imwrite(str(alpha / "b.png"), np.full((4, 5, 4), 200, np.uint8))
    (bgr,) = read_frames(alpha)
    assert bgr.shape == (4, 5, 3) and bgr.dtype == np.uint8
    cv2.imwrite(str(folder / "b.png"), np.full((4, 5, 3), 200, np.uint8))
    with pytest.raises(RecordingError, match=r"b\.png .* shape \(4, 5, 3\), but the folder's first image has shape"):
        list(read_frames(folder))


def test_frame_errors(tmp_path):
    with pytest.raises(RecordingError, match="no video or image folder at"):
        read_frames(tmp_path / "missing.mp4")
    bad = write(tmp_path / "bad.mp4", "this is not a video")
    with pytest.raises(RecordingError, match=r"cannot open the video .*bad\.mp4"):
        read_frames(bad)
    empty = tmp_path / "empty"
    empty.mkdir()
    (empty / "readme.txt").write_text("no images here")
    with pytest.raises(RecordingError, match="holds no image files"):
        read_frames(empty)
    folder = write_folder(tmp_path / "images", 5)
    with pytest.raises(RecordingError, match=r"has 5 images \(frames 0 to 4\); the frame range 2:9 goes beyond"):
        read_frames(folder, (2, 9))
    video = write_video(tmp_path / "spin.mp4", 6)
    frames = read_frames(video, (4, 10))
    with pytest.raises(RecordingError, match=r"spin\.mp4 has 6 frames \(0 to 5\); the frame range 4:10 goes beyond"):
        list(frames)
    with pytest.raises(RecordingError, match="6 frames"):
        list(read_frames(video, (6, None)))
    with pytest.raises(InputError, match="empty"):
        read_frames(video, (3, 3))
    with pytest.raises(InputError, match="non-negative integer"):
        read_frames(video, (-1, 3))


# ---------------------------------------------------------------------------------------------- datasets
class FakeTracker:
    """Counts the frames it is given and returns known tracks (pixels along a small arc, frames 0..n-1)."""

    def __init__(self, n_tracks=(3,)):
        self.n_tracks = n_tracks  # per call, the last one repeated
        self.calls = []

    def __call__(self, frames, params=None):
        images = list(frames)
        self.calls.append((len(images), params, images[0].shape if images else None))
        n = len(images)
        n_tracks = self.n_tracks[min(len(self.calls) - 1, len(self.n_tracks) - 1)]
        angles = np.linspace(0.0, 1.0, n)
        return [Track(np.column_stack([30 + (5 + j) * np.cos(angles), 20 + (5 + j) * np.sin(angles)]), np.arange(n))
                for j in range(n_tracks)]


def recording(tmp_path: Path) -> list[Path]:
    return [write_video(tmp_path / "pose_a.mp4", 8), write_folder(tmp_path / "pose_b", 6),
            write_video(tmp_path / "pose_c.mp4", 10)]


def test_make_dataset_end_to_end(tmp_path, arm, camera):
    videos = recording(tmp_path)
    tracker = FakeTracker()
    dataset = make_dataset(videos, POSES, camera, arm, tracker=tracker, tracker_params={"max_corners": 5},
                           frame_ranges=[None, (1, 5), (2, None)], progress=False)
    assert [c[0] for c in tracker.calls] == [8, 4, 8]
    assert all(c[1] == {"max_corners": 5} for c in tracker.calls)
    assert [m.name for m in dataset] == ["pose_a.mp4", "pose_b", "pose_c.mp4"]
    for k in range(3):
        np.testing.assert_array_equal(dataset.joint_angles(k), POSES[k])
    assert dataset[0].n_tracks == 3
    assert dataset[1].frame_span() == (1, 4) and dataset[2].frame_span() == (2, 9)
    record = dataset.metadata["recording"]
    assert record["videos"] == [str(v) for v in videos]
    assert record["frame_ranges"] == [None, [1, 5], [2, None]]
    assert record["tracker"]["params"] == {"max_corners": 5}
    assert "tracker" not in dataset.metadata  # another tracker's tracks: no image axes' floor is claimed for them


def test_make_dataset_names_each_videos_spinning_joint(tmp_path, arm, camera):
    videos = recording(tmp_path)
    dataset = make_dataset(videos, POSES, camera, arm, tracker=FakeTracker(), progress=False,
                           spin_joints=["wrist", "elbow", None])
    assert [m.spin_joint for m in dataset] == [None, "elbow", None]  # (the arm's wrist joint is the default)
    with pytest.raises(InputError, match=r"measurement 2 \(pose_c.mp4\): spinning joint 'knee' is not"):
        make_dataset(videos, POSES, camera, arm, tracker=FakeTracker(), progress=False,
                     spin_joints=[None, "elbow", "knee"])
    with pytest.raises(InputError, match="2 spin joint"):
        make_dataset(videos, POSES, camera, arm, tracker=FakeTracker(), progress=False, spin_joints=[None, None])


def test_make_dataset_from_files_with_progress(tmp_path, arm, capsys):
    videos = recording(tmp_path)
    joints = write(tmp_path / "joints.csv", "shoulder,elbow,wrist\n" + "\n".join(
        ",".join(repr(float(v)) for v in np.degrees(q)) for q in POSES))
    camera_path = write(tmp_path / "camera_info.yaml", ROS_CAMERA_INFO)
    dataset = make_dataset(videos, joints, camera_path, arm, tracker=FakeTracker(), progress=True,
                           joint_options={"degrees": True})
    np.testing.assert_allclose([dataset.joint_angles(k) for k in range(3)], POSES, atol=1e-15)
    assert_camera(dataset.camera)
    assert dataset.metadata["recording"]["joints_file"] == str(joints)
    assert "videos" in capsys.readouterr().err  # the tqdm bar


def test_make_dataset_errors(tmp_path, arm, camera):
    videos = recording(tmp_path)
    with pytest.raises(RecordingError, match=r"measurement 1 \(pose_b\): the tracker found 1 track\(s\) in"):
        make_dataset(videos, POSES, camera, arm, tracker=FakeTracker(n_tracks=(3, 1)), progress=False)
    tracker = FakeTracker()
    with pytest.raises(RecordingError, match=r"cannot open the video .*broken\.mp4"):
        make_dataset(videos[:2] + [write(tmp_path / "broken.mp4", "x")], POSES, camera, arm, tracker=tracker,
                     progress=False)
    assert tracker.calls == []  # every video is checked before the first is tracked
    with pytest.raises(RecordingError, match=r"pose_b has 6 images .* range 0:7 goes beyond"):
        make_dataset(videos, POSES, camera, arm, tracker=tracker, frame_ranges=[None, (0, 7), None],
                     progress=False)
    with pytest.raises(RecordingError, match=r"pose_c\.mp4 has 10 frames .* range 5:11 goes beyond"):
        make_dataset(videos, POSES, camera, arm, tracker=FakeTracker(), frame_ranges=[None, None, (5, 11)],
                     progress=False)
    with pytest.raises(InputError, match=r"2 row\(s\) of joint angles for 3 video"):
        make_dataset(videos, POSES[:2], camera, arm, tracker=tracker, progress=False)
    with pytest.raises(InputError, match=r"measurement 2 \(pose_c.mp4\): expected 3 joint angles"):
        make_dataset(videos, [*POSES[:2], [1.0, 2.0]], camera, arm, tracker=tracker, progress=False)
    other = Camera(K, 640, 480)
    with pytest.raises(RecordingError, match="the frames are 64x48 pixels but the camera is 640x480"):
        make_dataset(videos, POSES, other, arm, tracker=FakeTracker(), progress=False)
    with pytest.raises(InputError, match="one per video"):
        make_dataset(videos, POSES, camera, arm, tracker=tracker, frame_ranges=[None], progress=False)
    # the same video twice: its spins must not overlap (nothing is tracked before the check)
    twice, tracker = [videos[0], videos[1], videos[0]], FakeTracker()
    with pytest.raises(InputError, match=r"measurement 0 \(pose_a.*\) and measurement 2 \(pose_a.*\) are the same "
                                         r"video .* overlapping frames \(frames 0: and frames 4:8\)"):
        make_dataset(twice, POSES, camera, arm, tracker=tracker, frame_ranges=[None, None, (4, 8)], progress=False)
    assert tracker.calls == []
    made = make_dataset(twice, POSES, camera, arm, tracker=FakeTracker(), frame_ranges=[(0, 4), None, (4, 8)],
                        progress=False)  # two spins of one video
    assert len(made) == 3


# ---------------------------------------------------------------------------------------------- command line
def track_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="gtsam-rotid")
    add_track_parser(parser.add_subparsers(dest="command"))
    return parser


@pytest.fixture
def fake_tracking_module(monkeypatch):
    """``gtsam_rotid.tracking`` replaced by a module whose ``track`` is a FakeTracker (and whose ``Tracker`` runs it
    and says it kept one corner track)."""
    module = types.ModuleType("gtsam_rotid.tracking")
    module.track = FakeTracker()
    module.Tracker = lambda params=None: types.SimpleNamespace(run=lambda frames: types.SimpleNamespace(
        tracks=module.track(frames, params=params), n_corner_tracks=1))
    monkeypatch.setitem(sys.modules, "gtsam_rotid.tracking", module)
    return module


def test_cli_track_writes_a_dataset(tmp_path, arm, fake_tracking_module, capsys):
    videos = recording(tmp_path)
    urdf = write(tmp_path / "arm.urdf", URDF_3_JOINTS)
    stamps, positions, held = joint_series(np.random.default_rng(5))
    joints = write_series_csv(tmp_path / "states.csv", stamps, positions, degrees=True)
    camera_path = write_opencv_camera(tmp_path / "camera.yaml")
    out = tmp_path / "dataset"
    argv = ["track", "--video", *map(str, videos), "--joints", str(joints), "--camera", str(camera_path),
            "--urdf", str(urdf), "--frames", ":", "1:5", "2:", "--degrees", "-o", str(out), "--no-progress"]
    args = track_parser().parse_args(argv)
    assert args.func is cmd_track
    assert cmd_track(args) == 0
    assert f"wrote {out}" in capsys.readouterr().out
    loaded = Dataset.load(out)
    assert len(loaded) == 3 and loaded.arm.joint_names == arm.joint_names
    assert_camera(loaded.camera)
    expected = expected_poses(positions, held)
    np.testing.assert_allclose([loaded.joint_angles(k) for k in range(3)], expected, rtol=0, atol=1e-12)
    assert loaded[1].frame_span() == (1, 4)
    assert loaded.metadata["recording"]["joint_options"]["degrees"] is True
    # the default tracker's tracks: the dataset states its features' errors (floor, track offsets) for calibrate
    assert loaded.metadata["tracker"] == {"features": "auto", "axis_floor_px": AXIS_FLOOR_PX["corners"],
                                          "track_offset_px": TRACK_OFFSET_PX["corners"], "corner_tracks": 3}
    with pytest.raises(DatasetExistsError, match="--overwrite"):
        cmd_track(args)
    assert cmd_track(track_parser().parse_args([*argv, "--overwrite"])) == 0


def test_cli_videos_dir_and_errors(tmp_path, fake_tracking_module):
    session = tmp_path / "session"
    session.mkdir()
    recording(session)
    (session / "joints.json").write_text(json.dumps(POSES.tolist()))  # neither a video nor an image folder
    urdf = write(tmp_path / "arm.urdf", URDF_3_JOINTS)
    camera_path = write(tmp_path / "camera_info.yaml", ROS_CAMERA_INFO)
    common = ["--joints", str(session / "joints.json"), "--camera", str(camera_path), "--urdf", str(urdf),
              "--no-progress"]
    args = track_parser().parse_args(["track", "--videos-dir", str(session), *common, "-o", str(tmp_path / "d")])
    assert cmd_track(args) == 0
    assert [m.name for m in Dataset.load(tmp_path / "d")] == ["pose_a.mp4", "pose_b", "pose_c.mp4"]
    args = track_parser().parse_args(["track", "--videos-dir", str(session), *common, "--spin-joints", "wrist",
                                      "elbow", "wrist", "-o", str(tmp_path / "s")])
    assert cmd_track(args) == 0
    assert [m.spin_joint for m in Dataset.load(tmp_path / "s")] == [None, "elbow", None]
    args = track_parser().parse_args(["track", "--videos-dir", str(session), *common, "--spin-joints", "elbow",
                                      "-o", str(tmp_path / "t")])
    with pytest.raises(InputError, match=r"1 --spin-joints for 3 video\(s\)"):
        cmd_track(args)
    args = track_parser().parse_args(["track", "--videos-dir", str(session), *common, "--frames", "1:2",
                                      "-o", str(tmp_path / "e")])
    with pytest.raises(InputError, match=r"1 --frames range\(s\) for 3 video"):
        cmd_track(args)
    args = track_parser().parse_args(["track", "--video", str(session / "pose_a.mp4"), *common,
                                      "-o", str(tmp_path / "f")])
    with pytest.raises(RotIdError, match=r"3 row\(s\) of joint angles .* 1 measurements"):
        cmd_track(args)
    with pytest.raises(SystemExit):  # --robot or --urdf is required
        track_parser().parse_args(["track", "--video", "a.mp4", "--joints", "j.csv", "--camera", "c.yaml",
                                   "-o", "out"])


def test_module_exports():
    for name in ("load_camera", "load_joints", "read_joint_file", "find_spins", "read_frames", "make_dataset",
                 "RecordingError"):
        assert hasattr(recordings, name)
    assert not hasattr(recordings, "cmd_track"), "the command line lives in gtsam_rotid.cli"
    assert issubclass(RecordingError, InputError)


def test_a_truncated_video_is_refused_not_tracked_on_half_its_frames(tmp_path):
    whole = tmp_path / "whole.avi"
    writer = cv2.VideoWriter(str(whole), cv2.VideoWriter_fourcc(*"MJPG"), 30, (64, 48))
    for i in range(60):
        writer.write(np.full((48, 64, 3), 4 * i, np.uint8))
    writer.release()
    assert len(list(read_frames(whole))) == 60
    cut = tmp_path / "cut.avi"  # its header still says 60 frames
    cut.write_bytes(whole.read_bytes()[:len(whole.read_bytes()) // 2])
    with pytest.raises(RecordingError, match=r"cut.avi reports 60 frames but only (\d+) decode: it is truncated") \
            as raised:
        list(read_frames(cut))
    n = int(re.search(r"only (\d+) decode", str(raised.value)).group(1))
    assert 0 < n < 54 and len(list(read_frames(cut, (0, n)))) == n  # the frames that decode, asked for explicitly


def test_a_joint_file_in_degrees_read_as_radians_is_refused_with_the_hint(tmp_path, arm):
    path = write(tmp_path / "degrees.csv", ",".join(arm.joint_names) + "\n30,60,-45\n10,-20,90\n")
    with pytest.raises(RecordingError, match=r"degrees.csv, measurement 0.*outside the model's limits.*read them as "
                                             r"degrees \(--degrees"):
        load_joints(path, arm, 2)
    np.testing.assert_allclose(load_joints(path, arm, 2, degrees=True)[0], np.radians([30, 60, -45]))

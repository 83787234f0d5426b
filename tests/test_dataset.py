"""Tests of gtsam_rotid.dataset: Track / Measurement / Dataset validation and the on-disk format."""

from __future__ import annotations

import json
import os
from importlib import resources
from pathlib import Path

import jsonschema
import numpy as np
import pytest
from urdf_arm import URDF_3_JOINTS

from gtsam_rotid import dataset as dataset_module
from gtsam_rotid.arm import Arm
from gtsam_rotid.camera import Camera
from gtsam_rotid.dataset import Dataset, Measurement, SpinReadings, Track
from gtsam_rotid.errors import (
    DatasetExistsError,
    DatasetNotFoundError,
    InputError,
    OutputError,
    RotIdError,
    ValidationError,
)


# ---------------------------------------------------------------------------------------------- fixtures
@pytest.fixture(scope="module")
def kinova() -> Arm:
    return Arm.from_robot("kinova")


@pytest.fixture(scope="module")
def urdf_arm() -> Arm:
    return Arm.from_urdf_string(URDF_3_JOINTS)


@pytest.fixture()
def camera() -> Camera:
    """640x480 with distortion, so the round trip covers the distortion coefficients too."""
    return Camera([[570.0, 0.0, 319.5], [0.0, 572.0, 239.5], [0.0, 0.0, 1.0]], 640, 480,
                  dist=[0.1, -0.05, 0.001, -0.002, 0.01])


def arc_pixels(centre_uv, radius_px: float, n: int, phase0: float = 0.0) -> np.ndarray:
    """(n, 2) pixels on a small circle arc: hand-made track data well inside a 640x480 image."""
    phase = phase0 + np.linspace(0.0, 1.5, n)
    return np.column_stack([centre_uv[0] + radius_px * np.cos(phase), centre_uv[1] + radius_px * np.sin(phase)])


def make_measurements(joint_names: list[str]) -> list[Measurement]:
    """Two measurements: a vector of angles with framed tracks, and a dict of angles with mixed tracks."""
    dof = len(joint_names)
    # non-round floats, to test exact storage; inside the Kinova's and the 3-joint URDF's limits
    angles_0 = np.linspace(0.6, 1.5, dof) + 1.0 / 3.0
    m0 = Measurement(
        angles_0,
        [
            Track(arc_pixels((320.1, 240.7), 30.0, 7), frames=np.arange(3, 10)),
            Track(arc_pixels((300.0, 200.0), 12.3, 5, 1.0), frames=[0, 2, 4, 5, 9]),
        ],
        name="pose A",
    )
    angles_1 = {name: 0.1 * (i + 1) + 0.95 for i, name in enumerate(joint_names)}
    m1 = Measurement(
        angles_1,
        [
            arc_pixels((100.0, 400.0), 20.0, 4),  # plain array: no frames
            Track(np.array([[-0.5, -0.5], [639.5, 479.5]])),  # the extreme valid pixels
            Track(arc_pixels((500.0, 50.0), 8.0, 6, 2.0), frames=np.arange(100, 106)),
        ],
    )
    return [m0, m1]


@pytest.fixture()
def kinova_dataset(kinova, camera) -> Dataset:
    metadata = {"operator": "test", "noise_var": 1.5, "tags": ["a", "b"], "nested": {"seed": 3, "x": None}}
    return Dataset(kinova, camera, make_measurements(kinova.joint_names), metadata=metadata)


def read_json(root: Path) -> dict:
    return json.loads((root / "dataset.json").read_text(encoding="utf-8"))


def write_json(root: Path, document) -> None:
    (root / "dataset.json").write_text(json.dumps(document), encoding="utf-8")


def snapshot(root: Path) -> dict[str, bytes]:
    """Every file under ``root`` (relative path -> bytes)."""
    return {str(p.relative_to(root)): p.read_bytes() for p in sorted(root.rglob("*")) if p.is_file()}


def leftovers(parent: Path) -> list[str]:
    """Hidden staging / old-copy directories left next to a saved dataset."""
    return [p.name for p in parent.iterdir() if p.name.startswith(".")]


# ---------------------------------------------------------------------------------------------- Track
def test_track_stores_read_only_float_and_int_copies():
    source = [[1, 2], [3, 4]]
    frames = np.array([5, 7], dtype=np.int32)
    track = Track(source, frames)
    assert track.pixels.dtype == np.float64 and track.frames.dtype == np.int64
    assert len(track) == 2 and track.has_frames
    frames[0] = 99
    assert track.frames[0] == 5, "the track must own a copy of its frames"
    with pytest.raises(ValueError):
        track.pixels[0, 0] = 10.0
    with pytest.raises(ValueError):
        track.frames[0] = 1
    assert "2 pixels" in repr(track) and "5..7" in repr(track)


def test_track_equality_compares_arrays_and_frames():
    pixels = np.array([[1.0, 2.0], [3.0, 4.0]])
    assert Track(pixels) == Track(pixels.copy())
    assert Track(pixels, [0, 1]) == Track(pixels, np.array([0.0, 1.0]))  # integer-valued floats accepted
    assert Track(pixels) != Track(pixels, [0, 1])
    assert Track(pixels, [0, 1]) != Track(pixels, [0, 2])
    assert Track(pixels) != Track(pixels + 1e-12)


@pytest.mark.parametrize(
    ("pixels", "frames", "expected"),
    [
        ([[1.0, 2.0], [np.nan, 3.0], [4.0, 5.0]], None, r"1 of 3 pixels are NaN or infinite \(first: pixel 1"),
        ([[1.0, 2.0], [3.0, np.inf]], None, r"NaN or infinite \(first: pixel 1 = \[3\.0, inf\]\)"),
        (np.zeros((4, 3)), None, r"shape \(N, 2\), got shape \(4, 3\)"),
        (np.zeros(6), None, r"shape \(N, 2\), got shape \(6,\)"),
        (np.zeros((0, 2)), None, r"empty \(0 pixels\)"),
        ([["a", "b"]], None, r"pixels must be real numbers"),
        ([[1.0, 2.0], [3.0]], None, r"ragged or non-numeric"),
        (np.zeros((3, 2)), [0, 2, 2], r"strictly increasing; frame 2 is 2 after frame 1 = 2"),
        (np.zeros((3, 2)), [5, 4, 6], r"strictly increasing; frame 1 is 4 after frame 0 = 5"),
        (np.zeros((3, 2)), [-1, 0, 1], r"frames must be >= 0; frame 0 is -1"),
        (np.zeros((3, 2)), [0, 1], r"frames must have shape \(3,\), one per pixel, got shape \(2,\)"),
        (np.zeros((3, 2)), [0.0, 1.5, 2.0], r"frames must be integers; frame 1 is 1\.5"),
        (np.zeros((2, 2)), [True, False], r"frames must be integers, got dtype bool"),
    ],
)
def test_track_validation_errors(pixels, frames, expected):
    with pytest.raises(ValidationError, match=expected) as info:
        Track(pixels, frames)
    assert info.value.measurement is None and info.value.track is None
    assert isinstance(info.value, InputError) and isinstance(info.value, ValueError)


def test_track_from_any_names_measurement_and_track():
    existing = Track([[1.0, 2.0]])
    assert Track.from_any(existing) is existing
    assert Track.from_any([[1.0, 2.0]], measurement=0, track=0) == existing
    with pytest.raises(ValidationError) as info:
        Track.from_any([[1.0, np.nan]], measurement=2, track=5)
    assert str(info.value).startswith("measurement 2, track 5: ")
    assert "NaN" in str(info.value)
    assert (info.value.measurement, info.value.track) == (2, 5)


# ---------------------------------------------------------------------------------------------- Measurement
def test_measurement_copies_joint_angles_and_converts_tracks():
    angles = [0.1, 0.2, 0.3]
    measurement = Measurement(angles, [np.zeros((2, 2)), Track([[1.0, 1.0]], [4])], name="m")
    angles[0] = 9.0
    assert isinstance(measurement.joint_angles, np.ndarray)
    assert measurement.joint_angles.dtype == np.float64
    np.testing.assert_array_equal(measurement.joint_angles, [0.1, 0.2, 0.3])
    assert all(isinstance(t, Track) for t in measurement.tracks)
    assert measurement.n_tracks == 2 and measurement.n_observations == 3
    assert measurement.frame_span() == (4, 4)

    named = {"a": 1, "b": np.float32(0.5)}
    from_dict = Measurement(named, [np.zeros((1, 2))])
    named["a"] = 7
    assert from_dict.joint_angles == {"a": 1.0, "b": 0.5}
    assert all(type(v) is float for v in from_dict.joint_angles.values())


def test_measurement_equality():
    tracks = [np.ones((2, 2))]
    assert Measurement([0.1, 0.2], tracks, name="x") == Measurement(np.array([0.1, 0.2]), tracks, name="x")
    assert Measurement([0.1, 0.2], tracks, name="x") != Measurement([0.1, 0.2], tracks, name="y")
    assert Measurement([0.1, 0.2], tracks) != Measurement({"a": 0.1, "b": 0.2}, tracks)
    assert Measurement([0.1, 0.2], tracks) != Measurement([0.1, 0.2], [np.ones((3, 2))])


def test_measurement_error_names_the_track():
    good = np.ones((3, 2))
    with pytest.raises(ValidationError) as info:
        Measurement([0.0], [good, good, np.ones((3, 3))])
    assert str(info.value).startswith("track 2: ")
    assert "shape (N, 2)" in str(info.value)
    assert info.value.track == 2


def test_measurement_nan_pixels_name_the_track():
    with pytest.raises(ValidationError, match=r"^track 1: 1 of 2 pixels are NaN"):
        Measurement([0.0], [np.ones((2, 2)), [[1.0, 1.0], [np.nan, np.nan]]])


@pytest.mark.parametrize(
    ("joint_angles", "tracks", "expected"),
    [
        ([0.0], [], r"at least one track"),
        ([0.0], np.ones((4, 2)), r"got a single ndarray; wrap it in a list"),
        ([0.0], Track([[1.0, 1.0]]), r"got a single Track; wrap it in a list"),
        ([], [np.ones((1, 2))], r"joint angles are empty"),
        ([[0.0, 1.0]], [np.ones((1, 2))], r"flat sequence of numbers, got shape \(1, 2\)"),
        ([0.0, np.nan], [np.ones((1, 2))], r"joint angle 1 is NaN or infinite"),
        ({"a": "fast"}, [np.ones((1, 2))], r"joint angle of 'a' must be a number"),
        ("0.1", [np.ones((1, 2))], r"sequence of numbers or a dict"),
    ],
)
def test_measurement_validation_errors(joint_angles, tracks, expected):
    with pytest.raises(ValidationError, match=expected):
        Measurement(joint_angles, tracks)


# ---------------------------------------------------------------------------------------------- Dataset
def test_dataset_accessors_and_summary(kinova_dataset, kinova):
    assert len(kinova_dataset) == 2
    assert list(kinova_dataset) == list(kinova_dataset.measurements)
    assert kinova_dataset.n_observations == 7 + 5 + 4 + 2 + 6
    # dict joint angles come back as a vector in the arm's joint order
    expected_1 = [0.1 * (i + 1) + 0.95 for i in range(kinova.dof)]
    np.testing.assert_array_equal(kinova_dataset.joint_angles(1), expected_1)
    vector = kinova_dataset.joint_angles(0)
    vector[0] = 100.0
    assert kinova_dataset.joint_angles(0)[0] != 100.0, "joint_angles(k) must return a copy"
    with pytest.raises(IndexError, match="measurement index 2 out of range for 2"):
        kinova_dataset.joint_angles(2)
    summary = kinova_dataset.summary()
    assert "kinova" in summary and "640x480" in summary
    assert "measurement 0 'pose A': 2 tracks, 12 points, frames 0..9" in summary
    assert "measurement 1: 3 tracks, 12 points, frames 100..105 (2 tracks without frame indices)" in summary


def test_dataset_rejects_pixel_outside_image(kinova, camera):
    inside = make_measurements(kinova.joint_names)
    bad = Measurement(inside[0].joint_angles, [np.ones((2, 2)), [[10.0, 10.0], [10.0, 480.0], [700.0, 5.0]]])
    with pytest.raises(ValidationError) as info:
        Dataset(kinova, camera, [*inside, bad])
    message = str(info.value)
    assert message.startswith("measurement 2, track 1: ")
    assert "pixel 1 (u=10, v=480)" in message and "640x480 image" in message
    assert "2 of 3 pixels" in message
    assert (info.value.measurement, info.value.track) == (2, 1)


def test_dataset_rejects_wrong_joint_angle_count(kinova, camera):
    measurements = make_measurements(kinova.joint_names)
    measurements[1] = Measurement([0.0] * 5, [np.ones((2, 2))])
    with pytest.raises(ValidationError) as info:
        Dataset(kinova, camera, measurements)
    assert str(info.value).startswith("measurement 1: ")
    assert "expected 6 joint angles" in str(info.value) and "got 5" in str(info.value)
    assert info.value.measurement == 1 and info.value.track is None


def test_dataset_rejects_unknown_joint_name(kinova, camera):
    angles = {name: 0.0 for name in kinova.joint_names}
    angles["gripper_finger"] = 0.3
    with pytest.raises(ValidationError) as info:
        Dataset(kinova, camera, [Measurement(angles, [np.ones((2, 2))])])
    assert str(info.value).startswith("measurement 0: ")
    assert "unknown joint name" in str(info.value) and "gripper_finger" in str(info.value)


def test_dataset_rejects_missing_joint_name(urdf_arm, camera):
    with pytest.raises(ValidationError, match=r"^measurement 0: .*missing for \['wrist'\]"):
        Dataset(urdf_arm, camera, [Measurement({"shoulder": 0.0, "elbow": 0.1}, [np.ones((2, 2))])])


def test_dataset_needs_measurements_and_json_metadata(kinova, camera):
    with pytest.raises(ValidationError, match="at least one measurement"):
        Dataset(kinova, camera, [])
    measurements = make_measurements(kinova.joint_names)
    with pytest.raises(ValidationError, match="JSON-serialisable"):
        Dataset(kinova, camera, measurements, metadata={"when": object()})
    with pytest.raises(ValidationError, match="JSON-serialisable"):
        Dataset(kinova, camera, measurements, metadata={"sigma": float("nan")})
    with pytest.raises(ValidationError, match="^measurement 1: expected a Measurement"):
        Dataset(kinova, camera, [measurements[0], np.ones((2, 2))])


# ---------------------------------------------------------------------------------------------- round trips
def test_round_trip_kinova_is_exact(kinova_dataset, tmp_path):
    root = kinova_dataset.save(tmp_path / "session")
    assert root == tmp_path / "session"
    assert sorted(os.listdir(root)) == ["dataset.json", "tracks.npz"]
    assert leftovers(tmp_path) == []
    document = read_json(root)
    assert document["format"] == "gtsam_rotid.dataset" and document["version"] == 1  # (no spin_joint: version 1)
    assert document["arm"]["robot"] == "kinova"
    assert document["measurements"][0]["tracks"][0] == {"pixels": "m0_t0_pixels", "frames": "m0_t0_frames", "n": 7}
    assert document["measurements"][1]["tracks"][0]["frames"] is None

    loaded = Dataset.load(root)
    assert loaded == kinova_dataset
    assert loaded.metadata == kinova_dataset.metadata
    for original, copy in zip(kinova_dataset, loaded, strict=True):
        for t_original, t_copy in zip(original.tracks, copy.tracks, strict=True):
            assert t_copy.pixels.tobytes() == t_original.pixels.tobytes()  # bit-exact
    assert isinstance(loaded[1].joint_angles, dict)
    assert loaded[0].name == "pose A" and loaded[1].name is None
    assert loaded.camera.dist is not None
    np.testing.assert_array_equal(loaded.joint_angles(0), kinova_dataset.joint_angles(0))
    assert Dataset.load(root / "dataset.json") == kinova_dataset  # the JSON file's path works too


def test_round_trip_urdf_arm_is_exact(urdf_arm, camera, tmp_path):
    assert urdf_arm.joint_names == ["shoulder", "elbow", "wrist"]
    dataset = Dataset(urdf_arm, camera, make_measurements(urdf_arm.joint_names), metadata={"arm": "tri"})
    root = dataset.save(tmp_path / "urdf_session")
    assert sorted(os.listdir(root)) == ["arm.urdf", "dataset.json", "tracks.npz"]
    assert (root / "arm.urdf").read_bytes() == URDF_3_JOINTS.encode("utf-8")
    arm_json = read_json(root)["arm"]
    assert arm_json["urdf_file"] == "arm.urdf" and "urdf_xml" not in arm_json
    assert arm_json["joint_names"] == ["shoulder", "elbow", "wrist"]

    loaded = Dataset.load(root)
    assert loaded == dataset
    assert loaded.arm.to_dict() == urdf_arm.to_dict()
    assert loaded.arm.wrist_joint == "wrist"


def test_dataset_equality_detects_differences(kinova_dataset, kinova, camera):
    same = Dataset(kinova, camera, make_measurements(kinova.joint_names), metadata=dict(kinova_dataset.metadata))
    assert same == kinova_dataset
    other_meta = Dataset(kinova, camera, make_measurements(kinova.joint_names), metadata={"operator": "x"})
    assert other_meta != kinova_dataset
    other_camera = Dataset(kinova, Camera.xtion(), make_measurements(kinova.joint_names),
                           metadata=dict(kinova_dataset.metadata))
    assert other_camera != kinova_dataset


def test_metadata_changed_after_construction_is_saved(kinova_dataset, tmp_path):
    kinova_dataset.metadata["scene"] = "single-crossing"
    kinova_dataset.metadata["sigma"] = np.float32(0.5)  # numpy scalars are written as plain numbers
    loaded = Dataset.load(kinova_dataset.save(tmp_path / "d"))
    assert loaded.metadata["scene"] == "single-crossing" and loaded.metadata["sigma"] == 0.5
    assert loaded == kinova_dataset


# ---------------------------------------------------------------------------------------------- saving safely
def test_refuses_to_overwrite_and_leaves_existing_data_unchanged(kinova_dataset, urdf_arm, camera, tmp_path):
    root = kinova_dataset.save(tmp_path / "d")
    before = snapshot(root)
    other = Dataset(urdf_arm, camera, make_measurements(urdf_arm.joint_names))
    with pytest.raises(DatasetExistsError, match="already exists.*overwrite=True") as info:
        other.save(root)
    assert isinstance(info.value, FileExistsError) and isinstance(info.value, RotIdError)
    assert snapshot(root) == before
    assert leftovers(tmp_path) == []
    assert Dataset.load(root) == kinova_dataset


def test_overwrite_replaces_a_dataset(kinova_dataset, urdf_arm, camera, tmp_path):
    root = kinova_dataset.save(tmp_path / "d")
    (root / "truth.json").write_text("{}", encoding="utf-8")  # extra file inside a dataset: replaced too
    other = Dataset(urdf_arm, camera, make_measurements(urdf_arm.joint_names), metadata={"v": 2})
    other.save(root, overwrite=True)
    assert sorted(os.listdir(root)) == ["arm.urdf", "dataset.json", "tracks.npz"]
    assert Dataset.load(root) == other
    assert leftovers(tmp_path) == []


def test_failed_write_keeps_the_old_dataset(kinova_dataset, urdf_arm, camera, tmp_path, monkeypatch):
    root = kinova_dataset.save(tmp_path / "d")
    before = snapshot(root)

    def crash(*args, **kwargs):
        raise OSError("disk full")

    monkeypatch.setattr(dataset_module.np, "savez_compressed", crash)
    other = Dataset(urdf_arm, camera, make_measurements(urdf_arm.joint_names))
    with pytest.raises(OutputError, match=f"cannot write the dataset {root}: disk full"):
        other.save(root, overwrite=True)
    assert snapshot(root) == before
    assert leftovers(tmp_path) == [], "the staging directory must be removed"
    with pytest.raises(OutputError, match="cannot write the dataset .*new: disk full"):
        other.save(tmp_path / "new")
    assert not (tmp_path / "new").exists()
    assert leftovers(tmp_path) == []


@pytest.mark.parametrize("overwrite", [False, True])
def test_refuses_to_replace_a_directory_that_is_not_a_dataset(kinova_dataset, tmp_path, overwrite):
    folder = tmp_path / "photos"
    folder.mkdir()
    (folder / "holiday.jpg").write_bytes(b"\xff\xd8 precious")
    (folder / "dataset.json").write_text('{"format": "someone-else"}', encoding="utf-8")
    before = snapshot(folder)
    with pytest.raises(DatasetExistsError, match="is not a gtsam_rotid dataset.*even with overwrite=True"):
        kinova_dataset.save(folder, overwrite=overwrite)
    assert snapshot(folder) == before
    assert leftovers(tmp_path) == []


@pytest.mark.parametrize("overwrite", [False, True])
def test_refuses_to_replace_a_file(kinova_dataset, tmp_path, overwrite):
    path = tmp_path / "notes.txt"
    path.write_text("keep me", encoding="utf-8")
    with pytest.raises(DatasetExistsError, match="is a file"):
        kinova_dataset.save(path, overwrite=overwrite)
    assert path.read_text(encoding="utf-8") == "keep me"


def test_save_creates_missing_parent_directories(kinova_dataset, tmp_path):
    root = kinova_dataset.save(tmp_path / "a" / "b" / "d")
    assert Dataset.load(root) == kinova_dataset


# ---------------------------------------------------------------------------------------------- loading errors
@pytest.fixture()
def saved(kinova_dataset, tmp_path) -> Path:
    return kinova_dataset.save(tmp_path / "d")


def test_load_missing_directory(tmp_path):
    with pytest.raises(DatasetNotFoundError, match="does not exist") as info:
        Dataset.load(tmp_path / "nowhere")
    assert isinstance(info.value, FileNotFoundError) and isinstance(info.value, RotIdError)


@pytest.mark.parametrize("name", ["dataset.json", "tracks.npz"])
def test_load_missing_file(saved, name):
    (saved / name).unlink()
    with pytest.raises(DatasetNotFoundError, match=f"{name} is missing"):
        Dataset.load(saved)


def test_load_missing_urdf(urdf_arm, camera, tmp_path):
    root = Dataset(urdf_arm, camera, make_measurements(urdf_arm.joint_names)).save(tmp_path / "d")
    (root / "arm.urdf").unlink()
    with pytest.raises(DatasetNotFoundError, match="URDF arm.urdf is missing"):
        Dataset.load(root)


def test_load_corrupted_json(saved):
    text = (saved / "dataset.json").read_text(encoding="utf-8")
    (saved / "dataset.json").write_text(text[: len(text) // 2], encoding="utf-8")
    with pytest.raises(ValidationError, match=r"is not valid JSON: .*\(line \d+, column \d+\)"):
        Dataset.load(saved)


def test_load_rejects_nan_in_json(saved):
    document = read_json(saved)
    text = json.dumps(document).replace('"noise_var": 1.5', '"noise_var": NaN')
    assert "NaN" in text
    (saved / "dataset.json").write_text(text, encoding="utf-8")
    with pytest.raises(ValidationError, match="NaN is not valid JSON"):
        Dataset.load(saved)


def test_load_schema_violation_names_path_measurement_and_track(saved):
    document = read_json(saved)
    document["measurements"][1]["tracks"][2]["n"] = "six"
    write_json(saved, document)
    with pytest.raises(ValidationError) as info:
        Dataset.load(saved)
    message = str(info.value)
    assert message.startswith("measurement 1, track 2: ")
    assert "$.measurements[1].tracks[2].n" in message and "'six' is not of type 'integer'" in message
    assert (info.value.measurement, info.value.track) == (1, 2)


def test_load_schema_violation_missing_top_level_field(saved):
    document = read_json(saved)
    del document["camera"]
    write_json(saved, document)
    with pytest.raises(ValidationError, match=r"schema at \$: 'camera' is a required property"):
        Dataset.load(saved)


def test_load_rejects_urdf_file_outside_the_dataset(urdf_arm, camera, tmp_path):
    root = Dataset(urdf_arm, camera, make_measurements(urdf_arm.joint_names)).save(tmp_path / "d")
    document = read_json(root)
    document["arm"]["urdf_file"] = "../elsewhere.urdf"
    write_json(root, document)
    with pytest.raises(ValidationError, match=r"\$\.arm\.urdf_file"):
        Dataset.load(root)


def test_load_newer_version(saved):
    document = read_json(saved)
    document["version"] = 3
    document["something_new"] = {"x": 1}  # a future layout must not hide behind a schema error
    write_json(saved, document)
    with pytest.raises(ValidationError,
                       match=r"dataset format version 3 is newer than this gtsam_rotid supports \(2\)"):
        Dataset.load(saved)


def test_load_wrong_format_marker(saved):
    document = read_json(saved)
    document["format"] = "my.format"
    write_json(saved, document)
    with pytest.raises(ValidationError, match="not a gtsam_rotid dataset: its \"format\" is 'my.format'"):
        Dataset.load(saved)


def rewrite_npz(root: Path, change) -> None:
    with np.load(root / "tracks.npz") as npz:
        arrays = {key: npz[key] for key in npz.files}
    change(arrays)
    np.savez(root / "tracks.npz", **arrays)


def test_load_missing_npz_key(saved):
    rewrite_npz(saved, lambda arrays: arrays.pop("m1_t2_frames"))
    with pytest.raises(ValidationError) as info:
        Dataset.load(saved)
    assert str(info.value).startswith("measurement 1, track 2: ")
    assert "'m1_t2_frames'" in str(info.value) and "missing from tracks.npz" in str(info.value)


def test_load_wrong_array_shape(saved):
    def truncate(arrays):
        arrays["m0_t1_pixels"] = arrays["m0_t1_pixels"][:3]

    rewrite_npz(saved, truncate)
    with pytest.raises(ValidationError) as info:
        Dataset.load(saved)
    assert str(info.value).startswith("measurement 0, track 1: ")
    assert "shape (3, 2), expected (5, 2)" in str(info.value)


def test_load_invalid_track_data_names_measurement_and_track(saved):
    def break_frames(arrays):
        arrays["m1_t2_frames"] = arrays["m1_t2_frames"][::-1].copy()

    rewrite_npz(saved, break_frames)
    with pytest.raises(ValidationError, match=r"^measurement 1, track 2: frames must be strictly increasing"):
        Dataset.load(saved)


def test_load_track_count_mismatch(saved):
    document = read_json(saved)
    del document["measurements"][0]["tracks"][1]  # the npz still holds m0_t1_*
    write_json(saved, document)
    with pytest.raises(ValidationError) as info:
        Dataset.load(saved)
    message = str(info.value)
    assert message.startswith("measurement 0, track 1: ")
    assert "track count mismatch" in message and "lists 1 tracks" in message


def test_load_corrupted_npz(saved):
    (saved / "tracks.npz").write_bytes(b"PK\x03\x04 not really a zip file")
    with pytest.raises(ValidationError, match="tracks.npz"):
        Dataset.load(saved)


def test_load_joint_names_mismatch(saved):
    document = read_json(saved)
    document["arm"]["joint_names"][0] = "renamed_joint"
    write_json(saved, document)
    with pytest.raises(ValidationError, match="differ from the joint_names stored"):
        Dataset.load(saved)


def test_load_pixel_outside_image_names_measurement(saved):
    document = read_json(saved)
    document["camera"]["width"] = 320  # the saved tracks reach u = 639.5
    write_json(saved, document)
    with pytest.raises(ValidationError, match=r"^measurement 0, track 0: pixel .* outside the 320x480 image"):
        Dataset.load(saved)


# ---------------------------------------------------------------------------------------------- schema
def test_schema_is_valid_draft_2020_12_and_matches_saved_files(saved):
    schemas = {version: json.loads((resources.files("gtsam_rotid") / "schemas" / f"dataset-v{version}.schema.json"
                                    ).read_text(encoding="utf-8")) for version in (1, 2)}
    for schema in schemas.values():
        assert schema["$schema"] == "https://json-schema.org/draft/2020-12/schema"
        jsonschema.Draft202012Validator.check_schema(schema)
    document = read_json(saved)  # no spin joints: a version-1 file
    assert list(jsonschema.Draft202012Validator(schemas[1]).iter_errors(document)) == []
    document["version"] = 2
    document["measurements"][0]["spin_joint"] = "j2s6s200_joint_5"
    assert list(jsonschema.Draft202012Validator(schemas[2]).iter_errors(document)) == []


def test_load_schema_violation_in_arm_is_short_and_clear(saved):
    document = read_json(saved)
    document["arm"]["urdf_xml"] = "<robot>" * 500  # both an example-robot-data name and a URDF
    write_json(saved, document)
    with pytest.raises(ValidationError, match=r"schema at \$\.arm: .*is valid under each of") as info:
        Dataset.load(saved)
    assert len(str(info.value)) < 400, "the offending instance must be abbreviated in the message"


def test_refuses_to_replace_a_symbolic_link(kinova_dataset, tmp_path):
    real = kinova_dataset.save(tmp_path / "real")
    before = snapshot(real)
    link = tmp_path / "link"
    link.symlink_to(real, target_is_directory=True)
    with pytest.raises(DatasetExistsError, match="symbolic link"):
        kinova_dataset.save(link, overwrite=True)
    assert link.is_symlink() and snapshot(real) == before


def test_joint_angles_outside_the_models_limits_are_refused_with_a_hint(kinova, camera):
    """A joint CSV in degrees read as radians, or another robot's angles: refused by name (a bounded joint beyond
    its limits by more than a degree); continuous joints wrap and are never refused."""
    good = make_measurements(kinova.joint_names)
    q = np.array(good[0].joint_angles)
    degrees = Measurement(np.degrees(q), good[0].tracks)
    with pytest.raises(ValidationError, match=r"measurement 0: joint angle\(s\) outside the model's limits: "
                                              r"j2s6s200_joint_2 = .* read them as degrees"):
        Dataset(kinova, camera, [degrees, good[1]])
    beyond = q.copy()
    beyond[1] = kinova.upper_limits[1] + np.radians(3.0)
    with pytest.raises(ValidationError, match="j2s6s200_joint_2 .* right robot model"):
        Dataset(kinova, camera, [Measurement(beyond, good[0].tracks), good[1]])
    slightly = q.copy()
    slightly[1] = kinova.upper_limits[1] + np.radians(0.5)  # within the tolerance of a reading
    wrapped = slightly.copy()
    wrapped[0] += 4 * np.pi  # a continuous joint
    assert len(Dataset(kinova, camera, [Measurement(wrapped, good[0].tracks), good[1]])) == 2


def test_frame_indices_that_are_time_stamps_are_refused():
    with pytest.raises(ValidationError, match="span 66666666 frames .* time stamps"):
        Track(np.zeros((3, 2)), np.array([1_700_000_000_000_000_000, 1_700_000_000_033_333_333,
                                          1_700_000_000_066_666_666]))


def test_a_dataset_directory_with_the_users_files_is_never_replaced(kinova, camera, tmp_path):
    folder = tmp_path / "ds"
    dataset = Dataset(kinova, camera, make_measurements(kinova.joint_names))
    dataset.save(folder)
    (folder / "truth.json").write_text("{}")  # the simulator's: part of a dataset directory
    dataset.save(folder, overwrite=True)
    (folder / "notes.txt").write_text("mine")
    with pytest.raises(DatasetExistsError, match=r"holds files that are not part of the dataset \(notes.txt\)"):
        dataset.save(folder, overwrite=True)
    assert (folder / "notes.txt").read_text() == "mine" and (folder / "dataset.json").is_file()


# ---------------------------------------------------------------------------------------------- spin readings
def spin_readings(n_frames: int = 12) -> SpinReadings:
    times = np.linspace(-0.2, 1.0, 61) + 1e-3 / 7
    return SpinReadings(np.arange(n_frames) / 15.0 + 1.0 / 9.0, times, 0.5 * times + 1.0 / 3.0)


def test_spin_readings_round_trip_in_version_2(kinova, camera, tmp_path):
    """A measurement's spin readings (synced mode) are saved as three arrays and read back exactly; the file is
    then version 2 (older readers refuse it by the schema rather than drop the readings)."""
    measurements = make_measurements(kinova.joint_names)
    m0 = measurements[0]
    synced = Measurement(m0.joint_angles, m0.tracks, name=m0.name, spin_readings=spin_readings())
    dataset = Dataset(kinova, camera, [synced, measurements[1]])
    root = dataset.save(tmp_path / "synced")
    document = read_json(root)
    assert document["version"] == 2
    assert document["measurements"][0]["spin_readings"] == {
        "frame_times": "m0_spin_frame_times", "times": "m0_spin_times", "angles": "m0_spin_angles"}
    assert "spin_readings" not in document["measurements"][1]
    loaded = Dataset.load(root)
    assert loaded == dataset
    np.testing.assert_array_equal(loaded.measurements[0].spin_readings.angles, synced.spin_readings.angles)
    assert loaded.measurements[1].spin_readings is None
    # a named camera clock (one offset per clock in the calibration) is kept, and is part of equality
    r = spin_readings()
    clocked = Dataset(kinova, camera, [synced.replace(spin_readings=SpinReadings(r.frame_times, r.times, r.angles,
                                                                               clock="video 3")), measurements[1]])
    assert clocked != dataset
    root = clocked.save(tmp_path / "clocked")
    assert read_json(root)["measurements"][0]["spin_readings"]["clock"] == "video 3"
    assert Dataset.load(root).measurements[0].spin_readings.clock == "video 3" and Dataset.load(root) == clocked


def test_spin_readings_are_checked_with_words_that_name_the_problem(kinova):
    tracks = make_measurements(kinova.joint_names)[0].tracks
    angles = np.zeros(len(kinova.joint_names))
    with pytest.raises(ValidationError, match=r"track 0: frame 9 has no time in the spin readings' frame_times "
                                              r"\(8 frames\)"):
        Measurement(angles, tracks, spin_readings=spin_readings(8))
    with pytest.raises(ValidationError, match="track 0: spin readings need every track's frame indices"):
        Measurement(angles, [arc_pixels((300.0, 200.0), 10.0, 6)], spin_readings=spin_readings())
    with pytest.raises(ValidationError, match=r"times must be strictly increasing: times\[2\] = 0.1 s follows 0.1 s"):
        SpinReadings([0.0], [0.0, 0.1, 0.1], [0.0, 1.0, 2.0])
    with pytest.raises(ValidationError, match=r"frame_times must never decrease: frame_times\[2\] = 0.05 s follows"):
        SpinReadings([0.0, 0.1, 0.05], [0.0, 0.1], [0.0, 1.0])
    SpinReadings([0.0, 0.1, 0.1], [0.0, 0.1], [0.0, 1.0])  # two images may share a stamp
    with pytest.raises(ValidationError, match="one angle per time, got 2 angles for 3 times"):
        SpinReadings([0.0], [0.0, 0.1, 0.2], [0.0, 1.0])
    with pytest.raises(ValidationError, match=r"angles\[1\] is not finite"):
        SpinReadings([0.0], [0.0, 0.1], [0.0, np.nan])
    with pytest.raises(ValidationError, match="clock must be a non-empty string or None, got 3"):
        SpinReadings([0.0], [0.0, 0.1], [0.0, 1.0], clock=3)
    with pytest.raises(ValidationError, match="spin_readings must be SpinReadings or None, got dict"):
        Measurement(angles, tracks, spin_readings={"times": [0.0]})


def test_a_measurement_changed_keeps_everything_else(kinova):
    m = make_measurements(kinova.joint_names)[0]
    synced = m.replace(spin_readings=spin_readings())
    moved = synced.replace(joint_angles=np.asarray(m.joint_angles) + 0.1)
    assert moved.spin_readings == synced.spin_readings and moved.tracks == m.tracks and moved.name == "pose A"
    np.testing.assert_allclose(moved.joint_angles, np.asarray(m.joint_angles) + 0.1)
    assert moved.replace(spin_readings=None).spin_readings is None
    with pytest.raises(ValidationError, match=r"no field\(s\) \['readings'\]"):
        m.replace(readings=None)

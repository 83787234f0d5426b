"""gtsam_rotid.bags and bagdataset: ROS 1, ROS 2 sqlite3 and mcap bags written by rosbags' own writers are read back
(topics found, joint states in the model's order, CameraInfo, every image encoding), the camera-to-joint-state time
offset is recovered, a dataset tracked from a bag calibrates within its covariance, and bad bags get errors that
name the bag, the topic and what to do."""

from __future__ import annotations

import argparse

import cv2
import numpy as np
import pytest
from bag_scene import FPS, scene, timeline, write_bag

from gtsam_rotid.arm import Arm
from gtsam_rotid.bagdataset import dataset_from_bag
from gtsam_rotid.bags import Bag, BagError, decode_image, estimate_time_offset
from gtsam_rotid.cli import add_track_parser, cmd_track, main
from gtsam_rotid.dataset import Dataset
from gtsam_rotid.errors import InputError
from gtsam_rotid.estimate import calibrate
from gtsam_rotid.overlays import busiest_frame, recorded_frames

OFFSET_S = 0.137  # the camera clock runs ahead of the joint-state clock
CHI2_6_999 = 22.458


@pytest.fixture(scope="module")
def rendered():
    return scene(n_poses=6, duration=4.0)


@pytest.fixture(scope="module")
def bags(rendered, tmp_path_factory):
    """One bag per storage, each with another image encoding."""
    dataset, _, spins = rendered
    root = tmp_path_factory.mktemp("bags")
    return {storage: write_bag(root / storage, storage, dataset, spins, offset_s=OFFSET_S, encoding=encoding)
            for storage, encoding in (("ros1", "mono8"), ("sqlite3", "rgb8"), ("mcap", "png"))}


@pytest.mark.parametrize("storage", ["ros1", "sqlite3", "mcap"])
def test_a_bag_is_read_back_as_written(rendered, bags, storage):
    dataset, _, spins = rendered
    joint_t, joint_q, images = timeline(dataset, spins, OFFSET_S)
    with Bag(bags[storage]) as bag:
        topics = bag.choose_topics()
        assert (topics.image, topics.joints, topics.camera_info) == (
            "/camera/image_raw", "/joint_states", "/camera/camera_info")
        stamps, positions = bag.joint_states(topics.joints, dataset.arm.joint_names)  # the gripper left out
        assert set(np.round(stamps, 6)) == set(np.round(joint_t, 6))  # (equal stamps are one state)
        truth = np.stack([np.interp(stamps, joint_t, joint_q[:, j]) for j in range(joint_q.shape[1])], axis=1)
        np.testing.assert_allclose(positions, truth, atol=1e-9)
        camera = bag.camera(topics.camera_info)
        np.testing.assert_allclose(camera.K, dataset.camera.K)
        assert (camera.width, camera.height) == (dataset.camera.width, dataset.camera.height)
        bag.image_motion(topics.image)  # after which only the stretch asked for is read
        read = list(bag.images(topics.image, 40, 45))
        assert [i for i, _, _ in read] == list(range(40, 46))
        for (_, stamp, image), (t, k, i) in zip(read, images[40:46], strict=True):
            assert stamp == pytest.approx(t, abs=1e-9)
            grey = image if image.ndim == 2 else image[..., 0]
            if image.ndim == 3:  # rgb8 comes back as BGR: the three channels of a grey picture agree
                np.testing.assert_array_equal(image[..., 0], image[..., 2])
            np.testing.assert_array_equal(grey, spins[k].frame(i))


@pytest.mark.parametrize("encoding", ["bgr8", "mono16", "jpeg"])
def test_other_image_encodings_decode_to_the_same_picture(rendered, tmp_path, encoding):
    dataset, _, spins = rendered
    path = write_bag(tmp_path / "b", "ros1", dataset, spins[:1], encoding=encoding)
    with Bag(path) as bag:
        _, _, image = next(bag.images("/camera/image_raw"))
    grey = image if image.ndim == 2 else cv2.cvtColor(image, cv2.COLOR_BGR2GRAY)
    difference = np.abs(grey.astype(float) - spins[0].frame(0))
    assert difference.max() <= 0 if encoding != "jpeg" else difference.mean() < 2.0


@pytest.mark.parametrize("offset_s", [0.137, -0.25, 0.0])
def test_the_time_offset_is_recovered_to_a_tenth_of_a_frame(rendered, tmp_path, offset_s):
    dataset, _, spins = rendered
    path = write_bag(tmp_path / "b", "ros1", dataset, spins, offset_s=offset_s)
    with Bag(path) as bag:
        stamps, positions = bag.joint_states("/joint_states", dataset.arm.joint_names)
        image_stamps, motion = bag.image_motion("/camera/image_raw")
    offset, correlation, rival = estimate_time_offset(image_stamps, motion, stamps, positions)
    assert abs(offset - offset_s) < 0.1 / FPS, offset
    assert correlation > 0.8 and rival is None


def test_a_dataset_from_a_bag_calibrates_within_its_covariance(rendered, bags):
    dataset, truth, _ = rendered
    made = dataset_from_bag(bags["ros1"], dataset.arm, progress=False)
    assert len(made) == len(dataset)
    for ours, theirs in zip(made, dataset, strict=True):
        np.testing.assert_allclose(ours.joint_angles, theirs.joint_angles, atol=1e-9)  # the wrist at its spin's start
        assert len(ours.tracks) >= 4
    recording = made.metadata["recording"]
    assert recording["time_offset_applied"] and abs(recording["time_offset_s"] - OFFSET_S) < 0.1 / FPS
    assert recording["camera_from"] == "/camera/camera_info" and len(recording["spans"]) == len(dataset)
    assert "axis_floor_px" in made.metadata["tracker"]  # the default tracker states its floor (dots: none)
    for ours, span in zip(made, recording["spans"], strict=True):  # each spin's joint states, for synced mode
        readings = ours.spin_readings
        assert readings.times[0] <= span[0] and readings.times[-1] >= span[1]
        seen = readings.frame_times[np.concatenate([t.frames for t in ours.tracks])]
        assert readings.times[0] < seen.min() and seen.max() < readings.times[-1]
    result = calibrate(made)
    assert result.synced == tuple(range(len(made)))  # (steady spins: the offset left is its prior's, about 0)
    assert abs(result.time_offset_s) < 3 * result.time_offset_sigma_s
    error = result.error_to(truth.arm_T_camera)
    assert result.covariance_usable
    assert float(error @ np.linalg.solve(result.covariance, error)) < CHI2_6_999
    assert np.linalg.norm(error[3:]) < 1e-3


def test_a_bag_without_the_topics_or_joints_it_needs_is_refused_by_name(rendered, tmp_path):
    dataset, _, spins = rendered
    with pytest.raises(BagError, match="no bag at"):
        Bag(tmp_path / "missing.bag")
    (tmp_path / "text.bag").write_text("not a bag")
    with pytest.raises(BagError, match="cannot read the bag .*text.bag"):
        Bag(tmp_path / "text.bag")
    path = write_bag(tmp_path / "two", "ros1", dataset, spins[:2], camera_info=False)
    with Bag(path) as bag:
        with pytest.raises(BagError, match="no topic '/cam' .*--image-topic"):
            bag.choose_topics(image="/cam")
        with pytest.raises(BagError, match="--joint-topic /camera/image_raw .* carries sensor_msgs/msg/Image"):
            bag.choose_topics(joints="/camera/image_raw")
        assert bag.choose_topics().camera_info is None
        other = Arm.from_robot("ur5")
        with pytest.raises(BagError, match="never names the model's joint.*shoulder_pan_joint.*right robot model"):
            bag.joint_states("/joint_states", other.joint_names)
    with pytest.raises(BagError, match="no CameraInfo topic: give the camera"):
        dataset_from_bag(path, dataset.arm, progress=False)
    second = write_bag(tmp_path / "second", "ros1", dataset, spins[:1], image_topic="/other/image")
    merged = tmp_path / "merged.bag"  # two image topics: a choice is needed
    _merge([path, second], merged)
    with Bag(merged) as bag, pytest.raises(BagError, match="several image topics .*choose one with --image-topic"):
        bag.choose_topics()


def _merge(paths, out):
    from rosbags.rosbag1 import Reader, Writer

    with Writer(out) as writer:
        connections = {}
        for path in paths:
            with Reader(path) as reader:
                for connection, stamp, raw in reader.messages():
                    key = connection.topic
                    if key not in connections:
                        connections[key] = writer.add_connection(connection.topic, connection.msgtype,
                                                                 msgdef=connection.msgdef.data,
                                                                 md5sum=connection.digest)
                    writer.write(connections[key], stamp, raw)


def test_the_track_command_reads_a_bag(rendered, bags, tmp_path, capsys):
    dataset, _, _ = rendered
    out = tmp_path / "ds"
    assert main(["track", "--bag", str(bags["mcap"]), "--robot", "kinova", "-o", str(out), "--no-progress"]) == 0
    printed = capsys.readouterr().out
    assert "images /camera/image_raw, joint states /joint_states, camera /camera/camera_info; 6 spin(s)" in printed
    assert "time offset +13" in printed and "applied" in printed
    assert len(Dataset.load(out)) == len(dataset)
    parser = argparse.ArgumentParser()
    add_track_parser(parser.add_subparsers(dest="command"))
    with pytest.raises(InputError, match="--joints do.* not apply to --bag"):
        cmd_track(parser.parse_args(["track", "--bag", str(bags["mcap"]), "--robot", "kinova", "--joints", "j.csv",
                                     "-o", str(tmp_path / "x")]))
    with pytest.raises(InputError, match="videos need --joints and --camera"):
        cmd_track(parser.parse_args(["track", "--video", "a.mp4", "--robot", "kinova", "-o", str(tmp_path / "y")]))


@pytest.mark.parametrize("storage, suffix", [("sqlite3", "*.db3"), ("mcap", "*.mcap")])
def test_a_ros2_bag_opens_from_its_storage_file_too(bags, storage, suffix):
    (storage_file,) = bags[storage].glob(suffix)
    with Bag(storage_file) as bag:
        assert bag.path == bags[storage] and bag.count("/joint_states") > 100


def test_the_camera_of_the_images_and_not_another(rendered, tmp_path):
    dataset, _, spins = rendered
    spin = spins[:1]
    # image_transport's compressed sub-topic: its camera_info is the camera's, one level up
    path = write_bag(tmp_path / "c", "ros1", dataset, spin, encoding="jpeg", image_topic="/cam/image_raw/compressed",
                     camera_info_topic="/cam/camera_info")
    with Bag(path) as bag:
        assert bag.choose_topics().camera_info == "/cam/camera_info"
    # the bag's only CameraInfo, for another frame: not taken on trust
    path = write_bag(tmp_path / "o", "ros1", dataset, spin, camera_info_topic="/right/camera_info",
                     info_frame="right_optical")
    with Bag(path) as bag:
        with pytest.raises(BagError, match="only CameraInfo topic /right/camera_info is for the frame 'right_optical'"):
            bag.choose_topics()
        assert bag.choose_topics(camera_info="/right/camera_info").camera_info == "/right/camera_info"
        assert bag.choose_topics(with_camera_info=False).camera_info is None  # a camera file is given
    # rectified images: CameraInfo's P without distortion (K and D describe the raw images)
    path = write_bag(tmp_path / "r", "ros1", dataset, spin, image_topic="/camera/image_rect")
    with Bag(path) as bag:
        raw, rect = bag.camera("/camera/camera_info"), bag.camera("/camera/camera_info", rectified=True)
    np.testing.assert_allclose(rect.K[:2], 0.9 * raw.K[:2])
    assert rect.dist is None or not np.any(rect.dist)


def test_12_bit_images_and_depth_images(rendered, tmp_path):
    dataset, _, spins = rendered
    path = write_bag(tmp_path / "m", "ros1", dataset, spins[:1], encoding="mono12")
    with Bag(path) as bag:
        _, _, image = next(bag.images("/camera/image_raw"))
    assert np.abs(image.astype(float) - spins[0].frame(0)).max() <= 1  # scaled by its own depth, not 8 bits
    message = type("Image", (), dict(encoding="16UC1", height=2, width=2, step=4, is_bigendian=0,
                                     data=np.zeros(8, np.uint8)))
    with pytest.raises(BagError, match="16UC1 images are depth images"):
        decode_image(message, "sensor_msgs/msg/Image", "a bag")


def test_joint_states_from_two_publishers_are_interpolated_not_zigzagged(rendered, tmp_path):
    dataset, _, spins = rendered
    path = write_bag(tmp_path / "s", "ros1", dataset, spins, offset_s=OFFSET_S, split_joints=True)
    joint_t, joint_q, _ = timeline(dataset, spins, OFFSET_S)
    with Bag(path) as bag:
        stamps, positions = bag.joint_states("/joint_states", dataset.arm.joint_names)
        image_stamps, motion = bag.image_motion("/camera/image_raw")
    truth = np.stack([np.interp(stamps, joint_t, joint_q[:, j]) for j in range(joint_q.shape[1])], axis=1)
    error = np.max(np.abs(positions - truth), axis=1)
    # exact but near the kinks of the joints' motion (at spin starts, between poses), where interpolating between
    # samples cannot be; the last-value series this replaces was off by a speed times 3 ms at every sample
    assert np.median(error) < 1e-8 and error.max() < 0.05  # (stamps are whole nanoseconds)
    offset, _, _ = estimate_time_offset(image_stamps, motion, stamps, positions)
    assert abs(offset - OFFSET_S) < 0.1 / FPS


def test_a_damaged_bag_and_clocks_far_apart_are_named(rendered, bags, tmp_path, capsys):
    dataset, _, spins = rendered
    damaged = tmp_path / "damaged.bag"
    data = bytearray(bags["ros1"].read_bytes())
    data[len(data) // 3:len(data) // 3 + 1_000_000] = np.random.default_rng(0).integers(
        0, 256, 1_000_000, dtype=np.uint8).tobytes()  # across record headers, not only inside an image
    damaged.write_bytes(bytes(data))
    with pytest.raises(BagError, match="damaged.bag.*(damaged|cannot be read)"):
        with Bag(damaged) as bag:
            bag.image_motion("/camera/image_raw")
    far = write_bag(tmp_path / "far", "ros1", dataset, spins[:3], offset_s=5.0)
    with Bag(far) as bag:  # one spin later the repeating spins line up too, but less of the recording
        alias = estimate_time_offset(*bag.image_motion("/camera/image_raw"),
                                     *bag.joint_states("/joint_states", dataset.arm.joint_names))
    assert abs(alias.offset) <= 1.0 and alias.score < 0.8  # found inside the search, scored too low to apply
    with pytest.raises(BagError, match="--time-offset"):
        dataset_from_bag(far, dataset.arm, progress=False)
    assert "could not be measured" in capsys.readouterr().err
    made = dataset_from_bag(far, dataset.arm, progress=False, time_offset_s=5.0)
    assert len(made) == 3 and made.metadata["recording"]["time_offset_given_s"] == 5.0
    again = dataset_from_bag(far, dataset.arm, progress=False, max_offset_s=6.0)
    assert abs(again.metadata["recording"]["time_offset_s"] - 5.0) < 0.1 / FPS


def test_the_report_draws_each_spin_on_its_own_recorded_frame(rendered, bags, tmp_path, capsys):
    dataset, _, spins = rendered
    made = dataset_from_bag(bags["mcap"], dataset.arm, progress=False)
    frames, notes = recorded_frames(made)
    assert sorted(frames) == list(range(len(made))) and not notes
    _, _, images = timeline(dataset, spins, OFFSET_S)
    for k, (number, image) in frames.items():
        assert number == busiest_frame(made, k)
        _, spin, i = images[number]  # the bag's image at that position on the topic
        assert spin == k
        np.testing.assert_allclose(cv2.cvtColor(image, cv2.COLOR_BGR2GRAY) if image.ndim == 3 else image,
                                   spins[k].frame(i), atol=1)
    folder, result_path = tmp_path / "ds", tmp_path / "result.json"
    made.save(folder)
    main(["calibrate", str(folder), "-o", str(result_path)])
    assert main(["report", str(result_path), "--overlays", str(tmp_path / "quad")]) == 0
    assert sorted(p.name for p in (tmp_path / "quad").iterdir()) == [f"overlay_m{k}.png" for k in range(len(made))]
    assert recorded_frames(dataset)[1] == ["the dataset records no video or bag (it was not made by `gtsam-rotid "
                                           "track`)"]

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
from gtsam_rotid.bags import Bag, BagError, estimate_time_offset
from gtsam_rotid.cli import add_track_parser, cmd_track, main
from gtsam_rotid.dataset import Dataset
from gtsam_rotid.errors import InputError
from gtsam_rotid.estimate import calibrate

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
        np.testing.assert_allclose(stamps, joint_t, atol=1e-9)
        np.testing.assert_allclose(positions, joint_q, atol=1e-12)
        camera = bag.camera(topics.camera_info)
        np.testing.assert_allclose(camera.K, dataset.camera.K)
        assert (camera.width, camera.height) == (dataset.camera.width, dataset.camera.height)
        read = list(bag.images(topics.image, images[40][0] - 1e-6, images[45][0] + 1e-6))
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
    offset, correlation = estimate_time_offset(image_stamps, motion, stamps, positions)
    assert abs(offset - offset_s) < 0.1 / FPS, offset
    assert correlation > 0.5


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
    result = calibrate(made)
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

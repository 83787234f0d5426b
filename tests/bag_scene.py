"""Small ROS bags of a rendered scene, written with rosbags' own writers (ROS 1, ROS 2 sqlite3 and mcap): the
images of each spin (raw in several encodings, or compressed), the joint states at their own rate with a gripper
joint the model does not have, the arm moving between the poses, CameraInfo, and a camera clock that runs ahead of
the joint-state clock by a known offset. Used by tests/test_bags.py."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import cv2
import numpy as np

from gtsam_rotid import Dataset, simulate
from gtsam_rotid.render import render_measurement
from gtsam_rotid.renderconfig import RenderConfig

FPS = 15.0
JOINT_RATE = 50.0
STILL_S = 0.6
MOVE_S = 0.8


def scene(n_poses: int = 4, duration: float = 3.0, seed: int = 3, spin_ramp: float = 0.0):
    """A reference scene of ``n_poses`` spins of ``duration`` s at FPS (speeding up and slowing down over
    ``spin_ramp`` s at each end), rendered (dots), and its truth."""
    dataset, truth = simulate.reference_scene(seed=seed, duration=duration, fps=FPS, spin_ramp=spin_ramp)
    dataset = Dataset(dataset.arm, dataset.camera, list(dataset)[:n_poses], metadata=dataset.metadata)
    truth = replace(truth, measurements=truth.measurements[:n_poses])
    spins = [render_measurement(dataset, truth, k, RenderConfig(seed=seed)) for k in range(n_poses)]
    return dataset, truth, spins


def timeline(dataset, spins, offset_s: float = 0.0):
    """(joint stamps, joint positions (N, dof)) on the joint clock, and [(camera stamp, spin k, frame i)]: each
    pose held STILL_S before and after its spin (its first and last image repeated), the arm moving MOVE_S between
    poses (no images). A spin of another joint than the wrist (``Measurement.spin_joint``) turns that joint; after
    it the base swings 3 degrees out and back while that joint turns back (else the turn back would extend its spin:
    only one joint moving)."""
    arm = dataset.arm
    joint_t, joint_q, images = [], [], []
    t = 1.0
    for k, spin in enumerate(spins):
        q = np.array(dataset[k].joint_angles, dtype=float)
        spinning = arm.spin_index(dataset[k].spin_joint)
        angles = spin.spin_angles - spin.spin_angles[0]
        frame_t = t + STILL_S + np.arange(spin.n_frames) / FPS
        end = frame_t[-1] + STILL_S
        for s in np.arange(t, end, 1.0 / JOINT_RATE):
            row = q.copy()
            row[spinning] += np.interp(s, frame_t, angles)
            joint_t.append(s)
            joint_q.append(row)
        for s in np.arange(t, frame_t[0], 1.0 / FPS):
            images.append((s + offset_s, k, 0))
        images.extend((s + offset_s, k, i) for i, s in enumerate(frame_t))
        for s in np.arange(frame_t[-1] + 1.0 / FPS, end, 1.0 / FPS):
            images.append((s + offset_s, k, spin.n_frames - 1))
        if k + 1 < len(spins):
            last = joint_q[-1]
            nxt = np.array(dataset[k + 1].joint_angles, dtype=float)
            for s in np.arange(end, end + MOVE_S, 1.0 / JOINT_RATE):
                joint_t.append(s)
                row = last + (nxt - last) * (s - end) / MOVE_S
                if spinning != arm.wrist_index:  # (another joint turns back too: the turn back is no spin)
                    row[0] += np.radians(3.0) * np.sin(np.pi * (s - end) / MOVE_S)
                joint_q.append(row)
        t = end + MOVE_S
    return np.array(joint_t), np.array(joint_q), images


def write_bag(path: Path, storage: str, dataset, spins, *, offset_s: float = 0.0, encoding: str = "mono8",
              camera_info: bool = True, image_topic: str = "/camera/image_raw",
              camera_info_topic: str = "/camera/camera_info", info_frame: str = "camera_optical",
              split_joints: bool = False) -> Path:
    """Write the scene as a bag: ``storage`` "ros1" (a .bag file), "sqlite3" or "mcap" (a ROS 2 bag directory);
    ``encoding`` an Image encoding (mono8, bgr8, rgb8, mono16, "mono12": 12-bit data in mono16) or "jpeg" / "png"
    (CompressedImage). ``split_joints``: the arm's first three and last joints come from two publishers, 3 ms
    apart."""
    from rosbags.typesys import Stores, get_typestore

    ros1 = storage == "ros1"
    store = get_typestore(Stores.ROS1_NOETIC if ros1 else Stores.ROS2_HUMBLE)
    T = store.types

    def header(stamp: float, frame: str):
        sec = int(np.floor(stamp))
        time = T["builtin_interfaces/msg/Time"](sec=sec, nanosec=int(round((stamp - sec) * 1e9)))
        if ros1:
            return T["std_msgs/msg/Header"](seq=0, stamp=time, frame_id=frame)
        return T["std_msgs/msg/Header"](stamp=time, frame_id=frame)

    def serialize(message, msgtype):
        return store.serialize_ros1(message, msgtype) if ros1 else store.serialize_cdr(message, msgtype)

    camera = dataset.camera
    joint_t, joint_q, images = timeline(dataset, spins, offset_s)
    names = [*dataset.arm.joint_names, "gripper_finger_joint"]
    messages = []
    groups = [(0.0, list(range(3))), (0.003, list(range(3, len(names))))] if split_joints else \
        [(0.0, list(range(len(names))))]
    for s, q in zip(joint_t, joint_q, strict=True):
        for delay, members in groups:
            values = np.append(q, 0.01)
            if delay:  # the second publisher reads its joints later
                later = np.array([np.interp(s + delay, joint_t, joint_q[:, j]) for j in range(joint_q.shape[1])])
                values = np.append(later, 0.01)
            msg = T["sensor_msgs/msg/JointState"](header=header(s + delay, ""), name=[names[i] for i in members],
                                                   position=values[members], velocity=np.zeros(0),
                                                   effort=np.zeros(0))
            messages.append((s + delay, "/joint_states", "sensor_msgs/msg/JointState", msg))
    compressed = encoding in ("jpeg", "png")
    image_type = "sensor_msgs/msg/CompressedImage" if compressed else "sensor_msgs/msg/Image"
    for s, k, i in images:
        grey = spins[k].frame(i)
        if compressed:
            ok, data = cv2.imencode(".jpg" if encoding == "jpeg" else ".png", grey)
            assert ok
            msg = T[image_type](header=header(s, "camera_optical"), format=encoding, data=data.ravel())
        else:
            if encoding == "mono8":
                pixels, step = grey, camera.width
            elif encoding == "mono16":
                pixels, step = (grey.astype("<u2") * 256 + 7).view(np.uint8), 2 * camera.width
            elif encoding == "mono12":
                pixels, step = (grey.astype("<u2") * 16 + 3).view(np.uint8), 2 * camera.width
            else:
                colour = cv2.cvtColor(grey, cv2.COLOR_GRAY2BGR)
                pixels = colour if encoding == "bgr8" else colour[..., ::-1]
                step = 3 * camera.width
            msg = T[image_type](header=header(s, "camera_optical"), height=camera.height, width=camera.width,
                                encoding="mono16" if encoding == "mono12" else encoding, is_bigendian=0, step=step,
                                data=np.ascontiguousarray(pixels).ravel().view(np.uint8))
        messages.append((s, image_topic, image_type, msg))
    if camera_info:
        K = camera.K.ravel().tolist()
        D = [] if camera.dist is None else camera.dist.tolist()
        fields = dict(header=header(joint_t[0], info_frame), height=camera.height, width=camera.width,
                      distortion_model="plumb_bob", binning_x=0, binning_y=0,
                      roi=T["sensor_msgs/msg/RegionOfInterest"](x_offset=0, y_offset=0, height=0, width=0,
                                                                 do_rectify=False))
        R = np.eye(3).ravel()
        P = np.hstack([camera.K * np.array([[0.9], [0.9], [1.0]]), np.zeros((3, 1))]).ravel()  # rectified: other
        if ros1:
            fields.update(D=np.array(D), K=np.array(K), R=R, P=P)
        else:
            fields.update(d=np.array(D), k=np.array(K), r=R, p=P)
        messages.append((joint_t[0], camera_info_topic, "sensor_msgs/msg/CameraInfo",
                         T["sensor_msgs/msg/CameraInfo"](**fields)))
    messages.sort(key=lambda m: m[0])
    if ros1:
        from rosbags.rosbag1 import Writer
        path = path.with_suffix(".bag")
        writer = Writer(path)
    else:
        from rosbags.rosbag2 import StoragePlugin, Writer
        plugin = StoragePlugin.MCAP if storage == "mcap" else StoragePlugin.SQLITE3
        writer = Writer(path, version=9, storage_plugin=plugin)
    with writer:
        connections = {}
        for s, topic, msgtype, msg in messages:
            if topic not in connections:
                connections[topic] = writer.add_connection(topic, msgtype, typestore=store)
            writer.write(connections[topic], int(round(s * 1e9)), serialize(msg, msgtype))
    return path

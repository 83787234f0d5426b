"""Did the camera stay still between the videos? camera_motion reads each video's shift off the still background,
against shifts it is not told: images of one textured scene moved by known sub-pixel amounts (exactly, by the
Fourier shift theorem: ``benchmarks/stillness.py``'s scenes), with an arm that stands elsewhere in every video and
sensor noise."""

import sys
from pathlib import Path

import cv2
import numpy as np
import pytest

from gtsam_rotid.errors import InputError
from gtsam_rotid.stillness import DRIFT_SPREAD, SIGNIFICANT_Z, background_shift, camera_motion
from gtsam_rotid.videos import write_video
from gtsam_rotid.words import camera_motion_words

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
from stillness import H, W, moved_view, still_scene  # noqa: E402 (the benchmark's scenes)


def _scene(rng) -> np.ndarray:
    return still_scene(rng)


def _view(scene: np.ndarray, shift, arm_at: int, rng) -> np.ndarray:
    return moved_view(scene, shift, arm_at, rng)


@pytest.fixture(scope="module")
def views():
    rng = np.random.default_rng(3)
    scene = _scene(rng)
    shifts = np.array([[0.0, 0.0], [0.0, 0.0], [0.1, 0.0], [0.0, -0.05], [1.3, 0.7], [-0.03, 0.08]])
    frames = [_view(scene, s, 40 + 70 * k, rng) for k, s in enumerate(shifts)]
    return frames, shifts


def test_each_videos_shift_is_read_off_the_still_background(views):
    frames, shifts = views
    motion = camera_motion(frames)
    # the first video is the reference: every shift is against it
    error = np.abs(motion.shifts_px - (shifts - shifts[0]))[1:]
    # within a fiftieth of a pixel, and within 4 of their own standard errors (the median's, from the points' spread)
    assert np.all(error < 0.02) and np.all(error < 4 * motion.sigma_px[1:])
    assert np.all(motion.sigma_px[1:] < 0.01) and np.all(motion.n_points[1:] > 50)
    # a still camera is not called moved; 0.05 px and more is
    assert list(motion.moved) == [False, False, True, True, True, True]
    assert motion.floor_px == pytest.approx(np.hypot(1.3, 0.7), abs=0.01)
    assert SIGNIFICANT_Z * np.linalg.norm(motion.sigma_px[1]) > motion.size_px[1]


def test_videos_are_read_from_files_and_a_still_camera_needs_no_floor(views, tmp_path):
    frames, _ = views
    paths = []
    for k in (0, 1):  # the two taken from the same place
        path = tmp_path / f"pose{k}.mkv"
        write_video([frames[k]] * 3, path, fps=30)  # (FFV1: lossless)
        paths.append(path)
    motion = camera_motion(paths, names=["pose0.mkv", "pose1.mkv"])
    assert motion.names == ["pose0.mkv", "pose1.mkv"]
    assert motion.size_px[1] < 0.01 and not motion.moved[1] and motion.floor_px == 0.0


@pytest.fixture(scope="module")
def drifting():
    """Four videos' first and last frames: shifts between the videos and moves during them (px, x y), the arm
    elsewhere in each frame."""
    rng = np.random.default_rng(11)
    scene = _scene(rng)
    shifts = np.array([[0.0, 0.0], [0.1, 0.0], [0.0, 0.0], [0.0, 0.0]])
    drifts = np.array([[0.0, 0.0], [0.0, 0.0], [0.0, 0.2], [0.06, -0.03]])
    firsts = [_view(scene, s, 40 + 70 * k, rng) for k, s in enumerate(shifts)]
    lasts = [_view(scene, s + d, 330 - 60 * k, rng) for k, (s, d) in enumerate(zip(shifts, drifts, strict=True))]
    return firsts, lasts, shifts, drifts


def test_the_cameras_move_during_each_video_is_read_against_its_last_frame(drifting):
    firsts, lasts, shifts, drifts = drifting
    motion = camera_motion(firsts, last=lasts)
    error = np.abs(motion.drift_px - drifts)
    assert np.all(error < 0.02) and np.all(error < 4 * motion.drift_sigma_px + 1e-3)
    assert list(motion.drifted) == [False, False, True, True] and list(motion.moved) == [False, True, False, False]
    np.testing.assert_allclose(motion.positions_px, motion.shifts_px + 0.5 * motion.drift_px)
    # the largest move, a drift's end included (video 2: 0.2 px during it)
    assert motion.floor_px == pytest.approx(0.2, abs=0.02)
    positions = motion.positions_px
    scatter = np.sum((positions - positions.mean(axis=0)) ** 2) / (2 * 3)
    spread = 0.5 * DRIFT_SPREAD**2 * np.mean(np.sum(motion.drift_px**2, axis=1))
    assert motion.level_px == pytest.approx(np.sqrt(scatter + spread))
    data = motion.to_dict()
    assert data["drifted"] == [False, False, True, True] and len(data["drift_px"]) == 4
    words = "\n".join(camera_motion_words(motion))
    assert "MOVED DURING IT" in words and "moved between and during the videos" in words
    # without the last frames: the shifts alone, as before
    between = camera_motion(firsts)
    assert between.drift_px is None and not between.drifted.any() and "drift_px" not in between.to_dict()
    np.testing.assert_allclose(between.shifts_px, motion.shifts_px)
    # a last frame that cannot be read loses the drift, not the shifts between the videos, and says why
    plain = [*lasts[:3], np.full((H, W), 90, np.uint8)]
    lost = camera_motion(firsts, last=plain)
    assert lost.drift_px is None and "video 3 (its last frame against its first)" in lost.drift_error
    np.testing.assert_allclose(lost.shifts_px, motion.shifts_px)
    assert "drift_error" in lost.to_dict() and "could not be read" in "\n".join(camera_motion_words(lost))
    with pytest.raises(InputError, match="3 last frames for 4 videos"):
        camera_motion(firsts, last=lasts[:3])


def test_what_cannot_be_measured_is_named(views):
    frames, _ = views
    with pytest.raises(InputError, match="at least two videos"):
        camera_motion(frames[:1])
    with pytest.raises(InputError, match=r"video 1: 240x180 px, but the first video's frame is 480x360"):
        camera_motion([frames[0], cv2.resize(frames[1], (240, 180))])
    plain = np.full((H, W), 128, np.uint8)
    with pytest.raises(InputError, match="too little texture"):
        camera_motion([plain, plain])
    # another scene altogether (the camera pointed elsewhere): nothing found again or nothing agrees
    other = _view(_scene(np.random.default_rng(9)), (0.0, 0.0), 200, np.random.default_rng(1))
    with pytest.raises(InputError, match="pose 2"):
        background_shift(frames[0], other, "pose 2")
    with pytest.raises(InputError, match="uint8"):
        camera_motion([frames[0], frames[1].astype(np.float32)])


def test_the_still_command_names_each_videos_shift_and_the_floor_to_declare(views, tmp_path, capsys):
    from gtsam_rotid.cli import main

    frames, shifts = views
    paths = []
    for k in (0, 1, 2):  # still, still, 0.1 px
        path = tmp_path / f"pose{k}.mkv"
        write_video([frames[k]] * 2, path, fps=30)
        paths.append(str(path))
    assert main(["still", *paths[:2]]) == 0
    out = capsys.readouterr().out
    assert "stayed still" in out and "MOVED" not in out
    assert main(["still", *paths]) == 3
    out = capsys.readouterr().out
    line = next(line for line in out.splitlines() if "pose2.mkv:" in line)
    assert "MOVED" in line and float(line.split(":")[-1].split()[0]) == pytest.approx(0.1, abs=0.02)
    assert "--axis-floor-px 0.1" in out
    assert main(["still", paths[0]]) == 1
    assert "at least two videos" in capsys.readouterr().err
    assert main(["still", paths[0], str(tmp_path / "missing.mp4")]) == 1
    assert "missing.mp4" in capsys.readouterr().err


def _three_arcs(images, params=None):
    """A tracker for make_dataset that reads the frames and returns three arcs (the camera's motion is the test)."""
    from gtsam_rotid.dataset import Track

    n = len(list(images))
    angles = np.linspace(0.0, 1.0, n)
    return [Track(np.column_stack([200 + (20 + j) * np.cos(angles), 150 + (20 + j) * np.sin(angles)]), np.arange(n))
            for j in range(3)]


def test_make_dataset_measures_the_cameras_move_and_calibrate_takes_it_as_the_floor(views, tmp_path, capsys):
    from gtsam_rotid import simulate
    from gtsam_rotid.calibration.options import CalibrationOptions, camera_motion_level_px, with_tracker_defaults
    from gtsam_rotid.camera import Camera
    from gtsam_rotid.recordings import make_dataset

    frames, shifts = views
    scene, _ = simulate.reference_scene(seed=0, duration=1.0)
    camera = Camera(np.array([[570.0, 0, W / 2], [0, 570.0, H / 2], [0, 0, 1]]), W, H)

    videos = []
    for k in (0, 1, 2):  # still, still, moved by 0.1 px
        path = tmp_path / f"pose{k}.mkv"
        write_video([frames[k]] * 3, path, fps=30)
        videos.append(path)
    poses = [scene.joint_angles(k) for k in range(3)]
    dataset = make_dataset(videos, poses, camera, scene.arm, tracker=_three_arcs, progress=False)
    motion = dataset.metadata["camera_motion"]
    assert motion["names"] == ["pose0.mkv", "pose1.mkv", "pose2.mkv"]
    assert motion["floor_px"] == pytest.approx(0.1, abs=0.02)
    assert "the camera moved between the videos" in capsys.readouterr().err
    # the shifts' scatter about their mean (0, 0, 0.1 px along x): the level calibrate counts in the covariance
    assert motion["level_px"] == pytest.approx(np.sqrt(np.var([0.0, 0.0, 0.1], ddof=1) / 2), abs=0.01)
    assert camera_motion_level_px(dataset.metadata) == motion["level_px"]
    assert with_tracker_defaults(CalibrationOptions(), dataset.metadata).axis_floor_px == 0.0  # (no floor from it)
    with pytest.raises(InputError, match=r'metadata\["camera_motion"\]\["level_px"\] must be a finite number'):
        camera_motion_level_px({"camera_motion": {"level_px": float("nan")}})
    # saved and loaded with the dataset
    dataset.save(tmp_path / "dataset")
    from gtsam_rotid.dataset import Dataset

    assert Dataset.load(tmp_path / "dataset").metadata["camera_motion"]["floor_px"] == motion["floor_px"]
    # still videos: measured, no floor; plain frames: nothing to read, said on stderr, nothing claimed
    still = make_dataset(videos[:2], poses[:2], camera, scene.arm, tracker=_three_arcs, progress=False)
    assert still.metadata["camera_motion"]["floor_px"] == 0.0 and still.metadata["camera_motion"]["level_px"] == 0.0
    plain = []
    for k in (0, 1):
        path = tmp_path / f"plain{k}.mkv"
        write_video([np.full((H, W), 90, np.uint8)] * 3, path, fps=30)
        plain.append(path)
    capsys.readouterr()
    blank = make_dataset(plain, poses[:2], camera, scene.arm, tracker=_three_arcs, progress=False)
    assert "camera_motion" not in blank.metadata
    assert "could not be told from their background" in capsys.readouterr().err


def test_a_move_during_a_video_is_read_by_the_still_command_and_carried_by_make_dataset(drifting, tmp_path, capsys):
    from gtsam_rotid import simulate
    from gtsam_rotid.camera import Camera
    from gtsam_rotid.cli import main
    from gtsam_rotid.recordings import make_dataset

    firsts, lasts, _, _ = drifting
    videos = []
    for k in (0, 2):  # still; still between the videos, 0.2 px during the second
        path = tmp_path / f"pose{k}.mkv"
        write_video([firsts[k], firsts[k], lasts[k]], path, fps=30)  # (FFV1: lossless)
        videos.append(path)
    assert main(["still", *map(str, videos)]) == 3
    out = capsys.readouterr().out
    line = next(line for line in out.splitlines() if "pose2.mkv:" in line)
    assert line.endswith("MOVED DURING IT") and line.count("MOVED") == 1 and "moved during a video" in out
    assert main(["still", "--between-only", *map(str, videos)]) == 0
    assert "stayed still between the videos" in capsys.readouterr().out

    scene, _ = simulate.reference_scene(seed=0, duration=1.0)
    camera = Camera(np.array([[570.0, 0, W / 2], [0, 570.0, H / 2], [0, 0, 1]]), W, H)

    dataset = make_dataset(videos, [scene.joint_angles(k) for k in range(2)], camera, scene.arm, tracker=_three_arcs,
                           progress=False)
    motion = dataset.metadata["camera_motion"]
    assert motion["drifted"] == [False, True] and motion["drift_px"][1][1] == pytest.approx(0.2, abs=0.02)
    assert motion["level_px"] > 0.0 and motion["floor_px"] == pytest.approx(0.2, abs=0.02)
    assert "the camera moved during pose2.mkv (0.2" in capsys.readouterr().err


def test_on_the_rendered_arm_a_still_camera_reads_still_and_a_turn_of_a_hundredth_of_a_degree_is_seen():
    """The robot's own meshes, a photograph on the hand, a textured wall and floor (``render_mesh_measurement``
    with ``camera_moved``: the wall, the floor and the still links stay where they were). A turn's image shift
    varies over the view (0.099-0.117 px for 0.01 deg about x here, 0.20-0.26 px for 0.02 deg about y); the
    renderer rounds its texture look-ups to 1/32 texel (OpenCV's remap), so the reading is held to 0.04 px of that
    range."""
    import gtsam

    from gtsam_rotid import meshrender

    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
    from ambient import scene_spins

    dataset, truth = scene_spins("kinova", 0, 1.0)
    config = meshrender.MeshRenderConfig(covering="photo")
    meshes = meshrender.load_arm_meshes(dataset.arm)
    moves = [None, gtsam.Pose3(), gtsam.Pose3(gtsam.Rot3.Rx(np.radians(0.01)), np.zeros(3)),
             gtsam.Pose3(gtsam.Rot3.Ry(np.radians(0.02)), np.zeros(3))]
    frames = [meshrender.render_mesh_measurement(dataset, truth, k, config, frames=np.array([0]), meshes=meshes,
                                                 camera_moved=move).frame(0) for k, move in enumerate(moves)]
    motion = camera_motion(frames)
    assert not motion.moved[1] and motion.size_px[1] < 0.01
    assert motion.moved[2] and 0.099 - 0.04 < motion.shifts_px[2, 1] < 0.117 + 0.04
    assert abs(motion.shifts_px[2, 0]) < 0.04
    assert motion.moved[3] and -0.26 - 0.04 < motion.shifts_px[3, 0] < -0.20 + 0.04
    assert abs(motion.shifts_px[3, 1]) < 0.04

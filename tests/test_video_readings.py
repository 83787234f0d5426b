"""Videos with a joint time series (``gtsam-rotid track --videos ... --joints states.csv``): each video's frames are
placed on the series' clock by lining up image motion with joint motion, its spin readings attached, and the
calibration synced with them (``recordings.make_dataset(..., fps=, readings=)``)."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from bag_scene import FPS, scene, timeline

from gtsam_rotid.estimate import calibrate
from gtsam_rotid.recordings import make_dataset

CHI2_6_999 = 22.458


@pytest.fixture(scope="module")
def recorded(tmp_path_factory):
    """Four rendered spins as image folders (each with its still frames before and after), the joint states as a
    time-series CSV on their own clock, the true joint-clock time of every image, and the scene's truth."""
    dataset, truth, spins = scene(n_poses=4, duration=3.0)
    joint_t, joint_q, images = timeline(dataset, spins)
    root = tmp_path_factory.mktemp("videos")
    folders, times = [], []
    for k in range(len(spins)):
        mine = [(s, i) for s, kk, i in images if kk == k]
        # (the timeline's still frames may end a rounding error before the spin's first: a video's frames are
        # evenly spaced)
        mine = [a for a, b in zip(mine, mine[1:] + [(np.inf, 0)], strict=True) if b[0] - a[0] > 1e-6]
        assert np.allclose(np.diff([s for s, _ in mine]), 1.0 / FPS)
        folder = root / f"spin{k}"
        folder.mkdir()
        for j, (_, i) in enumerate(mine):
            assert cv2.imwrite(str(folder / f"frame{j:04d}.png"), spins[k].frame(i))
        folders.append(folder)
        times.append(np.array([s for s, _ in mine]))
    csv = root / "states.csv"
    rows = [",".join(["stamp", *dataset.arm.joint_names])]
    rows += [",".join(f"{v:.9f}" for v in (t, *q)) for t, q in zip(joint_t, joint_q, strict=True)]
    csv.write_text("\n".join(rows) + "\n")
    return dataset, truth, folders, times, csv


def test_each_videos_frames_are_placed_on_the_joint_clock_and_the_calibration_syncs(recorded):
    dataset, truth, folders, times, csv = recorded
    made = make_dataset(folders, csv, dataset.camera, dataset.arm, fps=FPS, progress=False)
    for k, (m, true_times) in enumerate(zip(made, times, strict=True)):
        readings = m.spin_readings
        assert readings is not None, k
        # within a tenth of a frame of the time each image was taken
        assert np.max(np.abs(readings.frame_times - true_times)) < 0.1 / FPS, k
        assert readings.times[0] <= true_times[0] and readings.times[-1] >= true_times[-1]
    starts = made.metadata["recording"]["video_starts"]
    assert [round(s["start_s"], 6) for s in starts] == pytest.approx([t[0] for t in times], abs=0.1 / FPS)
    result = calibrate(made)
    assert result.synced == (0, 1, 2, 3) and abs(result.time_offset_s) < 3.0 * result.time_offset_sigma_s
    error = result.error_to(truth.arm_T_camera)
    assert float(error @ np.linalg.solve(result.covariance, error)) < CHI2_6_999


def test_a_video_that_never_sees_its_spin_start_or_stop_gets_no_readings(recorded, capsys):
    dataset, _, folders, times, csv = recorded
    n = [len(t) for t in times]
    middle = [(10, n[0] - 10)] + [None] * (len(folders) - 1)  # video 0 cut to frames inside its spin
    made = make_dataset(folders, csv, dataset.camera, dataset.arm, fps=FPS, progress=False, frame_ranges=middle)
    assert made[0].spin_readings is None and all(m.spin_readings is not None for m in list(made)[1:])
    assert "spin0: where its frames fall on the joint time series' clock could not be measured" in \
        capsys.readouterr().err


def test_image_folders_need_a_frame_rate_and_readings_can_be_left_off(recorded, capsys):
    dataset, _, folders, _, csv = recorded
    made = make_dataset(folders[:4], csv, dataset.camera, dataset.arm, progress=False)
    assert all(m.spin_readings is None for m in made) and "states no frame rate" in capsys.readouterr().err
    off = make_dataset(folders, csv, dataset.camera, dataset.arm, fps=FPS, progress=False, readings=False)
    assert all(m.spin_readings is None for m in off) and "video_starts" not in off.metadata["recording"]

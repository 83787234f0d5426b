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
from gtsam_rotid.words import summary

CHI2_6_999 = 22.458


@pytest.fixture(scope="module")
def recorded(tmp_path_factory):
    """Six rendered spins (speeding up and slowing down over half a second, as an arm does) as image folders (each
    with its still frames before and after), the joint states as a time-series CSV on their own clock, the true
    joint-clock time of every image, and the scene's truth."""
    dataset, truth, spins = scene(n_poses=6, duration=4.0, spin_ramp=0.5)
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
    """Each video is placed on the series' clock by image motion to within half a frame; what is left of its
    offset is a variable of its own (its clock, named after the video) that the synced calibration estimates:
    each video's estimated offset holds the placement's true error within its 1 sigma's chi-square."""
    dataset, truth, folders, times, csv = recorded
    made = make_dataset(folders, csv, dataset.camera, dataset.arm, fps=FPS, progress=False)
    placed_error = []  # camera minus encoder: the placed time of each video's frames less the true time
    for k, (m, true_times) in enumerate(zip(made, times, strict=True)):
        readings = m.spin_readings
        assert readings is not None and readings.clock == folders[k].name, k
        error = readings.frame_times - true_times
        assert np.ptp(error) < 1e-9 and abs(error[0]) < 0.5 / FPS, (k, error[0])
        placed_error.append(float(error[0]))
    starts = made.metadata["recording"]["video_starts"]
    assert [s["start_s"] for s in starts] == pytest.approx([t[0] for t in times], abs=0.5 / FPS)
    result = calibrate(made)
    assert result.synced == tuple(range(6)) and result.time_offset_s is None  # (six clocks: no single offset)
    assert set(result.time_offsets) == {f.name for f in folders}
    z = []
    for k, folder in enumerate(folders):
        clock = result.time_offsets[folder.name]
        assert clock["measurements"] == [k] and clock["sigma_s"] < 0.1 / FPS, clock
        z.append((clock["offset_s"] - placed_error[k]) / clock["sigma_s"])
    assert float(np.sum(np.square(z))) < CHI2_6_999, z  # (6 clocks: 6 dof)
    error = result.error_to(truth.arm_T_camera)
    assert float(error @ np.linalg.solve(result.covariance, error)) < CHI2_6_999
    assert "each of the 6 camera clocks its own offset" in summary(result)


@pytest.mark.parametrize("cut", ["ends", "start"])
def test_a_video_that_never_sees_its_spin_start_or_stop_gets_no_readings(recorded, capsys, cut):
    """Video 0 cut to frames inside its spin (``ends``: 10 frames off each end; ``start``: frames 20-50, the end of
    its ramp and its steady spin, which image motion had placed a third of a second off at a correlation of 0.85):
    its images never come to rest, so it gets no readings, with a warning; the others are synced."""
    dataset, _, folders, times, csv = recorded
    n = [len(t) for t in times]
    first = (10, n[0] - 10) if cut == "ends" else (20, 50)
    made = make_dataset(folders, csv, dataset.camera, dataset.arm, fps=FPS, progress=False,
                        frame_ranges=[first] + [None] * (len(folders) - 1))
    assert made[0].spin_readings is None and all(m.spin_readings is not None for m in list(made)[1:])
    assert "(spin0): where its frames fall on the joint time series' clock could not be measured (the spin never " \
           "starts or stops within the video" in capsys.readouterr().err


def test_image_folders_need_a_frame_rate_and_readings_can_be_left_off(recorded, capsys):
    dataset, _, folders, _, csv = recorded
    made = make_dataset(folders, csv, dataset.camera, dataset.arm, progress=False)
    assert all(m.spin_readings is None for m in made) and "states no frame rate" in capsys.readouterr().err
    off = make_dataset(folders, csv, dataset.camera, dataset.arm, fps=FPS, progress=False, readings=False)
    assert all(m.spin_readings is None for m in off) and "video_starts" not in off.metadata["recording"]


def test_track_places_videos_on_the_joint_series_and_calibrate_says_each_clock(recorded, tmp_path, capsys):
    """From the command line: `track --videos ... --joints states.csv --fps` attaches each video's readings on its
    own clock (its frames cut to its pose's span of the series), `calibrate` estimates one offset per video and
    says so; --no-readings leaves them off."""
    from gtsam_rotid.cli import main
    from gtsam_rotid.dataset import Dataset

    dataset, _, folders, _, csv = recorded
    K = dataset.camera.K
    camera = tmp_path / "camera_info.yaml"
    matrix = ", ".join(repr(float(v)) for v in K.ravel())
    camera.write_text(f"image_width: {dataset.camera.width}\nimage_height: {dataset.camera.height}\n"
                      f"camera_matrix: {{rows: 3, cols: 3, data: [{matrix}]}}\ndistortion_model: plumb_bob\n"
                      "distortion_coefficients: {rows: 1, cols: 5, data: [0, 0, 0, 0, 0]}\n")
    common = ["track", "--videos", *map(str, folders), "--joints", str(csv), "--camera", str(camera), "--robot",
              "kinova", "--fps", str(FPS), "--no-progress"]
    assert main([*common, "-o", str(tmp_path / "d")]) == 0
    made = Dataset.load(tmp_path / "d")
    assert [m.spin_readings.clock for m in made] == [f.name for f in folders]
    for k, (m, start) in enumerate(zip(made, made.metadata["recording"]["video_starts"], strict=True)):
        first, last = start["frames_kept"]
        held = start["held_s"]
        times = m.spin_readings.frame_times
        assert held[0] + 0.1 <= times[first] and times[last] <= held[1] - 0.1, k
        assert all(first <= t.frames[0] and t.frames[-1] <= last for t in m.tracks), k
    assert main(["calibrate", str(tmp_path / "d"), "-o", str(tmp_path / "r.json")]) == 0
    out = capsys.readouterr().out
    assert "each of the 6 camera clocks its own offset" in out
    assert "measurement 0 (spin0): placed at " in out and "readings attached on clock 'spin0'" in out
    assert "(its spin's frame rate: 15.1 fps, 15 given)" in out
    assert main([*common, "--no-readings", "-o", str(tmp_path / "bare")]) == 0
    assert all(m.spin_readings is None for m in Dataset.load(tmp_path / "bare"))
    assert main([*common[:-3], "--fps", "0", "-o", str(tmp_path / "x")]) != 0
    assert "--fps must be a positive number" in capsys.readouterr().err


def test_a_wrong_frame_rate_is_caught_by_the_calibration(recorded):
    """--fps 5 % high: every video is still placed (image motion lines up with joint motion at least as well as at
    the true rate), but each spin's readings then run 5 % slow against its frames; the calibration refuses every
    video's readings (their likelihood ratio far beyond their frames) and its words name the frame rate."""
    dataset, _, folders, _, csv = recorded
    made = make_dataset(folders, csv, dataset.camera, dataset.arm, fps=1.05 * FPS, progress=False)
    assert all(m.spin_readings is not None for m in made)
    result = calibrate(made)
    assert result.synced == () and sorted(result.readings_refused) == list(range(6))
    assert all(v["chi2"] > 100 * v["dof"] for v in result.readings_refused.values())
    assert "its frame rate, track --fps" in summary(result)


def test_videos_trimmed_to_three_still_frames_are_placed_and_synced(recorded):
    """Each video cut to three still frames before and after its spin (of its nine): image motion hardly lines up
    with the joints' over the ramps alone (correlation 0.70-0.84, below a bag's 0.8), but the frames at rest at its
    ends date the spin's start and stop: every video is placed to within half a frame and gets its readings, and the
    calibration syncs every one (one placed a third of a frame off had its good readings refused by the start's test
    before its clock's offset was estimated) and holds its covariance."""
    dataset, truth, folders, times, csv = recorded
    n = [len(t) for t in times]
    made = make_dataset(folders, csv, dataset.camera, dataset.arm, fps=FPS, progress=False,
                        frame_ranges=[(6, n[k] - 6) for k in range(len(folders))])
    for k, m in enumerate(made):
        assert m.spin_readings is not None, k
        assert abs(m.spin_readings.frame_times[6] - times[k][6]) < 0.5 / FPS, k
    result = calibrate(made)
    assert result.synced == tuple(range(6)) and not result.readings_refused
    error = result.error_to(truth.arm_T_camera)
    assert result.covariance_usable and float(error @ np.linalg.solve(result.covariance, error)) < CHI2_6_999


def test_a_frame_rate_off_by_half_is_named_by_the_spins_themselves(recorded, capsys):
    """Each video's spin starts and stops within it: the frames it takes against the seconds its joint takes in the
    series give the frame rate (measured: 0.35 % high on these 4 s spins with half-second ramps; 4 % high where the
    joint's start was the time its angle first left its rest value by 0.25 deg, which lags the image's first moving
    frame). Given at the true rate, nothing is said; given at half of it (a 15 fps recording taken for 7.5 fps) or
    10 % high (16.5 fps: not named while the rate read 4 % high), make_dataset names the rate the spins show."""
    dataset, _, folders, _, csv = recorded
    made = make_dataset(folders, csv, dataset.camera, dataset.arm, fps=FPS, progress=False)
    measured = [p["fps_from_spin"] for p in made.metadata["recording"]["video_starts"]]
    assert len(measured) == 6 and all(abs(f / FPS - 1.0) < 0.01 for f in measured), measured
    assert "frame rate looks like" not in capsys.readouterr().err
    make_dataset(folders, csv, dataset.camera, dataset.arm, fps=0.5 * FPS, progress=False)
    err = capsys.readouterr().err
    line = next(line for line in err.splitlines() if "frame rate looks like" in line)
    rate = float(line.split("looks like about ")[1].split()[0])
    assert abs(rate / FPS - 1.0) < 0.01 and "not the 7.5 fps given (fps / --fps)" in line, line
    make_dataset(folders, csv, dataset.camera, dataset.arm, fps=1.1 * FPS, progress=False)
    assert "frame rate looks like about 15.1 fps, not the 16.5 fps given" in capsys.readouterr().err

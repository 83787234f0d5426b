"""An image shift common to a pose's tracks (a camera that turns a little between poses): the result says what such
a shift, which the axes' test all but cannot see, would add to its error (``CalibrationResult.image_shift_covariance``),
and its words say so where that exceeds the 1σ."""

import numpy as np
import pytest
from shift_refits import refitted_shift_covariance

from gtsam_rotid import Dataset, Measurement, Track, simulate
from gtsam_rotid.estimate import CalibrationOptions, CalibrationResult, calibrate
from gtsam_rotid.report import make_report
from gtsam_rotid.words import image_shift_words, summary


@pytest.fixture(scope="module")
def scene():
    dataset, truth = simulate.reference_scene(seed=200, duration=12.0, n_measurements=6)
    return dataset, calibrate(dataset, method="joint")


def test_the_image_shift_covariance_is_how_the_joint_estimate_moves_when_a_poses_image_shifts(scene):
    """The covariance per px² is computed to first order through the image axes; the ground truth here is the joint
    estimate itself, fitted again with each pose's pixels moved by 0.05 px along x and along y in turn: the sum
    of the outer products of those moves (per px) is the covariance of the estimate under a shift per pose of
    N(0, 1 px²) per image coordinate."""
    dataset, base = scene
    moved = refitted_shift_covariance(dataset, base, method="joint")
    predicted = base.image_shift_covariance
    assert predicted.shape == (6, 6)
    np.testing.assert_allclose(np.sqrt(np.diag(predicted)), np.sqrt(np.diag(moved)), rtol=0.05)
    # the whole matrix, not only its diagonal: the correlations agree too
    scale = np.sqrt(np.outer(np.diag(moved), np.diag(moved)))
    assert np.max(np.abs(predicted - moved) / scale) < 0.1


def test_a_usable_result_says_what_a_shift_per_pose_would_add_unless_its_covariance_already_holds_it(scene):
    dataset, base = scene
    assert base.covariance_usable
    # on this dot scene 0.1 px per pose is twice the 1σ along some direction (the README's image_shift benchmark:
    # NEES 17 with nothing declared)
    excess = base.image_shift_excess(0.1)
    assert excess > 1.0
    line = image_shift_words(base)
    assert line is not None and "0.1 px per pose" in line and "--axis-floor-px" in line
    mm, deg = base.image_shift_sigma(0.1)
    assert f"{np.max(mm):.2g} mm" in line and f"{np.sqrt(excess):.1f}x its 1σ" in line
    assert line in summary(base)
    assert line in make_report(base, dataset).to_text()
    # declared as the axes' floor, the shift is in the covariance: nothing to say
    floored = calibrate(dataset, method="joint", options=CalibrationOptions(axis_floor_px=0.1))
    assert floored.image_shift_excess(0.1) < 1.0
    assert image_shift_words(floored) is None and "camera still?" not in summary(floored)
    # (the shift moves the estimate as much: the floor widens the covariance, not the response)
    np.testing.assert_allclose(floored.image_shift_covariance, base.image_shift_covariance, rtol=0.05, atol=1e-12)


def test_the_image_shift_covariance_is_saved_with_the_result(scene, tmp_path):
    _, base = scene
    base.save(tmp_path / "result.json")
    loaded = CalibrationResult.load(tmp_path / "result.json")
    np.testing.assert_allclose(loaded.image_shift_covariance, base.image_shift_covariance)
    assert image_shift_words(loaded) == image_shift_words(base)
    # a file written before it was computed has none, and says nothing of it
    old = CalibrationResult.from_dict({**base.to_dict(), "image_shift_covariance": None})
    assert old.image_shift_covariance is None and image_shift_words(old) is None


def test_a_measured_camera_move_is_in_the_covariance_and_a_measured_still_camera_silences_the_warning(scene):
    """``metadata["camera_motion"]`` (what ``make_dataset`` writes from the videos' still background): a move adds
    its level squared times the image shift covariance and is said; a still camera bounds the unseen shift by what
    the background resolves, far below the 0.1 px assumed otherwise."""
    dataset, base = scene
    moved = Dataset(dataset.arm, dataset.camera, list(dataset),
                    metadata={"camera_motion": {"floor_px": 0.15, "level_px": 0.07, "bound_px": 0.02}})
    result = calibrate(moved, method="joint")
    assert result.axis_floor_px == 0.0 and result.camera_motion["level_px"] == 0.07
    np.testing.assert_allclose(result.covariance, base.covariance + 0.07**2 * base.image_shift_covariance)
    text = summary(result)
    assert "camera moved between them, by up to 0.15 px (0.07 px per pose, 1σ per coordinate)" in text
    assert "camera still?" not in text
    still = Dataset(dataset.arm, dataset.camera, list(dataset),
                    metadata={"camera_motion": {"floor_px": 0.0, "level_px": 0.0, "bound_px": 0.02}})
    result = calibrate(still, method="joint")
    np.testing.assert_allclose(result.covariance, base.covariance)
    text = summary(result)
    assert "shows the camera still between them (any shift below 0.02 px)" in text and "camera still?" not in text
    assert image_shift_words(result, 0.1) is not None  # (an unmeasured 0.1 px would still be worth saying)
    loaded = CalibrationResult.from_dict(result.to_dict())
    assert loaded.camera_motion == result.camera_motion
    # still between the videos, moved during two of them: said so, and counted at its level
    names = [f"pose{k}.mp4" for k in range(len(dataset))]
    during = {"names": names, "floor_px": 0.3, "level_px": 0.07, "bound_px": 0.02, "moved": [False] * len(names),
              "drift_px": [[0.0, 0.0]] * len(names), "drifted": [k in (1, 4) for k in range(len(names))]}
    result = calibrate(Dataset(dataset.arm, dataset.camera, list(dataset), metadata={"camera_motion": during}),
                       method="joint")
    np.testing.assert_allclose(result.covariance, base.covariance + 0.07**2 * base.image_shift_covariance)
    line = next(line for line in summary(result).splitlines() if "camera motion" in line)
    assert "moved during pose1.mp4 and pose4.mp4, by up to 0.3 px" in line and "between" not in line


def _drifted(dataset: Dataset, drift) -> Dataset:
    """Each pose's tracks slid steadily by ``drift[k]`` (px) from its first frame to its last: a camera that moves
    during the video."""
    out = []
    for k, m in enumerate(dataset):
        first, last = min(int(t.frames.min()) for t in m.tracks), max(int(t.frames.max()) for t in m.tracks)
        out.append(Measurement(m.joint_angles, [
            Track(t.pixels + drift[k] * ((t.frames - first) / (last - first))[:, None], t.frames) for t in m.tracks],
            name=m.name))
    return Dataset(dataset.arm, dataset.camera, out)


def test_a_camera_that_moves_during_each_video_is_held_by_the_level_its_background_reading_gives(scene):
    """The ground truth is the joint estimate itself, fitted again with each pose's tracks sliding by its own drift
    (N(0, 0.5²) px per coordinate, eight draws): what the drift moved it by, against the level that
    ``CameraMotion`` (the background's first and last frames of each video) gives times the image shift covariance.
    Half the drift alone, as a shift, is not enough (one draw at 27.8, beyond the 99.9 % point)."""
    from gtsam_rotid.stillness import CameraMotion

    dataset, base = scene
    n = len(dataset)
    lengths = []
    for seed in range(8):
        drift = np.random.default_rng(seed).normal(0.0, 0.5, (n, 2))
        moved = base.arm_T_camera.localCoordinates(calibrate(_drifted(dataset, drift), method="joint").arm_T_camera)
        motion = CameraMotion(np.zeros((n, 2)), np.full((n, 2), 0.005), np.full(n, 100), [f"{k}" for k in range(n)],
                              drift, np.full((n, 2), 0.005))
        assert motion.drifted.all() and not motion.moved.any()
        lengths.append(float(moved @ np.linalg.solve(motion.level_px**2 * base.image_shift_covariance, moved)))
    assert max(lengths) < 22.46 and np.mean(lengths) < 6.0, np.round(lengths, 2)

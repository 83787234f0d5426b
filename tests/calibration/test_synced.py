"""Synced mode in the calibration (CalibrationOptions.sync_encoders): the spinning joint's readings set the rigid
spin's angles, the encoder clock's offset estimated; compared with the simulation's truth, which the estimator never
sees."""

from __future__ import annotations

import numpy as np
import pytest

from gtsam_rotid import CalibrationOptions, InputError, calibrate, summary
from gtsam_rotid.calibration.result import CalibrationResult
from gtsam_rotid.dataset import Dataset, Measurement, SpinReadings
from gtsam_rotid.graph import chi2_quantile
from gtsam_rotid.report import make_report
from gtsam_rotid.simulate import reference_scene

OFFSET = 0.037  # s: the encoder's clock ahead of the camera's (the simulator's encoder_time_offset)
CAMERA_MINUS_ENCODER = -OFFSET  # the result's and the options' convention (as bags and track --time-offset)


@pytest.fixture(scope="module")
def ramped():
    return reference_scene(seed=11, duration=12.0, spin_ramp=2.0, encoder_rate=100.0, encoder_sigma_deg=0.02,
                           encoder_time_offset=OFFSET)


def chi2(result, truth) -> float:
    error = result.error_to(truth.arm_T_camera)
    return float(error @ np.linalg.solve(result.covariance, error))


def test_synced_calibration_finds_the_clocks_offset_and_holds_its_covariance(ramped):
    """Ramped spins read 37 ms late: every measurement synced, the offset within 3 of its 1 sigma (itself below a
    frame at 30 fps), the pose within its covariance (99.9 % point), which is below the unsynced fit's on every
    axis; the summary says it in words; the result's file keeps it."""
    dataset, truth = ramped
    synced = calibrate(dataset)
    plain = calibrate(dataset, options=CalibrationOptions(sync_encoders=False))
    assert synced.synced == tuple(range(len(dataset))) and plain.synced == ()
    assert plain.time_offset_s is None and plain.time_offset_sigma_s is None
    assert synced.covariance_usable and synced.time_offset_prior_sigma_s == 0.1
    assert abs(synced.time_offset_s - CAMERA_MINUS_ENCODER) < 3 * synced.time_offset_sigma_s
    assert synced.time_offset_sigma_s < 1.0 / 30
    assert chi2(synced, truth) < 22.5
    assert np.all(np.diag(synced.covariance) < np.diag(plain.covariance))
    words = summary(synced)
    assert f"{1000 * synced.time_offset_s:+.2f} ms" in words and "every spin (synced)" in words
    assert "mostly its prior" not in words
    again = CalibrationResult.from_dict(synced.to_dict())
    assert again.synced == synced.synced and again.time_offset_s == synced.time_offset_s
    assert again.time_offset_sigma_s == synced.time_offset_sigma_s


def test_a_known_offset_is_held_and_a_steady_spin_leaves_it_to_its_prior(ramped):
    """time_offset_sigma_s=None holds the offset where the options put it; spins at one speed cannot date the frames
    (exact readings: nothing but their rate's changes could): the offset's 1 sigma is then its prior's, and the
    words say why."""
    dataset, _ = ramped
    held = calibrate(dataset, options=CalibrationOptions(time_offset_s=CAMERA_MINUS_ENCODER,
                                                         time_offset_sigma_s=None))
    assert held.time_offset_s == CAMERA_MINUS_ENCODER and held.time_offset_sigma_s is None and held.synced
    assert "(held)" in summary(held)
    steady, _ = reference_scene(seed=11, duration=8.0, encoder_rate=100.0, encoder_sigma_deg=0.0,
                                encoder_time_offset=OFFSET)
    result = calibrate(steady)
    assert result.synced and result.time_offset_sigma_s > 0.09
    assert "mostly its prior's 100 ms" in summary(result)


def test_spins_on_named_clocks_get_one_offset_each(ramped):
    """Readings naming their camera clock (SpinReadings.clock: videos placed on a joint series one by one): each
    clock's offset is its own variable. Three clocks, the frames of each shifted by its own amount (and the
    simulator's 37 ms): every clock's offset within 3 of its 1 sigma of the truth, the pose within its covariance;
    the single-offset fields are empty (three clocks), the words name each clock, the result's file keeps them."""
    dataset, truth = ramped
    shifts = {"a": 0.0, "b": 0.020, "c": -0.015}  # s added to the frames' camera times, per clock
    names = ["a", "b", "c"] * len(dataset)
    measurements = []
    for k, m in enumerate(dataset):
        r = m.spin_readings
        measurements.append(m.replace(spin_readings=SpinReadings(r.frame_times + shifts[names[k]], r.times, r.angles,
                                                                 clock=names[k])))
    result = calibrate(Dataset(dataset.arm, dataset.camera, measurements))
    assert result.synced == tuple(range(len(dataset))) and result.time_offset_s is None
    assert set(result.time_offsets) == set(shifts)
    for name, shift in shifts.items():
        clock = result.time_offsets[name]
        assert clock["measurements"] == [k for k in range(len(dataset)) if names[k] == name]
        assert clock["sigma_s"] < 1.0 / 30
        assert abs(clock["offset_s"] - (CAMERA_MINUS_ENCODER + shift)) < 3 * clock["sigma_s"], (name, clock)
    assert chi2(result, truth) < 22.5
    words = summary(result)
    assert "each of the 3 camera clocks its own offset" in words
    assert f"clock 'b' (measurements 1, 4): the clocks' offset (camera minus encoder) " \
           f"{1000 * result.time_offsets['b']['offset_s']:+.2f} ms" in words
    again = CalibrationResult.from_dict(result.to_dict())
    assert again.time_offsets == result.time_offsets
    assert "camera clocks" in make_report(result).to_text()


def test_readings_of_only_some_spins_sync_those():
    dataset, truth = reference_scene(seed=12, duration=8.0, spin_ramp=2.0, encoder_rate=100.0,
                                     encoder_sigma_deg=0.02, encoder_time_offset=OFFSET)
    measurements = [m if k % 2 == 0 else Measurement(m.joint_angles, m.tracks, spin_joint=m.spin_joint)
                    for k, m in enumerate(dataset)]
    result = calibrate(Dataset(dataset.arm, dataset.camera, measurements))
    assert result.synced == tuple(range(0, len(dataset), 2))
    assert "measurements 0, 2, 4" in summary(result)
    assert chi2(result, truth) < 22.5


@pytest.mark.parametrize(("field", "value", "words"), [
    ("sync_encoders", "yes", "must be True or False"),
    ("encoder_sigma_deg", 0.0, "encoder_sigma_deg must be a positive number of degrees"),
    ("time_offset_s", float("nan"), "time_offset_s must be a finite number of seconds"),
    ("time_offset_sigma_s", -1.0, "time_offset_sigma_s must be a positive number of seconds or None"),
])
def test_options_are_checked(field, value, words):
    with pytest.raises(InputError, match=words):
        CalibrationOptions(**{field: value})


def test_readings_that_disagree_with_the_tracks_are_named_and_left_out(ramped):
    """Readings of the other sense (or 10 % off in scale) on some spins: exactly those spins' likelihood ratios
    beyond their 99.9 % points, those spins fitted without the readings (named in words), the others synced, the
    pose within its covariance and the pixel noise what the tracks have (readings that held wrong angles had
    inflated it four times)."""
    dataset, truth = ramped
    good = calibrate(dataset)
    wrong = {1: -1.0, 4: 0.9}
    measurements = [m if k not in wrong else Measurement(
        m.joint_angles, m.tracks, spin_readings=SpinReadings(m.spin_readings.frame_times, m.spin_readings.times,
                                                             wrong[k] * m.spin_readings.angles))
        for k, m in enumerate(dataset)]
    result = calibrate(Dataset(dataset.arm, dataset.camera, measurements))
    assert sorted(result.readings_refused) == [1, 4]
    assert result.synced == tuple(k for k in range(len(dataset)) if k not in wrong)
    for v in result.readings_refused.values():
        assert v["chi2"] > chi2_quantile(v["dof"]) and v["dof"] > 100
    assert chi2(result, truth) < 22.5
    assert abs(result.sigma_px / good.sigma_px - 1.0) < 0.05
    words = summary(result)
    assert "measurement 1's readings disagree with the spin its tracks show" in words
    assert "measurement 4's readings disagree" in words
    again = CalibrationResult.from_dict(result.to_dict())
    assert again.readings_refused == result.readings_refused


@pytest.mark.parametrize("refined", [{"joint_offsets": True}, {"refine_intrinsics": True}])
def test_synced_with_joint_offsets_or_intrinsics_refined(ramped, refined):
    """The readings stay with the measurements whose joint readings the offsets shift (they were once dropped
    there), and sync with intrinsics refined (the rigid factor's third key): synced, the offset within 3 sigma, the
    pose within its covariance."""
    dataset, truth = ramped
    result = calibrate(dataset, options=CalibrationOptions(**refined))
    assert result.synced == tuple(range(len(dataset)))
    assert abs(result.time_offset_s - CAMERA_MINUS_ENCODER) < 3 * result.time_offset_sigma_s
    assert chi2(result, truth) < 22.5


def test_readings_too_noisy_to_date_the_frames_leave_the_offset_to_its_prior():
    """Readings with 1 degree of noise (declared): the noise in their rates would count as the offset's
    information (it came out 15-35 ms off at +-1.2 ms); their own noise now shows as most of it, and the offset
    keeps its prior's 1 sigma, in words."""
    dataset, _ = reference_scene(seed=13, duration=12.0, spin_ramp=2.0, encoder_rate=100.0, encoder_sigma_deg=1.0,
                                 encoder_time_offset=OFFSET)
    result = calibrate(dataset, options=CalibrationOptions(encoder_sigma_deg=1.0))
    assert result.synced and result.time_offset_noise_share > 0.25
    assert result.time_offset_sigma_s == 0.1 and abs(result.time_offset_s - CAMERA_MINUS_ENCODER) < 0.1
    assert "the readings cannot date the frames" in summary(result)


def test_readings_that_never_move_are_refused(ramped):
    """Readings of another joint (never moving): every spin's refused, the calibration that of the tracks alone."""
    dataset, truth = ramped
    still = Dataset(dataset.arm, dataset.camera, [m.replace(spin_readings=SpinReadings(
        m.spin_readings.frame_times, m.spin_readings.times, np.full(len(m.spin_readings.times), 0.3)))
        for m in dataset])
    result = calibrate(still)
    plain = calibrate(dataset, options=CalibrationOptions(sync_encoders=False))
    assert sorted(result.readings_refused) == list(range(len(dataset))) and result.synced == ()
    np.testing.assert_allclose(result.error_to(truth.arm_T_camera), plain.error_to(truth.arm_T_camera), atol=1e-9)


def test_readings_that_miss_a_spins_frames_leave_that_spin_unsynced(ramped):
    """Readings that stop 2 s before one spin's video ends: that spin is named and fitted without them (the others
    synced), not the whole calibration refused."""
    dataset, truth = ramped
    measurements = list(dataset)
    r = measurements[2].spin_readings
    keep = r.times < r.times[-1] - 2.0
    measurements[2] = measurements[2].replace(spin_readings=SpinReadings(r.frame_times, r.times[keep],
                                                                         r.angles[keep]))
    result = calibrate(Dataset(dataset.arm, dataset.camera, measurements))
    assert list(result.readings_refused) == [2] and result.readings_refused[2]["why"] == "cover"
    assert result.synced == (0, 1, 3, 4, 5) and chi2(result, truth) < 22.5
    assert "measurement 2's readings" in summary(result) and "do not cover its frames" in summary(result)
    assert CalibrationResult.from_dict(result.to_dict()).readings_refused == result.readings_refused


def test_indices_are_the_datasets_and_other_methods_say_they_ignore_the_readings(ramped):
    """With a measurement left out before the fit (one track: no image axis), the synced and refused indices are
    still the dataset's; weighted says it does not use the readings."""
    dataset, truth = ramped
    measurements = list(dataset)
    measurements[1] = measurements[1].replace(tracks=measurements[1].tracks[:1])
    r = measurements[3].spin_readings
    measurements[3] = measurements[3].replace(spin_readings=SpinReadings(r.frame_times, r.times, -r.angles))
    result = calibrate(Dataset(dataset.arm, dataset.camera, measurements))
    assert result.synced == (0, 2, 4, 5) and list(result.readings_refused) == [3]
    assert "measurement 3's readings disagree" in summary(result) and not result.readings_ignored
    weighted = calibrate(dataset, method="weighted")
    assert weighted.readings_ignored and weighted.synced == ()
    assert "not used by the weighted method" in summary(weighted)
    report = make_report(weighted, dataset)  # the report says so too, and keeps it in its JSON
    assert "not used by the weighted method" in report.to_text() and report.to_dict()["readings_ignored"] is True
    assert "not used by" not in make_report(result).to_text()

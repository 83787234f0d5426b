"""calibration.swaps: two measurements given in each other's place (videos or joint rows in the wrong order) are
named, by the result and by a refusal, and never where nothing was exchanged."""

from dataclasses import replace

import numpy as np
import pytest

from gtsam_rotid import Dataset, simulate
from gtsam_rotid.calibration import run
from gtsam_rotid.calibration.options import CalibrationOptions
from gtsam_rotid.calibration.setup import _setup
from gtsam_rotid.calibration.swaps import exchange_candidate
from gtsam_rotid.estimate import CalibrationError, CalibrationResult, calibrate
from gtsam_rotid.report import make_report
from gtsam_rotid.simulate import SceneConfig
from gtsam_rotid.words import summary, verdict


def _scene(seed: int, duration: float = 6.0, n_measurements: int = 6):
    return simulate.simulate(SceneConfig(duration=duration, n_measurements=n_measurements), seed)


def _exchanged(dataset: Dataset, a: int, b: int) -> Dataset:
    """The dataset with the tracks of measurements ``a`` and ``b`` exchanged (their videos given in each other's
    place); joint angles and everything else as recorded."""
    ms = list(dataset)
    ms[a], ms[b] = dataset[a].replace(tracks=dataset[b].tracks), dataset[b].replace(tracks=dataset[a].tracks)
    return Dataset(dataset.arm, dataset.camera, ms, metadata=dataset.metadata)


def test_a_result_names_the_exchanged_measurements(tmp_path):
    """Ten poses, two exchanged: the other eight hold the calibration, which completes with the two disagreeing,
    and the exchange is confirmed (the screen's exchanged miss 0.18 of the miss as given). On six poses (seed 1)
    the same path sat at the scale check's limit, features 0.50 m from the axis against 0.5: float-level
    differences turned it into a refusal (which names the exchange too, tested below)."""
    dataset, _ = _scene(3, n_measurements=10)
    result = calibrate(_exchanged(dataset, 1, 3), method="weighted")
    assert result.swapped is not None and result.swapped["measurements"] == [1, 3]
    assert result.swapped["swapped_miss_px"] <= 0.5 * result.swapped["miss_px"]
    assert 0.0 < result.swapped["sigma_mm"] < 10.0  # the calibration with the two exchanged back is sound
    assert not result.covariance_usable
    assert next(iter(result.untrusted)) == "swapped"
    assert verdict(result).startswith("NOT USABLE: measurements 1 and 3 look swapped")
    assert "order of the videos" in summary(result)
    report = make_report(result, _exchanged(dataset, 1, 3))
    assert report.suggestion.startswith("give each video with its own arm pose") and report.next_pose is None
    assert "NOT TRUSTED: measurements 1 and 3 look swapped" in report.to_text()
    result.save(tmp_path / "r.json")
    assert CalibrationResult.load(tmp_path / "r.json").swapped == result.swapped


def test_a_refusal_names_the_exchanged_measurements():
    dataset, _ = _scene(1)
    with pytest.raises(CalibrationError, match=r"measurements 2 and 5 look swapped.*The calibration itself said"):
        calibrate(_exchanged(dataset, 2, 5))


def test_a_refusal_names_the_exchange_where_the_axes_as_recorded_disagree():
    """Six 6 s spins (seed 6) as recorded are usable with axes that disagree (P 1e-7: short arcs' image axes are far
    from Gaussian) and a covariance their scatter scales; with measurements 0 and 2 exchanged the calibration is
    refused, and the screen finds the exchange, but its calibration was no confirmation while its axes had to agree:
    the refusal did not name it. With 1 and 3 exchanged the centres' axes, 5.9 px off the FK axes as recorded, fit
    0.59 times as well exchanged back: the screen now tries exchanges down to 0.7 of the miss (it asked for 0.5).
    As recorded, nothing is called swapped."""
    dataset, _ = _scene(6)
    with pytest.raises(CalibrationError, match=r"measurements 0 and 2 look swapped"):
        calibrate(_exchanged(dataset, 0, 2))
    swapped = _exchanged(dataset, 1, 3)
    options = CalibrationOptions()
    found = exchange_candidate(dataset.camera, _setup(dataset.arm, dataset.camera, list(swapped), options), options)
    assert found is not None and found["positions"] == [1, 3], found
    assert 0.5 < found["swapped_miss_px"] / found["miss_px"] < 0.7, found
    recorded = calibrate(dataset)
    assert recorded.covariance_usable and not recorded.axis_consistency.consistent and recorded.swapped is None


def test_the_screen_finds_the_exchange_and_nothing_as_recorded():
    dataset, _ = _scene(0, 10.0)
    options = CalibrationOptions()
    setup = _setup(dataset.arm, dataset.camera, list(dataset), options)
    assert exchange_candidate(dataset.camera, setup, options) is None          # as recorded
    lines = list(setup.centre_axes)
    lines[0], lines[4] = lines[4], lines[0]
    found = exchange_candidate(dataset.camera, replace(setup, centre_axes=lines), options)
    assert found is not None and found["positions"] == [0, 4]
    assert found["swapped_miss_px"] < 0.2 * min(found["miss_px"], found["next_miss_px"])
    three = _setup(dataset.arm, dataset.camera, list(dataset)[:3], options)  # three axes fit any order
    assert exchange_candidate(dataset.camera, replace(three, centre_axes=three.centre_axes[::-1]), options) is None


def test_a_wrong_camera_is_not_called_a_swap():
    dataset, _ = _scene(0, 10.0)
    wrong = Dataset(dataset.arm, dataset.camera.with_intrinsics_changed(focal_factor=1.05), list(dataset),
                    metadata=dataset.metadata)
    result = calibrate(wrong)
    assert not result.covariance_usable
    assert result.swapped is None and "swapped" not in result.untrusted
    assert "intrinsics" in result.untrusted
    assert np.isfinite(result.sigma_px)



def test_no_exchange_is_tried_where_the_axes_leave_the_pose_undetermined(single_crossing, monkeypatch):
    # every wrist axis through one point: an exchange keeps the axes, so its calibration (150 s of a 155 s single
    # crossing) can never be sound and is not run, whatever the screen says (here it is made to name one)
    dataset, _ = single_crossing
    screened = []
    monkeypatch.setattr(run, "exchange_candidates", lambda *a: screened.append(1) or [{
        "positions": [1, 3], "miss_px": 1.0, "swapped_miss_px": 0.1, "next_miss_px": 1.0}])
    calls = []
    original = run._calibrate
    monkeypatch.setattr(run, "_calibrate", lambda *a, **k: calls.append(1) or original(*a, **k))
    result = calibrate(dataset)
    assert len(calls) == 1 and not screened
    assert len(result.observability.unobservable_directions) == 1 and result.swapped is None
    assert not result.covariance_usable


def test_an_exchanged_measurement_seen_end_on_is_not_a_confident_number():
    """Seed 9's six 6 s spins, measurements 1 and 3 exchanged: stage 1 fitted the exchanged measurement 1 from its
    ellipses' centres only, into a poor minimum (7 of 11 tracks at 2.3x the others' noise), whose wide axis agreed
    with its wrong FK axis, and ``weighted`` called the result usable 80 mm off (the error's chi-square 38.7). Its
    fit from the FK axis too (``stage1._stage1``) keeps all 11 tracks, and the exchange is refused, and named: the
    screen's best exchange (3 and 5, 4.13 px RMS) is a wrong pair whose calibration is not sound, the next (1 and 3,
    4.48 px) is confirmed."""
    dataset, truth = _scene(9)
    try:
        result = calibrate(_exchanged(dataset, 1, 3), method="weighted")
    except CalibrationError as error:
        assert "measurements 1 and 3 look swapped" in str(error) and "poor minimum" in str(error), str(error)
        return
    e = truth.arm_T_camera.localCoordinates(result.arm_T_camera)
    assert not result.covariance_usable or float(e @ np.linalg.solve(result.covariance, e)) < 22.5

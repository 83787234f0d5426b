"""calibration.run's paths through stage 1: where arcs are short and the standard path's result is refused or not
usable, the paths whose first fit only places the pose (``_refined_stage1(..., placing=True)``) are a second chance,
a placing path that ends where another path did is dropped, and the joint fit chooses among all ends."""

from dataclasses import replace
from types import SimpleNamespace

import gtsam
import numpy as np
import pytest

import gtsam_rotid.calibration.choice as choice
import gtsam_rotid.calibration.run as run
from gtsam_rotid import simulate
from gtsam_rotid.calibration.result import Alternative
from gtsam_rotid.estimate import CalibrationError, calibrate
from gtsam_rotid.graph import chi2_quantile

START = gtsam.Pose3(gtsam.Rot3.Ypr(0.1, -0.2, 0.3), gtsam.Point3(0.4, -0.1, 0.9))
TWIN = START.compose(gtsam.Pose3(gtsam.Rot3.Rx(np.pi), gtsam.Point3(0.0, 0.0, 0.0)))
OFF = gtsam.Pose3(gtsam.Rot3.Rz(np.radians(20.0)), gtsam.Point3(0.0, 0.0, 0.0))
NEAR = gtsam.Pose3(gtsam.Rot3.Rz(np.radians(0.1)), gtsam.Point3(0.001, 0.0, 0.0))


def _stubbed(monkeypatch, end):
    calls = []

    def refined(arm, camera, measurements, start, setup, options, anchor, placing=False):
        calls.append(placing)
        return start.compose(end), [f"stage 1 placing={placing}"]

    monkeypatch.setattr(run, "_refined_stage1", refined)
    return calls


def test_the_standard_paths_keep_every_start(monkeypatch):
    calls = _stubbed(monkeypatch, NEAR)
    runs, anchors = run._paths(None, None, [], [START, START], ["a", "b"], SimpleNamespace(short_arcs=True), None)
    assert calls == [False, False] and anchors == ["a", "b"] and len(runs) == 2


def test_a_placing_path_that_ends_where_another_did_is_dropped(monkeypatch):
    calls = _stubbed(monkeypatch, NEAR)
    standard = [(START, ["stage 1 of the standard path"])]
    runs, anchors = run._paths(None, None, [], [START, TWIN], ["a", "b"], SimpleNamespace(short_arcs=True), None,
                               placing=True, after=standard)
    assert calls == [True, True]
    assert anchors == ["b"] and runs[0][0].equals(TWIN.compose(NEAR), 1e-12)  # START's ended by the standard one
    assert runs[0][1] == ["stage 1 placing=True"]


def _holds(result, truth) -> bool:
    xi = result.error_to(truth.arm_T_camera)
    return float(xi @ np.linalg.solve(result.covariance, xi)) < chi2_quantile(6)  # its 99.9 % region


@pytest.fixture(scope="module")
def short_scene():
    """Six 2.5 s spins (72 degree arcs: short) of 60 features: usable from the standard path."""
    return simulate.reference_scene(seed=5, duration=2.5, noise_var=0.5, n_features=60)


def _standard_off(monkeypatch):
    """The standard paths end 20 degrees off where they would (so that the placing paths' ends are new)."""
    original = run._refined_stage1

    def refined(arm, camera, measurements, start, setup, options, anchor, placing=False):
        pose, stage1 = original(arm, camera, measurements, start, setup, options, anchor, placing)
        return (pose, stage1) if placing else (pose.compose(OFF), stage1)

    monkeypatch.setattr(run, "_refined_stage1", refined)


def _ambiguous(result, delta_chi2: float = 0.0):
    """``result`` with a rival about as good as it, ``delta_chi2`` worse (so not usable)."""
    return replace(result, alternatives=[*result.alternatives,
                                         Alternative(result.arm_T_camera.compose(OFF), delta_chi2)])


def _spied(monkeypatch) -> list:
    """``run._refined_stage1`` as it is, recording each call's ``placing``."""
    original, calls = run._refined_stage1, []

    def refined(*args, **kwargs):
        calls.append(args[7] if len(args) > 7 else kwargs.get("placing", False))
        return original(*args, **kwargs)

    monkeypatch.setattr(run, "_refined_stage1", refined)
    return calls


@pytest.mark.parametrize("standard", ["refused", "ambiguous"])
def test_a_standard_result_refused_or_not_usable_gets_its_second_chance(monkeypatch, short_scene, standard):
    """The standard paths end 20 degrees off and their result is made refused, or ambiguous; the placing paths
    then run and the joint fit chooses among all ends: the calibration holds and is usable. The joint fit from each
    end is made once (the choice among all ends takes the standard paths' from the first)."""
    dataset, truth = short_scene
    _standard_off(monkeypatch)
    fitted, joint = [], choice._joint
    monkeypatch.setattr(choice, "_joint", lambda *a: fitted.append(id(a[4])) or joint(*a))  # (a[4]: stage 1's fits)
    original, counts = run._from_runs, []

    def from_runs(*args):
        counts.append(len(args[5]))  # (the runs)
        result = original(*args)
        if len(counts) == 1:  # the standard paths'
            if standard == "refused":
                raise CalibrationError("the standard paths' result, refused here")
            return _ambiguous(result)
        return result

    monkeypatch.setattr(run, "_from_runs", from_runs)
    result = calibrate(dataset)
    assert len(counts) == 2 and counts[1] > counts[0]  # all ends: the standard paths' and the placing ones
    assert len(fitted) == len(set(fitted)) == counts[1]
    assert result.covariance_usable and not result.ambiguous and _holds(result, truth)


def test_a_second_chance_that_is_not_usable_either_leaves_the_standard_result(monkeypatch, short_scene):
    dataset, _ = short_scene
    _standard_off(monkeypatch)
    original, counts = run._from_runs, []

    def from_runs(*args):
        counts.append(1)
        return _ambiguous(original(*args), 0.5 * (len(counts) - 1))  # the standard result's rival at 0, the next's 0.5

    monkeypatch.setattr(run, "_from_runs", from_runs)
    result = calibrate(dataset)
    assert len(counts) == 2 and result.ambiguous
    assert result.alternatives[-1].delta_chi2 == 0.0  # the standard result


def test_a_usable_standard_result_stands_alone(monkeypatch, short_scene):
    dataset, truth = short_scene
    calls = _spied(monkeypatch)
    result = calibrate(dataset)
    assert calls and not any(calls)
    assert result.covariance_usable and _holds(result, truth)


def test_thin_evidence_tries_the_second_chance_and_still_holds(monkeypatch):
    """Six 3 s spins of 12 features: not usable (thin evidence) from the standard path, so the placing paths run
    too; the result still holds its covariance against the truth."""
    dataset, truth = simulate.reference_scene(seed=5, duration=3.0, noise_var=0.5)
    calls = _spied(monkeypatch)
    result = calibrate(dataset)
    assert calls[0] is False and True in calls
    assert not result.covariance_usable and _holds(result, truth)


def test_long_arcs_take_the_standard_path_only(monkeypatch, noise_free_scene):
    dataset, truth = noise_free_scene
    calls = _spied(monkeypatch)
    result = calibrate(dataset)
    assert calls and not any(calls)
    assert _holds(result, truth)

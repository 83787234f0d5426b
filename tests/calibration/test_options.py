"""calibration.options: CalibrationOptions refuses misspelt or impossible settings instead of replacing them
by defaults."""

import re

import pytest

from gtsam_rotid import InputError
from gtsam_rotid.estimate import CalibrationOptions


def test_axis_consistency_option_is_checked():
    from gtsam_rotid.estimate import CalibrationOptions

    with pytest.raises(InputError, match="axis_consistency_p must be in"):
        CalibrationOptions(axis_consistency_p=1.5)


def test_joint_sigma_option_is_checked():
    from gtsam_rotid.estimate import CalibrationOptions

    with pytest.raises(InputError, match="joint_sigma_deg must be a finite value >= 0"):
        CalibrationOptions(joint_sigma_deg=-0.1)


@pytest.mark.parametrize(("options", "words"), [
    (dict(spin_model="rigd"), "spin_model must be one of 'free', 'rigid', got 'rigd'"),
    (dict(joint_model="lines"), "joint_model must be one of"),
    (dict(max_iterations=0), "max_iterations must be an integer >= 1"),
    (dict(restarts=-1), "restarts must be an integer >= 0"),
    (dict(outlier_track_z=float("nan")), "outlier_track_z must be a finite number"),
])
def test_misspelt_or_impossible_options_are_refused_not_replaced_by_defaults(options, words):
    with pytest.raises(InputError, match=re.escape(words)):
        CalibrationOptions(**options)
    assert CalibrationOptions(spin_model="rigid").spin_model == "rigid"


def test_axis_floor_option_is_checked():
    from gtsam_rotid.estimate import CalibrationOptions

    for bad in (-0.1, float("nan"), True, "0.1"):
        with pytest.raises(InputError, match="axis_floor_px must be None or a finite number >= 0"):
            CalibrationOptions(axis_floor_px=bad)
        with pytest.raises(InputError, match="track_offset_px must be None or a finite number >= 0"):
            CalibrationOptions(track_offset_px=bad)

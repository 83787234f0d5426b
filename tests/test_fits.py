"""Circles fitted about the estimate's wrist axes (gtsam_rotid.fits): they match the simulated noise and radii.

The scene and its ``weighted`` calibration are the session's ``reference_8s_weighted`` (tests/conftest.py), shared
with test_plots.py.
"""

import numpy as np
import pytest
from scene_parameters import REFERENCE_8S_NOISE_VAR as NOISE_VAR

from gtsam_rotid.fits import fit_tracks


@pytest.fixture(scope="module")
def reference(reference_8s_weighted):
    return reference_8s_weighted


def test_fitted_circles_explain_the_tracks_at_the_simulated_noise(reference):
    dataset, truth, result = reference
    fit = fit_tracks(result, dataset, 0)
    kept = set(range(dataset[0].n_tracks)) - set(result.measurements[0].rejected_tracks)
    assert set(fit.circles) == kept
    rms = np.sqrt(np.mean(fit.all_residuals**2))
    # the residuals are pixel noise (sigma^2 = 1.5 px^2), less the 2 fitted parameters per track
    assert rms == pytest.approx(np.sqrt(NOISE_VAR), rel=0.1)
    # each circle's radius (unit: camera-to-axis distance) matches its feature's true radius
    axis = truth.measurements[0].axis
    distance = axis.distance_to(truth.arm_T_camera.translation())[0]
    for j, (_, r) in fit.circles.items():
        assert r * distance == pytest.approx(truth.measurements[0].tracks[j].radius, rel=0.05)

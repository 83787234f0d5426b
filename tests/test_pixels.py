"""Tests of gtsam_rotid.pixels: rendered video -> tracks -> calibration, against the simulator's ground truth.

One short rendered scene (four 8 s spins of the reference scene, ~1000 frames) runs through :func:`run_demo` once
per session (the ``demo`` fixture, tests/conftest.py, shared with test_demo.py); the tests read its outputs.
"""

from __future__ import annotations

import numpy as np
import pytest
from scene_parameters import DEMO_DURATION as DURATION
from scene_parameters import DEMO_N_MEASUREMENTS as N_MEASUREMENTS

from gtsam_rotid import Track
from gtsam_rotid.pixels import TrackingAccuracy, tracking_accuracy

#: 99.9 % point of the chi-square distribution with 6 degrees of freedom.
CHI2_999_6DOF = 22.458


# ---------------------------------------------------------------------------------------------- pixels -> pose
def test_calibration_from_pixels_lands_within_its_reported_uncertainty(demo):
    """Seed 0 (the default, not chosen). Over seeds 0-9 of this configuration the chi-square averaged 16 and 4 of
    10 exceeded the 99.9 % point: from rendered pixels the reported covariance is ~1.6x too small in sigma, because
    the tracker's error normal to the arc is correlated along each track (see the issue-4 notes); this test guards
    the pipeline and the seed-0 value (6.1), not the calibration of the covariance over scenes."""
    _, run, _ = demo
    result, truth = run.result, run.truth
    assert result.covariance_usable
    error = result.error_to(truth.arm_T_camera)
    chi2 = float(error @ np.linalg.solve(result.covariance, error))
    assert chi2 < CHI2_999_6DOF, (chi2, np.degrees(error[:3]), 1000 * error[3:])
    # and it is a calibration worth having even from 8 s spins: a fraction of a degree and a few mm
    assert np.all(np.abs(np.degrees(error[:3])) < 0.5)
    assert np.all(np.abs(1000.0 * error[3:]) < 10.0)


def test_tracked_dataset_keeps_the_scene_and_tracks_to_a_tenth_of_a_pixel(demo):
    _, run, _ = demo
    scene = run.scene
    assert len(scene.dataset) == N_MEASUREMENTS == len(scene.tracking) == len(scene.accuracy) == len(scene.spins)
    n_frames = int(round(DURATION * 30))
    for k, (measurement, spin) in enumerate(zip(scene.dataset, scene.spins, strict=True)):
        assert spin.n_frames == n_frames
        assert measurement.n_tracks >= 2
        for track in measurement.tracks:  # frame numbers of the spin, inside it
            assert track.frames is not None and np.all(np.diff(track.frames) > 0)
            assert 0 <= track.frames[0] and track.frames[-1] < n_frames
        assert scene.tracking[k].n_frames == n_frames
    total = scene.total_accuracy
    assert total.matched_fraction > 0.999          # every tracked point lies on a rendered dot ...
    assert total.rms_px < 0.1                      # ... within a tenth of a pixel (RMS)
    assert total.n_mixed == 0                      # and no track hops between dots
    assert total.coverage > 0.5


def test_stage1_keeps_the_trackers_good_tracks(demo):
    """Every tracked point lies on one dot (above), so stage 1 should reject few tracks for their fit. It rejected
    17 of these 90 (and counted two twice) while it tested every track at one noise level: tracked dots differ in
    precision (~13 % in residual RMS beyond sampling), and a first round far from the final line ran short arcs'
    circles off to degenerate ones."""
    _, run, _ = demo
    dataset, result = run.scene.dataset, run.result
    for_fit = [why for m in result.measurements for why in m.rejected_tracks.values()
               if "does not fit" in why or "residual RMS" in why]
    assert len(for_fit) <= 0.05 * sum(len(m.tracks) for m in dataset), for_fit
    for m in result.measurements:
        assert m.n_tracks + len(m.rejected_tracks) == len(dataset[m.index].tracks)


# ---------------------------------------------------------------------------------------------- accuracy helper
def test_tracking_accuracy_matches_each_point_to_the_nearest_drawn_dot():
    truth = np.full((6, 3, 2), np.nan)
    truth[:, 0] = np.column_stack([np.arange(6.0) * 5, np.zeros(6)])
    truth[:, 1] = np.column_stack([np.arange(6.0) * 5, np.full(6, 20.0)])
    truth[3:, 2] = [[50.0, 50.0]] * 3
    offset = np.array([0.03, -0.04])                                   # 0.05 px off
    tracks = [Track(truth[:, 0] + offset, np.arange(6)),
              Track(truth[1:5, 1], np.arange(1, 5)),                   # exact
              Track(np.array([[50.0, 50.0], [90.0, 90.0]]), [3, 4])]  # second point far from every dot
    visible = ~np.isnan(truth[..., 0])
    acc = tracking_accuracy(tracks, truth, visible=visible)
    assert (acc.n_tracks, acc.n_points, acc.n_matched, acc.n_mixed) == (3, 12, 11, 0)
    assert acc.rms_px == pytest.approx(0.05 * np.sqrt(6 / 11))
    assert acc.max_px == pytest.approx(0.05)
    assert acc.coverage == pytest.approx(11 / visible.sum())
    assert acc.bias_px == pytest.approx(0.05 / np.sqrt(3))
    # frame numbers other than 0..F-1 are looked up
    shifted = tracking_accuracy([Track(t.pixels, t.frames + 100) for t in tracks], truth,
                                frame_indices=np.arange(100, 106))
    assert shifted.rms_px == pytest.approx(acc.rms_px)
    # a track that hops from one dot to another is counted
    hop = Track(np.vstack([truth[:3, 0], truth[3:, 1]]), np.arange(6))
    assert tracking_accuracy([hop], truth).n_mixed == 1
    pooled = TrackingAccuracy.pooled([acc, acc])
    assert pooled.n_points == 24 and pooled.rms_px == pytest.approx(acc.rms_px)
    assert pooled.coverage == pytest.approx(acc.coverage)


def test_mesh_rendered_scene_is_tracked_against_the_surface_truth():
    """The robot's own meshes (dots on the hand): every kept track lies on the spinning hand and follows the
    projection of the surface point it started on (the mesh renderer's ground truth, not the tracker's)."""
    from gtsam_rotid import simulate
    from gtsam_rotid.meshrender import MeshRenderConfig
    from gtsam_rotid.pixels import dataset_from_video

    dataset, truth = simulate.reference_scene(seed=0, duration=4.0, n_measurements=3)
    scene = dataset_from_video(dataset, truth, MeshRenderConfig(covering="dots"), progress=False)
    assert scene.dataset.metadata["video"]["renderer"] == "mesh"
    assert scene.dataset.metadata["video"]["covering"] == "dots"
    # the camera stayed still: its videos' background says so (read on each one's first frame)
    motion = scene.dataset.metadata["camera_motion"]
    assert motion["floor_px"] == 0.0 and len(motion["shifts_px"]) == 3 and max(
        abs(v) for shift in motion["shifts_px"] for v in shift) < 0.02
    total = scene.total_accuracy
    assert total.truth == "surface" and "not on the spinning hand" in total.summary()
    assert total.n_tracks >= 6 and total.n_mixed == 0  # nothing tracked on the background or the still links
    assert total.matched_fraction > 0.9 and total.median_px < 0.3, total.summary()

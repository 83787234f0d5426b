"""Tracks shifted by constant image offsets, as a tracker's errors that follow a feature: shared by test_stage1.py
(the cluster-robust covariance) and test_stage2.py (the floor and the declared track offsets)."""

import numpy as np

from gtsam_rotid import Dataset, Measurement, Track


def with_offsets(dataset, sigma_px: float, seed: int, per_track: bool = True) -> Dataset:
    """The dataset with one constant random image offset (``sigma_px`` per coordinate) added to every pixel of each
    track, independent across tracks (``per_track``: a tracker's error that follows a feature over its whole arc),
    or of each measurement, shared by all its tracks (an error common to a pose's tracks, which per-track scores
    cannot see)."""
    rng = np.random.default_rng(seed)
    measurements = []
    for m in dataset:
        tracks = [Track.from_any(t) for t in m.tracks]
        shared = None if per_track else sigma_px * rng.standard_normal(2)  # (per track: each its own draw)
        measurements.append(Measurement(m.joint_angles, [
            Track(t.pixels + (sigma_px * rng.standard_normal(2) if per_track else shared), t.frames)
            for t in tracks]))
    return Dataset(dataset.arm, dataset.camera, measurements)

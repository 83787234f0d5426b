"""Thinned tracks, as a tracker that finds little texture keeps them: shared by test_initial.py (the refusal of a
poor start names the tracking first) and test_run.py (thin evidence is flagged or holds its covariance)."""

import numpy as np

from gtsam_rotid import Dataset, Measurement, Track


def _thin(dataset, seed: int, n_tracks: int = 3, shortest: int = 20, longest: int = 90) -> Dataset:
    """At most ``n_tracks`` tracks per measurement, each cut to a random arc of ``shortest``-``longest`` frames
    (0.7-3 s at 30 fps: 20-86 degrees of a 0.5 rad/s spin): what a tracker that finds little texture keeps."""
    rng = np.random.default_rng(seed)
    measurements = []
    for m in dataset:
        tracks = list(m.tracks)
        rng.shuffle(tracks)
        cut = []
        for t in tracks:
            if len(t) < shortest:
                continue
            length = int(rng.integers(shortest, min(longest, len(t)) + 1))
            first = int(rng.integers(0, len(t) - length + 1))
            cut.append(Track(t.pixels[first:first + length], t.frames[first:first + length]))
            if len(cut) == n_tracks:
                break
        measurements.append(Measurement(m.joint_angles, cut))
    return Dataset(dataset.arm, dataset.camera, measurements, metadata=dataset.metadata)

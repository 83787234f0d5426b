"""The ground truth for a covariance per px² of an image shift per pose: the calibration fitted again with each
pose's pixels moved by a small step along x and along y in turn. Shared by test_image_shift.py (the pose),
test_offsets.py and test_intrinsics.py (the pose with what is refined)."""

import numpy as np

from gtsam_rotid import Dataset, Measurement, Track
from gtsam_rotid.estimate import calibrate


def shifted(dataset: Dataset, k: int, shift) -> Dataset:
    """The dataset with every pixel of pose ``k``'s tracks moved by ``shift`` (px, x and y)."""
    return Dataset(dataset.arm, dataset.camera, [
        Measurement(m.joint_angles, [Track(t.pixels + (shift if i == k else 0.0), t.frames) for t in m.tracks],
                    name=m.name) for i, m in enumerate(dataset)])


def refitted_shift_covariance(dataset: Dataset, base, extra=lambda result: np.zeros(0), step: float = 0.05,
                              **calibrate_args) -> np.ndarray:
    """The sum over poses and image directions of the outer products of how far the calibration moves (per px)
    when that pose's pixels move by ``step``: the covariance of ``[pose tangent, extra(result)]`` under a shift per
    pose of N(0, 1 px²) per image coordinate, to first order. ``base``: the calibration of ``dataset`` itself;
    ``calibrate_args``: as it was made."""
    start = np.asarray(extra(base), dtype=float)
    moved = np.zeros((6 + len(start),) * 2)
    for k in range(len(dataset)):
        for shift in (np.array([step, 0.0]), np.array([0.0, step])):
            result = calibrate(shifted(dataset, k, shift), **calibrate_args)
            d = np.concatenate([base.arm_T_camera.localCoordinates(result.arm_T_camera),
                                np.asarray(extra(result), dtype=float) - start]) / step
            moved += np.outer(d, d)
    return moved

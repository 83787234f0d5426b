"""Two measurements given in each other's place: videos, or joint rows, in the wrong order.

Each measurement's image axis belongs to the arm pose it was recorded at; given at another pose's joint angles it
is a wrong measurement that no camera pose explains, and the calibration either refuses or disagrees with itself
and blames the arm poses, the kinematics or the tracking. :func:`exchange_candidate` screens: it exchanges the
image axes of two measurements at a time and keeps the exchange that the FK axes fit best, where it fits far better
than the measurements as given. ``calibrate`` then calibrates again with the two exchanged, and names them only
where that calibration is sound (see :func:`gtsam_rotid.calibration.run._confirmed_swap`).
"""

from __future__ import annotations

import itertools

import gtsam
import numpy as np

from ..camera import Camera
from .initial import guess_free_minima
from .setup import _Setup
from .tuning import POSE_KEY, SWAP_ALL_PAIRS, SWAP_CANDIDATES, SWAP_SCREEN_RATIO

#: fewer measurements fit any assignment: three image axes give exactly the pose's six equations
MIN_SWAP_MEASUREMENTS = 4


def _fit(camera: Camera, axes, lines, options) -> tuple[float, np.ndarray]:
    """The guess-free fit of the FK ``axes`` to the image ``lines`` (candidates from the back-projected planes, LM
    on the unweighted stage-2 distances, as the calibration's start): its miss (px RMS over the test points) and
    each measurement's (px RMS); inf where no candidate puts the wrist in front of the camera."""
    n = len(axes)
    _, graph, minima = guess_free_minima(camera.K, axes, lines, options)
    if not minima:
        return float("inf"), np.full(n, np.inf)
    pose, error, _, _ = minima[0]
    values = gtsam.Values()
    values.insert(POSE_KEY, pose)
    each = np.array([np.sqrt(graph.at(k).error(values)) for k in range(n)])  # error = |r|^2 / 2 over 2 residuals
    return float(np.sqrt(error / n)), each


def exchange_candidate(camera: Camera, setup: _Setup, options) -> dict | None:
    """The two measurements (positions in ``setup``) whose exchanged image axes through the ellipses' centres
    (``setup.centre_axes``: they need no pose, which an exchange makes wrong) the FK axes fit best, where that fit
    misses at most :data:`SWAP_SCREEN_RATIO` times the miss as given; None otherwise, or with fewer than
    :data:`MIN_SWAP_MEASUREMENTS`. ``{"positions": [a, b], "miss_px"`` (as given), ``"swapped_miss_px"``
    (exchanged), ``"next_miss_px"`` (the next best exchange; None when only one was tried)``}``.

    Up to :data:`SWAP_ALL_PAIRS` measurements every pair is tried, beyond it the pairs among those the FK axes miss
    most as given. Each try is a guess-free fit (about 0.1 s), so the calibration asks only where something is wrong.
    """
    found = exchange_candidates(camera, setup, options, 1)
    return found[0] if found else None


def exchange_candidates(camera: Camera, setup: _Setup, options, count: int = SWAP_CANDIDATES) -> list[dict]:
    """Up to ``count`` exchanges that pass :func:`exchange_candidate`'s screen, best first (each as it gives the
    best; ``"next_miss_px"`` the exchange after it). The centres' axes of short spins are far off their true ones,
    and the best screened exchange can be a wrong pair: seed 9's six 6 s spins with measurements 1 and 3 exchanged
    screened 3 and 5 first (4.13 px RMS, 1 and 3 at 4.48)."""
    lines = [np.asarray(line, dtype=float) for line in setup.centre_axes]
    n = len(lines)
    if n < MIN_SWAP_MEASUREMENTS or n != len(setup.axes):
        return []
    miss, each = _fit(camera, setup.axes, lines, options)
    if not np.isfinite(miss) or miss <= 0.0:
        return []
    suspects = range(n) if n <= SWAP_ALL_PAIRS else np.argsort(-np.nan_to_num(each, nan=np.inf))[:SWAP_ALL_PAIRS]
    tried = []
    for a, b in itertools.combinations(sorted(int(k) for k in suspects), 2):
        exchanged = list(lines)
        exchanged[a], exchanged[b] = lines[b], lines[a]
        tried.append((_fit(camera, setup.axes, exchanged, options)[0], a, b))
    tried.sort()
    return [{"positions": [a, b], "miss_px": miss, "swapped_miss_px": float(best),
             "next_miss_px": float(tried[i + 1][0]) if i + 1 < len(tried) else None}
            for i, (best, a, b) in enumerate(tried[:count]) if best <= SWAP_SCREEN_RATIO * miss]


def exchanged(measurements: list, a: int, b: int) -> list:
    """``measurements`` with the tracks of ``a`` and ``b`` exchanged (each video given its other pose); their spin
    readings, placed by the videos on the poses' spans, are dropped."""
    out = list(measurements)
    out[a] = measurements[a].replace(tracks=measurements[b].tracks, spin_readings=None)
    out[b] = measurements[b].replace(tracks=measurements[a].tracks, spin_readings=None)
    return out


def swap_sentence(swap: dict) -> str:
    """Plain words for a confirmed exchange (:attr:`CalibrationResult.swapped`): the refusal's and the result's."""
    a, b = swap["measurements"]
    return (f"measurements {a} and {b} look swapped: with each one's tracks given the other's joint angles the "
            f"calibration is sound (the FK axes miss the image axes through the ellipses' centres by "
            f"{swap['swapped_miss_px']:.3g} px RMS instead of {swap['miss_px']:.3g} px). Check the order of the videos "
            "(or image folders) against the arm poses' joint rows, give each video with its own pose, and calibrate "
            "again")

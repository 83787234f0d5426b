"""Sub-pixel blob centres: each dot's intensity centroid over its connected region above a fraction of its contrast,
vectorised over the dots in buckets of window size, with its shape (inertia, skewness) for the tracker's tests.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields

import cv2
import numpy as np

_BOUND_SCALE, _BOUND_PAD = 1.5, 3.0  # a blob lies within 1.5 radius + 3 px of its point
_BUCKET = 8  # window half-sizes are rounded up to a multiple of this; one vectorised pass per size
_CONTRAST_PIXELS = 5  # the blob's contrast is the mean of its strongest pixels near the estimate


# ---------------------------------------------------------------------------------------------- centroids
@dataclass(frozen=True)
class Centres:
    """Output of :func:`refine_centres`, one entry per input point."""

    centres: np.ndarray   #: (n, 2) refined (u, v)
    ok: np.ndarray        #: (n,) bool: a blob of enough contrast, inside the image, near the start
    contrast: np.ndarray  #: (n,) grey levels of the blob's core above (bright) or below (dark) its surroundings
    polarity: np.ndarray  #: (n,) +1 bright blob, -1 dark blob
    radius: np.ndarray    #: (n,) semi-major axis (px) from the second moments
    inertia: np.ndarray   #: (n,) minor / major second moment
    skewness: np.ndarray  #: (n,) largest |third standardised moment| along the principal axes (0: symmetric)


def refine_centres(grey: np.ndarray, points, radii, polarity=None, *, neighbours=None, iterations: int = 1,
                   level: float = 0.35, max_shift: float = 1.5, min_contrast: float = 8.0) -> Centres:
    """Sub-pixel blob centres near ``points`` in a grey image, vectorised over the points.

    Per point, in a window around it: the background is the median of a ring just outside the blob
    (radius ``radii``), a constant because the blob hides what is behind it; the contrast ``C`` is the
    mean of the strongest few of ``s (I - background)`` in the blob's core (``s`` the polarity: +1 bright,
    -1 dark, taken from the core when ``polarity`` is None); the blob is the 4-connected region of pixels
    above ``level * C`` that holds the strongest core pixel (so a neighbouring blob, or the background
    beyond a gap, never counts), within ``1.5 radius + 3`` px; the point moves to the centroid of
    ``s (I - background) - level * C`` over it. The region does not depend on where inside the blob the
    point starts, so one pass (``iterations``) suffices; more re-centre the ring and the core on the
    previous pass's centroid.
    ``neighbours``: optional (n, K, 3) ``(u, v, radius)`` of other blobs (NaN rows for none) whose discs
    (radius + 1 px) are left out of the ring.

    ``ok`` is False for points whose window leaves the image, whose blob is empty, of contrast below
    ``min_contrast``, reaches its limit (merged with something else), or lies more than ``max_shift`` px
    from the start. The second and third moments of the blob give ``radius`` (semi-major axis),
    ``inertia`` (minor / major variance) and ``skewness``.
    """
    grey = np.asarray(grey)
    start = np.asarray(points, dtype=np.float64).reshape(-1, 2)
    n = len(start)
    radii = np.broadcast_to(np.asarray(radii, dtype=np.float64), (n,)).copy()
    if polarity is not None:
        polarity = np.broadcast_to(np.asarray(polarity, dtype=np.float64), (n,))
    if neighbours is not None:
        neighbours = np.asarray(neighbours, dtype=np.float64).reshape(n, -1, 3)
    out = Centres(start.copy(), np.zeros(n, bool), np.zeros(n), np.ones(n) if polarity is None else polarity.copy(),
                  radii.copy(), np.zeros(n), np.zeros(n))
    iterations = max(int(iterations), 1)
    # window half-size; windows of similar size go together, so that a few large blobs do not enlarge all
    half = np.ceil(np.maximum(_BOUND_SCALE * radii + _BOUND_PAD, radii + 4.0) + (iterations - 1) * max_shift + 1.0)
    bucket = _BUCKET * np.ceil(half / _BUCKET).astype(np.int64)
    for size in np.unique(bucket):
        idx = np.flatnonzero(bucket == size)
        part = _refine_group(grey, start[idx], radii[idx], None if polarity is None else polarity[idx],
                             None if neighbours is None else neighbours[idx], int(size), iterations, level,
                             max_shift, min_contrast)
        for f, values in zip(fields(Centres), part, strict=True):
            getattr(out, f.name)[idx] = values
    return out


def _refine_group(grey, start, radii, polarity, neighbours, half: int, iterations: int, level: float,
                  max_shift: float, min_contrast: float):
    """:func:`refine_centres` for points whose windows fit in (2 half + 1)² pixels; returns the fields of
    :class:`Centres` in order."""
    n = len(start)
    height, width = grey.shape
    centre_px = np.rint(np.nan_to_num(start)).astype(np.int64)
    inside = ((centre_px[:, 0] >= half) & (centre_px[:, 0] < width - half)
              & (centre_px[:, 1] >= half) & (centre_px[:, 1] < height - half)
              & np.all(np.isfinite(start), axis=1))
    centre_px[~inside] = half                          # any valid window; those points are not ok
    offsets = np.arange(-half, half + 1)
    patch = grey[centre_px[:, 1, None, None] + offsets[None, :, None],
                 centre_px[:, 0, None, None] + offsets[None, None, :]].astype(np.float32)       # (n, w, w)
    # offsets of the window's columns (x) and rows (y) from the start point
    x0 = (centre_px[:, 0] - start[:, 0])[:, None] + offsets[None, :]
    y0 = (centre_px[:, 1] - start[:, 1])[:, None] + offsets[None, :]
    free = None if neighbours is None else _away_from(neighbours, start, x0, y0)
    bound2 = ((_BOUND_SCALE * radii + _BOUND_PAD) ** 2)[:, None, None]
    shift = np.zeros((n, 2))
    region = None
    for _ in range(iterations):
        xs = (x0 - shift[:, 0, None]).astype(np.float32)
        ys = (y0 - shift[:, 1, None]).astype(np.float32)
        dist2 = xs[:, None, :] ** 2 + ys[:, :, None] ** 2                               # (n, w, w)
        r = radii[:, None, None]
        ring = (dist2 >= (r + 2.0) ** 2) & (dist2 <= (r + 4.0) ** 2)
        if free is not None:
            ring &= free
        if region is not None:
            ring &= ~region
        count = ring.sum(axis=(1, 2))
        background = np.nan_to_num(_masked_median(patch.reshape(n, -1), ring.reshape(n, -1)))
        signal = patch - background.astype(np.float32)[:, None, None]
        core_radius = np.maximum(1.5, 0.5 * radii)                                        # >= 7 pixels
        core = dist2 <= (core_radius**2)[:, None, None]
        if polarity is None:
            polarity = np.where((signal * core).sum(axis=(1, 2)) >= 0, 1.0, -1.0)
        signal *= polarity.astype(np.float32)[:, None, None]
        # contrast: the strongest core pixels (a thin ellipse does not fill its core), searched near the centre
        c = min(half, int(math.ceil(float(core_radius.max()) + float(np.abs(shift).max(initial=0.0)))) + 1)
        inner = slice(half - c, half + c + 1)
        candidates = np.where(core[:, inner, inner], signal[:, inner, inner], -np.inf).reshape(n, -1)
        contrast = np.partition(candidates, -_CONTRAST_PIXELS, axis=1)[:, -_CONTRAST_PIXELS:].mean(axis=1)
        floor = (level * np.maximum(contrast, 0.0)).astype(np.float32)[:, None, None]
        above = (signal > floor) & (dist2 <= bound2)
        # the blob grows from the strongest core pixel: two blobs that both reach into the core are not merged
        strongest = np.argmax(np.where(core, signal, -np.inf).reshape(n, -1), axis=1)
        region = _grow(strongest, above)
        spill = np.any(region & (dist2 > ((np.sqrt(bound2) - 1.0) ** 2)), axis=(1, 2))
        weights = np.where(region, signal - floor, 0.0).astype(np.float64)
        # raw moments up to order 3 at once: m[q, p] = sum(weights x^p y^q)
        powers_x = np.stack([np.ones_like(xs), xs, xs**2, xs**3], axis=2).astype(np.float64)      # (n, w, 4)
        powers_y = np.stack([np.ones_like(ys), ys, ys**2, ys**3], axis=1).astype(np.float64)      # (n, 4, w)
        m = powers_y @ weights @ powers_x
        total = m[:, 0, 0]
        safe = np.where(total > 0, total, 1.0)
        m = m / safe[:, None, None]
        mx, my = m[:, 0, 1], m[:, 1, 0]
        shift += np.where(total[:, None] > 0, np.column_stack([mx, my]), 0.0)
    radius, inertia, skewness = _shape(m, mx, my)
    ok = (inside & (total > 0) & (contrast >= min_contrast) & (count >= 8) & ~spill
          & (np.hypot(shift[:, 0], shift[:, 1]) <= max_shift))
    return start + shift, ok, contrast, polarity, radius, inertia, skewness


def _away_from(neighbours: np.ndarray, start: np.ndarray, x0: np.ndarray, y0: np.ndarray) -> np.ndarray | None:
    """(n, w, w) window pixels clear of every neighbouring blob (``neighbours``: (n, k, 3) u, v, radius; NaN none);
    ``x0``, ``y0``: the windows' column and row offsets from the start points. None when no neighbour is given."""
    free = None
    for k in range(neighbours.shape[1]):
        other = neighbours[:, k]
        valid = np.isfinite(other).all(axis=1)
        if not valid.any():
            continue
        other = np.where(valid[:, None], other, [-1e6, -1e6, 0.0])   # far away: excludes nothing
        ox = x0 + (start[:, 0] - other[:, 0])[:, None]
        oy = y0 + (start[:, 1] - other[:, 1])[:, None]
        away = ox[:, None, :] ** 2 + oy[:, :, None] ** 2 > ((other[:, 2] + 1.0) ** 2)[:, None, None]
        free = away if free is None else free & away
    return free


def _shape(m: np.ndarray, mx: np.ndarray, my: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(radius, inertia ratio, skewness) of blobs from their normalised raw moments ``m[q, p]`` up to order 3 and
    centroids (``mx``, ``my``)."""
    cxx, cyy, cxy = m[:, 0, 2] - mx**2, m[:, 2, 0] - my**2, m[:, 1, 1] - mx * my
    half_trace, det = 0.5 * (cxx + cyy), cxx * cyy - cxy**2
    root = np.sqrt(np.maximum(half_trace**2 - det, 0.0))
    major, minor = half_trace + root, np.maximum(half_trace - root, 0.0)
    radius = 2.0 * np.sqrt(np.maximum(major, 0.0))
    inertia = np.where(major > 0, minor / np.where(major > 0, major, 1.0), 0.0)
    # third central moments, along and across the major axis: a blob cut by an occluding edge is lopsided
    c30 = m[:, 0, 3] - 3 * mx * m[:, 0, 2] + 2 * mx**3
    c03 = m[:, 3, 0] - 3 * my * m[:, 2, 0] + 2 * my**3
    c21 = m[:, 1, 2] - 2 * mx * m[:, 1, 1] - my * m[:, 0, 2] + 2 * mx**2 * my
    c12 = m[:, 2, 1] - 2 * my * m[:, 1, 1] - mx * m[:, 2, 0] + 2 * my**2 * mx
    angle = 0.5 * np.arctan2(2.0 * cxy, cxx - cyy)
    a, b = np.cos(angle), np.sin(angle)
    along = a**3 * c30 + 3 * a**2 * b * c21 + 3 * a * b**2 * c12 + b**3 * c03
    across = -(b**3) * c30 + 3 * b**2 * a * c21 - 3 * b * a**2 * c12 + a**3 * c03
    skewness = np.maximum(np.abs(along) / np.maximum(major, 1e-6) ** 1.5,
                          np.abs(across) / np.maximum(minor, 0.05) ** 1.5)
    return radius, inertia, skewness


def _grow(seed: np.ndarray, allowed: np.ndarray) -> np.ndarray:
    """The 4-connected part of each window of ``allowed`` (n, h, w) that holds its ``seed`` pixel ((n,) flat
    indices into h x w); empty where the seed pixel is not allowed.

    The windows are laid side by side, one empty column apart, and labelled by one
    ``cv2.connectedComponents`` call: labels are unique across windows.
    """
    n, h, w = allowed.shape
    tiled = np.zeros((h, n, w + 1), np.uint8)
    tiled[:, :, :w] = allowed.transpose(1, 0, 2)
    count, labels = cv2.connectedComponents(tiled.reshape(h, n * (w + 1)), connectivity=4, ltype=cv2.CV_32S)
    labels = labels.reshape(h, n, w + 1)[:, :, :w].transpose(1, 0, 2)
    chosen = labels.reshape(n, -1)[np.arange(n), seed]                  # 0 (background) where not allowed
    return (labels == chosen[:, None, None]) & (chosen > 0)[:, None, None]


def _masked_median(values: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """Median over the ``mask``-ed entries of each row of (n, m) ``values`` (NaN for rows with none)."""
    count = mask.sum(axis=1)
    ordered = np.sort(np.where(mask, values, np.inf), axis=1)
    low = np.maximum((count - 1) // 2, 0)
    high = np.maximum(count // 2, 0)
    rows = np.arange(len(values))
    median = 0.5 * (ordered[rows, low] + ordered[rows, high])
    return np.where(count > 0, median, np.nan)

"""The tracker's rejection tests on whole tracks: jumps off a smooth arc split a track (leave-one-out quadratic
fits), short or barely moving pieces are rejected, and in ``features="auto"`` corner tracks on blob tracks are
duplicates.
"""

from __future__ import annotations

import math

import cv2
import numpy as np

from .dataset import Track
from .trackparams import RejectedTrack, RejectReason, TrackerParams


# ---------------------------------------------------------------------------------------------- filtering
def filter_tracks(tracks, params: TrackerParams | None = None) -> tuple[list[Track], list[RejectedTrack]]:
    """The tracker's rejection tests alone: (accepted, rejected) for tracks from anywhere.

    A track (Track or (N, 2) array; without frame indices the points count as consecutive frames) is
    split where it jumps off a smooth arc; every piece shorter than ``min_length`` points or whose
    bounding-box diagonal is below ``min_extent`` px is rejected.
    """
    params = params or TrackerParams()
    accepted, rejected, _ = _filter([Track.from_any(t, track=j) for j, t in enumerate(tracks)], params)
    return accepted, rejected


def _extent(pixels: np.ndarray) -> float:
    return float(np.hypot(*np.ptp(pixels, axis=0)))


def _filter(tracks: list[Track], params: TrackerParams):
    accepted: list[Track] = []
    rejected: list[RejectedTrack] = []
    n_jumps = n_outliers = 0
    for track_ in tracks:
        frames = track_.frames if track_.frames is not None else np.arange(len(track_))
        if len(track_) < params.min_length:
            rejected.append(RejectedTrack(RejectReason.SHORT, track_, f"{len(track_)} points"))
            continue
        extent = _extent(track_.pixels)
        if extent < params.min_extent:
            rejected.append(RejectedTrack(RejectReason.STATIC, track_, f"spans {extent:.2f} px"))
            continue
        pieces, jumps, outliers = split_at_jumps(frames, track_.pixels, params.jump_threshold, params.jump_window)
        n_jumps += jumps
        n_outliers += outliers
        for k, idx in enumerate(pieces):
            piece = Track(track_.pixels[idx], frames[idx]) if track_.frames is not None else Track(track_.pixels[idx])
            where = f" (piece {k + 1} of {len(pieces)} after a jump)" if len(pieces) > 1 else ""
            if len(piece) < params.min_length:
                rejected.append(RejectedTrack(RejectReason.SHORT, piece, f"{len(piece)} points{where}"))
            elif (extent := _extent(piece.pixels)) < params.min_extent:
                rejected.append(RejectedTrack(RejectReason.STATIC, piece, f"spans {extent:.2f} px{where}"))
            else:
                accepted.append(piece)
    accepted.sort(key=lambda t: (int(t.frames[0]) if t.frames is not None else 0, *t.pixels[0]))
    return accepted, rejected, (n_jumps, n_outliers)


def _kept_patches(pieces: list[Track], patches: list, kept: list[Track]) -> list:
    """The patch of each kept track: kept tracks are pieces (maybe with points dropped) in the same order."""
    out, i = [], 0
    for t in kept:
        while i < len(pieces) and not (pieces[i].frames[0] <= t.frames[0] and pieces[i].frames[-1] >= t.frames[-1]
                                       and np.isin(t.frames, pieces[i].frames).all()):
            i += 1
        out.append(patches[i] if i < len(pieces) and pieces[i].frames[0] == t.frames[0] else None)
        i += 1
    return out


def _blob_area(tracks: list[Track], size, margin: float):
    """uint8 image of where blob tracks went (their points, dilated by ``margin`` px), or None without any."""
    if not tracks or size is None:
        return None
    width, height = size
    area = np.zeros((height, width), np.uint8)
    points = np.rint(np.concatenate([t.pixels for t in tracks])).astype(np.int64)
    inside = (points[:, 0] >= 0) & (points[:, 0] < width) & (points[:, 1] >= 0) & (points[:, 1] < height)
    area[points[inside, 1], points[inside, 0]] = 1
    r = int(math.ceil(margin))
    return cv2.dilate(area, cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * r + 1, 2 * r + 1)))


def _inside(area: np.ndarray, pixels: np.ndarray) -> float:
    """Fraction of ``pixels`` on the nonzero part of ``area``."""
    q = np.rint(pixels).astype(np.int64)
    h, w = area.shape
    q[:, 0] = np.clip(q[:, 0], 0, w - 1)
    q[:, 1] = np.clip(q[:, 1], 0, h - 1)
    return float(np.mean(area[q[:, 1], q[:, 0]] > 0))


def loo_residuals(frames, pixels, window: int = 9) -> np.ndarray:
    """Distance (px) of each point from a quadratic in the frame index fitted to its ``window - 1``
    neighbours (a centred window, shifted at the ends), vectorised over the points."""
    t = np.asarray(frames, dtype=np.float64)
    p = np.asarray(pixels, dtype=np.float64)
    n = len(t)
    width = min(window, n)
    if width < 4:
        return np.zeros(n)
    half = window // 2
    start = np.clip(np.arange(n) - half, 0, n - width)
    idx = start[:, None] + np.arange(width)
    keep = (idx != np.arange(n)[:, None]).astype(np.float64)
    dt = (t[idx] - t[:, None]) / max(half, 1)
    design = np.stack([np.ones_like(dt), dt, dt * dt], axis=-1) * keep[..., None]      # (n, width, 3)
    normal = np.einsum("nwi,nwj->nij", design, design)
    rhs = np.einsum("nwi,nwk->nik", design, p[idx])
    try:
        coef = np.linalg.solve(normal, rhs)
    except np.linalg.LinAlgError:
        coef = np.stack([np.linalg.lstsq(a, b, rcond=None)[0] for a, b in zip(normal, rhs, strict=True)])
    return np.linalg.norm(p - coef[:, 0, :], axis=1)


def _side_fit(t: np.ndarray, p: np.ndarray, at: float) -> np.ndarray:
    degree = 2 if len(t) >= 5 else 1
    centre = t.mean()
    coef = np.polyfit(t - centre, p, degree)
    return np.array([np.polyval(coef[:, k], at - centre) for k in range(2)])


def split_at_jumps(frames, pixels, threshold: float = 1.0, window: int = 9):
    """Indices of the smooth pieces of one track: ``(pieces, n_jumps, n_bad_points)``.

    Points further than ``threshold`` px from a leave-one-out local quadratic fit (:func:`loo_residuals`)
    are bad; runs of them are dropped. Where the arcs on the two sides of a run do not meet (their
    quadratic fits, evaluated in the run's middle, differ by more than ``threshold``) the track jumped
    (e.g. to a neighbouring feature) and is split there. Repeats on each piece until no point is bad.
    """
    return _split(np.asarray(frames, dtype=np.float64), np.asarray(pixels, dtype=np.float64), threshold, window, 0)


def _split(t: np.ndarray, p: np.ndarray, threshold: float, window: int, depth: int):
    n = len(t)
    all_idx = np.arange(n)
    residual = loo_residuals(t, p, window)
    bad = residual > threshold
    if not bad.any() or depth > 8:
        return [all_idx], 0, 0
    half = window // 2
    # runs of bad points, joined when fewer than half a window of good points separates them
    where = np.flatnonzero(bad)
    runs = [[where[0], where[0]]]
    for i in where[1:]:
        if i - runs[-1][1] <= half:
            runs[-1][1] = i
        else:
            runs.append([i, i])
    keep = np.ones(n, bool)
    cuts = []
    for a, b in runs:
        keep[a:b + 1] = False
        left = np.arange(max(0, a - 2 * half), a)
        right = np.arange(b + 1, min(n, b + 1 + 2 * half))
        if len(left) < 3:
            keep[:a] = False
            continue
        if len(right) < 3:
            keep[b + 1:] = False
            continue
        middle = 0.5 * (t[a] + t[b])
        gap = np.linalg.norm(_side_fit(t[left], p[left], middle) - _side_fit(t[right], p[right], middle))
        if gap > threshold:
            cuts.append(b + 1)
    n_bad = int(n - keep.sum())
    jumps = len(cuts)
    pieces = []
    bounds = [0, *cuts, n]
    for lo, hi in zip(bounds[:-1], bounds[1:], strict=True):
        idx = all_idx[lo:hi][keep[lo:hi]]
        if len(idx) == 0:
            continue
        sub, sub_jumps, sub_bad = _split(t[idx], p[idx], threshold, window, depth + 1)
        pieces.extend(idx[s] for s in sub)
        jumps += sub_jumps
        n_bad += sub_bad
    return pieces, jumps, n_bad

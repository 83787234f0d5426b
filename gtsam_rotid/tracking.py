"""Feature tracks from images of the spinning wrist (the seed paper's "Arc Identification").

Features on the end effector are found by OpenCV's :class:`cv2.SimpleBlobDetector` (dark and bright
blobs), followed from frame to frame by pyramidal Lucas–Kanade with a forward–backward check, and each
tracked point is re-centred on its blob (:func:`refine_centres`: the intensity centroid of the blob's
connected region above a fraction of its contrast), which is what makes the points sub-pixel accurate:
LK alone drifts. A point whose blob is lost, too faint, too elongated, lopsided (cut by an occluding
edge) or merged with another is dropped; a track ends after a few such frames, and two tracks that meet
both end. Blobs are detected again every few frames and soon after a track is lost, so features that
rotate into view start new tracks; blobs that stay put are static background and are no longer followed.
Finally tracks that are too short, that barely move or that jump off a smooth arc are rejected (a jump
splits the track; an isolated bad point is dropped).

All processing is vectorised over the tracked points of a frame (one numpy pass per window size, one
``cv2.connectedComponents`` call); pixel coordinates follow OpenCV's convention (the centre of the
top-left pixel is (0, 0)), like :class:`~gtsam_rotid.camera.Camera`.

Entry points: :func:`track` (the list of accepted :class:`~gtsam_rotid.dataset.Track` s),
:class:`Tracker` (frame-at-a-time, and :class:`TrackingResult` with the rejected tracks and why),
:func:`filter_tracks` (the rejection tests alone, for tracks from elsewhere) and :func:`refine_centres`
(the sub-pixel blob centroid). The settings and results are in :mod:`gtsam_rotid.trackparams`, the
centroids in :mod:`gtsam_rotid.centroids`, the whole-track tests in :mod:`gtsam_rotid.trackfilter`, the corner
follower in :mod:`gtsam_rotid.corners`; all are importable from here.
"""

from __future__ import annotations

import os
from collections.abc import Iterable, Iterator
from dataclasses import dataclass, field, fields, replace
from pathlib import Path

import cv2
import numpy as np

from .centroids import Centres, refine_centres
from .corners import CornerFollower, tracks_from_log
from .dataset import Track
from .errors import InputError
from .frames import frames_of, open_source
from .spinfilter import link_fragments, spin_filter
from .trackfilter import _blob_area, _filter, _inside, _kept_patches, filter_tracks, loo_residuals, split_at_jumps
from .trackparams import (
    AXIS_FLOOR_PX,
    FEATURES,
    TRACK_OFFSET_PX,
    RejectedTrack,
    RejectReason,
    TrackerParams,
    TrackingResult,
    tracker_metadata,
)

#: Also importable from here: the settings, results and track tests live in their own modules.
__all__ = ["AXIS_FLOOR_PX", "FEATURES", "TRACK_OFFSET_PX", "Centres", "RejectReason", "RejectedTrack", "Tracker",
           "TrackerParams", "TrackingResult", "filter_tracks", "frame_source", "loo_residuals", "refine_centres",
           "split_at_jumps", "track", "tracker_metadata"]

#: File name endings read as images when ``frames`` is a folder.

_MIN_IMAGE_SIDE = 16
_MAX_SHIFT_MARGIN = 2.0
_BLOB_AREA_MARGIN = 15.0  # features="auto": corner tracks mostly this close to blob tracks' points are dropped


# ---------------------------------------------------------------------------------------------- input
def _as_grey(image, where: str) -> np.ndarray:
    if not isinstance(image, np.ndarray):
        raise InputError(f"{where}: expected an 8-bit image (a numpy uint8 array), got {type(image).__name__}")
    if image.dtype != np.uint8:
        raise InputError(f"{where}: expected an 8-bit image (dtype uint8), got dtype {image.dtype}; convert it, "
                         f"e.g. with cv2.convertScaleAbs or np.clip(...).astype(np.uint8)")
    if image.ndim == 3 and image.shape[2] == 1:
        image = image[:, :, 0]
    if image.ndim == 2:
        grey = image
    elif image.ndim == 3 and image.shape[2] in (3, 4):
        grey = cv2.cvtColor(np.ascontiguousarray(image),
                            cv2.COLOR_BGR2GRAY if image.shape[2] == 3 else cv2.COLOR_BGRA2GRAY)
    else:
        raise InputError(f"{where}: expected a grey (H, W) or BGR (H, W, 3) image, got shape {image.shape}")
    if min(grey.shape) < _MIN_IMAGE_SIDE:
        raise InputError(f"{where}: the image is {grey.shape[1]}x{grey.shape[0]} pixels, too small to track "
                         f"(at least {_MIN_IMAGE_SIDE}x{_MIN_IMAGE_SIDE})")
    return np.ascontiguousarray(grey)


def _path_frames(frames: Iterator[np.ndarray], path: Path, first: int = 0) -> Iterator[tuple[np.ndarray, str]]:
    for index, image in enumerate(frames, first):
        yield image, f"frame {index} of {path}"


def _array_frames(frames: Iterable) -> Iterator[tuple[np.ndarray, str]]:
    for index, image in enumerate(frames):
        yield image, f"frame {index}"


def frame_source(frames) -> tuple[Iterator[tuple[np.ndarray, str]], int | None]:
    """(iterator of (image, description), number of frames when known) for any accepted ``frames``:
    an iterable of 8-bit images, an (F, H, W[, 3]) uint8 array, a video file or a folder of images."""
    if isinstance(frames, str | os.PathLike):
        path = Path(frames)
        images, total, first = frames_of(open_source(path), None)   # the one frame reader checks the path
        return _path_frames(images, path, first), total
    if isinstance(frames, np.ndarray):
        if frames.ndim == 3 and frames.shape[2] in (3, 4) and min(frames.shape[:2]) >= _MIN_IMAGE_SIDE:
            raise InputError(f"got one {frames.shape} image, not a sequence of frames: pass a list of images or an "
                             f"(F, H, W) / (F, H, W, 3) array")
        if frames.ndim not in (3, 4):
            raise InputError(f"a frame array must have shape (F, H, W) or (F, H, W, 3), got shape {frames.shape}")
        return _array_frames(frames), len(frames)
    if isinstance(frames, bytes | bytearray):
        raise InputError("frames must be images, an array, a video path or a folder path, not bytes")
    try:
        iterator = iter(frames)
    except TypeError:
        raise InputError(f"frames must be an iterable of 8-bit images, an (F, H, W[, 3]) uint8 array, a video "
                         f"file or a folder of images; got {type(frames).__name__}") from None
    total = len(frames) if hasattr(frames, "__len__") else None
    return _array_frames(iterator), total


# ---------------------------------------------------------------------------------------------- tracker
@dataclass
class _Active:
    """The tracks being followed, one row each."""

    ids: np.ndarray = field(default_factory=lambda: np.empty(0, np.int64))
    pos: np.ndarray = field(default_factory=lambda: np.empty((0, 2)))        # last point
    vel: np.ndarray = field(default_factory=lambda: np.empty((0, 2)))        # px per frame (smoothed)
    radius: np.ndarray = field(default_factory=lambda: np.empty(0))
    polarity: np.ndarray = field(default_factory=lambda: np.empty(0))
    missed: np.ndarray = field(default_factory=lambda: np.empty(0, np.int64))  # frames missed since pos
    count: np.ndarray = field(default_factory=lambda: np.empty(0, np.int64))   # points so far
    lo: np.ndarray = field(default_factory=lambda: np.empty((0, 2)))         # bounding box of the points
    hi: np.ndarray = field(default_factory=lambda: np.empty((0, 2)))

    def __len__(self) -> int:
        return len(self.ids)

    def keep(self, mask: np.ndarray) -> None:
        for f in fields(self):
            setattr(self, f.name, getattr(self, f.name)[mask])

    def add(self, ids, pos, radius, polarity) -> None:
        n = len(ids)
        new = dict(ids=ids, pos=pos, vel=np.zeros((n, 2)), radius=radius, polarity=polarity,
                   missed=np.zeros(n, np.int64), count=np.ones(n, np.int64), lo=pos, hi=pos)
        for name, values in new.items():
            setattr(self, name, np.concatenate([getattr(self, name), values]))

    def predicted(self, ahead: int = 0) -> np.ndarray:
        """Where each track is expected ``ahead`` frames after the last frame."""
        return self.pos + self.vel * (self.missed + ahead)[:, None]


class Tracker:
    """Frame-at-a-time tracker: :meth:`feed` each image, then :meth:`finish`; or :meth:`run` on a sequence."""

    def __init__(self, params: TrackerParams | None = None):
        if params is None:
            params = TrackerParams()
        if not isinstance(params, TrackerParams):
            raise InputError(f"params must be a TrackerParams, got {type(params).__name__}")
        self.params = params
        self._detector = cv2.SimpleBlobDetector_create(_detector_params(params))
        self._lk = dict(winSize=(params.lk_window, params.lk_window), maxLevel=int(params.lk_levels),
                        criteria=(cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, int(params.lk_iterations),
                                  float(params.lk_epsilon)),
                        flags=cv2.OPTFLOW_USE_INITIAL_FLOW)
        self._r_min, self._r_max = params.radius_range
        self._size: tuple[int, int] | None = None
        self._prev: np.ndarray | None = None
        self._frame = -1
        self._next_id = 0
        self._active = _Active()
        self._parked = np.empty((0, 3))            # (u, v, radius) of static blobs no longer followed
        self._last_detection = -(10**9)
        self._lost_since_detection = False
        self._detections = 0
        self._log: list[tuple[int, np.ndarray, np.ndarray]] = []
        self._blobs_on = params.features in ("blobs", "auto")
        self._corners = CornerFollower(params) if params.features in ("corners", "auto") else None

    @property
    def n_frames(self) -> int:
        """Frames fed so far."""
        return self._frame + 1

    @property
    def n_active(self) -> int:
        """Tracks currently followed (including those inside an allowed gap)."""
        return len(self._active)

    def feed(self, image, where: str | None = None) -> None:
        """Track one 8-bit grey or BGR image (the next frame); ``where`` names it in error messages."""
        where = where or f"frame {self._frame + 1}"
        grey = _as_grey(image, where)
        size = (grey.shape[1], grey.shape[0])
        if self._size is None:
            self._size = size
        elif size != self._size:
            raise InputError(f"{where} is {size[0]}x{size[1]} but the first frame is "
                             f"{self._size[0]}x{self._size[1]}: every frame must have the same size")
        self._frame += 1
        if self._blobs_on:
            if self._prev is not None and len(self._active):
                self._follow(grey)
            p = self.params
            since = self._frame - self._last_detection
            if since >= p.detect_every or (self._lost_since_detection and since >= p.detect_after_loss):
                self._detect(grey)
        if self._corners is not None:
            a = self._active
            exclude = np.column_stack([a.pos, a.radius]) if len(a) else None
            self._corners.feed(grey, self._frame, exclude)
        self._prev = grey

    def _refine(self, grey, points, radii, polarity, neighbours) -> Centres:
        p = self.params
        centres = refine_centres(grey, points, radii, polarity, neighbours=neighbours,
                                 iterations=p.centroid_iterations, level=p.centroid_level,
                                 max_shift=p.max_recentre_shift, min_contrast=p.min_contrast)
        if p.recentre:
            return centres
        n = len(centres.ok)                          # LK's points; the blob is only checked
        return replace(centres, centres=np.asarray(points, dtype=np.float64).reshape(n, 2))

    def _usable(self, centres: Centres) -> np.ndarray:
        p = self.params
        good = centres.ok & (centres.inertia >= p.min_inertia_ratio)
        if p.max_skewness > 0:
            good &= centres.skewness <= p.max_skewness
        return good

    def _follow(self, grey: np.ndarray) -> None:
        p, a = self.params, self._active
        prev_pts = a.predicted().astype(np.float32).reshape(-1, 1, 2)
        guess = a.predicted(1).astype(np.float32).reshape(-1, 1, 2)
        pts, status, _ = cv2.calcOpticalFlowPyrLK(self._prev, grey, prev_pts, guess, **self._lk)
        back, status_back, _ = cv2.calcOpticalFlowPyrLK(grey, self._prev, pts, prev_pts.copy(), **self._lk)
        fb_error = np.linalg.norm((back - prev_pts).reshape(-1, 2), axis=1)
        ok = (status.ravel() == 1) & (status_back.ravel() == 1) & (fb_error < p.fb_threshold)
        pts = pts.reshape(-1, 2).astype(np.float64)
        everyone = np.where(ok[:, None], pts, guess.reshape(-1, 2))     # where every track is now, roughly
        found = np.flatnonzero(ok)
        neighbours = _neighbours(pts[found], a.radius[found], everyone, a.radius, found)
        centres = self._refine(grey, pts[found], a.radius[found], a.polarity[found], neighbours)
        good = (self._usable(centres) & (centres.radius <= p.max_radius_growth * a.radius[found] + 0.5))
        found, centres = found[good], _subset(centres, good)
        ended = np.zeros(len(a), bool)
        if len(found) > 1:
            clash = _clashes(centres.centres, a.radius[found], p.min_separation)
            ended[found[clash]] = True
            found, centres = found[~clash], _subset(centres, ~clash)
        if len(found):
            new = centres.centres
            step = (new - a.pos[found]) / (a.missed[found] + 1)[:, None]
            a.vel[found] = 0.5 * a.vel[found] + 0.5 * step
            a.pos[found] = new
            a.radius[found] = np.clip(0.5 * a.radius[found] + 0.5 * centres.radius, self._r_min, self._r_max)
            a.count[found] += 1
            a.lo[found] = np.minimum(a.lo[found], new)
            a.hi[found] = np.maximum(a.hi[found], new)
            self._log.append((self._frame, a.ids[found].copy(), new.copy()))
        missed = np.ones(len(a), bool)
        missed[found] = False
        a.missed[missed] += 1
        a.missed[found] = 0
        ended |= a.missed > p.max_gap
        if ended.any() and np.any(a.count[ended] >= p.min_length):
            self._lost_since_detection = True          # an established track ended: look for new features
        parked = (a.count >= p.park_after) & (np.hypot(*(a.hi - a.lo).T) < p.park_extent) & ~ended
        if parked.any():
            zones = np.column_stack([a.pos[parked], a.radius[parked]])
            self._parked = np.concatenate([self._parked, zones])
        if ended.any() or parked.any():
            a.keep(~(ended | parked))

    def _detection_window(self, shape: tuple[int, int]) -> tuple[int, int, int, int]:
        """(x0, y0, x1, y1): around the moving tracks (where new features rotate into view), or the whole
        image every ``full_detect_every``-th detection and while nothing moves."""
        p, a = self.params, self._active
        height, width = shape
        self._detections += 1
        moving = (a.count >= 3) & (np.hypot(*(a.hi - a.lo).T) >= 1.0)
        if not moving.any() or p.full_detect_every <= 1 or self._detections % p.full_detect_every == 1:
            return 0, 0, width, height
        margin = p.detect_margin + 2.0 * float(a.radius[moving].max())
        lo = np.floor(a.pos[moving].min(axis=0) - margin).astype(int)
        hi = np.ceil(a.pos[moving].max(axis=0) + margin).astype(int) + 1
        return max(lo[0], 0), max(lo[1], 0), min(hi[0], width), min(hi[1], height)

    def _detect(self, grey: np.ndarray) -> None:
        p, a = self.params, self._active
        self._last_detection = self._frame
        self._lost_since_detection = False
        x0, y0, x1, y1 = self._detection_window(grey.shape)
        keypoints = self._detector.detect(grey[y0:y1, x0:x1])
        if not keypoints:
            return
        points = np.array([k.pt for k in keypoints], dtype=np.float64) + [x0, y0]
        radii = np.clip(np.array([k.size for k in keypoints]) / 2.0, self._r_min, self._r_max)
        # keypoints on a blob already followed, or on a parked static one, start nothing
        taken = np.concatenate([np.column_stack([a.predicted(), a.radius]), self._parked])
        fresh = _far_from(points, radii, taken, p.min_separation)
        points, radii = points[fresh], radii[fresh]
        if not len(points):
            return
        current = a.predicted()
        others = np.concatenate([current, points])
        other_radii = np.concatenate([a.radius, radii])
        neighbours = _neighbours(points, radii, others, other_radii, len(current) + np.arange(len(points)))
        centres = self._refine(grey, points, radii, None, neighbours)
        centres = _subset(centres, self._usable(centres))
        new_pts, polarity = centres.centres, centres.polarity
        radii = np.clip(centres.radius, self._r_min, self._r_max)
        # the same blob found twice (e.g. at two thresholds): keep the first
        distinct = np.ones(len(new_pts), bool)
        for i in range(1, len(new_pts)):
            if np.any(np.linalg.norm(new_pts[:i][distinct[:i]] - new_pts[i], axis=1) < 1.0):
                distinct[i] = False
        new_pts, radii, polarity = new_pts[distinct], radii[distinct], polarity[distinct]
        free = ~_clashes(new_pts, radii, p.min_separation)
        free &= _far_from(new_pts, radii, taken, p.min_separation)
        if not free.any():
            return
        new_pts, radii, polarity = new_pts[free], radii[free], polarity[free]
        ids = np.arange(self._next_id, self._next_id + len(new_pts))
        self._next_id += len(new_pts)
        a.add(ids, new_pts, radii, polarity)
        self._log.append((self._frame, ids, new_pts.copy()))

    def raw_tracks(self) -> list[Track]:
        """Every track followed so far, unfiltered, ordered by start frame."""
        if not self._log:
            return []
        return tracks_from_log(self._log)[0]

    def finish(self) -> TrackingResult:
        """Filter the tracks (see :func:`filter_tracks`; corner tracks are also tested against the spin's shared
        rotation and linked across occlusions, see :mod:`gtsam_rotid.corners`) and return the result; the
        tracker can go on."""
        raw = self.raw_tracks()
        accepted, rejected, stats = _filter(raw, self.params)
        result = TrackingResult(accepted, rejected, self.n_frames, self._size, len(raw), stats[0], stats[1],
                                self.params)
        if self._corners is not None:
            self._finish_corners(result)
        result.tracks.sort(key=lambda t: (int(t.frames[0]), *t.pixels[0]))
        return result

    def _finish_corners(self, result: TrackingResult) -> None:
        p = self.params
        raw, patches, ids = self._corners.raw_tracks()
        result.n_raw_tracks += len(raw)
        pieces, piece_patches = [], []
        for track_, track_id in zip(raw, ids, strict=True):
            accepted, rejected, (jumps, outliers) = _filter([track_], p)
            result.rejected.extend(rejected)
            result.n_jumps += jumps
            result.n_outliers += outliers
            for piece in accepted:
                pieces.append(piece)
                piece_patches.append(patches.get(track_id) if piece.frames[0] == track_.frames[0] else None)
        kept, spin_rejected, fit = spin_filter(pieces, p)
        reasons = {"ellipse": RejectReason.OFF_ELLIPSE, "rate": RejectReason.NOT_TURNING}
        result.rejected.extend(RejectedTrack(reasons[code], t, detail) for code, t, detail in spin_rejected)
        result.n_off_ellipse_points = fit.n_dropped_points
        if fit.model is not None:
            result.spin_rate = fit.model.omega
        # spin_filter keeps the order of its input: the patches of the kept tracks
        kept_patches = _kept_patches(pieces, piece_patches, kept)
        if p.link:
            kept, result.n_links = link_fragments(kept, kept_patches, fit, p)
        blob_area = _blob_area(result.tracks, self._size, _BLOB_AREA_MARGIN)
        for t in kept:
            if len(t) < p.min_length:
                result.rejected.append(RejectedTrack(RejectReason.SHORT, t, f"{len(t)} points after the spin tests"))
            elif blob_area is not None and (inside := _inside(blob_area, t.pixels)) > 0.5:
                result.rejected.append(RejectedTrack(RejectReason.DUPLICATE, t, f"{100 * inside:.0f} % of its "
                                                     f"points within {_BLOB_AREA_MARGIN:g} px of blob tracks"))
            else:
                result.tracks.append(t)
                result.n_corner_tracks += 1

    def run(self, frames, *, progress: bool = False) -> TrackingResult:
        """Track every frame of ``frames`` (see :func:`track`; after any frames already fed) and
        :meth:`finish`. ``progress`` draws a tqdm bar on stderr."""
        source, total = frame_source(frames)
        if progress:
            from tqdm import tqdm

            source = tqdm(source, total=total, unit="frame", desc="tracking")
        for image, where in source:
            self.feed(image, where)
        if self.n_frames == 0:
            raise InputError("no frames: the input holds no images")
        return self.finish()


def track(frames, params: TrackerParams | None = None, *, progress: bool = False) -> list[Track]:
    """Track the features of a wrist spin. Returns the accepted tracks, sorted by start frame.

    ``frames``: an iterable of 8-bit grey (H, W) or BGR (H, W, 3) images, an (F, H, W[, 3]) uint8 array, a
    video file path or a folder of images (read in sorted name order). Each :class:`Track` has
    ``.frames`` (the index of the frame of each point) and ``.pixels`` ((N, 2) float, raw pixels).
    ``Tracker(params).run(frames)`` also returns the rejected tracks and why. Bad input raises
    :class:`~gtsam_rotid.errors.InputError` naming the frame.
    """
    return Tracker(params).run(frames, progress=progress).tracks


# ---------------------------------------------------------------------------------------------- helpers
def _detector_params(p: TrackerParams) -> cv2.SimpleBlobDetector_Params:
    d = cv2.SimpleBlobDetector_Params()
    d.filterByColor = False                      # dark and bright blobs in one pass
    d.filterByArea = True
    d.minArea, d.maxArea = float(p.min_area), float(p.max_area)
    d.filterByCircularity = p.min_circularity > 0
    d.minCircularity = float(p.min_circularity)
    d.filterByConvexity = p.min_convexity > 0
    d.minConvexity = float(p.min_convexity)
    d.filterByInertia = p.min_inertia_ratio > 0
    d.minInertiaRatio = float(p.min_inertia_ratio)
    d.minThreshold, d.maxThreshold = float(p.min_threshold), float(p.max_threshold)
    d.thresholdStep = float(p.threshold_step)
    d.minRepeatability = 2
    d.minDistBetweenBlobs = 2.0
    return d


def _subset(c: Centres, mask) -> Centres:
    return Centres(*(getattr(c, f.name)[mask] for f in fields(Centres)))


def _neighbours(points, radii, others, other_radii, own, k: int = 2) -> np.ndarray | None:
    """(n, k, 3) ``(u, v, radius)`` of the ``k`` nearest of ``others`` (skipping each point's own index in
    ``own``) close enough to disturb its re-centring window; NaN rows for none; None when there are none."""
    if len(points) == 0 or len(others) < 2:
        return None
    gap = np.linalg.norm(points[:, None, :] - others[None, :, :], axis=2)
    gap[np.arange(len(points)), own] = np.inf
    reach = 1.5 * radii + 4.0 + _MAX_SHIFT_MARGIN                 # the re-centring window, plus slack
    gap[gap > reach[:, None] + other_radii[None, :] + 1.0] = np.inf
    if not np.isfinite(gap).any():
        return None
    k = min(k, gap.shape[1])
    nearest = np.argsort(gap, axis=1)[:, :k]
    out = np.concatenate([others[nearest], other_radii[nearest][..., None]], axis=2)
    out[~np.isfinite(np.take_along_axis(gap, nearest, axis=1))] = np.nan
    return out


def _far_from(points: np.ndarray, radii: np.ndarray, blobs: np.ndarray, factor: float) -> np.ndarray:
    """(n,) bool: points farther from every (u, v, radius) row of ``blobs`` than ``factor`` times the larger
    of the two radii."""
    if len(points) == 0 or len(blobs) == 0:
        return np.ones(len(points), bool)
    gap = np.linalg.norm(points[:, None, :] - blobs[None, :, :2], axis=2)
    return np.all(gap >= factor * np.maximum(radii[:, None], blobs[None, :, 2]), axis=1)


def _clashes(points: np.ndarray, radii: np.ndarray, factor: float) -> np.ndarray:
    """(n,) bool: points closer to another than ``factor`` times the larger of their radii."""
    if len(points) < 2:
        return np.zeros(len(points), bool)
    gap = np.linalg.norm(points[:, None, :] - points[None, :, :], axis=2)
    np.fill_diagonal(gap, np.inf)
    return np.any(gap < factor * np.maximum(radii[:, None], radii[None, :]), axis=1)

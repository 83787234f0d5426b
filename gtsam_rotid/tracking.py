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
(the sub-pixel blob centroid).
"""

from __future__ import annotations

import enum
import math
import os
from collections.abc import Iterable, Iterator
from dataclasses import dataclass, field, fields, replace
from pathlib import Path

import cv2
import numpy as np

from .corners import CornerFollower, link_fragments, spin_filter, tracks_from_log
from .dataset import Track
from .errors import InputError
from .frames import frames_of, open_source

#: File name endings read as images when ``frames`` is a folder.

_MIN_IMAGE_SIDE = 16
_MAX_SHIFT_MARGIN = 2.0
_BOUND_SCALE, _BOUND_PAD = 1.5, 3.0  # a blob lies within 1.5 radius + 3 px of its point
_BUCKET = 8  # window half-sizes are rounded up to a multiple of this; one vectorised pass per size
_CONTRAST_PIXELS = 5  # the blob's contrast is the mean of its strongest pixels near the estimate
_BLOB_AREA_MARGIN = 15.0  # features="auto": corner tracks mostly this close to blob tracks' points are dropped
#: Values of ``TrackerParams.features``.
FEATURES = ("auto", "blobs", "corners")


@dataclass(frozen=True)
class TrackerParams:
    """Tracker settings. Pixels (px), grey levels (0–255) and frames. The defaults suit the reference
    scene: 640x480, dots of 2.5–6 px radius moving up to a few px per frame, a few grey levels of noise."""

    # --- detection: cv2.SimpleBlobDetector, dark and bright blobs
    #: Blob contour area range (px²) for the detector; also bounds the tracked blob radius.
    min_area: float = 8.0
    max_area: float = 400.0
    min_circularity: float = 0.6
    min_convexity: float = 0.8
    #: Minimum ratio of a blob's second moments (minor / major), at detection and while tracking: 0.1 keeps a
    #: disc down to an axis ratio of 0.32 (seen 72° off face-on). The centroid of a disc seen more obliquely
    #: drifts 0.01-0.03 px across its arc, correlated along the track: at 0.05 that made the covariance from
    #: rendered pixels ~1.6x too small in sigma and left out a good measurement of the reference scene.
    min_inertia_ratio: float = 0.1
    #: Binarisation thresholds (grey levels) of the detector: from, to, step.
    min_threshold: float = 10.0
    max_threshold: float = 250.0
    threshold_step: float = 15.0
    #: A blob's core must differ from its surroundings by at least this many grey levels.
    min_contrast: float = 8.0
    #: Detect blobs every this many frames ...
    detect_every: int = 15
    #: ... and this many frames after a track was lost (features rotating into view replace it).
    detect_after_loss: int = 3
    #: Detection looks only within ``detect_margin`` px (plus two blob radii) of the moving tracks, where new
    #: features rotate into view, except every ``full_detect_every``-th time (1: always the whole image).
    detect_margin: float = 40.0
    full_detect_every: int = 4
    #: Two blobs whose centres are closer than this times the larger blob radius are one blob (or two merged
    #: ones): no new track starts on a followed blob, and two tracks that close both end (they may swap).
    #: Blobs further apart are told apart by their connected regions (see :func:`refine_centres`).
    min_separation: float = 1.0
    #: A tracked blob whose radius grows by more than this factor in a frame has merged with another: lost.
    max_radius_growth: float = 1.5

    # --- pyramidal Lucas–Kanade
    lk_window: int = 15
    lk_levels: int = 2
    lk_iterations: int = 20
    lk_epsilon: float = 0.03
    #: Forward–backward error (px) above which a point is lost.
    fb_threshold: float = 0.5

    # --- sub-pixel re-centring on the blob
    recentre: bool = True
    centroid_iterations: int = 1
    #: The blob is its connected region above this fraction of its contrast, and its centroid weights are
    #: the intensity above that level: lower uses more of the blob's edge, higher keeps out more background.
    centroid_level: float = 0.35
    #: A re-centred point further than this (px) from where LK put it is lost.
    max_recentre_shift: float = 1.5
    #: A blob whose third standardised moment along a principal axis exceeds this is lopsided (cut by an
    #: occluding edge, or merged with something) and its point is dropped; 0 disables the test.
    max_skewness: float = 0.2

    # --- track bookkeeping and rejection
    #: Frames a track may miss (LK or re-centring failed) and still continue.
    max_gap: int = 2
    #: A track that has stayed within ``park_extent`` px for ``park_after`` frames is static background: it
    #: is no longer followed (it ends, to be rejected as barely moving), and no new track starts on it.
    park_after: int = 20
    park_extent: float = 1.5
    min_length: int = 10
    #: Tracks whose bounding-box diagonal is below this (px) barely move: static background.
    min_extent: float = 10.0
    #: A point further than this (px) from a local quadratic fit of its neighbours (leave-one-out) is bad;
    #: a bad run across which the two sides do not join smoothly splits the track.
    jump_threshold: float = 1.0
    #: Points in the local fit window (odd, >= 5).
    jump_window: int = 9

    # --- which features: "blobs" (dots: SimpleBlobDetector, sub-pixel re-centring), "corners" (ambient texture:
    # Shi-Tomasi corners where the image moves, see gtsam_rotid.corners) or "auto" (both: blobs where blobs are
    # found, corners elsewhere; no corner starts on or near a followed blob, and a corner track that follows a
    # blob track is dropped as a duplicate). "auto", the default, tracks dots as "blobs" does (the same tracks on
    # the rendered dots) and textures as "corners" does.
    features: str = "auto"
    #: At most this many corner tracks at once; new corners every ``seed_every`` frames.
    max_corners: int = 300
    seed_every: int = 5
    #: cv2.goodFeaturesToTrack: quality (relative to the best corner), minimum distance (px), block size (px).
    corner_quality: float = 0.01
    corner_min_distance: float = 8.0
    corner_block_size: int = 5
    #: A corner's template: the smaller eigenvalue of its Gaussian-weighted gradient structure tensor (grey levels²
    #: per px²) must reach ``corner_min_eigen``: weaker texture is not followed.
    corner_min_eigen: float = 10.0
    #: Corners start only where the image moved (half-resolution frame difference above ``motion_threshold``
    #: grey levels) within the last ``motion_memory`` frames: the background and still links never seed; and not
    #: within ``seed_margin`` px of that region's boundary (a patch there straddles a silhouette).
    motion_threshold: float = 8.0
    motion_memory: int = 10
    seed_margin: float = 3.0
    #: ... and only where at least this fraction of the corner's window changed since the previous frame (a
    #: window straddling a silhouette is partly still background).
    seed_motion_fraction: float = 0.5
    #: Each corner is followed by affine inverse-compositional Lucas–Kanade (``ic_iterations`` steps, the first
    #: translation only) of a ``corner_window`` px square template (Gaussian-weighted, brightness and contrast
    #: normalised), predicted by the spin's rotation or the point's velocity; the template is taken anew every
    #: ``anchor_every`` frames at the tracked point (each renewal adds drift). A point is missed where the warped
    #: patch correlates below
    #: ``min_zncc`` with its template (e.g. a patch straddling an occluding edge), where the last step still moved
    #: it more than ``max_final_step`` px (not converged), or further than ``max_anchor_disagreement`` px from its
    #: prediction.
    corner_window: int = 9
    ic_iterations: int = 5
    min_zncc: float = 0.9
    max_final_step: float = 0.05
    anchor_every: int = 1000
    #: A track ends where its patch has turned or stretched so that the warp's linear part is further than this
    #: from the identity (largest entry).
    max_template_warp: float = 0.5
    #: Damping of the warp's linear part (relative), and whether the spin's rotation predicts it (off by default:
    #: the shared conic's turn W⁻¹ R W is the patch's turn only on surfaces facing along the axis, and a shape
    #: fitted to a few short arcs made it far off; the last frame's warp is the start).
    warp_damping: float = 0.5
    predict_turn: bool = False
    max_anchor_disagreement: float = 1.5
    #: The photometric model beside ZNCC's gain and offset: a linear brightness gradient across the patch, fitted
    #: and removed from template and patch alike (the shading across a patch changes as its surface turns under a
    #: directional light). Jaco2 mesh renders (5 clips of 8 s, text and photo): pooled RMS 0.36 -> 0.25 px, no
    #: track above 1 px (was 1-10 % of them), 12 % fewer tracks.
    shading_gradient: bool = True
    #: The spin's shared rotation (one ellipse shape, one rate): refitted every ``model_every`` frames from
    #: tracks of at least ``model_min_points`` points; it predicts each corner (LK's start) and gates it.
    model_every: int = 10
    model_min_points: int = 15
    #: ... and is used only while it predicts the tracks' own one-frame steps within this fraction of their
    #: speed (medians over the tracks).
    model_max_step_error: float = 0.3
    #: A point further from its track's ellipse than ``ellipse_sigmas`` robust sigmas (and than
    #: ``min_ellipse_gate`` px while tracking, ``min_ellipse_gate_offline`` px after) is dropped; a track with more
    #: than ``max_off_ellipse_fraction`` of its points so far off is rejected (an occluding edge, a highlight).
    ellipse_sigmas: float = 4.0
    min_ellipse_gate: float = 1.0
    min_ellipse_gate_offline: float = 0.3
    max_off_ellipse_fraction: float = 0.2
    #: A track whose arc spans this (rad) is tested against its own ellipse, not only the shared shape.
    own_ellipse_arc: float = 1.5
    #: A track whose phase rate differs from the spin's by more than this fraction does not turn with the spin.
    rate_tolerance: float = 0.1
    #: ... or whose phase strays from the common rate by more than this RMS (px along its ellipse): it slides.
    max_phase_residual: float = 3.0
    #: Link fragments of one feature across occlusions: same ellipse (centre and radius within
    #: ``link_tolerance`` px + 2 % / 1 % of the radius), phase within ``link_phase_tolerance`` rad of the common
    #: rate's prediction, gap <= ``link_max_gap`` frames, seed patches (turned) correlating >= ``link_min_ncc``.
    link: bool = True
    link_max_gap: int = 900
    link_tolerance: float = 1.5
    link_phase_tolerance: float = 0.2
    link_min_ncc: float = 0.8

    def __post_init__(self):
        positive = ("min_area", "max_area", "threshold_step", "lk_epsilon", "fb_threshold", "max_recentre_shift",
                    "jump_threshold", "lk_window", "lk_iterations", "detect_every", "detect_after_loss",
                    "centroid_iterations", "min_length", "park_after", "max_radius_growth", "full_detect_every",
                    "park_extent", "max_corners", "seed_every", "corner_min_distance", "corner_block_size",
                    "motion_memory", "anchor_every", "max_anchor_disagreement", "corner_window", "ic_iterations",
                    "min_zncc", "max_final_step", "max_template_warp", "warp_damping",
                    "model_every", "model_min_points", "model_max_step_error",
                    "ellipse_sigmas", "rate_tolerance", "link_max_gap", "link_phase_tolerance",
                    "max_phase_residual")
        non_negative = ("min_circularity", "min_convexity", "min_inertia_ratio", "min_threshold", "min_contrast",
                        "min_separation", "lk_levels", "max_gap", "min_extent", "centroid_level", "max_skewness",
                        "detect_margin", "corner_quality", "corner_min_eigen", "motion_threshold", "seed_margin",
                        "seed_motion_fraction",
                        "min_ellipse_gate", "min_ellipse_gate_offline", "max_off_ellipse_fraction", "own_ellipse_arc",
                        "link_tolerance", "link_min_ncc")
        for f in fields(self):
            value = getattr(self, f.name)
            if f.name in ("recentre", "link", "predict_turn", "shading_gradient"):
                if not isinstance(value, bool):
                    raise InputError(f"TrackerParams.{f.name} must be True or False, got {value!r}")
                continue
            if f.name == "features":
                if value not in FEATURES:
                    raise InputError(f"TrackerParams.features must be one of {', '.join(FEATURES)}, got {value!r}")
                continue
            if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
                raise InputError(f"TrackerParams.{f.name} must be a finite number, got {value!r}")
            if f.type == "int" and value != int(value):
                raise InputError(f"TrackerParams.{f.name} must be an integer, got {value!r}")
            if f.name in positive and value <= 0:
                raise InputError(f"TrackerParams.{f.name} must be > 0, got {value!r}")
            if f.name in non_negative and value < 0:
                raise InputError(f"TrackerParams.{f.name} must be >= 0, got {value!r}")
        if self.max_area <= self.min_area:
            raise InputError(f"TrackerParams: max_area ({self.max_area}) must exceed min_area ({self.min_area})")
        if self.max_threshold <= self.min_threshold:
            raise InputError(f"TrackerParams: max_threshold ({self.max_threshold}) must exceed min_threshold "
                             f"({self.min_threshold})")
        if self.lk_window < 3 or self.lk_window % 2 == 0:
            raise InputError(f"TrackerParams.lk_window must be odd and >= 3, got {self.lk_window}")
        if self.jump_window < 5 or self.jump_window % 2 == 0:
            raise InputError(f"TrackerParams.jump_window must be odd and >= 5, got {self.jump_window}")
        if self.centroid_level >= 1:
            raise InputError(f"TrackerParams.centroid_level must be in [0, 1), got {self.centroid_level}")
        if self.min_length < 3:
            raise InputError(f"TrackerParams.min_length must be >= 3, got {self.min_length}")
        if self.corner_quality >= 1 or self.corner_quality == 0:
            raise InputError(f"TrackerParams.corner_quality must be in (0, 1), got {self.corner_quality}")
        if self.max_off_ellipse_fraction >= 1:
            raise InputError(f"TrackerParams.max_off_ellipse_fraction must be in [0, 1), got "
                             f"{self.max_off_ellipse_fraction}")
        if self.corner_window < 7 or self.corner_window % 2 == 0:
            raise InputError(f"TrackerParams.corner_window must be odd and >= 7, got {self.corner_window}")
        if self.min_zncc >= 1:
            raise InputError(f"TrackerParams.min_zncc must be below 1, got {self.min_zncc}")
        if self.motion_memory > 250:
            raise InputError(f"TrackerParams.motion_memory must be <= 250 frames, got {self.motion_memory}")

    @property
    def radius_range(self) -> tuple[float, float]:
        """Blob radius range (px) implied by the area range."""
        return math.sqrt(self.min_area / math.pi), math.sqrt(self.max_area / math.pi)


class RejectReason(enum.Enum):
    """Why :func:`filter_tracks` rejected a track."""

    SHORT = "too short"
    STATIC = "barely moves"
    #: A corner track whose points leave its ellipse (an occluding edge: a silhouette point slides along the
    #: outline; a highlight; a jump between features).
    OFF_ELLIPSE = "off its ellipse"
    #: A corner track whose phase does not advance at the spin's common rate (a highlight, an edge junction).
    NOT_TURNING = "not turning with the spin"
    #: A corner track where blob tracks went (features="auto": blobs where blobs are found, corners elsewhere).
    DUPLICATE = "duplicates a blob track"


@dataclass(frozen=True)
class RejectedTrack:
    """A track (or a piece of one split at a jump) that was left out, with the reason and details."""

    reason: RejectReason
    track: Track
    detail: str = ""


@dataclass
class TrackingResult:
    """What :meth:`Tracker.run` returns: the accepted tracks (sorted by start frame), the rejected ones,
    the number of frames read, the image size (width, height) and the jump statistics."""

    tracks: list[Track]
    rejected: list[RejectedTrack] = field(default_factory=list)
    n_frames: int = 0
    image_size: tuple[int, int] | None = None
    n_raw_tracks: int = 0
    n_jumps: int = 0
    n_outliers: int = 0
    params: TrackerParams = field(default_factory=TrackerParams)
    #: Corner tracks: fragments joined into longer arcs, and points dropped off their ellipses.
    n_links: int = 0
    n_off_ellipse_points: int = 0
    #: The spin's common rate (rad per frame, in the frame where its ellipses are circles), NaN if not fitted.
    spin_rate: float = float("nan")

    def summary(self) -> str:
        """Multi-line human-readable description."""
        points = sum(len(t) for t in self.tracks)
        size = "" if self.image_size is None else f" of {self.image_size[0]}x{self.image_size[1]}"
        lines = [f"Tracked {self.n_frames} frames{size}: {len(self.tracks)} tracks ({points} points) accepted "
                 f"of {self.n_raw_tracks} raw tracks; {self.n_jumps} split at jumps, {self.n_outliers} bad "
                 f"points dropped"]
        if self.n_links or self.n_off_ellipse_points or math.isfinite(self.spin_rate):
            lines.append(f"  corners: {self.n_links} fragments linked, {self.n_off_ellipse_points} points off their "
                         f"ellipse dropped, spin rate {self.spin_rate:+.4f} rad/frame")
        for reason in RejectReason:
            count = sum(r.reason is reason for r in self.rejected)
            if count:
                lines.append(f"  rejected, {reason.value}: {count}")
        return "\n".join(lines)


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
    free = None
    if neighbours is not None:
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
    ok = (inside & (total > 0) & (contrast >= min_contrast) & (count >= 8) & ~spill
          & (np.hypot(shift[:, 0], shift[:, 1]) <= max_shift))
    return start + shift, ok, contrast, polarity, radius, inertia, skewness


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
        if not path.exists():
            raise InputError(f"{path} does not exist: expected a video file or a folder of images")
        images, total, first = frames_of(open_source(path), None)   # the one frame reader
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

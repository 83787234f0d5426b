"""The tracker's settings (:class:`TrackerParams`, every field with what it does and its default) and what it
returns (:class:`TrackingResult`, :class:`RejectedTrack` with a :class:`RejectReason`).
"""

from __future__ import annotations

import enum
import math
from dataclasses import dataclass, field, fields

from .dataset import Track
from .errors import InputError

#: Values of ``TrackerParams.features``.
FEATURES = ("auto", "blobs", "corners")

#: Each feature kind's own offset per track (px, 1 sigma per image coordinate; ``CalibrationOptions.track_offset_px``)
#: and image-axis floor (px; ``CalibrationOptions.axis_floor_px``), which the tracker writes into its datasets'
#: metadata for ``calibrate``. Blob centroids on the reference scene's dots put the image axes within hundredths of
#: a pixel: neither. Tracks of rendered photo and text coverings (corners, and the blobs that ``auto`` finds among
#: them) carry errors that follow a feature over its whole arc: corners drift by 0.1-0.3 px on surfaces that turn
#: towards or away from the camera, and blob centroids in a recess are pulled by its shading by a nearly constant
#: 0.1-0.2 px in the image (``docs/design.md``, "Track offsets"). A few long arcs carry a pose's image axis, so such
#: an offset moves it through that track's leverage, often many times its 1 sigma. Declared per track, the 24
#: scenes of ``benchmarks/ambient.py`` (seeds 0-3) hold their errors at 0.15 px with no floor (NEES 5.20 over the 16
#: usable, inside its interval 4.42-7.81; README, "Ambient features"; ``benchmarks/axis_floor.py --track-offsets``
#: on stage 1's axes: 0.18-0.24 px); a floor shared by every axis (0.09 px, measured by
#: ``benchmarks/axis_floor.py``) held them too but was conservative (NEES 1.64): it counts the same error on every
#: pose, however many tracks carry its axis. "auto" takes the corners' values when it kept corner tracks.
TRACK_OFFSET_PX = {"blobs": 0.0, "corners": 0.15, "auto": 0.15}
AXIS_FLOOR_PX = {"blobs": 0.0, "corners": 0.0, "auto": 0.0}
#: The corner tracker's errors as one floor on every image axis (px), as measured by ``benchmarks/axis_floor.py``
#: on the ambient scenes: the planner's stand-in for them (``PlanOptions.axis_floor_px``), which its information can
#: hold without the tracks themselves.
CORNER_AXIS_FLOOR_PX = 0.09


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
    #: ... and the ratio of its larger to its smaller eigenvalue at most ``corner_max_anisotropy``: an edge-like
    #: patch (a stroke, an outline in a photograph) is held along its edge only by how its appearance changes as
    #: the surface turns, and slides along it smoothly, across the point's motion, off its ellipse (Jaco2 photo,
    #: 6 poses: the quarter of the tracks above 4.7 drifted 0.21 px RMS smoothly across their motion, the others
    #: 0.04-0.06 px). Such errors are each track's own, yet smooth along a short arc they move a pose's image axis
    #: far more than white noise would. The default keeps every corner: 5 lowered the tracks' error on six rendered
    #: scenes and the image axes' on four, but lost most tracks of some poses (113 -> 6) and doubled one scene's error
    #: (README, "Ambient features").
    corner_max_anisotropy: float = 1e9
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
    #: A track whose points stray more than ``max_phase_residual`` px (RMS) from every turn about any centre at a
    #: rate within ``rate_tolerance`` (a fraction) of the spin's common rate, in the frame where the spin's
    #: ellipses are circles, slides or does not turn with the spin. The band is wide because that rate is only
    #: known to tens of per cent on real images (one ellipse shape for all tracks is an affine approximation):
    #: on Jaco2 renders the common rate read 0.64-1.4 times the true one and arcs of 1 rad read 1.3-1.9 times it
    #: about their own ellipses, so a 10 % test rejected good tracks (0.08 px from their surface points) by the
    #: hundred.
    rate_tolerance: float = 0.5
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
        if self.corner_max_anisotropy < 1:
            raise InputError(f"TrackerParams.corner_max_anisotropy must be >= 1 (an eigenvalue ratio), got "
                             f"{self.corner_max_anisotropy}")
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
    #: Of the accepted tracks, how many the corner follower made (the rest are blob tracks).
    n_corner_tracks: int = 0

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


def tracker_metadata(params: TrackerParams | None = None, corner_tracks: int | None = None) -> dict:
    """What a dataset's ``metadata["tracker"]`` says of tracks made with ``params`` (default settings when None):
    the feature kind, its image axes' prior floor and each track's own offset (px, :data:`AXIS_FLOOR_PX`,
    :data:`TRACK_OFFSET_PX`), which ``calibrate`` uses unless ``CalibrationOptions.axis_floor_px`` /
    ``track_offset_px`` are given, and, when known, how many corner tracks were kept (``corner_tracks``: with
    ``features="auto"`` none means blob tracks only, and the blobs' values)."""
    features = (params or TrackerParams()).features
    kind = features if features != "auto" or corner_tracks is None else ("corners" if corner_tracks else "blobs")
    out = {"features": features, "axis_floor_px": AXIS_FLOOR_PX[kind], "track_offset_px": TRACK_OFFSET_PX[kind]}
    if corner_tracks is not None:
        out["corner_tracks"] = int(corner_tracks)
    return out

"""Did the camera stay still between the videos? Measured on the still background, which every video of a
calibration shares.

A camera that turns or moves a little between arm poses shifts each pose's image: 0.01° is 0.1 px at a focal length
of 570 px. The shift moves the pose's image axis across itself, and the calibration's own test of the axes all but
cannot see it (README, "An image shift per pose"): only the scene around the arm can. :func:`camera_motion` finds
corners in one frame of the first video, follows each into the same frame of every other video (pyramidal
Lucas-Kanade, forward and backward), and takes the shift that most of them agree on: the background, the table and
the arm's base do not move unless the camera does, while the links that moved between the poses either fail the
forward-backward check or move far from that consensus. A window about each of those points is aligned again in
floating point, and each video's shift is the median of the windows' shifts, with its standard error
(``benchmarks/stillness.py``: 0.007-0.012 px on textured scenes, JPEG-compressed or blurred). Given each video's
last frame too, its move during the video (its drift) is read the same way, against its own first frame.

The result is a measurement, not a correction of the tracks: a turn of the camera shifts near and far points
alike, but a move of its centre shifts them in inverse proportion to their depth, so the hand (nearer than the
background) moves more. A dataset carries it (``metadata["camera_motion"]``, :func:`motion_metadata`) and
``calibrate`` adds what shifts of its scatter (:attr:`CameraMotion.level_px`) move the pose by to the covariance;
elsewhere, declare the largest shift as the image axes' floor (``--axis-floor-px``, :attr:`CameraMotion.floor_px`:
more cautious).
"""

from __future__ import annotations

import os
import sys
from collections import deque
from collections.abc import Sequence
from dataclasses import dataclass

import cv2
import numpy as np
from tqdm import tqdm

from .errors import InputError
from .frames import read_frames

#: Corners sought in the reference frame (Shi-Tomasi), their quality level and spacing (px).
MAX_CORNERS = 3000
QUALITY = 0.01
MIN_DISTANCE = 7
#: Lucas-Kanade window (px) and pyramid levels (level 3 follows shifts of tens of pixels).
WINDOW = 21
LEVELS = 3
#: A point counts when its backward track returns within this of where it started (px).
FORWARD_BACKWARD_PX = 0.05
#: Points within this of the median displacement (px) form the consensus.
CONSENSUS_PX = 0.5
#: Fewer agreeing points than this: the background cannot be read.
MIN_POINTS = 20
#: Half-size (px) of the window about each still point that is aligned again in floating point.
ALIGN_HALF = 7
#: Gauss-Newton steps of that alignment.
ALIGN_STEPS = 4
#: A shift counts as a move when it exceeds this many standard errors and :data:`MIN_MOVE_PX`: below a fiftieth of
#: a pixel the reading's own errors (the background's texture, compression) compete.
SIGNIFICANT_Z = 3.0
MIN_MOVE_PX = 0.02
#: A move during a video (its drift, last frame against first) shifts the spin's image axis by half of it and by up
#: to this fraction of it more, in a direction that depends on where the arcs were when the image slid: counted as
#: this fraction of its length, 1 sigma, in no known direction (a steady drift of N(0, 0.5²) px per coordinate per
#: pose during the 12 s reference scene moved the joint estimate by a mean squared Mahalanobis length of 3.78 under
#: the level so counted, 6 if exact, over 12 draws; 7.41 with half the drift as a shift alone, up to 27.8).
DRIFT_SPREAD = 0.5


@dataclass
class CameraMotion:
    """Each video's image shift against the first video's, read off the still background (px, image x and y)."""

    shifts_px: np.ndarray   # (n, 2); the first row is zero
    sigma_px: np.ndarray    # (n, 2) standard errors (the first row zero)
    n_points: np.ndarray    # (n,) background points in each video's consensus (0 for the first)
    names: list[str]
    #: (n, 2) each video's move during it: its last frame's shift against its first (px), with standard errors;
    #: None where it was not read (the last frames not given, or ``drift_error`` says why)
    drift_px: np.ndarray | None = None
    drift_sigma_px: np.ndarray | None = None
    drift_error: str | None = None

    @property
    def size_px(self) -> np.ndarray:
        """(n,) each video's shift's length (px)."""
        return np.linalg.norm(self.shifts_px, axis=1)

    @property
    def moved(self) -> np.ndarray:
        """(n,) whether each video's shift exceeds :data:`SIGNIFICANT_Z` standard errors and :data:`MIN_MOVE_PX`."""
        return _significant(self.shifts_px, self.sigma_px)

    @property
    def drifted(self) -> np.ndarray:
        """(n,) whether the camera moved during each video: its drift (last frame against first) beyond
        :data:`SIGNIFICANT_Z` standard errors and :data:`MIN_MOVE_PX` (all False where the drift was not read)."""
        if self.drift_px is None:
            return np.zeros(len(self.shifts_px), bool)
        return _significant(self.drift_px, self.drift_sigma_px)

    @property
    def positions_px(self) -> np.ndarray:
        """(n, 2) where each video's image sits on average against the first video's first frame: its shift plus
        half its drift; the shifts alone where the drift was not read."""
        return self.shifts_px if self.drift_px is None else self.shifts_px + 0.5 * self.drift_px

    @property
    def floor_px(self) -> float:
        """The largest significant shift (px), a drift's end included, 0 where none is: as an image axes' floor
        (``CalibrationOptions.axis_floor_px``) it covers the moves, cautiously (every axis, every pose)."""
        sizes = [self.size_px[self.moved]]
        if self.drift_px is not None:
            sizes.append(np.linalg.norm(self.shifts_px + self.drift_px, axis=1)[self.drifted])
        sizes = np.concatenate(sizes)
        return float(np.max(sizes)) if len(sizes) else 0.0

    @property
    def level_px(self) -> float:
        """The level of an image shift per pose (px, 1 sigma per image coordinate;
        ``CalibrationResult.image_shift_covariance`` is per px² of it), 0 where no video moved, between or during
        the videos: the scatter of the videos' positions (:attr:`positions_px`) about their mean (which is a turn
        of the camera that every pose shares, and the calibration follows), and, where the camera moved during a
        video, :data:`DRIFT_SPREAD` of its drift as a shift in no known direction (a drift does not move a spin's
        image axis exactly as a shift of half of it does: the centre of a circle fitted to an arc traced while the
        image slid moves across the slide too)."""
        if not np.any(self.moved | self.drifted) or len(self.shifts_px) < 2:
            return 0.0
        positions = self.positions_px
        deviations = positions - positions.mean(axis=0)
        variance = np.sum(deviations**2) / (2.0 * (len(positions) - 1))
        if self.drift_px is not None:  # (|d| DRIFT_SPREAD in all, half of its square per coordinate)
            variance += 0.5 * DRIFT_SPREAD**2 * float(np.mean(np.sum(self.drift_px**2, axis=1)))
        return float(np.sqrt(variance))

    @property
    def bound_px(self) -> float:
        """How far a video's position may have moved unseen (px): the shift of a video not called moved plus
        :data:`SIGNIFICANT_Z` standard errors (of a moved one, those alone), and half the same of its drift, the
        largest, at least :data:`MIN_MOVE_PX`."""
        unseen = _unseen(self.shifts_px, self.sigma_px, self.moved)
        if self.drift_px is not None:
            unseen = unseen + 0.5 * _unseen(self.drift_px, self.drift_sigma_px, self.drifted)
        return float(max(np.max(unseen), MIN_MOVE_PX))

    def to_dict(self) -> dict:
        """As a dataset's ``metadata["camera_motion"]`` holds it (``level_px`` and ``bound_px`` for ``calibrate``)."""
        out = {"shifts_px": self.shifts_px.tolist(), "sigma_px": self.sigma_px.tolist(),
               "n_points": [int(n) for n in self.n_points], "names": list(self.names),
               "floor_px": self.floor_px, "level_px": self.level_px, "bound_px": self.bound_px,
               "moved": [bool(m) for m in self.moved]}
        if self.drift_px is not None:
            out.update(drift_px=self.drift_px.tolist(), drift_sigma_px=self.drift_sigma_px.tolist(),
                       drifted=[bool(d) for d in self.drifted])
        elif self.drift_error is not None:
            out["drift_error"] = self.drift_error
        return out


def _significant(shifts: np.ndarray, sigmas: np.ndarray) -> np.ndarray:
    """(n,) shifts beyond :data:`SIGNIFICANT_Z` times their standard errors' length and :data:`MIN_MOVE_PX`."""
    size, sigma = np.linalg.norm(shifts, axis=1), np.linalg.norm(sigmas, axis=1)
    return (size > SIGNIFICANT_Z * np.maximum(sigma, 1e-12)) & (size > MIN_MOVE_PX)


def _unseen(shifts: np.ndarray, sigmas: np.ndarray, significant: np.ndarray) -> np.ndarray:
    """(n,) how far each shift may be unseen: its size where it is not significant, plus :data:`SIGNIFICANT_Z`
    standard errors."""
    size, sigma = np.linalg.norm(shifts, axis=1), np.linalg.norm(sigmas, axis=1)
    return np.where(significant, 0.0, size) + SIGNIFICANT_Z * sigma


def _grey(frame: np.ndarray, where: str) -> np.ndarray:
    frame = np.asarray(frame)
    if frame.dtype != np.uint8 or frame.ndim not in (2, 3) or (frame.ndim == 3 and frame.shape[2] not in (3, 4)):
        raise InputError(f"{where}: expected a uint8 grey or BGR image, got {frame.dtype} {frame.shape}")
    if frame.ndim == 2:
        return frame
    return cv2.cvtColor(frame, cv2.COLOR_BGRA2GRAY if frame.shape[2] == 4 else cv2.COLOR_BGR2GRAY)


def _first_frame(video, index: int, where: str) -> np.ndarray:
    if isinstance(video, str | os.PathLike):
        frames = read_frames(video, (index, index + 1))
        try:
            return next(iter(frames))
        except StopIteration:
            raise InputError(f"{where}: it has no frame {index}") from None
    return np.asarray(video)


def reference_corners(reference: np.ndarray) -> np.ndarray:
    """The corners (Shi-Tomasi, (m, 1, 2) float32) :func:`background_shift` follows from ``reference`` (a uint8 grey
    or BGR image), found once for every frame compared with it; an :class:`InputError` where there are fewer than
    :data:`MIN_POINTS`."""
    a = _grey(reference, "the reference frame")
    corners = cv2.goodFeaturesToTrack(a, MAX_CORNERS, QUALITY, MIN_DISTANCE)
    if corners is None or len(corners) < MIN_POINTS:
        raise InputError(f"the first video's frame has {0 if corners is None else len(corners)} corners, fewer "
                         f"than {MIN_POINTS}: too little texture around the arm to tell whether the camera moved")
    return corners


def lk_consensus(reference: np.ndarray, frame: np.ndarray, corners: np.ndarray, where: str = "frame"
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Lucas-Kanade's consensus: ``corners`` of ``reference`` (grey uint8) followed into ``frame`` (grey uint8) and
    back (pyramidal, :data:`WINDOW`, :data:`LEVELS`), those that return within :data:`FORWARD_BACKWARD_PX`, and of
    them those within :data:`CONSENSUS_PX` of their median move (three rounds): (the consensus' median move (2,),
    the moves in it (m, 2), their corners (m, 2)). An :class:`InputError` naming ``where`` where fewer than
    :data:`MIN_POINTS` are found again or agree."""
    criteria = (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 50, 1e-4)
    window = (WINDOW, WINDOW)
    ahead, found, _ = cv2.calcOpticalFlowPyrLK(reference, frame, corners, None, winSize=window, maxLevel=LEVELS,
                                               criteria=criteria)
    back, returned, _ = cv2.calcOpticalFlowPyrLK(frame, reference, ahead, None, winSize=window, maxLevel=LEVELS,
                                                 criteria=criteria)
    good = (found[:, 0] == 1) & (returned[:, 0] == 1) & (
        np.linalg.norm((back - corners)[:, 0], axis=1) < FORWARD_BACKWARD_PX)
    moves = (ahead - corners)[good, 0].astype(float)
    if len(moves) < MIN_POINTS:
        raise InputError(f"{where}: only {len(moves)} of the first video's {len(corners)} corners were found again "
                         f"(at least {MIN_POINTS} needed): the scene around the arm changed too much between the "
                         "videos to tell whether the camera moved")
    centre = np.median(moves, axis=0)
    for _ in range(3):  # the consensus about the median, and its median again
        near = np.linalg.norm(moves - centre, axis=1) < CONSENSUS_PX
        if near.sum() < MIN_POINTS:
            raise InputError(f"{where}: only {int(near.sum())} corners agree on one shift (at least {MIN_POINTS} "
                             "needed): too little of the scene around the arm stayed still to tell whether the "
                             "camera moved")
        centre = np.median(moves[near], axis=0)
    return centre, moves[near], corners[good, 0][near]


def background_shift(reference: np.ndarray, frame: np.ndarray, where: str = "frame",
                     corners: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, int]:
    """The image shift of ``frame`` against ``reference`` (two uint8 images of the same size) that most of the
    reference's corners agree on: (shift (2,) px, its standard error (2,), points in the consensus). ``corners``:
    the reference's (:func:`reference_corners`), where it is compared with several frames. Raises
    :class:`InputError` naming ``where`` when the sizes differ or fewer than :data:`MIN_POINTS` points agree."""
    a, b = _grey(reference, "the reference frame"), _grey(frame, where)
    if a.shape != b.shape:
        raise InputError(f"{where}: {b.shape[1]}x{b.shape[0]} px, but the first video's frame is "
                         f"{a.shape[1]}x{a.shape[0]}: the videos must come from one camera")
    corners = reference_corners(a) if corners is None else corners
    centre, _, still = lk_consensus(a, b, corners, where)
    # Lucas-Kanade's points share errors (its fixed-point interpolation locks them towards whole pixels, and every
    # still point has the same fraction of a pixel): the standard error of their median understated its error 1.3-
    # 1.9x (benchmarks/stillness.py). Each window about a consensus point is aligned again in floating point, whose
    # errors are nearer independent (the mean of (error / sigma)^2 1.4-3.4, 2 if honest)
    per_point = _window_shifts(a.astype(np.float32), b.astype(np.float32), still, np.rint(centre).astype(int))
    if len(per_point) < MIN_POINTS:
        raise InputError(f"{where}: only {len(per_point)} still points lie far enough inside both frames (at least "
                         f"{MIN_POINTS} needed) to tell whether the camera moved")
    shift = np.median(per_point, axis=0)
    spread = 1.4826 * np.median(np.abs(per_point - shift), axis=0)
    sigma = 1.2533 * spread / np.sqrt(len(per_point))  # the median's standard error
    return shift, sigma, len(per_point)


def _window_shifts(a: np.ndarray, b: np.ndarray, points: np.ndarray, whole: np.ndarray) -> np.ndarray:
    """(m, 2) the shift of ``b`` against ``a`` (float images) in the window of half-size :data:`ALIGN_HALF` about
    each of ``points`` (reference px), starting from the whole-pixel shift ``whole`` (2,) ints: Gauss-Newton on
    ``sum (b(p + s) - a(p))^2`` over the window's whole pixels ``p``, with ``b`` and its central-difference
    gradient sampled bilinearly in floating point (a symmetric kernel: no bias towards whole pixels, unlike
    OpenCV's fixed-point interpolation) and the mean of both images' gradients (:data:`ALIGN_STEPS` steps).
    Windows that reach out of either frame, or whose gradients do not determine both directions, are dropped."""
    h, w = a.shape
    r = ALIGN_HALF
    centres = np.rint(points).astype(int)
    margin = r + 3  # (the shift may still change by a pixel or so)
    low = np.maximum(margin, margin - whole)
    high = np.minimum([w - margin - 1, h - margin - 1], np.array([w - margin - 1, h - margin - 1]) - whole)
    centres = centres[np.all((centres >= low) & (centres <= high), axis=1)]
    if not len(centres):
        return np.zeros((0, 2))
    offsets = np.arange(-r, r + 1)
    xs, ys = np.broadcast_arrays(centres[:, 0, None, None] + offsets[None, None, :],
                                 centres[:, 1, None, None] + offsets[None, :, None])   # (m, k, k)
    ref = a[ys, xs]
    ax = 0.5 * (a[ys, xs + 1] - a[ys, xs - 1])
    ay = 0.5 * (a[ys + 1, xs] - a[ys - 1, xs])
    bx, by = np.zeros_like(b), np.zeros_like(b)
    bx[:, 1:-1], by[1:-1, :] = 0.5 * (b[:, 2:] - b[:, :-2]), 0.5 * (b[2:, :] - b[:-2, :])
    shift = np.tile(whole.astype(float), (len(centres), 1))
    ok = np.ones(len(centres), bool)
    for _ in range(ALIGN_STEPS):
        u, v = xs + shift[:, 0, None, None], ys + shift[:, 1, None, None]
        u = np.clip(u, 1, w - 3)
        v = np.clip(v, 1, h - 3)
        x0, y0 = np.floor(u).astype(int), np.floor(v).astype(int)
        fx, fy = u - x0, v - y0

        def sample(image, x0=x0, y0=y0, fx=fx, fy=fy):
            return ((1 - fy) * ((1 - fx) * image[y0, x0] + fx * image[y0, x0 + 1])
                    + fy * ((1 - fx) * image[y0 + 1, x0] + fx * image[y0 + 1, x0 + 1]))

        difference = sample(b) - ref
        gx, gy = 0.5 * (ax + sample(bx)), 0.5 * (ay + sample(by))
        G = np.stack([np.stack([(gx * gx).sum((1, 2)), (gx * gy).sum((1, 2))], -1),
                      np.stack([(gx * gy).sum((1, 2)), (gy * gy).sum((1, 2))], -1)], -2)   # (m, 2, 2)
        rhs = -np.stack([(gx * difference).sum((1, 2)), (gy * difference).sum((1, 2))], -1)
        eig = np.linalg.eigvalsh(G)
        ok &= eig[:, 0] > 1e-3 * np.maximum(eig[:, 1], 1e-12)
        step = np.zeros_like(shift)
        step[ok] = np.linalg.solve(G[ok], rhs[ok][..., None])[..., 0]
        shift += np.clip(step, -1.0, 1.0)
    return shift[ok]


def camera_motion(videos: Sequence, *, frame: int = 0, names: Sequence[str] | None = None,
                  last: Sequence | None = None, progress: bool = False) -> CameraMotion:
    """Each video's image shift against the first one's, on the still background (see the module docstring).

    ``videos``: one per arm pose, each a video file or image folder (its frame ``frame`` is read), or that frame
    itself (a uint8 grey or BGR image). ``names`` name them in errors and words (default: ``video k``). ``last``:
    each video's last frame (an image, or the video file or image folder, decoded to its end), to read the camera's
    move during each video too (:attr:`CameraMotion.drift_px`); where one cannot be read, no drift is, and
    :attr:`CameraMotion.drift_error` says why. ``progress``: a progress bar over the videos' last frames."""
    videos = list(videos)
    if len(videos) < 2:
        raise InputError(f"camera_motion needs at least two videos to compare, got {len(videos)}")
    names = [f"video {k}" for k in range(len(videos))] if names is None else [str(n) for n in names]
    if len(names) != len(videos):
        raise InputError(f"{len(names)} names for {len(videos)} videos")
    if last is not None and len(last) != len(videos):
        raise InputError(f"{len(last)} last frames for {len(videos)} videos")
    firsts = [_first_frame(video, frame, name) for video, name in zip(videos, names, strict=True)]
    corners = reference_corners(firsts[0])  # (once, for every video compared with the first)
    shifts, sigmas, counts = [np.zeros(2)], [np.zeros(2)], [0]
    for image, name in zip(firsts[1:], names[1:], strict=True):
        shift, sigma, n = background_shift(firsts[0], image, name, corners)
        shifts.append(shift)
        sigmas.append(sigma)
        counts.append(n)
    motion = CameraMotion(np.array(shifts), np.array(sigmas), np.array(counts), names)
    if last is None:
        return motion
    drifts, drift_sigmas = [], []
    try:
        for k, (image, end, name) in enumerate(tqdm(list(zip(firsts, last, names, strict=True)), desc="last frames",
                                                    unit="video", disable=not progress, file=sys.stderr)):
            drift, sigma, _ = background_shift(image, _last_frame(end, f"{name} (its last frame)"),
                                               f"{name} (its last frame against its first)", None if k else corners)
            drifts.append(drift)
            drift_sigmas.append(sigma)
    except InputError as exc:
        motion.drift_error = str(exc)
        return motion
    motion.drift_px, motion.drift_sigma_px = np.array(drifts), np.array(drift_sigmas)
    return motion


def _last_frame(video, where: str) -> np.ndarray:
    if isinstance(video, str | os.PathLike):
        kept = deque(read_frames(video), maxlen=1)  # (decoded to its end: a video's frame count is an estimate)
        if not kept:
            raise InputError(f"{where}: it has no frames")
        return kept[0]
    return np.asarray(video)


def motion_metadata(frames: Sequence[np.ndarray], names: Sequence[str], source: str = "the videos",
                    last: Sequence[np.ndarray] | None = None) -> dict | None:
    """:func:`camera_motion` of one frame per measurement (``frames``, named ``names``; with each one's ``last``
    frame, its move during it too) as a dataset's ``metadata["camera_motion"]`` (``calibrate`` counts its
    ``level_px`` in the covariance), a move said on stderr; None, with a warning, where the background cannot tell
    (``source`` names the recording in it)."""
    try:
        motion = camera_motion(frames, names=names, last=last)
    except InputError as exc:
        print(f"warning: whether the camera stayed still between {source} could not be told from their "
              f"background: {exc}", file=sys.stderr)
        return None
    if motion.drift_error is not None:
        print(f"warning: whether the camera stayed still during {source} could not be told: {motion.drift_error}",
              file=sys.stderr)
    if np.any(motion.moved):
        moved = [name for name, m in zip(motion.names, motion.moved, strict=True) if m]
        print(f"warning: the camera moved between {source} (the still background shifts by up to "
              f"{np.max(motion.size_px[motion.moved]):.3f} px: {', '.join(moved)}); calibrate counts what that moves "
              "the pose by in its covariance (`gtsam-rotid still` lists each video's shift)", file=sys.stderr)
    if np.any(motion.drifted):
        drifted = [f"{name} ({np.linalg.norm(d):.3f} px)" for name, d, m
                   in zip(motion.names, motion.drift_px, motion.drifted, strict=True) if m]
        print(f"warning: the camera moved during {', '.join(drifted)} (the still background's last frame against "
              "its first); calibrate counts what that moves the pose by in its covariance", file=sys.stderr)
    return motion.to_dict()

"""From pixels to a tracked dataset on a simulated scene: render the video, track it, measure the tracking.

The simulator (:mod:`gtsam_rotid.simulate`) gives the arm poses, the camera and the true ``arm_T_camera``; the
renderer (:mod:`gtsam_rotid.render`) draws each measurement's wrist spin as 8-bit frames; the tracker
(:mod:`gtsam_rotid.tracking`) turns them into tracks, frame by frame (frames are rendered one at a time and never
held); the estimator sees only the tracks. The simulator's own features are not used: the rendered dots (their
circles are those of the renderer's sections, :class:`~gtsam_rotid.render.RenderConfig`) are what is tracked.

- :func:`dataset_from_video`: a simulated scene -> :class:`VideoScene` (the tracked :class:`Dataset`, each
  measurement's :class:`~gtsam_rotid.tracking.TrackingResult`, the tracking accuracy against the rendered truth).
- :func:`tracking_accuracy` / :func:`spin_accuracy`: every tracked point matched to the nearest true dot centre
  in its frame; RMS error, the fraction matched, per-track bias, and tracks that follow more than one dot.

``gtsam-rotid demo`` (:mod:`gtsam_rotid.demo`) runs the whole pipeline on these.
"""

from __future__ import annotations

import dataclasses
import sys
import time
from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np

from .dataset import Dataset, Track
from .errors import InputError
from .frames import with_ends
from .meshrender import MeshRenderConfig, MeshSpin, load_arm_meshes, render_mesh_measurement, track_errors
from .render import RenderConfig, RenderedSpin, render_measurement
from .stillness import motion_metadata
from .tracking import Tracker, TrackerParams, TrackingResult, tracker_metadata

__all__ = [
    "TrackingAccuracy",
    "VideoScene",
    "dataset_from_video",
    "mesh_accuracy",
    "spin_accuracy",
    "tracking_accuracy",
]

#: A tracked point farther than this (px) from every true dot centre of its frame is unmatched.
MATCH_GATE_PX = 3.0


# ---------------------------------------------------------------------------------------------- accuracy
@dataclass(frozen=True)
class TrackingAccuracy:
    """Tracked points against the true dot centres (px).

    ``rms_px``, ``median_px`` and ``max_px`` are over the matched points (within ``gate_px`` of a true centre of
    their frame); ``bias_px`` is the RMS over tracks of each track's mean error vector (the part of the error that
    does not average out along an arc); ``n_mixed`` counts tracks whose matched points belong to more than one
    dot (the tracker hopped); ``n_on_visible`` counts matched points on dots the truth calls visible, and
    ``coverage`` is the fraction of the (frame, dot) pairs the truth calls visible that a matched point covers
    (NaN when the visibility is not known).
    """

    n_tracks: int
    n_points: int
    n_matched: int
    rms_px: float
    median_px: float
    max_px: float
    bias_px: float
    n_mixed: int
    n_on_visible: int
    coverage: float = float("nan")
    gate_px: float = MATCH_GATE_PX
    #: (frame, dot) pairs the truth calls visible (the denominator of ``coverage``)
    n_visible: int = 0
    #: ``"dots"``: matched to the nearest true dot centre (:func:`tracking_accuracy`); ``"surface"``: each track
    #: against the projection of the surface point it started on (:func:`mesh_accuracy`; ``n_mixed`` then counts
    #: tracks that do not lie on the spinning hand, and ``n_matched`` the points compared where that point is seen)
    truth: str = "dots"

    @property
    def matched_fraction(self) -> float:
        return self.n_matched / self.n_points if self.n_points else float("nan")

    def summary(self) -> str:
        if self.truth == "surface":
            return (f"{self.n_tracks} tracks, {self.n_points} points: RMS {self.rms_px:.3f} px (median "
                    f"{self.median_px:.3f}, max {self.max_px:.2f}) against the projection of each track's surface "
                    f"point, over the {100 * self.matched_fraction:.2f} % where it is visible; per-track bias "
                    f"{self.bias_px:.3f} px RMS; {self.n_mixed} tracks not on the spinning hand")
        return (f"{self.n_tracks} tracks, {self.n_points} points: RMS {self.rms_px:.3f} px (median "
                f"{self.median_px:.3f}, max {self.max_px:.2f}) over the {100 * self.matched_fraction:.2f} % "
                f"within {self.gate_px:g} px of a true dot centre; per-track bias {self.bias_px:.3f} px RMS; "
                f"{self.n_mixed} tracks on more than one dot"
                + ("" if np.isnan(self.coverage) else f"; {100 * self.coverage:.1f} % of visible dot-frames covered"))

    @staticmethod
    def pooled(parts) -> TrackingAccuracy:
        """The accuracy of several measurements together (exact for RMS and counts; the median is the
        points-weighted mean of the medians, the bias the tracks-weighted RMS)."""
        parts = list(parts)
        if not parts:
            raise InputError("no tracking accuracies to pool")
        matched = sum(p.n_matched for p in parts)
        tracks = sum(p.n_tracks for p in parts)

        def mean(values, weights):
            weights = np.asarray(weights, dtype=float)
            return float(np.sum(np.asarray(values) * weights) / weights.sum()) if weights.sum() else float("nan")

        return TrackingAccuracy(
            n_tracks=tracks, n_points=sum(p.n_points for p in parts), n_matched=matched,
            rms_px=float(np.sqrt(mean([p.rms_px ** 2 for p in parts], [p.n_matched for p in parts]))),
            median_px=mean([p.median_px for p in parts], [p.n_matched for p in parts]),
            max_px=max(p.max_px for p in parts),
            bias_px=float(np.sqrt(mean([p.bias_px ** 2 for p in parts], [p.n_tracks for p in parts]))),
            n_mixed=sum(p.n_mixed for p in parts), n_on_visible=sum(p.n_on_visible for p in parts),
            coverage=mean([p.coverage for p in parts], [p.n_visible for p in parts]), gate_px=parts[0].gate_px,
            n_visible=sum(p.n_visible for p in parts), truth=parts[0].truth)


def tracking_accuracy(tracks, truth_pixels, *, frame_indices=None, visible=None,
                      gate_px: float = MATCH_GATE_PX) -> TrackingAccuracy:
    """Match every tracked point to the nearest true dot centre of its frame and measure the error.

    Args:
        tracks: :class:`Track` s with frame indices.
        truth_pixels: (F, N, 2) true centres of N dots in F frames, NaN where a dot is not drawn (not a candidate).
        frame_indices: (F,) the frame number of each row of ``truth_pixels`` (default ``0..F-1``): a track's
            ``frames`` are looked up in it.
        visible: optional (F, N) bool, the dots the truth calls visible (for ``n_on_visible`` and ``coverage``).
        gate_px: a point farther than this from every candidate is unmatched (it counts in ``n_points`` only).
    """
    truth_pixels = np.asarray(truth_pixels, dtype=float)
    if truth_pixels.ndim != 3 or truth_pixels.shape[2] != 2:
        raise InputError(f"truth_pixels must have shape (F, N, 2), got {truth_pixels.shape}")
    n_frames = truth_pixels.shape[0]
    frame_indices = np.arange(n_frames) if frame_indices is None else np.asarray(frame_indices, dtype=np.int64)
    if frame_indices.shape != (n_frames,):
        raise InputError(f"frame_indices must have shape ({n_frames},), got {frame_indices.shape}")
    tracks = list(tracks)
    row_of = np.full(int(frame_indices.max(initial=-1)) + 1, -1, np.int64)
    row_of[frame_indices] = np.arange(n_frames)
    n_dots = truth_pixels.shape[1]
    if visible is not None:
        visible = np.asarray(visible, dtype=bool)
        if visible.shape != truth_pixels.shape[:2]:
            raise InputError(f"visible must have shape {truth_pixels.shape[:2]}, got {visible.shape}")
    errors, biases, cells, mixed, on_visible, total = [], [], [], 0, 0, 0
    for j, track in enumerate(tracks):
        track = Track.from_any(track, track=j)
        if track.frames is None:
            raise InputError(f"track {j} has no frame indices; they are needed to match it to the truth")
        total += len(track)
        known = track.frames < len(row_of)
        rows = np.where(known, row_of[np.minimum(track.frames, len(row_of) - 1)], -1)
        if np.any(rows < 0):
            raise InputError(f"track {j}: frame {int(track.frames[np.flatnonzero(rows < 0)[0]])} is not among the "
                             f"truth's frames")
        offsets = truth_pixels[rows] - track.pixels[:, None, :]                 # (n, N, 2): truth - tracked
        distance = np.where(np.isnan(offsets[..., 0]), np.inf, np.hypot(offsets[..., 0], offsets[..., 1]))
        nearest = np.argmin(distance, axis=1)
        matched = distance[np.arange(len(track)), nearest] <= gate_px
        if not matched.any():
            continue
        error = -offsets[np.arange(len(track)), nearest][matched]               # tracked - truth
        errors.append(error)
        biases.append(error.mean(axis=0))
        mixed += len(np.unique(nearest[matched])) > 1
        cells.append(rows[matched] * n_dots + nearest[matched])
        if visible is not None:
            on_visible += int(np.sum(visible[rows[matched], nearest[matched]]))
    n_tracks = len(tracks)
    n_visible = 0 if visible is None else int(visible.sum())
    coverage = float("nan")
    if visible is not None and n_visible:
        covered = np.unique(np.concatenate(cells)) if cells else np.zeros(0, np.int64)
        coverage = float(visible.ravel()[covered].sum() / n_visible)
    if not errors:
        return TrackingAccuracy(n_tracks, total, 0, float("nan"), float("nan"), float("nan"), float("nan"), mixed,
                                on_visible, coverage, gate_px, n_visible)
    norms = np.linalg.norm(np.concatenate(errors), axis=1)
    bias = np.linalg.norm(np.array(biases), axis=1)
    return TrackingAccuracy(n_tracks, total, len(norms), float(np.sqrt(np.mean(norms ** 2))), float(np.median(norms)),
                            float(norms.max()), float(np.sqrt(np.mean(bias ** 2))), mixed, on_visible, coverage,
                            gate_px, n_visible)


def spin_accuracy(tracks, spin: RenderedSpin, *, gate_px: float = MATCH_GATE_PX) -> TrackingAccuracy:
    """:func:`tracking_accuracy` against a rendering's true dot centres (``truth_pixels``: the projected centre,
    whose circle is the one the estimator fits). Every dot drawn in a frame (its face towards the camera, even
    if partly hidden or cut by the image border) is a candidate, so that no tracked point escapes the RMS."""
    drawn = np.where(spin.facing[..., None] > 0.0, spin.truth_pixels, np.nan)
    return tracking_accuracy(tracks, drawn, frame_indices=spin.frame_indices, visible=spin.visible, gate_px=gate_px)


def mesh_accuracy(tracks, spin: MeshSpin) -> TrackingAccuracy:
    """Tracked points against a mesh rendering's ground truth (:func:`gtsam_rotid.meshrender.track_errors`: each
    track's surface point located from its first points, projected in the track's frames where it is visible)."""
    tracks = list(tracks)
    e = track_errors(tracks, spin)
    compared = int(np.sum(e.n_compared))
    return TrackingAccuracy(len(tracks), sum(len(t) for t in tracks), compared, e.pooled_rms_px, e.pooled_median_px,
                            e.pooled_max_px, e.bias_px, len(e.off_links), compared, truth="surface")


# ---------------------------------------------------------------------------------------------- video -> dataset
@dataclass
class VideoScene:
    """What :func:`dataset_from_video` returns.

    ``dataset``: the simulated scene's arm, camera and joint angles with the tracker's tracks (frame numbers of
    the spin); ``tracking``: each measurement's :class:`TrackingResult` (with the rejected tracks and why);
    ``accuracy``: each measurement's :class:`TrackingAccuracy`; ``spins``: the renderings (frames are rendered
    again on demand, e.g. ``spins[k].frame(i)`` for a picture); ``render_seconds`` / ``track_seconds``: wall
    time spent drawing frames and tracking them.
    """

    dataset: Dataset
    tracking: list[TrackingResult]
    accuracy: list[TrackingAccuracy]
    spins: list[RenderedSpin]
    render_seconds: float = 0.0
    track_seconds: float = 0.0

    @property
    def n_frames(self) -> int:
        return sum(s.n_frames for s in self.spins)

    @property
    def total_accuracy(self) -> TrackingAccuracy:
        return TrackingAccuracy.pooled(self.accuracy)

    def busiest_frame(self, k: int) -> int:
        """Position (in ``spins[k]``) of the frame of measurement ``k`` with the most tracked points."""
        spin = self.spins[k]
        counts = np.zeros(spin.n_frames, np.int64)
        position = {int(f): i for i, f in enumerate(spin.frame_indices)}
        for track in self.dataset[k].tracks:
            counts[[position[int(f)] for f in track.frames]] += 1
        return int(np.argmax(counts))

    def summary(self) -> str:
        frames = self.n_frames
        speed = frames / self.track_seconds if self.track_seconds > 0 else float("nan")
        lines = [f"Rendered and tracked {frames} frames in {self.render_seconds:.1f} s + {self.track_seconds:.1f} s "
                 f"({speed:.0f} frames/s tracking)"]
        for k, (result, accuracy) in enumerate(zip(self.tracking, self.accuracy, strict=True)):
            rejected = len(result.rejected)
            lines.append(f"  measurement {k}: {len(result.tracks)} tracks kept, {rejected} rejected by the tracker; "
                         f"vs truth RMS {accuracy.rms_px:.3f} px, {100 * accuracy.matched_fraction:.1f} % matched")
        lines.append("  all: " + self.total_accuracy.summary())
        return "\n".join(lines)


class _Timed:
    """Frames from a generator, timing the generator (rendering) apart from the consumer (tracking)."""

    def __init__(self, frames: Iterator[np.ndarray], bar=None):
        self._frames, self._bar, self.seconds = frames, bar, 0.0

    def __iter__(self):
        while True:
            start = time.perf_counter()
            try:
                frame = next(self._frames)
            except StopIteration:
                return
            finally:
                self.seconds += time.perf_counter() - start
            yield frame
            if self._bar is not None:
                self._bar.update(1)


def dataset_from_video(dataset: Dataset, truth, render_config: RenderConfig | MeshRenderConfig | None = None,
                       tracker_params: TrackerParams | None = None, *, frames=None,
                       progress: bool = True) -> VideoScene:
    """Render every measurement of a simulated scene (``dataset, truth = simulate...``), track its frames and
    return the tracked dataset (same arm, camera and joint angles; the tracks come from the tracker, with the
    spin's frame numbers) with the tracking results and their accuracy against the rendered truth.

    ``render_config``: a :class:`~gtsam_rotid.render.RenderConfig` (default: the dotted stepped cylinder) or a
    :class:`~gtsam_rotid.meshrender.MeshRenderConfig` (the robot's own meshes with a covered hand).

    Frames are rendered one at a time and fed to the tracker (nothing is held). ``frames``: the frame selection
    of :func:`~gtsam_rotid.render.render_measurement` (default all). ``progress`` draws tqdm bars on stderr.
    A measurement in which the tracker keeps no track raises :class:`InputError` naming it.
    """
    from tqdm import tqdm

    render_config = RenderConfig() if render_config is None else render_config
    if not isinstance(render_config, RenderConfig | MeshRenderConfig):
        raise InputError(f"render_config must be a RenderConfig or a MeshRenderConfig, got "
                         f"{type(render_config).__name__}")
    mesh = isinstance(render_config, MeshRenderConfig)
    meshes = load_arm_meshes(dataset.arm) if mesh else None
    tracker_params = TrackerParams() if tracker_params is None else tracker_params
    measurements, results, accuracies, spins = [], [], [], []
    render_seconds = track_seconds = 0.0
    first_frames, last_frames = [], []
    n = len(dataset)
    with tqdm(total=n, desc="measurements", unit="spin", disable=not progress, file=sys.stderr) as outer:
        for k in range(n):
            start = time.perf_counter()
            spin = (render_mesh_measurement(dataset, truth, k, render_config, frames=frames, meshes=meshes) if mesh
                    else render_measurement(dataset, truth, k, render_config, frames=frames))
            render_seconds += time.perf_counter() - start
            start = time.perf_counter()
            with tqdm(total=spin.n_frames, desc=f"render + track {k}", unit="frame", leave=False,
                      disable=not progress, file=sys.stderr) as bar:
                ends: list = []  # (kept: the camera's stillness is read on each video's first and last frame)
                source = _Timed(with_ends(spin.frames(), ends), bar)
                result = Tracker(tracker_params).run(source)
            elapsed = time.perf_counter() - start
            render_seconds += source.seconds
            track_seconds += elapsed - source.seconds
            first_frames.append(ends[0])
            last_frames.append(ends[1])
            # the tracker numbers the frames it was fed 0, 1, ...: back to the spin's frame numbers
            tracks = [Track(t.pixels, spin.frame_indices[t.frames]) for t in result.tracks]
            rejected = [dataclasses.replace(r, track=Track(r.track.pixels, spin.frame_indices[r.track.frames]))
                        for r in result.rejected]
            result = dataclasses.replace(result, tracks=tracks, rejected=rejected)
            if not tracks:  # (one track is kept: the calibration leaves such a measurement out and names it)
                raise InputError(f"measurement {k}: the tracker kept no track in {spin.n_frames} rendered frames"
                                 f"\n{result.summary()}")
            measurements.append(dataset[k].replace(tracks=tracks))  # (frames numbered as the spin's)
            results.append(result)
            accuracies.append(mesh_accuracy(tracks, spin) if mesh else spin_accuracy(tracks, spin))
            spins.append(spin)
            outer.update(1)
    metadata = {key: value for key, value in dataset.metadata.items() if key != "noise_var"}
    metadata["video"] = {"rendered": True, "renderer": "mesh" if mesh else "cylinder",
                         **({"covering": render_config.covering} if mesh else {}),
                         "noise_sigma_grey": render_config.noise_sigma,
                         "render_seed": render_config.seed, "tracker": "gtsam_rotid.tracking.Tracker",
                         "tracker_params": dataclasses.asdict(tracker_params)}
    # the image axes' floor of its features
    metadata["tracker"] = tracker_metadata(tracker_params, sum(r.n_corner_tracks for r in results))
    if n > 1:  # did the camera stay still between and during the videos? (as make_dataset reads it)
        motion = motion_metadata(first_frames, [f"measurement {k}" for k in range(n)], "the rendered videos",
                                 last=last_frames)
        if motion is not None:
            metadata["camera_motion"] = motion
    tracked = Dataset(dataset.arm, dataset.camera, measurements, metadata=metadata)
    return VideoScene(tracked, results, accuracies, spins, render_seconds, track_seconds)

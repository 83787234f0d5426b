"""Synthetic video of a simulated scene: the spinning end effector seen through the scene's camera.

The model
---------
- **Body.** The end effector is a stepped cylinder about the spin axis (the measurement's truth: the wrist's, or
  the axis of the joint it spins, ``Measurement.spin_joint``; the cylinder then stands for the links after that
  joint and turns about its axis): coaxial :class:`Section` s, by
  default a wrist section (radius 3.5 cm, 0-5 cm along the axis) and a wider hand section (5.5 cm, 5-10 cm),
  inside the simulator's feature range (radius 3-6 cm, offset 0-10 cm). Sides are mid-grey, end caps a
  little darker, and each section's outline is a thin darker line (so the edge where the hand hides the
  wrist shows). A surface of revolution looks the same at every spin angle, so the body and the
  background are drawn once per measurement.
- **Covering.** A fixed set of dots painted on the sides (:func:`dot_covering`, the same for every
  measurement of a scene, since it is the same end effector): flat discs of radius ``size`` in the tangent
  plane of their section at radius ``R``, offset ``d`` along the axis, phase ``phase`` in the measurement's
  (e1, e2) basis, darker or brighter than the body by ``|contrast|`` grey levels, never overlapping. At
  frame f the centre of a dot is, as in :mod:`gtsam_rotid.simulate`,
  ``axis_point + d * axis + R (cos(phase + spin_f) e1 + sin(phase + spin_f) e2)``: it traces the circle
  of a simulated feature with that (R, d, phase). A flat disc's 3-D centroid is its centre, which lies on
  that circle exactly.
- **Occlusion.** A dot is drawn while its outward normal faces the camera (cos > 0); a section wider than
  the dot's own, nearer to the camera along the axis, hides it (the painter's algorithm: sections are drawn
  farthest first along the axis, and each dot is masked by the anti-aliased silhouette of the sections
  drawn after its own). A section no wider than the dot's own never hides it (it lies behind the dot's
  tangent plane).
- **Image formation.** Every outline is sampled in 3-D and projected with :meth:`Camera.project`, so lens
  distortion is included: a section's side is the convex hull of its two end circles (taken in
  undistorted pixels, its edges subdivided in 3-D before the distorted projection), each dot a
  ``dot_vertices``-gon. Anti-aliasing is by area: body outlines are filled at 4x4 and dots at
  ``supersample`` x ``supersample`` sub-pixels (sub-pixel vertex positions, ``cv2.fillPoly`` with ``shift``),
  then area-averaged. The static background is a smooth random texture (three octaves of cubic-upsampled
  noise, seeded, the same for every measurement: the camera does not move). Image noise is Gaussian with
  ``noise_sigma`` grey levels; for speed each frame takes a randomly shifted, randomly signed window of one
  pre-drawn noise field, seeded by (seed, measurement, frame number), so that any frame renders the same
  alone or in sequence. Frames are rounded to 8 bits.

Ground truth (per rendered frame and dot, :class:`RenderedSpin`): ``truth_pixels``, the projected dot
centre (distortion included, no noise); ``centroid_pixels``, the area centroid of the projected dot (what
an ideal blob detector measures: a finite disc seen in perspective, and through a distorted lens, has its
image centroid a few hundredths of a pixel from the image of its centre); ``facing``, the cosine between
the outward normal and the ray to the camera; ``visible``, facing > ``visibility_cos``, the centre and 8
rim points unhidden by any other section, and the whole dot inside the image.

Pixels follow the camera's convention: the origin at the centre of the top-left pixel (docs/design.md §2).

Entry points: :func:`render_measurement`, :func:`render_scene`, :func:`write_video`, :func:`save_truth`.
"""

from __future__ import annotations

import os
from collections.abc import Iterator
from dataclasses import dataclass, fields
from pathlib import Path

import cv2
import numpy as np

from .camera import Camera
from .errors import InputError, OutputExistsError, VideoWriteError
from .files import staged
from .renderconfig import RenderConfig, Section
from .videos import VIDEO_FOURCC, _check_output_target, write_video  # noqa: F401 (VIDEO_FOURCC: re-export)

__all__ = [
    "DotCovering",
    "OutputExistsError",
    "RenderConfig",
    "RenderedSpin",
    "Section",
    "VideoWriteError",
    "dot_covering",
    "render_measurement",
    "render_scene",
    "save_truth",
    "write_video",
]
_BODY_SUPERSAMPLE = 4
_OUTLINE_SAMPLES = 96  # points per end circle of a section outline
_RIM_SAMPLES_FOR_OCCLUSION = 8
_NOISE_PAD = 97  # the noise bank is this much larger than the image in each direction
_TRUTH_CHUNK = 128  # frames per vectorised truth computation
_DOT_LINE = cv2.LINE_AA  # anti-aliased edges on the fine grid: centroids ~1.5x closer than without


# --------------------------------------------------------------------------------------------- the covering
@dataclass(frozen=True, eq=False)
class DotCovering:
    """The dots on the end effector, one entry per dot (all arrays of length N).

    ``section``: index into ``RenderConfig.sections``; ``radius`` R and ``offset`` d (m) of the dot centre
    from the wrist axis and along it; ``phase`` (rad) at spin angle 0 in the measurement's (e1, e2) basis;
    ``size``: the disc radius (m); ``contrast``: dot grey minus body grey (negative: a dark dot).
    """

    section: np.ndarray
    radius: np.ndarray
    offset: np.ndarray
    phase: np.ndarray
    size: np.ndarray
    contrast: np.ndarray

    def __len__(self) -> int:
        return len(self.radius)


def dot_covering(config: RenderConfig | None = None) -> DotCovering:
    """Place every section's dots at random (seeded by ``config.seed``), never closer than ``dot_gap_mm``
    to each other or to the ends of their section. Raises :class:`InputError` when they do not fit."""
    config = RenderConfig() if config is None else config
    rng = np.random.default_rng([config.seed, 0])
    lo, hi = (v / 1000.0 for v in config.dot_radius_mm)
    gap = config.dot_gap_mm / 1000.0
    columns: dict[str, list] = {f.name: [] for f in fields(DotCovering)}
    for i, s in enumerate(config.sections):
        placed: list[tuple[float, float, float]] = []  # (offset, phase, size)
        for n in range(s.n_dots):
            for _ in range(5000):
                size = rng.uniform(lo, hi)
                d_lo, d_hi = s.start + size + gap, s.stop - size - gap
                if d_hi < d_lo:
                    continue
                d, phase = rng.uniform(d_lo, d_hi), rng.uniform(0.0, 2.0 * np.pi)
                if all(np.hypot(d - d2, s.radius * _wrapped(phase - p2)) >= size + size2 + gap
                       for d2, p2, size2 in placed):
                    placed.append((d, phase, size))
                    break
            else:
                raise InputError(
                    f"section {i} (radius {s.radius * 1000:g} mm, {(s.stop - s.start) * 1000:g} mm long) holds only "
                    f"{n} of its {s.n_dots} dots of radius {config.dot_radius_mm} mm with {config.dot_gap_mm} mm "
                    f"gaps; use fewer or smaller dots")
        for d, phase, size in placed:
            sign = 1.0 if rng.uniform() < config.bright_fraction else -1.0
            columns["section"].append(i)
            columns["radius"].append(s.radius)
            columns["offset"].append(d)
            columns["phase"].append(phase)
            columns["size"].append(size)
            columns["contrast"].append(sign * rng.uniform(*config.dot_contrast))
    arrays = {name: np.array(values, dtype=int if name == "section" else float) for name, values in columns.items()}
    for array in arrays.values():
        array.setflags(write=False)
    return DotCovering(**arrays)


def _wrapped(angle):
    return (np.asarray(angle) + np.pi) % (2.0 * np.pi) - np.pi


# --------------------------------------------------------------------------------------------- rasterising
def _fixed_point(polygon: np.ndarray, corner, scale: int) -> np.ndarray:
    """Pixel polygons (..., V, 2) -> int32 vertices for ``cv2.fillPoly(..., shift=4)`` on a ``scale``-times finer
    grid whose top-left sub-pixel starts at the top-left corner of pixel ``corner`` = (x0, y0)."""
    sub = (polygon - corner + 0.5) * scale - 0.5
    return np.round(sub * 16.0).astype(np.int32)


def _coverage(polygons: list[np.ndarray], window: tuple[int, int, int, int], scale: int,
              line_type: int = cv2.LINE_8, *, line_width: float = 0.0) -> np.ndarray:
    """Area coverage (uint8, 255 = full) of the union of pixel polygons over the pixel ``window``
    (x0, y0, x1, y1), by filling a ``scale``-times finer grid and area-averaging it. With ``line_width``
    (px), the coverage of the polygons' outlines drawn with that width instead."""
    x0, y0, x1, y1 = window
    fine = np.zeros(((y1 - y0) * scale, (x1 - x0) * scale), np.uint8)
    for polygon in polygons:  # one call each: fillPoly with several contours fills their symmetric difference
        vertices = _fixed_point(polygon, (x0, y0), scale)
        if line_width > 0:
            cv2.polylines(fine, [vertices], True, 255, max(1, round(line_width * scale)), cv2.LINE_AA, 4)
        else:
            cv2.fillPoly(fine, [vertices], 255, line_type, 4)
    if scale == 1:
        return fine
    return cv2.resize(fine, (x1 - x0, y1 - y0), interpolation=cv2.INTER_AREA)


def _window(polygons: list[np.ndarray], width: int, height: int, margin: int = 1) -> tuple[int, int, int, int] | None:
    """The image pixels a set of pixel polygons (grown by ``margin`` px) may touch, or None when none."""
    points = np.vstack(polygons)
    x0 = max(int(np.floor(points[:, 0].min())) - margin, 0)
    y0 = max(int(np.floor(points[:, 1].min())) - margin, 0)
    x1 = min(int(np.ceil(points[:, 0].max())) + margin + 1, width)
    y1 = min(int(np.ceil(points[:, 1].max())) + margin + 1, height)
    return None if x1 <= x0 or y1 <= y0 else (x0, y0, x1, y1)


def _full_coverage(polygons: list[np.ndarray], width: int, height: int, scale: int, *,
                   line_width: float = 0.0) -> np.ndarray:
    """Coverage in [0, 1] (float32, the whole image) of the union of pixel polygons (or of their outlines)."""
    out = np.zeros((height, width), np.float32)
    window = _window(polygons, width, height, margin=1 + int(np.ceil(line_width)))
    if window is not None:
        x0, y0, x1, y1 = window
        out[y0:y1, x0:x1] = _coverage(polygons, window, scale, line_width=line_width) * np.float32(1.0 / 255.0)
    return out


def _background(width: int, height: int, config: RenderConfig) -> np.ndarray:
    """A smooth random grey texture (float32), three octaves of cubic-upsampled Gaussian noise."""
    rng = np.random.default_rng([config.seed, 1])
    texture = np.zeros((height, width), np.float32)
    for scale, weight in ((config.background_scale_px, 1.0), (config.background_scale_px / 3.0, 0.5),
                          (config.background_scale_px / 9.0, 0.25)):
        scale = max(scale, 1.0)
        coarse = rng.standard_normal((int(np.ceil(height / scale)) + 3, int(np.ceil(width / scale)) + 3))
        texture += np.float32(weight) * cv2.resize(coarse.astype(np.float32), (width, height),
                                                   interpolation=cv2.INTER_CUBIC)
    texture -= texture.mean()
    texture /= max(float(texture.std()), 1e-6)
    lo, hi = config.background_grey
    return np.clip(0.5 * (lo + hi) + 0.2 * (hi - lo) * texture, lo, hi).astype(np.float32)


# --------------------------------------------------------------------------------------------- geometry
def _segments_hit_cylinder(origin: np.ndarray, points: np.ndarray, axis_point: np.ndarray, axis: np.ndarray,
                           radius: float, start: float, stop: float) -> np.ndarray:
    """True where the open segment from ``origin`` to each of ``points`` (..., 3) passes through the solid
    cylinder of ``radius`` about the axis, between offsets ``start`` and ``stop`` along it."""
    step = points - origin
    rel = origin - axis_point
    axial0 = rel @ axis
    axial_step = step @ axis
    radial0 = rel - axial0 * axis
    radial_step = step - axial_step[..., None] * axis
    a = np.einsum("...i,...i->...", radial_step, radial_step)
    b = radial_step @ radial0
    c = radial0 @ radial0 - radius * radius
    with np.errstate(divide="ignore", invalid="ignore"):
        root = np.sqrt(np.maximum(b * b - a * c, 0.0))
        t_in, t_out = (-b - root) / a, (-b + root) / a
        meets = b * b - a * c > 0.0
        # a segment parallel to the axis (a = 0) stays at one distance from it
        parallel = a <= 1e-300
        t_in = np.where(parallel, -np.inf, t_in)
        t_out = np.where(parallel, np.inf, t_out)
        meets = np.where(parallel, c <= 0.0, meets)
        t_a, t_b = (start - axial0) / axial_step, (stop - axial0) / axial_step
        flat = np.abs(axial_step) <= 1e-300
        inside = (start <= axial0) & (axial0 <= stop)
        t_lo = np.where(flat, np.where(inside, -np.inf, np.inf), np.minimum(t_a, t_b))
        t_hi = np.where(flat, np.where(inside, np.inf, -np.inf), np.maximum(t_a, t_b))
    lo = np.maximum(np.maximum(t_in, t_lo), 1e-9)
    hi = np.minimum(np.minimum(t_out, t_hi), 1.0 - 1e-9)
    return meets & (lo < hi)


def _polygon_centroids(polygons: np.ndarray) -> np.ndarray:
    """Area centroids of polygons (..., V, 2) -> (..., 2)."""
    nxt = np.roll(polygons, -1, axis=-2)
    cross = polygons[..., 0] * nxt[..., 1] - nxt[..., 0] * polygons[..., 1]
    area = cross.sum(axis=-1)
    with np.errstate(divide="ignore", invalid="ignore"):
        return ((polygons + nxt) * cross[..., None]).sum(axis=-2) / (3.0 * area[..., None])


# --------------------------------------------------------------------------------------------- one spin
class RenderedSpin:
    """One measurement's synthetic video: lazily rendered frames and the ground truth of every dot.

    Made by :func:`render_measurement`. Attributes (F = ``n_frames``, N = ``len(dots)``):
    ``measurement`` (index k), ``frame_indices`` (F,) frame numbers in the measurement (as in
    ``Track.frames``), ``spin_angles`` (F,), ``truth_pixels`` (F, N, 2), ``centroid_pixels`` (F, N, 2),
    ``facing`` (F, N), ``visible`` (F, N) bool, ``dots`` (:class:`DotCovering`), ``camera``, ``config``,
    ``fps``. See the module docstring for what each truth array means.
    """

    def __init__(self, k: int, camera: Camera, camera_T_arm, axis_point, axis_direction, e1, e2,
                 spin_angles, frame_indices, dots: DotCovering, config: RenderConfig, fps: float | None):
        self.measurement = k
        self.camera = camera
        self.config = config
        self.dots = dots
        self.fps = fps
        self.frame_indices = np.asarray(frame_indices, dtype=np.int64)
        self.spin_angles = np.asarray(spin_angles, dtype=float)
        self._R = camera_T_arm.rotation().matrix()
        self._t = camera_T_arm.translation()
        self._centre = -self._R.T @ self._t  # camera centre, arm frame
        self._p = np.asarray(axis_point, dtype=float)
        self._a = np.asarray(axis_direction, dtype=float)
        self._e1 = np.asarray(e1, dtype=float)
        self._e2 = np.asarray(e2, dtype=float)
        beta = np.linspace(0.0, 2.0 * np.pi, config.dot_vertices, endpoint=False)
        self._rim_cos, self._rim_sin = np.cos(beta), np.sin(beta)
        self._static: tuple[np.ndarray, dict[int, np.ndarray]] | None = None
        self._noise_bank: np.ndarray | None = None
        self._check_in_front()
        self._compute_truth()

    def __repr__(self) -> str:
        return (f"RenderedSpin(measurement {self.measurement}, {self.n_frames} frames of "
                f"{self.camera.width}x{self.camera.height}, {len(self.dots)} dots, "
                f"{self.visible.mean():.0%} visible)")

    @property
    def n_frames(self) -> int:
        return len(self.frame_indices)

    def __len__(self) -> int:
        return self.n_frames

    # ------------------------------------------------------------------ geometry
    def _to_camera(self, points_arm: np.ndarray) -> np.ndarray:
        return points_arm @ self._R.T + self._t

    def _project(self, points_arm: np.ndarray) -> np.ndarray:
        shape = points_arm.shape[:-1]
        return self.camera.project(self._to_camera(points_arm.reshape(-1, 3))).reshape(*shape, 2)

    def _dot_frames(self, spin: np.ndarray, dots: np.ndarray | slice = slice(None)):
        """Centres, outward normals and rims (arm frame) of dots at spin angles: (F, n, 3) x2, (F, n, V, 3)."""
        d = self.dots
        phase = d.phase[dots][None, :] + spin[:, None]
        cos, sin = np.cos(phase)[..., None], np.sin(phase)[..., None]
        normal = cos * self._e1 + sin * self._e2
        tangent = -sin * self._e1 + cos * self._e2
        centres = (self._p + d.offset[dots][:, None] * self._a) + d.radius[dots][:, None] * normal
        size = d.size[dots][None, :, None, None]
        rims = centres[..., None, :] + size * (self._rim_cos[:, None] * tangent[..., None, :]
                                               + self._rim_sin[:, None] * self._a)
        return centres, normal, rims

    def _facing(self, centres: np.ndarray, normal: np.ndarray) -> np.ndarray:
        to_camera = self._centre - centres
        return np.einsum("...i,...i->...", normal, to_camera) / np.linalg.norm(to_camera, axis=-1)

    def _check_in_front(self) -> None:
        for i, s in enumerate(self.config.sections):
            ring = self._section_circles(s)
            if np.min(self._to_camera(ring)[:, 2]) <= 1e-3:
                raise InputError(f"measurement {self.measurement}: section {i} of the end effector reaches behind "
                                 f"the camera; the renderer needs the whole end effector in front of it")
            rel = self._centre - self._p
            axial = rel @ self._a
            if s.start <= axial <= s.stop and np.linalg.norm(rel - axial * self._a) <= s.radius:
                raise InputError(f"measurement {self.measurement}: the camera is inside section {i} of the end "
                                 f"effector")

    def _compute_truth(self) -> None:
        n_frames, n_dots = self.n_frames, len(self.dots)
        width, height = self.camera.width, self.camera.height
        self.truth_pixels = np.empty((n_frames, n_dots, 2))
        self.centroid_pixels = np.empty((n_frames, n_dots, 2))
        self.facing = np.empty((n_frames, n_dots))
        self.visible = np.zeros((n_frames, n_dots), dtype=bool)
        sections = self.config.sections
        step = max(1, self.config.dot_vertices // _RIM_SAMPLES_FOR_OCCLUSION)
        for first in range(0, n_frames, _TRUTH_CHUNK):
            chunk = slice(first, min(first + _TRUTH_CHUNK, n_frames))
            centres, normal, rims = self._dot_frames(self.spin_angles[chunk])
            facing = self._facing(centres, normal)
            rim_px = self._project(rims)
            inside = np.all((rim_px[..., 0] >= -0.5) & (rim_px[..., 0] <= width - 0.5)
                            & (rim_px[..., 1] >= -0.5) & (rim_px[..., 1] <= height - 0.5), axis=-1)
            samples = np.concatenate([centres[:, :, None, :], rims[:, :, ::step, :]], axis=2)
            hidden = np.zeros(facing.shape, dtype=bool)
            for i, s in enumerate(sections):
                others = self.dots.section != i
                if not np.any(others):
                    continue
                hit = _segments_hit_cylinder(self._centre, samples[:, others], self._p, self._a,
                                             s.radius, s.start, s.stop)
                hidden[:, others] |= np.any(hit, axis=-1)
            self.truth_pixels[chunk] = self._project(centres)
            self.centroid_pixels[chunk] = _polygon_centroids(rim_px)
            self.facing[chunk] = facing
            self.visible[chunk] = (facing > self.config.visibility_cos) & ~hidden & inside
        for array in (self.truth_pixels, self.centroid_pixels, self.facing, self.visible):
            array.setflags(write=False)

    # ------------------------------------------------------------------ the static image
    def _section_circles(self, section: Section, samples: int = _OUTLINE_SAMPLES) -> np.ndarray:
        phi = np.linspace(0.0, 2.0 * np.pi, samples, endpoint=False)
        ring = section.radius * (np.cos(phi)[:, None] * self._e1 + np.sin(phi)[:, None] * self._e2)
        return np.vstack([self._p + section.start * self._a + ring, self._p + section.stop * self._a + ring])

    def _section_outline(self, section: Section) -> np.ndarray:
        """The image outline of a section's solid cylinder: the hull of its end circles, distorted."""
        points = self._section_circles(section)
        ideal = self.camera.project(self._to_camera(points), distort=False).astype(np.float32)
        hull = cv2.convexHull(ideal.reshape(-1, 1, 2), returnPoints=False).ravel()
        outline = []
        for a, b in zip(hull, np.roll(hull, -1), strict=True):
            pieces = int(np.clip(np.ceil(np.linalg.norm(ideal[b] - ideal[a]) / 2.0), 1, 500))
            t = np.arange(pieces)[:, None] / pieces
            outline.append(points[a] + t * (points[b] - points[a]))
        return self._project(np.vstack(outline))

    def _cap_outline(self, section: Section) -> np.ndarray | None:
        """The outline of the end cap that faces the camera, or None when the camera sees neither cap."""
        axial = (self._centre - self._p) @ self._a
        if section.start <= axial <= section.stop:
            return None
        ring = self._section_circles(section)
        return self._project(ring[_OUTLINE_SAMPLES:] if axial > section.stop else ring[:_OUTLINE_SAMPLES])

    def _static_layers(self) -> tuple[np.ndarray, dict[int, np.ndarray]]:
        """(background + body, float32) and, per section, the coverage of the sections drawn over it."""
        if self._static is None:
            cfg, width, height = self.config, self.camera.width, self.camera.height
            image = _background(width, height, cfg)
            axial = (self._centre - self._p) @ self._a
            distance = [max(s.start - axial, axial - s.stop, 0.0) for s in cfg.sections]
            order = sorted(range(len(cfg.sections)), key=lambda i: -distance[i])  # farthest first
            outlines = {i: self._section_outline(cfg.sections[i]) for i in order}
            for i in order:
                cover = _full_coverage([outlines[i]], width, height, _BODY_SUPERSAMPLE)
                image += cover * (np.float32(cfg.body_grey) - image)
                cap = self._cap_outline(cfg.sections[i])
                if cap is not None:
                    cover = _full_coverage([cap], width, height, _BODY_SUPERSAMPLE)
                    image += cover * (np.float32(cfg.cap_grey) - image)
                if cfg.edge_width_px > 0:
                    cover = _full_coverage([outlines[i]], width, height, _BODY_SUPERSAMPLE,
                                           line_width=cfg.edge_width_px)
                    image += cover * (np.float32(cfg.edge_grey) - image)
            masks = {}
            for rank, i in enumerate(order):
                nearer = [outlines[j] for j in order[rank + 1:]]
                if nearer:
                    masks[i] = 1.0 - _full_coverage(nearer, width, height, _BODY_SUPERSAMPLE)
            self._static = (image, masks)
        return self._static

    @property
    def background(self) -> np.ndarray:
        """The frame without dots and noise (background and body), uint8 (H, W)."""
        return _to_uint8(self._static_layers()[0].copy())

    # ------------------------------------------------------------------ frames
    def _noise(self, frame_number: int) -> tuple[np.ndarray, float]:
        if self._noise_bank is None:
            rng = np.random.default_rng([self.config.seed, 2])
            shape = (self.camera.height + _NOISE_PAD, self.camera.width + _NOISE_PAD)
            self._noise_bank = rng.standard_normal(shape, dtype=np.float32)
        rng = np.random.default_rng([self.config.seed, 3, self.measurement, frame_number])
        oy, ox = rng.integers(0, _NOISE_PAD + 1, size=2)
        sign = 1.0 if rng.integers(2) else -1.0
        return self._noise_bank[oy:oy + self.camera.height, ox:ox + self.camera.width], sign

    def frame(self, i: int, *, color: bool = False) -> np.ndarray:
        """Render frame ``i`` (position in ``frame_indices``): uint8 (H, W), or (H, W, 3) BGR with ``color``."""
        if isinstance(i, bool) or not isinstance(i, (int, np.integer)) or not -self.n_frames <= i < self.n_frames:
            raise InputError(f"measurement {self.measurement}: frame position {i!r} is outside this rendering's "
                             f"{self.n_frames} frames")
        i = int(i) % self.n_frames
        cfg = self.config
        base, masks = self._static_layers()
        image = base.copy()
        width, height = self.camera.width, self.camera.height
        drawn = np.flatnonzero(self.facing[i] > 0.0)
        if drawn.size:
            _, _, rims = self._dot_frames(self.spin_angles[i:i + 1], drawn)
            rim_px = self._project(rims[0])  # (n, V, 2)
            scale = cfg.supersample
            corner0 = np.maximum(np.floor(rim_px.min(axis=1)).astype(int) - 1, 0)
            corner1 = np.minimum(np.ceil(rim_px.max(axis=1)).astype(int) + 2, (width, height))
            fixed = _fixed_point(rim_px, corner0[:, None, :], scale)
            levels = (cfg.body_grey + self.dots.contrast[drawn]).astype(np.float32)
            for j, (x0, y0), (x1, y1), polygon, level in zip(drawn, corner0.tolist(), corner1.tolist(), fixed,
                                                              levels, strict=True):
                if x1 <= x0 or y1 <= y0:
                    continue  # outside the image
                fine = np.zeros(((y1 - y0) * scale, (x1 - x0) * scale), np.uint8)
                cv2.fillPoly(fine, [polygon], 255, _DOT_LINE, 4)
                alpha = cv2.resize(fine, (x1 - x0, y1 - y0), interpolation=cv2.INTER_AREA) * np.float32(1 / 255)
                mask = masks.get(int(self.dots.section[j]))
                if mask is not None:
                    alpha *= mask[y0:y1, x0:x1]
                patch = image[y0:y1, x0:x1]
                patch += alpha * (level - patch)
        if cfg.noise_sigma > 0:
            noise, sign = self._noise(int(self.frame_indices[i]))
            image = cv2.scaleAdd(noise, sign * cfg.noise_sigma, image)
        grey = _to_uint8(image)
        return cv2.cvtColor(grey, cv2.COLOR_GRAY2BGR) if color else grey

    def frames(self, *, color: bool = False) -> Iterator[np.ndarray]:
        """Every frame in order, rendered one at a time (nothing is kept)."""
        for i in range(self.n_frames):
            yield self.frame(i, color=color)

    def __iter__(self) -> Iterator[np.ndarray]:
        return self.frames()


def _to_uint8(image: np.ndarray) -> np.ndarray:
    """Round a float grey image to 8 bits, saturating at 0 and 255."""
    np.maximum(image, 0.0, out=image)
    return cv2.convertScaleAbs(image)


# --------------------------------------------------------------------------------------------- entry points
def _checked_scene(dataset, truth) -> None:
    for name in ("camera", "metadata"):
        if not hasattr(dataset, name):
            raise InputError(f"dataset must be a gtsam_rotid Dataset, got {type(dataset).__name__}")
    if not hasattr(truth, "measurements") or not hasattr(truth, "arm_T_camera"):
        raise InputError(f"truth must be the GroundTruth of a simulated scene, got {type(truth).__name__}")
    if len(truth.measurements) != len(dataset):
        raise InputError(f"the truth describes {len(truth.measurements)} measurements but the dataset holds "
                         f"{len(dataset)}; pass the pair returned by one simulate call")


def _frame_selection(frames, n_frames: int, k: int) -> np.ndarray:
    if frames is None:
        return np.arange(n_frames)
    if isinstance(frames, slice):
        selection = np.arange(n_frames)[frames]
    else:
        selection = np.atleast_1d(np.asarray(frames))
        if selection.ndim != 1 or (selection.size and selection.dtype.kind not in "iu"):
            raise InputError(f"measurement {k}: frames must be None, a slice or a 1-D array of integer frame "
                             f"numbers, got {frames!r}")
        bad = selection[(selection < 0) | (selection >= n_frames)]
        if bad.size:
            raise InputError(f"measurement {k}: frame {int(bad[0])} is outside the spin's frames 0..{n_frames - 1}")
    if selection.size == 0:
        raise InputError(f"measurement {k}: the frame selection {frames!r} is empty")
    return selection.astype(np.int64)


def scene_spin(dataset, truth, k, frames=None) -> tuple[int, object, np.ndarray, np.ndarray, float | None]:
    """Measurement ``k`` of a simulated scene, checked for a renderer: (k, its truth, its spin angles, the frame
    selection of ``frames`` (see :func:`render_measurement`), the video's fps or None)."""
    _checked_scene(dataset, truth)
    if isinstance(k, bool) or not isinstance(k, (int, np.integer)) or not 0 <= k < len(dataset):
        raise InputError(f"measurement index {k!r} is outside the dataset's measurements 0..{len(dataset) - 1}")
    k = int(k)
    mt = truth.measurements[k]
    spin = np.asarray(mt.spin_angles, dtype=float)
    if spin.ndim != 1 or spin.size == 0 or not np.all(np.isfinite(spin)):
        raise InputError(f"measurement {k}: the truth's spin_angles must be a non-empty finite 1-D array")
    selection = _frame_selection(frames, spin.size, k)
    fps = dataset.metadata.get("fps", getattr(truth, "config", {}).get("fps"))
    return k, mt, spin, selection, None if fps is None else float(fps)


def render_measurement(dataset, truth, k: int, config: RenderConfig | None = None, *,
                       frames=None) -> RenderedSpin:
    """The synthetic video of measurement ``k`` of a simulated scene (``dataset, truth = simulate...``).

    ``frames``: None (all of the spin's frames), a slice, or an array of frame numbers. The ground truth is
    computed at once; frames are rendered lazily by :meth:`RenderedSpin.frames`.
    """
    config = RenderConfig() if config is None else config
    if not isinstance(config, RenderConfig):
        raise InputError(f"config must be a RenderConfig, got {type(config).__name__}")
    k, mt, spin, selection, fps = scene_spin(dataset, truth, k, frames)
    return RenderedSpin(k, dataset.camera, truth.arm_T_camera.inverse(), mt.axis_point, mt.axis_direction,
                        mt.e1, mt.e2, spin[selection], selection, dot_covering(config), config, fps)


def render_scene(dataset, truth, config: RenderConfig | None = None, *, frames=None) -> list[RenderedSpin]:
    """:func:`render_measurement` for every measurement of the scene (the same covering on each)."""
    _checked_scene(dataset, truth)
    return [render_measurement(dataset, truth, k, config, frames=frames) for k in range(len(dataset))]


def save_truth(rendered: RenderedSpin, path: str | os.PathLike, *, overwrite: bool = False) -> Path:
    """Write a rendering's ground truth as a compressed ``.npz`` (arrays named like the attributes, the dot
    parameters as ``dot_<field>``). Refuses to overwrite unless asked; written through a temporary file."""
    if not isinstance(rendered, RenderedSpin):
        raise InputError(f"save_truth needs a RenderedSpin, got {type(rendered).__name__}")
    target = Path(os.path.abspath(os.fspath(path)))
    if target.suffix != ".npz":
        raise InputError(f"{target}: the truth file name must end in .npz")
    _check_output_target(target, overwrite, folder=False)
    arrays = {name: getattr(rendered, name) for name in
              ("frame_indices", "spin_angles", "truth_pixels", "centroid_pixels", "facing", "visible")}
    arrays.update({f"dot_{f.name}": getattr(rendered.dots, f.name) for f in fields(DotCovering)})
    arrays["measurement"] = np.array(rendered.measurement)
    arrays["fps"] = np.array(np.nan if rendered.fps is None else rendered.fps)
    with staged(target, overwrite) as staging, open(staging, "wb") as handle:
        np.savez_compressed(handle, **arrays)
    return target

"""Realistic synthetic video of a simulated scene: the robot's own meshes, ray cast on the CPU.

The model
---------
- **Scene.** The arm's visual meshes (the Pinocchio visual model: example-robot-data's .dae / .stl files, or
  a URDF's meshes found through ``package_dirs``), loaded with trimesh (pycollada for .dae), placed at the
  measurement's joint angles; a back wall perpendicular to the camera's optical axis at
  ``background_distance`` (a photograph, smooth noise or plain; with ``camera_moved`` the wall of the truth's
  camera, seen by the moved one) and optionally a floor (the plane
  ``z = floor_height`` of the arm-base frame, a wood-like noise). The geometry whose parent joint is the spinning
  joint (the measurement's ``spin_joint``, default the wrist) or one of its descendants (for the wrist: the hand,
  its fingers, the wrist ring) spins; everything else is still.
- **Spin.** In frame f the spinning joint is turned by ``spin_angles[f]``: the spinning links sit at
  ``arm_T_link(f) = arm_T_joint(q with q[spin] + spin_f)`` (Pinocchio's frame of the spinning joint), so a point
  p fixed in the link frame is at ``camera_T_arm * arm_T_link(f) * p``.
- **Covering.** The spinning links carry a texture mapped in their own frame, so a surface point's colour
  (albedo) never changes as it spins: cylindrical about the spin axis (angle about the axis, offset along it;
  the angle's origin is the simulator's phase-0 direction ``e1``) on faces that face sideways, planar
  (triplanar-style, the two coordinates across the axis) on faces within 41 deg of the axis (caps).
  ``covering`` is one of ``"photo"`` (matplotlib's sample photographs), ``"text"`` (printed text on a light
  label), ``"fabric"`` (woven-cloth noise), ``"stickers"`` (a few coloured stickers on plain plastic),
  ``"dots"`` (bright and dark dots, as :mod:`gtsam_rotid.render` paints) or ``"plain"``. With
  ``covered_fraction`` < 1 only that fraction of the circumference (angles from -pi) is textured, the rest is
  plain ``hand_color``. Still links take the visual model's colours (or ``arm_color``).
- **Shading.** One directional light fixed in the arm-base frame plus ambient light, Lambert diffuse and
  Blinn-Phong highlights, flat per triangle (normals flipped to face the camera, so open meshes work). No
  shadows. The shading moves over the hand as it spins (the light is still); the albedo does not.
- **Image formation.** Every sub-sample is a ray from the camera centre through ``camera.rays`` of its raw
  (distorted) pixel position: lens distortion is exactly :meth:`Camera.project`'s. Pixel (0, 0) is the centre
  of the top-left pixel; a pixel holds ``supersample`` x ``supersample`` sub-samples, box-averaged
  (anti-aliasing). Optional motion blur averages ``blur_samples`` spin angles spread over ``exposure`` of
  the frame interval. Gaussian sensor noise of ``noise_sigma`` levels (a shifted, signed window of one
  pre-drawn field, seeded by (seed, measurement, frame number): a frame renders the same alone or in a
  sequence), 8-bit output, BGR or grey.
- **Speed.** The still scene (background, floor, still links) does not move during a spin: it is cast once
  per measurement, colour and depth per sub-sample. Per frame only the sub-samples inside the image region
  the spinning links can cover (their swept cylinder, projected once; within it, the bounds of the frame's
  projected vertices) are cast, against the spinning links alone, by turning the rays into the spinning
  link's frame (inverse rotation about the spin axis) instead of moving the mesh, with the still scene's
  depth as the ray's far limit; the nearer surface wins. Ray casting is Intel Embree (``embreex``).

Ground truth (:class:`MeshSpin`; ``frame`` arguments are frame numbers of the measurement, as in
``Track.frames``): :meth:`MeshSpin.surface_points` (pixels -> link-frame points, NaN off the spinning links),
:meth:`MeshSpin.project_points` (link-frame points -> pixels and visibility), :meth:`MeshSpin.moving_mask`,
:meth:`MeshSpin.moving_region`, and :func:`track_errors` (tracks against the projection of their surface
point). :func:`pose_problem` says whether an arm pose is renderable.

Entry points: :func:`render_mesh_measurement`, :func:`render_mesh_scene`, :func:`load_arm_meshes`; write
videos with :func:`gtsam_rotid.render.write_video`.
"""

from __future__ import annotations

import functools
from collections.abc import Iterator
from dataclasses import dataclass

import cv2
import numpy as np

from .arm import Arm
from .armmeshes import ArmMeshes, load_arm_meshes
from .camera import Camera
from .errors import InputError
from .meshcast import _Geometry, _inside_convex, _renderability, _swept_polygon, pose_problem
from .meshconfig import BACKGROUNDS, COVERINGS, MeshRenderConfig
from .render import _checked_scene, scene_spin

__all__ = [
    "BACKGROUNDS",
    "COVERINGS",
    "ArmMeshes",
    "MeshRenderConfig",
    "MeshSpin",
    "TrackErrors",
    "load_arm_meshes",
    "pose_problem",
    "render_mesh_measurement",
    "render_mesh_scene",
    "track_errors",
]
_NOISE_PAD = 97


# --------------------------------------------------------------------------------------------- one spin
@functools.lru_cache(maxsize=4)
def _subsample_rays(K: bytes, dist: bytes | None, width: int, height: int, scale: int):
    """Unit camera-frame rays (float64) and undistorted normalised coordinates of the sub-sample grid."""
    camera = Camera(np.frombuffer(K).reshape(3, 3), width, height,
                    None if dist is None else np.frombuffer(dist))
    ys, xs = np.mgrid[0:height * scale, 0:width * scale]
    pixels = np.column_stack([(xs.ravel() + 0.5) / scale - 0.5, (ys.ravel() + 0.5) / scale - 0.5])
    xy = camera.normalize(pixels)
    rays = np.column_stack([xy, np.ones(len(xy))])
    rays /= np.linalg.norm(rays, axis=1, keepdims=True)
    rays.setflags(write=False)
    xy.setflags(write=False)
    return rays, xy


class MeshSpin:
    """One measurement's mesh-rendered video: lazily rendered frames and ground truth by ray casting.

    Made by :func:`render_mesh_measurement`. ``frame(i)`` takes a position in ``frame_indices``; the ground
    truth methods take frame numbers of the measurement (as ``Track.frames``; the same when every frame is
    rendered).
    """

    def __init__(self, k: int, arm: Arm, camera: Camera, arm_T_camera, joint_angles, all_spin_angles,
                 frame_indices, config: MeshRenderConfig, fps: float | None, meshes: ArmMeshes,
                 spin_joint: str | None = None, wall_arm_T_camera=None):
        self.measurement = k
        self.arm = arm
        self.camera = camera
        self.config = config
        self.fps = fps
        self.meshes = meshes
        self._all_spin = np.asarray(all_spin_angles, dtype=float)
        self.frame_indices = np.asarray(frame_indices, dtype=np.int64)
        self.spin_angles = self._all_spin[self.frame_indices]
        self._step = np.gradient(self._all_spin) if len(self._all_spin) > 1 else np.zeros(1)
        self._geometry = _Geometry(arm, meshes, camera, arm_T_camera, joint_angles, config, spin_joint,
                                   wall_arm_T_camera)
        #: the joint that spins (its name in the model; the wrist's when the measurement names none)
        self.spin_joint = self._geometry.spin_joint
        problem = _renderability(self._geometry)
        if problem is not None:
            raise InputError(f"measurement {k}: the mesh renderer cannot render this arm pose: {problem}")
        self.moving_links = tuple(self._geometry.moving_names)
        self._static: tuple | None = None
        self._noise_bank: dict[bool, np.ndarray] = {}

    def __repr__(self) -> str:
        return (f"MeshSpin(measurement {self.measurement}, {self.n_frames} frames of {self.camera.width}x"
                f"{self.camera.height}, covering {self.config.covering!r}, spinning {len(self.moving_links)} meshes)")

    @property
    def n_frames(self) -> int:
        return len(self.frame_indices)

    def __len__(self) -> int:
        return self.n_frames

    # ------------------------------------------------------------------ the still layer, once
    def _static_layers(self):
        if self._static is None:
            g, camera, s = self._geometry, self.camera, self.config.supersample
            W, H = camera.width * s, camera.height * s
            rays, xy = _subsample_rays(camera.K.tobytes(), None if camera.dist is None else camera.dist.tobytes(),
                                       camera.width, camera.height, s)
            t, kind, face = g.cast_still(rays)
            colors = g.still_colors(rays, t, kind, face).reshape(H, W, 3)
            image = cv2.resize(colors, (camera.width, camera.height), interpolation=cv2.INTER_AREA) if s > 1 \
                else colors.copy()
            inside = _inside_convex(_swept_polygon(g), xy).reshape(H, W)
            pixel_any = inside.reshape(camera.height, s, camera.width, s).any(axis=(1, 3))
            rows, cols = np.flatnonzero(pixel_any.any(axis=1)), np.flatnonzero(pixel_any.any(axis=0))
            if len(rows) == 0:
                raise InputError(f"measurement {self.measurement}: the spinning links do not appear in the image")
            y0, y1, x0, x1 = rows[0], rows[-1] + 1, cols[0], cols[-1] + 1
            block = (slice(y0 * s, y1 * s), slice(x0 * s, x1 * s))
            in_block = inside[block]
            flat = np.flatnonzero(in_block.ravel())
            grid_index = (np.arange(H * W).reshape(H, W)[block]).ravel()[flat]
            candidates = {
                "flat": flat,
                "dirs": rays[grid_index].astype(np.float32),
                "xy": xy[grid_index],
                "far": t[grid_index],
            }
            self._static = (image, colors, (y0, y1, x0, x1), candidates, pixel_any)
        return self._static

    def moving_region(self) -> np.ndarray:
        """(H, W) bool: the pixels the spinning links can cover at some spin angle (all others never change,
        noise aside)."""
        return self._static_layers()[4].copy()

    @property
    def background(self) -> np.ndarray:
        """The still scene alone (no spinning links, no noise), uint8 BGR (H, W, 3)."""
        return _to_uint8(self._static_layers()[0].copy())

    def _block(self, spin: float) -> np.ndarray:
        """Colours of the sub-samples of the moving block at one spin angle (still scene where unhit)."""
        g = self._geometry
        _, colors, (y0, y1, x0, x1), cand, _ = self._static_layers()
        s = self.config.supersample
        block = colors[y0 * s:y1 * s, x0 * s:x1 * s].copy()
        # this frame's projected vertices bound the rays worth casting (perspective keeps triangles convex)
        R, origin = g.camera_in_link(spin)
        cam = (g.hull_points @ R.astype(np.float32) - (origin @ R).astype(np.float32))
        xy = cam[:, :2] / cam[:, 2:3]
        (xmin, ymin), (xmax, ymax) = xy.min(axis=0) - 1e-4, xy.max(axis=0) + 1e-4
        cx, cy = cand["xy"][:, 0], cand["xy"][:, 1]
        sel = np.flatnonzero((cx >= xmin) & (cx <= xmax) & (cy >= ymin) & (cy <= ymax))
        if len(sel) == 0:
            return block
        dirs = cand["dirs"][sel] @ R.T.astype(np.float32)
        t, face = g.moving.cast(origin, dirs, cand["far"][sel])
        hit = face >= 0
        if np.any(hit):
            d = dirs[hit]
            points = origin + d * t[hit, None]
            color = g.moving_colors(points, face[hit], d, g.light_in_link(spin))
            block.reshape(-1, 3)[cand["flat"][sel[hit]]] = color
        return block

    def _spins_of(self, i: int) -> np.ndarray:
        spin = self.spin_angles[i]
        n = self.config.blur_angles
        if n == 1:
            return np.array([spin])
        step = self._step[self.frame_indices[i]]
        return spin + ((np.arange(n) + 0.5) / n - 0.5) * self.config.exposure * step

    def frame(self, i: int, *, color: bool = False) -> np.ndarray:
        """Render frame ``i`` (position in ``frame_indices``): uint8 (H, W) grey, or (H, W, 3) BGR with ``color``."""
        if isinstance(i, bool) or not isinstance(i, (int, np.integer)) or not -self.n_frames <= i < self.n_frames:
            raise InputError(f"measurement {self.measurement}: frame position {i!r} is outside this rendering's "
                             f"{self.n_frames} frames")
        i = int(i) % self.n_frames
        image, _, (y0, y1, x0, x1), _, _ = self._static_layers()
        spins = self._spins_of(i)
        block = self._block(float(spins[0]))
        for spin in spins[1:]:
            block += self._block(float(spin))
        if len(spins) > 1:
            block *= np.float32(1.0 / len(spins))
        out = image.copy()
        out[y0:y1, x0:x1] = cv2.resize(block, (x1 - x0, y1 - y0), interpolation=cv2.INTER_AREA) \
            if self.config.supersample > 1 else block
        if not color:
            out = cv2.cvtColor(out, cv2.COLOR_BGR2GRAY)
        if self.config.noise_sigma > 0:
            noise, sign = self._noise(int(self.frame_indices[i]), color)
            out = cv2.scaleAdd(noise, sign * self.config.noise_sigma, out)
        return _to_uint8(out)

    def _noise(self, frame_number: int, color: bool) -> tuple[np.ndarray, float]:
        height, width = self.camera.height, self.camera.width
        if color not in self._noise_bank:
            rng = np.random.default_rng([self.config.seed, 2, int(color)])
            shape = (height + _NOISE_PAD, width + _NOISE_PAD) + ((3,) if color else ())
            self._noise_bank[color] = rng.standard_normal(shape, dtype=np.float32)
        rng = np.random.default_rng([self.config.seed, 3, self.measurement, frame_number])
        oy, ox = rng.integers(0, _NOISE_PAD + 1, size=2)
        sign = 1.0 if rng.integers(2) else -1.0
        return self._noise_bank[color][oy:oy + height, ox:ox + width], sign

    def frames(self, *, color: bool = False) -> Iterator[np.ndarray]:
        """Every frame in order, rendered one at a time (nothing is kept)."""
        for i in range(self.n_frames):
            yield self.frame(i, color=color)

    def __iter__(self) -> Iterator[np.ndarray]:
        return self.frames()

    # ------------------------------------------------------------------ ground truth
    def _spin_of(self, frame) -> float:
        if isinstance(frame, bool) or not isinstance(frame, (int, np.integer)) or not \
                0 <= frame < len(self._all_spin):
            raise InputError(f"measurement {self.measurement}: frame number {frame!r} is outside the spin's frames "
                             f"0..{len(self._all_spin) - 1}")
        return float(self._all_spin[int(frame)])

    def arm_T_link(self, frame: int):
        """Pose (gtsam.Pose3) of the spinning link frame (the spinning joint's frame) at a frame number."""
        q = self._geometry.joint_angles.copy()
        q[self._geometry.spin_index] += self._spin_of(frame)
        return self.arm.arm_T_joint(q, self.spin_joint)

    def surface_points(self, frame: int, pixels) -> np.ndarray:
        """Link-frame points (N, 3) that raw ``pixels`` (N, 2) see at frame number ``frame``; NaN where the
        pixel does not see a spinning link first."""
        spin = self._spin_of(frame)
        pixels = np.asarray(pixels, dtype=float).reshape(-1, 2)
        out = np.full((len(pixels), 3), np.nan)
        finite = np.all(np.isfinite(pixels), axis=1)
        if not np.any(finite):
            return out
        dirs = self.camera.rays(pixels[finite])
        g = self._geometry
        t_still, _, _ = g.cast_still(dirs)
        t, face, dirs_link, origin = g.cast_moving(spin, dirs)
        hit = (face >= 0) & (t < t_still)
        # the link-frame direction in float64, for points precise beyond float32
        R, _ = g.camera_in_link(spin)
        d64 = dirs @ R.T
        points = np.where(hit[:, None], origin + d64 * t[:, None], np.nan)
        out[finite] = points
        return out

    def moving_mask(self, frame: int) -> np.ndarray:
        """(H, W) bool: the pixels whose centre ray sees a spinning link first at frame number ``frame``."""
        region = self._static_layers()[4]
        ys, xs = np.nonzero(region)
        points = self.surface_points(frame, np.column_stack([xs, ys]).astype(float))
        mask = np.zeros_like(region)
        mask[ys, xs] = np.isfinite(points[:, 0])
        return mask

    def project_points(self, points_link, frames) -> tuple[np.ndarray, np.ndarray]:
        """Link-frame points (N, 3) at frame numbers (F,) -> raw pixels (F, N, 2) (distortion included) and
        ``visible`` (F, N): in the image, the ray from the camera meets the spinning links first at the point
        (within ``depth_tolerance``), no still surface is nearer, and the surface is not seen edge-on
        (|cos| > ``visibility_cos``)."""
        points = np.asarray(points_link, dtype=float).reshape(-1, 3)
        frames = np.atleast_1d(np.asarray(frames))
        spins = np.array([self._spin_of(f) for f in frames.tolist()])
        g = self._geometry
        cam = g.link_to_camera(spins, points)  # (F, N, 3)
        flat = cam.reshape(-1, 3)
        pixels = self.camera.project(flat).reshape(len(frames), len(points), 2)
        visible = np.zeros(len(flat), bool)
        finite = np.all(np.isfinite(flat), axis=1) & (flat[:, 2] > 0)
        finite &= self.camera.in_image(np.nan_to_num(pixels.reshape(-1, 2), nan=-1e9))
        tol = self.config.depth_tolerance
        for f in range(len(frames)):
            rows = np.flatnonzero(finite[f * len(points):(f + 1) * len(points)])
            if len(rows) == 0:
                continue
            p = cam[f, rows]
            distance = np.linalg.norm(p, axis=1)
            dirs = p / distance[:, None]
            t, face, dirs_link, _ = g.cast_moving(float(spins[f]), dirs)
            t_still, _, _ = g.cast_still(dirs)
            ok = (face >= 0) & (np.abs(t - distance) <= tol) & (t_still > distance - tol)
            cos = np.abs(np.einsum("ij,ij->i", g.moving.normals[np.maximum(face, 0)], dirs_link))
            ok &= cos > self.config.visibility_cos
            visible[f * len(points) + rows] = ok
        return pixels, visible.reshape(len(frames), len(points))


def _to_uint8(image: np.ndarray) -> np.ndarray:
    np.maximum(image, 0.0, out=image)
    return cv2.convertScaleAbs(image)


# --------------------------------------------------------------------------------------------- track errors
@dataclass(frozen=True, eq=False)
class TrackErrors:
    """Tracks against the ground truth of a :class:`MeshSpin` (T tracks).

    ``points`` (T, 3): each track's surface point in the link frame (NaN when not on the spinning links);
    ``on_links`` (T,): the track's first points see the spinning links; ``rms_px`` / ``median_px`` /
    ``n_compared`` (T,): per-track pixel error against the projection of its point, where visible (NaN when
    nothing is compared); ``pooled_rms_px`` / ``pooled_median_px`` over every compared point.
    """

    points: np.ndarray
    on_links: np.ndarray
    rms_px: np.ndarray
    median_px: np.ndarray
    n_compared: np.ndarray
    pooled_rms_px: float
    pooled_median_px: float
    #: the largest point error, and the RMS over tracks of each track's mean error vector (what does not average
    #: out along an arc)
    pooled_max_px: float = float("nan")
    bias_px: float = float("nan")
    #: per track (T,) and pooled: the RMS about the projections of the one link-frame point that fits the whole
    #: track best (least squares, where visible). ``rms_px`` locates the point from the first few pixels, so a
    #: track first seen at a grazing angle is charged for the truth's own location error, which grows as the
    #: surface turns to face the camera; this is what a calibration sees: how far a track is from a rigid point's
    #: circle
    rigid_rms_px: np.ndarray | None = None
    pooled_rigid_rms_px: float = float("nan")

    @property
    def off_links(self) -> np.ndarray:
        """Indices of the tracks that do not lie on the spinning links (background, still links)."""
        return np.flatnonzero(~self.on_links)


def track_errors(tracks, spin: MeshSpin, *, n_first: int = 5) -> TrackErrors:
    """Locate each track's surface point from its first ``n_first`` points (median of their back-projected
    link-frame points; a track is off the links when fewer than half of them see the spinning links), then
    compare the track with that point's projection in the track's frames, where it is visible."""
    if not isinstance(spin, MeshSpin):
        raise InputError(f"track_errors needs a MeshSpin, got {type(spin).__name__}")
    n = len(tracks)
    points = np.full((n, 3), np.nan)
    on_links = np.zeros(n, bool)
    rms, median, count = np.full(n, np.nan), np.full(n, np.nan), np.zeros(n, np.int64)
    pooled, biases = [], []
    rigid, pooled_rigid = np.full(n, np.nan), []
    for j, track in enumerate(tracks):
        pixels = np.asarray(track.pixels, dtype=float)
        if track.frames is None:
            raise InputError(f"track {j}: track_errors needs the frame numbers of its points (Track.frames)")
        frames = np.asarray(track.frames, dtype=np.int64)
        first = min(n_first, len(frames))
        located = np.array([spin.surface_points(int(f), p[None])[0] for f, p in zip(frames[:first], pixels[:first],
                                                                                      strict=True)])
        good = np.all(np.isfinite(located), axis=1)
        if good.sum() * 2 < first or not np.any(good):
            continue
        on_links[j] = True
        points[j] = np.median(located[good], axis=0)
        projected, visible = spin.project_points(points[j][None], frames)
        use = visible[:, 0]
        if not np.any(use):
            continue
        offsets = pixels[use] - projected[use, 0]
        error = np.linalg.norm(offsets, axis=1)
        rms[j], median[j], count[j] = np.sqrt(np.mean(error**2)), np.median(error), len(error)
        pooled.append(error)
        biases.append(offsets.mean(axis=0))
        residuals = _rigid_residuals(spin, points[j], frames[use], pixels[use])
        rigid[j] = np.sqrt(np.mean(np.sum(residuals**2, axis=1)))
        pooled_rigid.append(np.sum(residuals**2, axis=1))
    pooled_errors = np.concatenate(pooled) if pooled else np.zeros(0)
    some = len(pooled_errors) > 0
    return TrackErrors(points, on_links, rms, median, count,
                       float(np.sqrt(np.mean(pooled_errors**2))) if some else float("nan"),
                       float(np.median(pooled_errors)) if some else float("nan"),
                       float(pooled_errors.max()) if some else float("nan"),
                       float(np.sqrt(np.mean(np.sum(np.square(biases), axis=1)))) if biases else float("nan"),
                       rigid, float(np.sqrt(np.mean(np.concatenate(pooled_rigid)))) if pooled_rigid else float("nan"))


def _rigid_residuals(spin: MeshSpin, start: np.ndarray, frames: np.ndarray, pixels: np.ndarray,
                     iterations: int = 5, step: float = 1e-6) -> np.ndarray:
    """(n, 2) pixel residuals of a track about the projections of the link-frame point that fits it best
    (Gauss-Newton from ``start``, numerical Jacobian; visibility is not re-tested)."""
    spins = np.array([spin._spin_of(int(f)) for f in frames])
    g, camera = spin._geometry, spin.camera

    def residual(point):
        return (pixels - camera.project(g.link_to_camera(spins, point[None])[:, 0])).ravel()

    point = np.asarray(start, dtype=float)
    for _ in range(iterations):
        r = residual(point)
        J = np.column_stack([(residual(point + d) - r) / step for d in np.eye(3) * step])
        delta = np.linalg.lstsq(J, -r, rcond=None)[0]
        point = point + delta
        if np.linalg.norm(delta) < 1e-9:
            break
    return residual(point).reshape(-1, 2)


# --------------------------------------------------------------------------------------------- entry points
def render_mesh_measurement(dataset, truth, k: int, config: MeshRenderConfig | None = None, *, frames=None,
                            meshes: ArmMeshes | None = None, package_dirs=None, camera_moved=None) -> MeshSpin:
    """The mesh-rendered video of measurement ``k`` of a simulated scene (``dataset, truth = simulate...``).

    ``frames``: None (all of the spin's frames), a slice, or an array of frame numbers. ``meshes``: the arm's
    visual meshes (default :func:`load_arm_meshes`, with ``package_dirs`` for a URDF arm). ``camera_moved``: a
    ``gtsam.Pose3``, the camera's move for this video in its own frame (it sees from ``truth.arm_T_camera *
    camera_moved``), with the back wall, the floor and the still links where they were (the wall faces the
    camera of ``truth``): a camera that did not stay still between poses. Raises :class:`InputError` naming the
    measurement when the pose cannot be rendered (see :func:`pose_problem`).
    """
    config = MeshRenderConfig() if config is None else config
    if not isinstance(config, MeshRenderConfig):
        raise InputError(f"config must be a MeshRenderConfig, got {type(config).__name__}")
    k, mt, spin, selection, fps = scene_spin(dataset, truth, k, frames)
    meshes = load_arm_meshes(dataset.arm, package_dirs) if meshes is None else meshes
    if camera_moved is None:
        return MeshSpin(k, dataset.arm, dataset.camera, truth.arm_T_camera, mt.joint_angles, spin, selection,
                        config, fps, meshes, dataset[k].spin_joint)
    return MeshSpin(k, dataset.arm, dataset.camera, truth.arm_T_camera.compose(camera_moved), mt.joint_angles, spin,
                    selection, config, fps, meshes, dataset[k].spin_joint, wall_arm_T_camera=truth.arm_T_camera)


def render_mesh_scene(dataset, truth, config: MeshRenderConfig | None = None, *, frames=None,
                      meshes: ArmMeshes | None = None, package_dirs=None) -> list[MeshSpin]:
    """:func:`render_mesh_measurement` for every measurement of the scene (the same covering on each)."""
    _checked_scene(dataset, truth)
    meshes = load_arm_meshes(dataset.arm, package_dirs) if meshes is None else meshes
    return [render_mesh_measurement(dataset, truth, k, config, frames=frames, meshes=meshes)
            for k in range(len(dataset))]

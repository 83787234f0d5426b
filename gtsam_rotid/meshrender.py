"""Realistic synthetic video of a simulated scene: the robot's own meshes, ray cast on the CPU.

The model
---------
- **Scene.** The arm's visual meshes (the Pinocchio visual model: example-robot-data's .dae / .stl files, or
  a URDF's meshes found through ``package_dirs``), loaded with trimesh (pycollada for .dae), placed at the
  measurement's joint angles; a back wall perpendicular to the camera's optical axis at
  ``background_distance`` (a photograph, smooth noise or plain) and optionally a floor (the plane
  ``z = floor_height`` of the arm-base frame, a wood-like noise). The geometry whose parent joint is the wrist
  joint or one of its descendants (the hand, its fingers, the wrist ring) spins; everything else is still.
- **Spin.** In frame f the wrist joint is turned by ``spin_angles[f]``: the spinning links sit at
  ``arm_T_link(f) = arm_T_joint(q with q[wrist] + spin_f)`` (Pinocchio's wrist joint frame), so a point p
  fixed in the link frame is at ``camera_T_arm * arm_T_link(f) * p``.
- **Covering.** The spinning links carry a texture mapped in their own frame, so a surface point's colour
  (albedo) never changes as it spins: cylindrical about the wrist axis (angle about the axis, offset along it;
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
  link's frame (inverse rotation about the wrist axis) instead of moving the mesh, with the still scene's
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
import os
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, replace

import cv2
import numpy as np

from .arm import Arm
from .camera import Camera
from .errors import ArmError, InputError
from .geometry import perpendicular_basis, rotation_about_axis
from .render import _checked_scene, check_integers, scene_spin

__all__ = [
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

COVERINGS = ("photo", "text", "fabric", "stickers", "dots", "plain")
BACKGROUNDS = ("photo", "noise", "plain")
_TEXTURE_RADIUS = 0.04  # m: the cylindrical texture's circumference is 2 pi times this
_TEXTURE_HEIGHT = 0.25  # m along the axis before the texture repeats
_CAP_COS = 0.75  # faces with |normal . axis| above this get the planar (cap) mapping
_NOISE_PAD = 97
_NEAR = 0.01  # m: the spinning links must stay this far in front of the camera
_REMAP_COLS = 1024
_CHECK_ANGLES = 8


# --------------------------------------------------------------------------------------------- configuration
@dataclass(frozen=True)
class MeshRenderConfig:
    """Everything the mesh renderer draws besides the scene itself. Metres, colour levels 0-255 (RGB), pixels."""

    #: Texture of the spinning links: one of :data:`COVERINGS`.
    covering: str = "photo"
    #: Fraction of the circumference (about the wrist axis) that carries the texture; the rest is plain.
    covered_fraction: float = 1.0
    #: Plain plastic of the spinning links (RGB), under stickers and dots and where uncovered.
    hand_color: tuple = (140.0, 140.0, 140.0)
    #: Colour of the still links (RGB); None: the visual model's own colours.
    arm_color: tuple | None = None
    #: Texture size on the spinning links (mm per texel).
    texel_mm: float = 0.5
    #: Back wall: one of :data:`BACKGROUNDS`, at this depth (m, camera frame) perpendicular to the optical axis.
    background: str = "photo"
    background_distance: float = 2.5
    #: A floor at arm-base height ``floor_height`` (m) under the arm.
    floor: bool = True
    floor_height: float = 0.0
    #: Direction towards the light, arm-base frame; ambient, diffuse and specular weights; Blinn-Phong exponent.
    light_direction: tuple = (-0.3, 0.4, 1.0)
    ambient: float = 0.4
    diffuse: float = 0.6
    specular: float = 0.25
    shininess: float = 30.0
    #: Sub-samples per pixel along each image axis (anti-aliasing).
    supersample: int = 2
    #: Motion blur: the exposure as a fraction of the frame interval (0: none), averaged over blur_samples angles.
    exposure: float = 0.0
    blur_samples: int = 4
    #: Standard deviation of the Gaussian sensor noise (levels); 0 for none.
    noise_sigma: float = 2.0
    #: project_points: a point is visible when the first surface its ray meets lies within this depth of it (m)
    #: and |cos(normal, ray)| exceeds visibility_cos.
    depth_tolerance: float = 1e-3
    visibility_cos: float = 0.1
    #: Renderability (pose_problem): least fraction of the spinning links' vertices inside the image, and least
    #: fraction of their projected area not hidden by still links, both over the spin.
    min_in_image: float = 0.95
    min_visible_fraction: float = 0.5
    #: Seeds the textures, the background and the noise.
    seed: int = 0

    def __post_init__(self):
        if self.covering not in COVERINGS:
            raise InputError(f"MeshRenderConfig.covering must be one of {COVERINGS}, got {self.covering!r}")
        if self.background not in BACKGROUNDS:
            raise InputError(f"MeshRenderConfig.background must be one of {BACKGROUNDS}, got {self.background!r}")
        _check_color("hand_color", self.hand_color)
        if self.arm_color is not None:
            _check_color("arm_color", self.arm_color)
        for name, low, high, open_low in (("covered_fraction", 0.0, 1.0, True), ("ambient", 0.0, 2.0, False),
                                          ("diffuse", 0.0, 2.0, False), ("specular", 0.0, 2.0, False),
                                          ("exposure", 0.0, 1.0, False), ("min_in_image", 0.0, 1.0, False),
                                          ("min_visible_fraction", 0.0, 1.0, False),
                                          ("visibility_cos", -1.0, 1.0, False)):
            value = getattr(self, name)
            if (isinstance(value, bool) or not isinstance(value, (int, float, np.number)) or not np.isfinite(value)
                    or value < low or value > high or (open_low and value <= low)):
                interval = f"({low}, {high}]" if open_low else f"[{low}, {high}]"
                raise InputError(f"MeshRenderConfig.{name} must be a number in {interval}, got {value!r}")
        for name in ("texel_mm", "background_distance", "shininess", "depth_tolerance"):
            value = getattr(self, name)
            if (isinstance(value, bool) or not isinstance(value, (int, float, np.number)) or not np.isfinite(value)
                    or value <= 0):
                raise InputError(f"MeshRenderConfig.{name} must be a finite number > 0, got {value!r}")
        for name in ("noise_sigma", "floor_height"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, float, np.number)) or not np.isfinite(value):
                raise InputError(f"MeshRenderConfig.{name} must be a finite number, got {value!r}")
        if self.noise_sigma < 0:
            raise InputError(f"MeshRenderConfig.noise_sigma must be >= 0, got {self.noise_sigma!r}")
        if not isinstance(self.floor, (bool, np.bool_)):
            raise InputError(f"MeshRenderConfig.floor must be True or False, got {self.floor!r}")
        try:
            light = np.array(self.light_direction, dtype=float).reshape(3)
        except (TypeError, ValueError):
            raise InputError(f"MeshRenderConfig.light_direction must be a 3-vector, got "
                             f"{self.light_direction!r}") from None
        if not np.all(np.isfinite(light)) or np.linalg.norm(light) < 1e-9:
            raise InputError(f"MeshRenderConfig.light_direction must be a finite non-zero 3-vector, got "
                             f"{self.light_direction!r}")
        check_integers(self, (("supersample", 1, 8), ("blur_samples", 1, 64), ("seed", 0, None)))

    def with_(self, **changes) -> MeshRenderConfig:
        return replace(self, **changes)

    @property
    def blur_angles(self) -> int:
        """Spin angles rendered per frame: 1 without motion blur."""
        return 1 if self.exposure == 0 else int(self.blur_samples)


def _place_disc(rng, placed: list, radii, width: float, height: float, gap: float, tries: int) -> bool:
    """Append to ``placed`` one disc ``(cx, cy, radius)`` (radius uniform in ``radii``) inside the texture that keeps
    ``gap`` from every disc already placed, drawing at most ``tries`` candidates; False if none fits."""
    for _ in range(tries):
        radius = float(rng.uniform(*radii))
        cx, cy = float(rng.uniform(radius, width - radius)), float(rng.uniform(radius, height - radius))
        if all(np.hypot(cx - x, cy - y) > radius + r + gap for x, y, r in placed):
            placed.append((cx, cy, radius))
            return True
    return False


def _check_color(name: str, value) -> None:
    try:
        rgb = np.array(value, dtype=float).reshape(3)
    except (TypeError, ValueError):
        raise InputError(f"MeshRenderConfig.{name} must be an RGB triple in [0, 255], got {value!r}") from None
    if not np.all(np.isfinite(rgb)) or np.any(rgb < 0) or np.any(rgb > 255):
        raise InputError(f"MeshRenderConfig.{name} must be an RGB triple in [0, 255], got {value!r}")


def _bgr(rgb) -> np.ndarray:
    return np.array(rgb, dtype=np.float32).reshape(3)[::-1].copy()


# --------------------------------------------------------------------------------------------- meshes
@dataclass(frozen=True, eq=False)
class ArmMeshes:
    """The arm's visual meshes, one entry per geometry object of the Pinocchio visual model.

    ``vertices[i]`` (V, 3) are in the frame of the parent joint ``joint_ids[i]`` (mesh scale and the
    geometry's placement applied), ``faces[i]`` (T, 3) int, ``colors[i]`` RGB in [0, 1].
    """

    names: tuple[str, ...]
    joint_ids: tuple[int, ...]
    vertices: tuple[np.ndarray, ...]
    faces: tuple[np.ndarray, ...]
    colors: tuple[np.ndarray, ...]

    def __len__(self) -> int:
        return len(self.names)


def _load_mesh_file(path: str, name: str):
    import trimesh  # imported here: only the mesh renderer needs it

    if not path or not os.path.isfile(path):
        raise ArmError(f"visual geometry {name!r}: mesh file {path!r} not found; pass package_dirs so that the "
                       f"URDF's mesh paths resolve")
    try:
        mesh = trimesh.load(path, force="mesh", process=False)
    except Exception as exc:  # trimesh raises many kinds
        raise ArmError(f"visual geometry {name!r}: trimesh cannot load {path!r} ({exc})") from None
    if not hasattr(mesh, "faces") or len(mesh.faces) == 0:
        raise ArmError(f"visual geometry {name!r}: {path!r} holds no triangles")
    return np.asarray(mesh.vertices, dtype=float), np.asarray(mesh.faces, dtype=np.int64)


def _meshes_from_geometry_model(model, visual_model) -> ArmMeshes:
    import pinocchio as pin

    names, joints, vertices, faces, colors = [], [], [], [], []
    for g in visual_model.geometryObjects:
        path = getattr(g, "meshPath", "")
        if not path:
            raise ArmError(f"visual geometry {g.name!r} is not a mesh (primitive shapes are not supported)")
        v, f = _load_mesh_file(path, g.name)
        v = v * np.asarray(g.meshScale, dtype=float)
        placement: pin.SE3 = g.placement
        v = v @ np.asarray(placement.rotation).T + np.asarray(placement.translation)
        color = np.asarray(getattr(g, "meshColor", (0.5, 0.5, 0.5, 1.0)), dtype=float)[:3]
        if not np.all(np.isfinite(color)) or np.all(color == 0):
            color = np.array([0.5, 0.5, 0.5])
        names.append(g.name)
        joints.append(int(g.parentJoint))
        vertices.append(v)
        faces.append(f)
        colors.append(np.clip(color, 0.0, 1.0))
    if not names:
        raise ArmError("the arm's visual model holds no geometry")
    for array in (*vertices, *faces):
        array.setflags(write=False)
    return ArmMeshes(tuple(names), tuple(joints), tuple(vertices), tuple(faces), tuple(colors))


@functools.lru_cache(maxsize=8)
def _robot_meshes(name: str) -> ArmMeshes:
    import example_robot_data as erd

    try:
        robot = erd.load(name)
    except Exception as exc:
        raise ArmError(f"example-robot-data cannot load {name!r} ({exc})") from None
    return _meshes_from_geometry_model(robot.model, robot.visual_model)


def load_arm_meshes(arm: Arm, package_dirs: Sequence[str | os.PathLike] | None = None) -> ArmMeshes:
    """The visual meshes of ``arm``: example-robot-data's for a named robot (cached), else the URDF's,
    resolved through ``package_dirs`` (``package://`` paths). Raises :class:`ArmError` when a mesh is missing."""
    if not isinstance(arm, Arm):
        raise InputError(f"arm must be a gtsam_rotid Arm, got {type(arm).__name__}")
    source = arm.to_dict()
    if "robot" in source:
        meshes = _robot_meshes(source["robot"])
    elif "urdf_xml" in source:
        import pinocchio as pin

        dirs = [os.fspath(d) for d in (package_dirs or [])]
        try:
            visual = pin.buildGeomFromUrdfString(arm.model, source["urdf_xml"], pin.GeometryType.VISUAL,
                                                 package_dirs=dirs)
        except Exception as exc:
            raise ArmError(f"Pinocchio cannot read the URDF's visual meshes ({exc}); pass package_dirs so that "
                           f"its mesh paths resolve") from None
        meshes = _meshes_from_geometry_model(arm.model, visual)
    else:
        raise ArmError("the arm has neither an example-robot-data name nor URDF text to read its meshes from")
    if max(meshes.joint_ids) >= arm.model.njoints:
        raise ArmError("the visual model does not belong to the arm's kinematic model")
    return meshes


# --------------------------------------------------------------------------------------------- textures
def _sample_photo(name: str) -> np.ndarray:
    import matplotlib.cbook as cbook

    path = cbook.get_sample_data(name, asfileobj=False)
    image = cv2.imread(os.fspath(path), cv2.IMREAD_COLOR)
    if image is None:  # pragma: no cover - matplotlib ships these
        raise InputError(f"cannot read matplotlib's sample image {name!r} at {path}")
    return image.astype(np.float32)


def _smooth_noise(shape: tuple[int, int], scale: float, rng: np.random.Generator, octaves: int = 3) -> np.ndarray:
    """Zero-mean unit-std smooth noise (float32), octaves of cubic-upsampled Gaussian noise."""
    height, width = shape
    out = np.zeros((height, width), np.float32)
    for octave in range(octaves):
        s = max(scale / 3.0**octave, 1.0)
        coarse = rng.standard_normal((int(np.ceil(height / s)) + 3, int(np.ceil(width / s)) + 3)).astype(np.float32)
        out += np.float32(0.5**octave) * cv2.resize(coarse, (width, height), interpolation=cv2.INTER_CUBIC)
    out -= out.mean()
    out /= max(float(out.std()), 1e-6)
    return out


def _texture_shape(config: MeshRenderConfig) -> tuple[int, int]:
    texel = config.texel_mm / 1000.0
    return int(round(_TEXTURE_HEIGHT / texel)), int(round(2.0 * np.pi * _TEXTURE_RADIUS / texel))


def _fit(image: np.ndarray, height: int, width: int) -> np.ndarray:
    return cv2.resize(image, (width, height), interpolation=cv2.INTER_AREA)


@functools.lru_cache(maxsize=16)
def _hand_texture(covering: str, hand_color: tuple, texel_mm: float, seed: int) -> np.ndarray:
    """The spinning links' texture, BGR float32 (H, W, 3); W spans the circumference at _TEXTURE_RADIUS."""
    config = MeshRenderConfig(covering=covering, hand_color=hand_color, texel_mm=texel_mm, seed=seed)
    height, width = _texture_shape(config)
    per_mm = 1.0 / texel_mm
    rng = np.random.default_rng([seed, 10, COVERINGS.index(covering)])
    base = _bgr(hand_color)
    texture = np.empty((height, width, 3), np.float32)
    texture[:] = base
    if covering == "photo":
        grace = _sample_photo("grace_hopper.jpg")
        present = _sample_photo("Minduka_Present_Blue_Pack.png")
        logo = _sample_photo("logo2.png")
        w_grace = int(round(height * grace.shape[1] / grace.shape[0]))
        column = max(width - w_grace, 8)
        rows = [_fit(present, height // 2, column), _fit(logo, height - height // 2, column)]
        strip = np.hstack([_fit(grace, height, w_grace), np.vstack(rows)])
        texture = _fit(strip, height, width) if strip.shape[1] != width else strip
    elif covering == "text":
        label = np.full((height, width, 3), (222.0, 232.0, 238.0), np.float32)  # BGR of a cream label
        words = ("GTSAM", "ROTID", "CALIBRATION", "LOT", "WRIST", "HAND", "EYE", "AXIS", "SERIAL", "KINOVA",
                 "OBSERVE", "SPIN", "MADE IN", "REV", "CE", "WARNING", "PINCH POINT", "MAX", "LOAD", "2.6 kg")
        inks = ((20, 20, 20), (110, 40, 10), (30, 30, 160), (60, 60, 60))
        y = int(6 * per_mm)
        while y < height - 2:
            scale = float(rng.uniform(0.35, 0.9)) * per_mm / 2.0
            thickness = 1 if scale < 0.6 else 2
            ink = inks[int(rng.integers(len(inks)))]
            line = " ".join(str(rng.choice(words)) if rng.uniform() < 0.7 else str(int(rng.integers(10, 99999)))
                            for _ in range(12))
            x = int(rng.integers(-width // 3, 0))
            cv2.putText(label, line, (x, y), cv2.FONT_HERSHEY_SIMPLEX, scale, ink, thickness, cv2.LINE_AA)
            y += int(round(scale * 30.0 + rng.uniform(2, 6) * per_mm))
        texture = label
    elif covering == "fabric":
        yy, xx = np.mgrid[0:height, 0:width].astype(np.float32)
        period = 3.0 * per_mm  # 3 mm threads
        warp = 0.5 + 0.5 * np.cos(2 * np.pi * xx / period)
        weft = 0.5 + 0.5 * np.cos(2 * np.pi * yy / period)
        twill = ((np.floor(xx / period) + np.floor(yy / period)) % 4 < 2).astype(np.float32)
        twill = cv2.GaussianBlur(twill, (0, 0), 0.3 * period)
        weave = twill * warp + (1 - twill) * weft
        fibre = cv2.GaussianBlur(rng.standard_normal((height, width)).astype(np.float32), (0, 0), 0.7)
        blotch = _smooth_noise((height, width), 12.0 * per_mm, rng, octaves=3)
        shade = 0.5 + 0.35 * weave + 0.10 * fibre / max(float(fibre.std()), 1e-6) + 0.12 * blotch
        denim = np.array([120.0, 72.0, 40.0], np.float32)  # BGR
        texture = np.clip(shade[..., None] * denim * 1.6, 0, 255).astype(np.float32)
    elif covering == "stickers":
        palette = ((40, 40, 220), (30, 200, 240), (60, 180, 40), (200, 110, 20), (30, 130, 250), (180, 40, 190),
                   (240, 240, 240), (20, 20, 20))
        placed: list[tuple[float, float, float]] = []
        for n in range(10):
            if not _place_disc(rng, placed, (5.0 * per_mm, 12.0 * per_mm), width, height, 3 * per_mm, 200):
                continue
            cx, cy, size = placed[-1]
            color = tuple(float(c) for c in palette[n % len(palette)])
            shape = n % 3
            centre = np.array([cx, cy])
            if shape == 0:
                cv2.circle(texture, (int(cx * 16), int(cy * 16)), int(size * 16), (245, 245, 245), -1, cv2.LINE_AA,
                           4)
                cv2.circle(texture, (int(cx * 16), int(cy * 16)), int(size * 0.85 * 16), color, -1, cv2.LINE_AA, 4)
            else:
                k = 4 if shape == 1 else 3
                angle = float(rng.uniform(0, 2 * np.pi))
                beta = angle + 2 * np.pi * np.arange(k) / k
                corners = centre + size * np.column_stack([np.cos(beta), np.sin(beta)])
                inner = centre + 0.8 * size * np.column_stack([np.cos(beta), np.sin(beta)])
                cv2.fillPoly(texture, [np.round(corners * 16).astype(np.int32)], (245, 245, 245), cv2.LINE_AA, 4)
                cv2.fillPoly(texture, [np.round(inner * 16).astype(np.int32)], color, cv2.LINE_AA, 4)
    elif covering == "dots":
        grey = float(np.mean(hand_color))
        placed = []
        for _ in range(60):
            _place_disc(rng, placed, (4.0 * per_mm, 9.0 * per_mm), width, height, 3 * per_mm, 300)
        for cx, cy, radius in placed:
            contrast = float(rng.uniform(50.0, 100.0)) * (1.0 if rng.uniform() < 0.5 else -1.0)
            level = float(np.clip(grey + contrast, 0, 255))
            cv2.circle(texture, (int(round(cx * 16)), int(round(cy * 16))), int(round(radius * 16)),
                       (level, level, level), -1, cv2.LINE_AA, 4)
    texture = cv2.GaussianBlur(np.ascontiguousarray(texture, dtype=np.float32), (0, 0), 0.5)  # against aliasing
    texture.setflags(write=False)
    return texture


@functools.lru_cache(maxsize=8)
def _wall_texture(kind: str, seed: int) -> tuple[np.ndarray, float]:
    """(BGR float32 texture, metres per texel) of the back wall."""
    rng = np.random.default_rng([seed, 11])
    if kind == "photo":
        grace = _sample_photo("grace_hopper.jpg")
        present = _fit(_sample_photo("Minduka_Present_Blue_Pack.png"), 300, 300)
        logo = _fit(_sample_photo("logo2.png"), 150, 626)
        right = np.vstack([present, np.full((150, 300, 3), 200, np.float32), _fit(logo, 150, 300)])
        poster = np.hstack([grace, _fit(right, 600, 300)])
        wall = np.full((900, 1200, 3), 0, np.float32)
        tint = _smooth_noise((900, 1200), 120.0, rng)
        wall[:] = (150.0 + 25.0 * tint)[..., None] * np.array([0.85, 0.95, 1.0], np.float32)
        wall[150:750, 200:1012] = poster
        texture, per_texel = wall, 0.0035
    elif kind == "noise":
        noise = _smooth_noise((600, 800), 40.0, rng)
        colour = np.stack([_smooth_noise((600, 800), 150.0, rng) for _ in range(3)], axis=-1)
        texture = np.clip(125.0 + 45.0 * noise[..., None] + 20.0 * colour, 5, 250).astype(np.float32)
        per_texel = 0.004
    else:
        texture, per_texel = np.full((4, 4, 3), 150.0, np.float32), 1.0
    texture.setflags(write=False)
    return texture, per_texel


@functools.lru_cache(maxsize=4)
def _floor_texture(seed: int) -> np.ndarray:
    """A wood-like table top, BGR float32, 2 mm per texel."""
    rng = np.random.default_rng([seed, 12])
    height, width = 512, 512
    yy, xx = np.mgrid[0:height, 0:width].astype(np.float32)
    warp = _smooth_noise((height, width), 60.0, rng)
    grain = 0.5 + 0.5 * np.sin(2 * np.pi * (yy + 12.0 * warp) / 9.0)
    fine = _smooth_noise((height, width), 3.0, rng, octaves=1)
    shade = 0.75 + 0.15 * grain + 0.05 * fine
    wood = np.array([70.0, 120.0, 170.0], np.float32)  # BGR
    texture = np.clip(shade[..., None] * wood, 0, 255).astype(np.float32)
    texture.setflags(write=False)
    return texture


def _sample(texture: np.ndarray, tx: np.ndarray, ty: np.ndarray, border=cv2.BORDER_WRAP) -> np.ndarray:
    """Bilinear texture look-up at texel coordinates (texel centres at integers) -> (N, 3) float32."""
    n = len(tx)
    if n == 0:
        return np.zeros((0, 3), np.float32)
    height, width = texture.shape[:2]
    if border == cv2.BORDER_WRAP:
        tx, ty = np.mod(tx, width), np.mod(ty, height)
    rows = -(-n // _REMAP_COLS)
    mx = np.zeros(rows * _REMAP_COLS, np.float32)
    my = np.zeros(rows * _REMAP_COLS, np.float32)
    mx[:n], my[:n] = tx, ty
    out = cv2.remap(texture, mx.reshape(rows, _REMAP_COLS), my.reshape(rows, _REMAP_COLS), cv2.INTER_LINEAR,
                    borderMode=border)
    return out.reshape(-1, 3)[:n]


# --------------------------------------------------------------------------------------------- ray casting
class _Caster:
    """One Embree scene of triangles (float32 vertices), with per-face unit normals and owners."""

    def __init__(self, vertices: list[np.ndarray], faces: list[np.ndarray], owners: list[int]):
        from embreex import mesh_construction, rtcore_scene

        offsets = np.cumsum([0] + [len(v) for v in vertices])
        self.vertices = np.vstack(vertices).astype(np.float64)
        self.faces = np.vstack([f + o for f, o in zip(faces, offsets[:-1], strict=True)]).astype(np.int32)
        self.owner = np.concatenate([np.full(len(f), o, np.int32) for f, o in zip(faces, owners, strict=True)])
        a, b, c = (self.vertices[self.faces[:, i]] for i in range(3))
        normal = np.cross(b - a, c - a)
        norm = np.linalg.norm(normal, axis=1, keepdims=True)
        self.normals = np.where(norm > 0, normal / np.maximum(norm, 1e-300), 0.0).astype(np.float32)
        self._scene = rtcore_scene.EmbreeScene()
        self._mesh = mesh_construction.TriangleMesh(scene=self._scene, vertices=self.vertices.astype(np.float32),
                                                    indices=self.faces)

    def cast(self, origin: np.ndarray, directions: np.ndarray, far: np.ndarray | None = None):
        """First hits of rays from one ``origin`` along unit ``directions`` (N, 3): (t, face); t = inf and
        face = -1 where nothing is hit (before ``far``, when given)."""
        n = len(directions)
        if n == 0:
            return np.zeros(0), np.zeros(0, np.int64)
        origins = np.empty((n, 3), np.float32)
        origins[:] = np.asarray(origin, dtype=np.float32)
        dirs = np.ascontiguousarray(directions, dtype=np.float32)
        if far is None:
            result = self._scene.run(origins, dirs, output=1)
        else:
            limit = np.ascontiguousarray(np.minimum(far, 1e30), dtype=np.float32)
            result = self._scene.run(origins, dirs, dists=limit, output=1)
        face = result["primID"].astype(np.int64)
        hit = result["geomID"] >= 0
        face[~hit] = -1
        t = np.where(hit, result["tfar"].astype(np.float64), np.inf)
        return t, face


def _cell_corners(points: np.ndarray, cell: float) -> np.ndarray:
    """Corners (float32) of the ``cell``-sized grid cubes that hold ``points``: a few hundred points whose
    convex hull contains every point (conservative bounds at a fraction of the cost of all vertices)."""
    index = np.unique(np.floor(points / cell).astype(np.int64), axis=0)
    offsets = np.array([[i, j, k] for i in (0, 1) for j in (0, 1) for k in (0, 1)])
    corners = np.unique((index[:, None, :] + offsets[None]).reshape(-1, 3), axis=0)
    return (corners * cell).astype(np.float32)


def _shade(albedo: np.ndarray, normal: np.ndarray, view: np.ndarray, light: np.ndarray,
           config: MeshRenderConfig) -> np.ndarray:
    """Ambient + Lambert + Blinn-Phong of (N, 3) BGR albedos; ``view`` runs from the camera to the surface."""
    cos_view = np.einsum("ij,ij->i", normal, view)
    normal = np.where((cos_view > 0)[:, None], -normal, normal)
    ndl = normal @ light
    half = light[None, :] - view
    half /= np.maximum(np.linalg.norm(half, axis=1, keepdims=True), 1e-9)
    ndh = np.maximum(np.einsum("ij,ij->i", normal, half), 0.0)
    lit = ndl > 0
    diffuse = np.float32(config.ambient) + np.float32(config.diffuse) * np.maximum(ndl, 0.0)
    highlight = np.where(lit, np.float32(config.specular * 255.0) * ndh ** np.float32(config.shininess), 0.0)
    return (albedo * diffuse[:, None] + highlight[:, None]).astype(np.float32)


class _Geometry:
    """One measurement's scene: the still part in the camera frame, the spinning part in the link frame."""

    def __init__(self, arm: Arm, meshes: ArmMeshes, camera: Camera, arm_T_camera, joint_angles,
                 config: MeshRenderConfig):
        self.camera = camera
        self.config = config
        q = arm.joint_angle_vector(joint_angles)
        self.joint_angles = q
        model = arm.model
        wrist = model.getJointId(arm.wrist_joint)
        moving_joints = set()
        for jid in range(model.njoints):
            j = jid
            while j > 0 and j != wrist:
                j = model.parents[j]
            if j == wrist:
                moving_joints.add(jid)
        camera_T_arm = arm_T_camera.inverse()
        self.cam_R_arm = camera_T_arm.rotation().matrix()
        self.cam_t_arm = camera_T_arm.translation()
        arm_T_link = arm.arm_T_joint(q)
        self.arm_R_link = arm_T_link.rotation().matrix()
        self.arm_t_link = arm_T_link.translation()
        link_T_camera = arm_T_link.inverse() * arm_T_camera
        self.link_R_cam = link_T_camera.rotation().matrix()  # at spin 0
        self.link_t_cam = link_T_camera.translation()  # camera centre in the link frame at spin 0
        self.axis = arm.wrist_axis_local()
        self.e1, self.e2 = perpendicular_basis(self.axis)
        placements = {}
        for jid in set(meshes.joint_ids):
            placements[jid] = arm.arm_T_joint(q, model.names[jid])
        still_v, still_f, still_o, move_v, move_f, move_o = [], [], [], [], [], []
        self.still_boxes, self.moving_names = [], []
        for i, (jid, v, f) in enumerate(zip(meshes.joint_ids, meshes.vertices, meshes.faces, strict=True)):
            pose = placements[jid]
            R, t = pose.rotation().matrix(), pose.translation()
            arm_v = v @ R.T + t
            if jid in moving_joints:
                move_v.append((arm_v - self.arm_t_link) @ self.arm_R_link)
                move_f.append(f)
                move_o.append(i)
                self.moving_names.append(meshes.names[i])
            else:
                still_v.append(arm_v @ self.cam_R_arm.T + self.cam_t_arm)
                still_f.append(f)
                still_o.append(i)
                centre_local = (np.asarray(arm_T_camera.translation()) - t) @ R
                self.still_boxes.append((meshes.names[i], v.min(axis=0), v.max(axis=0), centre_local))
        if not move_v:
            raise ArmError(f"no visual geometry is attached to the wrist joint {arm.wrist_joint!r} or after it")
        self.moving = _Caster(move_v, move_f, move_o)
        self.still = _Caster(still_v, still_f, still_o) if still_v else None
        arm_color = None if config.arm_color is None else _bgr(config.arm_color)
        self.still_albedo = np.array([arm_color if arm_color is not None else _bgr(c * 255.0)
                                      for c in meshes.colors], np.float32)
        mv = self.moving.vertices
        axial = mv @ self.axis
        self.axial_range = (float(axial.min()), float(axial.max()))
        self.max_radius = float(np.max(np.linalg.norm(mv - np.outer(axial, self.axis), axis=1)))
        self.hull_points = _cell_corners(mv, 0.01)  # their hull holds every vertex: bounds a frame's projection
        cap = np.abs(self.moving.normals @ self.axis.astype(np.float32)) > _CAP_COS
        self.cap_face = cap
        self.light_arm = (np.asarray(config.light_direction, float) / np.linalg.norm(config.light_direction))
        self.light_cam = (self.cam_R_arm @ self.light_arm).astype(np.float32)

    # ------------------------------------------------------------------ frames of the spinning link
    def link_rotation(self, spin: float) -> np.ndarray:
        """R(spin) about the local wrist axis: link(spin) = link(0) * R(spin)."""
        return rotation_about_axis(self.axis, [spin])[0]

    def camera_in_link(self, spin: float) -> tuple[np.ndarray, np.ndarray]:
        """(link_R_camera, camera centre in the link frame) at a spin angle."""
        Rt = self.link_rotation(spin).T
        return Rt @ self.link_R_cam, Rt @ self.link_t_cam

    def link_to_camera(self, spins: np.ndarray, points: np.ndarray) -> np.ndarray:
        """Link-frame points (N, 3) at spin angles (F,) -> camera-frame points (F, N, 3)."""
        rotations = rotation_about_axis(self.axis, spins)  # (F, 3, 3)
        rotated = np.einsum("fij,nj->fni", rotations, points) - self.link_t_cam
        return rotated @ self.link_R_cam  # link_R_cam^T applied on the left

    # ------------------------------------------------------------------ casting
    def cast_still(self, dirs_cam: np.ndarray):
        """Still scene along camera-frame unit rays: (t, kind, face): kind 0 mesh, 1 floor, 2 wall."""
        n = len(dirs_cam)
        if self.still is not None:
            t, face = self.still.cast(np.zeros(3), dirs_cam)
        else:
            t, face = np.full(n, np.inf), np.full(n, -1, np.int64)
        kind = np.zeros(n, np.int8)
        with np.errstate(divide="ignore", invalid="ignore"):
            t_wall = np.where(dirs_cam[:, 2] > 1e-9, self.config.background_distance / dirs_cam[:, 2], np.inf)
            t_floor = np.full(n, np.inf)
            if self.config.floor:
                dirs_arm_z = dirs_cam @ self.cam_R_arm[:, 2]  # z component in the arm frame
                centre_z = float((-self.cam_R_arm.T @ self.cam_t_arm)[2])
                t_floor = np.where(np.abs(dirs_arm_z) > 1e-12, (self.config.floor_height - centre_z) / dirs_arm_z,
                                   np.inf)
                t_floor = np.where(t_floor > 0, t_floor, np.inf)
        floor = (t_floor < t) & (t_floor <= t_wall)
        wall = (t_wall < t) & (t_wall < t_floor)
        t = np.where(floor, t_floor, np.where(wall, t_wall, t))
        kind[floor] = 1
        kind[wall] = 2
        face[floor | wall] = -1
        return t, kind, face

    def cast_moving(self, spin: float, dirs_cam: np.ndarray, far: np.ndarray | None = None):
        """Spinning links along camera-frame unit rays at a spin angle: (t, face, link-frame directions, origin)."""
        R, origin = self.camera_in_link(spin)
        dirs = (dirs_cam @ R.T).astype(np.float32)
        t, face = self.moving.cast(origin, dirs, far)
        return t, face, dirs, origin

    # ------------------------------------------------------------------ colours
    def still_colors(self, dirs_cam: np.ndarray, t: np.ndarray, kind: np.ndarray, face: np.ndarray) -> np.ndarray:
        cfg = self.config
        out = np.zeros((len(dirs_cam), 3), np.float32)
        mesh = face >= 0
        if np.any(mesh):
            albedo = self.still_albedo[self.still.owner[face[mesh]]]
            out[mesh] = _shade(albedo, self.still.normals[face[mesh]], dirs_cam[mesh].astype(np.float32),
                               self.light_cam, cfg)
        floor = kind == 1
        if np.any(floor):
            points_cam = dirs_cam[floor] * t[floor, None]
            points_arm = (points_cam - self.cam_t_arm) @ self.cam_R_arm
            albedo = _sample(_floor_texture(cfg.seed), points_arm[:, 0] / 0.002, points_arm[:, 1] / 0.002)
            lit = np.float32(cfg.ambient + cfg.diffuse * max(float(self.light_arm[2]), 0.0))
            out[floor] = albedo * lit
        wall = kind == 2
        if np.any(wall):
            texture, per_texel = _wall_texture(cfg.background, cfg.seed)
            height, width = texture.shape[:2]
            points = dirs_cam[wall] * t[wall, None]
            albedo = _sample(texture, points[:, 0] / per_texel + (width - 1) / 2.0,
                             points[:, 1] / per_texel + (height - 1) / 2.0, border=cv2.BORDER_REFLECT_101)
            out[wall] = albedo * np.float32(cfg.ambient + 0.7 * cfg.diffuse)
        return out

    def texture_coordinates(self, points_link: np.ndarray, faces: np.ndarray):
        """Texel coordinates and the covered flag of link-frame surface points on the given faces."""
        axial = points_link @ self.axis
        x1, x2 = points_link @ self.e1, points_link @ self.e2
        phi = np.arctan2(x2, x1)
        height, width = _texture_shape(self.config)
        texel = self.config.texel_mm / 1000.0
        cap = self.cap_face[faces]
        tx = np.where(cap, x1 / texel, (phi + np.pi) / (2 * np.pi) * width - 0.5)
        ty = np.where(cap, x2 / texel, (self.axial_range[1] - axial) / texel)  # rows run against the axis
        covered = np.mod(phi + np.pi, 2 * np.pi) < 2 * np.pi * self.config.covered_fraction
        return tx, ty, covered

    def moving_colors(self, points_link: np.ndarray, faces: np.ndarray, dirs_link: np.ndarray,
                      light_link: np.ndarray) -> np.ndarray:
        cfg = self.config
        n = len(faces)
        albedo = np.empty((n, 3), np.float32)
        albedo[:] = _bgr(cfg.hand_color)
        if cfg.covering != "plain" and n:
            tx, ty, covered = self.texture_coordinates(points_link, faces)
            if np.any(covered):
                texture = _hand_texture(cfg.covering, tuple(float(c) for c in cfg.hand_color), float(cfg.texel_mm),
                                        int(cfg.seed))
                albedo[covered] = _sample(texture, tx[covered], ty[covered])
        return _shade(albedo, self.moving.normals[faces], dirs_link, light_link, cfg)

    def light_in_link(self, spin: float) -> np.ndarray:
        return (self.link_rotation(spin).T @ (self.arm_R_link.T @ self.light_arm)).astype(np.float32)


# --------------------------------------------------------------------------------------------- renderability
def _renderability(geometry: _Geometry) -> str | None:
    """Why the scene cannot be rendered, or None."""
    cfg, camera = geometry.config, geometry.camera
    for name, low, high, centre in geometry.still_boxes:
        if np.all(centre > low) and np.all(centre < high):
            return f"the camera is inside the bounding box of the still mesh {name!r}"
    centre = geometry.link_t_cam
    axial = float(centre @ geometry.axis)
    radial = float(np.linalg.norm(centre - axial * geometry.axis))
    lo, hi = geometry.axial_range
    if lo <= axial <= hi and radial <= geometry.max_radius:
        return "the camera is inside the volume the spinning links sweep"
    swept = _swept_points(geometry)
    depth = swept @ geometry.link_R_cam[:, 2] - geometry.link_t_cam @ geometry.link_R_cam[:, 2]
    if np.min(depth) <= _NEAR:
        return (f"the spinning links reach behind the camera (or within {_NEAR * 100:g} cm of it): least depth "
                f"{np.min(depth):.3f} m")
    spins = np.linspace(0.0, 2.0 * np.pi, _CHECK_ANGLES, endpoint=False)
    points = geometry.hull_points.astype(float)
    step = max(1, len(points) // 4000)
    cam = geometry.link_to_camera(spins, points[::step]).reshape(-1, 3)
    inside = camera.in_image(camera.project(cam))
    if inside.mean() < cfg.min_in_image:
        return (f"only {inside.mean():.0%} of the spinning links' projected vertices lie inside the image over the "
                f"spin (min_in_image {cfg.min_in_image:.0%})")
    # occlusion by the still links: a coarse grid of the swept region
    pixels = _region_pixels(geometry, step=3)
    if len(pixels) == 0:
        return "the spinning links do not appear in the image"
    dirs = camera.rays(pixels)
    t_still, _, _ = geometry.cast_still(dirs)
    seen, drawn = 0, 0
    for spin in spins:
        t, face, _, _ = geometry.cast_moving(float(spin), dirs)
        hit = face >= 0
        drawn += int(hit.sum())
        seen += int((hit & (t < t_still)).sum())
    if drawn == 0:
        return "the spinning links do not appear in the image"
    if seen / drawn < cfg.min_visible_fraction:
        return (f"the still links hide {1 - seen / drawn:.0%} of the spinning links over the spin "
                f"(min_visible_fraction {cfg.min_visible_fraction:.0%})")
    return None


def _swept_points(geometry: _Geometry, samples: int = 128) -> np.ndarray:
    """Points (link frame) whose convex hull contains the solid the spinning links sweep about the wrist axis."""
    phi = np.linspace(0.0, 2.0 * np.pi, samples, endpoint=False)
    radius = geometry.max_radius / np.cos(np.pi / samples) * 1.001 + 1e-4
    ring = radius * (np.cos(phi)[:, None] * geometry.e1 + np.sin(phi)[:, None] * geometry.e2)
    lo, hi = geometry.axial_range
    return np.vstack([ring + (lo - 1e-4) * geometry.axis, ring + (hi + 1e-4) * geometry.axis])


def _swept_polygon(geometry: _Geometry) -> np.ndarray:
    """Convex polygon (undistorted normalised image coordinates) containing the swept solid's projection."""
    swept = _swept_points(geometry)
    cam = (swept - geometry.link_t_cam) @ geometry.link_R_cam
    xy = (cam[:, :2] / cam[:, 2:3]).astype(np.float32)
    return cv2.convexHull(xy.reshape(-1, 1, 2)).reshape(-1, 2).astype(float)


def _inside_convex(polygon: np.ndarray, xy: np.ndarray) -> np.ndarray:
    """Points (N, 2) inside (or on) a convex polygon (V, 2), either orientation."""
    edges = np.roll(polygon, -1, axis=0) - polygon
    area = np.sum(polygon[:, 0] * np.roll(polygon[:, 1], -1) - np.roll(polygon[:, 0], -1) * polygon[:, 1])
    sign = 1.0 if area >= 0 else -1.0
    (x0, y0), (x1, y1) = polygon.min(axis=0), polygon.max(axis=0)
    rows = np.flatnonzero((xy[:, 0] >= x0) & (xy[:, 0] <= x1) & (xy[:, 1] >= y0) & (xy[:, 1] <= y1))
    x, y = xy[rows, 0], xy[rows, 1]
    keep = np.ones(len(rows), bool)
    for p, e in zip(polygon, edges, strict=True):
        keep &= sign * (e[0] * (y - p[1]) - e[1] * (x - p[0])) >= -1e-12
    inside = np.zeros(len(xy), bool)
    inside[rows[keep]] = True
    return inside


def _region_pixels(geometry: _Geometry, step: int = 1) -> np.ndarray:
    """Pixel centres (every ``step``-th) whose rays fall inside the swept polygon."""
    camera = geometry.camera
    ys, xs = np.mgrid[0:camera.height:step, 0:camera.width:step]
    pixels = np.column_stack([xs.ravel(), ys.ravel()]).astype(float)
    xy = camera.normalize(pixels)
    return pixels[_inside_convex(_swept_polygon(geometry), xy)]


def pose_problem(arm: Arm, camera: Camera, arm_T_camera, joint_angles, config: MeshRenderConfig | None = None, *,
                 meshes: ArmMeshes | None = None, package_dirs=None) -> str | None:
    """Why the mesh renderer cannot render the arm at ``joint_angles`` seen from ``arm_T_camera``, or None
    when it can: the camera inside a mesh's bounding box or inside the hand's swept volume, the spinning
    links behind the camera, less than ``min_in_image`` of their projected vertices inside the image, or more
    than 1 - ``min_visible_fraction`` of their projected area hidden by still links (8 spin angles)."""
    config = MeshRenderConfig() if config is None else config
    meshes = load_arm_meshes(arm, package_dirs) if meshes is None else meshes
    return _renderability(_Geometry(arm, meshes, camera, arm_T_camera, joint_angles, config))


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
                 frame_indices, config: MeshRenderConfig, fps: float | None, meshes: ArmMeshes):
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
        self._geometry = _Geometry(arm, meshes, camera, arm_T_camera, joint_angles, config)
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
        """Pose (gtsam.Pose3) of the spinning link frame (the wrist joint frame) at a frame number."""
        q = self._geometry.joint_angles.copy()
        q[self.arm.wrist_index] += self._spin_of(frame)
        return self.arm.arm_T_joint(q)

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
    pooled_errors = np.concatenate(pooled) if pooled else np.zeros(0)
    some = len(pooled_errors) > 0
    return TrackErrors(points, on_links, rms, median, count,
                       float(np.sqrt(np.mean(pooled_errors**2))) if some else float("nan"),
                       float(np.median(pooled_errors)) if some else float("nan"),
                       float(pooled_errors.max()) if some else float("nan"),
                       float(np.sqrt(np.mean(np.sum(np.square(biases), axis=1)))) if biases else float("nan"))


# --------------------------------------------------------------------------------------------- entry points
def render_mesh_measurement(dataset, truth, k: int, config: MeshRenderConfig | None = None, *, frames=None,
                            meshes: ArmMeshes | None = None, package_dirs=None) -> MeshSpin:
    """The mesh-rendered video of measurement ``k`` of a simulated scene (``dataset, truth = simulate...``).

    ``frames``: None (all of the spin's frames), a slice, or an array of frame numbers. ``meshes``: the arm's
    visual meshes (default :func:`load_arm_meshes`, with ``package_dirs`` for a URDF arm). Raises
    :class:`InputError` naming the measurement when the pose cannot be rendered (see :func:`pose_problem`).
    """
    config = MeshRenderConfig() if config is None else config
    if not isinstance(config, MeshRenderConfig):
        raise InputError(f"config must be a MeshRenderConfig, got {type(config).__name__}")
    k, mt, spin, selection, fps = scene_spin(dataset, truth, k, frames)
    meshes = load_arm_meshes(dataset.arm, package_dirs) if meshes is None else meshes
    return MeshSpin(k, dataset.arm, dataset.camera, truth.arm_T_camera, mt.joint_angles, spin, selection, config,
                    fps, meshes)


def render_mesh_scene(dataset, truth, config: MeshRenderConfig | None = None, *, frames=None,
                      meshes: ArmMeshes | None = None, package_dirs=None) -> list[MeshSpin]:
    """:func:`render_mesh_measurement` for every measurement of the scene (the same covering on each)."""
    _checked_scene(dataset, truth)
    meshes = load_arm_meshes(dataset.arm, package_dirs) if meshes is None else meshes
    return [render_mesh_measurement(dataset, truth, k, config, frames=frames, meshes=meshes)
            for k in range(len(dataset))]

"""What the mesh renderer draws besides the scene (:class:`MeshRenderConfig`: the covering, the background, the
light, anti-aliasing, blur, noise), validated.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from .errors import InputError
from .renderconfig import check_integers

COVERINGS = ("photo", "text", "fabric", "stickers", "dots", "plain")
BACKGROUNDS = ("photo", "noise", "plain")


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

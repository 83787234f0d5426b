"""A synthetic test pattern for trackers: discs moving along image ellipses over a smooth texture.

Exact disc centres are known per frame (``render_dots`` returns them), so a tracker can be scored against a
truth it never sees. Used by the tracker tests and ``benchmarks/tracking.py``; :mod:`gtsam_rotid.render` draws
the physically modelled end effector instead.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import cv2
import numpy as np

__all__ = ["Dot", "render_dots", "smooth_texture", "spin_dots"]


@dataclass
class Dot:
    """A disc of radius ``radius`` and grey level ``level`` moving along an ellipse.

    Position at frame f: centre + R(tilt) (a cos θ, b sin θ), θ = phase + speed f. Hidden while
    sin(θ - hide_at) > hide_sin (the far side of the wrist), never when hide_sin >= 1.
    ``jumps``: {frame: (du, dv)} offsets added from that frame on (a planted teleport).
    """

    centre: tuple[float, float]
    axes: tuple[float, float]
    radius: float
    level: float
    speed: float = 0.03
    phase: float = 0.0
    tilt: float = 0.0
    hide_at: float = 0.0
    hide_sin: float = 1.0
    jumps: dict = field(default_factory=dict)

    def positions(self, n_frames: int) -> tuple[np.ndarray, np.ndarray]:
        f = np.arange(n_frames)
        theta = self.phase + self.speed * f
        local = np.stack([self.axes[0] * np.cos(theta), self.axes[1] * np.sin(theta)], axis=1)
        c, s = np.cos(self.tilt), np.sin(self.tilt)
        uv = np.asarray(self.centre) + local @ np.array([[c, s], [-s, c]])
        for start, offset in self.jumps.items():
            uv[start:] += offset
        visible = np.sin(theta - self.hide_at) <= self.hide_sin
        return uv, visible


def smooth_texture(width: int, height: int, rng, low: float = 70.0, high: float = 180.0, sigma: float = 9.0):
    noise = cv2.GaussianBlur(rng.normal(size=(height, width)).astype(np.float32), (0, 0), sigma)
    noise = (noise - noise.min()) / (noise.max() - noise.min())
    return low + (high - low) * noise


def render_dots(dots: list[Dot], n_frames: int, width: int = 320, height: int = 240, *, noise: float = 2.5,
                seed: int = 0, supersample: int = 5, background=None):
    """(frames (F, H, W) uint8, truth (F, n_dots, 2) with NaN where hidden). Pixel centres are at integer
    coordinates (OpenCV's convention); each disc's coverage is integrated by supersampling."""
    rng = np.random.default_rng(seed)
    if background is None:
        background = smooth_texture(width, height, rng)
    paths = [d.positions(n_frames) for d in dots]
    truth = np.full((n_frames, len(dots), 2), np.nan)
    sub = (np.arange(supersample) + 0.5) / supersample - 0.5
    frames = np.empty((n_frames, height, width), np.uint8)
    for f in range(n_frames):
        image = background.astype(np.float64).copy()
        for j, (dot, (uv, visible)) in enumerate(zip(dots, paths, strict=True)):
            if not visible[f]:
                continue
            u, v = uv[f]
            truth[f, j] = u, v
            h = int(np.ceil(dot.radius + 1))
            cu, cv = int(np.rint(u)), int(np.rint(v))
            ys = np.arange(max(cv - h, 0), min(cv + h + 1, height))
            xs = np.arange(max(cu - h, 0), min(cu + h + 1, width))
            if len(xs) == 0 or len(ys) == 0:
                continue
            gx = xs[None, :, None, None] + sub[None, None, None, :] - u
            gy = ys[:, None, None, None] + sub[None, None, :, None] - v
            cover = ((gx**2 + gy**2) <= dot.radius**2).mean(axis=(2, 3))
            window = image[ys[0]:ys[-1] + 1, xs[0]:xs[-1] + 1]
            window += cover * (dot.level - window)
        image += rng.normal(0.0, noise, image.shape)
        frames[f] = np.clip(np.rint(image), 0, 255).astype(np.uint8)
    return frames, truth


def spin_dots(n: int = 8, width: int = 320, height: int = 240, seed: int = 1, hide: bool = True) -> list[Dot]:
    """Dots on concentric-ish ellipses about the image centre, alternately dark and bright, 2.5–6 px."""
    rng = np.random.default_rng(seed)
    dots = []
    for j in range(n):
        a = 30.0 + 10.0 * j + rng.uniform(0, 4)
        dots.append(Dot(centre=(width / 2 + rng.uniform(-5, 5), height / 2 + rng.uniform(-5, 5)),
                        axes=(a, 0.55 * a), radius=rng.uniform(2.5, 6.0),
                        level=rng.uniform(215, 250) if j % 2 else rng.uniform(5, 35),
                        speed=0.02 + 0.01 * rng.uniform(), phase=2 * np.pi * j / n, tilt=0.3,
                        hide_at=rng.uniform(0, 2 * np.pi), hide_sin=0.6 if hide else 1.0))
    return dots

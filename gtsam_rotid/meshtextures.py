"""The textures of the mesh renderer: the hand's coverings (photographs, printed text, fabric-like noise,
stickers, dots), the back wall and the floor, and their bilinear sampling.
"""

from __future__ import annotations

import functools
import os

import cv2
import numpy as np

from .errors import InputError
from .meshconfig import COVERINGS, MeshRenderConfig, _bgr, _place_disc

_TEXTURE_RADIUS = 0.04  # m: the cylindrical texture's circumference is 2 pi times this
_TEXTURE_HEIGHT = 0.25  # m along the axis before the texture repeats
_REMAP_COLS = 1024


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
    texture = np.empty((height, width, 3), np.float32)
    texture[:] = _bgr(hand_color)
    if covering == "photo":
        texture = _photo_texture(height, width)
    elif covering == "text":
        texture = _text_texture(height, width, per_mm, rng)
    elif covering == "fabric":
        texture = _fabric_texture(height, width, per_mm, rng)
    elif covering == "stickers":
        _draw_stickers(texture, per_mm, rng)
    elif covering == "dots":
        _draw_dots(texture, float(np.mean(hand_color)), per_mm, rng)
    texture = cv2.GaussianBlur(np.ascontiguousarray(texture, dtype=np.float32), (0, 0), 0.5)  # against aliasing
    texture.setflags(write=False)
    return texture


def _photo_texture(height: int, width: int) -> np.ndarray:
    """matplotlib's sample photographs side by side around the circumference."""
    grace = _sample_photo("grace_hopper.jpg")
    present = _sample_photo("Minduka_Present_Blue_Pack.png")
    logo = _sample_photo("logo2.png")
    w_grace = int(round(height * grace.shape[1] / grace.shape[0]))
    column = max(width - w_grace, 8)
    rows = [_fit(present, height // 2, column), _fit(logo, height - height // 2, column)]
    strip = np.hstack([_fit(grace, height, w_grace), np.vstack(rows)])
    return _fit(strip, height, width) if strip.shape[1] != width else strip


def _text_texture(height: int, width: int, per_mm: float, rng: np.random.Generator) -> np.ndarray:
    """Lines of printed words and numbers in a few inks on a cream label."""
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
    return label


def _fabric_texture(height: int, width: int, per_mm: float, rng: np.random.Generator) -> np.ndarray:
    """A denim-like twill of 3 mm threads with fibre noise and blotches."""
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
    return np.clip(shade[..., None] * denim * 1.6, 0, 255).astype(np.float32)


def _draw_stickers(texture: np.ndarray, per_mm: float, rng: np.random.Generator) -> None:
    """Up to ten white-rimmed coloured discs, squares and triangles, drawn into ``texture``."""
    height, width = texture.shape[:2]
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
            cv2.circle(texture, (int(cx * 16), int(cy * 16)), int(size * 16), (245, 245, 245), -1, cv2.LINE_AA, 4)
            cv2.circle(texture, (int(cx * 16), int(cy * 16)), int(size * 0.85 * 16), color, -1, cv2.LINE_AA, 4)
        else:
            k = 4 if shape == 1 else 3
            angle = float(rng.uniform(0, 2 * np.pi))
            beta = angle + 2 * np.pi * np.arange(k) / k
            corners = centre + size * np.column_stack([np.cos(beta), np.sin(beta)])
            inner = centre + 0.8 * size * np.column_stack([np.cos(beta), np.sin(beta)])
            cv2.fillPoly(texture, [np.round(corners * 16).astype(np.int32)], (245, 245, 245), cv2.LINE_AA, 4)
            cv2.fillPoly(texture, [np.round(inner * 16).astype(np.int32)], color, cv2.LINE_AA, 4)


def _draw_dots(texture: np.ndarray, grey: float, per_mm: float, rng: np.random.Generator) -> None:
    """About 60 dark and bright 4-9 mm dots on the plain hand (``grey``: its mean level), drawn into ``texture``."""
    height, width = texture.shape[:2]
    placed: list[tuple[float, float, float]] = []
    for _ in range(60):
        _place_disc(rng, placed, (4.0 * per_mm, 9.0 * per_mm), width, height, 3 * per_mm, 300)
    for cx, cy, radius in placed:
        contrast = float(rng.uniform(50.0, 100.0)) * (1.0 if rng.uniform() < 0.5 else -1.0)
        level = float(np.clip(grey + contrast, 0, 255))
        cv2.circle(texture, (int(round(cx * 16)), int(round(cy * 16))), int(round(radius * 16)),
                   (level, level, level), -1, cv2.LINE_AA, 4)


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

"""Synthetic clips of ambient texture spinning about one axis, with exact ground truth, for the corner tracker.

A texture (a photograph, printed text, a plain surface with screws and its own edges) painted on a disc in a
plane turns about the disc's centre; a homography ``H`` (a tilted plane seen by a pinhole camera) maps it into
the image, so every surface point traces an ellipse whose image at any frame is known exactly. The disc turns
over a textured static background with static "links" (textured rectangles that never move) and, optionally, a
static bar in front of the disc (an occluder: its edges make T-junctions with the moving texture, which slide
along them). Frames are rendered at 2x and area-averaged, then get Gaussian noise and optional blur / JPEG.

``SpinClip.truth(track)`` is the true pixel of the surface point a track started on, at each of its frames
(the seed point is taken as exact: what is measured is how far the tracker drifts from that surface point), and
``SpinClip.on_disc(track)`` whether it started on the visible turning disc (not on the background, a link or the
bar).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

TEXTURE = 256          # texture side (px); the disc's centre is at (127.5, 127.5) in texture pixels
DISC_RADIUS = 120.0    # texture px
_SS = 2                # supersampling factor


def _texture(kind: str, rng) -> np.ndarray:
    """(TEXTURE, TEXTURE) float32 grey texture of the disc."""
    n = TEXTURE
    if kind == "photo":
        import matplotlib.cbook

        with matplotlib.cbook.get_sample_data("grace_hopper.jpg") as f:
            data = np.frombuffer(f.read(), np.uint8)
        image = cv2.imdecode(data, cv2.IMREAD_GRAYSCALE)
        side = min(image.shape)
        image = image[:side, :side]
        return cv2.resize(image, (n, n), interpolation=cv2.INTER_AREA).astype(np.float32)
    if kind == "text":
        image = np.full((n, n), 225, np.uint8)
        words = ["KINOVA", "Jaco2", "spin", "axis 6", "ROTID", "calib", "SN 0417", "wrist", "DANGER", "hand"]
        y = 18
        while y < n:
            x = int(rng.integers(0, 30))
            while x < n:
                word = words[int(rng.integers(len(words)))]
                scale = float(rng.uniform(0.35, 0.6))
                cv2.putText(image, word, (x, y), cv2.FONT_HERSHEY_SIMPLEX, scale, 30, 1, cv2.LINE_AA)
                x += int(cv2.getTextSize(word, cv2.FONT_HERSHEY_SIMPLEX, scale, 1)[0][0]) + int(rng.integers(8, 20))
            y += int(rng.integers(16, 24))
        return image.astype(np.float32)
    if kind == "plain":
        image = np.full((n, n), 150, np.float32)
        c = (n - 1) / 2
        yy, xx = np.mgrid[:n, :n]
        # a raised cap (its own edge) and four screws with slots
        cap = np.hypot(xx - c, yy - c) < 45
        image[cap] = 128
        for k in range(4):
            a = 0.4 + k * np.pi / 2
            sx, sy = c + 82 * np.cos(a), c + 82 * np.sin(a)
            screw = np.hypot(xx - sx, yy - sy) < 7
            image[screw] = 95
            slot = screw & (np.abs((xx - sx) * np.sin(a + 0.7) - (yy - sy) * np.cos(a + 0.7)) < 1.2)
            image[slot] = 40
        # a seam from the cap to the rim
        image[(np.abs(yy - c) < 1.5) & (xx > c + 45)] = 105
        return cv2.GaussianBlur(image, (0, 0), 0.8)
    raise ValueError(f"unknown texture kind {kind!r}")


def _background(width: int, height: int, rng) -> np.ndarray:
    """Smooth texture plus sharp rectangles (background corners)."""
    noise = cv2.GaussianBlur(rng.normal(size=(height, width)).astype(np.float32), (0, 0), 6.0 * _SS)
    noise = (noise - noise.min()) / (noise.max() - noise.min())
    image = 70 + 110 * noise
    for _ in range(40):
        x, y = int(rng.integers(0, width)), int(rng.integers(0, height))
        w, h = int(rng.integers(6, 30)) * _SS, int(rng.integers(6, 30)) * _SS
        image[y:y + h, x:x + w] = float(rng.uniform(30, 230))
    return image.astype(np.float32)


@dataclass
class SpinClip:
    frames: np.ndarray            # (F, H, W) uint8
    matrices: np.ndarray          # (F, 3, 3): texture px -> image px at each frame
    disc_mask: np.ndarray         # (F, H, W) bool: the visible turning disc (not under the bar)
    omega: float                  # rad per frame
    moving_region: np.ndarray     # (H, W) bool: pixels the disc ever covers (anything else is still)
    bar: tuple[int, int, int, int] | None   # (x0, y0, x1, y1) of the static occluder, image px

    def truth(self, track) -> np.ndarray:
        """(N, 2) true pixels of the surface point under the track's first point, at the track's frames."""
        f0 = int(track.frames[0])
        p0 = np.array([*track.pixels[0], 1.0])
        m = np.linalg.solve(self.matrices[f0], p0)
        out = self.matrices[track.frames] @ m
        return out[:, :2] / out[:, 2:]

    def on_disc(self, track) -> bool:
        f0 = int(track.frames[0])
        u, v = np.rint(track.pixels[0]).astype(int)
        h, w = self.disc_mask.shape[1:]
        if not (0 <= u < w and 0 <= v < h):
            return False
        # a few pixels inside the disc, not on its edge or the bar's
        y0, y1, x0, x1 = max(v - 3, 0), min(v + 4, h), max(u - 3, 0), min(u + 4, w)
        return bool(self.disc_mask[f0, y0:y1, x0:x1].all())

    def errors(self, tracks) -> np.ndarray:
        """Distance (px) of every point of every track from its truth."""
        if not tracks:
            return np.zeros(0)
        return np.concatenate([np.linalg.norm(t.pixels - self.truth(t), axis=1) for t in tracks])


def spin_clip(kind: str = "photo", n_frames: int = 90, width: int = 320, height: int = 240, *,
              omega: float = 0.5 / 30, tilt_deg: float = 50.0, disc_px: float = 85.0, noise: float = 2.0,
              blur: float = 0.0, jpeg: int | None = None, bar: bool = False, seed: int = 0) -> SpinClip:
    """Render a clip (see the module docstring). ``disc_px`` is the disc's radius in image px along its major
    axis; ``omega`` rad per frame; ``bar`` puts a static occluder across the lower part of the disc."""
    rng = np.random.default_rng(seed)
    texture = _texture(kind, rng)
    big_w, big_h = width * _SS, height * _SS
    c = (TEXTURE - 1) / 2
    # plane -> image homography of a tilted plane: pinhole camera f, plane rotated about the image x axis
    f = 3.0 * big_w
    t = np.radians(tilt_deg)
    rot = np.array([[1, 0, 0], [0, np.cos(t), -np.sin(t)], [0, np.sin(t), np.cos(t)]])
    z = f * DISC_RADIUS / (disc_px * _SS)
    k = np.array([[f, 0, (big_w - 1) / 2 + 8 * _SS], [0, f, (big_h - 1) / 2 - 4 * _SS], [0, 0, 1]])
    plane = k @ np.column_stack([rot[:, 0], rot[:, 1], [0, 0, z]])          # plane (x, y) centred -> image (2x)
    to_small = np.array([[1 / _SS, 0, 0.5 / _SS - 0.5], [0, 1 / _SS, 0.5 / _SS - 0.5], [0, 0, 1]])
    background = _background(big_w, big_h, rng)
    links = []
    # two still "links": textured rectangles that never move, at the image's left and right
    for x0 in (4 * _SS, width * _SS - 60 * _SS):
        y0 = 20 * _SS
        patch = cv2.resize(texture[:120, :120], (54 * _SS, 90 * _SS)) * 0.8 + 30
        background[y0:y0 + patch.shape[0], x0:x0 + patch.shape[1]] = patch
        links.append((x0, y0))
    disc = np.zeros((TEXTURE, TEXTURE), np.float32)
    yy, xx = np.mgrid[:TEXTURE, :TEXTURE]
    inside = np.hypot(xx - c, yy - c) <= DISC_RADIUS
    if kind == "plain":   # a tab on the rim: the outline turns with the disc
        inside |= (np.abs(yy - c) < 14) & (xx - c > 0) & (xx - c < DISC_RADIUS + 10)
    disc[inside] = 1.0
    bar_box = None
    if bar:
        bx0, bx1 = int(0.2 * width), int(0.85 * width)
        by0 = int(0.5 * height + 0.28 * disc_px)
        bar_box = (bx0, by0, bx1, by0 + 18)
        bar_tex = cv2.resize(_texture("text", np.random.default_rng(seed + 7)), (big_w, big_h))[:18 * _SS] * 0.6 + 20
    frames = np.empty((n_frames, height, width), np.uint8)
    matrices = np.empty((n_frames, 3, 3))
    masks = np.empty((n_frames, height, width), bool)
    ever = np.zeros((height, width), bool)
    centre = np.array([[1, 0, -c], [0, 1, -c], [0, 0, 1]], float)
    noise_rng = np.random.default_rng(seed + 1)
    for i in range(n_frames):
        a = omega * i
        spin = np.array([[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0], [0, 0, 1]])
        big = plane @ spin @ centre                                          # texture px -> big image px
        warped = cv2.warpPerspective(texture, big, (big_w, big_h), flags=cv2.INTER_LINEAR)
        alpha = cv2.warpPerspective(disc, big, (big_w, big_h), flags=cv2.INTER_LINEAR)
        image = background * (1 - alpha) + warped * alpha
        cover = alpha
        if bar_box is not None:
            bx0, by0, bx1, by1 = (v * _SS for v in bar_box)
            image[by0:by1, bx0:bx1] = bar_tex[:by1 - by0, bx0:bx1]
            cover = alpha.copy()
            cover[by0:by1, bx0:bx1] = 0
        small = cv2.resize(image, (width, height), interpolation=cv2.INTER_AREA)
        small_cover = cv2.resize(cover, (width, height), interpolation=cv2.INTER_AREA)
        if blur > 0:
            small = cv2.GaussianBlur(small, (0, 0), blur)
        small = small + noise_rng.normal(0, noise, small.shape).astype(np.float32)
        frame = np.clip(np.rint(small), 0, 255).astype(np.uint8)
        if jpeg is not None:
            ok, buf = cv2.imencode(".jpg", frame, [cv2.IMWRITE_JPEG_QUALITY, int(jpeg)])
            frame = cv2.imdecode(buf, cv2.IMREAD_GRAYSCALE)
        frames[i] = frame
        matrices[i] = to_small @ big
        masks[i] = small_cover > 0.999
        ever |= small_cover > 0.001
    return SpinClip(frames, matrices, masks, omega, ever, bar_box)

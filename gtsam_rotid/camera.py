"""Pinhole camera with OpenCV's distortion model (k1, k2, p1, p2, k3).

Conventions (docs/design.md §2): OpenCV camera frame (x right, y down, z forward); pixel coordinates with
the origin at the centre of the top-left pixel; tracks are raw (distorted) pixels and are undistorted
here. All functions are vectorised over points.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from .errors import CameraError

#: Where each of the intrinsics ``fx, fy, cx, cy`` sits in ``K``.
_K_ENTRIES = {"fx": (0, 0), "fy": (1, 1), "cx": (0, 2), "cy": (1, 2)}
_UNDISTORT_CRITERIA = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 200, 1e-14)


def _as_points(array, dim: int, what: str) -> np.ndarray:
    points = np.asarray(array, dtype=float)
    if points.ndim == 1 and points.shape[0] == dim:
        points = points[None, :]
    if points.ndim != 2 or points.shape[1] != dim:
        raise CameraError(f"{what} must have shape (N, {dim}), got {np.shape(array)}")
    return points


@dataclass(frozen=True, eq=False)
class Camera:
    """An intrinsically calibrated camera.

    Args:
        K: 3x3 intrinsic matrix ``[[fx, s, cx], [0, fy, cy], [0, 0, 1]]`` with fx, fy > 0.
        width, height: image size in pixels (positive integers).
        dist: OpenCV distortion coefficients ``(k1, k2, p1, p2[, k3])``; ``None`` means none.
    """

    K: np.ndarray
    width: int
    height: int
    dist: np.ndarray | None = None

    def __init__(self, K, width, height, dist=None):
        K = np.array(K, dtype=float)
        if K.shape != (3, 3):
            raise CameraError(f"K must be a 3x3 matrix, got shape {K.shape}")
        if not np.all(np.isfinite(K)):
            raise CameraError("K contains NaN or infinite entries")
        if not np.allclose(K[2], [0.0, 0.0, 1.0]) or K[1, 0] != 0.0:
            raise CameraError(f"K must have the form [[fx, s, cx], [0, fy, cy], [0, 0, 1]], got {K.tolist()}")
        if K[0, 0] <= 0 or K[1, 1] <= 0:
            raise CameraError(f"focal lengths must be positive, got fx={K[0, 0]}, fy={K[1, 1]}")
        for name, value in (("width", width), ("height", height)):
            if isinstance(value, bool) or not float(value).is_integer() or value <= 0:
                raise CameraError(f"image {name} must be a positive integer, got {value!r}")
        cx, cy = K[0, 2], K[1, 2]
        if not (0.0 <= cx <= float(width) and 0.0 <= cy <= float(height)):
            raise CameraError(f"the principal point ({cx:g}, {cy:g}) lies outside the {int(width)}x{int(height)} "
                              "image: is the camera matrix for another resolution (or are width and height "
                              "swapped)?")
        if dist is not None:
            dist = np.array(dist, dtype=float).ravel()
            if dist.shape[0] == 4:
                dist = np.append(dist, 0.0)
            if dist.shape[0] != 5:
                raise CameraError(
                    f"distortion must be (k1, k2, p1, p2) or (k1, k2, p1, p2, k3), got {dist.shape[0]} values"
                )
            if not np.all(np.isfinite(dist)):
                raise CameraError("distortion coefficients contain NaN or infinite entries")
            if not np.any(dist):
                dist = None
        K.setflags(write=False)
        if dist is not None:
            dist.setflags(write=False)
        object.__setattr__(self, "K", K)
        object.__setattr__(self, "width", int(width))
        object.__setattr__(self, "height", int(height))
        object.__setattr__(self, "dist", dist)

    # ------------------------------------------------------------------ constructors
    @classmethod
    def from_fov(cls, width: int, height: int, hfov_deg: float, dist=None) -> Camera:
        """Square-pixel camera with principal point at the image centre and the given horizontal FOV."""
        if not 0.0 < hfov_deg < 180.0:
            raise CameraError(f"horizontal field of view must be in (0, 180) degrees, got {hfov_deg}")
        f = 0.5 * width / np.tan(np.radians(hfov_deg) / 2.0)
        return cls([[f, 0.0, (width - 1) / 2.0], [0.0, f, (height - 1) / 2.0], [0.0, 0.0, 1.0]], width, height, dist)

    @classmethod
    def xtion(cls) -> Camera:
        """The reference scene's Asus Xtion-like camera: 640x480, fx = fy = 570 (docs/design.md §6)."""
        return cls([[570.0, 0.0, 319.5], [0.0, 570.0, 239.5], [0.0, 0.0, 1.0]], 640, 480)

    @classmethod
    def from_dict(cls, data: dict) -> Camera:
        try:
            return cls(data["K"], data["width"], data["height"], data.get("dist"))
        except KeyError as missing:
            raise CameraError(f"camera description lacks the field {missing}") from None

    def to_dict(self) -> dict:
        return {
            "K": self.K.tolist(),
            "width": self.width,
            "height": self.height,
            "dist": None if self.dist is None else self.dist.tolist(),
        }

    def __eq__(self, other) -> bool:
        if not isinstance(other, Camera):
            return NotImplemented
        same_dist = (self.dist is None and other.dist is None) or (
            self.dist is not None and other.dist is not None and np.array_equal(self.dist, other.dist)
        )
        return (
            np.array_equal(self.K, other.K)
            and self.width == other.width
            and self.height == other.height
            and same_dist
        )

    __hash__ = None

    def __repr__(self) -> str:
        fx, fy, cx, cy = self.K[0, 0], self.K[1, 1], self.K[0, 2], self.K[1, 2]
        dist = "none" if self.dist is None else np.array2string(self.dist, precision=4)
        return f"Camera({self.width}x{self.height}, fx={fx:g}, fy={fy:g}, cx={cx:g}, cy={cy:g}, dist={dist})"

    @property
    def intrinsics(self) -> dict[str, float]:
        """``fx, fy, cx, cy`` (px)."""
        return {name: float(self.K[entry]) for name, entry in _K_ENTRIES.items()}

    def with_intrinsics(self, values: dict[str, float]) -> Camera:
        """This camera with the intrinsics named in ``values`` (``fx``, ``fy``, ``cx``, ``cy``; px) replaced (the
        others, the skew, the distortion and the image size kept)."""
        K = np.array(self.K, dtype=float)
        for name, value in values.items():
            K[_K_ENTRIES[name]] = value
        return Camera(K, self.width, self.height, self.dist)

    def with_intrinsics_changed(self, focal_factor: float = 1.0, cx_px: float = 0.0, cy_px: float = 0.0) -> Camera:
        """This camera with fx and fy multiplied by ``focal_factor`` and the principal point moved by ``cx_px``,
        ``cy_px`` (the distortion and the image size kept): what a camera file a little off looks like."""
        K = np.array(self.K, dtype=float)
        K[0, 0] *= focal_factor
        K[1, 1] *= focal_factor
        K[0, 2] += cx_px
        K[1, 2] += cy_px
        return Camera(K, self.width, self.height, self.dist)

    # ------------------------------------------------------------------ geometry
    @property
    def has_distortion(self) -> bool:
        return self.dist is not None

    def distort_normalized(self, xy) -> np.ndarray:
        """Apply the distortion model to normalised image coordinates (x/z, y/z)."""
        xy = _as_points(xy, 2, "normalised points")
        if self.dist is None:
            return xy.copy()
        k1, k2, p1, p2, k3 = self.dist
        x, y = xy[:, 0], xy[:, 1]
        r2 = x * x + y * y
        radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
        xd = x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x)
        yd = y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y
        return np.column_stack([xd, yd])

    def normalized_to_pixels(self, xy) -> np.ndarray:
        """Apply K (no distortion) to normalised coordinates."""
        xy = _as_points(xy, 2, "normalised points")
        K = self.K
        u = K[0, 0] * xy[:, 0] + K[0, 1] * xy[:, 1] + K[0, 2]
        v = K[1, 1] * xy[:, 1] + K[1, 2]
        return np.column_stack([u, v])

    def pixels_to_normalized(self, uv) -> np.ndarray:
        """Invert K (no distortion) on pixel coordinates."""
        uv = _as_points(uv, 2, "pixels")
        K = self.K
        y = (uv[:, 1] - K[1, 2]) / K[1, 1]
        x = (uv[:, 0] - K[0, 2] - K[0, 1] * y) / K[0, 0]
        return np.column_stack([x, y])

    def project(self, points_camera, *, distort: bool = True) -> np.ndarray:
        """Project 3-D points given in the camera frame to pixels ((N, 3) -> (N, 2)).

        Points at or behind the camera centre (z <= 0) give NaN pixels.
        With ``distort=False`` the ideal (undistorted) pinhole pixels are returned.
        """
        points = _as_points(points_camera, 3, "camera-frame points")
        z = points[:, 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            xy = points[:, :2] / z[:, None]
        xy[z <= 0] = np.nan
        if distort:
            xy = self.distort_normalized(xy)
        return self.normalized_to_pixels(xy)

    def undistort_pixels(self, pixels) -> np.ndarray:
        """Raw (distorted) pixels -> ideal pinhole pixels with the same K."""
        return self.normalized_to_pixels(self.normalize(pixels))

    def normalize(self, pixels) -> np.ndarray:
        """Raw (distorted) pixels -> undistorted normalised coordinates (x/z, y/z)."""
        uv = _as_points(pixels, 2, "pixels")
        if self.dist is None:
            return self.pixels_to_normalized(uv)
        if uv.shape[0] == 0:
            return np.zeros((0, 2))
        out = cv2.undistortPointsIter(
            uv.reshape(-1, 1, 2), self.K, self.dist, None, None, _UNDISTORT_CRITERIA
        )
        return out.reshape(-1, 2)

    def rays(self, pixels) -> np.ndarray:
        """Unit viewing rays (camera frame) of raw pixels."""
        xy = self.normalize(pixels)
        rays = np.column_stack([xy, np.ones(len(xy))])
        return rays / np.linalg.norm(rays, axis=1, keepdims=True)

    def in_image(self, pixels, margin: float = 0.0) -> np.ndarray:
        """Boolean mask: pixel lies inside the image, at least ``margin`` pixels from the border."""
        uv = _as_points(pixels, 2, "pixels")
        with np.errstate(invalid="ignore"):
            return (
                (uv[:, 0] >= -0.5 + margin)
                & (uv[:, 0] <= self.width - 0.5 - margin)
                & (uv[:, 1] >= -0.5 + margin)
                & (uv[:, 1] <= self.height - 0.5 - margin)
            )

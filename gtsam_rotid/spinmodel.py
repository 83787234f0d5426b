"""The spin's shared rotation in the image (:class:`SpinModel`: one conic shape shared by every track of a spin, each
track's centre and size, the common rate), fitted by variable projection from per-track conic moments; direct
ellipse fits (Fitzgibbon) and Sampson distances.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

PATCH = 15              # side (px) of the appearance patch kept per track for linking
_SAMPSON_FLOOR = 1e-9


# ---------------------------------------------------------------------------------------------- conics
def _design(points: np.ndarray) -> np.ndarray:
    """(..., 6) conic design rows [x², xy, y², x, y, 1]."""
    x, y = points[..., 0], points[..., 1]
    return np.stack([x * x, x * y, y * y, x, y, np.ones_like(x)], axis=-1)


@dataclass
class SpinModel:
    """One spin's shared rotation in normalised image coordinates ``(p - origin) / scale``.

    ``shape``: the conic's quadratic part (s0 x² + s1 xy + s2 y²), shared by every track (exact for an affine
    camera, close for a perspective one); ``W`` the symmetric square root of its matrix (det 1), which maps
    every track's ellipse to a circle; ``omega`` the common rate (rad per frame, signed) in that frame.
    """

    origin: np.ndarray
    scale: float
    shape: np.ndarray                      # (3,)
    W: np.ndarray                          # (2, 2)
    omega: float = 0.0

    @classmethod
    def fit(cls, moments: np.ndarray, counts, origin, scale, iterations: int = 3) -> SpinModel | None:
        """From per-track conic moments (n, 6, 6) (sum of d dᵀ over each track's ``counts`` normalised points):
        the shared shape minimising each track's mean algebraic error with its linear part free (variable
        projection), tracks far off the shared shape down-weighted. None if it is not an ellipse."""
        if len(moments) == 0:
            return None
        moments = moments / np.asarray(counts, float)[:, None, None]
        reduced = _reduced(moments)
        # start with no track weighing more than the median one: a single track far off every ellipse (a point
        # sliding along a straight edge) has a large reduced scatter and alone could make the sum's best conic a
        # hyperbola
        size = np.trace(reduced, axis1=1, axis2=2)
        weights = 1.0 / np.maximum(size / max(float(np.median(size)), 1e-18), 1.0)
        model = None
        for _ in range(iterations):
            values, vectors = np.linalg.eigh((reduced * weights[:, None, None]).sum(axis=0))
            model = cls.from_shape(vectors[:, 0], origin, scale)
            if model is None:
                return None
            # each track's mean squared algebraic error at the shared shape, over its gradient scale
            error = np.einsum("i,nij,j->n", model.shape, reduced, model.shape)
            error = error / max(float(np.median(error)), 1e-18)
            weights = 1.0 / np.maximum(error, 1.0)
        return model

    @classmethod
    def from_shape(cls, s, origin, scale) -> SpinModel | None:
        s = np.asarray(s, float)
        matrix = np.array([[s[0], s[1] / 2], [s[1] / 2, s[2]]])
        det = np.linalg.det(matrix)
        if not det > 0:
            return None
        if matrix[0, 0] < 0:
            matrix, s = -matrix, -s
        matrix /= math.sqrt(det)
        s = s / math.sqrt(det)
        values, vectors = np.linalg.eigh(matrix)
        if values.min() <= 0:
            return None
        w = vectors @ np.diag(np.sqrt(values)) @ vectors.T
        return cls(np.asarray(origin, float), float(scale), s, w)

    def normalise(self, pixels: np.ndarray) -> np.ndarray:
        return (np.asarray(pixels, float) - self.origin) / self.scale

    def linear_parts(self, moments: np.ndarray) -> np.ndarray:
        """(n, 3) each track's linear conic coefficients (x, y, 1) given the shared shape."""
        a_ll = moments[:, 3:, 3:] + 1e-12 * np.eye(3)
        a_lq = moments[:, 3:, :3]
        return -np.linalg.solve(a_ll, (a_lq @ self.shape)[..., None])[..., 0]

    def centres(self, linear: np.ndarray) -> np.ndarray:
        """(n, 2) normalised ellipse centres of tracks with linear parts ``linear``."""
        s0, s1, s2 = self.shape
        m = np.array([[2 * s0, s1], [s1, 2 * s2]])
        return np.linalg.solve(m, -linear[:, :2].T).T

    def distance(self, points: np.ndarray, linear: np.ndarray) -> np.ndarray:
        """Sampson distance (px) of normalised points (n, 2) from their tracks' conics (n, 3)."""
        return _sampson(points, np.concatenate([np.broadcast_to(self.shape, (len(points), 3)), linear], axis=1)) \
            * self.scale

    def phase(self, points: np.ndarray, centres: np.ndarray) -> np.ndarray:
        """Angle (rad) of each normalised point about its centre in the frame where ellipses are circles."""
        q = (points - centres) @ self.W.T
        return np.arctan2(q[..., 1], q[..., 0])

    def radius(self, points: np.ndarray, centres: np.ndarray) -> np.ndarray:
        """Radius (px) of each point about its centre in that frame."""
        return np.linalg.norm((points - centres) @ self.W.T, axis=-1) * self.scale

    def turn(self, pixels: np.ndarray, centres_px: np.ndarray, angle) -> np.ndarray:
        """Pixels turned by ``angle`` (rad, per point or scalar) about their ellipse centres (px)."""
        angle = np.broadcast_to(np.asarray(angle, float), (len(pixels),))
        c, s = np.cos(angle), np.sin(angle)
        q = (pixels - centres_px) @ self.W.T
        turned = np.stack([c * q[:, 0] - s * q[:, 1], s * q[:, 0] + c * q[:, 1]], axis=1)
        return centres_px + np.linalg.solve(self.W, turned.T).T

    def local_warp(self, angle: float) -> np.ndarray:
        """2x2 linear map of a small patch turned by ``angle`` (affine approximation)."""
        c, s = math.cos(angle), math.sin(angle)
        return np.linalg.solve(self.W, np.array([[c, -s], [s, c]]) @ self.W)


def _reduced(moments: np.ndarray) -> np.ndarray:
    """(n, 3, 3) per-track quadratic-part scatter with the linear part eliminated (variable projection)."""
    a_qq = moments[:, :3, :3]
    a_ql = moments[:, :3, 3:]
    a_ll = moments[:, 3:, 3:] + 1e-12 * np.eye(3)
    return a_qq - a_ql @ np.linalg.solve(a_ll, np.transpose(a_ql, (0, 2, 1)))


def _sampson(points: np.ndarray, conic: np.ndarray) -> np.ndarray:
    """|g(p)| / |grad g(p)| for conics (n, 6) = [s0, s1, s2, b0, b1, c] (algebraic form of ``_design``)."""
    x, y = points[:, 0], points[:, 1]
    s0, s1, s2, b0, b1, c = conic.T
    g = s0 * x * x + s1 * x * y + s2 * y * y + b0 * x + b1 * y + c
    gx = 2 * s0 * x + s1 * y + b0
    gy = s1 * x + 2 * s2 * y + b1
    return np.abs(g) / np.maximum(np.hypot(gx, gy), _SAMPSON_FLOOR)


def fit_conic(points: np.ndarray) -> np.ndarray | None:
    """Algebraic conic (6,) through (n, 2) normalised points, constrained to an ellipse; None if not one."""
    if len(points) < 6:
        return None
    d = _design(points)
    # Fitzgibbon, Pilu & Fisher: min |D a|² s.t. 4 a0 a2 - a1² = 1, via the reduced 3x3 problem
    s = d.T @ d
    s1, s2, s3 = s[:3, :3], s[:3, 3:], s[3:, 3:]
    try:
        t = -np.linalg.solve(s3 + 1e-12 * np.eye(3), s2.T)
    except np.linalg.LinAlgError:
        return None
    m = s1 + s2 @ t
    m = np.array([m[2] / 2, -m[1], m[0] / 2])
    values, vectors = np.linalg.eig(m)
    vectors = np.real(vectors)
    cond = 4 * vectors[0] * vectors[2] - vectors[1] ** 2
    good = np.flatnonzero(cond > 0)
    if not len(good):
        return None
    a1 = vectors[:, good[0]]
    return np.concatenate([a1, t @ a1])

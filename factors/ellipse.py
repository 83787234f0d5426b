"""The image conic of a circle variable: certificates of closest phases, and the quadrant arcs of their search.

A converged stationary point of a pixel's distance to a projected circle is certified as the global minimum by
:class:`_Ellipse` (the image ellipse in its axes): cheaply where the pixel lies outside the curve or inside by less
than the smallest radius of curvature ``b^2 / a`` (``rho_min``, with the margin ``_RHO_MARGIN``), exactly where the
curve point lies in the pixel's open quadrant of the ellipse's axes; :meth:`_Ellipse.quadrant_arcs` brackets the
search of the pixels left. Used by :class:`.circle_track.CircleTrack` and, vectorised over tracks, by
:class:`.coaxial_tracks.CoaxialTracks` (see the certification in :class:`.circle_track.CircleTrack`).
"""

from __future__ import annotations

import math

import numpy as np

#: Certificate margin (relative) of "inside by less than the smallest radius of curvature".
_RHO_MARGIN = 1.0 - 1e-6


class _Ellipse:
    """The image conic of a circle variable, for the certificates and the bracketed search of
    :class:`.circle_track.CircleTrack`.

    ``Q = K^-T R Qn R^T K^-1`` with ``Qn = [[d^2, -d, 0], [-d, 1 - r^2, 0], [0, 0, d^2]]`` (the circle in the line
    variable's coordinates: ``v1 = d``, ``(v0 - 1)^2 + v2^2 = r^2``), i.e.
    ``Q = d^2 K^-T K^-1 + (1 - r^2 - d^2) k1 k1^T - d (k0 k1^T + k1 k0^T)`` with ``k_i = K^-T c_i``, and
    ``det Q = -d^4 r^2 / det(K)^2``. Centre ``-Q2^-1 q``; semi-axes^2 ``= kk / eig(Q2)`` with ``kk = -det Q / det Q2``.

    In its axes the ellipse is ``x^2 / a^2 + y^2 / b^2 = 1``; the stationary points of ``|q - p|`` are
    ``q = (a^2 X / (a^2 + t), b^2 Y / (b^2 + t))`` with ``(a X / (a^2 + t))^2 + (b Y / (b^2 + t))^2 = 1``, strictly
    decreasing in ``t > -b^2`` (Eberly, "Distance from a point to an ellipse"). So for a pixel ``p = (X, Y)`` off
    the axes exactly one stationary point lies in ``p``'s open quadrant (``t > -b^2``), and it is the global
    minimum (reflecting a point across an axis towards ``p`` brings it closer), wherever ``p`` is.
    """

    __slots__ = ("valid", "rho_min", "_args", "_frame")

    def __init__(self, k0, k1, omega, det_K: float, d: float, r: float):
        (g0x, g0y, _), (g1x, g1y, _) = k0, k1
        w00, w01, w11 = omega[:3]
        dd, rr = d * d, r * r
        alpha = 1.0 - rr - dd
        q00 = dd * w00 + alpha * g1x * g1x - 2.0 * d * g0x * g1x
        q01 = dd * w01 + alpha * g1x * g1y - d * (g0x * g1y + g1x * g0y)
        q11 = dd * w11 + alpha * g1y * g1y - 2.0 * d * g0y * g1y
        det_q2 = q00 * q11 - q01 * q01
        mean = 0.5 * (q00 + q11)
        self.valid = False
        self.rho_min = 0.0
        self._frame = None
        if det_q2 > 0.0 and mean > 0.0 and r != 0.0 and d != 0.0:
            half = math.hypot(0.5 * (q00 - q11), q01)
            lam_small, lam_big = mean - half, mean + half
            if lam_small > 0.0:
                kk = dd * dd * rr / (det_K * det_K * det_q2)
                self.valid = True
                self.rho_min = math.sqrt(kk * lam_small) / lam_big  # b^2 / a
                self._args = (k0, k1, omega, d, r, q00, q01, q11, det_q2, kk, lam_small, lam_big)

    def frame(self) -> tuple[float, float, float, float, float, float]:
        """Centre (xc, yc), unit minor-axis direction (cos, sin) and semi-axes a >= b (pixels)."""
        if self._frame is None:
            (g0x, g0y, g0z), (g1x, g1y, g1z), omega, d, r, q00, q01, q11, det_q2, kk, lam_small, lam_big = self._args
            dd = d * d
            alpha = 1.0 - r * r - dd
            q02 = dd * omega[3] + alpha * g1x * g1z - d * (g0x * g1z + g1x * g0z)
            q12 = dd * omega[4] + alpha * g1y * g1z - d * (g0y * g1z + g1y * g0z)
            xc = -(q11 * q02 - q01 * q12) / det_q2
            yc = -(q00 * q12 - q01 * q02) / det_q2
            theta = 0.5 * math.atan2(2.0 * q01, q00 - q11)  # eigenvector of lam_big: the minor axis
            self._frame = (xc, yc, math.cos(theta), math.sin(theta), math.sqrt(kk / lam_small),
                           math.sqrt(kk / lam_big))
        return self._frame

    def same_quadrant(self, px: np.ndarray, py: np.ndarray, y0: np.ndarray, y1: np.ndarray,
                      y2: np.ndarray) -> np.ndarray:
        """Mask of the pixels ``p`` that lie in the same open quadrant of the ellipse's axes as the curve points
        ``q = (y0, y1) / y2`` (``y2 > 0``): where ``q`` is stationary, it is then the global minimum."""
        xc, yc, cos_t, sin_t, _, _ = self.frame()
        dx, dy = px - xc, py - yc
        qx, qy = y0 - xc * y2, y1 - yc * y2  # (q - centre) y2
        along = (dx * cos_t + dy * sin_t) * (qx * cos_t + qy * sin_t)
        across = (dy * cos_t - dx * sin_t) * (qy * cos_t - qx * sin_t)
        return (along > 0.0) & (across > 0.0)

    def quadrant_arcs(self, px: np.ndarray, py: np.ndarray, G: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Phase interval ``[lo, lo + length]`` of the arc of the ellipse in each pixel's quadrant of its axes.

        The vertices' phases invert the projection exactly: a curve pixel's ray ``rho = G (u, 1)``,
        ``G = R^T K^-1``, meets the circle's plane ``v1 = d`` at ``v = (d / rho1) rho``, phase
        ``atan2((v0 - 1) / r, v2 / r)``.
        """
        xc, yc, cos_t, sin_t, a, b = self.frame()
        _, _, _, d, r = self._args[:5]
        # vertices: +major, -major, +minor, -minor (the major axis is (-sin, cos), the minor (cos, sin))
        vx = np.array([xc - a * sin_t, xc + a * sin_t, xc + b * cos_t, xc - b * cos_t])
        vy = np.array([yc + a * cos_t, yc - a * cos_t, yc + b * sin_t, yc - b * sin_t])
        rho = G @ np.vstack([vx, vy, np.ones(4)])
        t = rho[1] * r
        psi = np.arctan2((d * rho[0] - rho[1]) * t, (d * rho[2]) * t).tolist()
        two_pi = 2.0 * math.pi
        lo, length = [0.0] * 4, [0.0] * 4
        for index, (major, minor) in enumerate(((1, 3), (1, 2), (0, 3), (0, 2))):  # index = 2 [X > 0] + [Y > 0]
            start, arc = psi[major], (psi[minor] - psi[major]) % two_pi
            others = [psi[k] for k in range(4) if k not in (major, minor)]
            if any(0.0 < (o - start) % two_pi < arc for o in others):
                start, arc = psi[minor], two_pi - arc
            lo[index], length[index] = start, arc
        dx, dy = px - xc, py - yc
        index = 2 * ((dy * cos_t - dx * sin_t) > 0.0) + ((dx * cos_t + dy * sin_t) > 0.0)
        return np.array(lo)[index], np.array(length)[index]

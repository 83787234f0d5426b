"""Per-track coefficient tables of :class:`.coaxial_tracks.CoaxialTracks` at a line variable.

Everything the closest phases, residuals and Jacobians of a track need (CircleTrack's ``_coefficients``, see
:mod:`.circle_track`) is a polynomial in the track's ``(d, r)`` with coefficients that depend on the line variable
``R`` only: :meth:`_CoefficientTable.polynomials` maps the monomials of ``(d, r)`` to the table (one small matrix,
cached for the last ``R``), and :meth:`_CoefficientTable.coefficients` evaluates it for all tracks at once, one
(m,) array per row (rows named by this module's constants), with the cheap certificate's threshold. The pixels do
not enter: :class:`.coaxial_tracks.CoaxialTracks` gathers the rows per pixel.
"""

from __future__ import annotations

import numpy as np

from .ellipse import _RHO_MARGIN

# Rows of the per-track coefficient table of :meth:`_CoefficientTable.coefficients` (each an (m,) array).
_C8 = slice(0, 24)  # (g0..g4, lA, lB, lC) x (1, u_x, u_y): see _CoefficientTable.polynomials
_Z = slice(24, 29)  # |z[:2]|^2 on the basis (1, s, c, s c, c^2)
_Y2 = slice(29, 32)  # y2 on (1, s, c)
_KAPPA, _D, _R, _DDRR, _OPDR = 32, 33, 34, 35, 36
_Y0 = slice(37, 40)  # y0 on (1, s, c)
_Y1 = slice(40, 43)  # y1 on (1, s, c)
_Q = slice(43, 46)  # the image conic's q00, q01, q11
_N_POLY = 46  # rows that are polynomials in (d, r)
_THRESHOLD = 46  # the cheap certificate's threshold
_SIDE = 47  # CircleTrack's side (+-1)
_N_COEFFICIENTS = 48
_N_MONO = 16
#: g_k (k = 0..4) on the side monomials (r, r d, r d^2, r^2, r^2 d, r^3): weights of w_ij = w(h_i, k_j) (index
#: 3 i + j), see _CoefficientTable.polynomials.
_G_TERMS = np.zeros((5, 6, 9))
for _k, _mono, _i, _j, _weight in (
        (0, 3, 1, 0, -2.0), (0, 4, 0, 0, 1.0), (0, 4, 1, 1, -1.0),
        (1, 0, 1, 0, -1.0), (1, 1, 0, 0, 1.0), (1, 1, 1, 1, -1.0), (1, 2, 0, 1, 1.0), (1, 5, 1, 0, -1.0),
        (2, 1, 2, 0, 1.0), (2, 2, 2, 1, 1.0), (2, 5, 1, 2, -1.0),
        (3, 3, 1, 2, -1.0), (3, 4, 0, 2, 1.0), (3, 4, 2, 0, 1.0),
        (4, 3, 1, 0, 1.0), (4, 4, 2, 2, 1.0), (4, 4, 0, 0, -1.0)):
    _G_TERMS[_k, _mono, 3 * _i + _j] = _weight


_G_TERMS_2D = _G_TERMS.reshape(30, 9)


def _sparse_entries(KR: list, omega: tuple) -> tuple[list, list]:
    """(row, column) and value of the entries of :meth:`_CoefficientTable.polynomials` other than the g triples, from
    the rows of ``KK @ R`` (``K R``, ``cof(K) R``, ``K^-T R``) as lists: the l triples (columns: side monomials),
    ``|z[:2]|^2`` (columns 4..9: r^2, r^2 d, r^2 d^2, r^3, r^3 d, r^4), y0, y1, y2 (columns 0..2: 1, d, r) and the
    conic (columns 0, 1, 3, 4: 1, d, d^2, r^2)."""
    h = [[KR[3 + i][j] for i in range(3)] for j in range(3)]  # h[j] = column j of cof(K) R
    k = [[KR[i][j] for i in range(3)] for j in range(3)]  # k[j] = column j of K R
    index, value = [], []

    def put(row, col, x):
        index.append((row, col))
        value.append(x)

    for n, i in enumerate((2, 0, 1)):  # lA = P = -r^2 h1; lB = Q = -r h1 + r d h0; lC = T = r d h2
        put(15 + n, 13, -h[1][i])
        put(18 + n, 10, -h[1][i])
        put(18 + n, 11, h[0][i])
        put(21 + n, 11, h[2][i])
    D = [[h[i][0] * h[j][0] + h[i][1] * h[j][1] for j in range(3)] for i in range(3)]
    for col, x in ((9, D[1][1]), (4, D[1][1]), (5, -2.0 * D[0][1]), (6, D[0][0])):
        put(24, col, x)  # D(P, P) + D(Q, Q)
    put(25, 7, 2.0 * D[1][1])  # 2 D(P, Q)
    put(25, 8, -2.0 * D[0][1])
    put(26, 8, -2.0 * D[1][2])  # 2 D(P, T)
    put(27, 5, -2.0 * D[1][2])  # 2 D(Q, T)
    put(27, 6, 2.0 * D[0][2])
    for col, x in ((6, D[2][2] - D[0][0]), (4, -D[1][1]), (5, 2.0 * D[0][1])):
        put(28, col, x)  # D(T, T) - D(Q, Q)
    for row, i in ((_Y2.start, 2), (_Y0.start, 0), (_Y1.start, 1)):  # (k0 + d k1, r k0, r k2)
        put(row, 0, k[0][i])
        put(row, 1, k[1][i])
        put(row + 1, 2, k[0][i])
        put(row + 2, 2, k[2][i])
    (g0x, g0y), (g1x, g1y) = (KR[6][0], KR[7][0]), (KR[6][1], KR[7][1])
    G11 = (g1x * g1x, g1x * g1y, g1y * g1y)
    G01 = (2.0 * g0x * g1x, g0x * g1y + g1x * g0y, 2.0 * g0y * g1y)
    for n in range(3):  # (q00, q01, q11) = W3 d^2 + G11 (1 - r^2 - d^2) - G01 d
        put(_Q.start + n, 0, G11[n])
        put(_Q.start + n, 1, -G01[n])
        put(_Q.start + n, 3, omega[n] - G11[n])
        put(_Q.start + n, 4, -G11[n])
    return index, value


#: Flat indices of the entries of _sparse_entries in the (_N_POLY, _N_MONO) matrix.
_SPARSE_INDEX = np.array([row * _N_MONO + col for row, col in _sparse_entries([[0.0] * 3] * 9, (0.0,) * 5)[0]])


class _CoefficientTable:
    """Camera constants (as CircleTrack's) and the per-track coefficient table of one camera at (R, d, r)."""

    def __init__(self, K: np.ndarray):
        self.det_K = float(np.linalg.det(K))
        self.K_inv = np.linalg.inv(K)
        self.KK = np.vstack([K, self.det_K * self.K_inv.T, self.K_inv.T])
        omega = self.K_inv.T @ self.K_inv
        self.omega = tuple(float(omega[i, j]) for i, j in ((0, 0), (0, 1), (1, 1), (0, 2), (1, 2)))
        self._key, self._poly = None, None
        self._template = np.zeros((_N_POLY, _N_MONO))
        self._template[_KAPPA, 10] = self.det_K
        self._template[_D, 1] = self._template[_R, 2] = 1.0
        self._template[_DDRR, [3, 4]] = 1.0
        self._template[_OPDR, [0, 3, 4]] = 1.0

    def polynomials(self, R: np.ndarray) -> np.ndarray:
        """The (``_N_POLY``, ``_N_MONO``) matrix that maps the monomials of (d, r) (see :meth:`coefficients`) to
        the coefficient table at the line variable R (cached for the last R).

        CircleTrack's ``_coefficients``, organised by vectors: with ``k_i``, ``h_i`` the columns of ``K R`` and
        ``cof(K) R``, the homogeneous curve point is ``y = A + B s + E c`` with ``A = k0 + d k1``, ``B = r k0``,
        ``E = r k2``, and its tangent line is ``side`` times ``z = P + Q s + T c`` with ``P = -r^2 h1``,
        ``Q = -r h1 + r d h0``, ``T = r d h2``. CircleTrack's ``F = z1 (y0 - u_x y2) - z0 (y1 - u_y y2)`` sums the
        bilinear ``w(u, v) = (u1 v0 - u0 v1, -u1 v2, u0 v2) . (1, u_x, u_y)`` over products of a ``z`` and a ``y``
        term; on the basis ``(1, s, c, s c, c^2)`` (``s^2 = 1 - c^2``) its coefficients ``g_k = f_k + u_x x_k +
        u_y y_k`` are, with ``w_ij = w(h_i, k_j)`` and all times ``side``:

        - ``g0 = W(P, A) + W(Q, B) = r^2 (-2 w10) + r^2 d (w00 - w11)``
        - ``g1 = W(P, B) + W(Q, A) = r (-w10) + r d (w00 - w11) + r d^2 w01 + r^3 (-w10)``
        - ``g2 = W(P, E) + W(T, A) = r d w20 + r d^2 w21 + r^3 (-w12)``
        - ``g3 = W(Q, E) + W(T, B) = r^2 (-w12) + r^2 d (w02 + w20)``
        - ``g4 = W(T, E) - W(Q, B) = r^2 w10 + r^2 d (w22 - w00)``

        ``F'`` and ``F''/2`` are fixed combinations of the same ``g_k`` (see ``CoaxialTracks._halley``). The residual's
        numerator is ``l = lA + lB s + lC c`` with ``lA = (P2, P0, P1) . (1, u_x, u_y)`` (lB, lC from Q, T), and
        ``|z[:2]|^2`` on the basis is ``(D(P, P) + D(Q, Q), 2 D(P, Q), 2 D(P, T), 2 D(Q, T), D(T, T) - D(Q, Q))``
        with the 2-D dot products ``D`` (``side^2 = 1``). The image conic's ``(q00, q01, q11)`` (CircleTrack's
        ``_Ellipse``) are linear in ``(d^2, 1 - r^2 - d^2, d)``.
        """
        key = R.tobytes()
        if self._key == key:
            return self._poly
        KR = self.KK @ R
        k, h = KR[0:3], KR[3:6]
        # w[3 i + j] = w(h_i, k_j)
        w = np.empty((9, 3))
        w[:, 0] = (np.multiply.outer(h[1], k[0]) - np.multiply.outer(h[0], k[1])).ravel()
        w[:, 1] = -np.multiply.outer(h[1], k[2]).ravel()
        w[:, 2] = np.multiply.outer(h[0], k[2]).ravel()
        A = self._template.copy()
        # g triples on the side monomials (r, r d, r d^2, r^2, r^2 d, r^3) (columns 10..15)
        A[0:15, 10:16] = (_G_TERMS_2D @ w).reshape(5, 6, 3).transpose(0, 2, 1).reshape(15, 6)
        _, values = _sparse_entries(KR.tolist(), self.omega)
        A.flat[_SPARSE_INDEX] = values
        self._key, self._poly = key, A
        return A

    def coefficients(self, R: np.ndarray, d: np.ndarray, r: np.ndarray) -> np.ndarray:
        """The (``_N_COEFFICIENTS``, m) table of per-track coefficients (rows named by the module's constants):
        :meth:`polynomials` times the monomials ``(1, d, r, d^2, r^2, r^2 d, r^2 d^2, r^3, r^3 d, r^4)`` and
        ``side (r, r d, r d^2, r^2, r^2 d, r^3)``, ``side = sign(det(K) d a2)`` (CircleTrack's), and the cheap
        certificate's threshold ``-rho_min`` (``+inf`` for a track whose image conic is not a usable ellipse)."""
        A = self.polynomials(R)
        m = len(d)
        M = np.empty((_N_MONO, m))
        M[0] = 1.0
        M[1] = d
        M[2] = r
        dd = M[3] = d * d
        rr = M[4] = r * r
        rrd = M[5] = rr * d
        M[6] = rrd * d
        rrr = M[7] = rr * r
        M[8] = rrr * d
        M[9] = rr * rr
        a2 = A[_Y2.start, 0] + A[_Y2.start, 1] * d
        side = (self.det_K * d * a2 < 0.0).astype(float)
        side *= -2.0
        side += 1.0
        M[10:16] = M[(2, 1, 3, 4, 5, 7), :]
        M[11] *= r
        M[12] *= r
        M[10:16] *= side
        out = np.empty((_N_COEFFICIENTS, m))
        out[:_N_POLY] = A @ M
        # the image conic (CircleTrack's _Ellipse): validity and the smallest radius of curvature b^2 / a
        q00, q01, q11 = out[_Q]
        det_q2 = q00 * q11 - q01 * q01
        mean = 0.5 * (q00 + q11)
        half = np.hypot(0.5 * (q00 - q11), q01)
        lam_small = mean - half
        with np.errstate(divide="ignore", invalid="ignore"):
            rho_min = np.sqrt(dd * dd * rr * lam_small / (self.det_K**2 * det_q2)) / (mean + half)
        valid = (det_q2 > 0.0) & (mean > 0.0) & (lam_small > 0.0) & (r != 0.0) & (d != 0.0)
        valid &= out[_Y2.start] > np.hypot(out[_Y2.start + 1], out[_Y2.start + 2])
        # every pixel of an invalid track fails the cheap certificate (and goes to CircleTrack's own search)
        threshold = out[_THRESHOLD]
        np.multiply(rho_min, -_RHO_MARGIN, out=threshold)
        threshold[~valid] = np.inf
        out[_SIDE] = side
        return out

    def frames(self, R: np.ndarray, d: np.ndarray, r: np.ndarray):
        """Centre and minor-axis direction of each track's image ellipse (CircleTrack's ``_Ellipse.frame``)."""
        m = (self.KK @ R).tolist()
        (g0x, g0y, g0z), (g1x, g1y, g1z) = (m[6][0], m[7][0], m[8][0]), (m[6][1], m[7][1], m[8][1])
        w00, w01, w11, w02, w12 = self.omega
        dd = d * d
        alpha = 1.0 - r * r - dd
        q00 = dd * w00 + alpha * g1x * g1x - 2.0 * d * g0x * g1x
        q01 = dd * w01 + alpha * g1x * g1y - d * (g0x * g1y + g1x * g0y)
        q11 = dd * w11 + alpha * g1y * g1y - 2.0 * d * g0y * g1y
        q02 = dd * w02 + alpha * g1x * g1z - d * (g0x * g1z + g1x * g0z)
        q12 = dd * w12 + alpha * g1y * g1z - d * (g0y * g1z + g1y * g0z)
        det_q2 = q00 * q11 - q01 * q01
        with np.errstate(divide="ignore", invalid="ignore"):
            xc = -(q11 * q02 - q01 * q12) / det_q2
            yc = -(q00 * q12 - q01 * q02) / det_q2
        theta = 0.5 * np.arctan2(2.0 * q01, q00 - q11)
        return xc, yc, np.cos(theta), np.sin(theta)

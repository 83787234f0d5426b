"""All tracks of one measurement at once, and a variable-projection factor on the measurement's line variable.

:class:`CoaxialTracks` evaluates the circle-point maths of :class:`.circle_track.CircleTrack` (closest phases,
residuals, Jacobians; see the module docstring of :mod:`.circle_track`) for every track of a measurement
in one go: the per-track coefficients are one small matrix product of monomials of the (m,) arrays ``d``, ``r``
(see :meth:`CoaxialTracks._polynomials`), the pixels sit in a padded (rows, L) layout (a track fills one or more
rows of L points; see :func:`_layout`), and the warm-started Halley iterations, the certificates and the Jacobians
are whole-array operations. Pixels whose closest phase neither the cheap nor the exact certificate of CircleTrack
certifies go through CircleTrack's stage 1 (coarse grid, safeguarded Newton), vectorised too, and the few still
uncertified through CircleTrack's own later stages, track by track. The results are those of
``CircleTrack.evaluate`` (the certified closest phase is unique, so they do not depend on the start), to ~1e-14 px
and, because the phases get their last Newton step, with Jacobians exact to ~tol^2 (CircleTrack's to ~tol).

:meth:`CoaxialTracks.solve_circles` projects the circles out: for a fixed line variable ``R``, each track's
``(d, r)`` minimising its sum of squared residuals, by Gauss-Newton vectorised across tracks (per-track 2x2
normal equations via per-row sums, closed-form solves), with a per-track secant estimate of the curvature term that
Gauss-Newton drops (Dennis-Gay-Welsch), per-track step halving, and only the still-moving tracks evaluated once most
have converged.

:func:`make_coaxial_line_factor` builds ONE ``gtsam.CustomFactor`` per measurement on the line variable only. Its
residual is ``e(R, c*(R)) / sigma`` (all tracks, at the projected-out circles), its Jacobian the
variable-projection (Golub-Pereyra; Kaufman's Gauss-Newton form) Jacobian ``P_j H_R,j`` per track with
``P_j = I - H_c,j (H_c,j^T H_c,j)^-1 H_c,j^T`` (applied per track through its 2x3 ``(H_c^T H_c)^-1 H_c^T H_R``, no
N x N matrix). Its ``J^T J`` is the Schur complement (circles eliminated) of the Gauss-Newton Hessian of the full
graph (line + one ``(d, r)`` variable and one circle-point factor per track) linearised at ``(R, c*(R))``, and its
gradient ``J^T e = H_R^T e`` (because ``H_c^T e = 0`` at ``c*``) that of the full graph. So LM on a graph of these
factors follows the full graph's reduced problem, and ``gtsam.Marginals`` gives the same line (and pose) marginals,
with one variable per measurement instead of ~60. Each call at a new line solves the circles there, starting from
an anchor's solution (the latest linearisation point's, for LM's trial steps) moved by its Gauss-Newton change
``dc*/dw w``; never from a trial line's, so that the factor's value at a line does not depend on the lines evaluated
before (see :meth:`CoaxialLineFactor._anchor`).

Caveat: ``P H_R`` is the exact derivative of ``e(R, c*(R))`` only at zero residual. In general the exact derivative
is ``H_R + H_c dc*/dR`` with the exact ``dc*/dR``, which differs from Gauss-Newton's
``-(H_c^T H_c)^-1 H_c^T H_R`` by the residual-weighted second derivatives (Kaufman drops them, and so does
Gauss-Newton on the full graph). With the free closest phase per pixel these are not small: on the reference scene
``dc*/dR`` differs from Gauss-Newton's by a factor ~2 along two of the three line directions, and ``P H_R`` from
the exact Jacobian by ~4 % (its ``J^T J`` by ~2e-4).

Caveat (damping): LM's diagonal (scale-invariant) damping of a graph of these factors damps the reduced problem,
not the circles. On the full graph, the circles' damping also holds back the line steps that move the circles
far (``M^T D_c M`` is added to the line's damping); here, a line's weakly determined direction (its tilt within
the projection plane, which the projected-axis tie leaves free) gets only its own small diagonal. From a pose ~1 deg
off (the noise-free 5-measurement scene of ``tests/test_graph.py``), LM with diagonal damping then takes steps of
~0.1-0.3 rad along it, some circles move far along the axis (to larger, farther circles that fit better at a wrong
line), and LM crawls or stops at such a point; with isotropic damping it converges to the truth in ~16 iterations.
From poorer starts (stage 1 from a pose ~8 deg off) LM tries line steps of ~1 rad: the factor refuses trial lines
further than ``TRUST_RAD`` from its anchors (a trust region, see :meth:`CoaxialLineFactor._refused`).
"""

from __future__ import annotations

import math
from collections import OrderedDict

import gtsam
import numpy as np

from .circle_track import COLD_GRID_SIZE, CircleTrack, _phase_grid
from .ellipse import _RHO_MARGIN
from .geometry import _matrix

__all__ = ["CoaxialLineFactor", "CoaxialTracks", "make_coaxial_line_factor"]

#: Cost of one row of the padded layout, in padded points (the per-row coefficient gathers and batched products).
ROW_COST = 16
#: Halving steps of :meth:`CoaxialTracks.solve_circles` before a track's step is given up (it keeps its value).
MAX_HALVINGS = 30
#: The circle solve evaluates only the tracks still moving once their rows are at most this fraction of all rows.
SUBSET_FRACTION = 0.7
#: Relative Gauss-Newton decrement (predicted decrease of a track's sum of squares over that sum) below which a
#: track's circle counts as converged.
CIRCLE_TOL = 1e-10
#: Absolute floor of that decrement per pixel (px^2): noise-free tracks converge to ~1e-10 px.
CIRCLE_ATOL_PX2 = 1e-20
#: A line variable further than this (rad) from its anchor (see :meth:`CoaxialLineFactor._anchor`) starts its
#: circles from the anchor's without the first-order prediction ``c + dc*/dw w``.
PREDICT_MAX_RAD = 0.2
#: Linearisation states kept as anchors (the only starts of the circle solves, with the first state solved).
PINNED_STATES = 2
#: Trust region of LM's trial steps (rad): GTSAM's error (no Jacobians) at a line further than this from every
#: anchor (and not cached) is refused, see :meth:`CoaxialLineFactor._refused`.
TRUST_RAD = 0.1
#: Whitened residual of every point at a refused line.
REFUSED_RESIDUAL = 1e8

# (n, a_max(n)): Taylor terms of sin / cos that are exact to ~1e-17 for |x| <= a_max(n) (first omitted term
# x^(2n+2) / (2n+2)!), and the Horner factors 1 / ((2k)(2k+1)) and 1 / ((2k-1)(2k)).
_TAYLOR = [(n, (1e-17 * math.factorial(2 * n + 2)) ** (1.0 / (2 * n + 2))) for n in range(1, 9)]
_SIN_F = [1.0 / ((2 * k) * (2 * k + 1)) for k in range(1, 10)]
_COS_F = [1.0 / ((2 * k - 1) * (2 * k)) for k in range(1, 10)]
#: Largest step rotated with the Taylor series (else np.sin / np.cos of the step).
_TAYLOR_MAX = 0.35

# Rows of the per-track coefficient table of :meth:`CoaxialTracks._coefficients` (each an (m,) array).
_C8 = slice(0, 24)  # (g0..g4, lA, lB, lC) x (1, u_x, u_y): see CoaxialTracks._polynomials
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
#: 3 i + j), see CoaxialTracks._polynomials.
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
    """(row, column) and value of the entries of :meth:`CoaxialTracks._polynomials` other than the g triples, from
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


def _rotate(s: np.ndarray, c: np.ndarray, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(sin, cos)(phi - x)`` from ``(s, c) = (sin, cos)(phi)``: a short Taylor series of ``x`` where every
    ``|x|`` is small (exact to ~1e-17, far cheaper than np.sin), else np.sin and np.cos of ``x``."""
    a = max(float(x.max()), -float(x.min())) if x.size else 0.0
    if a <= _TAYLOR_MAX:
        n = next(n for n, a_max in _TAYLOR if a <= a_max)
        x2 = x * x
        sin_f = 1.0 - x2 * _SIN_F[n - 1]
        cos_f = 1.0 - x2 * _COS_F[n - 1]
        for k in range(n - 2, -1, -1):
            sin_f *= x2
            sin_f *= -_SIN_F[k]
            sin_f += 1.0
            cos_f *= x2
            cos_f *= -_COS_F[k]
            cos_f += 1.0
        sin_x = sin_f
        sin_x *= x
        cos_x = cos_f
    else:
        sin_x, cos_x = np.sin(x), np.cos(x)
    return s * cos_x - c * sin_x, c * cos_x + s * sin_x


def _layout(counts: np.ndarray, row_length: int | None) -> int:
    """Row length L of the padded layout: a track of n points fills ceil(n / L) rows; L minimises the padded size
    plus ``ROW_COST`` per row."""
    nonzero = counts[counts > 0]
    if row_length is not None:
        return max(1, int(row_length))
    if len(nonzero) == 0:
        return 1
    longest = int(nonzero.max())
    candidates = np.union1d(np.arange(1, min(longest, 1024) + 1), nonzero)
    rows = -(-nonzero[None, :] // candidates[:, None])  # ceil
    cost = (rows * candidates[:, None]).sum(axis=1) + ROW_COST * rows.sum(axis=1)
    return int(candidates[np.argmin(cost)])


def _inverse2(a: np.ndarray, b: np.ndarray, c: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Entries (a', b', c') of the inverse of the symmetric 2x2 matrices [[a, b], [b, c]] (m,), with a relative ridge
    of 1e-14 so that a singular (indeterminate) circle gets a finite, minimal-norm-like answer; zero matrices give
    zeros."""
    ridge = 1e-14 * (a + c)
    a, c = a + ridge, c + ridge
    det = a * c - b * b
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = np.where(det > 0.0, 1.0 / det, 0.0)
    return c * inv, -b * inv, a * inv


class _Layout:
    """Pixels of whole tracks in the padded (rows, L) layout: a track fills ceil(N_j / L) consecutive rows; padding
    entries repeat the track's first pixel (so they converge with it) and are left out of every output."""

    __slots__ = ("L", "row_track", "local", "valid", "dense", "flat_index", "pad", "pad_src", "px", "py", "P3")

    def __init__(self, L: int, row_track: np.ndarray, local: np.ndarray, valid: np.ndarray, px: np.ndarray,
                 py: np.ndarray):
        self.L = L
        self.row_track = row_track  # (rows,) track of each row
        self.local = local  # (rows, L) index of each entry in its track
        self.valid = valid  # (rows, L) False for padding
        self.dense = bool(valid.all())
        self.flat_index = np.flatnonzero(valid)
        self.pad = np.flatnonzero(~valid)
        if len(self.pad):
            starts = np.flatnonzero(np.diff(row_track, prepend=-1))  # first row of each track
            first = starts[np.searchsorted(starts, np.arange(len(row_track)), side="right") - 1]
            self.pad_src = first[self.pad // L] * L
        else:
            self.pad_src = self.pad
        self.px, self.py = px, py
        self.P3 = np.stack([np.ones_like(px), px, py], axis=1)  # (rows, 3, L)

    def subset(self, sel: np.ndarray) -> _Layout:
        """The layout of the rows ``sel`` (all rows of some tracks)."""
        return _Layout(self.L, self.row_track[sel], self.local[sel], self.valid[sel], self.px[sel], self.py[sel])

    def sync_padding(self, s: np.ndarray, c: np.ndarray) -> None:
        if len(self.pad):
            s.ravel()[self.pad] = s.ravel()[self.pad_src]
            c.ravel()[self.pad] = c.ravel()[self.pad_src]


class _Eval:
    """One evaluation of all tracks at (R, d, r) in the padded layout (padding entries are zero in V and f)."""

    __slots__ = ("key", "R", "d", "r", "s", "c", "V", "f", "rows", "has_line_jacobian")

    def __init__(self, key, R, d, r, s, c, V, f, rows):
        self.key = key
        self.R = R
        self.d = d  # (m,) the circles each track was evaluated at
        self.r = r
        self.s = s  # (rows, L) sin, cos of the closest phases
        self.c = c
        self.V = V  # (6, rows, L): e, de/dd, de/dr, de/dw0, de/dw1, de/dw2 (only the first 3 until completed)
        self.f = f  # (rows, L) kappa / (|z[:2]| y2): the Jacobians' common factor (zero at padding)
        self.rows = rows  # (N_COEFFICIENTS, rows) per-row coefficients
        self.has_line_jacobian = False


class CoaxialTracks:
    """Closest phases, residuals and Jacobians of all tracks of one measurement against coaxial circles.

    The same maths and results as one :class:`.circle_track.CircleTrack` per track, vectorised across the tracks, and
    warm-started: the phases of the last call start the next call's Halley iterations. Pixels whose phase the
    cheap or the exact certificate does not certify go through CircleTrack's stage 1 (the nearest of
    ``COLD_GRID_SIZE`` phases, safeguarded Newton), vectorised too, and the few still uncertified through
    CircleTrack's own later stages, track by track.

    Args:
        K: (3, 3) intrinsic matrix.
        tracks: list of (N_j, 2) ideal (undistorted) pixels, one per track (may be empty).
        tol: convergence tolerance of the phase (rad), as CircleTrack's; the phases are corrected by the last
            Newton step, so the residuals and Jacobians are exact to ~``tol^2``.
        warm_steps, cold_steps: Halley iterations from the warm start and from the cold (ray-plane) start, and
            safeguarded Newton iterations of stage 1.
        row_length: points per row of the padded layout (default: chosen by :func:`_layout`).

    Attributes:
        counts: (m,) points per track; offsets: (m + 1,) start of each track in the concatenated arrays;
        track_index: (N,) track of each point.
        calls, restarted_points, fallback_points: diagnostics (evaluations, pixels that went through stage 1, and
        through CircleTrack's own later stages).
    """

    def __init__(self, K, tracks, *, tol: float = 1e-8, warm_steps: int = 6, cold_steps: int = 10,
                 row_length: int | None = None):
        K = np.array(K, dtype=float).reshape(3, 3)
        pixels = [np.array(p, dtype=float).reshape(-1, 2) for p in tracks]
        self.K = K
        self.pixels = pixels
        m = len(pixels)
        counts = np.array([len(p) for p in pixels], dtype=np.int64)
        self.counts = counts
        self.offsets = np.concatenate([[0], np.cumsum(counts)]).astype(np.int64)
        self.n_points = int(self.offsets[-1])
        self.track_index = np.repeat(np.arange(m), counts)
        self.tol = float(tol)
        self.warm_steps = max(1, int(warm_steps))
        self.cold_steps = max(1, int(cold_steps))
        # camera constants, as CircleTrack's
        self._det_K = float(np.linalg.det(K))
        self._K_inv = np.linalg.inv(K)
        self._KK = np.vstack([K, self._det_K * self._K_inv.T, self._K_inv.T])
        omega = self._K_inv.T @ self._K_inv
        self._omega = tuple(float(omega[i, j]) for i, j in ((0, 0), (0, 1), (1, 1), (0, 2), (1, 2)))
        # padded layout
        L = _layout(counts, row_length)
        n_rows = -(-counts // L)
        self.row_length = L
        row_track = np.repeat(np.arange(m), n_rows)
        first_row = np.concatenate([[0], np.cumsum(n_rows)[:-1]]).astype(np.int64)
        local = ((np.arange(len(row_track)) - first_row[row_track]) * L)[:, None] + np.arange(L)[None, :]
        valid = local < counts[row_track][:, None]
        source = self.offsets[row_track][:, None] + np.where(valid, local, 0)
        all_pixels = np.vstack(pixels) if self.n_points else np.zeros((1, 2))
        self._layout = _Layout(L, row_track, local, valid, all_pixels[source, 0], all_pixels[source, 1])
        self._nonempty = np.flatnonzero(n_rows > 0)
        self._first_rows = first_row[self._nonempty]
        self._circle_tracks: dict[int, CircleTrack] = {}
        self._poly_key, self._poly = None, None
        self._poly_template = np.zeros((_N_POLY, _N_MONO))
        self._poly_template[_KAPPA, 10] = self._det_K
        self._poly_template[_D, 1] = self._poly_template[_R, 2] = 1.0
        self._poly_template[_DDRR, [3, 4]] = 1.0
        self._poly_template[_OPDR, [0, 3, 4]] = 1.0
        self._s = None  # warm start: (rows, L) sin, cos of the last phases
        self._c = None
        self._last: _Eval | None = None
        self._solution = None  # (d, r) of the last solve_circles
        self._curvature = np.zeros((3, m))  # per-track secant curvature terms of the circle solve (dd, dr, rr)
        self.last_solve = None
        self.calls = 0
        self.restarted_points = 0
        self.fallback_points = 0

    def __len__(self) -> int:
        return self.n_points

    @property
    def n_tracks(self) -> int:
        return len(self.counts)

    def reset(self) -> None:
        """Forget the warm start (phases and the last solution)."""
        self._s = self._c = None
        self._last = None
        self._solution = None
        self._curvature[:] = 0.0

    # ------------------------------------------------------------------------------------------------------------
    # per-track coefficients (CircleTrack._coefficients with (m,) arrays)

    def _polynomials(self, R: np.ndarray) -> np.ndarray:
        """The (``_N_POLY``, ``_N_MONO``) matrix that maps the monomials of (d, r) (see :meth:`_coefficients`) to
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

        ``F'`` and ``F''/2`` are fixed combinations of the same ``g_k`` (see :meth:`_halley`). The residual's
        numerator is ``l = lA + lB s + lC c`` with ``lA = (P2, P0, P1) . (1, u_x, u_y)`` (lB, lC from Q, T), and
        ``|z[:2]|^2`` on the basis is ``(D(P, P) + D(Q, Q), 2 D(P, Q), 2 D(P, T), 2 D(Q, T), D(T, T) - D(Q, Q))``
        with the 2-D dot products ``D`` (``side^2 = 1``). The image conic's ``(q00, q01, q11)`` (CircleTrack's
        ``_Ellipse``) are linear in ``(d^2, 1 - r^2 - d^2, d)``.
        """
        key = R.tobytes()
        if self._poly_key == key:
            return self._poly
        KR = self._KK @ R
        k, h = KR[0:3], KR[3:6]
        # w[3 i + j] = w(h_i, k_j)
        w = np.empty((9, 3))
        w[:, 0] = (np.multiply.outer(h[1], k[0]) - np.multiply.outer(h[0], k[1])).ravel()
        w[:, 1] = -np.multiply.outer(h[1], k[2]).ravel()
        w[:, 2] = np.multiply.outer(h[0], k[2]).ravel()
        A = self._poly_template.copy()
        # g triples on the side monomials (r, r d, r d^2, r^2, r^2 d, r^3) (columns 10..15)
        A[0:15, 10:16] = (_G_TERMS_2D @ w).reshape(5, 6, 3).transpose(0, 2, 1).reshape(15, 6)
        _, values = _sparse_entries(KR.tolist(), self._omega)
        A.flat[_SPARSE_INDEX] = values
        self._poly_key, self._poly = key, A
        return A

    def _coefficients(self, R: np.ndarray, d: np.ndarray, r: np.ndarray) -> np.ndarray:
        """The (``_N_COEFFICIENTS``, m) table of per-track coefficients (rows named by the module's constants):
        :meth:`_polynomials` times the monomials ``(1, d, r, d^2, r^2, r^2 d, r^2 d^2, r^3, r^3 d, r^4)`` and
        ``side (r, r d, r d^2, r^2, r^2 d, r^3)``, ``side = sign(det(K) d a2)`` (CircleTrack's), and the cheap
        certificate's threshold ``-rho_min`` (``+inf`` for a track whose image conic is not a usable ellipse)."""
        A = self._polynomials(R)
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
        side = (self._det_K * d * a2 < 0.0).astype(float)
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
            rho_min = np.sqrt(dd * dd * rr * lam_small / (self._det_K**2 * det_q2)) / (mean + half)
        valid = (det_q2 > 0.0) & (mean > 0.0) & (lam_small > 0.0) & (r != 0.0) & (d != 0.0)
        valid &= out[_Y2.start] > np.hypot(out[_Y2.start + 1], out[_Y2.start + 2])
        # every pixel of an invalid track fails the cheap certificate (and goes to CircleTrack's own search)
        threshold = out[_THRESHOLD]
        np.multiply(rho_min, -_RHO_MARGIN, out=threshold)
        threshold[~valid] = np.inf
        out[_SIDE] = side
        return out

    def _frames(self, R: np.ndarray, d: np.ndarray, r: np.ndarray):
        """Centre and minor-axis direction of each track's image ellipse (CircleTrack's ``_Ellipse.frame``)."""
        m = (self._KK @ R).tolist()
        (g0x, g0y, g0z), (g1x, g1y, g1z) = (m[6][0], m[7][0], m[8][0]), (m[6][1], m[7][1], m[8][1])
        w00, w01, w11, w02, w12 = self._omega
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

    # ------------------------------------------------------------------------------------------------------------
    # closest phases

    def _halley(self, G: np.ndarray, s: np.ndarray, c: np.ndarray, steps: int):
        """Halley's iterations on CircleTrack's ``F`` from (s, c), then the last Newton step applied.

        ``F = g0 + g1 s + g2 c + g3 s c + g4 c^2``, ``F' = -g3 - g2 s + g1 c - 2 g4 s c + 2 g3 c^2``,
        ``F''/2 = g4 - (g1 s + g2 c) / 2 - 2 (g3 s c + g4 c^2)``.

        Returns (s, c, mask of the points whose last step exceeds tol, or None).
        """
        if s.size == 0:
            return s, c, None
        g0, g1, g2, g3, g4 = G[0], G[1], G[2], G[3], G[4]
        tol = self.tol
        with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
            for i in range(steps):
                sc = s * c
                cc = c * c
                F = g0 + g1 * s
                F += g2 * c
                F += g3 * sc
                F += g4 * cc
                dF = g1 * c - g2 * s
                dF -= g3
                dF += 2.0 * (g3 * cc - g4 * sc)
                delta = F / dF
                # (no BLAS dot here: OpenBLAS threads a long dot, which is slow on a busy machine; NaN -> False)
                converged = float(delta.max()) <= tol and float(delta.min()) >= -tol
                if converged:
                    # the last Newton step, |delta| <= tol: first order is exact to ~tol^2
                    return s - c * delta, c + s * delta, None
                if i == steps - 1:
                    s, c = _rotate(s, c, delta)
                    return s, c, ~(np.abs(delta) <= tol)
                half_ddF = g4 - 0.5 * (g1 * s + g2 * c)
                half_ddF -= 2.0 * (g3 * sc + g4 * cc)
                step = delta / (1.0 - delta * half_ddF / dF)
                s, c = _rotate(s, c, step)
        raise AssertionError("unreachable")

    def _cold_start(self, R: np.ndarray, rows: np.ndarray, lay: _Layout) -> tuple[np.ndarray, np.ndarray]:
        """Phases where each pixel's ray meets its circle's plane ``v1 = d`` (exact for pixels on the curve)."""
        G = R.T @ self._K_inv
        px, py = lay.px, lay.py
        rho0 = G[0, 0] * px + G[0, 1] * py + G[0, 2]
        rho1 = G[1, 0] * px + G[1, 1] * py + G[1, 2]
        rho2 = G[2, 0] * px + G[2, 1] * py + G[2, 2]
        d, r = rows[_D][:, None], rows[_R][:, None]
        with np.errstate(divide="ignore", invalid="ignore"):
            t = d / rho1
            x = (t * rho0 - 1.0) * r  # (v0 - 1) r = r^2 sin(phi)
            y = (t * rho2) * r  # v2 r = r^2 cos(phi)
            h = np.hypot(x, y)
            return x / h, y / h

    def _final(self, G, rows, s, c, V, lay: _Layout) -> np.ndarray:
        """Residuals (px) and Jacobians wrt (d, r) into V[0:3] at the phases (s, c), padding entries zeroed; returns
        the Jacobians' common factor ``kappa / (|z[:2]| y2)``."""
        sc = s * c
        cc = c * c
        Z = rows[_Z]
        z2 = Z[0][:, None] + Z[1][:, None] * s
        z2 += Z[2][:, None] * c
        z2 += Z[3][:, None] * sc
        z2 += Z[4][:, None] * cc
        Y2 = rows[_Y2]
        y2 = Y2[0][:, None] + Y2[1][:, None] * s
        y2 += Y2[2][:, None] * c
        with np.errstate(divide="ignore", invalid="ignore"):
            sq = np.sqrt(z2)
            l = G[5] + G[6] * s
            l += G[7] * c
            np.divide(l, sq, out=V[0])
            f = rows[_KAPPA][:, None] / (sq * y2)
        if not lay.dense:
            f.ravel()[lay.pad] = 0.0
            V[0].ravel()[lay.pad] = 0.0
        np.multiply(f, rows[_R][:, None] + s, out=V[1])
        np.multiply(f, -rows[_D][:, None], out=V[2])
        return f

    def _line_jacobian(self, ev: _Eval) -> None:
        """Jacobians wrt the Rot3 tangent into V[3:6] (CircleTrack's rows 2-4 times kappa / (|z[:2]| y2))."""
        if ev.has_line_jacobian:
            return
        s, c, rows, V, f = ev.s, ev.c, ev.rows, ev.V, ev.f
        r = rows[_R][:, None]
        fc = f * c
        np.multiply(fc, -(rows[_DDRR][:, None] + r * s), out=V[3])
        np.multiply(fc, rows[_D][:, None], out=V[4])
        np.multiply(f, 2.0 * r + rows[_OPDR][:, None] * s - r * (c * c), out=V[5])
        ev.has_line_jacobian = True

    def _same_quadrant(self, R, d, r, rows, lay: _Layout, idx, si, ci) -> np.ndarray:
        """Exact certificate of the pixels ``idx`` (flat indices into ``lay``) at the phases (si, ci): a valid image
        ellipse, and the curve point in the pixel's open quadrant of its axes (CircleTrack's ``_Ellipse``)."""
        row = idx // lay.L
        track = lay.row_track[row]
        xc, yc, cos_t, sin_t = (a[track] for a in self._frames(R, d, r))
        Y0, Y1, Y2 = rows[_Y0][:, row], rows[_Y1][:, row], rows[_Y2][:, row]
        y0 = Y0[0] + Y0[1] * si + Y0[2] * ci
        y1 = Y1[0] + Y1[1] * si + Y1[2] * ci
        y2 = Y2[0] + Y2[1] * si + Y2[2] * ci
        dx, dy = lay.px.ravel()[idx] - xc, lay.py.ravel()[idx] - yc
        qx, qy = y0 - xc * y2, y1 - yc * y2
        with np.errstate(invalid="ignore"):
            along = (dx * cos_t + dy * sin_t) * (qx * cos_t + qy * sin_t)
            across = (dy * cos_t - dx * sin_t) * (qy * cos_t - qx * sin_t)
            return (along > 0.0) & (across > 0.0) & np.isfinite(rows[_THRESHOLD, row])

    def _certify(self, R, d, r, rows, s, c, e, bad, lay: _Layout) -> np.ndarray:
        """Flat indices (into ``lay``) of the real pixels whose phase is not certified: cheap certificate (converged,
        and outside the curve or inside by less than b^2 / a), then the exact one."""
        with np.errstate(invalid="ignore"):
            fails = ~(e > rows[_THRESHOLD][:, None])
        if bad is not None:
            fails |= bad
        if not lay.dense:
            fails.ravel()[lay.pad] = False
        idx = np.flatnonzero(fails)
        if len(idx) == 0:
            return idx
        ok = self._same_quadrant(R, d, r, rows, lay, idx, s.ravel()[idx], c.ravel()[idx])
        if bad is not None:
            ok &= ~bad.ravel()[idx]
        return idx[~ok]

    def _restart(self, R, d, r, rows, G, s, c, todo, lay: _Layout) -> np.ndarray:
        """CircleTrack's stage 1 for the pixels ``todo`` of tracks with a valid image ellipse, vectorised: the
        nearest of ``COLD_GRID_SIZE`` phases, then safeguarded Newton on ``y2^3 f'`` (Gauss-Newton
        ``|z[:2]|^2 / y2`` where ``F'`` is not safely positive; steps clamped to one grid cell). Writes the phases
        into (s, c); returns the pixels still not certified."""
        n = len(todo)
        if n == 0:  # every pixel left belongs to a track without a valid image ellipse
            return todo
        row = todo // lay.L
        self.restarted_points += n
        grid, basis = _phase_grid(COLD_GRID_SIZE)
        Y = [rows[part][:, row] for part in (_Y0, _Y1, _Y2)]  # (3, n) each
        y0, y1, y2 = (np.einsum("kn,kg->ng", Yi, basis[:3]) for Yi in Y)
        dx = lay.px.ravel()[todo][:, None] - y0 / y2
        dy = lay.py.ravel()[todo][:, None] - y1 / y2
        nearest = np.argmin(dx * dx + dy * dy, axis=1)
        si, ci = basis[1, nearest], basis[2, nearest]
        g = G.reshape(8, -1)[:, todo]
        sign = -rows[_SIDE, row]  # F' > 0 at a minimum of the distance for sign * F
        Z, Y2 = rows[_Z][:, row], Y[2]
        max_step = 2.0 * np.pi / COLD_GRID_SIZE
        tol = self.tol
        with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
            for i in range(self.cold_steps):
                sc, cc = si * ci, ci * ci
                F = sign * (g[0] + g[1] * si + g[2] * ci + g[3] * sc + g[4] * cc)
                dF = sign * (g[1] * ci - g[2] * si - g[3] + 2.0 * (g[3] * cc - g[4] * sc))
                gn = (Z[0] + Z[1] * si + Z[2] * ci + Z[3] * sc + Z[4] * cc) / (Y2[0] + Y2[1] * si + Y2[2] * ci)
                step = np.clip(F / np.where(dF > 1e-3 * gn, dF, gn), -max_step, max_step)
                converged = float(step.max()) <= tol and float(step.min()) >= -tol
                si, ci = _rotate(si, ci, step)
                if converged or i == self.cold_steps - 1:
                    break
            bad = None if converged else ~(np.abs(step) <= tol)
            sc, cc = si * ci, ci * ci
            z2 = Z[0] + Z[1] * si + Z[2] * ci + Z[3] * sc + Z[4] * cc
            e = (g[5] + g[6] * si + g[7] * ci) / np.sqrt(z2)
            ok = e > rows[_THRESHOLD, row]
        if bad is not None:
            ok &= ~bad
        check = np.flatnonzero(~ok)
        if len(check):
            exact = self._same_quadrant(R, d, r, rows, lay, todo[check], si[check], ci[check])
            if bad is not None:
                exact &= ~bad[check]
            ok[check] = exact
        s.ravel()[todo], c.ravel()[todo] = si, ci
        return todo[~ok]

    def _fallback(self, R, d, r, s, c, todo, lay: _Layout) -> None:
        """CircleTrack's own search from stage 2 on (the bracketed search in the pixel's quadrant arc; the grid
        search for a conic that is not an ellipse) for the pixels ``todo``, track by track."""
        L = lay.L
        track = lay.row_track[todo // L]
        local = lay.local.ravel()[todo]
        bounds = np.flatnonzero(np.diff(track)) + 1
        s_flat, c_flat = s.ravel(), c.ravel()
        for part, part_local in zip(np.split(todo, bounds), np.split(local, bounds), strict=True):
            j = int(lay.row_track[part[0] // L])
            track_j = self._circle_tracks.get(j)
            if track_j is None:
                track_j = self._circle_tracks[j] = CircleTrack(self.K, self.pixels[j], warm_start=False)
            dj, rj = float(d[j]), float(r[j])
            setup = track_j._coefficients(R, dj, rj)
            stage = 2 if setup[3].valid else 3
            phi, _, _, _ = track_j._solve_points(R, dj, rj, setup, part_local, None, stage)
            pair = np.sin(phi)
            s_flat[part], c_flat[part] = pair[0], pair[1]
        self.fallback_points += len(todo)

    def _evaluate(self, R: np.ndarray, d: np.ndarray, r: np.ndarray, active: np.ndarray | None = None) -> _Eval:
        """All tracks at (R, d, r): the cached evaluation when the variables are those of the last call.

        With ``active`` (m,) only the active tracks are evaluated; the others keep the values of the last
        evaluation (which must be at the same R; their entries of d, r are then ignored).
        """
        base = self._last
        subset = active is not None and base is not None and np.array_equal(base.R, R)
        if subset:
            d = np.where(active, d, base.d)
            r = np.where(active, r, base.r)
        key = (R.tobytes(), d.tobytes(), r.tobytes())
        self.calls += 1
        if base is not None and base.key == key:
            return base
        table = self._coefficients(R, d, r)
        lay = self._layout
        sel = None
        if subset:
            sel = np.flatnonzero(active[lay.row_track])
            lay = lay.subset(sel)
        rows = table[:, lay.row_track]
        n_rows, L = lay.px.shape
        C8 = np.ascontiguousarray(rows[_C8].T).reshape(n_rows, 8, 3)
        G = np.ascontiguousarray(np.matmul(C8, lay.P3).transpose(1, 0, 2))  # (8, rows, L)
        if self._s is None:
            s, c = self._cold_start(R, rows, lay)
            steps = self.cold_steps
        else:
            s, c = (self._s, self._c) if sel is None else (self._s[sel], self._c[sel])
            steps = self.warm_steps
        s, c, bad = self._halley(G, s, c, steps)
        V = np.empty((6, n_rows, L))
        f = self._final(G, rows, s, c, V, lay)
        todo = self._certify(R, d, r, rows, s, c, V[0], bad, lay)
        if len(todo):
            valid = np.isfinite(rows[_THRESHOLD, todo // L])
            rest = np.concatenate([self._restart(R, d, r, rows, G, s, c, todo[valid], lay), todo[~valid]])
            if len(rest):
                self._fallback(R, d, r, s, c, np.sort(rest), lay)
            lay.sync_padding(s, c)
            f = self._final(G, rows, s, c, V, lay)
        if sel is not None:
            V_all, f_all, s_all, c_all, rows_all = base.V.copy(), base.f.copy(), base.s.copy(), base.c.copy(), \
                base.rows.copy()
            V_all[:3, sel], f_all[sel], s_all[sel], c_all[sel], rows_all[:, sel] = V[:3], f, s, c, rows
            V, f, s, c, rows = V_all, f_all, s_all, c_all, rows_all
        self._s, self._c = s, c
        ev = _Eval(key, R, d, r, s, c, V, f, rows)
        self._last = ev
        return ev

    # ------------------------------------------------------------------------------------------------------------
    # flat outputs and per-track sums

    def _flat(self, a: np.ndarray) -> np.ndarray:
        """Concatenated per-point values of a (rows, L) array (track by track, in point order)."""
        return a.ravel() if self._layout.dense else a.ravel().take(self._layout.flat_index)

    def _track_sums(self, per_row: np.ndarray) -> np.ndarray:
        """Per-track sums (m, ...) of per-row values (rows, ...)."""
        out = np.zeros((self.n_tracks,) + per_row.shape[1:])
        if len(self._nonempty):
            out[self._nonempty] = np.add.reduceat(per_row, self._first_rows, axis=0)
        return out

    def _gram(self, ev: _Eval, n: int, active: np.ndarray | None = None) -> np.ndarray:
        """Per-track sums (m, n, n) of the products of ev.V[:n] (e, H_d, H_r[, H_w]); with ``active`` only for the
        active tracks (zeros elsewhere)."""
        if n > 3:
            self._line_jacobian(ev)
        if active is None:
            V = ev.V[:n]
            return self._track_sums(np.einsum("irl,jrl->rij", V, V))
        row_track = self._layout.row_track
        sel = np.flatnonzero(active[row_track])
        V = ev.V[:n, sel]
        return self._subset_sums(np.einsum("irl,jrl->rij", V, V), row_track[sel])

    def _subset_sums(self, per_row: np.ndarray, tracks: np.ndarray) -> np.ndarray:
        """Per-track sums (m, ...) of per-row values of some tracks' rows (``tracks``: their tracks, grouped)."""
        out = np.zeros((self.n_tracks,) + per_row.shape[1:])
        if len(tracks):
            starts = np.flatnonzero(np.diff(tracks, prepend=-1))
            out[tracks[starts]] = np.add.reduceat(per_row, starts, axis=0)
        return out

    @staticmethod
    def _variables(R, d, r) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        return (np.ascontiguousarray(_matrix(R)), np.array(d, dtype=float).reshape(-1),
                np.array(r, dtype=float).reshape(-1))

    def evaluate(self, R, d, r, jacobians: bool = True):
        """Residuals e (N,) of all tracks (concatenated in order), and Jacobians H_R (N, 3) wrt the Rot3 tangent and
        H_dr (N, 2) wrt each point's own track's (d, r) (or None, None).

        Args:
            R: line variable (``gtsam.Rot3`` or 3x3).
            d, r: (m,) circle offsets and radii, one per track.
        """
        R, d, r = self._variables(R, d, r)
        if len(d) != self.n_tracks or len(r) != self.n_tracks:
            raise ValueError(f"need one (d, r) per track ({self.n_tracks}), got {len(d)} and {len(r)}")
        ev = self._evaluate(R, d, r)
        e = self._flat(ev.V[0])
        if not jacobians:
            return e, None, None
        self._line_jacobian(ev)
        H_R = np.column_stack([self._flat(ev.V[3]), self._flat(ev.V[4]), self._flat(ev.V[5])])
        H_dr = np.column_stack([self._flat(ev.V[1]), self._flat(ev.V[2])])
        return e, H_R, H_dr

    def phases(self, R, d, r) -> np.ndarray:
        """Closest phases (N,) in [-pi, pi] at the given variables."""
        ev = self._evaluate(*self._variables(R, d, r))
        return np.arctan2(self._flat(ev.s), self._flat(ev.c))

    def track_sums(self, values) -> np.ndarray:
        """Per-track sums (m,) of a per-point array (N,) in the concatenated order."""
        return np.bincount(self.track_index, weights=np.asarray(values, dtype=float), minlength=self.n_tracks)

    # ------------------------------------------------------------------------------------------------------------
    # variable projection of the circles

    def _solve(self, R: np.ndarray, d: np.ndarray, r: np.ndarray, tol: float = CIRCLE_TOL,
               max_evaluations: int = 60):
        """Every track's (d, r) minimising its sum of squares at fixed R, vectorised across tracks.

        Gauss-Newton steps augmented, per track, by a secant estimate ``S_j`` of the residuals' curvature term
        ``sum e d2e/dc2`` that Gauss-Newton drops (Dennis, Gay and Welsch's structured update, as NL2SOL's), kept
        from one solve to the next: the steps are then nearly Newton steps, where plain Gauss-Newton converges only
        linearly (slowly for an arc whose residuals are large for its curvature). A step whose cost rises is halved,
        and that track falls back to Gauss-Newton. A track stops once its Gauss-Newton decrement is below ``tol``
        times its sum of squares (+ 1e-20 px^2 per point). Once most tracks have stopped, only the others are
        evaluated.

        Returns (evaluation at the solution, converged mask (m,), evaluations, work: evaluated rows over all rows).
        """
        d, r = d.copy(), r.copy()
        ev = self._evaluate(R, d, r)
        S = self._gram(ev, 3)
        atol = CIRCLE_ATOL_PX2 * self.counts
        row_track = self._layout.row_track
        row_counts = np.bincount(row_track, minlength=self.n_tracks)
        n_rows = max(1, len(row_track))
        curvature = self._curvature  # (3, m): entries (dd, dr, rr) of S_j

        def steps(S):
            gd, gr = S[:, 1, 0], S[:, 2, 0]
            a, b, c = _inverse2(S[:, 1, 1], S[:, 1, 2], S[:, 2, 2])
            decrement = 0.5 * (gd * (a * gd + b * gr) + gr * (b * gd + c * gr))  # Gauss-Newton's
            Hdd, Hdr, Hrr = S[:, 1, 1] + curvature[0], S[:, 1, 2] + curvature[1], S[:, 2, 2] + curvature[2]
            newton = (Hdd > 0.0) & (Hdd * Hrr - Hdr * Hdr > 0.0)
            a, b, c = (np.where(newton, x, y) for x, y in zip(_inverse2(Hdd, Hdr, Hrr), (a, b, c), strict=True))
            return np.column_stack([-(a * gd + b * gr), -(b * gd + c * gr)]), decrement

        cost = S[:, 0, 0].copy()
        step, decrement = steps(S)
        with np.errstate(invalid="ignore"):
            done = (self.counts == 0) | ~(decrement > tol * cost + atol)
        converged = done.copy()
        halvings = np.zeros(self.n_tracks, dtype=np.int64)
        evaluations, work = 1, 1.0
        while not done.all() and evaluations < max_evaluations:
            move = ~done
            trial_d = np.where(move, d + step[:, 0], d)
            trial_r = np.where(move, r + step[:, 1], r)
            fraction = row_counts[move].sum() / n_rows
            active = move if fraction <= SUBSET_FRACTION else None
            previous = ev
            ev = self._evaluate(R, trial_d, trial_r, active)
            S_trial = self._gram(ev, 3, active)
            evaluations += 1
            work += fraction if active is not None else 1.0
            cost_trial = S_trial[:, 0, 0]
            with np.errstate(invalid="ignore"):
                accept = move & (cost_trial <= cost * (1.0 + 1e-12))
            reject = move & ~accept
            if accept.any():
                # secant update of the curvature term where the step started at the previous evaluation
                update = accept & (previous.d == d) & (previous.r == r)
                if update.any():
                    self._update_curvature(update, previous, ev, S[:, 1:3, 0], S_trial[:, 1:3, 0],
                                           (trial_d - d, trial_r - r))
                d[accept], r[accept] = trial_d[accept], trial_r[accept]
                cost[accept] = cost_trial[accept]
                S[accept] = S_trial[accept]
                new_step, new_decrement = steps(S_trial)
                step[accept] = new_step[accept]
                halvings[accept] = 0
                with np.errstate(invalid="ignore"):
                    finished = accept & ~(new_decrement > tol * cost + atol)
                done |= finished
                converged |= finished
            if reject.any():
                curvature[:, reject] = 0.0  # back to Gauss-Newton for these tracks
                step[reject] *= 0.5
                halvings[reject] += 1
                done |= reject & (halvings > MAX_HALVINGS)
        stale = (ev.d != d) | (ev.r != r)  # a track whose last trial was rejected: evaluate it where it stays
        if stale.any():
            ev = self._evaluate(R, d, r, stale)
            evaluations += 1
            work += row_counts[stale].sum() / n_rows
        return ev, converged, evaluations, work

    def _update_curvature(self, update, previous: _Eval, ev: _Eval, g_old, g_new, step) -> None:
        """Dennis-Gay-Welsch update of the tracks' curvature terms ``S`` (symmetric 2x2) after the steps ``s``:
        ``S+ s = y# = (J+ - J)^T e+`` (J the Jacobian wrt (d, r)), with NL2SOL's sizing ``S <- min(1, |s.y#| /
        |s.S s|) S``, where the gradient change ``y = g+ - g`` has ``s.y > 0``."""
        row_track = self._layout.row_track
        sel = np.flatnonzero(update[row_track])
        cross = self._subset_sums(np.einsum("irl,rl->ri", previous.V[1:3, sel], ev.V[0, sel]), row_track[sel])
        s0, s1 = step[0], step[1]
        y0, y1 = g_new[:, 0] - g_old[:, 0], g_new[:, 1] - g_old[:, 1]
        p0, p1 = g_new[:, 0] - cross[:, 0], g_new[:, 1] - cross[:, 1]  # y#
        Sdd, Sdr, Srr = self._curvature
        Ss0, Ss1 = Sdd * s0 + Sdr * s1, Sdr * s0 + Srr * s1
        with np.errstate(divide="ignore", invalid="ignore"):
            sSs = s0 * Ss0 + s1 * Ss1
            size = np.where(sSs != 0.0, np.minimum(1.0, np.abs(s0 * p0 + s1 * p1) / np.abs(sSs)), 1.0)
            Sdd, Sdr, Srr, Ss0, Ss1 = Sdd * size, Sdr * size, Srr * size, Ss0 * size, Ss1 * size
            v0, v1 = p0 - Ss0, p1 - Ss1
            ys = y0 * s0 + y1 * s1
            vs = v0 * s0 + v1 * s1
            ok = update & (ys > 0.0)
            inv = np.where(ok, 1.0 / ys, 0.0)
            inv2 = vs * inv * inv
            new = (Sdd + 2.0 * v0 * y0 * inv - inv2 * y0 * y0, Sdr + (v0 * y1 + y0 * v1) * inv - inv2 * y0 * y1,
                   Srr + 2.0 * v1 * y1 * inv - inv2 * y1 * y1)
        for i in range(3):
            self._curvature[i] = np.where(ok & np.isfinite(new[i]), new[i], np.where(update, 0.0,
                                                                                    self._curvature[i]))

    def solve_circles(self, R, d0=None, r0=None, *, tol: float = CIRCLE_TOL, max_evaluations: int = 60):
        """Per-track (d, r) minimising each track's sum of squared residuals at the fixed line variable R.

        Gauss-Newton vectorised across tracks (per-track 2x2 normal equations), a track's step halved while its
        cost rises; a track stops once its Gauss-Newton decrement (predicted decrease) is below ``tol`` times its
        sum of squares (+ 1e-20 px^2 per point). Starts from (d0, r0), by default from the previous call's solution.

        Returns:
            d, r: (m,) arrays.
        """
        if d0 is None or r0 is None:
            if self._solution is None:
                raise ValueError("no previous solution: pass d0 and r0")
            d0 = self._solution[0] if d0 is None else d0
            r0 = self._solution[1] if r0 is None else r0
        R, d0, r0 = self._variables(R, d0, r0)
        if len(d0) != self.n_tracks or len(r0) != self.n_tracks:
            raise ValueError(f"need one (d, r) per track ({self.n_tracks}), got {len(d0)} and {len(r0)}")
        ev, converged, evaluations, work = self._solve(R, d0, r0, tol, max_evaluations)
        #: per-track convergence, and the evaluations and work (evaluated tracks' rows over all rows) of the solve
        self.last_solve = {"converged": converged, "evaluations": evaluations, "work": work}
        self._solution = (ev.d.copy(), ev.r.copy())
        return ev.d.copy(), ev.r.copy()


# ----------------------------------------------------------------------------------------------------------------
# The variable-projection line factor
# ----------------------------------------------------------------------------------------------------------------


class _LineState:
    """The projected-out circles at one line variable, and what the factor needs there."""

    __slots__ = ("rot", "R", "ev", "gram", "converged", "evaluations", "M", "curvature", "_J")

    def __init__(self, rot, R, ev, gram, converged, evaluations, M, curvature):
        self.rot = rot  # gtsam.Rot3
        self.R = R
        self.ev = ev  # evaluation at (R, c*(R)) with the line Jacobians
        self.gram = gram  # (m, 6, 6) per-track sums of products of (e, H_d, H_r, H_w0, H_w1, H_w2)
        self.converged = converged
        self.evaluations = evaluations
        self.M = M  # (m, 2, 3) (H_c^T H_c)^-1 H_c^T H_R: dc*/dw = -M (Gauss-Newton)
        self.curvature = curvature  # (3, m) the circle solve's secant curvature terms at its end
        self._J = None  # (3, rows, L) P H_R, unweighted

    @property
    def sse(self) -> np.ndarray:
        return self.gram[:, 0, 0]


class CoaxialLineFactor:
    """One measurement's variable-projection factor (``.factor``) and what it knows about its tracks.

    Built by :func:`make_coaxial_line_factor`. Every inspection method takes the line variable as ``x``: a
    ``gtsam.Values`` (read at ``line_key``), a ``gtsam.Rot3``, a 3x3 matrix, or None for the line of the factor's
    last evaluation. The circles at a line are solved once and cached (the last few lines). GTSAM's error (no
    Jacobians) at a line further than ``TRUST_RAD`` from every anchor (the last linearisation points, the first
    line evaluated) is refused with a huge constant residual (LM's trust region, see :meth:`_refused`); the
    inspection methods (``error(x)`` etc.) and linearisations always solve.

    Attributes:
        factor: the ``gtsam.CustomFactor`` (key ``line_key``, dimension N, unit noise model: its residual is
            already whitened by ``sigma_px``).
        tracks: the :class:`CoaxialTracks` (may be shared with a new factor: each factor's solves start their
            phases from its own anchors).
        sigma_px: the pixel noise (may be changed between solves).
        counts: (m,) points per track.

    Memory: the ``CustomFactor`` keeps its Python error function alive from C++, where Python's garbage collector
    cannot see it, so a cycle ``self -> factor -> error function -> self`` would never be freed (every solve's
    cached states with it: ~1 MB per factor on a 10 s scene). The error function is therefore bound to a
    twin of this object that shares its attributes (``__dict__``) but not the ``factor`` slot: the factor keeps
    the twin (and so the shared state) alive for as long as a graph holds it, even without this object, and
    nothing in the shared state refers back to the factor. Keep it so: never store ``self`` or the factor in an
    attribute.
    """

    __slots__ = ("__dict__", "__weakref__", "factor")

    def __init__(self, line_key: int, tracks: CoaxialTracks, circles, sigma_px: float = 1.0, robust=None, *,
                 tol: float = CIRCLE_TOL, max_evaluations: int = 60, cache_size: int = 4):
        circles = np.array(circles, dtype=float).reshape(-1, 2)
        if len(circles) != tracks.n_tracks:
            raise ValueError(f"need one (d, r) per track ({tracks.n_tracks}), got {len(circles)}")
        if not np.isfinite(sigma_px) or sigma_px <= 0:
            raise ValueError(f"sigma_px must be a positive number of pixels, got {sigma_px!r}")
        self.line_key = line_key
        self.tracks = tracks
        self.sigma_px = float(sigma_px)
        self.counts = tracks.counts
        self.tol = float(tol)
        self.max_evaluations = int(max_evaluations)
        self._start = (circles[:, 0].copy(), circles[:, 1].copy())
        self._huber_k, self._estimators = _robust_setup(robust, tracks.counts)
        self._cache: OrderedDict[bytes, _LineState] = OrderedDict()
        #: anchors, the only starts of the circle solves (see _anchor): the states of the last linearisation
        #: points (LM's accepted lines), never evicted by trial lines, and the first state solved
        self._pinned: OrderedDict[bytes, _LineState] = OrderedDict()
        self._home: _LineState | None = None
        self._cache_size = max(1, int(cache_size))
        self._last: _LineState | None = None
        #: diagnostics: circle solves, the evaluations they took, and their work in passes over all tracks; errors
        #: refused (outside the trust region, see _refused)
        self.refused = 0
        self.solves = 0
        self.evaluations = 0
        self.work = 0.0
        twin = object.__new__(type(self))  # same attributes, no factor slot: no cycle through C++ (see above)
        twin.__dict__ = self.__dict__
        self.factor = gtsam.CustomFactor(gtsam.noiseModel.Unit.Create(tracks.n_points), [line_key],
                                         twin._error_function)

    # ------------------------------------------------------------------------------------------------------------

    def _error_function(self, this, values, H):
        rot = values.atRot3(self.line_key)
        if H is None and self._refused(rot):
            self.refused += 1
            return np.full(self.tracks.n_points, REFUSED_RESIDUAL)
        state = self._state(rot)
        if H is None:
            return self._residual(state, self._scales(state)[1])
        key = state.R.tobytes()
        self._pinned[key] = state
        self._pinned.move_to_end(key)
        if len(self._pinned) > PINNED_STATES:
            self._pinned.popitem(last=False)
        irls = self._scales(state)[0]
        H[0] = self._jacobian(state, irls)
        return self._residual(state, irls)

    def _rot(self, x) -> gtsam.Rot3:
        if x is None:
            if self._last is None:
                raise ValueError("the factor has not been evaluated yet: pass the line variable")
            return self._last.rot
        if isinstance(x, gtsam.Values):
            return x.atRot3(self.line_key)
        if isinstance(x, gtsam.Rot3):
            return x
        return gtsam.Rot3(np.asarray(x, dtype=float).reshape(3, 3))

    def _state(self, rot: gtsam.Rot3) -> _LineState:
        R = np.ascontiguousarray(rot.matrix())
        key = R.tobytes()
        state = self._cache.get(key)
        if state is not None:
            self._cache.move_to_end(key)
        else:
            state = self._pinned.get(key)
        if state is not None:
            self._last = state
            return state
        tracks = self.tracks
        anchor, w, norm = self._anchor(rot)
        # the whole solve is a function of (anchor, line) only: its phases and curvature terms start from the
        # anchor's too, not from whatever line the tracks (or another factor sharing them) evaluated last
        if anchor is None:
            tracks._s = tracks._c = None
            tracks._curvature[:] = 0.0
            d0, r0 = self._start
        else:
            tracks._s, tracks._c = anchor.ev.s, anchor.ev.c
            tracks._curvature[:] = anchor.curvature
            d0, r0 = anchor.ev.d, anchor.ev.r
            if norm <= PREDICT_MAX_RAD:
                change = -anchor.M @ w  # (m, 2): Gauss-Newton's dc*/dw w
                ok = np.isfinite(change).all(axis=1)
                d0, r0 = np.where(ok, d0 + change[:, 0], d0), np.where(ok, r0 + change[:, 1], r0)
        ev, converged, evaluations, work = tracks._solve(R, d0, r0, self.tol, self.max_evaluations)
        gram = tracks._gram(ev, 6)
        a, b, c = _inverse2(gram[:, 1, 1], gram[:, 1, 2], gram[:, 2, 2])
        B = gram[:, 1:3, 3:6]
        M = np.stack([a[:, None] * B[:, 0] + b[:, None] * B[:, 1], b[:, None] * B[:, 0] + c[:, None] * B[:, 1]],
                     axis=1)
        state = _LineState(rot, R, ev, gram, converged, evaluations, M, tracks._curvature.copy())
        self.solves += 1
        self.evaluations += evaluations
        self.work += work
        self._cache[key] = state
        self._cache.move_to_end(key)
        if len(self._cache) > self._cache_size:
            self._cache.popitem(last=False)
        if self._home is None:
            self._home = state
        self._last = state
        return state

    def _anchors(self) -> list[_LineState]:
        anchors = list(self._pinned.values())[::-1]  # the latest linearisation point first
        if self._home is not None:
            anchors.append(self._home)
        return anchors

    def _anchor(self, rot: gtsam.Rot3):
        """Anchor of the circle solve at ``rot`` (or None), the line step w from it and its norm.

        The solve starts from the anchor's circles moved by their Gauss-Newton change ``-M w`` (``M =
        (H_c^T H_c)^-1 H_c^T H_R`` at the anchor; beyond ``PREDICT_MAX_RAD`` from the anchor, its circles
        themselves). The anchors are the last ``PINNED_STATES`` linearisation points and the first state solved
        (from the initial circles); never a trial line. The latest linearisation point is the anchor of every line
        within ``PREDICT_MAX_RAD`` of it (LM's trial steps), else the nearest anchor is. So the circles at a line
        depend only on its anchor, not on which trial lines were evaluated before (a rejected trial far away,
        whose circles may have fallen into another local solution, cannot move the circles found near the
        linearisation point), and re-evaluating a line gives its value again to the solve's tolerance. The
        solve's phases and secant curvature terms start from the anchor's too (see :meth:`_state`).
        """
        best, best_w, best_norm = None, None, np.inf
        anchors = self._anchors()
        for state in anchors:
            w = np.asarray(state.rot.localCoordinates(rot))
            norm = float(np.linalg.norm(w))
            if norm < best_norm:
                best, best_w, best_norm = state, w, norm
            if state is anchors[0] and norm <= PREDICT_MAX_RAD:
                break  # LM's trials: from the point LM linearised at, whatever lies nearer
        return best, best_w, best_norm

    def _refused(self, rot: gtsam.Rot3) -> bool:
        """Whether GTSAM's error at ``rot`` is refused: a trust region for LM's trial steps.

        A line further than ``TRUST_RAD`` from every anchor (the last linearisation points and the first line
        solved) and not cached gets the constant residual ``REFUSED_RESIDUAL`` per point instead of its circle
        solve, so LM raises lambda and tries a shorter step. LM's diagonal damping of the reduced problem leaves a
        line's tilt within its projection plane nearly undamped (the circles, whose damping holds such steps back
        in the full graph, are projected out): from a poor start LM then tries steps of ~1 rad, where the solve
        from the anchor is far from any prediction, slow, and may fall into another local solution (circles far
        along the axis) that happens to be lower, which LM then accepts. The first evaluation, linearisations
        (``H`` given) and the inspection methods always solve.
        """
        anchors = self._anchors()
        if not anchors:
            return False
        key = np.ascontiguousarray(rot.matrix()).tobytes()
        if key in self._cache or key in self._pinned:
            return False
        return all(np.linalg.norm(state.rot.localCoordinates(rot)) > TRUST_RAD for state in anchors)

    def _scales(self, state: _LineState) -> tuple[np.ndarray, np.ndarray]:
        """Per-track row scales (m,): IRLS ``sqrt(w_j) / sigma`` (linearisation) and the loss-consistent
        ``sqrt(2 rho_j) / (|e_j| sigma)`` (error)."""
        inv = 1.0 / self.sigma_px
        if self._huber_k is None and self._estimators is None:
            ones = np.full(self.tracks.n_tracks, inv)
            return ones, ones
        x = np.sqrt(np.maximum(state.sse, 0.0)) * inv
        w, loss = _robust_terms(x, self._huber_k, self._estimators)
        with np.errstate(divide="ignore", invalid="ignore"):
            loss_scale = np.where(x > 0.0, np.sqrt(2.0 * loss) / x, 1.0)
        return np.sqrt(w) * inv, loss_scale * inv

    def _per_row(self, per_track: np.ndarray) -> np.ndarray:
        return per_track[self.tracks._layout.row_track][:, None]

    def _residual(self, state: _LineState, scale: np.ndarray) -> np.ndarray:
        return self.tracks._flat(state.ev.V[0] * self._per_row(scale))

    def _jacobian(self, state: _LineState, scale: np.ndarray) -> np.ndarray:
        """(N, 3) ``P H_R`` per track, rows scaled."""
        tracks = self.tracks
        if state._J is None:
            V = state.ev.V
            M = state.M[tracks._layout.row_track]  # (rows, 2, 3)
            J = np.empty((3, V.shape[1], V.shape[2]))
            for k in range(3):
                np.subtract(V[3 + k], M[:, 0, k, None] * V[1], out=J[k])
                J[k] -= M[:, 1, k, None] * V[2]
            state._J = J
        J = state._J * self._per_row(scale)[None]
        if tracks._layout.dense:
            return J.reshape(3, -1).T
        return J.reshape(3, -1)[:, tracks._layout.flat_index].T

    # ------------------------------------------------------------------------------------------------------------
    # inspection

    def circles(self, x=None) -> np.ndarray:
        """(m, 2) projected-out circles (d, r) at the line variable."""
        ev = self._state(self._rot(x)).ev
        return np.column_stack([ev.d, ev.r])

    def track_sse(self, x=None) -> np.ndarray:
        """(m,) sum of squared residuals (px^2) of each track at its projected-out circle."""
        return self._state(self._rot(x)).sse.copy()

    def track_rms(self, x=None) -> np.ndarray:
        """(m,) residual RMS (px) of each track (0 for an empty track)."""
        sse = self.track_sse(x)
        with np.errstate(divide="ignore", invalid="ignore"):
            return np.where(self.counts > 0, np.sqrt(sse / np.maximum(self.counts, 1)), 0.0)

    def track_chi2(self, x=None) -> np.ndarray:
        """(m,) whitened chi-square ``sse / sigma^2`` of each track."""
        return self.track_sse(x) / self.sigma_px**2

    def weights(self, x=None) -> np.ndarray:
        """(m,) robust weights of the tracks (the IRLS weights ``w_j``; ones without a robust kernel)."""
        return (self._scales(self._state(self._rot(x)))[0] * self.sigma_px) ** 2

    def converged(self, x=None) -> np.ndarray:
        """(m,) whether each track's circle solve converged."""
        return self._state(self._rot(x)).converged.copy()

    def residuals(self, x=None) -> np.ndarray:
        """(N,) signed pixel residuals (unweighted) of all tracks at their projected-out circles."""
        return self.tracks._flat(self._state(self._rot(x)).ev.V[0]).copy()

    def phases(self, x=None) -> np.ndarray:
        """(N,) closest phases in [-pi, pi] at the projected-out circles."""
        ev = self._state(self._rot(x)).ev
        return np.arctan2(self.tracks._flat(ev.s), self.tracks._flat(ev.c))

    def error(self, x=None) -> float:
        """The factor's error (GTSAM's): half the whitened chi-square, or the sum of the robust losses."""
        state = self._state(self._rot(x))
        scale = self._scales(state)[1]
        return float(0.5 * np.sum(state.sse * scale**2))

    def track_scores(self, x=None) -> np.ndarray:
        """(m, 3) each track's score ``J_j^T e_j`` (whitened and robust-weighted, as GTSAM sees the factor): its
        part of the gradient at the line variable.

        ``sum_j s_j s_j^T`` estimates the information the pixels carry when different tracks' errors are
        independent but one track's may be correlated (a tracker's sub-pixel bias that follows a dot): the
        "meat" of a cluster-robust (sandwich) covariance. With white pixel noise of the assumed sigma its
        expectation is :meth:`information`.
        """
        state = self._state(self._rot(x))
        irls = self._scales(state)[0]
        Je = self._jacobian(state, irls) * self._residual(state, irls)[:, None]
        tracks = self.tracks
        flat_track = tracks._flat(np.broadcast_to(tracks._layout.row_track[:, None], state.ev.V[0].shape))
        return np.stack([np.bincount(flat_track, weights=Je[:, k], minlength=tracks.n_tracks) for k in range(3)],
                        axis=1)

    def track_information(self, x=None) -> np.ndarray:
        """(m, 3, 3) each track's ``J_j^T J_j`` (weighted, its circle projected out): its part of
        :meth:`information`, from the per-track sums (no N-sized work)."""
        state = self._state(self._rot(x))
        w = self._scales(state)[0] ** 2
        G = state.gram
        per_track = G[:, 3:6, 3:6] - np.einsum("jki,jkl->jil", G[:, 1:3, 3:6], state.M)
        return w[:, None, None] * per_track

    def information(self, x=None) -> np.ndarray:
        """(3, 3) ``J^T J`` of the (weighted) factor: the Schur complement of the full graph's Gauss-Newton
        Hessian, from the per-track sums (no N-sized work)."""
        return self.track_information(x).sum(axis=0)


def _robust_setup(robust, counts):
    """(Huber thresholds (m,) or None, per-track estimators or None) of ``robust``."""
    if robust is None:
        return None, None
    if callable(robust) and not isinstance(robust, gtsam.noiseModel.mEstimator.Base):
        estimators = [robust(int(n)) if n > 0 else None for n in counts]
    elif isinstance(robust, gtsam.noiseModel.mEstimator.Base):
        estimators = [robust] * len(counts)
    else:
        k = np.array(robust, dtype=float).reshape(-1)
        if len(k) != len(counts) or not np.all(k > 0):
            raise ValueError("robust must be an mEstimator, a callable n_points -> mEstimator, or one positive "
                             "Huber threshold per track")
        return k, None
    k = np.full(len(counts), np.inf)
    for j, estimator in enumerate(estimators):
        if estimator is None:
            continue
        if not isinstance(estimator, gtsam.noiseModel.mEstimator.Huber):
            return None, estimators
        big = 1e30
        k[j] = estimator.weight(big) * big
    return k, None


def _robust_terms(x: np.ndarray, huber_k, estimators) -> tuple[np.ndarray, np.ndarray]:
    """Weights ``w(x)`` and losses ``rho(x)`` of the tracks' whitened norms x (m,)."""
    if huber_k is not None:
        with np.errstate(divide="ignore", invalid="ignore"):
            inside = x <= huber_k
            w = np.where(inside, 1.0, huber_k / x)
            loss = np.where(inside, 0.5 * x * x, huber_k * x - 0.5 * huber_k * huber_k)
        return w, loss
    w, loss = np.ones_like(x), 0.5 * x * x
    for j, estimator in enumerate(estimators):
        if estimator is not None:
            w[j], loss[j] = estimator.weight(float(x[j])), estimator.loss(float(x[j]))
    return w, loss


def make_coaxial_line_factor(line_key: int, tracks, K, circles, *, sigma_px: float = 1.0, robust=None,
                             tol: float = CIRCLE_TOL, max_evaluations: int = 60) -> CoaxialLineFactor:
    """One variable-projection factor for all tracks of one measurement, keyed on its line variable only.

    Residual (dimension N, unit noise model): ``e(R, c*(R)) / sigma_px`` of all tracks concatenated, with every
    track's circle ``c* = (d, r)`` projected out (:meth:`CoaxialTracks.solve_circles`, started from an anchor's
    solution moved by its first-order change, see :meth:`CoaxialLineFactor._anchor`). Jacobian:
    ``P_j H_R,j / sigma_px`` per track (see the module docstring).

    Robust kernel per track (like a ``noiseModel.Robust`` on each track's circle-point factor, which GTSAM applies
    to the track's whole whitened norm ``x_j = |e_j| / sigma_px``): at a linearisation the rows of track j are
    scaled by ``sqrt(w_j)`` (GTSAM's ``Robust.WhitenSystem``), e.g. ``w_j = min(1, k_j / x_j)`` for Huber; the
    residual returned WITHOUT Jacobians (GTSAM's ``error``, ``unwhitenedError``) is scaled by
    ``sqrt(2 rho_j(x_j)) / x_j`` instead, so that the factor's error is ``sum_j rho_j(x_j)``, the full graph's
    robust error. The kernel does not change the circles (``rho`` is increasing in ``x_j``).

    Args:
        line_key: key of the measurement's ``gtsam.Rot3`` line variable.
        tracks: list of (N_j, 2) ideal pixels, or a :class:`CoaxialTracks` (K unused).
        K: (3, 3) intrinsic matrix.
        circles: (m, 2) initial (d, r) per track.
        sigma_px: pixel noise of the measurement.
        robust: None; a ``gtsam.noiseModel.mEstimator``; a callable ``n_points -> mEstimator`` such as
            :func:`gtsam_rotid.graph.track_huber`; or (m,) Huber thresholds. Huber kernels are vectorised; other
            estimators are called per track.
        tol, max_evaluations: the circle solve's relative decrement tolerance and its evaluation budget.

    Returns:
        :class:`CoaxialLineFactor`; add ``.factor`` to the graph.
    """
    if not isinstance(tracks, CoaxialTracks):
        tracks = CoaxialTracks(K, tracks)
    return CoaxialLineFactor(line_key, tracks, circles, sigma_px, robust, tol=tol, max_evaluations=max_evaluations)

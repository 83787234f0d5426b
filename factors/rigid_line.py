"""The rigid spin projected out: one factor per measurement on its line variable (variable projection).

The rigid-spin model of :mod:`.rigid` (docs/design.md §4): within a measurement every feature turns with one spin
angle per frame, ``phi_i = theta_{f_i} + phi0_j``; each track has a circle ``(d, r)`` and a phase offset ``phi0``.
:mod:`.rigid` puts all of these into the graph (one variable per track and per 32 frames); here they are projected
out, as :mod:`.coaxial` projects out the free-phase circles: :func:`make_rigid_line_factor` builds ONE
``gtsam.CustomFactor`` per measurement on its line variable only. At a line ``R`` it solves the inner problem

    ``min over (d_j, r_j, phi0_j, theta_f) of sum_j rho_j(|e_j| / sigma)``, ``e_i = u(theta_{f_i} + phi0_j) - u_obs_i``

by Gauss-Newton (IRLS for the robust kernel, one per track as in :mod:`.coaxial`), and returns the 2-D reprojection
errors there, interleaved ``[du_0, dv_0, du_1, dv_1, ...]`` (2N values), with the variable-projection Jacobian
(Kaufman's form) ``P H_R``, ``P = I - J (J^T W J)^-1 J^T W`` (``J`` the inner Jacobian: ``(d, r, phi0)`` of each track
and ``theta`` of each frame). So LM on the line variables follows the full rigid graph's reduced problem and
``gtsam.Marginals`` gives its line (and pose) marginals, with one variable per measurement instead of one per track
and per chunk of frames.

The inner normal equations are sparse: each pixel touches its track's three parameters and its frame's angle, so
the frames' block is diagonal and is eliminated first (Schur complement; ``3m x 3m`` dense system for ``m``
tracks); every sum is one ``np.add.reduceat`` (per track: a track's pixels are contiguous) or ``np.bincount`` (per
frame) over all pixels at once.

Gauge: ``theta_f + k, phi0_j - k`` over a connected component of tracks (linked by shared frames) changes nothing;
``phi0`` of the first track of each component is held at its start (not an inner variable). Frames that no track
sees have no angle. The first-order change of the inner variables with the line (``-X w``, ``X = (J^T W J)^-1 J^T W
H_R``) starts the solves of LM's trial lines from the last linearisation point, and the caching, anchors and trust
region are those of :class:`.coaxial.CoaxialLineFactor`.
"""

from __future__ import annotations

import gtsam
import numpy as np

from .coaxial import PREDICT_MAX_RAD, CoaxialLineFactor, _robust_terms
from .coaxial_solve import CIRCLE_TOL
from .geometry import cal3_s2
from .rigid import _track_components

__all__ = ["RigidLineFactor", "RigidTracks", "make_rigid_line_factor"]

#: Trust region of the inner steps: no track's circle ``(d, r)`` moves by more than this times its radius in one
#: step (nor by the first-order prediction, which is then left out). Without it, a track whose circle is weakly
#: determined (a small thin ellipse: offset and radius trade off) can be thrown far along the axis, to a circle
#: near infinity whose projection still fits a short arc, where Gauss-Newton runs off.
MAX_CIRCLE_STEP = 0.5
#: Frames per group in the Schur complement's ``C C^T`` (a track is seen in a few groups, so most track pairs share
#: none and their block is never computed).
GROUP_FRAMES = 200


class RigidTracks:
    """One measurement's tracks with frame indices, flattened: every pixel's track, its (compacted) frame, and the
    gauge (the first track of each connected component keeps its ``phi0``).

    Args:
        tracks: per track ``(pixels (N_j, 2) ideal, frames (N_j,) int)``; a track may not see a frame twice.
    """

    def __init__(self, tracks):
        pixels, frames, owner = [], [], []
        for j, (p, f) in enumerate(tracks):
            p = np.asarray(p, dtype=float).reshape(-1, 2)
            f = np.asarray(f).reshape(-1)
            if len(f) != len(p):
                raise ValueError(f"track {j}: {len(f)} frames for {len(p)} pixels")
            if len(f) and not np.issubdtype(f.dtype, np.integer):
                raise TypeError(f"track {j}: frames must be integers, got dtype {f.dtype}")
            if len(np.unique(f)) != len(f):
                raise ValueError(f"track {j} sees a frame twice")
            if not np.all(np.isfinite(p)):
                raise ValueError(f"track {j} has pixels that are not finite")
            pixels.append(p)
            frames.append(f.astype(np.int64))
            owner.append(np.full(len(p), j))
        self.n_tracks = len(pixels)
        if self.n_tracks == 0 or not sum(len(p) for p in pixels):
            raise ValueError("need at least one track with pixels")
        self.pixels = np.concatenate(pixels)
        self.counts = np.array([len(p) for p in pixels])
        self.n_points = len(self.pixels)
        self.track = np.concatenate(owner)
        self.frame_ids, self.frame = np.unique(np.concatenate(frames), return_inverse=True)
        self.n_frames = len(self.frame_ids)
        local = np.split(self.frame, np.cumsum(self.counts)[:-1])
        self.components = _track_components([(f, None) for f in local], self.n_frames)
        #: (3m,) inner track parameters ``(d, r, phi0)`` per track that are free (the gauge's phi0 are held)
        self.free = np.ones(3 * self.n_tracks, dtype=bool)
        self.free[[3 * comp[0] + 2 for comp in self.components]] = False
        self._indices: dict[int, np.ndarray] = {}
        #: each non-empty track's first pixel (a track's pixels are contiguous): per-track sums by ``np.add.reduceat``
        self._nonempty = np.flatnonzero(self.counts > 0)
        self._starts = (np.cumsum(self.counts) - self.counts)[self._nonempty]
        self._group_layout()
        for a in (self.pixels, self.track, self.frame, self.free, self.counts, self._coupling, self._starts):
            a.setflags(write=False)

    def _group_layout(self) -> None:
        """The track-frame coupling of the normal matrix (3m x F, one entry per pixel and track parameter: a track
        sees a frame once) stored by groups of about ``GROUP_FRAMES`` frames, each a dense block of the rows of the
        tracks seen in it only: ``_groups`` holds (rows, first frame, end, ``np.ix_`` of the rows, offset in the
        flat store), ``_coupling`` each pixel's flat position per parameter (3N), ``_coupling_size`` the store's."""
        self._groups, offset = [], 0
        position = np.empty((3, self.n_points), dtype=np.int64)
        group = self.frame // GROUP_FRAMES
        for g, first in enumerate(range(0, self.n_frames, GROUP_FRAMES)):
            end = min(first + GROUP_FRAMES, self.n_frames)
            here = np.flatnonzero(group == g)
            seen, local = np.unique(self.track[here], return_inverse=True)
            rows = (3 * seen[:, None] + np.arange(3)).reshape(-1)
            for a in range(3):
                position[a, here] = offset + (3 * local + a) * (end - first) + self.frame[here] - first
            self._groups.append((rows, first, end, np.ix_(rows, rows), offset))
            offset += len(rows) * (end - first)
        self._coupling, self._coupling_size = position.reshape(-1), offset

    def track_sums(self, values: np.ndarray) -> np.ndarray:
        """(..., N) per-pixel values -> (..., m) their sums per track (0 for an empty track)."""
        sums = np.add.reduceat(values, self._starts, axis=-1)
        if len(self._nonempty) == self.n_tracks:
            return sums
        out = np.zeros(values.shape[:-1] + (self.n_tracks,))
        out[..., self._nonempty] = sums
        return out

    def _frame_index(self, q: int) -> np.ndarray:
        """Bincount targets ``frame * q + c`` of a (q, N) array of per-pixel values summed per frame."""
        if q not in self._indices:
            target = self.frame[None, :] * q + np.arange(q)[:, None]
            self._indices[q] = np.ascontiguousarray(target.reshape(-1))
        return self._indices[q]


class _Inner:
    """An evaluation of the rigid spin at one line and inner point: residuals and derivatives per pixel."""

    __slots__ = ("x", "e", "a", "sse", "_G", "_v", "_H_R", "_u", "_K")

    def __init__(self, tracks: RigidTracks, K: np.ndarray, R: np.ndarray, x: np.ndarray):
        m = tracks.n_tracks
        self.x = x
        d, r, p = x[0:3 * m:3][tracks.track], x[1:3 * m:3][tracks.track], x[2:3 * m:3][tracks.track]
        phi = x[3 * m:][tracks.frame] + p
        s, c = np.sin(phi), np.cos(phi)
        rs, rc = r * s, r * c
        M = K @ R
        v0 = 1.0 + rs
        y = M[:, 0:1] * v0 + M[:, 1:2] * d + M[:, 2:3] * rc  # (3, N): K X with X = R v, v = (1 + r s, d, r c)
        iz = 1.0 / y[2]
        u = y[:2] * iz
        self.e = u - tracks.pixels.T  # (2, N)
        # G_k = du_k/dv = (M[k] - u_k M[2]) / y2, (2, 3, N)
        G = (M[:2, :, None] - u[:, None, :] * M[2][None, :, None]) * iz
        # a: (3, 2, N) derivatives of (du, dv) wrt (d, r, phi) (phi: both phi0 and theta)
        self.a = np.stack([G[:, 1], G[:, 0] * s + G[:, 2] * c, G[:, 0] * rc - G[:, 2] * rs])
        self.sse = tracks.track_sums(np.einsum("kn,kn->n", self.e, self.e))
        self._G, self._v, self._H_R, self._u, self._K = G, (v0, d, rc), None, u, K

    @property
    def H_K(self) -> np.ndarray:
        """(5, 2, N) derivatives wrt the intrinsics in ``gtsam.Cal3_S2``'s order ``(fx, fy, s, cx, cy)``: the pixel
        is ``(fx x + s y + cx, fy y + cy)`` of the normalised point ``(x, y)``."""
        (fx, s, cx), (_, fy, cy) = self._K[0], self._K[1]
        y = (self._u[1] - cy) / fy
        x = (self._u[0] - cx - s * y) / fx
        zero, one = np.zeros_like(x), np.ones_like(x)
        return np.stack([np.stack([x, zero]), np.stack([zero, y]), np.stack([y, zero]), np.stack([one, zero]),
                         np.stack([zero, one])])

    @property
    def H_R(self) -> np.ndarray:
        """(3, 2, N) derivatives wrt the line's tangent (``R * Exp(w)``): rows ``v x g_k``."""
        if self._H_R is None:
            (g0, g1, g2), (v0, v1, v2) = self._G.transpose(1, 0, 2), self._v
            self._H_R = np.stack([v1 * g2 - v2 * g1, v2 * g0 - v0 * g2, v0 * g1 - v1 * g0])
        return self._H_R


class _Normal:
    """The inner Gauss-Newton normal equations at an evaluation, the frames' diagonal block eliminated."""

    def __init__(self, tracks: RigidTracks, ev: _Inner, w_pixel: np.ndarray):
        m, F = tracks.n_tracks, tracks.n_frames
        self.tracks = tracks
        a = ev.a
        wa = a * w_pixel  # (3, 2, N)
        P = np.einsum("isn,ksn->ikn", wa, a)  # (3, 3, N): per pixel, products of the (d, r, phi) derivatives
        A = tracks.track_sums(P.reshape(9, -1)).reshape(3, 3, m)
        self.root = np.sqrt(np.maximum(np.bincount(tracks.frame, weights=P[2, 2], minlength=F), 1e-300))  # D^1/2
        # C = B D^-1/2, B (3m, F) the track-frame block of the normal matrix, S = A - C C^T, all by frame groups
        self._C = np.zeros(tracks._coupling_size)
        self._C[tracks._coupling] = (P[:, 2] / self.root[tracks.frame]).reshape(-1)
        S = np.zeros((3 * m, 3 * m))
        idx = np.arange(m)
        S.reshape(m, 3, m, 3)[idx, :, idx, :] = A.transpose(2, 0, 1)
        for _, _, _, block, Cg in self._blocks():
            S[block] -= Cg @ Cg.T
        held = np.flatnonzero(~tracks.free)
        S[held, :] = 0.0
        S[:, held] = 0.0
        S[held, held] = 1.0
        self.S, self.held, self.wa = S, held, wa

    def _blocks(self):
        """Per frame group: its rows, first frame, end, the rows' ``np.ix_`` block and its part of C (rows x
        frames)."""
        for rows, first, end, block, offset in self.tracks._groups:
            yield rows, first, end, block, self._C[offset:offset + len(rows) * (end - first)].reshape(-1, end - first)

    def project(self, V: np.ndarray, gradients: bool = False) -> tuple[np.ndarray, ...]:
        """``(J^T W J)^-1 J^T W V`` for per-pixel columns ``V`` (q, 2, N): (3m, q) and (F, q); with ``gradients``
        also ``J^T W V`` (held entries 0)."""
        tracks = self.tracks
        m, F = tracks.n_tracks, tracks.n_frames
        q = V.shape[0]
        G = np.einsum("isn,qsn->iqn", self.wa, V)  # (3, q, N)
        gt = tracks.track_sums(G.reshape(3 * q, -1)).reshape(3, q, m).transpose(2, 0, 1).reshape(3 * m, q)
        gf = np.bincount(tracks._frame_index(q), weights=G[2].reshape(-1), minlength=F * q).reshape(F, q)
        gt[self.held] = 0.0
        xt, xf = self.solve(gt, gf)
        return (xt, xf, gt, gf) if gradients else (xt, xf)

    def solve(self, gt: np.ndarray, gf: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The solution of the normal equations with right-hand sides ``(gt, gf)`` (held entries 0)."""
        gf = gf / self.root[:, None]
        rhs = gt.copy()
        for rows, first, end, _, Cg in self._blocks():
            rhs[rows] -= Cg @ gf[first:end]
        rhs[self.held] = 0.0  # S is the identity there
        try:
            xt = np.linalg.solve(self.S, rhs)
            finite = bool(np.all(np.isfinite(xt)))
        except np.linalg.LinAlgError:
            finite = False
        if not finite:  # a direction the pixels do not determine (a short arc's radius): the pseudo-inverse's step
            xt = np.linalg.lstsq(self.S, rhs, rcond=1e-12)[0]  # and projection leave it alone
        xf = gf.copy()
        for rows, first, end, _, Cg in self._blocks():
            xf[first:end] -= Cg.T @ xt[rows]
        return xt, xf / self.root[:, None]


class _RigidState:
    """The inner solution at one line variable, and what the factor needs there."""

    __slots__ = ("rot", "R", "K", "ev", "converged", "evaluations", "normal", "X", "_J")

    def __init__(self, rot, R, ev: _Inner, converged: bool, evaluations: int, normal: _Normal, X: np.ndarray,
                 K: np.ndarray):
        self.rot, self.R, self.K, self.ev = rot, R, K, ev
        self.converged, self.evaluations = converged, evaluations
        self.normal = normal  # the inner normal equations at ev, weighted by its IRLS weights
        self.X = X  # (3m + F, 3) (J^T W J)^-1 J^T W H_R (at ev, by normal); with intrinsics (3m + F, 8): H_K too
        self._J = None  # (3, 2, N) P H_R (with intrinsics (8, 2, N): P H_K too)

    @property
    def sse(self) -> np.ndarray:
        return self.ev.sse


class RigidLineFactor(CoaxialLineFactor):
    """One measurement's rigid-spin variable-projection factor (``.factor``) and what it knows about its tracks.

    Built by :func:`make_rigid_line_factor`; the caching, anchors, trust region, robust kernel and the inspection
    methods' conventions are :class:`.coaxial.CoaxialLineFactor`'s. Residuals are 2-D per pixel (``2N`` values,
    interleaved); ``residuals`` returns them as (N, 2).

    Attributes:
        factor: the ``gtsam.CustomFactor`` (key ``line_key``, dimension 2N, unit noise model).
        tracks: the :class:`RigidTracks`.
        sigma_px: the pixel noise (per image coordinate).
        counts: (m,) points per track.
    """

    __slots__ = ()

    def __init__(self, line_key: int, tracks: RigidTracks, K, circles, phi0, theta, sigma_px: float = 1.0,
                 robust=None, *, tol: float = CIRCLE_TOL, max_evaluations: int = 30, cache_size: int = 4,
                 intrinsics_key: int | None = None):
        circles = np.array(circles, dtype=float).reshape(-1, 2)
        phi0 = np.array(phi0, dtype=float).reshape(-1)
        theta = np.array(theta, dtype=float).reshape(-1)
        if len(circles) != tracks.n_tracks or len(phi0) != tracks.n_tracks:
            raise ValueError(f"need one (d, r) and one phi0 per track ({tracks.n_tracks}), got {len(circles)} "
                             f"and {len(phi0)}")
        if len(theta) != tracks.n_frames:
            raise ValueError(f"need one spin angle per frame seen ({tracks.n_frames}), got {len(theta)}")
        self.K = np.asarray(K, dtype=float).reshape(3, 3)
        x0 = np.empty(3 * tracks.n_tracks + tracks.n_frames)
        x0[0:3 * tracks.n_tracks:3], x0[1:3 * tracks.n_tracks:3] = circles[:, 0], circles[:, 1]
        x0[2:3 * tracks.n_tracks:3], x0[3 * tracks.n_tracks:] = phi0, theta
        self._setup(line_key, tracks, x0, sigma_px, robust, tol, max_evaluations, cache_size, 2 * tracks.n_points,
                    intrinsics_key)

    # ------------------------------------------------------------------------------------------------------------

    def _irls(self, sse: np.ndarray) -> np.ndarray:
        if self._huber_k is None and self._estimators is None:
            return np.ones(self.tracks.n_tracks)
        return _robust_terms(np.sqrt(np.maximum(sse, 0.0)) / self.sigma_px, self._huber_k, self._estimators)[0]

    def _solve(self, rot: gtsam.Rot3, R: np.ndarray, K: np.ndarray | None = None) -> _RigidState:
        """The inner problem at ``rot`` (and the intrinsic matrix ``K``, default the factor's) by Gauss-Newton
        (IRLS), from its anchor's solution moved by its first-order change, with steps shortened to the trust region
        ``MAX_CIRCLE_STEP`` and halved where the robust cost rises."""
        tracks = self.tracks
        K = self.K if K is None else K
        intrinsics = self.intrinsics_key is not None
        anchor, w, norm = self._anchor(rot)
        if anchor is None:
            x = self._start.copy()
        else:
            x = anchor.ev.x.copy()
            if norm <= PREDICT_MAX_RAD:
                if intrinsics:  # the intrinsics' change too (Cal3_S2's tangent: fx, fy, s, cx, cy)
                    w = np.concatenate([w, cal3_s2(K).vector() - cal3_s2(anchor.K).vector()])
                change = -anchor.X[:, :len(w)] @ w
                if np.all(np.isfinite(change)) and self._circle_change(x, change) <= MAX_CIRCLE_STEP:
                    x += change
        ev = _Inner(tracks, K, R, x)
        cost = self._cost(ev.sse)
        converged, evaluations = False, 1
        while True:
            normal = _Normal(tracks, ev, self._irls(ev.sse)[tracks.track] / self.sigma_px**2)
            # the line's derivatives ride along (one factorisation): the projection the Jacobian needs if this is
            # the last evaluation
            columns = [ev.e[None], ev.H_R, ev.H_K] if intrinsics else [ev.e[None], ev.H_R]
            xt, xf, gt, gf = normal.project(np.concatenate(columns), gradients=True)
            projected = (xt[:, 1:], xf[:, 1:])
            decrement = float(gt[:, 0] @ xt[:, 0] + gf[:, 0] @ xf[:, 0])  # g^T (J^T W J)^-1 g, whitened
            if decrement <= self.tol * max(cost, 1e-300) or decrement < 1e-20 * tracks.n_points:
                converged = True
                break
            if evaluations >= self.max_evaluations:
                break
            step = -np.concatenate([xt[:, 0], xf[:, 0]])
            t = min(1.0, MAX_CIRCLE_STEP / max(self._circle_change(x, step), 1e-300))
            while True:
                trial = _Inner(tracks, K, R, x + t * step)
                evaluations += 1
                trial_cost = self._cost(trial.sse)
                if trial_cost <= cost or evaluations >= self.max_evaluations or t < 1e-3:
                    break
                t *= 0.5
            if not trial_cost <= cost:
                break
            x, ev, cost = x + t * step, trial, trial_cost
        state = _RigidState(rot, R, ev, converged, evaluations, normal, np.concatenate(projected), K)
        self.solves += 1
        self.evaluations += evaluations
        self.work += evaluations
        return state

    def _circle_change(self, x: np.ndarray, change: np.ndarray) -> float:
        """The largest change of a track's circle ``(d, r)`` relative to its radius."""
        m = self.tracks.n_tracks
        circles, moves = x[:3 * m].reshape(m, 3)[:, :2], change[:3 * m].reshape(m, 3)[:, :2]
        return float(np.max(np.abs(moves).max(axis=1) / np.maximum(np.abs(circles[:, 1]), 1e-12)))

    def _cost(self, sse: np.ndarray) -> float:
        """The robust cost (sum of losses of the tracks' whitened norms)."""
        x = np.sqrt(np.maximum(sse, 0.0)) / self.sigma_px
        if self._huber_k is None and self._estimators is None:
            return float(0.5 * np.sum(x * x))
        return float(np.sum(_robust_terms(x, self._huber_k, self._estimators)[1]))

    def _per_row(self, per_track: np.ndarray) -> np.ndarray:
        return per_track[self.tracks.track]

    def _residual(self, state: _RigidState, scale: np.ndarray) -> np.ndarray:
        return (state.ev.e * self._per_row(scale)).T.reshape(-1)

    def _projected(self, state: _RigidState) -> np.ndarray:
        """(3, 2, N) ``P H_R`` (unweighted rows; the projection ``state.X``, made with the state's last inner step,
        weighted by the IRLS weights of the state's residuals); with an intrinsics variable (8, 2, N): ``P H_K``
        follows."""
        if state._J is None:
            tracks, ev = self.tracks, state.ev
            m, q = tracks.n_tracks, state.X.shape[1]
            xt, xf = state.X[:3 * m], state.X[3 * m:]
            # J X per pixel: sum over (d, r, phi0) of a * X_track, plus a_phi * X_theta
            Xt = xt.reshape(m, 3, q)[tracks.track]  # (N, param, column)
            Xf = xf[tracks.frame]  # (N, column)
            JX = np.einsum("asn,nal->lsn", ev.a, Xt) + ev.a[2][None] * Xf.T[:, None, :]
            H = ev.H_R if q == 3 else np.concatenate([ev.H_R, ev.H_K])
            state._J = H - JX
        return state._J

    def _jacobian(self, state: _RigidState, scale: np.ndarray) -> np.ndarray:
        """(2N, 3) ``P H_R``, rows scaled."""
        J = self._projected(state)[:3] * self._per_row(scale)[None, None]
        return J.transpose(2, 1, 0).reshape(-1, 3)

    def _jacobian_intrinsics(self, state: _RigidState, scale: np.ndarray) -> np.ndarray:
        """(2N, 5) ``P H_K`` (``gtsam.Cal3_S2``'s tangent), rows scaled."""
        J = self._projected(state)[3:] * self._per_row(scale)[None, None]
        return J.transpose(2, 1, 0).reshape(-1, 5)

    # ------------------------------------------------------------------------------------------------------------
    # inspection

    @property
    def inner_dof(self) -> int:
        """Parameters projected out of the factor: ``(d, r, phi0)`` per track, less the held ``phi0`` (one per
        group of tracks linked by shared frames), and one spin angle per frame."""
        return 3 * self.tracks.n_tracks - len(self.tracks.components) + self.tracks.n_frames

    def _inner(self, x=None) -> np.ndarray:
        return self._at(x).ev.x

    def circles(self, x=None) -> np.ndarray:
        """(m, 2) projected-out circles (d, r) at the line variable."""
        inner = self._inner(x)
        m = self.tracks.n_tracks
        return np.column_stack([inner[0:3 * m:3], inner[1:3 * m:3]])

    def phase_offsets(self, x=None) -> np.ndarray:
        """(m,) each track's ``phi0`` at the line variable (the gauge: the first track of each component's is held)."""
        return self._inner(x)[2:3 * self.tracks.n_tracks:3].copy()

    def spin_angles(self, x=None) -> np.ndarray:
        """(F,) spin angle of each frame seen (``tracks.frame_ids``) at the line variable."""
        return self._inner(x)[3 * self.tracks.n_tracks:].copy()

    def track_rms(self, x=None) -> np.ndarray:
        """(m,) residual RMS (px per image coordinate) of each track (0 for an empty track)."""
        sse = self.track_sse(x)
        with np.errstate(divide="ignore", invalid="ignore"):
            return np.where(self.counts > 0, np.sqrt(sse / np.maximum(2 * self.counts, 1)), 0.0)

    def converged(self, x=None) -> np.ndarray:
        """(m,) whether the inner solve converged (one solve for all tracks)."""
        return np.full(self.tracks.n_tracks, self._at(x).converged)

    def residuals(self, x=None) -> np.ndarray:
        """(N, 2) pixel residuals (unweighted) of all tracks at the projected-out spin."""
        return self._at(x).ev.e.T.copy()

    def phases(self, x=None) -> np.ndarray:
        """(N,) phases ``theta_f + phi0_j`` of the pixels, wrapped to [-pi, pi)."""
        inner, tracks = self._inner(x), self.tracks
        phi = inner[3 * tracks.n_tracks:][tracks.frame] + inner[2:3 * tracks.n_tracks:3][tracks.track]
        return np.mod(phi + np.pi, 2.0 * np.pi) - np.pi

    def track_scores(self, x=None) -> np.ndarray:
        """(m, 3) each track's part ``J_j^T e_j`` of the gradient at the line variable (whitened, robust-weighted)."""
        state = self._at(x)
        irls = self._scales(state)[0]
        row = self._per_row(irls)
        Je = np.einsum("lsn,sn->ln", self._projected(state)[:3], state.ev.e) * row * row
        return self.tracks.track_sums(Je).T

    def track_information(self, x=None) -> np.ndarray:
        """(m, 3, 3) each track's ``J_j^T J_j`` (weighted, the spin projected out)."""
        state = self._at(x)
        row = self._per_row(self._scales(state)[0])
        J = self._projected(state)[:3] * row
        m = self.tracks.n_tracks
        out = np.empty((m, 3, 3))
        for i in range(3):
            for k in range(i, 3):
                out[:, i, k] = out[:, k, i] = self.tracks.track_sums(np.einsum("sn,sn->n", J[i], J[k]))
        return out


def make_rigid_line_factor(line_key: int, tracks, K, circles, phi0, theta, *, sigma_px: float = 1.0,
                           robust=None, tol: float = CIRCLE_TOL, max_evaluations: int = 30,
                           intrinsics_key: int | None = None) -> RigidLineFactor:
    """One rigid-spin variable-projection factor for all framed tracks of one measurement, keyed on its line variable.

    Args:
        line_key: key of the measurement's ``gtsam.Rot3`` line variable.
        tracks: a :class:`RigidTracks`, or per track ``(ideal pixels (N_j, 2), frames (N_j,))``.
        K: (3, 3) intrinsic matrix.
        circles: (m, 2) initial (d, r) per track; phi0: (m,) initial phase offsets (held where they fix the gauge);
        theta: (F,) initial spin angle of each frame seen, in the order of ``tracks.frame_ids`` (ascending).
        sigma_px: pixel noise per image coordinate.
        robust: as :func:`.coaxial.make_coaxial_line_factor` (per track, on its whole whitened norm).
        tol, max_evaluations: the inner solve's relative decrement tolerance and evaluation budget.
        intrinsics_key: key of a ``gtsam.Cal3_S2`` variable: the intrinsics are then that variable (``K`` is only
            the start of the first solve) and the factor has a second Jacobian, (2N, 5) wrt its tangent
            ``(fx, fy, s, cx, cy)``. The ``tracks``' pixels stay as given (undistorted with the camera's own
            intrinsics).

    Returns:
        :class:`RigidLineFactor`; add ``.factor`` to the graph.
    """
    if not isinstance(tracks, RigidTracks):
        tracks = RigidTracks(tracks)
    return RigidLineFactor(line_key, tracks, K, circles, phi0, theta, sigma_px, robust, tol=tol,
                           max_evaluations=max_evaluations, intrinsics_key=intrinsics_key)

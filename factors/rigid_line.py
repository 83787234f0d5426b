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

Synced (an :class:`EncoderPrior`): the spinning joint's own readings put a prior on every frame's angle,
``theta_f = sign * q(t_f + delta)`` (``q`` the readings interpolated, ``t_f`` the frame's time on the camera's clock,
``delta`` the offset of the encoder's clock), one extra residual per frame ``(theta_f - sign q(t_f + delta)) / sigma``.
It is a diagonal term in the frames' block of the inner normal equations (the Schur elimination is unchanged), the
gauge is then fixed by the readings (no ``phi0`` is held), and with ``time_key`` the offset ``delta`` is an outer
variable (a ``gtsam`` Vector1, seconds) whose column is the prior rows' derivative ``-sign q'(t_f + delta)``,
projected as the line's columns are.
"""

from __future__ import annotations

import gtsam
import numpy as np

from .coaxial import PREDICT_MAX_RAD, CoaxialLineFactor, _robust_terms
from .coaxial_solve import CIRCLE_TOL
from .coaxial_tracks import CoaxialTracks
from .geometry import cal3_s2
from .rigid import _track_components, initial_spin

__all__ = ["EncoderPrior", "RigidLineFactor", "RigidTracks", "closest_spin", "make_rigid_line_factor"]

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


def readings_cover(frame_times, times) -> bool:
    """Whether every frame time lies within the readings' ``times`` (encoder clock), or beyond them by at most their
    median interval (where :class:`EncoderPrior`'s line beyond the readings is one step of theirs)."""
    frame_times, times = np.asarray(frame_times, dtype=float), np.asarray(times, dtype=float)
    step = float(np.median(np.diff(times)))
    return bool(frame_times.min() >= times[0] - step and frame_times.max() <= times[-1] + step)


class EncoderPrior:
    """Readings of the spinning joint as a prior on a rigid spin's per-frame angles (synced mode).

    Frame ``f``'s angle is ``sign * q(frame_times[f] + delta)``: ``q`` the readings smoothed and interpolated,
    ``delta`` the encoder clock's offset from the camera's (s). ``sign`` is +1 when the line variable's axis (its
    second column) points along the joint's axis (the angle turns features right-handed about it), else -1.

    ``q`` is a local quadratic fit (weighted least squares, tricube weights over ``smoothing_s``) evaluated at each
    reading, its values and slopes joined by cubic Hermite segments: continuous with a continuous derivative, so
    that ``delta``'s column is; linear beyond the readings. The smoothing matters for ``delta``: its column is the
    readings' rate, and finite differences of noisy readings 10 ms apart (0.02 deg noise at 100 per second) put
    noise of ~0.07 rad/s on it at every frame, which the offset's information counted as signal (its 1 sigma came
    out 0.74x the Cramér-Rao bound's on the ramped spins of ``benchmarks/accuracy.py --synced``).

    Args:
        frame_times: (F,) the frames' times on the camera's clock (s), in the order of the tracks' ``frame_ids``.
        times: (K,) the readings' times on the encoder's clock (s), K >= 2, strictly increasing.
        angles: (K,) the joint's readings (rad; unwrapped here: a joint reported in [-pi, pi) is continuous).
        sigma_rad: each frame's prior sigma (the readings' noise and jitter, rad).
        sign: +1 or -1 (see above).
        smoothing_s: the local fit's window (s); 0: the readings as they are (finite-difference slopes).
    """

    __slots__ = ("frame_times", "times", "angles", "sigma", "sign", "_values", "_slopes")

    def __init__(self, frame_times, times, angles, sigma_rad: float, sign: float = 1.0,
                 smoothing_s: float = 0.1):
        self.frame_times = np.array(frame_times, dtype=float).reshape(-1)
        self.times = np.array(times, dtype=float).reshape(-1)
        self.angles = np.unwrap(np.array(angles, dtype=float).reshape(-1))
        if len(self.times) < 2 or len(self.angles) != len(self.times):
            raise ValueError(f"need at least 2 readings with one angle each, got {len(self.times)} times and "
                             f"{len(self.angles)} angles")
        for name, a in (("frame_times", self.frame_times), ("times", self.times), ("angles", self.angles)):
            if not np.all(np.isfinite(a)):
                raise ValueError(f"encoder {name} must be finite")
        if np.any(np.diff(self.times) <= 0):
            i = int(np.flatnonzero(np.diff(self.times) <= 0)[0])
            raise ValueError(f"encoder times must be strictly increasing: reading {i + 1} at {self.times[i + 1]} s "
                             f"follows {self.times[i]} s")
        if not np.isfinite(sigma_rad) or sigma_rad <= 0:
            raise ValueError(f"sigma_rad must be a positive angle, got {sigma_rad!r}")
        if sign not in (1, -1, 1.0, -1.0):
            raise ValueError(f"sign must be +1 or -1, got {sign!r}")
        if not np.isfinite(smoothing_s) or smoothing_s < 0:
            raise ValueError(f"smoothing_s must be a window >= 0 s, got {smoothing_s!r}")
        self.sigma, self.sign = float(sigma_rad), float(sign)
        self._values, self._slopes = _smoothed(self.times, self.angles, float(smoothing_s))

    def covers(self, delta: float = 0.0) -> bool:
        """Whether every frame's time (plus ``delta``) lies within the readings (:func:`readings_cover`)."""
        return readings_cover(self.frame_times + delta, self.times)

    def rate_noise(self, delta: float, frames: int = 15) -> float:
        """The variance (rad^2/s^2) that the readings' own noise puts on the frames' rates (``at``'s derivative),
        read from the rates themselves: their robust scatter (1.4826 median absolute deviation) about their running
        mean over ``frames`` frames, which a spin's real changes of speed hardly leave."""
        order = np.argsort(self.frame_times)
        rate = self.at(delta)[1][order]
        if len(rate) <= 2 * frames:  # (no rate with a full running mean on each side)
            return 0.0
        smooth = np.convolve(rate, np.full(frames, 1.0 / frames), mode="same")
        inner = slice(frames, len(rate) - frames)
        scatter = 1.4826 * float(np.median(np.abs(rate[inner] - smooth[inner])))
        return scatter**2 * frames / (frames - 1)  # (the running mean shares 1/frames of each rate's noise)

    def at(self, delta: float) -> tuple[np.ndarray, np.ndarray]:
        """(F,) the frames' prior angles ``sign * q(t_f + delta)`` and (F,) their derivatives wrt ``delta``."""
        t, q, m = self.times, self._values, self._slopes
        x = self.frame_times + float(delta)
        i = np.clip(np.searchsorted(t, x, side="right") - 1, 0, len(t) - 2)
        h = t[i + 1] - t[i]
        u = np.clip((x - t[i]) / h, 0.0, 1.0)
        u2, u3 = u * u, u * u * u
        value = ((2 * u3 - 3 * u2 + 1) * q[i] + (u3 - 2 * u2 + u) * h * m[i] + (3 * u2 - 2 * u3) * q[i + 1]
                 + (u3 - u2) * h * m[i + 1])
        rate = (6 * u2 - 6 * u) * (q[i] - q[i + 1]) / h + (3 * u2 - 4 * u + 1) * m[i] + (3 * u2 - 2 * u) * m[i + 1]
        before, after = x < t[0], x > t[-1]  # linear beyond the readings
        value = np.where(before, q[0] + m[0] * (x - t[0]), np.where(after, q[-1] + m[-1] * (x - t[-1]), value))
        rate = np.where(before, m[0], np.where(after, m[-1], rate))
        return self.sign * value, self.sign * rate


def _smoothed(t: np.ndarray, q: np.ndarray, window: float) -> tuple[np.ndarray, np.ndarray]:
    """Values and slopes at the readings ``(t, q)``: a quadratic fitted about each reading to those within
    ``window / 2`` (tricube weights; at least two neighbours on each side, where the readings have them: at least
    three readings), or with ``window`` 0 (or fewer than five readings) the readings and their finite-difference
    slopes."""
    if window <= 0 or len(t) < 5:
        slopes = np.empty_like(q)
        slopes[1:-1] = (q[2:] - q[:-2]) / (t[2:] - t[:-2])
        slopes[0], slopes[-1] = (q[1] - q[0]) / (t[1] - t[0]), (q[-1] - q[-2]) / (t[-1] - t[-2])
        return q.copy(), slopes
    n = len(t)
    lo = np.minimum(np.searchsorted(t, t - window / 2), np.maximum(np.arange(n) - 2, 0))
    hi = np.maximum(np.searchsorted(t, t + window / 2, side="right"), np.minimum(np.arange(n) + 3, n))
    width = int(np.max(hi - lo))
    index = lo[:, None] + np.arange(width)[None, :]
    inside = index < hi[:, None]
    index = np.minimum(index, n - 1)
    dt = t[index] - t[:, None]
    # (every reading inside weighs: the farthest 0.12 of the nearest)
    reach = np.maximum(np.abs(np.where(inside, dt, 0.0)).max(axis=1, keepdims=True), 1e-300) * 1.25
    w = np.where(inside, (1.0 - np.abs(dt / reach) ** 3) ** 3, 0.0)
    scale = reach  # (the columns 1, dt/scale, (dt/scale)^2: well conditioned)
    basis = np.stack([np.ones_like(dt), dt / scale, (dt / scale) ** 2], axis=-1)  # (n, width, 3)
    normal = np.einsum("nk,nki,nkj->nij", w, basis, basis)
    rhs = np.einsum("nk,nki,nk->ni", w, basis, q[index] - q[:, None])
    c = np.linalg.solve(normal, rhs[..., None])[..., 0]
    return q + c[:, 0], c[:, 1] / scale[:, 0]


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

    def __init__(self, tracks: RigidTracks, ev: _Inner, w_pixel: np.ndarray, held: np.ndarray,
                 frame_weight: float | None = None):
        m, F = tracks.n_tracks, tracks.n_frames
        self.tracks = tracks
        self.frame_weight = frame_weight  # the encoder prior's weight per frame angle (synced), or None
        a = ev.a
        wa = a * w_pixel  # (3, 2, N)
        P = np.einsum("isn,ksn->ikn", wa, a)  # (3, 3, N): per pixel, products of the (d, r, phi) derivatives
        A = tracks.track_sums(P.reshape(9, -1)).reshape(3, 3, m)
        D = np.bincount(tracks.frame, weights=P[2, 2], minlength=F)
        if frame_weight is not None:
            D = D + frame_weight
        self.root = np.sqrt(np.maximum(D, 1e-300))  # D^1/2
        # C = B D^-1/2, B (3m, F) the track-frame block of the normal matrix, S = A - C C^T, all by frame groups
        self._C = np.zeros(tracks._coupling_size)
        self._C[tracks._coupling] = (P[:, 2] / self.root[tracks.frame]).reshape(-1)
        S = np.zeros((3 * m, 3 * m))
        idx = np.arange(m)
        S.reshape(m, 3, m, 3)[idx, :, idx, :] = A.transpose(2, 0, 1)
        for _, _, _, block, Cg in self._blocks():
            S[block] -= Cg @ Cg.T
        S[held, :] = 0.0
        S[:, held] = 0.0
        S[held, held] = 1.0
        self.S, self.held, self.wa = S, held, wa

    def _blocks(self):
        """Per frame group: its rows, first frame, end, the rows' ``np.ix_`` block and its part of C (rows x
        frames)."""
        for rows, first, end, block, offset in self.tracks._groups:
            yield rows, first, end, block, self._C[offset:offset + len(rows) * (end - first)].reshape(-1, end - first)

    def project(self, V: np.ndarray, gradients: bool = False, frame_V: np.ndarray | None = None
                ) -> tuple[np.ndarray, ...]:
        """``(J^T W J)^-1 J^T W V`` for per-pixel columns ``V`` (q, 2, N) (and, synced, their prior rows ``frame_V``
        (F, q)): (3m, q) and (F, q); with ``gradients`` also ``J^T W V`` (held entries 0)."""
        tracks = self.tracks
        m, F = tracks.n_tracks, tracks.n_frames
        q = V.shape[0]
        G = np.einsum("isn,qsn->iqn", self.wa, V)  # (3, q, N)
        gt = tracks.track_sums(G.reshape(3 * q, -1)).reshape(3, q, m).transpose(2, 0, 1).reshape(3 * m, q)
        gf = np.bincount(tracks._frame_index(q), weights=G[2].reshape(-1), minlength=F * q).reshape(F, q)
        if frame_V is not None:
            gf = gf + self.frame_weight * frame_V
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

    __slots__ = ("rot", "R", "K", "delta", "ev", "converged", "evaluations", "normal", "X", "prior", "_J", "_Jf")

    def __init__(self, rot, R, ev: _Inner, converged: bool, evaluations: int, normal: _Normal, X: np.ndarray,
                 K: np.ndarray, delta: float = 0.0, prior: tuple[np.ndarray, np.ndarray] | None = None):
        self.rot, self.R, self.K, self.delta, self.ev = rot, R, K, delta, ev
        self.converged, self.evaluations = converged, evaluations
        self.normal = normal  # the inner normal equations at ev, weighted by its IRLS weights
        # (3m + F, q) (J^T W J)^-1 J^T W H of the outer columns (at ev, by normal): the line's 3, then with
        # intrinsics their 5 (H_K), then with a time offset its 1
        self.X = X
        self.prior = prior  # synced: (F,) the prior rows' unwhitened residuals and (F,) their delta derivatives
        self._J = None  # (q, 2, N) P H of the pixel rows
        self._Jf = None  # synced: (q, F) P H of the prior rows (unwhitened)

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
                 intrinsics_key: int | None = None, encoder: EncoderPrior | None = None, time_key: int | None = None,
                 time_offset: float = 0.0):
        circles = np.array(circles, dtype=float).reshape(-1, 2)
        phi0 = np.array(phi0, dtype=float).reshape(-1)
        theta = np.array(theta, dtype=float).reshape(-1)
        if len(circles) != tracks.n_tracks or len(phi0) != tracks.n_tracks:
            raise ValueError(f"need one (d, r) and one phi0 per track ({tracks.n_tracks}), got {len(circles)} "
                             f"and {len(phi0)}")
        if len(theta) != tracks.n_frames:
            raise ValueError(f"need one spin angle per frame seen ({tracks.n_frames}), got {len(theta)}")
        if time_key is not None and encoder is None:
            raise ValueError("a time offset variable needs the encoder's readings (encoder=EncoderPrior(...))")
        if encoder is not None and len(encoder.frame_times) != tracks.n_frames:
            raise ValueError(f"need one encoder frame time per frame seen ({tracks.n_frames}), got "
                             f"{len(encoder.frame_times)}")
        if not np.isfinite(time_offset):
            raise ValueError(f"time_offset must be finite seconds, got {time_offset!r}")
        self.K = np.asarray(K, dtype=float).reshape(3, 3)
        self.encoder, self.time_key, self._delta0 = encoder, time_key, float(time_offset)
        self._robust = robust
        #: inner parameters held to fix the gauge (none when the encoder's readings fix it)
        self._held = np.flatnonzero(~tracks.free) if encoder is None else np.zeros(0, dtype=np.int64)
        if encoder is not None:  # the readings' zero: every angle shifted onto them, the phase offsets against
            shift = float(np.mean(theta - encoder.at(self._delta0)[0]))
            theta, phi0 = theta - shift, phi0 + shift
        x0 = np.empty(3 * tracks.n_tracks + tracks.n_frames)
        x0[0:3 * tracks.n_tracks:3], x0[1:3 * tracks.n_tracks:3] = circles[:, 0], circles[:, 1]
        x0[2:3 * tracks.n_tracks:3], x0[3 * tracks.n_tracks:] = phi0, theta
        dim = 2 * tracks.n_points + (0 if encoder is None else tracks.n_frames)
        self._setup(line_key, tracks, x0, sigma_px, robust, tol, max_evaluations, cache_size, dim, intrinsics_key,
                    extra_keys=() if time_key is None else (time_key,))

    # ------------------------------------------------------------------------------------------------------------

    def _irls(self, sse: np.ndarray) -> np.ndarray:
        if self._huber_k is None and self._estimators is None:
            return np.ones(self.tracks.n_tracks)
        return _robust_terms(np.sqrt(np.maximum(sse, 0.0)) / self.sigma_px, self._huber_k, self._estimators)[0]

    def _outer(self, values: gtsam.Values | None = None) -> np.ndarray | None:
        """What the factor reads besides its line: None (fixed intrinsics and time offset), else the intrinsic
        matrix (9, row-major) and the time offset (s) in one vector, from ``values`` (None: the factor's own)."""
        if self.intrinsics_key is None and self.time_key is None:
            return None
        K = self.K if values is None or self.intrinsics_key is None else values.atCal3_S2(self.intrinsics_key).K()
        delta = self._delta0 if values is None or self.time_key is None else float(values.atVector(self.time_key)[0])
        return np.concatenate([np.ravel(K), [delta]])

    def _intrinsics(self, values: gtsam.Values) -> np.ndarray | None:
        return self._outer(values)

    def _at(self, x):
        if isinstance(x, gtsam.Values):
            return self._state(self._rot(x), self._outer(x))
        return self._state(self._rot(x), self._last_K if self._last is not None else self._outer())

    def _solve(self, rot: gtsam.Rot3, R: np.ndarray, outer: np.ndarray | None = None) -> _RigidState:
        """The inner problem at ``rot`` (and ``outer``: the intrinsic matrix and time offset, default the factor's,
        see :meth:`_outer`) by Gauss-Newton (IRLS), from its anchor's solution moved by its first-order change, with
        steps shortened to the trust region ``MAX_CIRCLE_STEP`` and halved where the robust cost rises."""
        tracks = self.tracks
        K = self.K if outer is None else outer[:9].reshape(3, 3)
        delta = self._delta0 if outer is None else float(outer[9])
        intrinsics, timed = self.intrinsics_key is not None, self.time_key is not None
        anchor, w, norm = self._anchor(rot)
        if anchor is None:
            x = self._start.copy()
        else:
            x = anchor.ev.x.copy()
            if norm <= PREDICT_MAX_RAD:
                if intrinsics:  # the intrinsics' change too (Cal3_S2's tangent: fx, fy, s, cx, cy)
                    w = np.concatenate([w, cal3_s2(K).vector() - cal3_s2(anchor.K).vector()])
                if timed:
                    w = np.append(w, delta - anchor.delta)
                change = -anchor.X[:, :len(w)] @ w
                if np.all(np.isfinite(change)) and self._circle_change(x, change) <= MAX_CIRCLE_STEP:
                    x += change
        m3 = 3 * tracks.n_tracks
        prior, frame_weight = None, None
        if self.encoder is not None:
            target, rate = self.encoder.at(delta)
            frame_weight = 1.0 / self.encoder.sigma**2
        ev = _Inner(tracks, K, R, x)
        cost = self._cost(ev.sse) + self._prior_cost(x, target if self.encoder is not None else None)
        converged, evaluations = False, 1
        while True:
            normal = _Normal(tracks, ev, self._irls(ev.sse)[tracks.track] / self.sigma_px**2, self._held,
                             frame_weight)
            # the outer derivatives ride along (one factorisation): the projection the Jacobian needs if this is
            # the last evaluation
            columns = [ev.e[None], ev.H_R] + ([ev.H_K] if intrinsics else []) + (
                [np.zeros((1,) + ev.e.shape)] if timed else [])
            frame_V = None
            if self.encoder is not None:  # the prior rows: residual, zero for the line and intrinsics, -q' for delta
                eps = x[m3:] - target
                frame_V = np.zeros((tracks.n_frames, sum(c.shape[0] for c in columns)))
                frame_V[:, 0] = eps
                if timed:
                    frame_V[:, -1] = -rate
                prior = (eps, rate)
            xt, xf, gt, gf = normal.project(np.concatenate(columns), gradients=True, frame_V=frame_V)
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
                trial_cost = self._cost(trial.sse) + self._prior_cost(
                    x + t * step, target if self.encoder is not None else None)
                if trial_cost <= cost or evaluations >= self.max_evaluations or t < 1e-3:
                    break
                t *= 0.5
            if not trial_cost <= cost:
                break
            x, ev, cost = x + t * step, trial, trial_cost
        state = _RigidState(rot, R, ev, converged, evaluations, normal, np.concatenate(projected), K, delta, prior)
        self.solves += 1
        self.evaluations += evaluations
        self.work += evaluations
        return state

    def _circle_change(self, x: np.ndarray, change: np.ndarray) -> float:
        """The largest change of a track's circle ``(d, r)`` relative to its radius."""
        m = self.tracks.n_tracks
        circles, moves = x[:3 * m].reshape(m, 3)[:, :2], change[:3 * m].reshape(m, 3)[:, :2]
        return float(np.max(np.abs(moves).max(axis=1) / np.maximum(np.abs(circles[:, 1]), 1e-12)))

    def _prior_cost(self, x: np.ndarray, target: np.ndarray | None) -> float:
        """Half the encoder prior's whitened chi-square at inner point ``x`` (0 unsynced)."""
        if target is None:
            return 0.0
        eps = (x[3 * self.tracks.n_tracks:] - target) / self.encoder.sigma
        return float(0.5 * eps @ eps)

    def _cost(self, sse: np.ndarray) -> float:
        """The robust cost (sum of losses of the tracks' whitened norms)."""
        x = np.sqrt(np.maximum(sse, 0.0)) / self.sigma_px
        if self._huber_k is None and self._estimators is None:
            return float(0.5 * np.sum(x * x))
        return float(np.sum(_robust_terms(x, self._huber_k, self._estimators)[1]))

    def _per_row(self, per_track: np.ndarray) -> np.ndarray:
        return per_track[self.tracks.track]

    def _residual(self, state: _RigidState, scale: np.ndarray) -> np.ndarray:
        pixels = (state.ev.e * self._per_row(scale)).T.reshape(-1)
        if state.prior is None:
            return pixels
        return np.concatenate([pixels, state.prior[0] / self.encoder.sigma])

    def _projected(self, state: _RigidState) -> np.ndarray:
        """(q, 2, N) ``P H`` of the pixel rows (unweighted rows; the projection ``state.X``, made with the state's
        last inner step, weighted by the IRLS weights of the state's residuals): the line's 3 columns, then with an
        intrinsics variable its 5 (``P H_K``), then with a time offset its 1. Synced, ``state._Jf`` (q, F) holds
        the prior rows' (unwhitened)."""
        if state._J is None:
            tracks, ev = self.tracks, state.ev
            m, q = tracks.n_tracks, state.X.shape[1]
            xt, xf = state.X[:3 * m], state.X[3 * m:]
            # J X per pixel: sum over (d, r, phi0) of a * X_track, plus a_phi * X_theta
            Xt = xt.reshape(m, 3, q)[tracks.track]  # (N, param, column)
            Xf = xf[tracks.frame]  # (N, column)
            XtT = Xt.transpose(1, 2, 0)  # (param, column, N)
            JX = (ev.a[0][None] * XtT[0][:, None] + ev.a[1][None] * XtT[1][:, None]
                  + ev.a[2][None] * (XtT[2] + Xf.T)[:, None])
            H = [ev.H_R] + ([ev.H_K] if self.intrinsics_key is not None else [])
            if self.time_key is not None:  # the pixels do not depend on the time offset
                H.append(np.zeros((1,) + ev.e.shape))
            state._J = (H[0] if len(H) == 1 else np.concatenate(H)) - JX
            if state.prior is not None:  # the prior rows: d theta_f / d inner = 1, d/d delta = -q'
                Jf = -xf.T.copy()
                if self.time_key is not None:
                    Jf[-1] -= state.prior[1]
                state._Jf = Jf
        return state._J

    def _columns(self, state: _RigidState, scale: np.ndarray, columns: slice) -> np.ndarray:
        """(2N (+ F synced), c) the factor's Jacobian in the outer ``columns`` (see :meth:`_projected`), rows
        scaled (the prior rows by the encoder's sigma)."""
        J = self._projected(state)[columns] * self._per_row(scale)[None, None]
        J = J.transpose(2, 1, 0).reshape(-1, J.shape[0])
        if state.prior is None:
            return J
        return np.concatenate([J, state._Jf[columns].T / self.encoder.sigma])

    def _jacobian(self, state: _RigidState, scale: np.ndarray) -> np.ndarray:
        """(2N, 3) ``P H_R`` (synced: (2N + F, 3)), rows scaled."""
        return self._columns(state, scale, slice(0, 3))

    def _jacobian_intrinsics(self, state: _RigidState, scale: np.ndarray) -> np.ndarray:
        """(2N, 5) ``P H_K`` (``gtsam.Cal3_S2``'s tangent; synced: (2N + F, 5)), rows scaled."""
        return self._columns(state, scale, slice(3, 8))

    def _outer_jacobians(self, state: _RigidState, scale: np.ndarray) -> list[np.ndarray]:
        out = [] if self.intrinsics_key is None else [self._jacobian_intrinsics(state, scale)]
        if self.time_key is not None:
            q = 3 + (5 if self.intrinsics_key is not None else 0)
            out.append(self._columns(state, scale, slice(q, q + 1)))
        return out

    # ------------------------------------------------------------------------------------------------------------
    # inspection

    @property
    def inner_dof(self) -> int:
        """Parameters projected out of the factor: ``(d, r, phi0)`` per track, less the held ``phi0`` (one per
        group of tracks linked by shared frames; none when synced), and one spin angle per frame."""
        return 3 * self.tracks.n_tracks - len(self._held) + self.tracks.n_frames

    def pixel_dof(self, x=None) -> float:
        """Degrees of freedom of the pixels' residuals at ``x``: ``2N`` less the inner parameters they fit (as
        :attr:`inner_dof`); synced, each frame's angle counts by the pixels' share of its information (the readings
        hold the rest)."""
        dof = 2 * self.tracks.n_points - self.inner_dof
        if self.encoder is None:
            return float(dof)
        information = self._at(x).normal.root ** 2  # the pixels' and the prior's: the prior's share is given back
        return float(dof + np.sum(1.0 / (self.encoder.sigma**2 * information)))

    def error(self, x=None) -> float:
        """The factor's error (GTSAM's): the pixels' (half the whitened chi-square, or the robust losses), plus
        half the encoder prior's whitened chi-square when synced."""
        state = self._at(x)
        pixels = super().error(x)
        return pixels if state.prior is None else pixels + 0.5 * float(np.sum((state.prior[0] / self.encoder.sigma)
                                                                              ** 2))

    def time_offset(self, x=None) -> float:
        """The time offset (s) of the state at ``x`` (the factor's fixed one without a time variable)."""
        return self._at(x).delta

    def readings_test(self, x=None) -> tuple[float, int] | None:
        """Do the readings agree with the spin the tracks show? The likelihood ratio of the synced fit against the
        same tracks with free angles at the same line (``x``): twice the difference of their errors, and its
        degrees of freedom where they agree (one per frame, less one per group of tracks linked by shared frames:
        the constant the phases take up). None unsynced. Far above its chi-square point, the joint's sense, scale
        or clock is wrong, or the readings are noisier than the encoder's sigma says. (The prior's own residuals
        cannot tell: readings far more precise than the tracks hold every angle, wrong or not, and the tracks'
        residuals take the disagreement.)"""
        state = self._at(x)
        if state.prior is None:
            return None
        free = self._free_spin(state, x)
        # at the pixel noise the free fit shows: readings that force wrong angles inflate the synced fit's own
        # estimate of it, which would shrink the statistic (flipped readings had passed)
        free_sse = float(free.track_sse(state.rot).sum())
        variance = max(free_sse / max(free.pixel_dof(state.rot), 1.0), 1e-300)
        pixels = (float(state.sse.sum()) - free_sse) / variance
        statistic = pixels + float(np.sum((state.prior[0] / self.encoder.sigma) ** 2))
        return statistic, self.tracks.n_frames - len(self.tracks.components)

    def dating(self, x=None) -> tuple[float, float] | None:
        """What dates the frames here: the time offset's information from this factor at ``x`` (its column's
        ``J^T J``, s^-2) and the part of it that the readings' own noise makes (their rates' variance through each
        frame's angle: a rate that is noise dates nothing, but counts as information all the same). None without a
        time offset variable."""
        state = self._at(x)
        if state.prior is None or self.time_key is None:
            return None
        J = self._outer_jacobians(state, self._scales(state)[0])[-1][:, 0]
        weight = 1.0 / self.encoder.sigma**2
        pixels = np.maximum(state.normal.root**2 - weight, 0.0)  # each frame's angle's information from the pixels
        noise = float(np.sum(self.encoder.rate_noise(state.delta) * weight * pixels / (pixels + weight)))
        return float(J @ J), noise

    def _free_spin(self, state: _RigidState, x) -> RigidLineFactor:
        """The same tracks with free angles (no readings), started from the closest phases on the factor's start
        circles (not from this state's: readings that never move, say, drag the circles where no spin fits)."""
        tracks, m3 = self.tracks, 3 * self.tracks.n_tracks
        circles = np.column_stack([self._start[0:m3:3], self._start[1:m3:3]])
        phi0, theta = closest_spin(tracks, state.K, state.R, circles)
        return RigidLineFactor(self.line_key, tracks, state.K, circles, phi0, theta, self.sigma_px, self._robust,
                               tol=self.tol, max_evaluations=self.max_evaluations)

    def encoder_residuals(self, x=None) -> np.ndarray | None:
        """(F,) the frames' angles less the encoder prior's (rad) at ``x``; None unsynced."""
        prior = self._at(x).prior
        return None if prior is None else prior[0].copy()

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

    def _pixel_columns(self, intrinsics: bool) -> int:
        """How many outer columns the tracks' scores and information span: the line's 3, with ``intrinsics`` (and
        an intrinsics variable) its 5 too (the time offset, which moves no pixel, never)."""
        return 8 if intrinsics and self.intrinsics_key is not None else 3

    def track_scores(self, x=None, intrinsics: bool = False) -> np.ndarray:
        """(m, 3) each track's part ``J_j^T e_j`` of the gradient at the line variable (whitened, robust-weighted);
        with ``intrinsics`` (m, 8): at the line and the intrinsics variable (``gtsam.Cal3_S2``'s tangent), where the
        factor has one."""
        state = self._at(x)
        irls = self._scales(state)[0]
        row = self._per_row(irls)
        q = self._pixel_columns(intrinsics)
        Je = np.einsum("lsn,sn->ln", self._projected(state)[:q], state.ev.e) * row * row
        return self.tracks.track_sums(Je).T

    def track_translation_scores(self, x=None, intrinsics: bool = False) -> np.ndarray:
        """(m, 3, 2) how each track's score (:meth:`track_scores`) moves when all its pixels move by one image
        translation ``t`` (px): ``V_j t`` to first order, ``V_j = -sum_n P_n^T w_n`` (the residual is the model's pixel
        less the observed; ``P`` the projected Jacobian,
        whose projection carries the re-solved circles, phases and spin angles; ``w`` the row weights squared); with
        ``intrinsics`` (m, 8, 2), as :meth:`track_scores`. See
        :meth:`.coaxial.CoaxialLineFactor.track_translation_scores`."""
        state = self._at(x)
        row = self._per_row(self._scales(state)[0])
        q = self._pixel_columns(intrinsics)
        P = self._projected(state)[:q] * -(row * row)
        return np.stack([self.tracks.track_sums(P[:, u]).T for u in range(2)], axis=-1)

    def track_information(self, x=None, intrinsics: bool = False) -> np.ndarray:
        """(m, 3, 3) each track's ``J_j^T J_j`` (weighted, the spin projected out); with ``intrinsics`` (m, 8, 8),
        as :meth:`track_scores`."""
        state = self._at(x)
        row = self._per_row(self._scales(state)[0])
        q = self._pixel_columns(intrinsics)
        J = self._projected(state)[:q] * row
        m = self.tracks.n_tracks
        out = np.empty((m, q, q))
        for i in range(q):
            for k in range(i, q):
                out[:, i, k] = out[:, k, i] = self.tracks.track_sums(np.einsum("sn,sn->n", J[i], J[k]))
        return out


def closest_spin(tracks: RigidTracks, K, R, circles) -> tuple[np.ndarray, np.ndarray]:
    """A rigid spin's start from circles: ``(phi0 (m,), theta (F,))`` (:func:`.rigid.initial_spin` of the closest
    phases of the tracks' pixels on the circles ``(m, 2)`` about the line ``R``), theta in ``tracks.frame_ids``'
    order."""
    split = np.cumsum(tracks.counts)[:-1]
    circles = np.asarray(circles, dtype=float).reshape(-1, 2)
    phases = CoaxialTracks(K, np.split(tracks.pixels, split)).phases(R, circles[:, 0], circles[:, 1])
    first = int(tracks.frame_ids[0])
    spin = initial_spin(list(zip(np.split(tracks.frame_ids[tracks.frame], split), np.split(phases, split),
                                 strict=True)), int(tracks.frame_ids[-1]) - first + 1, first)
    return spin.phi0, spin.theta[0][tracks.frame_ids - first]


def make_rigid_line_factor(line_key: int, tracks, K, circles, phi0, theta, *, sigma_px: float = 1.0,
                           robust=None, tol: float = CIRCLE_TOL, max_evaluations: int = 30,
                           intrinsics_key: int | None = None, encoder: EncoderPrior | None = None,
                           time_key: int | None = None, time_offset: float = 0.0) -> RigidLineFactor:
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
        encoder: synced mode: an :class:`EncoderPrior` (one frame time per frame seen) puts the spinning joint's
            readings as a prior on every frame's angle (the factor then has F more residuals, after the 2N).
        time_key: with ``encoder``, key of a ``gtsam`` Vector1 variable: the encoder clock's offset from the
            camera's (s), the factor's last key (Jacobian (2N + F, 1)); without it the offset is ``time_offset``.

    Returns:
        :class:`RigidLineFactor`; add ``.factor`` to the graph.
    """
    if not isinstance(tracks, RigidTracks):
        tracks = RigidTracks(tracks)
    return RigidLineFactor(line_key, tracks, K, circles, phi0, theta, sigma_px, robust, tol=tol,
                           max_evaluations=max_evaluations, intrinsics_key=intrinsics_key, encoder=encoder,
                           time_key=time_key, time_offset=time_offset)

"""The variable-projection factor on a measurement's line variable: all its tracks, their circles projected out.

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

The tracks are a :class:`.coaxial_tracks.CoaxialTracks` (also importable from here), which evaluates them all at
once; the circle solve is :func:`.coaxial_solve.project_circles`.
"""

from __future__ import annotations

from collections import OrderedDict

import gtsam
import numpy as np

from .coaxial_solve import CIRCLE_TOL, _inverse2, project_circles
from .coaxial_tracks import CoaxialTracks

__all__ = ["CoaxialLineFactor", "CoaxialTracks", "make_coaxial_line_factor"]

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
        self._setup(line_key, tracks, (circles[:, 0].copy(), circles[:, 1].copy()), sigma_px, robust, tol,
                    max_evaluations, cache_size, tracks.n_points)

    def _setup(self, line_key: int, tracks, start, sigma_px: float, robust, tol: float, max_evaluations: int,
               cache_size: int, dim: int, intrinsics_key: int | None = None, extra_keys=()) -> None:
        """What every projected-out line factor holds (this and :class:`.rigid_line.RigidLineFactor`): its
        settings, the start of its first solve, the caches and anchors, the diagnostics, and the CustomFactor of
        dimension ``dim``, bound to a twin (see the class docstring); with ``intrinsics_key`` the factor's second
        key is a ``gtsam.Cal3_S2`` (only factors that implement :meth:`_jacobian_intrinsics`); ``extra_keys`` follow
        (only factors whose :meth:`_outer_jacobians` give theirs)."""
        if not np.isfinite(sigma_px) or sigma_px <= 0:
            raise ValueError(f"sigma_px must be a positive number of pixels, got {sigma_px!r}")
        self.line_key = line_key
        self.intrinsics_key = intrinsics_key
        self.tracks = tracks
        self.sigma_px = float(sigma_px)
        self.counts = tracks.counts
        self.tol = float(tol)
        self.max_evaluations = int(max_evaluations)
        self._start = start
        self._huber_k, self._estimators = _robust_setup(robust, tracks.counts)
        self._cache: OrderedDict[bytes, _LineState] = OrderedDict()
        #: anchors, the only starts of the solves (see _anchor): the states of the last linearisation points (LM's
        #: accepted lines), never evicted by trial lines, and the first state solved
        self._pinned: OrderedDict[bytes, _LineState] = OrderedDict()
        self._home: _LineState | None = None
        self._cache_size = max(1, int(cache_size))
        self._last: _LineState | None = None
        self._last_K: np.ndarray | None = None
        #: diagnostics: solves, the evaluations they took, and their work in passes over all tracks; errors refused
        #: (outside the trust region, see _refused)
        self.refused = 0
        self.solves = 0
        self.evaluations = 0
        self.work = 0.0
        twin = object.__new__(type(self))  # same attributes, no factor slot: no cycle through C++ (see above)
        twin.__dict__ = self.__dict__
        keys = [line_key] + ([] if intrinsics_key is None else [intrinsics_key]) + list(extra_keys)
        self.factor = gtsam.CustomFactor(gtsam.noiseModel.Unit.Create(dim), keys, twin._error_function)

    # ------------------------------------------------------------------------------------------------------------

    def _error_function(self, this, values, H):
        rot = values.atRot3(self.line_key)
        K = self._intrinsics(values)
        if H is None and self._refused(rot, K):
            self.refused += 1
            return np.full(this.dim(), REFUSED_RESIDUAL)
        state = self._state(rot, K)
        if H is None:
            return self._residual(state, self._scales(state)[1])
        key = self._key(state.R, K)
        self._pinned[key] = state
        self._pinned.move_to_end(key)
        if len(self._pinned) > PINNED_STATES:
            self._pinned.popitem(last=False)
        irls = self._scales(state)[0]
        H[0] = self._jacobian(state, irls)
        for i, J in enumerate(self._outer_jacobians(state, irls), start=1):
            H[i] = J
        return self._residual(state, irls)

    def _intrinsics(self, values: gtsam.Values) -> np.ndarray | None:
        """The intrinsic matrix of the factor's ``gtsam.Cal3_S2`` variable in ``values`` (None: fixed intrinsics)."""
        if self.intrinsics_key is None:
            return None
        return np.ascontiguousarray(values.atCal3_S2(self.intrinsics_key).K())

    @staticmethod
    def _key(R: np.ndarray, K: np.ndarray | None) -> bytes:
        """The cache key of a line (and intrinsic matrix)."""
        return R.tobytes() if K is None else R.tobytes() + K.tobytes()

    def _jacobian_intrinsics(self, state, scale: np.ndarray) -> np.ndarray:
        raise NotImplementedError(f"{type(self).__name__} has fixed intrinsics")

    def _outer_jacobians(self, state, scale: np.ndarray) -> list[np.ndarray]:
        """The Jacobians of the factor's keys after the line (in key order), rows scaled."""
        return [] if self.intrinsics_key is None else [self._jacobian_intrinsics(state, scale)]

    def _at(self, x):
        """The state at ``x`` (see the class docstring; with an intrinsics variable, a ``gtsam.Values`` gives both
        and anything else the line at the intrinsics last evaluated)."""
        if isinstance(x, gtsam.Values):
            return self._state(self._rot(x), self._intrinsics(x))
        if self._last is not None:
            return self._state(self._rot(x), self._last_K)
        return self._state(self._rot(x), None if self.intrinsics_key is None else self.K)

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

    def _state(self, rot: gtsam.Rot3, K: np.ndarray | None = None) -> _LineState:
        R = np.ascontiguousarray(rot.matrix())
        key = self._key(R, K)
        state = self._cache.get(key)
        if state is not None:
            self._cache.move_to_end(key)
        else:
            state = self._pinned.get(key)
        if state is not None:
            self._last, self._last_K = state, K
            return state
        state = self._solve(rot, R) if K is None else self._solve(rot, R, K)
        self._cache[key] = state
        self._cache.move_to_end(key)
        if len(self._cache) > self._cache_size:
            self._cache.popitem(last=False)
        if self._home is None:
            self._home = state
        self._last, self._last_K = state, K
        return state

    def _solve(self, rot: gtsam.Rot3, R: np.ndarray) -> _LineState:
        """The circles projected out at the line ``rot`` (matrix ``R``), solved from its anchor (:meth:`_anchor`)."""
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
        ev, converged, evaluations, work = project_circles(tracks, R, d0, r0, self.tol,
                                                           self.max_evaluations)
        gram = tracks._gram(ev, 6)
        a, b, c = _inverse2(gram[:, 1, 1], gram[:, 1, 2], gram[:, 2, 2])
        B = gram[:, 1:3, 3:6]
        M = np.stack([a[:, None] * B[:, 0] + b[:, None] * B[:, 1], b[:, None] * B[:, 0] + c[:, None] * B[:, 1]],
                     axis=1)
        state = _LineState(rot, R, ev, gram, converged, evaluations, M, tracks._curvature.copy())
        self.solves += 1
        self.evaluations += evaluations
        self.work += work
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

    def _refused(self, rot: gtsam.Rot3, K: np.ndarray | None = None) -> bool:
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
        key = self._key(np.ascontiguousarray(rot.matrix()), K)
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
        # (a trial line far off can leave a track's circle unsolved, inf: its residual is then not finite and LM
        # refuses the trial)
        with np.errstate(invalid="ignore", over="ignore"):
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

    @property
    def inner_dof(self) -> int:
        """Parameters projected out of the factor (a graph's residual degrees of freedom must count them):
        ``(d, r)`` per track."""
        return 2 * self.tracks.n_tracks

    def circles(self, x=None) -> np.ndarray:
        """(m, 2) projected-out circles (d, r) at the line variable."""
        ev = self._at(x).ev
        return np.column_stack([ev.d, ev.r])

    def track_sse(self, x=None) -> np.ndarray:
        """(m,) sum of squared residuals (px^2) of each track at its projected-out circle."""
        return self._at(x).sse.copy()

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
        return (self._scales(self._at(x))[0] * self.sigma_px) ** 2

    def converged(self, x=None) -> np.ndarray:
        """(m,) whether each track's circle solve converged."""
        return self._at(x).converged.copy()

    def residuals(self, x=None) -> np.ndarray:
        """(N,) signed pixel residuals (unweighted) of all tracks at their projected-out circles."""
        return self.tracks._flat(self._at(x).ev.V[0]).copy()

    def phases(self, x=None) -> np.ndarray:
        """(N,) closest phases in [-pi, pi] at the projected-out circles."""
        ev = self._at(x).ev
        return np.arctan2(self.tracks._flat(ev.s), self.tracks._flat(ev.c))

    def error(self, x=None) -> float:
        """The factor's error (GTSAM's): half the whitened chi-square, or the sum of the robust losses."""
        state = self._at(x)
        scale = self._scales(state)[1]
        return float(0.5 * np.sum(state.sse * scale**2))

    def track_scores(self, x=None, intrinsics: bool = False) -> np.ndarray:
        """(m, 3) each track's score ``J_j^T e_j`` (whitened and robust-weighted, as GTSAM sees the factor): its
        part of the gradient at the line variable.

        ``sum_j s_j s_j^T`` estimates the information the pixels carry when different tracks' errors are
        independent but one track's may be correlated (a tracker's sub-pixel bias that follows a dot): the
        "meat" of a cluster-robust (sandwich) covariance. With white pixel noise of the assumed sigma its
        expectation is :meth:`information`. (``intrinsics``: the intrinsics' columns too, which only the rigid
        spin's factor has.)
        """
        _line_only(self, intrinsics)
        state = self._at(x)
        irls = self._scales(state)[0]
        Je = self._jacobian(state, irls) * self._residual(state, irls)[:, None]
        tracks = self.tracks
        flat_track = tracks._flat(np.broadcast_to(tracks._layout.row_track[:, None], state.ev.V[0].shape))
        return np.stack([np.bincount(flat_track, weights=Je[:, k], minlength=tracks.n_tracks) for k in range(3)],
                        axis=1)

    def track_information(self, x=None, intrinsics: bool = False) -> np.ndarray:
        """(m, 3, 3) each track's ``J_j^T J_j`` (weighted, its circle projected out): its part of
        :meth:`information`, from the per-track sums (no N-sized work)."""
        _line_only(self, intrinsics)
        state = self._at(x)
        w = self._scales(state)[0] ** 2
        G = state.gram
        per_track = G[:, 3:6, 3:6] - np.einsum("jki,jkl->jil", G[:, 1:3, 3:6], state.M)
        return w[:, None, None] * per_track

    def track_translation_scores(self, x=None, intrinsics: bool = False) -> np.ndarray:
        """(m, 3, 2) how each track's score (:meth:`track_scores`, summed: the line's gradient) moves when all its
        pixels move by one image translation ``t`` (px): ``V_j t`` to first order, ``V_j = sum_n J_n^T w_n n_n^T``
        (``J`` the projected Jacobian, whose projection carries the circles' re-solve; ``n`` the residual's
        derivative by the pixel, :meth:`.coaxial_tracks.CoaxialTracks.pixel_normals`; ``w`` the row weights
        squared). A tracker's offset that follows a track (a blob centroid pulled by shading, a corner drifting on a
        surface that turns) ``t_j ~ N(0, tau^2 I)``, independent across tracks, adds ``tau^2 sum_j V_j V_j^T`` to the
        line's meat."""
        _line_only(self, intrinsics)
        state = self._at(x)
        tracks = self.tracks
        irls = self._scales(state)[0]
        J = self._jacobian(state, irls)  # (N, 3), each row scaled by its track's weight
        row = self._per_row(irls)
        normals = tracks.pixel_normals(state.ev)
        flat_track = tracks._flat(np.broadcast_to(tracks._layout.row_track[:, None], state.ev.V[0].shape))
        out = np.empty((tracks.n_tracks, 3, 2))
        for u in range(2):
            weighted = J * tracks._flat(normals[u] * row)[:, None]
            for k in range(3):
                out[:, k, u] = np.bincount(flat_track, weights=weighted[:, k], minlength=tracks.n_tracks)
        return out

    def information(self, x=None) -> np.ndarray:
        """(3, 3) ``J^T J`` of the (weighted) factor: the Schur complement of the full graph's Gauss-Newton
        Hessian, from the per-track sums (no N-sized work)."""
        return self.track_information(x).sum(axis=0)


def _line_only(factor, intrinsics: bool) -> None:
    if intrinsics and factor.intrinsics_key is not None:
        raise NotImplementedError(f"{type(factor).__name__} has no per-track intrinsics columns")


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

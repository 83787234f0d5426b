"""The circles of all tracks of one measurement projected out: each track's ``(d, r)`` at a fixed line variable.

:func:`project_circles` (behind :meth:`.coaxial_tracks.CoaxialTracks.solve_circles` and the variable-projection
factor of :mod:`.coaxial`) projects the circles out: for a fixed line variable ``R``, each track's ``(d, r)``
minimising its sum of squared residuals, by Gauss-Newton vectorised across tracks (per-track 2x2 normal equations
via per-row sums, closed-form solves), with a per-track secant estimate of the curvature term that Gauss-Newton
drops (Dennis-Gay-Welsch), per-track step halving, and only the still-moving tracks evaluated once most have
converged.

The tracks are a :class:`.coaxial_tracks.CoaxialTracks`: the solve evaluates them (``_evaluate``, ``_gram``) and
keeps the secant curvature terms in their ``_curvature``, from one solve to the next.
"""

from __future__ import annotations

import numpy as np

#: Halving steps of :func:`project_circles` before a track's step is given up (it keeps its value).
MAX_HALVINGS = 30
#: The circle solve evaluates only the tracks still moving once their rows are at most this fraction of all rows.
SUBSET_FRACTION = 0.7
#: Relative Gauss-Newton decrement (predicted decrease of a track's sum of squares over that sum) below which a
#: track's circle counts as converged.
CIRCLE_TOL = 1e-10
#: Absolute floor of that decrement per pixel (px^2): noise-free tracks converge to ~1e-10 px.
CIRCLE_ATOL_PX2 = 1e-20


def _inverse2(a: np.ndarray, b: np.ndarray, c: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Entries (a', b', c') of the inverse of the symmetric 2x2 matrices [[a, b], [b, c]] (m,), with a relative ridge
    of 1e-14 so that a singular (indeterminate) circle gets a finite, minimal-norm-like answer; zero matrices give
    zeros."""
    with np.errstate(divide="ignore", invalid="ignore"):  # a track whose sums are not finite gives NaN, not noise
        ridge = 1e-14 * (a + c)
        a, c = a + ridge, c + ridge
        det = a * c - b * b
        inv = np.where(det > 0.0, 1.0 / det, 0.0)
        return c * inv, -b * inv, a * inv


def _steps(S: np.ndarray, curvature: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per-track steps (m, 2) from the Gram sums S (m, 3, 3) of (e, H_d, H_r): Newton's with the secant curvature
    terms (3, m) where that Hessian is positive definite, else Gauss-Newton's; and Gauss-Newton's decrement (m,)."""
    gd, gr = S[:, 1, 0], S[:, 2, 0]
    a, b, c = _inverse2(S[:, 1, 1], S[:, 1, 2], S[:, 2, 2])
    decrement = 0.5 * (gd * (a * gd + b * gr) + gr * (b * gd + c * gr))  # Gauss-Newton's
    Hdd, Hdr, Hrr = S[:, 1, 1] + curvature[0], S[:, 1, 2] + curvature[1], S[:, 2, 2] + curvature[2]
    with np.errstate(invalid="ignore"):  # NaN sums: not Newton's (the comparison is False)
        newton = (Hdd > 0.0) & (Hdd * Hrr - Hdr * Hdr > 0.0)
    a, b, c = (np.where(newton, x, y) for x, y in zip(_inverse2(Hdd, Hdr, Hrr), (a, b, c), strict=True))
    return np.column_stack([-(a * gd + b * gr), -(b * gd + c * gr)]), decrement


class _CircleSolve:
    """The state of one circle solve: the tracks' circles, Gram sums, costs and steps, and which tracks are done."""

    def __init__(self, tracks, R: np.ndarray, d: np.ndarray, r: np.ndarray, tol: float):
        self.tracks, self.R, self.tol = tracks, R, tol
        self.d, self.r = d.copy(), r.copy()
        self.ev = tracks._evaluate(R, self.d, self.r)
        self.S = tracks._gram(self.ev, 3)
        self.atol = CIRCLE_ATOL_PX2 * tracks.counts
        row_track = tracks._layout.row_track
        self.row_counts = np.bincount(row_track, minlength=tracks.n_tracks)
        self.n_rows = max(1, len(row_track))
        self.curvature = tracks._curvature  # (3, m): entries (dd, dr, rr) of S_j
        self.cost = self.S[:, 0, 0].copy()
        self.step, decrement = _steps(self.S, self.curvature)
        with np.errstate(invalid="ignore"):
            self.done = (tracks.counts == 0) | ~(decrement > tol * self.cost + self.atol)
        self.converged = self.done.copy()
        self.halvings = np.zeros(tracks.n_tracks, dtype=np.int64)
        self.evaluations, self.work = 1, 1.0

    def iterate(self) -> None:
        """One trial step of the tracks still moving: accepted where the cost does not rise, else halved."""
        d, r, step = self.d, self.r, self.step
        move = ~self.done
        trial_d = np.where(move, d + step[:, 0], d)
        trial_r = np.where(move, r + step[:, 1], r)
        fraction = self.row_counts[move].sum() / self.n_rows
        active = move if fraction <= SUBSET_FRACTION else None
        previous = self.ev
        self.ev = self.tracks._evaluate(self.R, trial_d, trial_r, active)
        S_trial = self.tracks._gram(self.ev, 3, active)
        self.evaluations += 1
        self.work += fraction if active is not None else 1.0
        cost_trial = S_trial[:, 0, 0]
        with np.errstate(invalid="ignore"):
            accept = move & (cost_trial <= self.cost * (1.0 + 1e-12))
        reject = move & ~accept
        if accept.any():
            self._accept(accept, previous, S_trial, trial_d, trial_r)
        if reject.any():
            self.curvature[:, reject] = 0.0  # back to Gauss-Newton for these tracks
            step[reject] *= 0.5
            self.halvings[reject] += 1
            self.done |= reject & (self.halvings > MAX_HALVINGS)

    def _accept(self, accept, previous, S_trial, trial_d, trial_r) -> None:
        """Take the accepted tracks' trial circles (evaluated in ``self.ev``; ``previous`` the evaluation before)."""
        d, r, S, cost = self.d, self.r, self.S, self.cost
        # secant update of the curvature term where the step started at the previous evaluation
        update = accept & (previous.d == d) & (previous.r == r)
        if update.any():
            _update_curvature(self.tracks, update, previous, self.ev, S[:, 1:3, 0], S_trial[:, 1:3, 0],
                              (trial_d - d, trial_r - r))
        d[accept], r[accept] = trial_d[accept], trial_r[accept]
        cost[accept] = S_trial[:, 0, 0][accept]
        S[accept] = S_trial[accept]
        new_step, new_decrement = _steps(S_trial, self.curvature)
        self.step[accept] = new_step[accept]
        self.halvings[accept] = 0
        with np.errstate(invalid="ignore"):
            finished = accept & ~(new_decrement > self.tol * cost + self.atol)
        self.done |= finished
        self.converged |= finished

    def finish(self):
        """(evaluation at the solution, converged mask, evaluations, work); a track whose last trial was rejected is
        evaluated where it stays."""
        d, r, ev = self.d, self.r, self.ev
        stale = (ev.d != d) | (ev.r != r)
        if stale.any():
            ev = self.tracks._evaluate(self.R, d, r, stale)
            self.evaluations += 1
            self.work += self.row_counts[stale].sum() / self.n_rows
        return ev, self.converged, self.evaluations, self.work


def project_circles(tracks, R: np.ndarray, d: np.ndarray, r: np.ndarray, tol: float = CIRCLE_TOL,
                    max_evaluations: int = 60):
    """Every track's (d, r) minimising its sum of squares at fixed R, vectorised across tracks.

    Gauss-Newton steps augmented, per track, by a secant estimate ``S_j`` of the residuals' curvature term
    ``sum e d2e/dc2`` that Gauss-Newton drops (Dennis, Gay and Welsch's structured update, as NL2SOL's), kept
    from one solve to the next: the steps are then nearly Newton steps, where plain Gauss-Newton converges only
    linearly (slowly for an arc whose residuals are large for its curvature). A step whose cost rises is halved,
    and that track falls back to Gauss-Newton. A track stops once its Gauss-Newton decrement is below ``tol``
    times its sum of squares (+ 1e-20 px^2 per point). Once most tracks have stopped, only the others are
    evaluated.

    Args:
        tracks: the :class:`.coaxial_tracks.CoaxialTracks`.
        R: (3, 3) line variable; d, r: (m,) starting circles (not modified).

    Returns (evaluation at the solution, converged mask (m,), evaluations, work: evaluated rows over all rows).
    """
    solve = _CircleSolve(tracks, R, d, r, tol)
    while not solve.done.all() and solve.evaluations < max_evaluations:
        solve.iterate()
    return solve.finish()


def _update_curvature(tracks, update, previous, ev, g_old, g_new, step) -> None:
    """Dennis-Gay-Welsch update of the tracks' curvature terms ``S`` (symmetric 2x2) after the steps ``s``:
    ``S+ s = y# = (J+ - J)^T e+`` (J the Jacobian wrt (d, r)), with NL2SOL's sizing ``S <- min(1, |s.y#| /
    |s.S s|) S``, where the gradient change ``y = g+ - g`` has ``s.y > 0``."""
    row_track = tracks._layout.row_track
    sel = np.flatnonzero(update[row_track])
    cross = tracks._subset_sums(np.einsum("irl,rl->ri", previous.V[1:3, sel], ev.V[0, sel]), row_track[sel])
    s0, s1 = step[0], step[1]
    Sdd, Sdr, Srr = tracks._curvature
    # (a trial line far off can send a track's gradient to inf: its update is then not made, ``ok`` below)
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        y0, y1 = g_new[:, 0] - g_old[:, 0], g_new[:, 1] - g_old[:, 1]
        p0, p1 = g_new[:, 0] - cross[:, 0], g_new[:, 1] - cross[:, 1]  # y#
        Ss0, Ss1 = Sdd * s0 + Sdr * s1, Sdr * s0 + Srr * s1
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
        tracks._curvature[i] = np.where(ok & np.isfinite(new[i]), new[i], np.where(update, 0.0,
                                                                                  tracks._curvature[i]))

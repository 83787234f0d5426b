"""All tracks of one measurement at once: closest phases, residuals and Jacobians against coaxial circles.

:class:`CoaxialTracks` evaluates the circle-point maths of :class:`.circle_track.CircleTrack` (closest phases,
residuals, Jacobians; see :mod:`.circle_track`) for every track of a measurement in one go: the per-track
coefficients are one small matrix product of monomials of the (m,) arrays ``d``, ``r`` (see
:meth:`.coaxial_coefficients._CoefficientTable.polynomials`), the pixels sit in a padded (rows, L) layout (a track
fills one or more rows of L points; see :mod:`.coaxial_layout`), and the warm-started Halley iterations, the
certificates and the Jacobians are whole-array operations. Pixels whose closest phase neither the cheap nor the
exact certificate of CircleTrack certifies go through CircleTrack's stage 1 (coarse grid, safeguarded Newton),
vectorised too, and the few still uncertified through CircleTrack's own later stages: its bracketed search track by
track, its grid search (where the image conic is no ellipse) for all such tracks at once. The results
are those of ``CircleTrack.evaluate`` (the certified closest phase is unique, so they do not depend on the
start), to ~1e-14 px and, because the phases get their last Newton step, with Jacobians exact to ~tol^2
(CircleTrack's to ~tol).

:meth:`CoaxialTracks.solve_circles` projects the circles out (each track's ``(d, r)`` at a fixed line variable, see
:mod:`.coaxial_solve`); :mod:`.coaxial` builds the variable-projection factor on the line variable from it.
"""

from __future__ import annotations

import math

import numpy as np

from .circle_track import _QUARTER, _Y012, COLD_GRID_SIZE, CircleTrack, _phase_grid
from .coaxial_coefficients import (
    _C8,
    _D,
    _DDRR,
    _KAPPA,
    _OPDR,
    _R,
    _SIDE,
    _THRESHOLD,
    _Y0,
    _Y1,
    _Y2,
    _Z,
    _CoefficientTable,
)
from .coaxial_layout import _Eval, _Layout, _layout
from .coaxial_solve import CIRCLE_TOL, project_circles
from .geometry import _matrix

__all__ = ["CoaxialTracks"]

# (n, a_max(n)): Taylor terms of sin / cos that are exact to ~1e-17 for |x| <= a_max(n) (first omitted term
# x^(2n+2) / (2n+2)!), and the Horner factors 1 / ((2k)(2k+1)) and 1 / ((2k-1)(2k)).
_TAYLOR = [(n, (1e-17 * math.factorial(2 * n + 2)) ** (1.0 / (2 * n + 2))) for n in range(1, 9)]
_SIN_F = [1.0 / ((2 * k) * (2 * k + 1)) for k in range(1, 10)]
_COS_F = [1.0 / ((2 * k - 1) * (2 * k)) for k in range(1, 10)]
#: Largest step rotated with the Taylor series (else np.sin / np.cos of the step).
_TAYLOR_MAX = 0.35


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
        row_length: points per row of the padded layout (default: chosen by :func:`.coaxial_layout._layout`).

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
        # camera constants (as CircleTrack's) and the per-track coefficient table
        self._table = _CoefficientTable(K)
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
        G = R.T @ self._table.K_inv
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
        with np.errstate(invalid="ignore"):  # a pixel whose phase has no real solution carries NaN (as in V[0:3])
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
        xc, yc, cos_t, sin_t = (a[track] for a in self._table.frames(R, d, r))
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
        """CircleTrack's own search from stage 2 on for the pixels ``todo``: the bracketed search in the pixel's
        quadrant arc, track by track; where the image conic is not an ellipse (part of the circle behind the camera:
        a short arc's runaway circle), CircleTrack's grid search, for all such tracks at once
        (:func:`_grid_search`)."""
        L = lay.L
        track = lay.row_track[todo // L]
        local = lay.local.ravel()[todo]
        bounds = np.flatnonzero(np.diff(track)) + 1
        s_flat, c_flat = s.ravel(), c.ravel()
        no_ellipse = []
        for part, part_local in zip(np.split(todo, bounds), np.split(local, bounds), strict=True):
            j = int(lay.row_track[part[0] // L])
            track_j = self._circle_tracks.get(j)
            if track_j is None:
                track_j = self._circle_tracks[j] = CircleTrack(self.K, self.pixels[j], warm_start=False)
            dj, rj = float(d[j]), float(r[j])
            setup = track_j._coefficients(R, dj, rj)
            if not setup[3].valid:
                no_ellipse.append((part, track_j, part_local, setup))
                continue
            phi, _, _, _ = track_j._solve_points(R, dj, rj, setup, part_local, None, 2)
            pair = np.sin(phi)
            s_flat[part], c_flat[part] = pair[0], pair[1]
        if no_ellipse:
            pair = np.sin(_grid_search(no_ellipse))
            part = np.concatenate([p for p, _, _, _ in no_ellipse])
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
        table = self._table.coefficients(R, d, r)
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
            with np.errstate(invalid="ignore", over="ignore"):  # (rows not finite sum to NaN: LM refuses the trial)
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
            with np.errstate(invalid="ignore", over="ignore"):  # (rows not finite sum to NaN: LM refuses the trial)
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

    def pixel_normals(self, ev) -> np.ndarray:
        """(2, rows, L) the residuals' derivative by the observed pixel ``(u_x, u_y)`` at the evaluation ``ev`` (of
        :meth:`_evaluate`): the curve's unit normal at each closest point (the closest phase moves with the pixel,
        but the residual is stationary in it). The residual's numerator ``l = G5 + G6 s + G7 c`` is linear in the
        pixel (``G = C8 (1, u_x, u_y)``) and its denominator ``|z[:2]|`` does not depend on it."""
        C, s, c = ev.rows[_C8], ev.s, ev.c
        sc, cc = s * c, c * c
        Z = ev.rows[_Z]
        z2 = Z[0][:, None] + Z[1][:, None] * s + Z[2][:, None] * c + Z[3][:, None] * sc + Z[4][:, None] * cc
        with np.errstate(divide="ignore", invalid="ignore"):
            inv = 1.0 / np.sqrt(z2)
        # C8's row of G_i's coefficient of u_x (column 1) and of u_y (column 2): C[3 i + column]
        return np.stack([(C[15 + u][:, None] + C[18 + u][:, None] * s + C[21 + u][:, None] * c) * inv
                         for u in (1, 2)])

    def phases(self, R, d, r) -> np.ndarray:
        """Closest phases (N,) in [-pi, pi] at the given variables."""
        ev = self._evaluate(*self._variables(R, d, r))
        return np.arctan2(self._flat(ev.s), self._flat(ev.c))

    def track_sums(self, values) -> np.ndarray:
        """Per-track sums (m,) of a per-point array (N,) in the concatenated order."""
        return np.bincount(self.track_index, weights=np.asarray(values, dtype=float), minlength=self.n_tracks)

    # ------------------------------------------------------------------------------------------------------------
    # variable projection of the circles

    def solve_circles(self, R, d0=None, r0=None, *, tol: float = CIRCLE_TOL, max_evaluations: int = 60):
        """Per-track (d, r) minimising each track's sum of squared residuals at the fixed line variable R.

        Gauss-Newton vectorised across tracks (per-track 2x2 normal equations), a track's step halved while its
        cost rises; a track stops once its Gauss-Newton decrement (predicted decrease) is below ``tol`` times its
        sum of squares (+ 1e-20 px^2 per point). Starts from (d0, r0), by default from the previous call's solution.
        The solve is :func:`.coaxial_solve.project_circles`.

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
        ev, converged, evaluations, work = project_circles(self, R, d0, r0, tol, max_evaluations)
        #: per-track convergence, and the evaluations and work (evaluated tracks' rows over all rows) of the solve
        self.last_solve = {"converged": converged, "evaluations": evaluations, "work": work}
        self._solution = (ev.d.copy(), ev.r.copy())
        return ev.d.copy(), ev.r.copy()


def _grid_search(parts) -> np.ndarray:
    """CircleTrack's stage 3 (``_solve_points(..., stage=3)``: the nearest of its ``grid_size`` phases, then up to
    ``newton_steps`` safeguarded Newton steps, each track stopping once its steps' sum of squares is below tol^2, and
    the last step applied) for several tracks' pixels at once, with each track's own coefficients, so that the
    phases are CircleTrack's to rounding. ``parts``: (flat indices, CircleTrack, its pixels' indices, its
    ``_coefficients``) per track; returns the phase pairs ``(phi, phi + pi/2)`` (2, n) in the parts' order."""
    first = parts[0][1]
    grid, grid_basis = _phase_grid(first.grid_size)
    phis, PCs, CRs, owner = [], [], [], []
    for t, (_, track, idx, (PC, CR, _, _, sign)) in enumerate(parts):
        with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
            y0, y1, y2 = CR[_Y012] @ grid_basis  # homogeneous curve points at the grid phases
            dx = track._px[idx, None] - y0 / y2
            dy = track._py[idx, None] - y1 / y2
        phis.append(grid[np.argmin(dx * dx + dy * dy, axis=1)] + _QUARTER)
        PCs.append(PC[:, :, idx] * np.array([[sign], [sign], [1.0], [sign]]))  # F, F', F'' as y2^3 f', ...
        CRs.append(CR[:2])
        owner.append(np.full(len(idx), t))
    phi, PC, owner = np.concatenate(phis, axis=1), np.concatenate(PCs, axis=2), np.concatenate(owner)
    ends = np.cumsum([len(idx) for _, _, idx, _ in parts])
    spans = list(zip(ends - [len(idx) for _, _, idx, _ in parts], ends, strict=True))
    gn_num, gn_den = np.empty(len(owner)), np.empty(len(owner))
    basis, basis3, product = CircleTrack._workspace(phi.shape[1])
    active = np.ones(phi.shape[1], dtype=bool)
    max_step = 2.0 * np.pi / first.grid_size
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        for _ in range(first.newton_steps):
            CircleTrack._fill_basis(phi, basis)
            F, dF, _, _ = np.add.reduce(np.multiply(PC, basis3, out=product), 0)
            for (a, b), C in zip(spans, CRs, strict=True):  # (each track's own product: near the camera plane
                gn_num[a:b], gn_den[a:b] = C @ np.ascontiguousarray(basis[:, a:b])  # the sums cancel)
            gn = gn_num / gn_den
            step = np.minimum(np.maximum(F / np.where(dF > 1e-3 * gn, dF, gn), -max_step), max_step)
            step = np.where(active, step, 0.0)
            phi -= step  # (a track's last step too: CircleTrack applies it after stopping)
            active &= ~(np.bincount(owner, weights=step * step, minlength=len(parts)) <= first._tol2)[owner]
            if not active.any():
                break
    return phi

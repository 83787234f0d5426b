"""Closest phases, residuals and Jacobians of one track's pixels against a projected coaxial circle.

:class:`CircleTrack` is the maths of :func:`circle_point_residuals` (and :func:`closest_phases`), evaluated in
closed form with certified closest phases (the certificates: :mod:`.ellipse`); :mod:`.geometry` has the
parametrisation and the projected circle's curve derivatives (:func:`.geometry.projected_circle`).

Fast path (see :class:`CircleTrack`). With ``M = K R S``, ``S = [[1, r, 0], [d, 0, 0], [0, 0, r]]``, the homogeneous
image point is ``y = M (1, s, c)`` (``s, c = sin, cos(phi)``) and its tangent line ``z = y x y'`` is, by
``(M a) x (M b) = cof(M) (a x b)`` and ``cof(K R S) = cof(K) R cof(S)``, the *linear* form
``z = cof(K) R w`` with ``w = r (-d s, r + s, -d c)``. Everything the factor needs is then a quadratic
trigonometric polynomial in the phase, i.e. a row of coefficients on the basis ``(1, s, c, s c, c^2)``:

- closest-point condition ``F = y2^3 f' = det((u_obs, 1), y, (z0, z1, 0)) = F0 + u_x Fx + u_y Fy`` (``f`` the half
  squared pixel distance), and its phase derivative ``F'`` (``F' = y2^3 f'' > 0`` at a minimum);
- residual: at the closest point the distance to the curve is the distance to its tangent line,
  ``e = -side (z . (u_obs, 1)) / |z[:2]|`` with ``side = sign(det K d)`` (``u' x u'' = -det(M) / y2^3`` and
  ``det M = -det(K) d r^2``: the curve's orientation is the same at every phase);
- Jacobians: the normal ``n`` and ``n^T du/dX K`` are ``side (z0, z1, z2) / (|z[:2]| y2)``, and
  ``R^T K^T cof(K) R w = det(K) w``, so ``de/dw``, ``de/dd``, ``de/dr`` are ``kappa`` times quadratic trigonometric
  polynomials with ``kappa = side det(K) r / (|z[:2]| y2)``.

Per call, the per-pixel coefficients of ``F, F', F''`` and of the residual's numerator are formed once
((20, 3) @ (3, N)); each Halley iteration is then one sine of the phase pairs ``(phi, phi + pi/2)``, two products
and one fused multiply-reduce over the basis, and the final rows come from one (9, 5) @ (5, N) product.
"""

from __future__ import annotations

import math

import numpy as np

from .ellipse import _RHO_MARGIN, _Ellipse
from .geometry import _matrix

#: Phases on the grid of the original search of :func:`closest_phases`, now used only when the projected circle is
#: not an ellipse (see :class:`CircleTrack`, stage 3).
PHASE_GRID_SIZE = 72
#: Safeguarded Newton iterations after that grid search.
PHASE_NEWTON_STEPS = 8
#: Phases on the coarse grid that starts the search without a warm start (see :class:`CircleTrack`).
COLD_GRID_SIZE = 24

#: Rows (y0, y1, y2) of the ``CR`` matrix of :meth:`CircleTrack._coefficients`.
_Y012 = [7, 8, 1]
_GRIDS: dict[int, tuple[np.ndarray, np.ndarray]] = {}


def _phase_grid(size: int) -> tuple[np.ndarray, np.ndarray]:
    """``size`` phases on [-pi, pi) and their basis ``(1, s, c, s c, c^2)`` (5, size), cached."""
    if size not in _GRIDS:
        grid = np.linspace(-np.pi, np.pi, size, endpoint=False)
        s, c = np.sin(grid), np.cos(grid)
        _GRIDS[size] = (grid, np.vstack([np.ones(size), s, c, s * c, c * c]))
    return _GRIDS[size]


#: Offsets of the phase pairs ``(phi, phi + pi/2)`` whose sines are ``(sin(phi), cos(phi))``.
_QUARTER = np.array([[0.0], [0.5 * np.pi]])


class CircleTrack:
    """Closest phases, residuals and Jacobians of one track's pixels against a projected coaxial circle.

    The maths of :func:`circle_point_residuals`, evaluated in closed form (see the module docstring) with a few small
    array operations per Newton iteration, and optionally warm-started: the phases of the last call start the Newton
    iterations of the next.

    Every closest phase is the global minimum of the pixel distance, *certified* as such (except for a conic that is
    not an ellipse, e.g. a circle not wholly in front of the camera: then the original grid search decides). The
    projected circle is an ellipse. A converged stationary point ``q`` of the distance is the global minimum if
    (cheap tests first, for all pixels at once) the pixel lies outside the curve there (``q`` is then the projection
    onto the convex ellipse), or inside at a distance below the smallest radius of curvature ``b^2 / a`` (Blaschke's
    rolling disc: the disc of that radius tangent at ``q`` lies inside the ellipse, and so does the disc about the
    pixel through ``q``); otherwise (exact test, for the remaining pixels) if ``q`` lies in the pixel's open quadrant
    of the ellipse's axes (see :class:`_Ellipse`).

    The search, in stages (each pixel goes on to the next stage until its phase is certified):

    0. Halley's iterations from the previous call's phases (warm start; typically two iterations);
    1. the nearest of ``COLD_GRID_SIZE`` phases, then safeguarded Newton steps;
    2. a bracketed Newton / bisection search on the pixel's quadrant arc of the ellipse, which holds exactly one
       stationary point, the global minimum (certified by construction);
    3. only for a conic that is not an ellipse: the original grid search (``grid_size`` phases, ``newton_steps``
       safeguarded Newton steps).

    A certified minimum is unique, so the result does not depend on the warm start (up to the convergence tolerance
    ``tol``), nor on the stage that found it.

    A call at exactly the variables of the previous call returns the previous result.

    Args:
        K: (3, 3) intrinsic matrix.
        pixels: (N, 2) observed ideal pixels.
        warm_start: keep the last phases (and result) between calls.
        grid_size, newton_steps: grid and safeguarded Newton iterations of the grid search (stage 3).
        warm_steps, cold_steps: iterations of stages 0 and 1.
        tol: convergence tolerance of the Newton step (rad). The residual is stationary in the phase, so it is exact
            to ~``|e''| tol^2``; the Jacobians hold the phase fixed and are exact to a relative ~``tol``.
    """

    def __init__(self, K, pixels, *, warm_start: bool = True, grid_size: int = PHASE_GRID_SIZE,
                 newton_steps: int = PHASE_NEWTON_STEPS, warm_steps: int = 6, cold_steps: int = 10,
                 tol: float = 1e-8):
        K = np.array(K, dtype=float).reshape(3, 3)
        pixels = np.array(pixels, dtype=float).reshape(-1, 2)
        n = len(pixels)
        K_inv = np.linalg.inv(K)
        self.K = K
        self.pixels = pixels
        self.warm_start = bool(warm_start)
        self.grid_size = int(grid_size)
        self.newton_steps = int(newton_steps)
        self.warm_steps = max(1, int(warm_steps))
        self.cold_steps = max(1, int(cold_steps))
        self.tol = float(tol)
        self._tol2 = self.tol * self.tol
        self._px = np.ascontiguousarray(pixels[:, 0])
        self._py = np.ascontiguousarray(pixels[:, 1])
        self._P3 = np.vstack([np.ones(n), self._px, self._py])  # (3, N): (1, u_x, u_y)
        self._det_K = float(np.linalg.det(K))
        self._K_inv = K_inv
        # Rows 0-2: K; 3-5: cof(K) = det(K) K^-T; 6-8: K^-T (its products with R give k_i = K^-T c_i).
        self._KK = np.vstack([K, self._det_K * K_inv.T, K_inv.T])
        omega = K_inv.T @ K_inv
        self._omega = tuple(float(omega[i, j]) for i, j in ((0, 0), (0, 1), (1, 1), (0, 2), (1, 2)))
        self._work = self._workspace(n)
        #: [key, phase pairs (2, N), rows, e, |z[:2]|, kappa numerator, H or None] of the last call (warm start).
        self._state = None
        #: Diagnostics: calls, and pixels that went through the coarse-grid search, the bracketed search in their
        #: quadrant arc, and the fine grid search (only for a conic that is not an ellipse).
        self.calls = 0
        self.cold_points = 0
        self.bracketed_points = 0
        self.grid_points = 0

    def __len__(self) -> int:
        return len(self._px)

    @staticmethod
    def _workspace(n: int):
        """Basis buffer (5, N) with row 0 = 1, its (5, 1, N) view, and a (5, 4, N) product buffer."""
        basis = np.empty((5, n))
        basis[0] = 1.0
        return basis, basis[:, None, :], np.empty((5, 4, n))

    def reset(self) -> None:
        """Forget the warm start."""
        self._state = None

    # ------------------------------------------------------------------------------------------------------------

    def _coefficients(self, R: np.ndarray, d: float, r: float):
        """Per-call coefficients, all on the phase basis ``(1, s, c, s c, c^2)``.

        Returns:
            PC: (5, 4, N) per pixel: coefficients of ``F``, ``F'``, ``l = -side z . (u_obs, 1)`` and ``F''/2``
                (``F`` here is ``-side y2^3 f'``).
            CR: (9, 5) rows ``|z[:2]|^2``, ``y2``, the five Jacobian numerators, ``y0``, ``y1``.
            kappa_num: ``side det(K) r``.
            ellipse: the :class:`_Ellipse` of the variables.
            sign: ``-side``, the sign of the ``F`` in ``PC`` relative to ``y2^3 f'``.
        """
        m = (self._KK @ R).tolist()
        (k00, k01, k02), (k10, k11, k12), (k20, k21, k22) = m[0], m[1], m[2]
        (h00, h01, h02), (h10, h11, h12), (h20, h21, h22) = m[3], m[4], m[5]
        det_K = self._det_K
        # y_i = a_i + b_i s + e_i c (homogeneous pixel); z = y x y' = cof(K) R w scaled by -side: p_i + q_i s + t_i c.
        a2 = k20 + d * k21
        side = -1.0 if det_K * d * a2 < 0.0 else 1.0
        a0, b0, e0 = k00 + d * k01, r * k00, r * k02
        a1, b1, e1 = k10 + d * k11, r * k10, r * k12
        b2, e2 = r * k20, r * k22
        sr = -side * r
        srr, sdr = sr * r, sr * d
        p0, q0, t0 = srr * h01, sr * h01 - sdr * h00, -sdr * h02
        p1, q1, t1 = srr * h11, sr * h11 - sdr * h10, -sdr * h12
        p2, q2, t2 = srr * h21, sr * h21 - sdr * h20, -sdr * h22
        # F = F0 + u_x Fx + u_y Fy, F0 = z1 y0 - z0 y1, Fx = -z1 y2, Fy = z0 y2 (products of linear forms on
        # (1, s, c) -> basis (1, s, c, s c, c^2) with s^2 = 1 - c^2); d/dphi maps k to (-k3, -k2, k1, -2 k4, 2 k3).
        f0 = p1 * a0 + q1 * b0 - p0 * a1 - q0 * b1
        f1 = p1 * b0 + q1 * a0 - p0 * b1 - q0 * a1
        f2 = p1 * e0 + t1 * a0 - p0 * e1 - t0 * a1
        f3 = q1 * e0 + t1 * b0 - q0 * e1 - t0 * b1
        f4 = t1 * e0 - q1 * b0 - t0 * e1 + q0 * b1
        x0, x1 = -(p1 * a2 + q1 * b2), -(p1 * b2 + q1 * a2)
        x2, x3, x4 = -(p1 * e2 + t1 * a2), -(q1 * e2 + t1 * b2), q1 * b2 - t1 * e2
        y0, y1 = p0 * a2 + q0 * b2, p0 * b2 + q0 * a2
        y2, y3, y4 = p0 * e2 + t0 * a2, q0 * e2 + t0 * b2, t0 * e2 - q0 * b2
        dd, rr = d * d, r * r
        coefficients = np.array([
            # PC generators: rows (basis term k, quantity F / F' / l / F''/2), columns (1, u_x, u_y)
            f0, x0, y0, -f3, -x3, -y3, p2, p0, p1, f4, x4, y4,
            f1, x1, y1, -f2, -x2, -y2, q2, q0, q1, -0.5 * f1, -0.5 * x1, -0.5 * y1,
            f2, x2, y2, f1, x1, y1, t2, t0, t1, -0.5 * f2, -0.5 * x2, -0.5 * y2,
            f3, x3, y3, -2.0 * f4, -2.0 * x4, -2.0 * y4, 0.0, 0.0, 0.0, -2.0 * f3, -2.0 * x3, -2.0 * y3,
            f4, x4, y4, 2.0 * f3, 2.0 * x3, 2.0 * y3, 0.0, 0.0, 0.0, -2.0 * f4, -2.0 * x4, -2.0 * y4,
            # CR
            p0 * p0 + q0 * q0 + p1 * p1 + q1 * q1, 2.0 * (p0 * q0 + p1 * q1), 2.0 * (p0 * t0 + p1 * t1),
            2.0 * (q0 * t0 + q1 * t1), t0 * t0 - q0 * q0 + t1 * t1 - q1 * q1,
            a2, b2, e2, 0.0, 0.0,
            0.0, 0.0, -(dd + rr), -r, 0.0,
            0.0, 0.0, d, 0.0, 0.0,
            2.0 * r, 1.0 + rr + dd, 0.0, 0.0, -r,
            r, 1.0, 0.0, 0.0, 0.0,
            -d, 0.0, 0.0, 0.0, 0.0,
            a0, b0, e0, 0.0, 0.0,
            a1, b1, e1, 0.0, 0.0,
        ])
        PC = (coefficients[:60].reshape(20, 3) @ self._P3).reshape(5, 4, -1)
        ellipse = _Ellipse((m[6][0], m[7][0], m[8][0]), (m[6][1], m[7][1], m[8][1]), self._omega, det_K, d, r)
        if not a2 > math.hypot(b2, e2):  # not all of the circle in front of the camera (y2 > 0): no certificates
            ellipse.valid = False
        return PC, coefficients[60:].reshape(9, 5), side * det_K * r, ellipse, -side

    @staticmethod
    def _fill_basis(phases: np.ndarray, basis: np.ndarray) -> None:
        """Basis ``(1, s, c, s c, c^2)`` at the phase pairs ``(phi, phi + pi/2)`` (2, N): ``sin`` gives ``(s, c)``."""
        np.sin(phases, out=basis[1:3])
        np.multiply(basis[1], basis[2], out=basis[3])
        np.multiply(basis[2], basis[2], out=basis[4])

    @classmethod
    def _newton(cls, PC: np.ndarray, phi: np.ndarray, work, steps: int, tol: float, tol2: float):
        """Halley's iterations on ``F`` (Newton with the curvature ``F''``) from the phase pairs ``phi`` (2, N),
        modified in place.

        Returns (phi, (F, F', l, F''/2) at phi, the last step, mask of the points whose last step exceeds tol or None
        when all converged). The basis buffer of ``work`` holds the basis at ``phi``.
        """
        basis, basis3, product = work
        for i in range(steps):
            cls._fill_basis(phi, basis)
            FDL = np.add.reduce(np.multiply(PC, basis3, out=product), 0)
            F, dF, _, half_ddF = FDL
            delta = F / dF  # the Newton step: within ~tol of the root when below tol
            if delta.dot(delta) <= tol2:
                return phi, FDL, delta, None
            if i == steps - 1:
                return phi, FDL, delta, ~(np.abs(delta) <= tol)
            phi -= delta / (1.0 - delta * half_ddF / dF)  # Halley's step: cubic convergence
        raise AssertionError("unreachable")

    def _grid_descent(self, setup, idx, grid_size: int, steps: int):
        """Nearest of ``grid_size`` phases, then safeguarded Newton: Newton on ``F``, Gauss-Newton
        ``y2^3 |u'|^2 = |z[:2]|^2 / y2`` where ``F'`` is not safely positive, steps clamped to one grid cell.

        Returns (phase pairs phi, (F, F', l, F''/2) at phi, last step, mask of the points whose last step exceeds tol
        or None), as :meth:`_newton`, and the workspace whose basis is at ``phi``.
        """
        PC, CR, _, _, sign = setup
        grid, grid_basis = _phase_grid(grid_size)
        y0, y1, y2 = CR[_Y012] @ grid_basis  # homogeneous curve points at the grid phases
        dx = self._px[idx, None] - y0 / y2
        dy = self._py[idx, None] - y1 / y2
        phi = grid[np.argmin(dx * dx + dy * dy, axis=1)] + _QUARTER
        max_step = 2.0 * np.pi / grid_size
        PC = PC[:, :, idx] * np.array([[sign], [sign], [1.0], [sign]])  # F, F', F'' as y2^3 f', ...
        basis, basis3, product = work = self._workspace(phi.shape[1])
        for i in range(steps):
            self._fill_basis(phi, basis)
            F, dF, _, _ = np.add.reduce(np.multiply(PC, basis3, out=product), 0)
            gn_num, gn_den = CR[:2] @ basis
            gn = gn_num / gn_den
            step = np.minimum(np.maximum(F / np.where(dF > 1e-3 * gn, dF, gn), -max_step), max_step)
            if step.dot(step) <= self._tol2:
                return phi, product.sum(0) * np.array([[sign], [sign], [1.0], [sign]]), step, None, work
            if i == steps - 1:
                FDL = product.sum(0) * np.array([[sign], [sign], [1.0], [sign]])
                return phi, FDL, step, ~(np.abs(step) <= self.tol), work
            phi -= step
        raise AssertionError("unreachable")

    def _bracketed(self, R, setup, idx, steps: int = 64):
        """The closest phase inside each pixel's quadrant arc (see :class:`_Ellipse`): Newton on ``F``, bisection
        where the Newton step leaves the bracket. ``f'`` goes from negative to positive across the only stationary
        point of the arc (the global minimum), so the sign of ``F`` at each iterate shrinks the bracket.

        Returns as :meth:`_grid_descent`.
        """
        PC, _, _, ellipse, sign = setup
        lo, length = ellipse.quadrant_arcs(self._px[idx], self._py[idx], R.T @ self._K_inv)
        hi = lo + length
        phi = lo + 0.5 * length
        signs = np.array([[sign], [sign], [1.0], [sign]])
        PC = PC[:, :, idx] * signs  # F, F', F'' as y2^3 f', ...
        basis, basis3, product = work = self._workspace(len(phi))
        pairs = np.empty((2, len(phi)))
        for i in range(steps):
            np.add(phi, _QUARTER, out=pairs)
            self._fill_basis(pairs, basis)
            F, dF, _, _ = np.add.reduce(np.multiply(PC, basis3, out=product), 0)
            above = F > 0.0  # f' > 0: the minimum is below phi
            hi = np.where(above, phi, hi)
            lo = np.where(above, lo, phi)
            newton = phi - F / dF
            new = np.where((newton > lo) & (newton < hi), newton, 0.5 * (lo + hi))
            step = phi - new
            if step.dot(step) <= self._tol2 or i == steps - 1:
                bad = None if step.dot(step) <= self._tol2 else ~(np.abs(step) <= self.tol)
                return pairs, product.sum(0) * signs, step, bad, work
            phi = new
        raise AssertionError("unreachable")

    def _solve_points(self, R, d: float, r: float, setup, idx, phi=None, stage: int = 1):
        """Phases, rows (``CR @ basis``), residuals and ``|z[:2]|`` of the pixels ``idx`` (an index array or
        ``slice(None)``).

        Stage 0: Halley's iterations from the warm start ``phi``; stage 1: coarse grid (``COLD_GRID_SIZE`` phases)
        and safeguarded Newton; stage 2: the bracketed search in the pixel's quadrant arc (certified by
        construction); stage 3, only if the conic is not an ellipse or stage 2 does not converge: the grid search
        (``grid_size`` phases, ``newton_steps`` safeguarded Newton steps), uncertified. Pixels whose phase is not
        certified go on to the next stage. The rows and residuals are evaluated at phases within ``tol`` of the
        closest ones; the returned phases include the last step (accurate to ~``tol^2`` after Newton steps), as
        phase pairs ``(phi, phi + pi/2)`` (2, n).
        """
        PC, CR, _, ellipse, _ = setup
        full = isinstance(idx, slice)
        with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
            if stage == 0:
                work = self._work
                phi, FDL, delta, bad = self._newton(PC, phi, work, self.warm_steps, self.tol, self._tol2)
            elif stage == 2:
                self.bracketed_points += len(self._px[idx])
                phi, FDL, delta, bad, work = self._bracketed(R, setup, idx)
            else:
                if stage == 1:
                    grid_size, steps = COLD_GRID_SIZE, self.cold_steps
                    self.cold_points += len(self._px[idx])
                else:
                    grid_size, steps = self.grid_size, self.newton_steps
                    self.grid_points += len(self._px[idx])
                phi, FDL, delta, bad, work = self._grid_descent(setup, idx, grid_size, steps)
            rows = CR @ work[0]
            sq = np.sqrt(rows[0])
            e = FDL[2] / sq
            phi -= delta
        if stage == 3 or (stage == 2 and bad is None):
            return phi, rows, e, sq
        if stage == 2:
            todo = np.flatnonzero(bad)
        else:
            # Cheap certificates first: converged, and outside the curve or inside by less than b^2 / a.
            threshold = -_RHO_MARGIN * ellipse.rho_min
            if not ellipse.valid:
                fails = np.ones(len(e), dtype=bool)
            elif bad is None and e.min() > threshold:
                return phi, rows, e, sq
            else:
                fails = ~(e > threshold)
                if bad is not None:
                    fails |= bad
            todo = np.flatnonzero(fails)
            if ellipse.valid:
                # Exact certificate: a converged stationary point in the pixel's quadrant of the ellipse's axes.
                sub = todo if full else idx[todo]
                ok = ellipse.same_quadrant(self._px[sub], self._py[sub], rows[7, todo], rows[8, todo], rows[1, todo])
                if bad is not None:
                    ok &= ~bad[todo]
                todo = todo[~ok]
        if len(todo):
            sub = todo if full else idx[todo]
            next_stage = stage + 1 if ellipse.valid else 3
            phi[:, todo], rows[:, todo], e[todo], sq[todo] = self._solve_points(R, d, r, setup, sub, None, next_stage)
        return phi, rows, e, sq

    def _state_at(self, R, d: float, r: float) -> list:
        R = _matrix(R)
        d, r = float(d), float(r)
        self.calls += 1
        key = (R.tobytes(), d, r)
        previous = self._state
        if previous is not None and previous[0] == key:
            return previous
        setup = self._coefficients(R, d, r)
        if len(self._px) == 0:
            empty = np.zeros(0)
            state = [key, np.zeros((2, 0)), np.zeros((9, 0)), empty, empty, setup[2], None]
            return state
        if previous is None:
            phi, rows, e, sq = self._solve_points(R, d, r, setup, slice(None))
        else:
            phi, rows, e, sq = self._solve_points(R, d, r, setup, slice(None), previous[1].copy(), stage=0)
        state = [key, phi, rows, e, sq, setup[2], None]
        if self.warm_start:
            self._state = state
        return state

    def evaluate(self, R, d: float, r: float, jacobians: bool = True):
        """Residuals (N,), and Jacobians (N, 3) wrt the Rot3 tangent and (N, 2) wrt (d, r) (or None, None).

        The returned arrays may be views of the cache: copy them before modifying them.
        """
        state = self._state_at(R, d, r)
        if not jacobians:
            return state[3], None, None
        H = state[6]
        if H is None:
            rows = state[2]
            H = state[6] = rows[2:7] * (state[5] / (state[4] * rows[1]))
        HT = H.T
        return state[3], HT[:, :3], HT[:, 3:]

    def phases(self, R, d: float, r: float) -> np.ndarray:
        """Closest phases (N,) in [-pi, pi) at the given variables."""
        return np.mod(self._state_at(R, d, r)[1][0] + np.pi, 2.0 * np.pi) - np.pi


def closest_phases(K, R, d: float, r: float, pixels, grid_size: int = PHASE_GRID_SIZE,
                   newton_steps: int = PHASE_NEWTON_STEPS) -> np.ndarray:
    """Phase of the projected-circle point closest (in pixels) to each observed pixel.

    Vectorised, no loop over pixels: the nearest of ``COLD_GRID_SIZE`` phases, then safeguarded Newton steps on
    ``f(phi) = |u(phi) - u_obs|^2 / 2`` (Newton where ``f''`` is safely positive, else Gauss-Newton ``|u'|^2``; steps
    clamped to one grid cell); the converged phase is kept where it is certified to be the global minimum, else the
    pixel's quadrant arc of the projected ellipse is searched (see :class:`CircleTrack`). ``grid_size`` and
    ``newton_steps`` are the original grid search's, used only when the projected circle is not an ellipse.

    Args:
        K: (3, 3) intrinsic matrix.
        R: line variable (``gtsam.Rot3`` or (3, 3)).
        d, r: circle offset and radius (unit scale).
        pixels: (N, 2) observed ideal pixels.

    Returns:
        (N,) phases in [-pi, pi).
    """
    pixels = np.asarray(pixels, dtype=float).reshape(-1, 2)
    if len(pixels) == 0:
        return np.zeros(0)
    track = CircleTrack(K, pixels, warm_start=False, grid_size=grid_size, newton_steps=newton_steps)
    return track.phases(R, d, r)


def circle_point_residuals(K, R, d: float, r: float, pixels,
                           jacobians: bool = True) -> tuple[np.ndarray, np.ndarray | None, np.ndarray | None]:
    """Signed geometric pixel distances of observed pixels to the projected circle, with Jacobians.

    ``e_i = n_i . (u(phi_i) - u_obs_i)`` with ``phi_i`` the closest phase and ``n_i`` the unit normal of the
    projected curve at ``phi_i`` pointing towards its centre of curvature (inwards for an ellipse), so
    ``e_i > 0`` when ``u_obs_i`` lies outside the projected circle and ``|e_i|`` is its pixel distance.

    Jacobians hold ``phi_i`` and ``n_i`` fixed (envelope theorem: ``de/dphi = 0`` at the closest phase, and
    ``dn`` is orthogonal to ``n`` while ``u - u_obs`` is parallel to it). With ``g_i = (n_i^T du/dX)`` (row) and
    ``v_i = (1 + r sin, d, r cos)``: ``X(R Exp(w)) = X + R (w x v)``, so ``de = (R^T g) . (w x v) = w . (v x R^T g)``,
    i.e. ``de_i/dw = v_i x (R^T g_i)``; ``de/dd = g . c1``; ``de/dr = g . R (sin, 0, cos)``. These are evaluated
    in closed form (see the module docstring); a fresh :class:`CircleTrack` does the work.

    Args:
        K: (3, 3) intrinsic matrix.
        R: line variable (``gtsam.Rot3`` or (3, 3)).
        d, r: circle offset and radius (unit scale).
        pixels: (N, 2) observed ideal pixels.
        jacobians: also return the Jacobians.

    Returns:
        e: (N,) signed distances (px).
        H_line: (N, 3) ``de/dw`` (Rot3 tangent) or None.
        H_circle: (N, 2) ``de/d(d, r)`` or None.
    """
    return CircleTrack(K, pixels, warm_start=False).evaluate(R, d, r, jacobians=jacobians)


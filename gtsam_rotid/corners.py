"""Corner features on ambient texture, and the spin's shared rotation (used by :mod:`gtsam_rotid.tracking`).

:class:`CornerFollower` seeds Shi–Tomasi corners (``cv2.goodFeaturesToTrack``) only where the image moves (a
motion mask: frame differences at half resolution, remembered for ``motion_memory`` frames, so the background
and the still links never seed tracks), follows them with pyramidal Lucas–Kanade (forward–backward check) from
a prediction, and limits LK's drift by tracking each point against a reference (anchor) frame that is renewed
only every ``anchor_every`` frames, not frame to frame. All features of one spin turn together about one axis:
each track's points lie on an ellipse and all advance in phase at one rate. :class:`SpinModel` holds that
shared rotation (one conic shape shared by all tracks, each with its own centre and size, and the common rate),
fitted by variable projection from per-track moments; online it predicts every point (a better LK start) and
gates points off their track's ellipse (:mod:`gtsam_rotid.spinmodel`). Offline,
:func:`gtsam_rotid.spinfilter.spin_filter` fits it to whole tracks, drops points off
their track's ellipse, rejects tracks that are off their ellipse (occluding edges: a silhouette point slides
along the outline) or that do not turn with the spin (specular highlights, edges), and
:func:`gtsam_rotid.spinfilter.link_fragments`
joins pieces of one feature seen again after an occlusion (same ellipse, a phase consistent with the common
rate, a similar patch once turned) into long arcs.

Everything per frame is vectorised over the points (a few numpy passes and OpenCV calls per frame).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, fields

import cv2
import numpy as np

from .dataset import Track
from .spinmodel import PATCH, SpinModel, _design


# ---------------------------------------------------------------------------------------------- online
def _offsets(half: int) -> tuple[np.ndarray, np.ndarray]:
    o = np.arange(-half, half + 1, dtype=np.float32)
    u, v = np.meshgrid(o, o)
    return u.ravel(), v.ravel()


def _sample(image: np.ndarray, warp: np.ndarray, half: int) -> np.ndarray:
    """(n, (2 half + 1)²) float32: bilinear samples of ``image`` at each point's patch, mapped by ``warp`` (n, 2, 3)
    from patch offsets (u, v, 1) to pixels; one ``cv2.remap`` for all points."""
    u, v = _offsets(half)
    w = warp.astype(np.float32)
    x = w[:, 0, 0, None] * u + w[:, 0, 1, None] * v + w[:, 0, 2, None]
    y = w[:, 1, 0, None] * u + w[:, 1, 1, None] * v + w[:, 1, 2, None]
    n, side = len(w), 2 * half + 1
    if n == 0:
        return np.zeros((0, side * side), np.float32)
    out = cv2.remap(image, x.reshape(n * side, side), y.reshape(n * side, side), cv2.INTER_LINEAR,
                    borderMode=cv2.BORDER_REPLICATE)
    return out.reshape(n, side * side).astype(np.float32)


def _identity(points: np.ndarray) -> np.ndarray:
    warp = np.zeros((len(points), 2, 3))
    warp[:, 0, 0] = warp[:, 1, 1] = 1.0
    warp[:, :, 2] = points
    return warp


class _Templates:
    """Per-point appearance templates for affine inverse-compositional Lucas–Kanade (Baker & Matthews), with the
    patch's brightness and contrast normalised (Gaussian-weighted), vectorised over the points. With ``plane``, a
    brightness gradient across the patch is removed too (a linear shading term beside gain and offset: the shading
    changes across a patch as its surface turns under a directional light); the steepest-descent images are then
    projected off that brightness plane (Hager & Belhumeur)."""

    def __init__(self, half: int, damping: float = 0.5, plane: bool = False):
        self.half = half
        self.damping = damping
        self.plane = plane
        u, v = _offsets(half)
        sigma = 0.6 * half
        w = np.exp(-(u**2 + v**2) / (2 * sigma**2)).astype(np.float32)
        self.w = w / w.sum()
        self.u, self.v = u, v
        basis = np.stack([np.ones_like(u), u, v])                        # brightness plane a + b u + c v
        gram = (basis * self.w) @ basis.T
        self._proj = (np.linalg.solve(gram, basis * self.w).T @ basis).astype(np.float32)   # x -> its plane: x @ P

    def _flatten(self, x: np.ndarray) -> np.ndarray:
        """``x`` (n, P) minus its weighted mean, or with ``plane`` its weighted least-squares brightness plane."""
        if not self.plane:
            return x - (x @ self.w)[:, None]
        return x - x @ self._proj

    def make(self, image: np.ndarray, points: np.ndarray):
        """(T (n, P), SDw (n, 6, P), Hinv (n, 6, 6), Htinv (n, 2, 2), strength (n,), anisotropy (n,)) of patches
        at ``points``: strength is the translation's smaller Hessian eigenvalue (grey levels² per px²), anisotropy
        the ratio of its larger to its smaller eigenvalue (1 for a round corner, large along an edge)."""
        half, n = self.half, len(points)
        side = 2 * half + 1
        big = _sample(image, _identity(points), half + 1).reshape(n, side + 2, side + 2)
        t = big[:, 1:-1, 1:-1].reshape(n, -1)
        gx = (0.5 * (big[:, 1:-1, 2:] - big[:, 1:-1, :-2])).reshape(n, -1)
        gy = (0.5 * (big[:, 2:, 1:-1] - big[:, :-2, 1:-1])).reshape(n, -1)
        t = self._flatten(t)
        std = np.sqrt((t * t) @ self.w) + 1e-3
        t /= std[:, None]
        gx /= std[:, None]
        gy /= std[:, None]
        u, v = self.u, self.v
        sd = np.stack([gx * u, gx * v, gy * u, gy * v, gx, gy], axis=1)          # (n, 6, P)
        if self.plane:
            sd = sd - sd @ self._proj
        sdw = sd * self.w
        h = sdw @ np.transpose(sd, (0, 2, 1)) + 1e-6 * np.eye(6, dtype=np.float32)
        ht = h[:, 4:, 4:].copy()
        # damping of the linear part (a small window determines it weakly): a fraction of what a patch with the
        # translation's texture spread evenly over the window would give
        spread = float(self.w @ (self.u**2))
        damp = self.damping * spread * 0.5 * np.trace(ht, axis1=1, axis2=2)
        h[:, np.arange(4), np.arange(4)] += damp[:, None]
        eig = np.linalg.eigvalsh(ht)
        strength = eig[:, 0] * std**2                                           # translation min eigenvalue
        anisotropy = eig[:, 1] / np.maximum(eig[:, 0], 1e-12)
        return t, sdw, np.linalg.inv(h), np.linalg.inv(ht), strength, anisotropy

    def track(self, image, warp, t, sdw, hinv, htinv, iterations: int, translation_iterations: int = 1):
        """Refine warps (n, 2, 3) on ``image``; returns (warp, zncc (n,), last translation step (n,) px)."""
        n = len(warp)
        warp = warp.copy()
        step = np.zeros(n)
        zncc = np.zeros(n)
        for it in range(iterations + 1):
            sample = _sample(image, warp, self.half)
            sample = self._flatten(sample)
            sample /= (np.sqrt((sample * sample) @ self.w) + 1e-3)[:, None]
            r = sample - t
            zncc = 1.0 - 0.5 * ((r * r) @ self.w)
            if it == iterations:
                break
            b = (sdw @ r[:, :, None])[..., 0].astype(np.float64)                    # (n, 6)
            if it < translation_iterations:
                dp = np.zeros((n, 6))
                dp[:, 4:] = (htinv @ b[:, 4:, None])[..., 0]
            else:
                dp = (hinv @ b[:, :, None])[..., 0]
            # W <- W o W(dp)^-1, W(dp) = [[1 + p0, p1, p4], [p2, 1 + p3, p5]]
            a, bb, c, d = 1 + dp[:, 0], dp[:, 1], dp[:, 2], 1 + dp[:, 3]
            det = a * d - bb * c
            inv = np.stack([np.stack([d, -bb], 1), np.stack([-c, a], 1)], 1) / det[:, None, None]
            lin = warp[:, :, :2] @ inv
            warp[:, :, 2] -= (lin @ dp[:, 4:, None])[..., 0]
            warp[:, :, :2] = lin
            step = np.hypot(*(warp[:, :, :2] @ dp[:, 4:, None])[..., 0].T)
        return warp, zncc, step


@dataclass
class _Corners:
    """The corner tracks being followed, one row each."""

    ids: np.ndarray = field(default_factory=lambda: np.empty(0, np.int64))
    pos: np.ndarray = field(default_factory=lambda: np.empty((0, 2)))
    vel: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))
    warp: np.ndarray = field(default_factory=lambda: np.empty((0, 2, 2)))     # template -> image, linear part
    key: np.ndarray = field(default_factory=lambda: np.empty(0, np.int64))    # the template's frame
    missed: np.ndarray = field(default_factory=lambda: np.empty(0, np.int64))
    count: np.ndarray = field(default_factory=lambda: np.empty(0, np.int64))
    lo: np.ndarray = field(default_factory=lambda: np.empty((0, 2)))
    hi: np.ndarray = field(default_factory=lambda: np.empty((0, 2)))
    moments: np.ndarray = field(default_factory=lambda: np.empty((0, 6, 6)))  # conic moments, normalised points
    centre: np.ndarray = field(default_factory=lambda: np.full((0, 2), np.nan))  # ellipse centre (px), NaN unknown
    t: np.ndarray = field(default_factory=lambda: np.empty((0, 0), np.float32))        # templates
    sdw: np.ndarray = field(default_factory=lambda: np.empty((0, 6, 0), np.float32))
    hinv: np.ndarray = field(default_factory=lambda: np.empty((0, 6, 6), np.float32))
    htinv: np.ndarray = field(default_factory=lambda: np.empty((0, 2, 2), np.float32))

    def __len__(self) -> int:
        return len(self.ids)

    def keep(self, mask) -> None:
        for f in fields(self):
            setattr(self, f.name, getattr(self, f.name)[mask])

    def add(self, ids, pos, key: int, templates) -> None:
        n = len(ids)
        t, sdw, hinv, htinv = templates
        new = dict(ids=ids, pos=pos, vel=np.zeros((n, 2)), warp=np.tile(np.eye(2), (n, 1, 1)),
                   key=np.full(n, key, np.int64), missed=np.zeros(n, np.int64), count=np.ones(n, np.int64),
                   lo=pos, hi=pos, moments=np.zeros((n, 6, 6)), centre=np.full((n, 2), np.nan), t=t, sdw=sdw,
                   hinv=hinv, htinv=htinv)
        for name, values in new.items():
            old = getattr(self, name)
            if len(old) == 0:
                setattr(self, name, values)
            else:
                setattr(self, name, np.concatenate([old, values]))

    def renew(self, idx, templates, key: int) -> None:
        self.t[idx], self.sdw[idx], self.hinv[idx], self.htinv[idx] = templates
        self.warp[idx] = np.eye(2)
        self.key[idx] = key


class CornerFollower:
    """Frame-at-a-time corner tracker; ``params`` is a :class:`gtsam_rotid.tracking.TrackerParams`."""

    def __init__(self, params):
        self.p = params
        self._tpl = _Templates(int(params.corner_window) // 2, float(params.warp_damping),
                               bool(params.shading_gradient))
        self._a = _Corners()
        self._next_id = 0
        self._frame = -1
        self._prev_small = None
        self._prev_grey = None
        self._heat = None
        self._last_seed = -(10**9)
        self._parked = np.empty((0, 2))
        self._log: list[tuple[int, np.ndarray, np.ndarray]] = []
        self._patch_ids: list[np.ndarray] = []
        self._patches: list[np.ndarray] = []
        self.model: SpinModel | None = None
        self._origin = None
        self._scale = 1.0
        self._omega_votes: list[float] = []
        self._sigma = 0.5                   # robust scale (px) of the online ellipse distances
        self._size = None

    # --- per frame
    def feed(self, grey: np.ndarray, frame: int, exclude: np.ndarray | None = None) -> None:
        """Track one grey frame; ``exclude``: (k, 3) (u, v, radius) where no corner may start (blob tracks)."""
        p = self.p
        self._frame = frame
        if self._origin is None:
            h, w = grey.shape
            self._size = (w, h)
            self._origin = np.array([(w - 1) / 2, (h - 1) / 2])
            self._scale = 0.5 * max(w, h)
        small = cv2.pyrDown(grey)
        if self._prev_small is not None:
            moving = cv2.compare(cv2.absdiff(small, self._prev_small), float(p.motion_threshold), cv2.CMP_GT)
            self._heat = cv2.max(cv2.subtract(self._heat, 1), cv2.bitwise_and(moving, int(p.motion_memory)))
        else:
            self._heat = np.zeros_like(small)
        if len(self._a):
            self._follow(grey, frame)
        if frame - self._last_seed >= p.seed_every:
            self._seed(grey, frame, exclude)
        if frame % p.model_every == 0:
            self._update_model()
        self._prev_small = small
        self._prev_grey = grey

    def _predict(self, ahead: np.ndarray) -> np.ndarray:
        a, m = self._a, self.model
        guess = a.pos + a.vel * ahead[:, None]
        if m is None or m.omega == 0.0:
            return guess
        known = np.isfinite(a.centre[:, 0]) & (a.count >= self.p.model_min_points)
        if known.any():
            guess[known] = m.turn(a.pos[known], a.centre[known], m.omega * ahead[known])
        return guess

    def _coarse(self, grey, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Pyramidal LK (translation, forward-backward checked) of ``points`` from the previous frame, on the crop
        around them only: the first step of a new track, which has no velocity yet."""
        p = self.p
        h, w = grey.shape
        reach = 2 ** (int(p.lk_levels) + 1) * p.lk_window
        x0, y0 = (np.maximum(np.floor(points.min(axis=0)) - reach, 0)).astype(int)
        x1, y1 = np.minimum(np.ceil(points.max(axis=0)) + reach + 1, [w, h]).astype(int)
        prev, cur = self._prev_grey[y0:y1, x0:x1], grey[y0:y1, x0:x1]
        start = (points - [x0, y0]).astype(np.float32).reshape(-1, 1, 2)
        lk = dict(winSize=(p.lk_window, p.lk_window), maxLevel=int(p.lk_levels),
                  criteria=(cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, int(p.lk_iterations), float(p.lk_epsilon)))
        fwd, st, _ = cv2.calcOpticalFlowPyrLK(prev, cur, start, None, **lk)
        back, st_back, _ = cv2.calcOpticalFlowPyrLK(cur, prev, fwd, start.copy(), **lk,
                                                    flags=cv2.OPTFLOW_USE_INITIAL_FLOW)
        ok = (st.ravel() == 1) & (st_back.ravel() == 1) & \
            (np.linalg.norm((back - start).reshape(-1, 2), axis=1) < p.fb_threshold)
        return fwd.reshape(-1, 2).astype(np.float64) + [x0, y0], ok

    def _follow(self, grey, frame: int) -> None:
        p, a = self.p, self._a
        guess = self._predict(a.missed + 1)
        lin0 = a.warp
        if self.p.predict_turn and self.model is not None and self.model.omega != 0.0:
            # the patch turns with the spin: its linear part predicted by the shared rotation
            turn = np.stack([self.model.local_warp(self.model.omega * (m + 1)) for m in range(int(p.max_gap) + 1)])
            lin0 = turn[np.minimum(a.missed, int(p.max_gap))] @ a.warp
        fresh = np.flatnonzero((a.count == 1) & (a.missed == 0))
        coarse_ok = np.ones(len(a), bool)
        if len(fresh) and self._prev_grey is not None:
            guess[fresh], coarse_ok[fresh] = self._coarse(grey, a.pos[fresh])
        warp = np.concatenate([lin0, guess[:, :, None]], axis=2)
        image = grey.astype(np.float32)
        warp, zncc, step = self._tpl.track(image, warp, a.t, a.sdw, a.hinv, a.htinv, int(p.ic_iterations))
        new = warp[:, :, 2]
        lin = warp[:, :, :2]
        sv = np.linalg.svd(lin, compute_uv=False)
        w, h = self._size
        margin = self._tpl.half + 1
        # a patch turned or stretched by more than max_template_warp since its template ends its track (taking
        # the template anew would add drift)
        ok = (coarse_ok & (zncc >= p.min_zncc) & (np.abs(lin - np.eye(2)).max(axis=(1, 2)) < p.max_template_warp)
              & (step < p.max_final_step) & (sv[:, 1] > 0.6) & (sv[:, 0] < 1.6)
              & (np.linalg.norm(new - guess, axis=1) < p.max_anchor_disagreement)
              & (new[:, 0] >= margin) & (new[:, 0] < w - margin) & (new[:, 1] >= margin) & (new[:, 1] < h - margin)
              & np.isfinite(new).all(axis=1))
        model = self.model
        # the spin: a point off its track's ellipse (beyond a few sigma) is not taken
        gated = ok & np.isfinite(a.centre[:, 0]) & (a.count >= p.model_min_points)
        if model is not None and gated.any():
            idx = np.flatnonzero(gated)
            linear = model.linear_parts(a.moments[idx])
            dist = model.distance(model.normalise(new[idx]), linear)
            limit = max(p.ellipse_sigmas * self._sigma, p.min_ellipse_gate)
            ok[idx[dist > limit]] = False
            inlier = dist <= limit
            if inlier.sum() >= 5:
                mad = 1.4826 * float(np.median(dist[inlier]))
                self._sigma = 0.9 * self._sigma + 0.1 * max(mad, 0.02)
            # the phase advanced since the last point: votes for the common rate
            cen = model.normalise(a.centre[idx])
            dphi = model.phase(model.normalise(new[idx]), cen) - model.phase(model.normalise(a.pos[idx]), cen)
            dphi = (dphi + np.pi) % (2 * np.pi) - np.pi
            rate = dphi[inlier] / (a.missed[idx][inlier] + 1)
            if len(rate) >= 3:
                self._omega_votes.append(float(np.median(rate)))
                self._omega_votes = self._omega_votes[-30:]
        found = np.flatnonzero(ok)
        if len(found):
            pts = new[found]
            step_px = (pts - a.pos[found]) / (a.missed[found] + 1)[:, None]
            a.vel[found] = np.where((a.count[found] > 1)[:, None], 0.5 * a.vel[found] + 0.5 * step_px, step_px)
            a.pos[found] = pts
            a.warp[found] = lin[found]
            a.count[found] += 1
            a.lo[found] = np.minimum(a.lo[found], pts)
            a.hi[found] = np.maximum(a.hi[found], pts)
            d = _design((pts - self._origin) / self._scale)
            a.moments[found] += d[:, :, None] * d[:, None, :]
            self._log.append((frame, a.ids[found].copy(), pts.copy()))
            # templates older than anchor_every frames are taken anew here, at the tracked points
            old = found[frame - a.key[found] >= p.anchor_every]
            if len(old):
                a.renew(old, self._tpl.make(image, a.pos[old])[:4], frame)
        missed = np.ones(len(a), bool)
        missed[found] = False
        a.missed[missed] += 1
        a.missed[found] = 0
        ended = a.missed > p.max_gap
        parked = (a.count >= p.park_after) & (np.hypot(*(a.hi - a.lo).T) < p.park_extent) & ~ended
        if parked.any():
            self._parked = np.concatenate([self._parked, a.pos[parked]])[-2000:]
        if ended.any() or parked.any():
            a.keep(~(ended | parked))

    def _update_model(self) -> None:
        p, a = self.p, self._a
        use = (a.count >= p.model_min_points) & (np.hypot(*(a.hi - a.lo).T) >= p.min_extent)
        if use.sum() < 3:
            return
        model = SpinModel.fit(a.moments[use], a.count[use], self._origin, self._scale)
        if model is None:
            return
        linear = model.linear_parts(a.moments[use])
        centres = model.centres(linear) * self._scale + self._origin
        if self._omega_votes and self.model is not None:
            model.omega = float(np.median(self._omega_votes))
        else:
            # first model: the rate from the tracks' velocities about their centres
            cen = model.normalise(centres)
            now = model.normalise(a.pos[use])
            before = model.normalise(a.pos[use] - a.vel[use])
            dphi = model.phase(now, cen) - model.phase(before, cen)
            dphi = (dphi + np.pi) % (2 * np.pi) - np.pi
            model.omega = float(np.median(dphi))
        # a model from a few short arcs can be far off, and then its predictions lose every new corner (so it is
        # never refitted, and the tracks die at their first step): it is used only while it predicts the
        # tracks' own one-frame steps
        step = model.turn(a.pos[use], centres, model.omega) - a.pos[use]
        speed = float(np.median(np.hypot(*a.vel[use].T)))
        step_error = float(np.median(np.hypot(*(step - a.vel[use]).T)))
        a.centre[:] = np.nan
        if step_error > p.model_max_step_error * max(speed, 1e-3):
            self.model = None
            self._omega_votes = []
            return
        self.model = model
        a.centre[use] = centres

    def _seed(self, grey, frame: int, exclude) -> None:
        p, a = self.p, self._a
        self._last_seed = frame
        room = int(p.max_corners) - len(a)
        if room <= 0:
            return
        heat = cv2.compare(self._heat, 0, cv2.CMP_GT)
        nz = cv2.findNonZero(heat)
        if nz is None:
            return
        # only the moving region's bounding box (at full resolution) is searched
        x, y, bw, bh = cv2.boundingRect(nz)
        h, w = grey.shape
        x0, y0, x1, y1 = max(2 * x - 2, 0), max(2 * y - 2, 0), min(2 * (x + bw) + 2, w), min(2 * (y + bh) + 2, h)
        mask = cv2.resize(heat, (w, h), interpolation=cv2.INTER_NEAREST)[y0:y1, x0:x1]
        if p.seed_margin > 0:
            # not within seed_margin px of the moving region's boundary (silhouettes against the still scene)
            r = int(math.ceil(p.seed_margin))
            mask = cv2.erode(mask, cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * r + 1, 2 * r + 1)))
        taken = np.zeros_like(mask)
        points = np.concatenate([a.pos, self._parked]) - [x0, y0]
        _stamp(taken, points)
        r = int(math.ceil(p.corner_min_distance))
        taken = cv2.dilate(taken, cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * r + 1, 2 * r + 1)))
        if exclude is not None and len(exclude):
            blobs = np.zeros_like(mask)
            _stamp(blobs, exclude[:, :2] - [x0, y0])
            rb = int(math.ceil(2.0 * float(np.median(exclude[:, 2])) + p.corner_min_distance))
            taken |= cv2.dilate(blobs, cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * rb + 1, 2 * rb + 1)))
        mask[taken > 0] = 0
        border = self._tpl.half + 3
        mask[:max(border - y0, 0)] = 0
        mask[:, :max(border - x0, 0)] = 0
        if y1 > h - border:
            mask[mask.shape[0] - (y1 - (h - border)):] = 0
        if x1 > w - border:
            mask[:, mask.shape[1] - (x1 - (w - border)):] = 0
        if not mask.any():
            return
        found = cv2.goodFeaturesToTrack(grey[y0:y1, x0:x1], maxCorners=room, qualityLevel=float(p.corner_quality),
                                        minDistance=float(p.corner_min_distance), mask=mask,
                                        blockSize=int(p.corner_block_size))
        if found is None or not len(found):
            return
        pts = found.reshape(-1, 2).astype(np.float64) + [x0, y0]
        *templates, strength, anisotropy = self._tpl.make(grey.astype(np.float32), pts)
        # an edge-like patch is followed along its edge by its appearance changes alone, not by its texture: such a
        # track drifts smoothly off its ellipse (normal to its motion) as the surface turns
        strong = (strength >= p.corner_min_eigen) & (anisotropy <= p.corner_max_anisotropy)
        if self._prev_grey is not None and p.seed_motion_fraction > 0:
            # a patch straddling a silhouette is partly still: most of a seed's window must have just changed
            crop = (slice(y0, y1), slice(x0, x1))
            changed = cv2.compare(cv2.absdiff(grey[crop], self._prev_grey[crop]), float(p.motion_threshold) / 2,
                                  cv2.CMP_GT)
            side = int(p.corner_window)
            support = cv2.boxFilter(changed, cv2.CV_32F, (side, side), normalize=True) / 255.0
            q = np.rint(pts - [x0, y0]).astype(np.int64)
            strong &= support[q[:, 1], q[:, 0]] >= p.seed_motion_fraction
        if not strong.any():
            return
        pts = pts[strong]
        templates = [t[strong] for t in templates]
        ids = np.arange(self._next_id, self._next_id + len(pts))
        self._next_id += len(pts)
        a.add(ids, pts, frame, templates)
        d = _design((pts - self._origin) / self._scale)
        a.moments[-len(pts):] += d[:, :, None] * d[:, None, :]
        self._log.append((frame, ids, pts.copy()))
        self._patch_ids.append(ids)
        self._patches.append(_patches(grey, pts))

    # --- results
    def raw_tracks(self) -> tuple[list[Track], dict[int, np.ndarray], list[int]]:
        """(tracks, {track id: seed patch}, track ids), tracks ordered by id."""
        if not self._log:
            return [], {}, []
        tracks, track_ids = tracks_from_log(self._log)
        patches = {}
        for pid, patch in zip(self._patch_ids, self._patches, strict=True):
            patches.update(zip(pid.tolist(), patch, strict=True))
        return tracks, patches, track_ids


def tracks_from_log(log) -> tuple[list[Track], list[int]]:
    """Tracks (ordered by id) and their ids from a per-frame log of ``(frame, ids (n,), pixels (n, 2))``."""
    frames = np.concatenate([np.full(len(ids), f, np.int64) for f, ids, _ in log])
    ids = np.concatenate([ids for _, ids, _ in log])
    pixels = np.concatenate([pts for _, _, pts in log])
    order = np.lexsort((frames, ids))
    frames, ids, pixels = frames[order], ids[order], pixels[order]
    cuts = np.flatnonzero(np.diff(ids)) + 1
    tracks = [Track(px, fr) for fr, px in zip(np.split(frames, cuts), np.split(pixels, cuts), strict=True)]
    return tracks, [int(i) for i in ids[np.concatenate([[0], cuts])]]


def _stamp(image: np.ndarray, points: np.ndarray) -> None:
    if not len(points):
        return
    h, w = image.shape
    q = np.rint(points).astype(np.int64)
    inside = (q[:, 0] >= 0) & (q[:, 0] < w) & (q[:, 1] >= 0) & (q[:, 1] < h)
    image[q[inside, 1], q[inside, 0]] = 255


def _patches(grey: np.ndarray, points: np.ndarray) -> np.ndarray:
    """(n, PATCH, PATCH) float32 patches centred (to the nearest pixel) on the points, edge-padded."""
    half = PATCH // 2
    padded = np.pad(grey, half, mode="edge")
    q = np.rint(points).astype(np.int64) + half
    off = np.arange(-half, half + 1)
    return padded[q[:, 1, None, None] + off[None, :, None], q[:, 0, None, None] + off[None, None, :]].astype(
        np.float32)

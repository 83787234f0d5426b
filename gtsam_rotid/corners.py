"""Corner features on ambient texture, and the spin's shared rotation (used by :mod:`gtsam_rotid.tracking`).

:class:`CornerFollower` seeds Shi–Tomasi corners (``cv2.goodFeaturesToTrack``) only where the image moves (a
motion mask: frame differences at half resolution, remembered for ``motion_memory`` frames, so the background
and the still links never seed tracks), follows them with pyramidal Lucas–Kanade (forward–backward check) from
a prediction, and limits LK's drift by tracking each point against a reference (anchor) frame that is renewed
only every ``anchor_every`` frames, not frame to frame. All features of one spin turn together about one axis:
each track's points lie on an ellipse and all advance in phase at one rate. :class:`SpinModel` holds that
shared rotation (one conic shape shared by all tracks, each with its own centre and size, and the common rate),
fitted by variable projection from per-track moments; online it predicts every point (a better LK start) and
gates points off their track's ellipse. Offline, :func:`spin_filter` fits it to whole tracks, drops points off
their track's ellipse, rejects tracks that are off their ellipse (occluding edges: a silhouette point slides
along the outline) or that do not turn with the spin (specular highlights, edges), and :func:`link_fragments`
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

PATCH = 15              # side (px) of the appearance patch kept per track for linking
_SAMPSON_FLOOR = 1e-9


# ---------------------------------------------------------------------------------------------- conics
def _design(points: np.ndarray) -> np.ndarray:
    """(..., 6) conic design rows [x², xy, y², x, y, 1]."""
    x, y = points[..., 0], points[..., 1]
    return np.stack([x * x, x * y, y * y, x, y, np.ones_like(x)], axis=-1)


@dataclass
class SpinModel:
    """One spin's shared rotation in normalised image coordinates ``(p - origin) / scale``.

    ``shape``: the conic's quadratic part (s0 x² + s1 xy + s2 y²), shared by every track (exact for an affine
    camera, close for a perspective one); ``W`` the symmetric square root of its matrix (det 1), which maps
    every track's ellipse to a circle; ``omega`` the common rate (rad per frame, signed) in that frame.
    """

    origin: np.ndarray
    scale: float
    shape: np.ndarray                      # (3,)
    W: np.ndarray                          # (2, 2)
    omega: float = 0.0

    @classmethod
    def fit(cls, moments: np.ndarray, counts, origin, scale, iterations: int = 3) -> SpinModel | None:
        """From per-track conic moments (n, 6, 6) (sum of d dᵀ over each track's ``counts`` normalised points):
        the shared shape minimising each track's mean algebraic error with its linear part free (variable
        projection), tracks far off the shared shape down-weighted. None if it is not an ellipse."""
        if len(moments) == 0:
            return None
        moments = moments / np.asarray(counts, float)[:, None, None]
        reduced = _reduced(moments)
        weights = np.ones(len(moments))
        model = None
        for _ in range(iterations):
            values, vectors = np.linalg.eigh((reduced * weights[:, None, None]).sum(axis=0))
            model = cls.from_shape(vectors[:, 0], origin, scale)
            if model is None:
                return None
            # each track's mean squared algebraic error at the shared shape, over its gradient scale
            error = np.einsum("i,nij,j->n", model.shape, reduced, model.shape)
            error = error / max(float(np.median(error)), 1e-18)
            weights = 1.0 / np.maximum(error, 1.0)
        return model

    @classmethod
    def from_shape(cls, s, origin, scale) -> SpinModel | None:
        s = np.asarray(s, float)
        matrix = np.array([[s[0], s[1] / 2], [s[1] / 2, s[2]]])
        det = np.linalg.det(matrix)
        if not det > 0:
            return None
        if matrix[0, 0] < 0:
            matrix, s = -matrix, -s
        matrix /= math.sqrt(det)
        s = s / math.sqrt(det)
        values, vectors = np.linalg.eigh(matrix)
        if values.min() <= 0:
            return None
        w = vectors @ np.diag(np.sqrt(values)) @ vectors.T
        return cls(np.asarray(origin, float), float(scale), s, w)

    def normalise(self, pixels: np.ndarray) -> np.ndarray:
        return (np.asarray(pixels, float) - self.origin) / self.scale

    def linear_parts(self, moments: np.ndarray) -> np.ndarray:
        """(n, 3) each track's linear conic coefficients (x, y, 1) given the shared shape."""
        a_ll = moments[:, 3:, 3:] + 1e-12 * np.eye(3)
        a_lq = moments[:, 3:, :3]
        return -np.linalg.solve(a_ll, (a_lq @ self.shape)[..., None])[..., 0]

    def centres(self, linear: np.ndarray) -> np.ndarray:
        """(n, 2) normalised ellipse centres of tracks with linear parts ``linear``."""
        s0, s1, s2 = self.shape
        m = np.array([[2 * s0, s1], [s1, 2 * s2]])
        return np.linalg.solve(m, -linear[:, :2].T).T

    def distance(self, points: np.ndarray, linear: np.ndarray) -> np.ndarray:
        """Sampson distance (px) of normalised points (n, 2) from their tracks' conics (n, 3)."""
        return _sampson(points, np.concatenate([np.broadcast_to(self.shape, (len(points), 3)), linear], axis=1)) \
            * self.scale

    def phase(self, points: np.ndarray, centres: np.ndarray) -> np.ndarray:
        """Angle (rad) of each normalised point about its centre in the frame where ellipses are circles."""
        q = (points - centres) @ self.W.T
        return np.arctan2(q[..., 1], q[..., 0])

    def radius(self, points: np.ndarray, centres: np.ndarray) -> np.ndarray:
        """Radius (px) of each point about its centre in that frame."""
        return np.linalg.norm((points - centres) @ self.W.T, axis=-1) * self.scale

    def turn(self, pixels: np.ndarray, centres_px: np.ndarray, angle) -> np.ndarray:
        """Pixels turned by ``angle`` (rad, per point or scalar) about their ellipse centres (px)."""
        angle = np.broadcast_to(np.asarray(angle, float), (len(pixels),))
        c, s = np.cos(angle), np.sin(angle)
        q = (pixels - centres_px) @ self.W.T
        turned = np.stack([c * q[:, 0] - s * q[:, 1], s * q[:, 0] + c * q[:, 1]], axis=1)
        return centres_px + np.linalg.solve(self.W, turned.T).T

    def local_warp(self, angle: float) -> np.ndarray:
        """2x2 linear map of a small patch turned by ``angle`` (affine approximation)."""
        c, s = math.cos(angle), math.sin(angle)
        return np.linalg.solve(self.W, np.array([[c, -s], [s, c]]) @ self.W)


def _reduced(moments: np.ndarray) -> np.ndarray:
    """(n, 3, 3) per-track quadratic-part scatter with the linear part eliminated (variable projection)."""
    a_qq = moments[:, :3, :3]
    a_ql = moments[:, :3, 3:]
    a_ll = moments[:, 3:, 3:] + 1e-12 * np.eye(3)
    return a_qq - a_ql @ np.linalg.solve(a_ll, np.transpose(a_ql, (0, 2, 1)))


def _sampson(points: np.ndarray, conic: np.ndarray) -> np.ndarray:
    """|g(p)| / |grad g(p)| for conics (n, 6) = [s0, s1, s2, b0, b1, c] (algebraic form of ``_design``)."""
    x, y = points[:, 0], points[:, 1]
    s0, s1, s2, b0, b1, c = conic.T
    g = s0 * x * x + s1 * x * y + s2 * y * y + b0 * x + b1 * y + c
    gx = 2 * s0 * x + s1 * y + b0
    gy = s1 * x + 2 * s2 * y + b1
    return np.abs(g) / np.maximum(np.hypot(gx, gy), _SAMPSON_FLOOR)


def fit_conic(points: np.ndarray) -> np.ndarray | None:
    """Algebraic conic (6,) through (n, 2) normalised points, constrained to an ellipse; None if not one."""
    if len(points) < 6:
        return None
    d = _design(points)
    # Fitzgibbon, Pilu & Fisher: min |D a|² s.t. 4 a0 a2 - a1² = 1, via the reduced 3x3 problem
    s = d.T @ d
    s1, s2, s3 = s[:3, :3], s[:3, 3:], s[3:, 3:]
    try:
        t = -np.linalg.solve(s3 + 1e-12 * np.eye(3), s2.T)
    except np.linalg.LinAlgError:
        return None
    m = s1 + s2 @ t
    m = np.array([m[2] / 2, -m[1], m[0] / 2])
    values, vectors = np.linalg.eig(m)
    vectors = np.real(vectors)
    cond = 4 * vectors[0] * vectors[2] - vectors[1] ** 2
    good = np.flatnonzero(cond > 0)
    if not len(good):
        return None
    a1 = vectors[:, good[0]]
    return np.concatenate([a1, t @ a1])


# ---------------------------------------------------------------------------------------------- online
@dataclass
class _Corners:
    """The corner tracks being followed, one row each."""

    ids: np.ndarray = field(default_factory=lambda: np.empty(0, np.int64))
    pos: np.ndarray = field(default_factory=lambda: np.empty((0, 2)))
    vel: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))
    anchor: np.ndarray = field(default_factory=lambda: np.empty((0, 2)))      # the point in its anchor frame
    key: np.ndarray = field(default_factory=lambda: np.empty(0, np.int64))    # the anchor frame
    missed: np.ndarray = field(default_factory=lambda: np.empty(0, np.int64))
    count: np.ndarray = field(default_factory=lambda: np.empty(0, np.int64))
    lo: np.ndarray = field(default_factory=lambda: np.empty((0, 2)))
    hi: np.ndarray = field(default_factory=lambda: np.empty((0, 2)))
    moments: np.ndarray = field(default_factory=lambda: np.empty((0, 6, 6)))  # conic moments, normalised points
    centre: np.ndarray = field(default_factory=lambda: np.full((0, 2), np.nan))  # ellipse centre (px), NaN unknown

    def __len__(self) -> int:
        return len(self.ids)

    def keep(self, mask) -> None:
        for f in fields(self):
            setattr(self, f.name, getattr(self, f.name)[mask])

    def add(self, ids, pos, key: int) -> None:
        n = len(ids)
        new = dict(ids=ids, pos=pos, vel=np.zeros((n, 2)), anchor=pos.copy(), key=np.full(n, key, np.int64),
                   missed=np.zeros(n, np.int64), count=np.ones(n, np.int64), lo=pos, hi=pos,
                   moments=np.zeros((n, 6, 6)), centre=np.full((n, 2), np.nan))
        for name, values in new.items():
            setattr(self, name, np.concatenate([getattr(self, name), values]))


class CornerFollower:
    """Frame-at-a-time corner tracker; ``params`` is a :class:`gtsam_rotid.tracking.TrackerParams`."""

    def __init__(self, params):
        self.p = params
        self._lk_win = (params.lk_window, params.lk_window)
        self._criteria = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, int(params.lk_iterations),
                          float(params.lk_epsilon))
        self._a = _Corners()
        self._next_id = 0
        self._frame = -1
        self._prev_pyr = None
        self._prev_small = None
        self._heat = None
        self._keys: dict[int, list] = {}
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

    # --- per frame
    def feed(self, grey: np.ndarray, frame: int, exclude: np.ndarray | None = None) -> None:
        """Track one grey frame; ``exclude``: (k, 3) (u, v, radius) where no corner may start (blob tracks)."""
        p = self.p
        self._frame = frame
        if self._origin is None:
            h, w = grey.shape
            self._origin = np.array([(w - 1) / 2, (h - 1) / 2])
            self._scale = 0.5 * max(w, h)
        pyr = grey   # OpenCV's Python binding takes images, not prebuilt pyramids
        small = cv2.pyrDown(grey)
        if self._prev_small is not None:
            moving = cv2.compare(cv2.absdiff(small, self._prev_small), float(p.motion_threshold), cv2.CMP_GT)
            self._heat = cv2.max(cv2.subtract(self._heat, 1), cv2.bitwise_and(moving, int(p.motion_memory)))
        else:
            self._heat = np.zeros_like(small)
        if self._prev_pyr is not None and len(self._a):
            self._follow(pyr, frame)
        if frame - self._last_seed >= p.seed_every:
            self._seed(grey, pyr, frame, exclude)
        if frame % p.model_every == 0:
            self._update_model()
        live = set(int(k) for k in np.unique(self._a.key)) if len(self._a) else set()
        self._keys = {k: v for k, v in self._keys.items() if k in live or k == frame}
        self._prev_pyr, self._prev_small = pyr, small

    def _predict(self, ahead: np.ndarray) -> np.ndarray:
        a, m = self._a, self.model
        guess = a.pos + a.vel * ahead[:, None]
        if m is None or m.omega == 0.0:
            return guess
        known = np.isfinite(a.centre[:, 0]) & (a.count >= self.p.model_min_points)
        if known.any():
            guess[known] = m.turn(a.pos[known], a.centre[known], m.omega * ahead[known])
        return guess

    def _lk(self, pyr0, pyr1, points, guess, levels):
        pts, status, _ = cv2.calcOpticalFlowPyrLK(
            pyr0, pyr1, points.astype(np.float32).reshape(-1, 1, 2), guess.astype(np.float32).reshape(-1, 1, 2),
            winSize=self._lk_win, maxLevel=levels, criteria=self._criteria, flags=cv2.OPTFLOW_USE_INITIAL_FLOW,
            minEigThreshold=float(self.p.corner_min_eigen))
        return pts.reshape(-1, 2).astype(np.float64), status.ravel() == 1

    def _follow(self, pyr, frame: int) -> None:
        p, a = self.p, self._a
        levels = int(p.lk_levels)
        start = a.pos + a.vel * a.missed[:, None]          # where each point was, had it been seen last frame
        guess = self._predict(a.missed + 1)
        start = np.where((a.missed > 0)[:, None], self._predict(a.missed), start)
        fwd, ok = self._lk(self._prev_pyr, pyr, start, guess, levels)
        back, ok_back = self._lk(pyr, self._prev_pyr, fwd, start, levels)
        ok &= ok_back & (np.linalg.norm(back - start, axis=1) < p.fb_threshold)
        # drift: the same points tracked from their anchor frame, started where frame-to-frame LK put them
        new = fwd.copy()
        model = self.model
        for key in np.unique(a.key[ok]):
            idx = np.flatnonzero(ok & (a.key == key))
            if key >= frame - 1 or key not in self._keys:
                continue
            reference, anchor = self._keys[key], a.anchor[idx]
            # the anchor frame's patches have turned with the spin since: one affine warp of that frame for all
            # its points, measured from their motion (about their ellipse centres when known). LK (translation
            # only) on a turned patch would be biased by the turn times the offset of the texture in the window.
            warp = _group_warp(anchor, fwd[idx])
            if warp is None:
                renew = idx
            else:
                h, w = reference.shape
                reference = cv2.warpAffine(reference, warp, (w, h), flags=cv2.INTER_CUBIC,
                                           borderMode=cv2.BORDER_REPLICATE)
                ref, ok_ref = self._lk(reference, pyr, anchor @ warp[:, :2].T + warp[:, 2], fwd[idx], min(levels, 1))
                agree = ok_ref & (np.linalg.norm(ref - fwd[idx], axis=1) < p.max_anchor_disagreement)
                new[idx] = np.where(agree[:, None], ref, fwd[idx])
                renew = idx[~agree]
            # where there is no warp or the anchored result disagrees, the point goes on from frame-to-frame LK,
            # anchored anew here
            a.anchor[renew] = fwd[renew]
            a.key[renew] = frame
            if len(renew):
                self._keys[frame] = pyr
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
            step = (pts - a.pos[found]) / (a.missed[found] + 1)[:, None]
            a.vel[found] = np.where((a.count[found] > 1)[:, None], 0.5 * a.vel[found] + 0.5 * step, step)
            a.pos[found] = pts
            a.count[found] += 1
            a.lo[found] = np.minimum(a.lo[found], pts)
            a.hi[found] = np.maximum(a.hi[found], pts)
            d = _design((pts - self._origin) / self._scale)
            a.moments[found] += d[:, :, None] * d[:, None, :]
            self._log.append((frame, a.ids[found].copy(), pts.copy()))
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
        omega = float(np.median(self._omega_votes)) if self._omega_votes and self.model is not None else 0.0
        model.omega = omega
        self.model = model
        a.centre[:] = np.nan
        a.centre[use] = centres
        if not self._omega_votes:
            # first model: the rate from the tracks' velocities about their centres
            cen = model.normalise(centres)
            now = model.normalise(a.pos[use])
            before = model.normalise(a.pos[use] - a.vel[use])
            dphi = model.phase(now, cen) - model.phase(before, cen)
            dphi = (dphi + np.pi) % (2 * np.pi) - np.pi
            model.omega = float(np.median(dphi))

    def _seed(self, grey, pyr, frame: int, exclude) -> None:
        p, a = self.p, self._a
        self._last_seed = frame
        room = int(p.max_corners) - len(a)
        if room <= 0:
            return
        h, w = grey.shape
        mask = cv2.resize(cv2.compare(self._heat, 0, cv2.CMP_GT), (w, h), interpolation=cv2.INTER_NEAREST)
        if not mask.any():
            return
        taken = np.zeros((h, w), np.uint8)
        points = np.concatenate([a.pos, self._parked])
        _stamp(taken, points)
        r = int(math.ceil(p.corner_min_distance))
        taken = cv2.dilate(taken, cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * r + 1, 2 * r + 1)))
        if exclude is not None and len(exclude):
            blobs = np.zeros((h, w), np.uint8)
            _stamp(blobs, exclude[:, :2])
            rb = int(math.ceil(2.0 * float(np.median(exclude[:, 2])) + p.corner_min_distance))
            taken |= cv2.dilate(blobs, cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * rb + 1, 2 * rb + 1)))
        mask[taken > 0] = 0
        border = p.lk_window // 2 + 2
        mask[:border], mask[-border:], mask[:, :border], mask[:, -border:] = 0, 0, 0, 0
        found = cv2.goodFeaturesToTrack(grey, maxCorners=room, qualityLevel=float(p.corner_quality),
                                        minDistance=float(p.corner_min_distance), mask=mask,
                                        blockSize=int(p.corner_block_size))
        if found is None or not len(found):
            return
        pts = found.reshape(-1, 2).astype(np.float64)
        ids = np.arange(self._next_id, self._next_id + len(pts))
        self._next_id += len(pts)
        a.add(ids, pts, frame)
        d = _design((pts - self._origin) / self._scale)
        a.moments[-len(pts):] += d[:, :, None] * d[:, None, :]
        self._keys[frame] = pyr
        # renew the anchors of tracks whose anchor frame is old: they now track from this frame
        old = (frame - a.key >= p.anchor_every) & (a.missed == 0)
        a.anchor[old] = a.pos[old]
        a.key[old] = frame
        self._log.append((frame, ids, pts.copy()))
        self._patch_ids.append(ids)
        self._patches.append(_patches(grey, pts))

    # --- results
    def raw_tracks(self) -> tuple[list[Track], dict[int, np.ndarray], list[int]]:
        """(tracks, {track id: seed patch}, track ids), tracks ordered by id."""
        if not self._log:
            return [], {}, []
        frames = np.concatenate([np.full(len(ids), f, np.int64) for f, ids, _ in self._log])
        ids = np.concatenate([ids for _, ids, _ in self._log])
        pixels = np.concatenate([pts for _, _, pts in self._log])
        order = np.lexsort((frames, ids))
        frames, ids, pixels = frames[order], ids[order], pixels[order]
        cuts = np.flatnonzero(np.diff(ids)) + 1
        tracks = [Track(px, fr) for fr, px in zip(np.split(frames, cuts), np.split(pixels, cuts), strict=True)]
        track_ids = [int(i) for i in ids[np.concatenate([[0], cuts])]]
        patches = {}
        for pid, patch in zip(self._patch_ids, self._patches, strict=True):
            patches.update(zip(pid.tolist(), patch, strict=True))
        return tracks, patches, track_ids


def _group_warp(before: np.ndarray, after: np.ndarray, min_points: int = 6, min_motion: float = 0.5):
    """The 2x3 affine map ``after ≈ L before + t`` of one anchor group's moving points (RANSAC,
    ``cv2.estimateAffine2D``). Only its linear part matters to the patches (LK finds each point's own shift:
    coaxial circles at different heights do not share one translation). None with too few moving points or
    if L is not close to a turn (det far from 1)."""
    moving = np.linalg.norm(after - before, axis=1) >= min_motion
    if moving.sum() < min_points:
        return None
    warp, inliers = cv2.estimateAffine2D(before[moving].astype(np.float32), after[moving].astype(np.float32),
                                         method=cv2.RANSAC, ransacReprojThreshold=1.0, maxIters=200,
                                         refineIters=10)
    if warp is None or inliers is None or int(inliers.sum()) < min_points:
        return None
    det = float(np.linalg.det(warp[:, :2]))
    if not 0.8 < det < 1.25:
        return None
    return warp.astype(np.float64)


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


# ---------------------------------------------------------------------------------------------- offline
@dataclass
class SpinFit:
    """What :func:`spin_filter` found: the model, and per kept track its centre (px), radius (px, in the frame
    where ellipses are circles) and unwrapped phases."""

    model: SpinModel | None
    sigma: float = float("nan")            # robust scale (px) of the points' distances from their ellipses
    n_dropped_points: int = 0


def _track_fit(model: SpinModel, pixels: np.ndarray, own_min_arc: float):
    """(distances px, centre px, phases) of one track on the shared model, or on its own ellipse when its arc
    is long enough for one."""
    q = model.normalise(pixels)
    d = _design(q)
    moments = (d.T @ d)[None]
    linear = model.linear_parts(moments)
    centre = model.centres(linear)[0]
    phases = np.unwrap(model.phase(q, centre))
    dist = model.distance(q, np.broadcast_to(linear[0], (len(q), 3)))
    if abs(phases[-1] - phases[0]) >= own_min_arc and len(q) >= 12:
        conic = fit_conic(q)
        if conic is not None:
            own = _sampson(q, np.broadcast_to(conic, (len(q), 6))) * model.scale
            if np.median(own) <= np.median(dist):
                dist = own
    return dist, centre * model.scale + model.origin, phases


def spin_filter(tracks: list[Track], params):
    """Test tracks of one spin against its shared rotation.

    Returns ``(kept, rejected, fit)``: ``kept`` tracks (points off their ellipse by more than
    ``ellipse_sigmas`` robust sigmas dropped), ``rejected`` a list of ``(code, track, detail)`` with code
    ``"ellipse"`` (off its ellipse) or ``"rate"`` (not turning with the spin), and the :class:`SpinFit`.
    With fewer than 3 tracks long enough to fit the shared shape, nothing is tested.
    """
    p = params
    if len(tracks) < 3:
        return list(tracks), [], SpinFit(None)
    allpts = np.concatenate([t.pixels for t in tracks])
    origin = allpts.mean(axis=0)
    scale = max(float(allpts.std()), 1.0)
    designs = [_design((t.pixels - origin) / scale) for t in tracks]
    moments = np.stack([d.T @ d for d in designs])
    use = np.array([len(t) >= p.model_min_points and np.hypot(*np.ptp(t.pixels, axis=0)) >= p.min_extent
                    for t in tracks])
    if use.sum() < 3:
        return list(tracks), [], SpinFit(None)
    counts = np.array([len(t) for t in tracks])
    model = SpinModel.fit(moments[use], counts[use], origin, scale)
    if model is None:
        return list(tracks), [], SpinFit(None)
    fits = [_track_fit(model, t.pixels, p.own_ellipse_arc) for t in tracks]
    sigma = 1.4826 * float(np.median(np.concatenate([f[0] for f in fits])))
    sigma = max(sigma, 0.01)
    limit = max(p.ellipse_sigmas * sigma, p.min_ellipse_gate_offline)
    # the common rate: median of the tracks' phase slopes
    rates, spans = [], []
    for t, (_, _, phases) in zip(tracks, fits, strict=True):
        frames = t.frames if t.frames is not None else np.arange(len(t))
        rates.append(np.polyfit(frames - frames.mean(), phases, 1)[0] if len(t) >= 3 else 0.0)
        spans.append(frames[-1] - frames[0])
    rates = np.array(rates)
    long_enough = np.array(spans) >= p.min_length
    omega = float(np.median(rates[use & long_enough])) if np.any(use & long_enough) else float(np.median(rates))
    model.omega = omega
    kept, rejected, dropped = [], [], 0
    for t, (dist, _, _), rate in zip(tracks, fits, rates, strict=True):
        bad = dist > limit
        if bad.mean() > p.max_off_ellipse_fraction:
            rejected.append(("ellipse", t, f"{int(bad.sum())} of {len(t)} points beyond {limit:.2f} px "
                                           f"({p.ellipse_sigmas:g} sigma) of its ellipse, RMS "
                                           f"{float(np.sqrt(np.mean(dist**2))):.2f} px"))
            continue
        if omega != 0 and abs(rate - omega) > p.rate_tolerance * abs(omega):
            rejected.append(("rate", t, f"turns at {rate:+.4f} rad/frame, the spin at {omega:+.4f} "
                                        f"(tolerance {100 * p.rate_tolerance:.0f} %)"))
            continue
        lag = _phase_lag(t, model, omega)
        if omega != 0 and lag > p.max_phase_residual:
            rejected.append(("rate", t, f"its phase strays {lag:.1f} px (RMS along its ellipse) from the spin's "
                                        f"common rate (limit {p.max_phase_residual:g} px): it slides"))
            continue
        if bad.any():
            dropped += int(bad.sum())
            t = Track(t.pixels[~bad], None if t.frames is None else t.frames[~bad])
        kept.append(t)
    return kept, rejected, SpinFit(model, sigma, dropped)


def _phase_lag(track: Track, model: SpinModel, omega: float) -> float:
    """RMS (px along the ellipse) of a track's phases about a line of slope ``omega``: a point sliding along an
    outline (at another rate, or stopping and going) strays from the common rate."""
    _, centre, phases = _track_fit(model, track.pixels, np.inf)
    frames = track.frames if track.frames is not None else np.arange(len(track))
    residual = phases - omega * frames
    residual -= residual.mean()
    radius = float(np.median(model.radius(model.normalise(track.pixels), model.normalise(centre[None])[0])))
    return float(np.sqrt(np.mean(residual**2))) * radius


def link_fragments(tracks: list[Track], patches: list[np.ndarray | None], fit: SpinFit, params):
    """Join tracks that are pieces of one feature's arc (see the module docstring). ``patches``: the seed patch
    of each track (None: unknown, never linked). Returns (tracks, number of links made)."""
    p, model = params, fit.model
    if model is None or model.omega == 0 or len(tracks) < 2 or any(t.frames is None for t in tracks):
        return tracks, 0
    n = len(tracks)
    info = []
    for t in tracks:
        _, centre, phases = _track_fit(model, t.pixels, np.inf)
        radius = float(np.median(model.radius(model.normalise(t.pixels), model.normalise(centre[None])[0])))
        info.append((centre, radius, phases))
    candidates = []
    for i in range(n):
        for j in range(n):
            a, b = tracks[i], tracks[j]
            gap = int(b.frames[0]) - int(a.frames[-1])
            if i == j or gap <= 0 or gap > p.link_max_gap or patches[i] is None or patches[j] is None:
                continue
            (ca, ra, pa), (cb, rb, pb) = info[i], info[j]
            if np.linalg.norm(ca - cb) > p.link_tolerance + 0.02 * ra or abs(ra - rb) > p.link_tolerance + 0.01 * ra:
                continue
            want = pa[-1] + model.omega * gap
            miss = (pb[0] - want + np.pi) % (2 * np.pi) - np.pi
            if abs(miss) > p.link_phase_tolerance:
                continue
            # appearance: a's seed patch turned to b's seed phase
            turn = (pb[0] - pa[0] + np.pi) % (2 * np.pi) - np.pi
            score = _ncc(_turned(patches[i], model.local_warp(turn)), patches[j])
            if score < p.link_min_ncc:
                continue
            candidates.append((abs(miss), i, j))
    candidates.sort()
    successor, predecessor = {}, {}
    for _, i, j in candidates:
        if i in successor or j in predecessor:
            continue
        k = i     # no cycles
        while k in predecessor:
            k = predecessor[k]
        if k == j:
            continue
        successor[i], predecessor[j] = j, i
    out = []
    for i in range(n):
        if i in predecessor:
            continue
        chain = [i]
        while chain[-1] in successor:
            chain.append(successor[chain[-1]])
        pixels = np.concatenate([tracks[k].pixels for k in chain])
        frames = np.concatenate([tracks[k].frames for k in chain])
        out.append(Track(pixels, frames))
    return out, len(successor)


def _turned(patch: np.ndarray, linear: np.ndarray) -> np.ndarray:
    c = (PATCH - 1) / 2
    m = np.column_stack([linear, np.array([c, c]) - linear @ np.array([c, c])])
    return cv2.warpAffine(patch, m, (PATCH, PATCH), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)


def _ncc(a: np.ndarray, b: np.ndarray) -> float:
    inner = slice(3, PATCH - 3)
    a, b = a[inner, inner].ravel(), b[inner, inner].ravel()
    a, b = a - a.mean(), b - b.mean()
    denom = math.sqrt(float(a @ a) * float(b @ b))
    return float(a @ b) / denom if denom > 0 else 0.0

"""Offline tests of corner tracks against their spin's shared rotation (:func:`spin_filter`: points and tracks
off their ellipse, tracks that do not turn with the spin) and the linking of one feature's fragments across
occlusions (:func:`link_fragments`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

from .dataset import Track
from .spinmodel import PATCH, SpinModel, _design, _sampson, fit_conic


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
    # each track's own phase slope (about its own centre); the common rate: their median
    rates, spans = [], []
    for t, (_, _, phases) in zip(tracks, fits, strict=True):
        frames = t.frames if t.frames is not None else np.arange(len(t))
        rates.append(np.polyfit(frames - frames.mean(), phases, 1)[0] if len(t) >= 3 else 0.0)
        spans.append(frames[-1] - frames[0])
    rates, spans = np.array(rates), np.array(spans, float)
    long_enough = spans >= p.min_length
    omega = float(np.median(rates[use & long_enough])) if np.any(use & long_enough) else float(np.median(rates))
    model.omega = omega
    kept, rejected, dropped = [], [], 0
    for t, (dist, _, _) in zip(tracks, fits, strict=True):
        bad = dist > limit
        if bad.mean() > p.max_off_ellipse_fraction:
            rejected.append(("ellipse", t, f"{int(bad.sum())} of {len(t)} points beyond {limit:.2f} px "
                                           f"({p.ellipse_sigmas:g} sigma) of its ellipse, RMS "
                                           f"{float(np.sqrt(np.mean(dist**2))):.2f} px"))
            continue
        # the spin's rate in the frame where its ellipses are circles is only known to tens of per cent on real
        # renders (one ellipse shape for all tracks is an affine approximation; a 0.5 rad arc's own rate read
        # 0.3-3 times the spin's): a track must fit a turn at some rate within rate_tolerance of the spin's
        if omega != 0 and (lag := _rate_residual(t, model, omega, p.rate_tolerance)) > p.max_phase_residual:
            rejected.append(("rate", t, f"its points stray {lag:.1f} px (RMS) from the best turn about any centre "
                                        f"at a rate within {100 * p.rate_tolerance:.0f} % of the spin's "
                                        f"{omega:+.4f} rad/frame (limit {p.max_phase_residual:g} px): it slides or "
                                        f"does not turn with the spin"))
            continue
        if bad.any():
            dropped += int(bad.sum())
            t = Track(t.pixels[~bad], None if t.frames is None else t.frames[~bad])
        kept.append(t)
    return kept, rejected, SpinFit(model, sigma, dropped)


def _turn_sse(x: np.ndarray, t: np.ndarray, omegas: np.ndarray, w: np.ndarray) -> np.ndarray:
    """Sum of squared image distances (normalised units) of points ``x`` (n, 2) at centred frames ``t`` from the
    best turn at each rate of ``omegas`` (m,) about any centre: ``x_k = c + W⁻¹ R(omega t_k) a`` (``W`` maps the
    spin's ellipses to circles) is linear in the centre ``c`` and the radius vector ``a``: one 4x4 solve per
    rate. A still arc (every angle equal) leaves the radius undetermined: it fits any centre at zero radius."""
    angle = np.outer(omegas, t)
    cos, sin = np.cos(angle), np.sin(angle)
    turn = np.stack([np.stack([cos, -sin], axis=-1), np.stack([sin, cos], axis=-1)], axis=-2)    # (m, n, 2, 2)
    design = np.concatenate([np.broadcast_to(np.eye(2), turn.shape), np.linalg.inv(w) @ turn], axis=-1)
    normal = np.einsum("mnij,mnik->mjk", design, design)
    rhs = np.einsum("mnij,ni->mj", design, x)
    ridge = 1e-12 * np.trace(normal, axis1=1, axis2=2)[:, None, None] * np.eye(4)
    solution = np.linalg.solve(normal + ridge, rhs[..., None])[..., 0]
    return np.maximum(float(np.sum(x * x)) - np.sum(solution * rhs, axis=1), 0.0)


def _rate_residual(track: Track, model: SpinModel, omega: float, tolerance: float, steps: int = 21) -> float:
    """RMS (image px) of a track's points about the best turn about any centre at a rate within ``tolerance`` (a
    fraction) of the common rate ``omega`` (the turn taken in the frame where the spin's ellipses are circles,
    :func:`_turn_sse`). A point sliding
    along an outline (stopping and going, or at another rate over an arc long enough to tell) strays from every
    such turn; a good short arc does not, whatever its own centre's scatter (the centre is free here)."""
    frames = np.asarray(track.frames if track.frames is not None else np.arange(len(track)), float)
    rates = omega * (1.0 + tolerance * np.linspace(-1.0, 1.0, steps))
    sse = _turn_sse(model.normalise(track.pixels), frames - frames.mean(), rates, model.W)
    return float(np.sqrt(np.min(sse) / len(track))) * model.scale


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

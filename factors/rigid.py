"""Rigid-spin circle factor: every feature of a measurement turns with one wrist angle per frame.

Model (``docs/design.md`` §4, "The rigid spin"). Within one measurement, at frame ``f`` every feature's phase
is ``theta_f + phi0_j``. The observed pixel ``i`` of track ``j`` at frame ``f_i`` is predicted as

    ``u(phi) = pi(K X(phi))``,  ``X(phi) = R @ (1 + r sin(phi), d, r cos(phi))``,  ``phi = theta_{f_i} + phi0_j``

exactly as :func:`.geometry.circle_coordinates` / :func:`.geometry.projected_circle` (``R`` the measurement's
``gtsam.Rot3`` line variable, perturbed as ``R * Exp(w)``; ``d, r`` the track's offset and radius at unit scale).
The residual is the 2-D reprojection error ``u(phi_i) - u_obs_i``, **interleaved per pixel**:
``[du_0, dv_0, du_1, dv_1, ...]`` (i.e. ``(u - u_obs).reshape(-1)`` of the (N, 2) arrays), 2N values per track.
Unlike the free-phase circle-point factor there is no closest-phase search: the phase is a variable.

Variables:

- the line variable (``gtsam.Rot3``, tangent 3);
- one **track variable** per track, a 3-vector ``(d, r, phi0)``;
- the spin angles in **chunk variables**: ``gtsam`` Vector variables of fixed length ``C`` (``chunk_size``), chunk
  ``c`` holding ``theta`` of the frames ``first_frame + c*C .. first_frame + c*C + C - 1`` (:func:`spin_chunk_index`).
  A track's factor has keys ``[line, track, chunk_a, ..., chunk_b]`` (only the chunks its frames fall in, ascending
  chunk id) and Jacobian blocks (2N, 3), (2N, 3) and (2N, C) per chunk (zero except, in each pixel's two rows, the
  column of the pixel's frame).

Jacobians, with ``v = (1 + r s, d, r c)`` (``s, c = sin, cos(phi)``) and ``G = (du/dX) R = du/dv`` (rows ``g``):
``X(R Exp(w)) = X + R (w x v)``, so ``du/dw`` has rows ``v x g``; ``du/dd = G e1``; ``du/dr = G (s, 0, c)``;
``du/dphi = G (r c, 0, -r s)``, which is both ``du/dphi0`` and ``du/dtheta_f``.

Gauge and unconstrained entries. ``theta_f + k, phi0_j - k`` (all frames and tracks of a *connected component* — tracks
linked by shared frames — shifted together) leaves every residual unchanged: one exact gauge freedom per component.
Frames seen by no track are in no factor. :func:`initial_spin` returns the components and a mask of the observed
chunk entries, and :func:`spin_priors` builds what makes the graph well posed for LM and ``gtsam.Marginals``:

- per component, a tight prior on ``phi0`` of its first track (at its initial value, 0): any sigma fixes an exact
  gauge without changing the estimates or marginals of gauge-invariant quantities (line, ``d``, ``r``, phase
  *differences*); the tight default makes ``theta``'s and ``phi0``'s marginals those of the gauge "``phi0`` of the
  first track = 0";
- per chunk with unobserved entries, a prior on exactly those entries (at their initial values; any sigma): they
  touch no other factor, so the prior determines them and nothing else.

In synced mode (encoder priors on ``theta_f``) the encoder priors fix the gauge; leave out the gauge priors of the
components they touch. Note that ``theta`` turns with the sense of ``c1`` (the line variable's direction), so an
encoder angle ``q_f`` enters as ``theta_f = ±q_f + const``.

Cost. A factor's Jacobian is stored dense, (2N) x (6 + C * chunks touched): a track spanning a whole 60 s spin at
30 fps (1800 pixels, 57 chunks of 32) is a 3600 x 1830 matrix (~53 MB, ~150 ms per linearisation, and a 1830^2
Hessian block per track in the solve). Cut long tracks at chunk boundaries with :func:`chunk_segments` (one factor
per segment, same track key): the same 1800 pixels in segments of 2 chunks linearise in ~9 ms. A robust kernel then
reweights per segment, not per track.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from typing import NamedTuple

import gtsam
import numpy as np

from .circle import checked_track
from .geometry import _matrix

#: Default number of frames per chunk variable.
DEFAULT_CHUNK_SIZE = 32


def spin_chunk_index(frames, chunk_size: int, first_frame: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Chunk id and column within the chunk of each frame.

    Args:
        frames: (N,) integer frame indices.
        chunk_size: frames per chunk variable (``C``).
        first_frame: frame index of column 0 of chunk 0.

    Returns:
        chunk ids (N,) and columns (N,), ``frames - first_frame == ids * C + columns``.
    """
    if chunk_size < 1:
        raise ValueError(f"chunk_size must be positive, got {chunk_size}")
    frames = np.asarray(frames)
    if frames.size and not np.issubdtype(frames.dtype, np.integer):
        raise TypeError(f"frames must be integers, got dtype {frames.dtype}")
    rel = frames.astype(np.int64).reshape(-1) - int(first_frame)
    if rel.size and rel.min() < 0:
        raise ValueError(f"frame {int(rel.min()) + int(first_frame)} is before first_frame {first_frame}")
    return rel // chunk_size, rel % chunk_size


def rigid_spin_residuals(K, R, d: float, r: float, phi0: float, theta, pixels, jacobians: bool = True):
    """Reprojection errors of pixels on the circle ``(d, r)`` at phases ``theta + phi0``, with Jacobians.

    Args:
        K: (3, 3) intrinsic matrix.
        R: line variable (``gtsam.Rot3`` or (3, 3)).
        d, r, phi0: the track variable.
        theta: (N,) spin angle of each pixel's frame.
        pixels: (N, 2) observed ideal pixels.
        jacobians: also return the Jacobians.

    Returns:
        e: (2N,) ``u(theta_i + phi0) - u_obs_i``, interleaved ``[du_0, dv_0, du_1, dv_1, ...]``.
        H_line: (2N, 3) wrt the Rot3 tangent (``R * Exp(w)``), or None.
        H_track: (2N, 3) wrt ``(d, r, phi0)``, or None.
        H_theta: (2N,) wrt each row's own ``theta_i`` (``du/dphi``; equals ``H_track[:, 2]``), or None.
    """
    M = np.asarray(K, dtype=float) @ _matrix(R)
    theta = np.asarray(theta, dtype=float).reshape(-1)
    pixels = np.asarray(pixels, dtype=float).reshape(-1, 2)
    phi = theta + phi0
    s, c = np.sin(phi), np.cos(phi)
    rs, rc = r * s, r * c
    # y = K X = M v with v = (1 + r s, d, r c); u = y[:2] / y2.
    y = (M[:, 0] + d * M[:, 1])[:, None] + M[:, 0:1] * rs + M[:, 2:3] * rc  # (3, N)
    inv_z = 1.0 / y[2]
    u = y[:2] * inv_z
    e = (u.T - pixels).reshape(-1)
    if not jacobians:
        return e, None, None, None
    # G = du/dv = ([I_2 | -u] / y2) M, rows g_k = (M[k] - u_k M[2]) / y2; column j of G is Gj (N, 2).
    uz = u.T * inv_z[:, None]
    n = len(phi)
    H = np.empty((n, 2, 6))
    G0, G1, G2 = (np.outer(inv_z, M[:2, j]) - uz * M[2, j] for j in range(3))
    v0, v2 = (1.0 + rs)[:, None], rc[:, None]
    H[..., 0] = d * G2 - v2 * G1  # rows v x g (v1 = d)
    H[..., 1] = v2 * G0 - v0 * G2
    H[..., 2] = v0 * G1 - d * G0
    H[..., 3] = G1
    H[..., 4] = G0 * s[:, None] + G2 * c[:, None]
    H[..., 5] = G0 * rc[:, None] - G2 * rs[:, None]
    H = H.reshape(-1, 6)
    return e, H[:, :3], H[:, 3:], H[:, 5]


def chunk_segments(frames, chunk_size: int, chunks_per_segment: int = 2, first_frame: int = 0) -> list[np.ndarray]:
    """Pixel indices of a track cut at chunk boundaries into segments that touch at most ``chunks_per_segment`` chunks.

    A factor's Jacobian is dense over its chunks (see the module docstring), so a long track should be one
    :func:`make_rigid_circle_factor` per segment (same track key): ``pixels[idx], frames[idx]`` for each ``idx``.

    Returns:
        index arrays (ascending), one per non-empty segment, in segment order.
    """
    if chunks_per_segment < 1:
        raise ValueError(f"chunks_per_segment must be positive, got {chunks_per_segment}")
    ids, _ = spin_chunk_index(frames, chunk_size, first_frame)
    segment = ids // chunks_per_segment
    order = np.argsort(segment, kind="stable")
    bounds = np.flatnonzero(np.diff(segment[order])) + 1
    return np.split(order, bounds) if len(order) else []


def _key_lookup(keys) -> Callable[[int], int]:
    if callable(keys):
        return keys
    if isinstance(keys, Mapping):
        return keys.__getitem__
    return lambda i: keys[i]


def make_rigid_circle_factor(noise, line_key: int, track_key: int, chunk_keys_by_id, pixels, frames, K,
                             chunk_size: int = DEFAULT_CHUNK_SIZE, first_frame: int = 0) -> gtsam.CustomFactor:
    """One rigid-spin factor per track (or track segment), vectorised over its N pixels.

    Args:
        noise: gtsam noise model of dimension 2N (residuals interleaved ``[du_0, dv_0, ...]``), e.g.
            ``noiseModel.Isotropic.Sigma(2 * N, sigma_px)``; a ``noiseModel.Robust`` reweights the whole factor.
        line_key: key of the measurement's ``gtsam.Rot3`` line variable.
        track_key: key of the track variable, a 3-vector ``(d, r, phi0)``.
        chunk_keys_by_id: chunk id -> key of that chunk's Vector variable (length ``chunk_size``): a callable, a
            mapping, or a sequence indexed by chunk id.
        pixels: (N, 2) observed ideal (undistorted) pixels.
        frames: (N,) integer frame index of each pixel.
        K: (3, 3) intrinsic matrix.
        chunk_size: frames per chunk variable.
        first_frame: frame index of column 0 of chunk 0 (frames must not precede it).

    Returns:
        ``gtsam.CustomFactor`` with keys ``[line, track, chunk_a, ..., chunk_b]`` (touched chunks, ascending id).
    """
    pixels, K = checked_track(noise, pixels, K, residuals_per_pixel=2)
    ids, cols = spin_chunk_index(frames, chunk_size, first_frame)
    n = len(pixels)
    if len(ids) != n:
        raise ValueError(f"{len(ids)} frames for {n} pixels")
    if n == 0:
        raise ValueError("a track needs at least one pixel")
    chunk_ids, local = np.unique(ids, return_inverse=True)
    lookup = _key_lookup(chunk_keys_by_id)
    keys = [line_key, track_key] + [int(lookup(int(c))) for c in chunk_ids]
    n_chunks = len(chunk_ids)
    rows2 = np.arange(2 * n)
    cols2 = np.repeat(local * chunk_size + cols, 2)
    for a in (cols, local, rows2, cols2):
        a.setflags(write=False)

    def error_func(this: gtsam.CustomFactor, values: gtsam.Values, H) -> np.ndarray:
        keys = this.keys()
        d, r, phi0 = values.atVector(keys[1])
        if n_chunks == 1:
            theta = values.atVector(keys[2])[cols]
        else:
            theta = np.stack([values.atVector(k) for k in keys[2:]])[local, cols]
        e, H_line, H_track, H_theta = rigid_spin_residuals(K, values.atRot3(keys[0]).matrix(), d, r, phi0, theta,
                                                           pixels, jacobians=H is not None)
        if H is not None:
            H[0] = H_line
            H[1] = H_track
            block = np.zeros((2 * n, n_chunks * chunk_size))
            block[rows2, cols2] = H_theta
            for i in range(n_chunks):
                H[2 + i] = block[:, i * chunk_size:(i + 1) * chunk_size]
        return e

    return gtsam.CustomFactor(noise, keys, error_func)


# ----------------------------------------------------------------------------------------------------------------
# Initial values, gauge and unconstrained entries
# ----------------------------------------------------------------------------------------------------------------


class SpinInit(NamedTuple):
    """Result of :func:`initial_spin`.

    theta: chunk id -> (C,) spin angles (only chunks some track touches); per component unwrapped along the frames,
        unobserved entries linearly interpolated (meaningless: see ``observed``).
    phi0: (J,) phase offset per track in [-pi, pi); 0 for the first track of each component.
    components: lists of track indices linked by shared frames, each ascending, ordered by first track.
    observed: chunk id -> (C,) bool, entries of frames that some track sees.
    """

    theta: dict[int, np.ndarray]
    phi0: np.ndarray
    components: list[list[int]]
    observed: dict[int, np.ndarray]


def _wrap(a):
    return np.mod(np.asarray(a) + np.pi, 2.0 * np.pi) - np.pi


def initial_spin(phases_by_track: Sequence[tuple], chunk_size: int = DEFAULT_CHUNK_SIZE, first_frame: int = 0,
                 refine_iterations: int = 3) -> SpinInit:
    """Consistent spin angles ``theta_f`` and phase offsets ``phi0_j`` from per-pixel phases.

    The per-pixel phases ``p_i ≈ theta_{f_i} + phi0_j`` (e.g. :func:`.circle_track.closest_phases` of each track on a
    solved free-phase model) are combined with circular means, so wraps by 2 pi anywhere are harmless. Tracks that
    share a frame are linked; in each connected component ``phi0`` of its first track is 0, the other tracks are
    placed one at a time (the one sharing most pixels with the frames placed so far first): ``phi0_j`` = circular
    mean of ``p_i - theta_{f_i}`` over the shared frames, then its frames' ``theta`` accumulate ``p_i - phi0_j``.
    ``refine_iterations`` rounds of alternating circular means (``theta_f`` over all pixels at ``f``, then each
    ``phi0_j``) follow, and the component is shifted back to ``phi0`` of its first track = 0.

    Args:
        phases_by_track: per track ``(frames (N_j,) int, phases (N_j,))``.
        chunk_size: frames per chunk variable.
        first_frame: frame index of column 0 of chunk 0.
        refine_iterations: alternating refinement rounds.

    Returns:
        :class:`SpinInit` ``(theta, phi0, components, observed)``.
    """
    tracks = _phasor_tracks(phases_by_track, chunk_size, first_frame)
    n_frames = max((int(f.max()) + 1 for f, _ in tracks if len(f)), default=0)
    components = _track_components(tracks, n_frames)
    phi0 = _place_tracks(tracks, components, n_frames)
    _refine_offsets(tracks, phi0, n_frames, refine_iterations)
    theta, seen, phi0 = _spin_angles(tracks, components, phi0, n_frames)
    theta_chunks, observed = _spin_chunks(tracks, theta, seen, n_frames, chunk_size)
    return SpinInit(theta_chunks, phi0, components, observed)


def _phasor_tracks(phases_by_track: Sequence[tuple], chunk_size: int,
                   first_frame: int) -> list[tuple[np.ndarray, np.ndarray]]:
    """Per track: its pixels' frames (relative to ``first_frame``) and the unit phasors ``exp(i p)`` of their
    phases."""
    tracks = []
    for frames, phases in phases_by_track:
        ids, cols = spin_chunk_index(frames, chunk_size, first_frame)
        phases = np.asarray(phases, dtype=float).reshape(-1)
        if len(phases) != len(ids):
            raise ValueError(f"{len(ids)} frames for {len(phases)} phases")
        tracks.append((ids * chunk_size + cols, np.exp(1j * phases)))
    return tracks


def _track_components(tracks: list, n_frames: int) -> list[list[int]]:
    """Connected components of the track-frame graph (union-find on tracks): tracks linked by shared frames, each
    ascending, ordered by first track."""
    parent = list(range(len(tracks)))

    def find(a: int) -> int:
        while parent[a] != a:
            parent[a] = parent[parent[a]]
            a = parent[a]
        return a

    owner = np.full(n_frames, -1)
    for j, (f, _) in enumerate(tracks):
        for o in np.unique(owner[f]):
            if o >= 0:
                ra, rb = find(j), find(int(o))
                parent[max(ra, rb)] = min(ra, rb)
        owner[f] = j
    groups: dict[int, list[int]] = {}
    for j in range(len(tracks)):
        groups.setdefault(find(j), []).append(j)
    return sorted(groups.values(), key=lambda g: g[0])


def _place_tracks(tracks: list, components: list[list[int]], n_frames: int) -> np.ndarray:
    """``phi0`` (J,) of the tracks placed one at a time per component (its first track at 0, then the one sharing
    most pixels with the frames placed so far, the earliest in component order on a tie): the circular mean of
    ``p_i - theta_{f_i}`` over the shared frames. The counts of shared pixels are kept up to date from the frames
    each placement newly covers (not recounted for every track at every step)."""
    phi0 = np.zeros(len(tracks))
    Z = np.zeros(n_frames, dtype=complex)  # sum of unit phasors exp(i theta_f) from the placed tracks
    covered = np.zeros(n_frames, dtype=bool)
    frames = np.concatenate([f for f, _ in tracks]) if tracks else np.zeros(0, dtype=int)
    owner = np.repeat(np.arange(len(tracks)), [len(f) for f, _ in tracks])
    order = np.argsort(frames, kind="stable")
    starts = np.searchsorted(frames[order], np.arange(n_frames + 1))  # pixels of frame f: order[starts[f]:starts[f+1]]
    for comp in components:
        shared = np.zeros(len(tracks), dtype=np.int64)  # pixels of each track at covered frames
        todo = list(comp)
        j, first = todo.pop(0), True
        while True:
            f, z = tracks[j]
            if not first:
                phi0[j] = np.angle(np.sum(z * np.conj(Z[f])))
            np.add.at(Z, f, z * np.exp(-1j * phi0[j]))
            new = np.unique(f[~covered[f]])
            covered[new] = True
            lengths = starts[new + 1] - starts[new]
            at_new = order[np.repeat(starts[new] - np.cumsum(lengths) + lengths, lengths) + np.arange(lengths.sum())]
            shared += np.bincount(owner[at_new], minlength=len(tracks))
            if not todo:
                break
            j, first = todo.pop(int(np.argmax(shared[todo]))), False
    return phi0


def _phasor_sums(tracks: list, phi0: np.ndarray, n_frames: int) -> np.ndarray:
    """Per frame, the sum over the tracks' pixels at that frame of ``exp(i (p_i - phi0_j))``."""
    if not tracks:
        return np.zeros(n_frames, dtype=complex)
    frames = np.concatenate([f for f, _ in tracks])
    z = np.concatenate([z * np.exp(-1j * phi0[j]) for j, (_, z) in enumerate(tracks)])
    return np.bincount(frames, weights=z.real, minlength=n_frames) + 1j * np.bincount(frames, weights=z.imag,
                                                                                       minlength=n_frames)


def _refine_offsets(tracks: list, phi0: np.ndarray, n_frames: int, iterations: int) -> None:
    """Alternating circular means, ``phi0`` modified in place: ``theta_f`` over all pixels at ``f``, then each
    ``phi0_j``."""
    if not tracks:
        return
    frames = np.concatenate([f for f, _ in tracks])
    z = np.concatenate([z for _, z in tracks])
    owner = np.repeat(np.arange(len(tracks)), [len(f) for f, _ in tracks])
    seen = np.bincount(owner, minlength=len(tracks)) > 0
    for _ in range(iterations):
        unit = np.exp(1j * np.angle(_phasor_sums(tracks, phi0, n_frames)))
        w = z * np.conj(unit[frames])
        sums = np.bincount(owner, weights=w.real, minlength=len(tracks)) + 1j * np.bincount(
            owner, weights=w.imag, minlength=len(tracks))
        phi0[seen] = np.angle(sums[seen])


def _spin_angles(tracks: list, components: list[list[int]], phi0: np.ndarray,
                 n_frames: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Spin angles ``theta`` (n_frames,) (per component unwrapped along the frames, unseen frames interpolated), the
    mask of the frames seen, and ``phi0`` shifted per component to ``phi0`` of its first track = 0 (``phi0`` is
    modified) and wrapped to [-pi, pi)."""
    Z = _phasor_sums(tracks, phi0, n_frames)
    seen = np.abs(Z) > 0.0
    theta = np.angle(Z)
    for comp in components:
        shift = phi0[comp[0]]
        phi0[comp] -= shift
        frames = np.unique(np.concatenate([tracks[j][0] for j in comp]))
        if len(frames):
            theta[frames] = np.unwrap(theta[frames] + shift)
    phi0 = _wrap(phi0)

    seen_frames = np.flatnonzero(seen)
    if len(seen_frames):
        theta = np.interp(np.arange(n_frames), seen_frames, theta[seen_frames])
    return theta, seen, phi0


def _spin_chunks(tracks: list, theta: np.ndarray, seen: np.ndarray, n_frames: int,
                 chunk_size: int) -> tuple[dict[int, np.ndarray], dict[int, np.ndarray]]:
    """``theta`` and the mask of the frames seen, cut into the chunks that some track touches."""
    touched = sorted({int(c) for f, _ in tracks for c in np.unique(f // chunk_size)})
    padded = np.zeros((touched[-1] + 1) * chunk_size if touched else 0)
    padded[:n_frames] = theta
    mask = np.zeros(len(padded), dtype=bool)
    mask[:n_frames] = seen
    theta_chunks = {c: padded[c * chunk_size:(c + 1) * chunk_size].copy() for c in touched}
    observed = {c: mask[c * chunk_size:(c + 1) * chunk_size].copy() for c in touched}
    return theta_chunks, observed


def make_entries_prior(key: int, columns, mean, sigma: float) -> gtsam.CustomFactor:
    """Prior on selected entries of a Vector variable: residual ``x[columns] - mean`` (isotropic ``sigma``).

    Args:
        key: key of the Vector variable.
        columns: (M,) entry indices.
        mean: (M,) prior values.
        sigma: standard deviation of each entry.
    """
    columns = np.array(columns, dtype=int).reshape(-1)
    mean = np.array(mean, dtype=float).reshape(-1)
    if len(columns) == 0 or len(mean) != len(columns):
        raise ValueError(f"need one mean per column, got {len(mean)} means for {len(columns)} columns")
    columns.setflags(write=False)
    mean.setflags(write=False)

    def error_func(this: gtsam.CustomFactor, values: gtsam.Values, H) -> np.ndarray:
        x = values.atVector(this.keys()[0])
        if H is not None:
            J = np.zeros((len(columns), len(x)))
            J[np.arange(len(columns)), columns] = 1.0
            H[0] = J
        return x[columns] - mean

    return gtsam.CustomFactor(gtsam.noiseModel.Isotropic.Sigma(len(columns), sigma), [key], error_func)


def spin_priors(init: SpinInit, chunk_keys_by_id, track_keys, *, gauge_sigma: float = 1e-6,
                free_sigma: float = 1.0, gauge: bool = True) -> list[gtsam.CustomFactor]:
    """The priors that make a rigid-spin graph well posed (see the module docstring).

    - ``gauge``: per component, ``phi0`` of its first track (entry 2 of the track variable) at ``init.phi0`` (0),
      sigma ``gauge_sigma``;
    - per chunk with unobserved entries, those entries at ``init.theta``, sigma ``free_sigma``.

    Args:
        init: the :class:`SpinInit` whose values the graph starts from.
        chunk_keys_by_id: chunk id -> key (callable, mapping or sequence).
        track_keys: track index -> key (callable, mapping or sequence).
        gauge_sigma: sigma of the gauge priors (rad); any value fixes the gauge.
        free_sigma: sigma of the unobserved entries (rad); they affect nothing else.
        gauge: add the gauge priors (leave out when encoder priors on theta fix the gauge).
    """
    chunk_key = _key_lookup(chunk_keys_by_id)
    track_key = _key_lookup(track_keys)
    factors = []
    if gauge:
        for comp in init.components:
            factors.append(make_entries_prior(int(track_key(comp[0])), [2], [init.phi0[comp[0]]], gauge_sigma))
    for c, seen in init.observed.items():
        free = np.flatnonzero(~seen)
        if len(free):
            factors.append(make_entries_prior(int(chunk_key(c)), free, init.theta[c][free], free_sigma))
    return factors

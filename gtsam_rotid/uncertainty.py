"""Information, observability and covariance of ``arm_T_camera`` (docs/design.md §5).

The information matrix of the pose is the Schur complement of the whole linearised graph onto the
Pose3 block (every other variable marginalised). Its eigen-decomposition, in the Pose3 tangent
(rotation rad, translation m in the camera frame), names the directions the data do not determine.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import gtsam
import numpy as np

#: A direction whose 1σ exceeds these (rad for rotation-dominated, m for translation-dominated
#: directions) is reported as not determined by the data.
UNOBSERVABLE_SIGMA_RAD = np.radians(5.0)
UNOBSERVABLE_SIGMA_M = 0.05
#: Eigenvalues below this fraction of the largest are numerically zero.
RELATIVE_ZERO = 1e-10
#: A numerically null direction whose rotation part (rad per m of translation) is below this is taken as a pure
#: translation. The exact symmetries of this problem (scale about the camera when every wrist axis passes through
#: one point; a shift along the axes when they are parallel) move only the camera position, and the rotation part
#: of the computed eigenvector (~1e-7) is rounding error; left in, the 1e12 variance put on that direction would
#: leak into the rotation block (1e12 x (1e-7)^2 rad^2, degrees of spurious rotation sigma).
PURE_TRANSLATION_ROTATION = 1e-3
#: Variance (rad^2 or m^2) given to an undetermined direction: sigma = 1e6, i.e. 1000 km or 1e6 rad.
UNDETERMINED_VARIANCE = 1e12


def _hessian_key_first(graph: gtsam.NonlinearFactorGraph, values: gtsam.Values,
                       key: int | list[int]) -> tuple[np.ndarray, dict[int, int]]:
    """The Gauss-Newton Hessian of the linearised graph with ``key``'s block first (or those of a list of keys, in
    its order), and each variable's offset."""
    first = list(key) if isinstance(key, list | tuple) else [key]
    ordering = gtsam.Ordering()
    for k in first:
        ordering.push_back(k)
    for other in values.keys():
        if other not in first:
            ordering.push_back(other)
    H, _ = graph.linearize(values).hessian(ordering)
    zeros = values.zeroVectors()
    offsets, offset = {}, 0
    for i in range(ordering.size()):
        offsets[ordering.at(i)] = offset
        offset += len(zeros.at(ordering.at(i)))
    return 0.5 * (H + H.T), offsets


def joint_marginal_covariance(graph: gtsam.NonlinearFactorGraph, values: gtsam.Values, keys: list[int],
                              dim: int) -> np.ndarray | None:
    """Covariance (dim x dim) of several variables together (``keys``, their dimensions summing to ``dim``), every
    other variable marginalised as :func:`marginal_information` does; None when their information is singular."""
    H, _ = _hessian_key_first(graph, values, list(keys))
    S = _schur(H, dim)
    try:
        C = np.linalg.inv(S)
    except np.linalg.LinAlgError:
        return None
    if not np.all(np.isfinite(C)) or np.min(np.linalg.eigvalsh(0.5 * (C + C.T))) <= 0.0:
        return None
    return 0.5 * (C + C.T)


def marginal_information(graph: gtsam.NonlinearFactorGraph, values: gtsam.Values, key: int | list[int],
                         dim: int) -> np.ndarray:
    """Information (dim x dim) of one variable (or of a list of them together, in its order, their dimensions
    summing to ``dim``) with every other variable marginalised (Schur complement).

    Unlike ``gtsam.Marginals`` this never throws on an indeterminate nuisance variable: directions of the
    other variables with (numerically) zero information are dropped, so a degenerate pose shows up as
    small eigenvalues of the result instead of an exception.
    """
    H, _ = _hessian_key_first(graph, values, key)
    return _schur(H, dim)


def _schur(H: np.ndarray, dim: int) -> np.ndarray:
    """The first ``dim`` variables' information with the rest marginalised (their numerically null directions
    dropped)."""
    if H.shape[0] == dim:
        return H
    H_pp, H_po, H_oo = H[:dim, :dim], H[:dim, dim:], H[dim:, dim:]
    S = _cholesky_schur(H_pp, H_po, H_oo)  # the usual case: the other variables are determined given this one
    if S is not None:
        return S
    # Scaled to a unit diagonal first: a variable held by a tight prior (the skew of refined intrinsics, 1e12 at
    # HELD_INTRINSIC_PX) must not make the others' weakly determined directions (joint offsets held by their prior
    # alone, at 1e3) look numerically null: dropped, they were taken as known, and a calibration of six poses with
    # the offsets and the intrinsics refined was called usable 3.4 mm off at a chi-square of 74.
    d = np.diag(H_oo)
    s = np.where(d > 0, 1.0 / np.sqrt(np.where(d > 0, d, 1.0)), 1.0)
    H_oo, H_po = H_oo * s[:, None] * s[None, :], H_po * s[None, :]
    S = _cholesky_schur(H_pp, H_po, H_oo)
    if S is not None:
        return S
    w, V = np.linalg.eigh(H_oo)
    keep = w > RELATIVE_ZERO * max(w.max(), 1e-300)
    H_oo_inv = (V[:, keep] / w[keep]) @ V[:, keep].T
    S = H_pp - H_po @ H_oo_inv @ H_po.T
    return 0.5 * (S + S.T)


def _cholesky_schur(H_pp: np.ndarray, H_po: np.ndarray, H_oo: np.ndarray) -> np.ndarray | None:
    """``H_pp - H_po H_oo^-1 H_op`` by Cholesky, or None where ``H_oo`` is not clearly positive definite (a pivot
    below RELATIVE_ZERO of its largest diagonal entry)."""
    try:
        L = np.linalg.cholesky(H_oo)
    except np.linalg.LinAlgError:
        return None
    if np.min(np.diag(L)) ** 2 <= RELATIVE_ZERO * np.max(np.diag(H_oo)):
        return None
    B = np.linalg.solve(L, H_po.T)
    S = H_pp - B.T @ B
    return 0.5 * (S + S.T)


def sandwich_marginal(graph: gtsam.NonlinearFactorGraph, values: gtsam.Values, key: int, dim: int,
                      extra: dict[int | tuple[int, ...], np.ndarray]) -> np.ndarray | None:
    """``key``'s block of ``H^-1 (H + D) H^-1``: the covariance when the data carry less information than the
    graph's noise models say, ``D`` (per variable, ``extra[variable] = D_block``, or per tuple of variables a block
    over them together, in the tuple's order) being the excess of the estimated meat (e.g. summed per-cluster
    scores) over ``H``. None when ``H`` is singular."""
    out = _sandwiches(graph, values, key, dim, [extra], True)
    return None if out is None else out[0]


def meat_marginals(graph: gtsam.NonlinearFactorGraph, values: gtsam.Values, keys: list[int], dim: int,
                   extras: list[dict[int | tuple[int, ...], np.ndarray]]) -> list[np.ndarray] | None:
    """Per error of ``extras``, the block of ``H^-1 D H^-1`` of several variables together (``keys``, their
    dimensions summing to ``dim``): what an error the graph does not model, of covariance ``D`` on its scores (as
    :func:`sandwich_marginal`'s ``extra``), adds to their covariance (``H`` linearised and solved once for all).
    None when ``H`` is singular."""
    return _sandwiches(graph, values, list(keys), dim, extras, False)


def _sandwiches(graph, values, key, dim: int, extras: list, with_hessian: bool) -> list[np.ndarray] | None:
    H, offsets = _hessian_key_first(graph, values, key)
    try:
        X = np.linalg.solve(H, np.eye(len(H))[:, :dim])  # the key's columns of H^-1
    except np.linalg.LinAlgError:
        return None
    if not np.all(np.isfinite(X)):
        return None
    starts = sorted(offsets.values()) + [len(H)]
    ends = dict(zip(starts[:-1], starts[1:], strict=True))
    out = []
    for extra in extras:
        D = np.zeros_like(H)
        for variables, block in extra.items():
            index = np.concatenate([np.arange(offsets[v], ends[offsets[v]])
                                    for v in (variables if isinstance(variables, tuple) else (variables,))])
            if len(index) != len(block):
                raise ValueError(f"a {len(block)}x{len(block)} block for variables {variables} of dimension "
                                 f"{len(index)}")
            D[np.ix_(index, index)] += block
        C = X.T @ (H + D if with_hessian else D) @ X
        out.append(0.5 * (C + C.T))
    return out


def pose_information(graph: gtsam.NonlinearFactorGraph, values: gtsam.Values, pose_key: int) -> np.ndarray:
    """6x6 information of the Pose3 ``pose_key``, all other variables marginalised (Schur complement)."""
    return marginal_information(graph, values, pose_key, 6)


@dataclass
class Observability:
    """Eigen-analysis of the pose information. ``unobservable_directions`` is empty when all is determined; the
    sentences that say it are :func:`gtsam_rotid.words.observability_words`."""

    eigenvalues: np.ndarray  # ascending
    eigenvectors: np.ndarray  # columns, Pose3 tangent
    unobservable_directions: list[np.ndarray]
    arm_R_camera: np.ndarray
    condition_number: float
    #: the eigenvector (column of ``eigenvectors``) each of ``unobservable_directions`` comes from
    unobservable_indices: list[int] = field(default_factory=list)

    @property
    def is_observable(self) -> bool:
        return not self.unobservable_directions

    @property
    def unobservable_sigmas(self) -> list[float]:
        """The 1σ along each of ``unobservable_directions`` (inf where the information is numerically zero)."""
        w_max = max(self.eigenvalues.max(), 1e-300)
        return [_sigma(self.eigenvalues[i], w_max) for i in self.unobservable_indices]

    def covariance(self, information: np.ndarray) -> np.ndarray:
        """Inverse of the information on the determined directions; each undetermined direction gets a variance of
        ``UNDETERMINED_VARIANCE`` (σ = 1000 km or 1e6 rad) along itself and nothing anywhere else.

        With ``N`` an orthonormal basis of the undetermined directions and ``Q`` of the rest, this is
        ``Q (Qᵀ I Q)⁻¹ Qᵀ + 1e12 N Nᵀ``: the determined block is the covariance given the undetermined
        coordinates, so a (snapped, pure-translation) null direction cannot inflate the rotation sigmas.
        """
        information = 0.5 * (information + information.T)
        if not self.unobservable_directions:
            w, V = np.linalg.eigh(information)
            w = np.where(w > RELATIVE_ZERO * max(w.max(), 1e-300), w, 1.0 / UNDETERMINED_VARIANCE)
            return (V / w) @ V.T
        basis, _, _ = np.linalg.svd(np.column_stack(self.unobservable_directions), full_matrices=True)
        k = len(self.unobservable_directions)
        N, Q = basis[:, :k], basis[:, k:]
        covariance = UNDETERMINED_VARIANCE * (N @ N.T)
        if Q.shape[1]:
            w, V = np.linalg.eigh(Q.T @ information @ Q)
            w = np.where(w > RELATIVE_ZERO * max(np.abs(information).max(), 1e-300), w, 1.0 / UNDETERMINED_VARIANCE)
            QV = Q @ V
            covariance += (QV / w) @ QV.T
        return 0.5 * (covariance + covariance.T)

    def to_dict(self) -> dict:
        return {
            "eigenvalues": self.eigenvalues.tolist(),
            "eigenvectors": self.eigenvectors.tolist(),
            "unobservable_directions": [d.tolist() for d in self.unobservable_directions],
            "arm_R_camera": self.arm_R_camera.tolist(),
            "condition_number": self.condition_number,
            "unobservable_indices": list(self.unobservable_indices),
            "words": [],  # the sentences are gtsam_rotid.words.observability_words; older readers require the key
        }

    @classmethod
    def from_dict(cls, data: dict) -> Observability:
        """Also reads files written before ``unobservable_indices`` (each direction's eigenvector is the one it is
        closest to) and ignores their ``words``."""
        V = np.array(data["eigenvectors"])
        directions = [np.array(d) for d in data["unobservable_directions"]]
        indices = data.get("unobservable_indices")
        if indices is None:
            indices = [int(np.argmax(np.abs(V.T @ d))) for d in directions]
        return cls(np.array(data["eigenvalues"]), V, directions, np.array(data["arm_R_camera"]),
                   float(data["condition_number"]), [int(i) for i in indices])


def _sigma(value: float, w_max: float) -> float:
    """1σ of an eigen-direction of the information (eigenvalue ``value``, largest ``w_max``); inf if null."""
    return np.inf if value <= RELATIVE_ZERO * w_max else 1.0 / np.sqrt(value)


def analyse_observability(information: np.ndarray, arm_T_camera: gtsam.Pose3) -> Observability:
    """Find the pose directions the information does not determine (1σ beyond ``UNOBSERVABLE_SIGMA_RAD`` or
    ``UNOBSERVABLE_SIGMA_M``)."""
    w, V = np.linalg.eigh(0.5 * (information + information.T))
    w_max = max(w.max(), 1e-300)
    R = arm_T_camera.rotation().matrix()
    unobservable, indices = [], []
    for i, (value, v) in enumerate(zip(w, V.T, strict=True)):
        rotation_part = np.linalg.norm(v[:3])
        limit = UNOBSERVABLE_SIGMA_RAD if rotation_part >= np.linalg.norm(v[3:]) else UNOBSERVABLE_SIGMA_M
        sigma = _sigma(value, w_max)
        if sigma <= limit:
            continue
        v = v if v[np.argmax(np.abs(v))] > 0 else -v
        if not np.isfinite(sigma) and rotation_part < PURE_TRANSLATION_ROTATION * np.linalg.norm(v[3:]):
            v = np.concatenate([np.zeros(3), v[3:] / np.linalg.norm(v[3:])])
        unobservable.append(v)
        indices.append(i)
    positive = w[w > RELATIVE_ZERO * w_max]
    condition = float(w_max / positive.min()) if len(positive) == 6 else float("inf")
    return Observability(w, V, unobservable, R, condition, indices)


def loewner_max(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """The smallest covariance at least as large as both ``a`` (positive definite) and ``b`` (positive
    semi-definite) in every direction that the two share eigen-directions of ``a^-1 b``: ``a^1/2 max(I, M) a^1/2``
    with ``M = a^-1/2 b a^-1/2`` (its eigenvalues clipped below at 1). Where ``a`` is not positive definite it is
    returned unchanged."""
    a = 0.5 * (a + a.T)
    try:
        root = np.linalg.cholesky(a)
    except np.linalg.LinAlgError:
        return a
    inverse = np.linalg.inv(root)
    w, U = np.linalg.eigh(inverse @ (0.5 * (b + b.T)) @ inverse.T)
    grown = root @ (U * np.maximum(w, 1.0)) @ U.T @ root.T
    return 0.5 * (grown + grown.T)


def chi2_sf(x: float, dof: int) -> float:
    """Upper-tail probability P(χ²_dof >= x): exact for dof <= 400 (half-integer incomplete gamma series,
    summed in log space), Wilson-Hilferty above."""
    if dof <= 0:
        return math.nan
    if x <= 0.0:
        return 1.0
    y = 0.5 * x
    if dof <= 400:
        if dof % 2 == 0:  # Q(n, y) = e^-y sum_{i<n} y^i / i!
            logs = [i * math.log(y) - y - math.lgamma(i + 1) for i in range(dof // 2)]
            return float(min(1.0, sum(math.exp(v) for v in logs)))
        # Q(n + 1/2, y) = erfc(sqrt(y)) + e^-y sum_{j<n} y^(j + 1/2) / Gamma(j + 3/2)
        logs = [(j + 0.5) * math.log(y) - y - math.lgamma(j + 1.5) for j in range((dof - 1) // 2)]
        return float(min(1.0, math.erfc(math.sqrt(y)) + sum(math.exp(v) for v in logs)))
    h = 2.0 / (9.0 * dof)
    z = ((x / dof) ** (1.0 / 3.0) - (1.0 - h)) / math.sqrt(h)
    return 0.5 * math.erfc(z / math.sqrt(2.0))


def chi2_isf(p: float, dof: int) -> float:
    """The x with P(χ²_dof >= x) = ``p`` (the inverse of :func:`chi2_sf`, by bisection on it; infinite at ``p`` 0,
    0 at ``p`` 1)."""
    if dof <= 0 or not 0.0 <= p <= 1.0:
        return math.nan
    if p <= 0.0:
        return math.inf
    if p >= 1.0:
        return 0.0
    low, high = 0.0, float(dof) + 10.0 * math.sqrt(2.0 * dof) + 10.0
    while chi2_sf(high, dof) > p:
        high *= 2.0
    for _ in range(100):  # the tail falls in x
        middle = 0.5 * (low + high)
        low, high = (middle, high) if chi2_sf(middle, dof) > p else (low, middle)
        if high - low <= 1e-12 * high:
            break
    return 0.5 * (low + high)


def chi2_mean_interval(dof: int, n: int, z: float = 1.959964) -> tuple[float, float]:
    """Interval of the mean of n chi-square(dof) samples (e.g. a NEES over n trials; 95 % at the default normal
    quantile z, 99.9 % at z = 3.29), by Wilson-Hilferty on chi-square(n dof)."""
    k = n * dof
    h = 2.0 / (9.0 * k)
    return tuple(k * (1.0 - h + s * z * np.sqrt(h)) ** 3 / n for s in (-1.0, 1.0))

"""The padded layout of :class:`.coaxial_tracks.CoaxialTracks`, and one evaluation of all tracks in it.

The pixels of all tracks of a measurement sit in a padded (rows, L) array: a track of ``N_j`` points fills
``ceil(N_j / L)`` consecutive rows (:class:`_Layout`); the row length ``L`` minimises the padded size plus
``ROW_COST`` per row (:func:`_layout`). Whole-array operations on the layout evaluate every track at once;
:class:`_Eval` keeps one such evaluation (phases, residuals, Jacobians, per-row coefficients).
"""

from __future__ import annotations

import numpy as np

#: Cost of one row of the padded layout, in padded points (the per-row coefficient gathers and batched products).
ROW_COST = 16


def _layout(counts: np.ndarray, row_length: int | None) -> int:
    """Row length L of the padded layout: a track of n points fills ceil(n / L) rows; L minimises the padded size
    plus ``ROW_COST`` per row."""
    nonzero = counts[counts > 0]
    if row_length is not None:
        return max(1, int(row_length))
    if len(nonzero) == 0:
        return 1
    longest = int(nonzero.max())
    candidates = np.union1d(np.arange(1, min(longest, 1024) + 1), nonzero)
    rows = -(-nonzero[None, :] // candidates[:, None])  # ceil
    cost = (rows * candidates[:, None]).sum(axis=1) + ROW_COST * rows.sum(axis=1)
    return int(candidates[np.argmin(cost)])


class _Layout:
    """Pixels of whole tracks in the padded (rows, L) layout: a track fills ceil(N_j / L) consecutive rows; padding
    entries repeat the track's first pixel (so they converge with it) and are left out of every output."""

    __slots__ = ("L", "row_track", "local", "valid", "dense", "flat_index", "pad", "pad_src", "px", "py", "P3")

    def __init__(self, L: int, row_track: np.ndarray, local: np.ndarray, valid: np.ndarray, px: np.ndarray,
                 py: np.ndarray):
        self.L = L
        self.row_track = row_track  # (rows,) track of each row
        self.local = local  # (rows, L) index of each entry in its track
        self.valid = valid  # (rows, L) False for padding
        self.dense = bool(valid.all())
        self.flat_index = np.flatnonzero(valid)
        self.pad = np.flatnonzero(~valid)
        if len(self.pad):
            starts = np.flatnonzero(np.diff(row_track, prepend=-1))  # first row of each track
            first = starts[np.searchsorted(starts, np.arange(len(row_track)), side="right") - 1]
            self.pad_src = first[self.pad // L] * L
        else:
            self.pad_src = self.pad
        self.px, self.py = px, py
        self.P3 = np.stack([np.ones_like(px), px, py], axis=1)  # (rows, 3, L)

    def subset(self, sel: np.ndarray) -> _Layout:
        """The layout of the rows ``sel`` (all rows of some tracks)."""
        return _Layout(self.L, self.row_track[sel], self.local[sel], self.valid[sel], self.px[sel], self.py[sel])

    def sync_padding(self, s: np.ndarray, c: np.ndarray) -> None:
        if len(self.pad):
            s.ravel()[self.pad] = s.ravel()[self.pad_src]
            c.ravel()[self.pad] = c.ravel()[self.pad_src]


class _Eval:
    """One evaluation of all tracks at (R, d, r) in the padded layout (padding entries are zero in V and f)."""

    __slots__ = ("key", "R", "d", "r", "s", "c", "V", "f", "rows", "has_line_jacobian")

    def __init__(self, key, R, d, r, s, c, V, f, rows):
        self.key = key
        self.R = R
        self.d = d  # (m,) the circles each track was evaluated at
        self.r = r
        self.s = s  # (rows, L) sin, cos of the closest phases
        self.c = c
        self.V = V  # (6, rows, L): e, de/dd, de/dr, de/dw0, de/dw1, de/dw2 (only the first 3 until completed)
        self.f = f  # (rows, L) kappa / (|z[:2]| y2): the Jacobians' common factor (zero at padding)
        self.rows = rows  # (N_COEFFICIENTS, rows) per-row coefficients
        self.has_line_jacobian = False

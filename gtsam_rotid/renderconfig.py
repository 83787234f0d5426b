"""What the dotted-cylinder renderer draws (:class:`RenderConfig`, its :class:`Section` s), validated.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from .errors import InputError


# --------------------------------------------------------------------------------------------- configuration
@dataclass(frozen=True)
class Section:
    """One coaxial cylinder of the end effector: ``radius`` (m) from the wrist axis, from ``start`` to
    ``stop`` (m, offsets along the axis from the wrist joint origin), carrying ``n_dots`` dots."""

    radius: float
    start: float
    stop: float
    n_dots: int


@dataclass(frozen=True)
class RenderConfig:
    """Everything the renderer draws besides the scene itself. Metres, grey levels (0-255), pixels."""

    #: The end effector, coaxial sections that do not overlap along the axis.
    sections: tuple[Section, ...] = (Section(0.035, 0.0, 0.05, 12), Section(0.055, 0.05, 0.10, 18))
    #: Range of dot radii (mm): at 0.75 m and f = 570 px, 3-7 px.
    dot_radius_mm: tuple[float, float] = (4.0, 9.0)
    #: Least gap between two dots, and between a dot and the end of its section (mm).
    dot_gap_mm: float = 3.0
    #: Range of |dot grey - body grey|; a fraction ``bright_fraction`` of the dots is brighter than the body.
    dot_contrast: tuple[float, float] = (50.0, 100.0)
    bright_fraction: float = 0.5
    body_grey: float = 128.0
    cap_grey: float = 104.0
    #: Each section's outline is drawn as a line of this grey and width (px; 0 for none), so that the edge
    #: where a nearer section hides a farther one shows.
    edge_grey: float = 84.0
    edge_width_px: float = 1.0
    #: Grey range of the static background texture and the size of its coarsest blobs (px).
    background_grey: tuple[float, float] = (40.0, 210.0)
    background_scale_px: float = 40.0
    #: Standard deviation of the Gaussian image noise (grey levels); 0 for none.
    noise_sigma: float = 2.0
    #: A dot counts as visible while cos(normal, ray to camera) exceeds this (simulate's default).
    visibility_cos: float = 0.1
    dot_vertices: int = 32
    #: Dots are filled on supersample x supersample sub-pixels per pixel.
    supersample: int = 8
    #: Seeds the covering, the background and the noise.
    seed: int = 0

    def __post_init__(self):
        sections = tuple(self.sections)
        if not sections:
            raise InputError("RenderConfig.sections must hold at least one Section")
        for i, s in enumerate(sections):
            if not isinstance(s, Section):
                raise InputError(f"RenderConfig.sections[{i}] must be a Section, got {type(s).__name__}")
            values = np.array([s.radius, s.start, s.stop], dtype=float)
            if not np.all(np.isfinite(values)) or s.radius <= 0 or s.stop <= s.start:
                raise InputError(f"section {i}: need radius > 0 and start < stop (m), got radius={s.radius}, "
                                 f"start={s.start}, stop={s.stop}")
            if isinstance(s.n_dots, bool) or not isinstance(s.n_dots, (int, np.integer)) or s.n_dots < 0:
                raise InputError(f"section {i}: n_dots must be a non-negative integer, got {s.n_dots!r}")
        by_start = sorted(range(len(sections)), key=lambda i: sections[i].start)
        for i, j in zip(by_start, by_start[1:], strict=False):
            if sections[j].start < sections[i].stop - 1e-12:
                raise InputError(f"sections {i} and {j} overlap along the axis ([{sections[i].start}, "
                                 f"{sections[i].stop}] and [{sections[j].start}, {sections[j].stop}] m)")
        object.__setattr__(self, "sections", sections)
        _check_range("dot_radius_mm", self.dot_radius_mm, low=0.0, strict_low=True)
        _check_range("dot_contrast", self.dot_contrast, low=0.0)
        _check_range("background_grey", self.background_grey, low=0.0, high=255.0)
        for name in ("dot_gap_mm", "noise_sigma", "edge_width_px"):
            value = getattr(self, name)
            if not np.isfinite(value) or value < 0:
                raise InputError(f"RenderConfig.{name} must be a finite number >= 0, got {value!r}")
        for name in ("body_grey", "cap_grey", "edge_grey"):
            value = getattr(self, name)
            if not np.isfinite(value) or not 0.0 <= value <= 255.0:
                raise InputError(f"RenderConfig.{name} must be in [0, 255], got {value!r}")
        if self.body_grey - self.dot_contrast[1] < 0.0 or self.body_grey + self.dot_contrast[1] > 255.0:
            raise InputError(f"dots at body_grey {self.body_grey} +- dot_contrast up to {self.dot_contrast[1]} "
                             f"leave the 8-bit range [0, 255]")
        if not 0.0 <= self.bright_fraction <= 1.0:
            raise InputError(f"RenderConfig.bright_fraction must be in [0, 1], got {self.bright_fraction!r}")
        if not np.isfinite(self.background_scale_px) or self.background_scale_px < 2.0:
            raise InputError(f"RenderConfig.background_scale_px must be >= 2 px, got {self.background_scale_px!r}")
        if not -1.0 < self.visibility_cos < 1.0:
            raise InputError(f"RenderConfig.visibility_cos must be in (-1, 1), got {self.visibility_cos!r}")
        check_integers(self, (("dot_vertices", 8, 1024), ("supersample", 1, 32), ("seed", 0, None)))

    def with_(self, **changes) -> RenderConfig:
        return replace(self, **changes)


def check_integers(config, bounds) -> None:
    """Each ``(field, low, high)`` of a renderer config an integer in ``[low, high]`` (``high`` None: no upper bound),
    else an :class:`InputError` naming the config class and the field."""
    for name, low, high in bounds:
        value = getattr(config, name)
        if (isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < low
                or (high is not None and value > high)):
            bound = f"an integer >= {low}" if high is None else f"an integer in [{low}, {high}]"
            raise InputError(f"{type(config).__name__}.{name} must be {bound}, got {value!r}")


def _check_range(name: str, pair, *, low: float, high: float = np.inf, strict_low: bool = False) -> None:
    try:
        lo, hi = (float(v) for v in pair)
    except (TypeError, ValueError):
        raise InputError(f"RenderConfig.{name} must be a pair (low, high), got {pair!r}") from None
    below = lo <= low if strict_low else lo < low
    if not (np.isfinite(lo) and np.isfinite(hi)) or below or hi > high or hi < lo:
        bound = f"({low}, {high}]" if strict_low else f"[{low}, {high}]"
        raise InputError(f"RenderConfig.{name} must be a pair low <= high inside {bound}, got {pair!r}")

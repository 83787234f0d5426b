"""Memory retention: a calibration, and the factors it builds, are freed once nothing refers to them.

A ``gtsam.CustomFactor`` keeps its Python error function alive from C++, where Python's garbage collector cannot
see the reference: a cycle through it (an object holding the factor whose error function refers back to the
object) is never collected. The variable-projection factor had one (``CoaxialLineFactor.factor`` calling the
bound method ``self._error_function``), so every ``calibrate`` with the default (joint, projected) method kept its
factors, their tracks and cached solves alive: ~13 MB per call on a 10 s scene, ~40 MB on the reference scene,
until a long Monte Carlo worker ran out of memory.
"""

from __future__ import annotations

import gc
import os
import weakref

import gtsam
import numpy as np
import pytest
from gtsam.symbol_shorthand import L

from gtsam_rotid.estimate import calibrate
from gtsam_rotid.factors import circle_points, make_coaxial_line_factor, project, rot3_from_line
from gtsam_rotid.factors.coaxial import CoaxialLineFactor, CoaxialTracks
from gtsam_rotid.simulate import SceneConfig, simulate

K = np.array([[570.0, 0.0, 320.0], [0.0, 575.0, 240.0], [0.0, 0.0, 1.0]])


def _line_and_tracks(n_tracks: int = 4, n_points: int = 200, seed: int = 3):
    """A line variable, noisy arcs of coaxial circles about it and their true (d, r)."""
    rng = np.random.default_rng(seed)
    line, _ = rot3_from_line(np.array([0.05, -0.02, 0.8]), np.array([0.3, 0.9, -0.3]))
    circles = np.column_stack([np.linspace(-0.1, 0.1, n_tracks), np.full(n_tracks, 0.06)])
    tracks = []
    for d, r in circles:
        phases = np.sort(rng.uniform(-2.0, 2.0, n_points))
        tracks.append(project(K, circle_points(line, d, r, phases))[0] + 0.5 * rng.standard_normal((n_points, 2)))
    return line, tracks, circles


def _used(factor: CoaxialLineFactor, line: gtsam.Rot3) -> None:
    """Solve, cache and anchor some lines, as LM does (errors and linearisations)."""
    values = gtsam.Values()
    values.insert(L(0), line)
    factor.factor.linearize(values)
    for w in ([0.01, 0.0, 0.0], [0.0, -0.02, 0.01]):
        values.update(L(0), line.retract(np.array(w)))
        factor.factor.error(values)
    assert factor.solves >= 3


def _live(*types) -> int:
    gc.collect()
    return sum(1 for o in gc.get_objects() if isinstance(o, types))


def test_coaxial_factor_is_freed():
    """Dropping the factor frees it, its tracks and its cached solves (no cycle through the CustomFactor)."""
    line, tracks, circles = _line_and_tracks()
    factor = make_coaxial_line_factor(L(0), tracks, K, circles * 1.02, sigma_px=0.5)
    _used(factor, line)
    graph = gtsam.NonlinearFactorGraph()
    graph.add(factor.factor)
    dead = [weakref.ref(factor), weakref.ref(factor.tracks)]
    del factor, graph
    gc.collect()
    assert [ref() for ref in dead] == [None, None]


def test_factor_in_a_graph_outlives_its_handle():
    """The graph's factor keeps working (same cached state) without the CoaxialLineFactor, then is freed with the
    graph."""
    line, tracks, circles = _line_and_tracks()
    handle = make_coaxial_line_factor(L(0), tracks, K, circles * 1.02, sigma_px=0.5)
    _used(handle, line)
    values = gtsam.Values()
    values.insert(L(0), line)
    expected, solves = handle.error(values), handle.solves
    graph = gtsam.NonlinearFactorGraph()
    graph.add(handle.factor)
    handle.sigma_px = 1.0  # the handle's attributes are the error function's
    assert graph.error(values) == pytest.approx(expected / 4.0, rel=1e-12)
    handle.sigma_px = 0.5
    tracks_ref = weakref.ref(handle.tracks)
    del handle
    gc.collect()
    assert tracks_ref() is not None  # held by the factor in the graph
    assert graph.error(values) == pytest.approx(expected, rel=1e-12)
    state = next(o for o in gc.get_objects() if isinstance(o, CoaxialLineFactor))  # the error function's twin
    assert state.solves == solves  # the cached solve was reused
    del state
    result = gtsam.LevenbergMarquardtOptimizer(graph, values).optimize()
    assert graph.error(result) <= expected
    del graph, result  # optimize()'s Values keeps its optimizer alive, and so the optimizer's copy of the graph
    gc.collect()
    assert tracks_ref() is None


@pytest.fixture(scope="module")
def dataset():
    return simulate(SceneConfig(duration=10.0), seed=0)[0]


def test_calibrate_keeps_no_factors_alive(dataset):
    """After ``calibrate`` returns (and its result is dropped), none of its variable-projection factors survive."""
    types = (CoaxialLineFactor, CoaxialTracks)
    before = _live(*types)
    result = calibrate(dataset)
    assert result.converged
    del result
    assert _live(*types) == before


@pytest.mark.skipif(not os.path.exists("/proc/self/status"), reason="needs /proc for the resident set size")
def test_repeated_calibrations_do_not_grow_memory(dataset):
    """Resident memory stays flat over repeated calls (the leak was ~13 MB per call on this scene)."""

    def rss_mb() -> float:
        gc.collect()
        with open("/proc/self/status") as f:
            return next(int(line.split()[1]) / 1024.0 for line in f if line.startswith("VmRSS:"))

    calibrate(dataset)  # warm-up: caches, allocator pools
    start = rss_mb()
    calls = 3
    for _ in range(calls):
        calibrate(dataset)
    growth = rss_mb() - start
    assert growth < 4.0 * calls, f"resident memory grew by {growth:.1f} MB over {calls} calibrations"

"""Speed of the circle-point factors on the reference scene (docs/design.md §6: six 60 s spins, ~56k pixels).

Builds one circle-point factor per track (as :class:`gtsam_rotid.graph.RotIdGraph` does, from the true
``arm_T_camera``; the projected-axis ties are left out) and times ``graph.error`` and ``graph.linearize`` of all
of them for several variants of the same factor:

- ``warm``: the library factor (warm-started closest phases, see ``factors/circle_track.py`` ``CircleTrack``);
- ``cold``: the library factor with ``warm_start=False`` (ray-plane start + certificate + grid fallback, every call);
- ``reference``: the original implementation (72-phase grid + 8 Newton steps every call),
  ``tests/factors/reference_circle.py``;
- ``per-pixel``: one library CustomFactor per pixel (same maths), on a subset of the pixels.

Scenarios: the same values evaluated repeatedly ("same"), a new nearby point every call, as LM's trial steps
("step 1e-5" / "step 1e-2": random tangent steps of that size on the line and relative size on the circles), and a
whole Levenberg-Marquardt solve of the circle factors from the initial values.

Run: ``python benchmarks/factor_speed.py [--seed 0] [--repeats 5] [--no-reference]``.
"""

from __future__ import annotations

import argparse
import importlib.util
import statistics
import time
from pathlib import Path

import gtsam
import numpy as np

from gtsam_rotid.dataset import Track
from gtsam_rotid.factors import CircleTrack, make_circle_point_factor
from gtsam_rotid.graph import RotIdGraph
from gtsam_rotid.simulate import reference_scene

ROOT = Path(__file__).resolve().parents[1]


def load_reference_module():
    """The original implementation, kept in the tests as a reference."""
    path = ROOT / "tests" / "factors" / "reference_circle.py"
    spec = importlib.util.spec_from_file_location("reference_circle", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def build_problem(seed: int):
    """K, the tracks [(line key, circle key, ideal pixels)], and the builder's initial values."""
    dataset, truth = reference_scene(seed=seed)
    graph, values = gtsam.NonlinearFactorGraph(), gtsam.Values()
    builder = RotIdGraph(dataset.arm, dataset.camera)
    tracks = []
    for k, measurement in enumerate(dataset.measurements):
        keys = builder.add_measurement(graph, values, k, measurement, arm_T_camera=truth.arm_T_camera, tie=False)
        for circle_key, j in zip(keys.circles, keys.tracks, strict=True):
            ideal = dataset.camera.undistort_pixels(Track.from_any(measurement.tracks[j]).pixels)
            tracks.append((keys.line_key, circle_key, ideal))
    return dataset.camera.K, tracks, values


def build_graph(tracks, K, make) -> gtsam.NonlinearFactorGraph:
    graph = gtsam.NonlinearFactorGraph()
    for line_key, circle_key, pixels in tracks:
        graph.add(make(gtsam.noiseModel.Isotropic.Sigma(len(pixels), 1.0), line_key, circle_key, pixels, K))
    return graph


def perturbed(values: gtsam.Values, tracks, scale: float, rng: np.random.Generator) -> gtsam.Values:
    """A copy of ``values`` with random tangent steps: ``scale`` rad on the lines, relative ``scale`` on circles."""
    out = gtsam.Values()
    lines = sorted({line_key for line_key, _, _ in tracks})
    for line_key in lines:
        out.insert(line_key, values.atRot3(line_key).retract(rng.normal(scale=scale, size=3)))
    for _, circle_key, _ in tracks:
        d, r = values.atVector(circle_key)
        out.insert(circle_key, np.array([d + scale * abs(r) * rng.normal(), r * (1.0 + scale * rng.normal())]))
    return out


def timed(fn, items) -> tuple[float, float]:
    """(best, median) wall time of ``fn(item)`` over the items."""
    times = []
    for item in items:
        start = time.perf_counter()
        fn(item)
        times.append(time.perf_counter() - start)
    return min(times), statistics.median(times)


def report(label: str, seconds: tuple[float, float], points: int) -> None:
    best, median = seconds
    print(f"  {label:<34s} {best * 1e3:9.2f} ms  (median {median * 1e3:9.2f})  {best / points * 1e6:7.3f} us/point")


def bench_graph(name: str, graph, values, tracks, points: int, repeats: int, fresh) -> None:
    print(f"{name}:")
    report("first error (cold start)", timed(lambda g: g.error(values), [fresh()]), points)
    report("first linearize (cold start)", timed(lambda g: g.linearize(values), [fresh()]), points)
    graph.linearize(values)
    same = [values] * repeats
    report("error, same values", timed(graph.error, same), points)
    report("linearize, same values", timed(graph.linearize, same), points)
    for scale in (1e-5, 1e-2):
        rng = np.random.default_rng(1)
        steps = [perturbed(values, tracks, scale, rng) for _ in range(repeats)]
        graph.linearize(values)
        report(f"error, step {scale:g}", timed(graph.error, steps), points)
        graph.linearize(values)
        report(f"linearize, step {scale:g}", timed(graph.linearize, steps), points)
        graph.linearize(values)

        def lm_iteration(trial):
            graph.error(trial)
            graph.linearize(trial)

        report(f"error + linearize, step {scale:g}", timed(lm_iteration, steps), points)


def lm_params() -> gtsam.LevenbergMarquardtParams:
    params = gtsam.LevenbergMarquardtParams()
    params.setDiagonalDamping(True)
    params.setlambdaUpperBound(1e15)
    params.setRelativeErrorTol(1e-10)
    params.setAbsoluteErrorTol(1e-10)
    params.setMaxIterations(30)
    return params


def python_lm(graph: gtsam.NonlinearFactorGraph, values: gtsam.Values, params: gtsam.LevenbergMarquardtParams,
              lam: float = 1e-5) -> tuple[gtsam.Values, int]:
    """A minimal Levenberg-Marquardt loop in Python: damping ``lam diag(J^T J)``, lambda /10 on success, x10 on
    failure, GTSAM's relative / absolute error tolerances.

    Every ``gtsam.Values`` here is owned by Python. GTSAM's C++ optimisers hand their internal ``Values`` to each
    CustomFactor callback, and pybind11 *copies* a C++ object that has no Python wrapper: one copy of the whole
    ``Values`` (~0.25 us per variable) per factor evaluation. A Python-owned ``Values`` is passed by reference.
    """
    values = gtsam.Values(values)
    dims = {}
    for key in values.keys():
        try:
            values.atRot3(key)
            dims[key] = 3
        except RuntimeError:
            dims[key] = len(values.atVector(key))
    error = graph.error(values)
    iterations = 0
    for _ in range(params.getMaxIterations()):
        iterations += 1
        linear = graph.linearize(values)
        diagonal = {key: np.zeros(dim) for key, dim in dims.items()}
        for i in range(linear.size()):
            factor = linear.at(i)
            A, _ = factor.jacobian()
            column = 0
            for key in factor.keys():
                diagonal[key] += np.sum(A[:, column:column + dims[key]] ** 2, axis=0)
                column += dims[key]
        while True:
            damped = gtsam.GaussianFactorGraph()
            damped.push_back(linear)
            for key, dim in dims.items():
                damped.add(gtsam.JacobianFactor(key, np.diag(np.sqrt(lam * np.maximum(diagonal[key], 1e-6))),
                                                np.zeros(dim), gtsam.noiseModel.Unit.Create(dim)))
            candidate = values.retract(damped.optimize())
            new_error = graph.error(candidate)
            if new_error < error:
                break
            lam *= 10.0
            if lam > params.getlambdaUpperBound():
                return values, iterations
        decrease = error - new_error
        values, error, lam = candidate, new_error, max(lam / 10.0, 1e-12)
        if decrease < params.getRelativeErrorTol() * error or decrease < params.getAbsoluteErrorTol():
            break
    return values, iterations


def measure_values_copy_overhead(values: gtsam.Values, factors: int = 200) -> float:
    """Microseconds per CustomFactor callback that GTSAM's LM spends outside the callback, with ``values``' size.

    Trivial one-dimensional factors on extra variables, solved by GTSAM's LM with the given ``values`` alongside.
    """
    values = gtsam.Values(values)
    graph = gtsam.NonlinearFactorGraph()
    inside = [0, 0.0]

    def error_func(this, v, H):
        start = time.perf_counter()
        x = v.atVector(this.keys()[0])
        if H is not None:
            H[0] = np.eye(1)
        inside[0] += 1
        inside[1] += time.perf_counter() - start
        return 0.5 * x

    for j in range(factors):
        key = gtsam.symbol("z", j)
        values.insert(key, np.array([1.0]))
        graph.add(gtsam.CustomFactor(gtsam.noiseModel.Unit.Create(1), [key], error_func))
    params = gtsam.LevenbergMarquardtParams()
    params.setMaxIterations(3)
    start = time.perf_counter()
    gtsam.LevenbergMarquardtOptimizer(graph, values, params).optimize()
    return (time.perf_counter() - start - inside[1]) / inside[0] * 1e6


def bench_lm(name: str, graph, values) -> gtsam.Values:
    """GTSAM's LevenbergMarquardtOptimizer (note: it copies its Values into every CustomFactor callback)."""
    start = time.perf_counter()
    optimizer = gtsam.LevenbergMarquardtOptimizer(graph, values, lm_params())
    result = optimizer.optimize()
    seconds = time.perf_counter() - start
    print(f"  GTSAM LM, {name:<10s} {seconds * 1e3:9.1f} ms  {optimizer.iterations():3d} iterations, "
          f"error {graph.error(values):.6g} -> {graph.error(result):.10g}")
    return result


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--per-pixel-points", type=int, default=3000)
    parser.add_argument("--no-reference", action="store_true", help="skip the (slow) original implementation")
    parser.add_argument("--no-lm", action="store_true", help="skip the Levenberg-Marquardt solves")
    args = parser.parse_args()

    K, tracks, values = build_problem(args.seed)
    points = sum(len(pixels) for _, _, pixels in tracks)
    sizes = [len(pixels) for _, _, pixels in tracks]
    print(f"reference scene (seed {args.seed}): {points} points in {len(tracks)} tracks "
          f"(N = {min(sizes)}..{max(sizes)}, median {int(np.median(sizes))}), "
          f"{len({t[0] for t in tracks})} measurements")

    def warm_factory():
        return build_graph(tracks, K, make_circle_point_factor)

    def cold_factory():
        return build_graph(tracks, K, lambda *a: make_circle_point_factor(*a, warm_start=False))

    warm = warm_factory()
    bench_graph("warm (library default)", warm, values, tracks, points, args.repeats, warm_factory)
    cold = cold_factory()
    bench_graph("cold (warm_start=False)", cold, values, tracks, points, args.repeats, cold_factory)
    reference = None
    if not args.no_reference:
        module = load_reference_module()

        def reference_factory():
            return build_graph(tracks, K, module.make_reference_circle_factor)

        reference = reference_factory()
        bench_graph("reference (original implementation)", reference, values, tracks, points,
                    max(2, args.repeats // 3), reference_factory)

    # One CustomFactor per pixel, same maths: the per-factor overhead dominates.
    subset, count = [], 0
    for line_key, circle_key, pixels in tracks:
        for pixel in pixels:
            if count >= args.per_pixel_points:
                break
            subset.append((line_key, circle_key, pixel[None, :]))
            count += 1
    per_pixel = build_graph(subset, K, make_circle_point_factor)
    print(f"per-pixel factors ({count} factors of one pixel each):")
    per_pixel.linearize(values)
    report("error, same values", timed(per_pixel.error, [values] * args.repeats), count)
    report("linearize, same values", timed(per_pixel.linearize, [values] * args.repeats), count)
    rng = np.random.default_rng(2)
    steps = [perturbed(values, tracks, 1e-5, rng) for _ in range(args.repeats)]
    report("linearize, step 1e-05", timed(per_pixel.linearize, steps), count)

    print("closest-phase search stages after the warm start (CircleTrack diagnostics; share of points):")
    solvers = [(line_key, circle_key, CircleTrack(K, pixels)) for line_key, circle_key, pixels in tracks]
    rng = np.random.default_rng(3)
    for label, vals in [("first call (no warm start)", values)] + [
            (f"step {scale:g}", perturbed(values, tracks, scale, rng)) for scale in (1e-5, 1e-3, 1e-2, 1e-1)]:
        before = [(t.cold_points, t.bracketed_points, t.grid_points) for _, _, t in solvers]
        for line_key, circle_key, solver in solvers:
            d, r = vals.atVector(circle_key)
            solver.evaluate(vals.atRot3(line_key).matrix(), d, r, jacobians=False)
        counts = np.sum([np.subtract((t.cold_points, t.bracketed_points, t.grid_points), b)
                         for (_, _, t), b in zip(solvers, before, strict=True)], axis=0) / points
        print(f"  {label:<28s} coarse grid {counts[0]:7.2%}   quadrant arc {counts[1]:7.2%}   "
              f"original grid {counts[2]:7.2%}")
    if args.no_lm:
        return

    print("Levenberg-Marquardt on the circle factors (from the builder's initial values):")
    graph = warm_factory()
    start = time.perf_counter()
    result, iterations = python_lm(graph, values, lm_params())
    seconds = time.perf_counter() - start
    print(f"  Python LM loop, warm {seconds * 1e3:9.1f} ms  {iterations:3d} iterations, "
          f"error {graph.error(values):.6g} -> {graph.error(result):.10g}")
    result_warm = bench_lm("warm", warm_factory(), values)
    result_cold = bench_lm("cold", cold_factory(), values)
    results = [result_warm, result_cold]
    if reference is not None:
        results.append(bench_lm("reference", reference_factory(), values))
    for other in results[1:]:
        diff = max(np.max(np.abs(result_warm.atRot3(key).localCoordinates(other.atRot3(key))))
                   for key in {t[0] for t in tracks})
        print(f"  max line difference to the warm result: {diff:.2e} rad")
    overhead = measure_values_copy_overhead(values)
    print(f"  GTSAM's optimisers copy their Values ({values.size()} variables) into every CustomFactor callback: "
          f"{overhead:.1f} us per callback here")


if __name__ == "__main__":
    main()

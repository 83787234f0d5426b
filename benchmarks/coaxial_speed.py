"""Speed of the variable-projection line factor (``factors/coaxial.py``) against one circle-point factor per track.

Reference scene (docs/design.md §6: six 60 s spins, ~56k pixels). Per measurement, the stage-1 problem as
:class:`gtsam_rotid.graph.RotIdGraph` builds it (``tie=False``): a Rot3 line variable and, either, one ``(d, r)``
variable and one circle-point factor per track (the "per-track" graph, ~60 variables), or ONE
:func:`~gtsam_rotid.factors.make_coaxial_line_factor` on the line only (the "VP" graph: the circles are projected
out inside the factor). Timed, summed over the measurements (best of ``--repeats``):

1. one evaluation (``graph.error``) and one linearisation at new values (a random step of ``--step`` rad on each
   line, as LM's trial steps; the per-track graph's circles move by the same relative step). The VP factor's
   evaluation includes the solve of its circles at the new line (warm-started); ``CoaxialTracks.evaluate`` alone
   (one pass over all tracks at given circles, no solve) is shown too;
2. stage 1: GTSAM's LM on each measurement from the builder's start at a perturbed pose (``--start-deg``,
   ``--start-mm``): the per-track graph against the VP graph (which starts its circles where the per-track graph
   starts its circle variables), stopped as ``gtsam_rotid.estimate``'s stage 1 stops (the image axis no longer
   moves, or a relative decrease below 1e-8), and with the relative tolerance alone. Also the difference of the
   resulting lines (rad; the tilt within the projection plane is weakly determined);
3. the joint graph (the pose, one line per measurement tied to it by the projected-axis factor, Huber per track,
   a weak prior on the pose) from the stage-1 results at a pose 0.05 deg / 0.5 mm from the truth: per-track
   factors (~380 variables) against one VP factor per measurement (7 variables), LM as ``estimate``'s joint
   (stops once the pose stops moving), then ``gtsam.Marginals`` of the pose; the pose difference over its sigma.

Run: ``python benchmarks/coaxial_speed.py [--seed 0] [--repeats 3] [--unwatched] [--profile]`` (~1 min).
"""

from __future__ import annotations

import argparse
import cProfile
import pstats
import time

import gtsam
import numpy as np

from gtsam_rotid.factors import image_line_from_rot3, line_distances, make_coaxial_line_factor
from gtsam_rotid.graph import RotIdGraph, lm_params, track_huber
from gtsam_rotid.simulate import reference_scene

#: As gtsam_rotid.estimate's stage 1: the image axis is watched at the tracks' bounding-box corners (px per px RMS).
WATCH_LINE_PX = 1e-4
#: As gtsam_rotid.estimate's joint: LM stops once the pose moves less than this (rad, m) per px RMS, twice.
WATCH_POSE = 1e-7


class Problem:
    """One measurement's stage-1 problem: the per-track graph and values, and what the VP factor needs."""

    def __init__(self, builder: RotIdGraph, measurement, k: int, pose: gtsam.Pose3, refine: bool):
        self.graph, self.values = gtsam.NonlinearFactorGraph(), gtsam.Values()
        prepared = builder.prepare(measurement, k)
        self.keys = builder.add_measurement(self.graph, self.values, k, measurement, arm_T_camera=pose, tie=False,
                                            prepared=prepared, refine_circles=refine)
        self.tracks = [prepared.usable[j].ideal for j in self.keys.tracks]
        self.circles = np.array([self.values.atVector(c) for c in self.keys.circles])
        self.line = self.values.atRot3(self.keys.line_key)
        self.K = builder.camera.K
        self.n_points = sum(len(t) for t in self.tracks)
        self.corners = np.array([np.min([t.min(axis=0) for t in self.tracks], axis=0),
                                 np.max([t.max(axis=0) for t in self.tracks], axis=0)])

    def vp(self):
        """A fresh VP factor and its graph and values."""
        factor = make_coaxial_line_factor(self.keys.line_key, self.tracks, self.K, self.circles)
        graph = gtsam.NonlinearFactorGraph()
        graph.add(factor.factor)
        values = gtsam.Values()
        values.insert(self.keys.line_key, self.line)
        return factor, graph, values

    def stepped(self, rng: np.random.Generator, scale: float) -> tuple[gtsam.Values, gtsam.Values]:
        """(per-track values, VP values) after the same random step of the line (and of the circles)."""
        line = self.line.retract(rng.normal(scale=scale, size=3))
        full, vp = gtsam.Values(), gtsam.Values()
        full.insert(self.keys.line_key, line)
        vp.insert(self.keys.line_key, line)
        for key, (d, r) in zip(self.keys.circles, self.circles, strict=True):
            full.insert(key, np.array([d + scale * abs(r) * rng.normal(), r * (1.0 + scale * rng.normal())]))
        return full, vp


def perturbed_pose(pose: gtsam.Pose3, degrees: float, mm: float, rng: np.random.Generator) -> gtsam.Pose3:
    axis, shift = rng.normal(size=3), rng.normal(size=3)
    xi = np.concatenate([np.radians(degrees) * axis / np.linalg.norm(axis), 1e-3 * mm * shift / np.linalg.norm(shift)])
    return pose.retract(xi)


def best(times: list[float]) -> float:
    return min(times)


def time_passes(problems, repeats: int, step: float) -> None:
    """One evaluation and one linearisation at new values, summed over the measurements."""
    rng = np.random.default_rng(1)
    vps = [p.vp() for p in problems]
    for p, (_, graph, values) in zip(problems, vps, strict=True):
        p.graph.linearize(p.values)  # warm starts
        graph.linearize(values)
    rows = {"per-track error": [], "VP error (incl. circle solve)": [], "per-track linearize": [],
            "VP linearize (incl. circle solve)": [], "CoaxialTracks.evaluate (one pass, no solve)": []}
    evaluations = []
    for _ in range(repeats):
        steps = [p.stepped(rng, step) for p in problems]
        totals = dict.fromkeys(rows, 0.0)
        before = sum(f.work for f, _, _ in vps)

        def timed(name, call, *args, totals=totals, **kwargs):
            start = time.perf_counter()
            call(*args, **kwargs)
            totals[name] += time.perf_counter() - start

        for p, (factor, graph, _), (full, vp) in zip(problems, vps, steps, strict=True):
            timed("per-track error", p.graph.error, full)
            timed("VP error (incl. circle solve)", graph.error, vp)
            line = vp.atRot3(p.keys.line_key)
            d, r = factor.circles(line).T
            timed("CoaxialTracks.evaluate (one pass, no solve)", factor.tracks.evaluate, line, d * (1.0 + 1e-9), r,
                  jacobians=True)
        evaluations.append(sum(f.work for f, _, _ in vps) - before)
        steps = [p.stepped(rng, step) for p in problems]
        for p, (_, graph, _), (full, vp) in zip(problems, vps, steps, strict=True):
            timed("per-track linearize", p.graph.linearize, full)
            timed("VP linearize (incl. circle solve)", graph.linearize, vp)
        for name, seconds in totals.items():
            rows[name].append(seconds)
    n_points = sum(p.n_points for p in problems)
    print(f"One pass over all {len(problems)} measurements ({n_points} pixels), new values (step {step:g} rad), "
          f"best of {repeats}:")
    for name, times in rows.items():
        print(f"  {name:<44s} {best(times) * 1e3:8.2f} ms  ({best(times) / n_points * 1e9:6.1f} ns/pixel, "
              f"{best(times) / len(problems) * 1e3:5.2f} ms per measurement)")
    error_ratio = best(rows["per-track error"]) / best(rows["VP error (incl. circle solve)"])
    print(f"  error ratio per-track / VP:      {error_ratio:6.2f}x"
          f"   (the VP solve took {np.mean(evaluations) / len(problems):.1f} track passes per measurement)")
    print(f"  linearize ratio per-track / VP:  "
          f"{best(rows['per-track linearize']) / best(rows['VP linearize (incl. circle solve)']):6.2f}x")


def watched_lm(graph, values, p: Problem, watch: bool) -> tuple[gtsam.Values, int]:
    """GTSAM's LM, relative error tolerance 1e-8; with ``watch``, as ``gtsam_rotid.estimate``'s stage 1 does, it also
    stops once two iterations in a row move the image axis at the corners of the tracks' bounding box by less than
    ``WATCH_LINE_PX`` per pixel of residual RMS (the axis' tilt within its projection plane is a nuisance)."""
    params = lm_params(100, 1e-8)
    optimizer = gtsam.LevenbergMarquardtOptimizer(graph, values, params)
    if not watch:
        return optimizer.optimize(), optimizer.iterations()

    def image_axis(v):
        line, _ = image_line_from_rot3(p.K, v.atRot3(p.keys.line_key))
        return line_distances(line, p.corners)

    n_residuals = sum(graph.at(i).dim() for i in range(graph.size()))
    error, watched, quiet = optimizer.error(), image_axis(values), 0
    while optimizer.iterations() < params.getMaxIterations():
        optimizer.iterate()
        new_error, new_watched = optimizer.error(), image_axis(optimizer.values())
        rms = np.sqrt(2.0 * new_error / n_residuals)
        quiet = quiet + 1 if np.max(np.abs(new_watched - watched)) < WATCH_LINE_PX * rms else 0
        small_decrease = error - new_error <= 1e-8 * error
        error, watched = new_error, new_watched
        if quiet >= 2 or small_decrease or optimizer.lambda_() >= params.getlambdaUpperBound():
            break
    return optimizer.values(), optimizer.iterations()


def stage1(problems, repeats: int, watch: bool) -> list[tuple[gtsam.Rot3, np.ndarray, float]]:
    """GTSAM's LM per measurement: the per-track graph against the VP graph, from the same start (each timed as
    the best of ``repeats``). Returns the VP results (line, circles, pixel sigma) of each measurement."""
    details, results = [], []
    for p in problems:
        full_seconds, vp_seconds = [], []
        for _ in range(repeats):
            start = time.perf_counter()
            full, full_iterations = watched_lm(p.graph, p.values, p, watch)
            full_seconds.append(time.perf_counter() - start)
            start = time.perf_counter()
            factor, graph, values = p.vp()
            vp, vp_iterations = watched_lm(graph, values, p, watch)
            vp_seconds.append(time.perf_counter() - start)
        sigma = float(np.sqrt(2.0 * graph.error(vp) / max(p.n_points - 3 - 2 * len(p.tracks), 1)))
        results.append((vp.atRot3(p.keys.line_key), factor.circles(vp), sigma))
        difference = np.linalg.norm(full.atRot3(p.keys.line_key).localCoordinates(vp.atRot3(p.keys.line_key)))
        details.append((best(full_seconds), full_iterations, best(vp_seconds), vp_iterations,
                        factor.solves, factor.work, difference, p.graph.error(full), graph.error(vp)))
    how = "stops when the image axis stops moving, as estimate.py" if watch else "relative tolerance 1e-8 only"
    print(f"Stage 1 (GTSAM LM per measurement, {how}), best of {repeats}:")
    print("   k   per-track ms  its |   VP ms  its  solves  passes | line diff (rad)  error per-track / VP")
    for k, (fs, fi, vs, vi, solves, passes, diff, fe, ve) in enumerate(details):
        print(f"  {k:2d}   {fs * 1e3:10.1f} {fi:4d} | {vs * 1e3:7.1f} {vi:4d} {solves:7d} {passes:7.1f} | {diff:14.2e}"
              f"   {fe:.6f} / {ve:.6f}")
    print("  (passes: the circle solves' work in passes over all tracks)")
    full_total, vp_total = sum(d[0] for d in details), sum(d[2] for d in details)
    print(f"  total: per-track {full_total * 1e3:.1f} ms, VP {vp_total * 1e3:.1f} ms, "
          f"ratio {full_total / vp_total:.1f}x")
    return results


def joint(dataset, problems, stage1_results, pose: gtsam.Pose3, repeats: int) -> None:
    """The joint graph (the pose, one line per measurement tied to it, Huber per track, a weak prior on the pose),
    from the stage-1 lines and circles at a pose near the truth: per-track factors against one VP factor per
    measurement. LM as ``gtsam_rotid.estimate``'s joint (stops once the pose stops moving), then Marginals."""
    builder = RotIdGraph(dataset.arm, dataset.camera, robust=track_huber)
    pose_key = builder.pose_key
    anchor = gtsam.PriorFactorPose3(pose_key, pose, gtsam.noiseModel.Isotropic.Sigma(6, 1.0))
    full_graph, full_values = gtsam.NonlinearFactorGraph(), gtsam.Values()
    full_values.insert(pose_key, pose)
    parts = []
    for k, (p, (line, circles, sigma)) in enumerate(zip(problems, stage1_results, strict=True)):
        initial = dict(zip(p.keys.tracks, circles, strict=True))
        keys = builder.add_measurement(full_graph, full_values, k, dataset.measurements[k],
                                       track_sigmas=dict.fromkeys(p.keys.tracks, sigma), initial_circles=initial,
                                       initial_line=line, refine_circles=False,
                                       skip_tracks=set(range(len(dataset.measurements[k].tracks))) - set(initial))
        parts.append((p, keys, circles, sigma))
    full_graph.add(anchor)

    def vp_problem():
        graph, values = gtsam.NonlinearFactorGraph(), gtsam.Values()
        values.insert(pose_key, pose)
        factors = []
        for p, keys, circles, sigma in parts:
            factor = make_coaxial_line_factor(keys.line_key, p.tracks, p.K, circles, sigma_px=sigma, robust=track_huber)
            graph.add(factor.factor)
            graph.add(full_graph.at(keys.tie_factor))
            values.insert(keys.line_key, full_values.atRot3(keys.line_key))
            factors.append(factor)
        graph.add(anchor)
        return graph, values, factors

    def watched(graph, values):
        params = lm_params(100, 1e-8)
        optimizer = gtsam.LevenbergMarquardtOptimizer(graph, values, params)
        n_residuals = sum(graph.at(i).dim() for i in range(graph.size()))
        error, quiet, last = optimizer.error(), 0, pose
        while optimizer.iterations() < params.getMaxIterations():
            optimizer.iterate()
            new_error, new_pose = optimizer.error(), optimizer.values().atPose3(pose_key)
            rms = np.sqrt(2.0 * new_error / n_residuals)
            quiet = quiet + 1 if np.max(np.abs(last.localCoordinates(new_pose))) < WATCH_POSE * rms else 0
            small_decrease = error - new_error <= 1e-8 * error
            error, last = new_error, new_pose
            if quiet >= 2 or small_decrease or optimizer.lambda_() >= params.getlambdaUpperBound():
                break
        return optimizer.values(), optimizer.iterations()

    rows = {"per-track LM": [], "VP LM": [], "per-track Marginals": [], "VP Marginals": []}
    for _ in range(repeats):
        start = time.perf_counter()
        full, full_iterations = watched(full_graph, full_values)
        rows["per-track LM"].append(time.perf_counter() - start)
        start = time.perf_counter()
        graph, values, factors = vp_problem()
        vp, vp_iterations = watched(graph, values)
        rows["VP LM"].append(time.perf_counter() - start)
        start = time.perf_counter()
        cov_full = gtsam.Marginals(full_graph, full).marginalCovariance(pose_key)
        rows["per-track Marginals"].append(time.perf_counter() - start)
        start = time.perf_counter()
        cov_vp = gtsam.Marginals(graph, vp).marginalCovariance(pose_key)
        rows["VP Marginals"].append(time.perf_counter() - start)
    n_variables = full_values.size()
    print(f"Joint graph ({n_variables} variables per-track, {values.size()} VP), best of {repeats}:")
    for name, times in rows.items():
        print(f"  {name:<22s} {best(times) * 1e3:8.1f} ms")
    print(f"  iterations: per-track {full_iterations}, VP {vp_iterations}; circle solves "
          f"{sum(f.solves for f in factors)}, passes {sum(f.work for f in factors):.1f}")
    difference = full.atPose3(pose_key).localCoordinates(vp.atPose3(pose_key))
    sigma = np.sqrt(np.diag(cov_full))
    print(f"  pose difference / its sigma: {np.array2string(difference / sigma, precision=4)}; "
          f"covariance: max relative difference of the sigmas "
          f"{np.max(np.abs(np.sqrt(np.diag(cov_vp)) / sigma - 1.0)):.1e}")
    total = best(rows["per-track LM"]) + best(rows["per-track Marginals"])
    total_vp = best(rows["VP LM"]) + best(rows["VP Marginals"])
    print(f"  LM + Marginals: per-track {total * 1e3:.1f} ms, VP {total_vp * 1e3:.1f} ms, "
          f"ratio {total / total_vp:.1f}x")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--step", type=float, default=1e-5, help="line step (rad) of the single-pass timings")
    parser.add_argument("--start-deg", type=float, default=0.5, help="stage-1 start: pose rotation error (deg)")
    parser.add_argument("--start-mm", type=float, default=5.0, help="stage-1 start: pose translation error (mm)")
    parser.add_argument("--unwatched", action="store_true", help="also stage 1 with the relative tolerance only")
    parser.add_argument("--profile", action="store_true", help="cProfile the VP stage 1")
    args = parser.parse_args()
    dataset, truth = reference_scene(seed=args.seed)
    builder = RotIdGraph(dataset.arm, dataset.camera)
    at_truth = [Problem(builder, m, k, truth.arm_T_camera, True) for k, m in enumerate(dataset.measurements)]
    time_passes(at_truth, args.repeats, args.step)
    start = perturbed_pose(truth.arm_T_camera, args.start_deg, args.start_mm, np.random.default_rng(args.seed))
    problems = [Problem(builder, m, k, start, False) for k, m in enumerate(dataset.measurements)]
    results = stage1(problems, args.repeats, watch=True)
    if args.unwatched:
        stage1(problems, args.repeats, watch=False)
    near = perturbed_pose(truth.arm_T_camera, 0.05, 0.5, np.random.default_rng(args.seed + 1))
    joint(dataset, problems, results, near, args.repeats)
    if args.profile:
        profiler = cProfile.Profile()
        profiler.enable()
        for p in problems:
            _, graph, values = p.vp()
            watched_lm(graph, values, p, True)
        profiler.disable()
        pstats.Stats(profiler).sort_stats("tottime").print_stats(20)


if __name__ == "__main__":
    main()

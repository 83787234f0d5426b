"""Wall time of ``calibrate`` per method on the reference scene, and the cost per observation of our factors.

1. ``calibrate(dataset, method=...)`` on the reference scene (docs/design.md §6: six 60 s spins, ~56k pixel
   observations), best of ``--repeats`` runs after one warm-up (imports, first-call overheads); and ``joint``
   synced with the spinning joint's readings (the same poses, spins ramped over 2 s, readings at 100/s).
2. One linearisation of the joint graph (one pose-bound circle-point CustomFactor per track, vectorised over its
   pixels) against the same maths with one CustomFactor per pixel, timed on a subset of the tracks and given per
   observation; the per-pixel cost is extrapolated to the whole scene. The issue's target: the whole joint
   calibration should take less than one linearisation of the per-pixel graph.

3. Cost against the observations (``--scaling``, default 6, 12 and 48 arm poses of 20 s spins of the reference
   scene's simulator; wrist axes 20 degrees apart, 5 for more than 12 poses): the joint calibration's time per
   observation, and against one per-pixel linearisation of the same observations (the issue's target at 48 poses:
   at most 2x).

Run: ``python benchmarks/speed.py [--seed 0] [--repeats 3] [--pixel-subset 3000] [--scaling 6,12,48]``.
"""

from __future__ import annotations

import argparse
import os
import time

import gtsam

from gtsam_rotid import simulate
from gtsam_rotid.estimate import calibrate
from gtsam_rotid.factors import FKAxis, make_pose_circle_point_factor
from gtsam_rotid.graph import RotIdGraph

METHODS = ("joint", "weighted", "paper")


def best_time(fn, repeats: int) -> float:
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        fn()
        times.append(time.perf_counter() - start)
    return min(times)


def joint_graph_at_truth(dataset, truth):
    """The joint graph (one factor per track) at the true pose, with the circles fitted there."""
    builder = RotIdGraph(dataset.arm, dataset.camera)
    graph, values = gtsam.NonlinearFactorGraph(), gtsam.Values()
    values.insert(builder.pose_key, truth.arm_T_camera)
    made = [builder.add_measurement(graph, values, k, m) for k, m in enumerate(dataset)]
    return builder, graph, values, made


def per_pixel_graph(builder, dataset, values, made, max_pixels: int):
    """The same factors with one CustomFactor per pixel, on the first tracks up to ``max_pixels`` pixels."""
    graph = gtsam.NonlinearFactorGraph()
    noise = gtsam.noiseModel.Isotropic.Sigma(1, 1.0)
    count = 0
    for k, keys in enumerate(made):
        measurement = dataset[k]
        axis = dataset.arm.wrist_axis(measurement.joint_angles, measurement.spin_joint)
        fk_axis = FKAxis(axis.point, axis.direction)
        for j, circle_key in zip(keys.tracks, keys.circles, strict=True):
            ideal = dataset.camera.undistort_pixels(measurement.tracks[j].pixels)
            for pixel in ideal:
                graph.add(make_pose_circle_point_factor(noise, builder.pose_key, circle_key, pixel[None],
                                                        dataset.camera.K, fk_axis))
                count += 1
                if count >= max_pixels:
                    return graph, count
    return graph, count


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--pixel-subset", type=int, default=3000, help="pixels in the per-pixel comparison")
    parser.add_argument("--scaling", default="6,12,48",
                        help="arm poses of 20 s spins whose joint calibration is timed against one per-pixel "
                             "linearisation of the same observations ('' to skip)")
    args = parser.parse_args(argv)

    dataset, truth = simulate.reference_scene(seed=args.seed)
    n_points = sum(m.n_observations for m in dataset)
    print(f"reference scene (seed {args.seed}): {len(dataset)} measurements, "
          f"{sum(m.n_tracks for m in dataset)} tracks, {n_points} observations; {os.cpu_count()} CPUs")

    print(f"\ncalibrate (best of {args.repeats} after a warm-up)")
    calibrate(dataset, method="paper")  # warm-up
    seconds = {}
    for method in METHODS:
        seconds[method] = best_time(lambda method=method: calibrate(dataset, method=method), args.repeats)
        print(f"  {method:9} {seconds[method]:7.2f} s  ({1e6 * seconds[method] / n_points:.1f} us per observation)")
    # synced: the same poses, spins ramped over 2 s with the joint's readings at 100/s (every frame's angle under a
    # prior, the clocks' offset a variable)
    synced, _ = simulate.reference_scene(seed=args.seed, spin_ramp=2.0, encoder_rate=100.0, encoder_sigma_deg=0.02,
                                         encoder_time_offset=0.037)
    seconds["synced"] = best_time(lambda: calibrate(synced), args.repeats)
    n_synced = sum(m.n_observations for m in synced)
    print(f"  {'synced':9} {seconds['synced']:7.2f} s  ({1e6 * seconds['synced'] / n_synced:.1f} us per observation; "
          f"joint, ramped spins with readings, {n_synced} observations)")

    builder, graph, values, made = joint_graph_at_truth(dataset, truth)
    n_graph = sum(graph.at(i).dim() for i in range(graph.size()))
    graph.linearize(values)  # warm the closest-phase caches, as inside LM
    t_track = best_time(lambda: graph.linearize(values), args.repeats) / n_graph
    pixel_graph, n_pixel = per_pixel_graph(builder, dataset, values, made, args.pixel_subset)
    pixel_graph.linearize(values)
    t_pixel = best_time(lambda: pixel_graph.linearize(values), args.repeats) / n_pixel
    print(f"\none linearisation of the joint graph ({graph.size()} factors, {n_graph} residuals)")
    print(f"  one CustomFactor per track: {1e6 * t_track:7.2f} us per observation, "
          f"{1e3 * t_track * n_points:7.1f} ms for the scene")
    print(f"  one CustomFactor per pixel: {1e6 * t_pixel:7.2f} us per observation, "
          f"{1e3 * t_pixel * n_points:7.1f} ms for the scene (measured on {n_pixel} pixels)")
    print(f"  per-pixel / per-track: {t_pixel / t_track:.0f}x")
    print(f"  joint calibrate / one per-pixel linearisation: {seconds['joint'] / (t_pixel * n_points):.2f} "
          "(target < 1)")
    if args.scaling:
        print("\ncost against the observations: 20 s spins, joint calibrate (best of 3) / one per-pixel linearisation "
              f"of the same observations at {1e6 * t_pixel:.2f} us each (target at 48 poses: <= 2)")
        first = None
        for n in (int(v) for v in args.scaling.split(",")):
            # (48 poses with the wrist in view are not found 20 degrees apart: 5 degrees apart there)
            data = simulate.reference_scene(seed=args.seed, duration=20.0, n_measurements=n,
                                            min_axis_separation_deg=20.0 if n <= 12 else 5.0)[0]
            points = sum(m.n_observations for m in data)
            t = best_time(lambda data=data: calibrate(data), 3)
            first = first or (t, points)
            print(f"  {n:3} poses, {points:7} observations: {t:6.2f} s, {1e6 * t / points:5.1f} us per observation "
                  f"({t / first[0]:.1f}x the time of {first[1] / 1000:.0f}k for {points / first[1]:.1f}x the "
                  f"observations); / one per-pixel linearisation: {t / (t_pixel * points):.2f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

"""Parallel wrist axes: every measurement's axis has the same direction a (the wrist at different positions).

Moving the camera along a moves every axis along itself: the image lines do not change, so the camera's position
along a is not determined (the other five degrees of freedom are). This scenario puts six wrist axes parallel by
inverse kinematics, then tilts them apart by a growing angle, and shows what the report says and how the
reported 1σ along a shrinks (as 1 / angle at small angles, until other directions limit it), next to the
Cramér-Rao bound of each scene.

Run: ``python scenarios/parallel_axes.py [--quick] [--out DIR] [--seed N]``.
"""

from __future__ import annotations

import sys

import numpy as np
from _common import (
    CHI2_6_999,
    Growth,
    Verdict,
    growth_cells,
    growth_figure,
    header,
    parse_args,
    perpendicular,
    rotate_towards,
    save_figure,
    solve_axis,
    sweep_scene,
    within_3_sigma,
)

from gtsam_rotid import Arm, simulate
from gtsam_rotid.plots import plot_pose_3d
from gtsam_rotid.simulate import SceneConfig

NOISE_VAR = 1.5


def parallel_poses(arm, config, ref, rng):
    """(direction, positions, start poses): the reference axis direction reachable at most reference wrist
    positions (every pose checked by the simulator)."""
    best = None
    for m in ref.measurements:
        a = m.axis_direction
        found = [(r.axis_point, q) for r in ref.measurements
                 if (q := solve_axis(arm, config, r.axis_point, a, [r.joint_angles, m.joint_angles], rng, 5))
                 is not None]
        if best is None or len(found) > len(best[1]):
            best = (a, found)
    return best


def tilted_poses(arm, config, a, found, perps, angle_deg, rng):
    """Poses with each axis at ``found``'s positions turned by ``angle_deg`` from ``a`` (towards ``perps``)."""
    poses = []
    for (point, start), perp in zip(found, perps, strict=True):
        direction = rotate_towards(a, perp, np.radians(angle_deg))
        q = solve_axis(arm, config, point, direction, [start], rng, 10)
        if q is None:
            return None
        poses.append(q)
    return poses


def main(argv=None) -> int:
    args = parse_args("parallel_axes", __doc__.split("\n\n")[0])
    quick = args.quick
    duration = 10.0 if quick else 60.0
    tilts = (0.0, 0.3) if quick else (0.0, 0.03, 0.1, 0.3, 1.0, 3.0, 10.0)
    header(args, "parallel wrist axes, then tilted apart",
           [f"Kinova Jaco2 reference camera, {duration:g} s spins, sigma^2 = {NOISE_VAR} px^2, method joint; each "
            f"axis tilted by {', '.join(f'{t:g}' for t in tilts)} deg from the common direction"])
    verdict = Verdict(args)
    arm = Arm.from_robot("kinova")
    config = SceneConfig(duration=duration, noise_var=NOISE_VAR)
    rng = np.random.default_rng(args.seed)
    _, ref = simulate.reference_scene(seed=args.seed, duration=1.0, min_track_length=2)
    a, found = parallel_poses(arm, config, ref, rng)
    if len(found) < 4:
        verdict.check(False, f"found at least 4 wrist positions with a common axis direction ({len(found)})")
        return verdict.finish("parallel axes: not enough poses")
    perps = [perpendicular(a, rng) for _ in found]
    print(f"common direction a = {np.round(a, 3).tolist()} (arm frame), {len(found)} wrist positions")

    rows, figures = [], []
    for tilt in tilts:
        poses = tilted_poses(arm, config, a, found, perps, tilt, rng)
        if poses is None:
            print(f"\ntilt {tilt:g} deg: no reachable poses, skipped")
            continue
        scene = sweep_scene(config, poses, a, seed=args.seed + 1, arm=arm, noise_var=NOISE_VAR)
        dataset, truth, geometry = scene.dataset, scene.truth, scene.geometry
        result, report = scene.result, scene.report
        print(f"\ntilt {tilt:g} deg (largest angle between two axes {geometry.spread_deg:.1f} deg): "
              f"{scene.seconds:.1f} s")
        if scene.failure:
            print(f"  calibrate FAILED: {scene.failure}")
            rows.append((tilt, geometry.spread_deg, None, scene.crlb, None, None, None))
            verdict.check(False, f"tilt {tilt:g} deg: calibrate returns an estimate")
            continue
        scene.print_along("camera position along a")
        sigma, crlb_a, along = scene.sigma, scene.crlb, scene.along
        honest = None
        if result.covariance_usable:
            honest, d2 = within_3_sigma(result, truth.arm_T_camera)
            print(f"  error across the other directions: e^T Sigma^-1 e = {d2:.2f}")
        rows.append((tilt, geometry.spread_deg, sigma, crlb_a, along, result.covariance_usable, honest))
        if tilt == 0.0:
            obs = result.observability
            verdict.check(not result.covariance_usable and any("parallel" in w for w in report.observability),
                          "parallel: covariance flagged unusable and the report says the axes are parallel")
            if obs.unobservable_directions:
                d = obs.unobservable_directions[0]
                d_arm = result.arm_T_camera.rotation().matrix() @ d[3:]
                angle = float(np.degrees(np.arccos(min(1.0, abs(d_arm @ a) / np.linalg.norm(d_arm)))))
                verdict.check(len(obs.unobservable_directions) == 1 and angle < 2.0,
                              f"parallel: the one undetermined direction is the position along a ({angle:.2f} deg "
                              f"from it, {len(obs.unobservable_directions)} direction(s))")
            figures.append(save_figure(plot_pose_3d(result, dataset), args.out, "parallel_pose_3d.png"))
        elif result.covariance_usable:
            verdict.check(honest, f"tilt {tilt:g} deg: error inside the reported 99.9 % region "
                          f"(e^T Sigma^-1 e <= {CHI2_6_999:.1f})")
            if np.isfinite(crlb_a):
                verdict.check(0.7 < sigma / crlb_a < 1.4, f"tilt {tilt:g} deg: reported 1 sigma along a within "
                              f"0.7-1.4x the Cramér-Rao bound ({sigma / crlb_a:.2f}x)")

    print("\n  tilt deg  spread deg  reported 1 sigma along a (mm)  Cramér-Rao (mm)  error along a (mm)")
    for tilt, spread, sigma, crlb_a, along, _, _ in rows:
        s, c, e = growth_cells(sigma, crlb_a, along)
        print(f"  {tilt:8g}  {spread:10.1f}  {s:>29}  {c:>15}  {e:>17}")
    growth = Growth.of(r[:1] + r[2:5] for r in rows)
    if growth is not None:
        t, s = growth.x, growth.sigma
        growth.check(verdict, (-1.3, -0.7),
                     f"the reported 1 sigma along a shrinks as the axes tilt apart ({s[0]:.3g} mm at {t[0]:g} deg, "
                     f"{s[-1]:.3g} mm at {t[-1]:g} deg)",
                     f"at small tilts it grows as 1 / tilt (log-log slope {growth.slope:.2f} between {t[0]:g} and "
                     f"{t[1]:g} deg; larger tilts saturate where other directions limit it)")
        fig = growth_figure(growth, along="along a", variable="tilt",
                            x_label="tilt of each axis from the common direction (deg)",
                            y_label="camera position along a (mm)",
                            title="parallel wrist axes tilted apart: what the covariance says (tilt 0: not determined)")
        figures.append(save_figure(fig, args.out, "sigma_vs_tilt.png"))
    summary = "parallel axes: position along the common direction undetermined and named; " + ", ".join(
        f"{r[0]:g} deg -> {r[2]:.3g} mm" for r in rows if r[2] is not None and np.isfinite(r[2]))
    return verdict.finish(summary, figures)


if __name__ == "__main__":
    sys.exit(main())

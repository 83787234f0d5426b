"""The paper's stated minimum: three measurements, one of them off the common point of the other two.

"To avoid this condition [a single crossing], a minimum of three measurements are required, with one measurement
having a different position from the other two." Each measurement's wrist axis gives two equations (its image
line), so three give the six of ``arm_T_camera``: the two-stage methods have no redundancy left, the joint one
still has every pixel. Those six equations have several exact solutions (here one 130 deg and 1.7 m from the
truth); the estimator fits the circles from each and keeps the one the pixels prefer, listing the others with how
much worse they fit (``result.alternatives``), or reports the calibration AMBIGUOUS when the pixels cannot tell
them apart. This scenario calibrates (a) two axes through a point P plus one that misses it: every
degree of freedom determined, error inside the reported region; (b) three axes through P: the report names the
undetermined direction; (c) two measurements: refused with a clear message.

Run: ``python scenarios/minimal_three.py [--quick] [--out DIR] [--seed N]``.
"""

from __future__ import annotations

import sys

import numpy as np
from _common import (
    CHI2_6_999,
    Verdict,
    calibrate_and_print,
    error_lines,
    header,
    parse_args,
    position_error_mm,
    print_observability,
    rotation_error_deg,
    run_calibration,
    save_figure,
    subset,
    within_3_sigma,
)
from single_crossing import extra_pose

from gtsam_rotid import simulate
from gtsam_rotid.plots import plot_pose_3d
from gtsam_rotid.report import make_report
from gtsam_rotid.simulate import SceneConfig

NOISE_VAR = 1.5


def main(argv=None) -> int:
    args = parse_args("minimal_three", __doc__.split("\n\n")[0])
    duration = 10.0 if args.quick else 60.0
    header(args, "three measurements, one off the common point of the other two (the paper's minimum)",
           [f"Kinova Jaco2 reference camera, spins of {duration:g} s, sigma^2 = {NOISE_VAR} px^2"])
    verdict = Verdict(args)
    _, crossing_truth = simulate.single_crossing_scene(seed=args.seed, duration=1.0, min_track_length=2)
    P = np.array(crossing_truth.config["crossing_point"])
    poses = [m.joint_angles for m in crossing_truth.measurements[:3]]
    directions = [m.axis_direction for m in crossing_truth.measurements[:3]]
    config = SceneConfig(duration=duration, noise_var=NOISE_VAR)
    found = extra_pose(args.seed, P, directions, config)
    if found is None:
        verdict.check(False, "found an arm pose whose wrist axis misses P")
        return verdict.finish("minimal three: no extra pose found")
    q_extra, miss, tilt = found
    config = config.with_(joint_angles=tuple(tuple(q) for q in [*poses, q_extra]), n_measurements=4)
    dataset, truth = simulate.simulate(config, seed=args.seed + 1)
    minimal = subset(dataset, [0, 1, 3])
    through_p = subset(dataset, [0, 1, 2])
    two = subset(dataset, [0, 3])
    print(f"measurements 0, 1, 2: wrist axes through P = {np.round(1000 * P, 1).tolist()} mm; measurement 3 misses "
          f"P by {1000 * miss:.0f} mm, tilted {tilt:.0f} deg from the others")
    figures = []

    print("\n(a) measurements 0, 1 (through P) and 3 (off P): the minimum")
    results = {}
    for method in ("joint", "weighted") if args.quick else ("joint", "weighted", "paper"):
        result = calibrate_and_print(verdict, minimal, truth.arm_T_camera, method, f"(a) {method}", indent="    ")
        if result is None:
            continue
        results[method] = result
        print("    report: " + make_report(result, minimal).chi2.sentence())
        print("    residual RMS per measurement (px): "
              + ", ".join(f"{m.residual_rms_px:.3f}" for m in result.measurements))
    joint = results.get("joint")
    if joint is not None:
        print_observability(joint, minimal, indent="    ")
        for a in joint.alternatives:
            print(f"    other solution examined: {rotation_error_deg(a.arm_T_camera, truth.arm_T_camera):.1f} deg and "
                  f"{np.linalg.norm(position_error_mm(a.arm_T_camera, truth.arm_T_camera)):.0f} mm from the truth, "
                  f"chi-square {a.delta_chi2:.1f} worse than the estimate")
        verdict.check(joint.alternatives and not joint.ambiguous,
                      f"(a) joint: the other exact solutions of the image axes were fitted to the circles and "
                      f"rejected ({len(joint.alternatives)} examined, chi-square at least "
                      f"{min((a.delta_chi2 for a in joint.alternatives), default=float('nan')):.1f} worse)")
        r = rotation_error_deg(joint.arm_T_camera, truth.arm_T_camera)
        verdict.check(r < 5.0, f"(a) joint: the right solution is kept (rotation error {r:.3f} deg < 5 deg)")
        verdict.check(joint.covariance_usable, "(a) joint: all six degrees of freedom determined by three measurements")
        honest, d2 = within_3_sigma(joint, truth.arm_T_camera)
        # with three 10 s spins (--quick) the joint cost has local minima ~30 mm apart and the linearised
        # covariance is optimistic (README, Known limits): judged at full size only
        verdict.check(honest, f"(a) joint: error inside the reported 99.9 % region (e^T Sigma^-1 e = {d2:.2f} <= "
                      f"{CHI2_6_999:.1f})", robust_when_quick=False)
        figures.append(save_figure(plot_pose_3d(joint, minimal), args.out, "minimal_pose_3d.png"))
    weighted = results.get("weighted")
    if weighted is not None:
        # with 10 s spins (--quick) one measurement's ellipses are thin against the noise and its free-phase line
        # has two minima (leaving out any one of four of its 13 tracks moves it 18 sigma): the jackknife then leaves
        # the pose undetermined, honestly; with 60 s spins it is determined (error chi-square 5.5): judged at full
        # size only
        verdict.check(weighted.covariance_usable and make_report(weighted, minimal).chi2.dof == 0,
                      "(a) weighted: determined, with no redundancy (0 residual dof: the report says so)",
                      robust_when_quick=False)

    print("\n(b) measurements 0, 1, 2: three axes through P")
    degenerate, seconds, failure = run_calibration(through_p, "joint")
    print(f"  joint: {seconds:.1f} s")
    if failure:
        print(f"    calibrate FAILED: {failure}")
        verdict.check(False, "(b) calibrate returns an estimate that names the undetermined direction")
    else:
        for line in error_lines(degenerate, truth.arm_T_camera, indent="    "):
            print(line)
        words = print_observability(degenerate, through_p, indent="    ")
        verdict.check(not degenerate.covariance_usable and any("DEGENERATE" in w for w in words),
                      "(b) three axes through one point: the covariance is flagged unusable and the report says "
                      "DEGENERATE")
        r = rotation_error_deg(degenerate.arm_T_camera, truth.arm_T_camera)
        verdict.check(r < 5.0, f"(b) the orientation is still recovered (rotation error {r:.3f} deg < 5 deg)")
        figures.append(save_figure(plot_pose_3d(degenerate, through_p), args.out, "through_p_pose_3d.png"))

    print("\n(c) measurements 0 and 3 only")
    refused, seconds, failure = run_calibration(two, "joint")
    print(f"  calibrate: {failure or 'returned an estimate'}")
    verdict.check(refused is None and failure is not None and "at least 3" in failure,
                  "(c) two measurements: refused with a message that asks for at least 3")

    summary = "minimal three"
    if joint is not None:
        summary += (f": 2 axes through P + 1 off it, joint error "
                    f"{np.linalg.norm(position_error_mm(joint.arm_T_camera, truth.arm_T_camera)):.2f} mm, "
                    f"{rotation_error_deg(joint.arm_T_camera, truth.arm_T_camera):.3f} deg, reported position 1 sigma "
                    f"{', '.join(f'{v:.2f}' for v in joint.sigma_mm_arm)} mm")
    return verdict.finish(summary, figures)


if __name__ == "__main__":
    sys.exit(main())

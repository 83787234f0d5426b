"""Refinement of what the calibration assumes (issue 17): joint offsets, against offsets the estimator never sees.

Per trial (a new scene per seed: poses, features, noise) the simulator records wrist spins with exact kinematics and
the readings of every joint between the first and the spinning one are then shifted by ``--offset-deg`` (random sign
per joint and trial; the true angle is the reading plus the offset). The first joint's offset turns the whole arm
as ``arm_T_camera`` does, so no camera data can determine it: it is not perturbed. Each trial is calibrated twice:

- with the kinematics as given (the default): it must be flagged (not usable) or refused on every trial;
- with ``CalibrationOptions(joint_offsets=True)`` (prior 1 sigma ``--prior-deg``): the pose error and the offsets'
  error against the truth, under the reported covariances.

Printed per robot: how many exact-model results were flagged or refused; how many refined results are usable; the
NEES of the pose (6 dof) and of the offsets (one dof per offset), each with its 95 % interval over the usable
trials; the RMSE per axis of the refined pose over two Cramér–Rao bounds at the same poses (the rigid spin's,
averaged over the trials): that of the exact-model problem (no offsets to find: the target is 1.2x) and that of the
problem with the offsets free under their prior (what refining costs at these poses); the offsets' RMSE and bound;
time per calibration. ``--two-spins``: at every pose the joint before the wrist spins too (two measurements per
pose, ``Measurement.spin_joint``). ``--focal-percent P --cx-px C``: the camera file given to both calibrations has
its focal lengths P % and its principal point C px off the simulator's camera (``--offset-deg 0``: no offsets), and
the refined calibration refines the intrinsics too (``refine_intrinsics=True``, with the offsets if there are
some): their NEES (4 dof) and RMSE against their bound are printed as well, the bounds then with the intrinsics free
under their prior.

Run: ``python benchmarks/refinement.py [--robots kinova,ur5] [--trials 30] [--duration 12] [--two-spins]
[--focal-percent 3 --cx-px 10] [--poses 12]``; ``--quick`` (one robot, 3 trials) checks that it runs. ``--poses N``
(more than six): the targets' reference is the exact-model bound of the first six poses' wrist spins.
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from dataclasses import replace
from pathlib import Path

import gtsam
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

AXES = ("rx", "ry", "rz", "tx", "ty", "tz")
#: Arm poses of the usual recording: the targets' reference is the exact-model bound of their wrist spins.
USUAL_POSES = 6
UNITS = np.array([math.degrees(1.0)] * 3 + [1000.0] * 3)
NOISE_VAR = 1.5


def _scene(robot: str, seed: int, duration: float, two_spins: bool = False, poses: int = 6):
    from ambient import PLACEMENTS

    from gtsam_rotid.arm import Arm
    from gtsam_rotid.simulate import SceneConfig, simulate

    arm = Arm.from_robot(robot)
    spins = tuple(arm.joint_names[arm.wrist_index - 1:arm.wrist_index + 1]) if two_spins else ()
    return simulate(SceneConfig(robot=robot, duration=duration, noise_var=NOISE_VAR, spin_joints=spins,
                                n_measurements=poses, **PLACEMENTS[robot]), seed=seed, arm=arm)


def _offset_bound(dataset, truth, readings, joints, offsets, prior_deg: float, intrinsics_sigma=None
                  ) -> tuple[np.ndarray, np.ndarray | None, np.ndarray | None]:
    """(pose bound 6x6, offsets bound, intrinsics bound (4x4: fx, fy, cx, cy)) of the rigid-spin problem with the
    offsets (if ``joints``) and the intrinsics (if ``intrinsics_sigma``, the prior) free under their priors, at the
    truth: the estimators' graph on noise-free pixels of the same tracks, with the readings' FK plus the offsets
    (``benchmarks/accuracy.py``'s ``crlb_rigid`` with those variables)."""
    from accuracy import add_noise_free

    from gtsam_rotid.calibration.joint import CAL3_S2_ORDER, intrinsics_prior_sigmas
    from gtsam_rotid.calibration.options import INTRINSICS
    from gtsam_rotid.graph import RotIdGraph
    from gtsam_rotid.uncertainty import joint_marginal_covariance

    pose = truth.arm_T_camera
    names = [dataset.arm.joint_names[j] for j in joints]
    key = gtsam.symbol("k", 0)
    builder = RotIdGraph(dataset.arm, dataset.camera, track_sigma_px=math.sqrt(NOISE_VAR), model="projected",
                         spin_model="rigid", joint_offsets=names or None,
                         intrinsics_key=None if intrinsics_sigma is None else key)
    graph, values = gtsam.NonlinearFactorGraph(), gtsam.Values()
    values.insert(builder.pose_key, pose)
    keys, dims = [builder.pose_key], [6]
    if names:
        builder.add_offsets_prior(graph, values, prior_deg, initial_deg=np.degrees(offsets))
        keys.append(builder.offsets_key)
        dims.append(len(joints))
    if intrinsics_sigma is not None:
        builder.add_intrinsics_prior(graph, values, intrinsics_prior_sigmas(dataset.camera.K, INTRINSICS,
                                                                            intrinsics_sigma))
        keys.append(key)
        dims.append(5)
    add_noise_free(builder, graph, values, dataset.camera, list(readings), truth)
    both = joint_marginal_covariance(graph, values, keys, sum(dims))
    offsets_bound = both[6:6 + len(joints), 6:6 + len(joints)] if names else None
    intrinsics_bound = None
    if intrinsics_sigma is not None:
        chosen = 6 + len(joints) + np.array([CAL3_S2_ORDER.index(n) for n in INTRINSICS])  # (the skew left out)
        intrinsics_bound = both[np.ix_(chosen, chosen)]
    return both[:6, :6], offsets_bound, intrinsics_bound


def offset_readings(dataset, camera, offset_deg: float, seed: int):
    """(readings, joints, offsets): ``dataset``'s measurements with every joint between the first and the spinning
    one read ``offset_deg`` off its zero (random signs, drawn from ``seed``), with ``camera`` as the camera file; the
    joints' indices and their offsets (rad)."""
    from gtsam_rotid.dataset import Dataset, Measurement

    arm = dataset.arm
    joints = arm.offset_joints(True)
    rng = np.random.default_rng(10_000 + seed)
    offsets = np.radians(offset_deg) * rng.choice([-1.0, 1.0], size=len(joints))
    shift = np.zeros(arm.dof)
    shift[joints] = offsets
    readings = Dataset(arm, camera, [Measurement(dataset.joint_angles(k) - shift, m.tracks, spin_joint=m.spin_joint)
                                     for k, m in enumerate(dataset)])
    return readings, joints, offsets


def trial(robot: str, seed: int, duration: float, offset_deg: float, prior_deg: float, two_spins: bool = False,
          focal_percent: float = 0.0, cx_px: float = 0.0, poses: int = 6) -> dict:
    from accuracy import crlb_rigid

    from gtsam_rotid.calibration import CalibrationOptions
    from gtsam_rotid.dataset import Dataset
    from gtsam_rotid.errors import RotIdError
    from gtsam_rotid.estimate import calibrate

    dataset, truth = _scene(robot, seed, duration, two_spins, poses)
    arm = dataset.arm
    intrinsics = bool(focal_percent or cx_px)
    given = dataset.camera.with_intrinsics_changed(1.0 + focal_percent / 100.0, cx_px) if intrinsics else dataset.camera
    readings, joints, offsets = offset_readings(dataset, given, offset_deg, seed)
    if offset_deg == 0.0:
        joints, offsets = [], np.zeros(0)
    out = {"seed": seed, "bound_exact": crlb_rigid(dataset, truth, NOISE_VAR)}
    if two_spins or poses > USUAL_POSES:  # the exact-model bound of the usual recording: the wrist spins of six poses
        # (one wrist spin per pose, in pose order: the first six poses')
        wrist = [k for k, m in enumerate(dataset) if m.spin_joint in (None, arm.wrist_joint)][:USUAL_POSES]
        out["bound_wrist"] = crlb_rigid(Dataset(arm, dataset.camera, [dataset[k] for k in wrist]),
                                        replace(truth, measurements=[truth.measurements[k] for k in wrist]),
                                        NOISE_VAR)
    options = CalibrationOptions(joint_offsets=True if joints else None, joint_offset_sigma_deg=prior_deg,
                                 refine_intrinsics=intrinsics)
    out["bound_offsets"], out["bound_offsets_joint"], out["bound_intrinsics"] = _offset_bound(
        dataset, truth, Dataset(arm, dataset.camera, list(readings)), joints, offsets, prior_deg,
        options.intrinsics_sigma if intrinsics else None)
    start = time.perf_counter()
    try:
        exact = calibrate(readings)
        e = exact.error_to(truth.arm_T_camera)
        out["exact"] = {"usable": exact.covariance_usable, "untrusted": sorted(exact.untrusted),
                        "chi2": float(e @ np.linalg.solve(exact.covariance, e))}
    except RotIdError as error:
        out["exact"] = {"refused": str(error)[:120]}
    start = time.perf_counter()
    try:
        result = calibrate(readings, options=options)
    except RotIdError as error:
        out["refined"] = {"refused": str(error)[:200]}
        return out
    e = result.error_to(truth.arm_T_camera)
    out["refined"] = {"usable": result.covariance_usable, "untrusted": sorted(result.untrusted), "error": e,
                      "chi2": float(e @ np.linalg.solve(result.covariance, e)),
                      "seconds": time.perf_counter() - start, "n_offsets": len(joints)}
    if joints:
        miss = np.array(list(result.joint_offsets.values())) - offsets
        out["refined"].update(offsets_miss=miss,
                              offsets_chi2=float(miss @ np.linalg.solve(result.joint_offsets_covariance, miss)))
    if intrinsics:
        true = dataset.camera.intrinsics
        miss = np.array([result.intrinsics[n] - true[n] for n in result.refined_intrinsics])
        out["refined"].update(intrinsics_miss=miss,
                              intrinsics_chi2=float(miss @ np.linalg.solve(result.intrinsics_covariance, miss)))
    return out


def _interval(n: int, dof: int) -> tuple[float, float]:
    from gtsam_rotid.uncertainty import chi2_mean_interval

    return chi2_mean_interval(dof, n)


def report(robot: str, results: list[dict]) -> None:
    n = len(results)
    flagged = sum(1 for r in results if "refused" in r["exact"] or not r["exact"]["usable"])
    exact_refused = sum(1 for r in results if "refused" in r["exact"])
    refined = [r["refined"] for r in results if "refused" not in r["refined"]]
    usable = [r for r in refined if r["usable"]]
    print(f"\n{robot}: {n} trials; offsets on {results[0]['refined'].get('n_offsets', '?')} joints"
          + ("; intrinsics refined" if results[0].get("bound_intrinsics") is not None else ""))
    print(f"  kinematics as given: flagged {flagged - exact_refused} + refused {exact_refused} of {n} "
          f"(target: all)")
    for r in results:
        if "refused" not in r["exact"] and r["exact"]["usable"]:
            print(f"    seed {r['seed']}: called usable, chi2 of its error {r['exact']['chi2']:.1f}")
    print(f"  offsets refined: {len(usable)} usable, {len(refined) - len(usable)} flagged "
          f"({', '.join(sorted({k for r in refined if not r['usable'] for k in r['untrusted']})) or '-'}), "
          f"{n - len(refined)} refused")
    if not usable:
        return
    nees = float(np.mean([r["chi2"] for r in usable]))
    lo, hi = _interval(len(usable), 6)
    line = f"  NEES pose {nees:.2f} (95 % interval [{lo:.2f}, {hi:.2f}])"
    for what, label in (("offsets", "offsets"), ("intrinsics", "intrinsics")):
        if f"{what}_miss" not in usable[0]:
            continue
        dof = usable[0][f"{what}_miss"].size
        lo_o, hi_o = _interval(len(usable), dof)
        line += (f"; {label} {np.mean([r[f'{what}_chi2'] for r in usable]):.2f} ({dof} dof, [{lo_o:.2f}, "
                 f"{hi_o:.2f}])")
    print(line + f"; worst pose chi2 {max(r['chi2'] for r in usable):.1f}")
    errors = np.array([r["error"] for r in usable]) * UNITS
    rmse = np.sqrt(np.mean(errors**2, axis=0))
    exact_bound = np.sqrt(np.diag(np.mean([r["bound_exact"] for r in results], axis=0))) * UNITS
    free_bound = np.sqrt(np.diag(np.mean([r["bound_offsets"] for r in results], axis=0))) * UNITS
    print(f"  {'':28}" + "".join(f"{a:>9}" for a in AXES) + "   (deg, mm camera frame)")
    print(f"  {'RMSE, offsets refined':28}" + "".join(f"{v:9.4f}" for v in rmse))
    print(f"  {'bound, exact model':28}" + "".join(f"{v:9.4f}" for v in exact_bound))
    print(f"  {'RMSE / exact-model bound':28}" + "".join(f"{v:9.2f}" for v in rmse / exact_bound)
          + "   (target <= 1.2, with more poses)")
    if "bound_wrist" in results[0]:  # the target's reference: the exact model at the same poses, wrist spins only
        wrist_bound = np.sqrt(np.diag(np.mean([r["bound_wrist"] for r in results], axis=0))) * UNITS
        print(f"  {'bound, exact, 6 wrist spins':28}" + "".join(f"{v:9.4f}" for v in wrist_bound))
        print(f"  {'RMSE / that bound':28}" + "".join(f"{v:9.2f}" for v in rmse / wrist_bound)
              + "   (target <= 1.2, with the second spins or more poses)")
    print(f"  {'bound, refined ones free':28}" + "".join(f"{v:9.4f}" for v in free_bound))
    print(f"  {'RMSE / that bound':28}" + "".join(f"{v:9.2f}" for v in rmse / free_bound))
    if "offsets_miss" in usable[0]:
        miss = np.degrees(np.array([r["offsets_miss"] for r in usable]))
        bound_o = np.degrees(np.sqrt(np.diag(np.mean([r["bound_offsets_joint"] for r in results], axis=0))))
        print(f"  offsets RMSE (deg): {' '.join(f'{v:.3f}' for v in np.sqrt(np.mean(miss**2, axis=0)))}; bound "
              f"{' '.join(f'{v:.3f}' for v in bound_o)}")
    if "intrinsics_miss" in usable[0]:
        miss = np.array([r["intrinsics_miss"] for r in usable])
        bound_i = np.sqrt(np.diag(np.mean([r["bound_intrinsics"] for r in results], axis=0)))
        print(f"  intrinsics RMSE (px, fx fy cx cy): {' '.join(f'{v:.2f}' for v in np.sqrt(np.mean(miss**2, axis=0)))}"
              f"; bound {' '.join(f'{v:.2f}' for v in bound_i)}")
    print(f"  seconds per refined calibration: median {np.median([r['seconds'] for r in usable]):.1f}")


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--robots", default="kinova,ur5")
    parser.add_argument("--trials", type=int, default=30)
    parser.add_argument("--duration", type=float, default=12.0, help="spin length, s (default 12)")
    parser.add_argument("--offset-deg", type=float, default=0.5)
    parser.add_argument("--prior-deg", type=float, default=1.0)
    parser.add_argument("--two-spins", action="store_true",
                        help="at every pose the joint before the wrist spins too (two measurements per pose)")
    parser.add_argument("--focal-percent", type=float, default=0.0,
                        help="the camera file's focal lengths off by this %% (then the intrinsics are refined too)")
    parser.add_argument("--cx-px", type=float, default=0.0, help="the camera file's cx off by this (px)")
    parser.add_argument("--poses", type=int, default=USUAL_POSES,
                        help="arm poses per trial (more than 6: the reference bound is that of the first six)")
    parser.add_argument("--quick", action="store_true", help="one robot, 3 trials")
    args = parser.parse_args(argv)
    robots = args.robots.split(",")
    if args.quick:
        robots, args.trials = robots[:1], 3
    print(f"joint offsets of {args.offset_deg} deg (random signs) on every joint between the first and the spinning "
          f"one; {args.trials} trials per robot, {args.duration:g} s spins, pixel noise {NOISE_VAR} px^2, prior "
          f"{args.prior_deg} deg; {args.poses} arm poses"
          + ("; the joint before the wrist spins too at every pose" if args.two_spins else "")
          + (f"; camera file focal {args.focal_percent:+g} %, cx {args.cx_px:+g} px (intrinsics refined)"
             if args.focal_percent or args.cx_px else ""))
    for robot in robots:
        start = time.perf_counter()
        results = [trial(robot, seed, args.duration, args.offset_deg, args.prior_deg, args.two_spins,
                         args.focal_percent, args.cx_px, args.poses) for seed in range(args.trials)]
        report(robot, results)
        print(f"  ({time.perf_counter() - start:.0f} s)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

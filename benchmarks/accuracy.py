"""Monte Carlo accuracy of the estimators on the reference scene, against the Cramér–Rao bound (issue 3).

Each trial simulates the reference scene (docs/design.md §6: Kinova Jaco2, six 60 s spins, sigma^2 = 1.5 px^2) with the
arm poses of ``--scene-seed`` held fixed and its own seed for the features and the pixel noise, calibrates it with
every method, and records the error against the truth (which the estimators never see) and the reported
covariance. The Cramér–Rao bound of the trial is the inverse of the pose information (every circle marginalised)
of the joint graph evaluated at the true pose and true circles with the true noise (:func:`crlb`, free phase per
observation; with the rigid spin, the default of ``joint``, also :func:`crlb_rigid`, which ``joint`` is compared
with); the table
compares the RMSE per axis with the bound averaged over the trials, and also gives the RMS of each error over its
own trial's bound (the fairer figure when the trials' bounds differ, e.g. with ``--scene-seed -1``).

Printed per method:
- RMSE per axis (rotation in degrees about the camera axes, translation in mm in the camera frame, i.e. the Pose3
  tangent in which the covariance is reported) and its ratio to the bound (target <= 1.1 for joint and weighted);
- mean error per axis in units of the RMSE (a bias shows as |mean| >> 1/sqrt(trials));
- NEES = mean of e^T Sigma^-1 e with the reported Sigma (6 is ideal) and its 95 % interval for this many trials.

Synced (``--synced``): every spin speeds up from rest over ``--spin-ramp`` s and slows down again, and each
measurement carries its spinning joint's readings (100 per second, ``--encoder-sigma-deg`` noise, stamped
``--time-offset`` s ahead of the camera); ``joint`` syncs them (``CalibrationOptions.sync_encoders``) and is compared
with the synced bound (:func:`crlb_synced`: the same graph, exact readings, the offset estimated under its 0.1 s
prior), and the estimated offset with its own bound and NEES (target: within a tenth of a frame). With ``--clocks
per-spin`` every spin's readings name a camera clock of their own (``SpinReadings.clock``, as videos placed one by
one on a joint series: ``track --videos ... --joints states.csv``), its frames' camera times shifted by a draw of
+-half a frame (what the placement by image motion leaves), and the calibration estimates one offset per spin;
the bound has one offset variable per clock, and the offsets' errors are pooled over the clocks.

Run: ``python benchmarks/accuracy.py [--trials 50] [--jobs 2] [--duration 60] [--noise-var 1.5] [--synced]``.
Trials run in separate processes (CustomFactors cannot be pickled: each process builds its own graphs).
"""

from __future__ import annotations

import argparse
import time
from concurrent.futures import ProcessPoolExecutor

import gtsam
import numpy as np
from tqdm import tqdm

from gtsam_rotid.dataset import Measurement
from gtsam_rotid.uncertainty import chi2_mean_interval

METHODS = ("joint", "weighted", "paper")
AXES = ("rx deg", "ry deg", "rz deg", "tx mm", "ty mm", "tz mm")
#: tangent (rad, m) -> (deg, mm)
UNITS = np.array([np.degrees(1.0)] * 3 + [1000.0] * 3)


def crlb(dataset, truth, noise_var: float) -> np.ndarray:
    """Cramér–Rao bound (6x6, Pose3 tangent) of ``arm_T_camera`` for this scene's tracks at the truth.

    The pose-bound joint graph (exact kinematics, free phase per observation) is linearised at the true pose and
    the true circles; the pose information is its Schur complement over the circles, at the true pixel noise.
    """
    from gtsam_rotid.graph import RotIdGraph
    from gtsam_rotid.uncertainty import pose_information

    pose = truth.arm_T_camera
    builder = RotIdGraph(dataset.arm, dataset.camera, track_sigma_px=float(np.sqrt(noise_var)), model="pose")
    graph, values = gtsam.NonlinearFactorGraph(), gtsam.Values()
    values.insert(builder.pose_key, pose)
    for k, (measurement, m_truth) in enumerate(zip(dataset, truth.measurements, strict=True)):
        point_cam = pose.transformTo(m_truth.axis_point)
        direction_cam = pose.rotation().unrotate(m_truth.axis_direction)
        along = point_cam @ direction_cam
        scale = float(m_truth.axis.distance_to(pose.translation())[0])  # camera centre to the axis
        circles = {j: np.array([(t.offset + along) / scale, t.radius / scale])
                   for j, t in enumerate(m_truth.tracks)}
        builder.add_measurement(graph, values, k, measurement, initial_circles=circles, refine_circles=False)
    return np.linalg.inv(pose_information(graph, values, builder.pose_key))


def crlb_rigid(dataset, truth, noise_var: float) -> np.ndarray:
    """Cramér–Rao bound (6x6) of ``arm_T_camera`` with the rigid spin, for this scene's tracks at the truth.

    The rigid-spin joint graph of the estimators (a line variable per measurement, tied to the FK axis by their
    stiff tie; one spin angle per frame and one phase offset per track) on the noise-free pixels of the same
    tracks (the true feature points at the tracks' frames): each measurement's rigid-spin factor solves its spin
    and circles to the truth with zero residual, where its information is the Fisher information with them
    marginalised; the pose information is the Schur complement over the lines, at the true pixel noise.
    """
    from gtsam_rotid.graph import RotIdGraph
    from gtsam_rotid.uncertainty import pose_information

    pose = truth.arm_T_camera
    builder = RotIdGraph(dataset.arm, dataset.camera, track_sigma_px=float(np.sqrt(noise_var)), model="projected",
                         spin_model="rigid")
    graph, values = gtsam.NonlinearFactorGraph(), gtsam.Values()
    values.insert(builder.pose_key, pose)
    add_noise_free(builder, graph, values, dataset.camera, list(dataset), truth)
    return np.linalg.inv(pose_information(graph, values, builder.pose_key))


def crlb_synced(dataset, truth, noise_var: float, config, shifts: dict | None = None
                ) -> tuple[np.ndarray, float | dict]:
    """Cramér–Rao bound (6x6) of ``arm_T_camera`` and (1 sigma, s) of the clocks' offset with the rigid spin synced
    with the spinning joint's readings: :func:`crlb_rigid`'s graph on noise-free pixels with noise-free readings
    (``config``'s spin, stamped with its offset) under the estimator's prior (``encoder_sigma_deg`` per frame), the
    offset a variable under ``CalibrationOptions``' default prior (0.1 s). With ``shifts`` (clock -> s, the
    readings naming their clocks): one offset per clock, the bound's 1 sigma per clock."""
    from gtsam_rotid.calibration.options import CalibrationOptions
    from gtsam_rotid.dataset import SpinReadings
    from gtsam_rotid.graph import RotIdGraph
    from gtsam_rotid.simulate import spin_profile
    from gtsam_rotid.uncertainty import marginal_information

    options = CalibrationOptions(encoder_sigma_deg=config.encoder_sigma_deg)
    keys = {None: gtsam.symbol("d", 0)} if shifts is None else {
        c: gtsam.symbol("d", i) for i, c in enumerate(shifts)}
    builder = RotIdGraph(dataset.arm, dataset.camera, track_sigma_px=float(np.sqrt(noise_var)), model="projected",
                         spin_model="rigid", encoder_sigma_deg=options.encoder_sigma_deg,
                         time_offset_key=keys[None] if shifts is None else keys)
    graph, values = gtsam.NonlinearFactorGraph(), gtsam.Values()
    values.insert(builder.pose_key, truth.arm_T_camera)
    for clock in keys:  # (the graph's offset is encoder minus camera: a shifted camera clock's less its shift)
        builder.add_time_offset_prior(graph, values, options.time_offset_sigma_s, options.time_offset_s,
                                      config.encoder_time_offset - (0.0 if shifts is None else shifts[clock]),
                                      clock=clock)
    exact = []
    for measurement, m_truth in zip(dataset, truth.measurements, strict=True):
        r = measurement.spin_readings
        start = float(m_truth.joint_angles[dataset.arm.spin_index(measurement.spin_joint)])
        angles = start + spin_profile(r.times - config.encoder_time_offset, config)
        exact.append(Measurement(measurement.joint_angles, measurement.tracks, spin_joint=measurement.spin_joint,
                                 spin_readings=SpinReadings(r.frame_times, r.times, angles, clock=r.clock)))
    add_noise_free(builder, graph, values, dataset.camera, exact, truth)
    pose = np.linalg.inv(marginal_information(graph, values, builder.pose_key, 6))
    offsets = {c: float(np.sqrt(1.0 / marginal_information(graph, values, key, 1)[0, 0])) for c, key in keys.items()}
    return pose, offsets[None] if shifts is None else offsets


def add_noise_free(builder, graph, values, camera, measurements, truth) -> None:
    """Each measurement's tracks as noise-free pixels (the true feature points at the tracks' frames, seen from the
    true pose), its circles started at the truth, added to ``builder``'s graph (readings as ``measurements`` have
    them): the estimators' graph at the truth, where its information is the Fisher information."""
    from gtsam_rotid.dataset import Track

    pose = truth.arm_T_camera
    for k, (measurement, m_truth) in enumerate(zip(measurements, truth.measurements, strict=True)):
        exact = []
        for j, track in enumerate(measurement.tracks):
            points = pose.transformTo(m_truth.feature_points(j, track.frames).T).T
            exact.append(Track(camera.project(points), track.frames))
        point_cam = pose.transformTo(m_truth.axis_point)
        along = point_cam @ pose.rotation().unrotate(m_truth.axis_direction)
        scale = float(m_truth.axis.distance_to(pose.translation())[0])
        circles = {j: np.array([(t.offset + along) / scale, t.radius / scale]) for j, t in enumerate(m_truth.tracks)}
        builder.add_measurement(graph, values, k, Measurement(measurement.joint_angles, exact,
                                                              spin_joint=measurement.spin_joint,
                                                              spin_readings=measurement.spin_readings),
                                initial_circles=circles, refine_circles=False)


def per_spin_clocks(dataset, seed: int, fps: float):
    """The dataset with each spin's readings on a camera clock of its own (``spin<k>``), its frames' camera times
    shifted by a draw of +-half a frame (the trial's seed), and the shifts (clock -> s)."""
    from gtsam_rotid.dataset import Dataset, SpinReadings

    rng = np.random.default_rng([seed, 18])
    shifts, measurements = {}, []
    for k, m in enumerate(dataset):
        r = m.spin_readings
        shifts[f"spin{k}"] = shift = float(rng.uniform(-0.5, 0.5)) / fps
        measurements.append(m.replace(spin_readings=SpinReadings(r.frame_times + shift, r.times, r.angles,
                                                                 clock=f"spin{k}")))
    return Dataset(dataset.arm, dataset.camera, measurements, metadata=dataset.metadata), shifts


def trial(seed: int, duration: float, noise_var: float, joint_model: str, spin_model: str, methods,
          joint_angles, synced: dict | None = None, clocks: str = "one") -> dict:
    from gtsam_rotid import simulate
    from gtsam_rotid.errors import RotIdError
    from gtsam_rotid.estimate import CalibrationOptions, calibrate

    dataset, truth = simulate.reference_scene(seed=seed, noise_var=noise_var, duration=duration,
                                              joint_angles=joint_angles, **(synced or {}))
    shifts = None
    if synced and clocks == "per-spin":
        dataset, shifts = per_spin_clocks(dataset, seed, simulate.SceneConfig().fps)
    out = {"seed": seed, "crlb": crlb(dataset, truth, noise_var), "points": sum(m.n_observations for m in dataset)}
    if spin_model == "rigid" and "joint" in methods:
        out["crlb_rigid"] = crlb_rigid(dataset, truth, noise_var)
        if synced:
            config = simulate.SceneConfig().with_(duration=duration, **synced)
            out["crlb_synced"], out["offset_bound"] = crlb_synced(dataset, truth, noise_var, config, shifts)
            out["shifts"] = shifts
    options = CalibrationOptions(joint_model=joint_model, spin_model=spin_model,
                                 **({} if not synced else {"encoder_sigma_deg": synced["encoder_sigma_deg"]}))
    for method in methods:
        start = time.perf_counter()
        try:
            result = calibrate(dataset, method=method, options=options)
        except RotIdError as error:
            out[method] = {"failed": str(error)}
            continue
        out[method] = {
            "error": result.error_to(truth.arm_T_camera),
            "covariance": result.covariance,
            "usable": result.covariance_usable,
            "seconds": time.perf_counter() - start,
            "offset": result.time_offset_s,
            "offset_sigma": result.time_offset_sigma_s,
            "offsets": None if result.time_offsets is None else {
                c: (v["offset_s"], v["sigma_s"]) for c, v in result.time_offsets.items()},
            "refused": len(result.readings_refused),
            "spins": len(dataset),
        }
    return out


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--trials", type=int, default=50)
    parser.add_argument("--jobs", type=int, default=2)
    parser.add_argument("--duration", type=float, default=60.0, help="seconds of spin per measurement")
    parser.add_argument("--noise-var", type=float, default=1.5, help="pixel noise variance, px^2")
    parser.add_argument("--first-seed", type=int, default=1000)
    parser.add_argument("--scene-seed", type=int, default=0, help="seed of the reference scene whose arm poses "
                        "every trial keeps (-1: new poses in every trial)")
    parser.add_argument("--joint-model", default="projected", choices=("projected", "line", "pose"),
                        help="graph of the joint method (CalibrationOptions.joint_model)")
    parser.add_argument("--spin-model", default="rigid", choices=("free", "rigid"),
                        help="phase model of the joint method (CalibrationOptions.spin_model) and of the bound")
    parser.add_argument("--methods", default=",".join(METHODS), help="comma-separated subset of " + ",".join(METHODS))
    parser.add_argument("--save", help="also write every trial's errors and covariances to this .npz file")
    parser.add_argument("--synced", action="store_true", help="ramped spins with the spinning joint's readings; "
                        "joint syncs them and is compared with the synced bound")
    parser.add_argument("--spin-ramp", type=float, default=2.0, help="synced: seconds of speeding up and of "
                        "slowing down at each end of a spin")
    parser.add_argument("--encoder-sigma-deg", type=float, default=0.02, help="synced: the readings' noise (deg)")
    parser.add_argument("--time-offset", type=float, default=0.037, help="synced: the encoder clock's offset (s)")
    parser.add_argument("--clocks", choices=("one", "per-spin"), default="one",
                        help="synced: one camera clock for every spin (a bag), or one per spin, each shifted by up "
                             "to half a frame (videos placed one by one on a joint series)")
    args = parser.parse_args(argv)
    methods = [m for m in args.methods.split(",") if m]
    unknown = set(methods) - set(METHODS)
    if unknown:
        parser.error(f"unknown methods {sorted(unknown)}")

    seeds = range(args.first_seed, args.first_seed + args.trials)
    joint_angles = None
    if args.scene_seed >= 0:
        from gtsam_rotid import simulate

        _, scene = simulate.reference_scene(seed=args.scene_seed, duration=1.0)
        joint_angles = tuple(tuple(m.joint_angles.tolist()) for m in scene.measurements)
    synced = None
    if args.synced:
        if args.spin_model != "rigid":
            parser.error("--synced needs --spin-model rigid")
        synced = {"spin_ramp": args.spin_ramp, "encoder_rate": 100.0, "encoder_sigma_deg": args.encoder_sigma_deg,
                  "encoder_time_offset": args.time_offset}
    start = time.perf_counter()
    with ProcessPoolExecutor(max_workers=args.jobs) as pool:
        futures = [pool.submit(trial, s, args.duration, args.noise_var, args.joint_model,
                               args.spin_model, methods, joint_angles, synced, args.clocks) for s in seeds]
        results = [f.result() for f in tqdm(futures, desc="trials", unit="trial")]
    wall = time.perf_counter() - start
    if args.save:
        arrays = {"seeds": np.array([r["seed"] for r in results]), "crlb": np.array([r["crlb"] for r in results])}
        for method in methods:
            ok = [(r["seed"], r[method]) for r in results if "error" in r[method]]
            arrays[f"{method}_seeds"] = np.array([seed for seed, _ in ok])
            arrays[f"{method}_errors"] = np.array([o["error"] for _, o in ok])
            arrays[f"{method}_covariances"] = np.array([o["covariance"] for _, o in ok])
        np.savez(args.save, **arrays)

    bound = np.mean([r["crlb"] for r in results], axis=0)
    bound_sigma = np.sqrt(np.diag(bound)) * UNITS
    rigid = "crlb_rigid" in results[0]
    if rigid:
        rigid_sigma = np.sqrt(np.diag(np.mean([r["crlb_rigid"] for r in results], axis=0))) * UNITS
    synced_bound = "crlb_synced" in results[0]
    if synced_bound:
        synced_sigma = np.sqrt(np.diag(np.mean([r["crlb_synced"] for r in results], axis=0))) * UNITS
    poses = f"arm poses of seed {args.scene_seed}" if joint_angles else "new arm poses every trial"
    spins = "" if not synced else (f", synced: {args.spin_ramp:g} s ramps, readings at 100/s with "
                                   f"{args.encoder_sigma_deg:g} deg noise, {1000 * args.time_offset:g} ms late")
    print(f"\nreference scene ({poses}), {args.trials} trials, {args.duration:g} s spins{spins}, "
          f"sigma^2 = {args.noise_var} px^2, ~{int(np.mean([r['points'] for r in results]))} points per trial "
          f"({wall:.0f} s wall, {args.jobs} jobs)")
    print(f"{'':24}" + "".join(f"{a:>10}" for a in AXES))
    print(f"{'CRLB (1 sigma)':24}" + "".join(f"{v:10.4f}" for v in bound_sigma) + "   free phase")
    if rigid:
        print(f"{'CRLB (1 sigma)':24}" + "".join(f"{v:10.4f}" for v in rigid_sigma) + "   rigid spin"
              + ("" if synced_bound else " (joint)"))
    if synced_bound:
        print(f"{'CRLB (1 sigma)':24}" + "".join(f"{v:10.4f}" for v in synced_sigma) + "   synced (joint)")
    low, high = chi2_mean_interval(6, args.trials)
    for method in methods:
        ok = [r[method] for r in results if "error" in r[method]]
        failed = args.trials - len(ok)
        if not ok:
            print(f"{method}: every trial failed ({results[0][method]['failed']})")
            continue
        errors = np.array([o["error"] for o in ok])
        rmse = np.sqrt(np.mean(errors**2, axis=0)) * UNITS
        mean = np.mean(errors, axis=0) * UNITS
        usable = [o for o in ok if o["usable"]]
        nees = np.mean([o["error"] @ np.linalg.solve(o["covariance"], o["error"]) for o in usable])
        seconds = np.median([o["seconds"] for o in ok])
        print(f"\n{method} ({len(ok)} trials{f', {failed} FAILED' if failed else ''}, median {seconds:.1f} s)")
        print(f"{'  RMSE':24}" + "".join(f"{v:10.4f}" for v in rmse))
        key = "crlb" if not (rigid and method == "joint") else "crlb_synced" if synced_bound else "crlb_rigid"
        reference = {"crlb": bound_sigma, "crlb_rigid": rigid_sigma if rigid else None,
                     "crlb_synced": synced_sigma if synced_bound else None}[key]
        print(f"{'  RMSE / bound':24}" + "".join(f"{v:10.3f}" for v in rmse / reference)
              + {"crlb": "", "crlb_rigid": "   (rigid spin's)", "crlb_synced": "   (synced)"}[key])
        own = np.array([np.sqrt(np.diag(r[key])) for r in results if "error" in r[method]])
        per_trial = np.sqrt(np.mean((errors / own) ** 2, axis=0))
        print(f"{'  RMS(error / own bound)':24}" + "".join(f"{v:10.3f}" for v in per_trial))
        print(f"{'  mean error / RMSE':24}" + "".join(f"{v:10.2f}" for v in mean / rmse))
        verdict = "inside" if low <= nees <= high else "OUTSIDE"
        print(f"  NEES {nees:.2f} (ideal 6; 95 % interval for {len(usable)} trials [{low:.2f}, {high:.2f}]: {verdict})")
        if synced_bound and method == "joint" and args.clocks == "per-spin":
            clocked = [(o["offsets"], r["shifts"], r["offset_bound"]) for r in results
                       for o in [r[method]] if "error" in o and o.get("offsets")]
            rows = [(-offsets[c][0] - (args.time_offset - shifts[c]), offsets[c][1], bounds[c])
                    for offsets, shifts, bounds in clocked for c in offsets if offsets[c][1] is not None]
            if rows:
                print_offsets(f"time offsets, one per spin's clock ({len(rows)} clocks)", *zip(*rows, strict=True),
                              ok)
        timed = [(o["offset"], o["offset_sigma"]) for o in ok if o.get("offset_sigma") is not None]
        if synced_bound and method == "joint" and timed and args.clocks == "one":
            offsets, sigmas = np.array(timed).T
            # (the result's offset is camera minus encoder; --time-offset the encoder's lead)
            print_offsets("time offset", -offsets - args.time_offset, sigmas, [r["offset_bound"] for r in results], ok)
    return 0


def print_offsets(label: str, errors, sigmas, bounds, ok: list) -> None:
    """The clocks' offsets' line: RMSE of ``errors`` (s, estimate less truth, encoder minus camera) against the RMS
    of ``bounds``, mean error, the reported 1 sigma (median of ``sigmas``), NEES and the readings refused in ``ok``."""
    errors, sigmas, bounds = (np.asarray(v, dtype=float) for v in (errors, sigmas, bounds))
    rmse, bound = float(np.sqrt(np.mean(errors**2))), float(np.sqrt(np.mean(bounds**2)))
    nees = float(np.mean((errors / sigmas) ** 2))
    low, high = chi2_mean_interval(1, len(errors))
    frame = 1.0 / simulate_fps()
    print(f"  {label}: RMSE {1000 * rmse:.2f} ms ({rmse / frame:.3f} frame; bound {1000 * bound:.2f} ms, ratio "
          f"{rmse / bound:.2f}), mean error {1000 * np.mean(errors):+.2f} ms, reported 1 sigma median "
          f"{1000 * np.median(sigmas):.2f} ms, NEES {nees:.2f} (95 % interval [{low:.2f}, {high:.2f}]: "
          f"{'inside' if low <= nees <= high else 'OUTSIDE'}); readings refused (disagreeing with the tracks) on "
          f"{sum(o.get('refused', 0) for o in ok)} of {sum(o['spins'] for o in ok)} spins")


def simulate_fps() -> float:
    from gtsam_rotid.simulate import SceneConfig

    return SceneConfig().fps


if __name__ == "__main__":
    raise SystemExit(main())

"""Wrong intrinsics and joint offsets flagged, not hidden behind one measurement called an outlier
(``calibration.modelcheck``).

The reference scene (Jaco2, six ``--duration`` s spins, 1.5 px² noise) of each seed is calibrated through the camera
file as given and through cameras whose focal length (fx and fy together) or principal point is off, and with one
pose's shoulder reading 1 degree off (a wrong joint reading: it must not be blamed on the camera), and with joint
offsets (zero-position errors common to every pose: each joint before the wrist read 0.5 degree off, signs drawn per
seed; issue 17 wants them flagged without refinement). Printed per case: how many seeds are flagged ``intrinsics``,
``intrinsics_shapes`` (the tracks' shapes ask for another camera), ``kinematics``, ``camera_or_measurement`` and
``kinematics_or_measurement`` (with the measurement named: the wrong
shoulder reading is on measurement 2), how many still call their covariance usable, the median true error (worst
axis, mm and deg) and the median chi-square of the error under the reported covariance, and the median intrinsics
change the check reads where it flags (refused calibrations are counted apart). With ``--panda`` the Panda scenes of
``benchmarks/ambient.py``'s placement (small hand, exact intrinsics) are also calibrated, to count false flags.

Run: ``python benchmarks/intrinsics_check.py [--seeds 10] [--duration 20] [--panda 20] [--cases NAME,...]``.
"""

from __future__ import annotations

import argparse
import sys
import time

import numpy as np

from gtsam_rotid import Dataset, Measurement, simulate
from gtsam_rotid.errors import RotIdError
from gtsam_rotid.estimate import calibrate

#: case -> (focal factor, cx shift px, cy shift px, wrong joint reading, joint offsets deg)
CASES = {
    "exact": (1.0, 0.0, 0.0, False, 0.0),
    "focal +5 %": (1.05, 0.0, 0.0, False, 0.0),
    "focal +3 %": (1.03, 0.0, 0.0, False, 0.0),
    "focal -2 %": (0.98, 0.0, 0.0, False, 0.0),
    "cx +20 px": (1.0, 20.0, 0.0, False, 0.0),
    "cx +10 px": (1.0, 10.0, 0.0, False, 0.0),
    "cy -10 px": (1.0, 0.0, -10.0, False, 0.0),
    "one shoulder reading +1 deg": (1.0, 0.0, 0.0, True, 0.0),
    "joint offsets 0.5 deg": (1.0, 0.0, 0.0, False, 0.5),
    "joint offsets 0.5 deg with focal +3 % and cx +10 px": (1.03, 10.0, 0.0, False, 0.5),
}


def case_dataset(dataset: Dataset, focal: float, cx: float, cy: float, wrong_joint: bool, offsets_deg: float,
                 seed: int = 0) -> Dataset:
    measurements = list(dataset)
    if wrong_joint:
        q = np.array(measurements[2].joint_angles, dtype=float)
        q[1] += np.radians(1.0)
        measurements[2] = Measurement(q, measurements[2].tracks)
    if offsets_deg:
        w = dataset.arm.wrist_index
        signs = np.random.default_rng([17, seed]).choice([-1.0, 1.0], size=w)
        shift = np.zeros(len(dataset.arm.joint_names))
        shift[:w] = np.radians(offsets_deg) * signs
        measurements = [Measurement(dataset.joint_angles(k) - shift, m.tracks, name=m.name)
                        for k, m in enumerate(measurements)]
    return Dataset(dataset.arm, dataset.camera.with_intrinsics_changed(focal, cx, cy), measurements)


def run(dataset: Dataset, truth) -> dict:
    try:
        result = calibrate(dataset)
    except RotIdError as error:
        return {"refused": str(error)}
    e = result.error_to(truth.arm_T_camera)
    check = (result.axis_consistency.intrinsics or {}) if result.axis_consistency is not None else {}
    return {"flagged": "intrinsics" in result.untrusted, "kinematics": "kinematics" in result.untrusted,
            "shapes": "intrinsics_shapes" in result.untrusted,
            "measurement": result.untrusted.get("camera_or_measurement"),
            "km": result.untrusted.get("kinematics_or_measurement"),
            "after": result.untrusted.get("inconsistent_after_outliers"),
            "usable": result.covariance_usable,
            "mm": 1000.0 * float(np.max(np.abs(truth.arm_T_camera.rotation().matrix() @ e[3:]))),
            "deg": float(np.degrees(np.max(np.abs(e[:3])))),
            "chi2": float(e @ np.linalg.solve(result.covariance, e)),
            "reading": (check.get("focal_percent"), check.get("cx_px"), check.get("cy_px"))}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=10)
    parser.add_argument("--duration", type=float, default=20.0)
    parser.add_argument("--panda", type=int, default=0, help="also this many Panda scenes (exact intrinsics)")
    parser.add_argument("--cases", default="", help="comma-separated case names (default: all)")
    args = parser.parse_args(argv)
    started = time.perf_counter()
    cases = {name: CASES[name] for name in args.cases.split(",")} if args.cases else CASES
    rows = {name: [] for name in cases}
    for seed in range(args.seeds):
        dataset, truth = simulate.reference_scene(seed=seed, duration=args.duration)
        for name, case in cases.items():
            rows[name].append(run(case_dataset(dataset, *case, seed=seed), truth))
        print(f"seed {seed} done ({time.perf_counter() - started:.0f} s)", flush=True)
    print(f"\nreference scene, {args.seeds} seeds, {args.duration:g} s spins\n")
    print("| case | flagged intrinsics | flagged intrinsics_shapes | flagged kinematics | flagged camera or "
          "measurement (which) | flagged kinematics or measurement (which) | flagged inconsistent after outliers "
          "(left out) | covariance usable | error mm / deg (median) | χ² of the error (median) | reading where "
          "flagged: focal %, cx px, cy px (median) |")
    print("| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |")
    for name, results in rows.items():
        done = [r for r in results if "refused" not in r]
        flagged = [r for r in done if r["flagged"]]
        reading = (np.median([r["reading"] for r in flagged], axis=0) if flagged else None)
        named = [r["measurement"][0] for r in done if r["measurement"]]
        km = [r["km"][0] for r in done if r["km"]]
        after = [r["after"] for r in done if r["after"]]
        print(f"| {name} | {len(flagged)} of {len(done)} | {sum(r['shapes'] for r in done)} of {len(done)} | "
              f"{sum(r['kinematics'] for r in done)} of {len(done)} | "
              f"{len(named)} of {len(done)}" + (f" ({', '.join(str(k) for k in named)})" if named else "") + " | "
              f"{len(km)} of {len(done)}" + (f" ({', '.join(str(k) for k in km)})" if km else "") + " | "
              f"{len(after)} of {len(done)}" + (f" ({'; '.join(','.join(map(str, k)) for k in after)})" if after
                                                else "") + " | "
              f"{sum(r['usable'] for r in done)} of {len(done)} | "
              f"{np.median([r['mm'] for r in done]):.2f} / {np.median([r['deg'] for r in done]):.3f} | "
              f"{np.median([r['chi2'] for r in done]):.3g} | "
              + ("" if reading is None else f"{reading[0]:+.2f}, {reading[1]:+.1f}, {reading[2]:+.1f}")
              + (f" ({len(results) - len(done)} refused)" if len(done) < len(results) else "") + " |")
    if args.panda:
        sys.path.insert(0, str(__import__("pathlib").Path(__file__).parent))
        from ambient import PLACEMENTS

        config = simulate.SceneConfig(robot="panda", **PLACEMENTS["panda"], duration=args.duration)
        results = [run(*simulate.simulate(config, seed=seed)) for seed in range(args.panda)]
        done = [r for r in results if "refused" not in r]
        print(f"\nPanda placement, exact intrinsics, {args.panda} seeds: {sum(r['flagged'] for r in done)} of "
              f"{len(done)} flagged intrinsics, {sum(r['shapes'] for r in done)} intrinsics_shapes, "
              f"{sum(r['kinematics'] for r in done)} kinematics, "
              f"{sum(bool(r['measurement']) for r in done)} camera or measurement, "
              f"{sum(bool(r['km']) for r in done)} kinematics or measurement, "
              f"{sum(bool(r['after']) for r in done)} inconsistent after outliers; "
              f"{sum(r['usable'] for r in done)} usable")
    print(f"\n{time.perf_counter() - started:.0f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())

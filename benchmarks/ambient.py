"""Ambient features (issue 13): the robot's own meshes, a covered hand, no calibration target, from pixels.

For each scene (a robot, a covering, a seed): the scene's arm poses and camera come from the simulator
(``simulate.simulate``, six arm poses), every spin is rendered by :mod:`gtsam_rotid.meshrender` (the robot's
visual meshes, the hand covered by ``--covering``: photo, text, fabric, stickers, dots or plain; a photographed
background; shading, 2x2 anti-aliasing and sensor noise), tracked with the given tracker settings (``--features``;
default ``TrackerParams()``), and calibrated (``joint``). Printed per scene:

- tracks kept per arm pose, and the tracker's frames per second on one core (rendering excluded);
- the tracked points against the renderer's ground truth (each track's surface point located from its first points
  and projected in the track's frames; ``meshrender.track_errors``): pooled RMS and median (px), and how many kept
  tracks do not lie on the spinning links at all;
- the calibration error (worst axis, mm and deg) against the reported 1 sigma, the Mahalanobis chi-square of the
  true error under the reported covariance (6 dof), and whether the result calls its covariance usable (with the
  reasons when not).

Then the NEES over the scenes whose covariance is called usable, with its 95 % interval, and the number of usable
scenes outside their 99.9 % region (the "confident wrong numbers"; the target is none).

Run: ``python benchmarks/ambient.py [--robots kinova,ur5,panda] [--coverings photo,text,dots] [--seeds 0,1]
[--duration 20] [--features blobs|corners|auto] [--jobs 2]``; ``--quick`` (one 3 s scene) checks that it runs.
"""

from __future__ import annotations

import argparse
import itertools
import sys
import time

import cv2
import numpy as np

from gtsam_rotid import meshrender as mr
from gtsam_rotid import simulate
from gtsam_rotid.camera import Camera
from gtsam_rotid.dataset import Dataset, Measurement
from gtsam_rotid.errors import InputError, RotIdError
from gtsam_rotid.estimate import calibrate, untrusted_words
from gtsam_rotid.simulate import SceneConfig
from gtsam_rotid.tracking import Tracker, TrackerParams
from gtsam_rotid.uncertainty import chi2_mean_interval

CHI2_999_6DOF = 22.458
#: arm poses per scene, drawn from this many candidates of the simulator
POSES, CANDIDATES = 6, 14
#: robot -> scene placement (the cameras of scenarios/other_arms.py, at 640x480 here)
PLACEMENTS = {
    "kinova": {},
    "ur5": dict(camera=Camera.from_fov(640, 480, 60.0), camera_eye=(0.9, 0.7, 0.9), camera_target=(0.3, 0.1, 0.3)),
    "panda": dict(camera=Camera.from_fov(640, 480, 60.0), camera_eye=(1.1, -0.4, 0.8),
                  camera_target=(0.4, 0.0, 0.4)),
}


def run_scene(robot: str, covering: str, seed: int, duration: float, params: TrackerParams) -> dict:
    """Render, track and calibrate one scene; a dict of the measured numbers (or why it could not run)."""
    cv2.setNumThreads(1)
    out = {"robot": robot, "covering": covering, "seed": seed}
    try:
        # the simulator's pose sampler knows no meshes: draw spare poses and keep the first POSES the mesh
        # renderer accepts (the hand in the image and not hidden behind the arm for most of the spin)
        dataset, truth = simulate.simulate(SceneConfig(robot=robot, duration=duration, n_measurements=CANDIDATES,
                                                       **PLACEMENTS[robot]), seed)
        meshes = mr.load_arm_meshes(dataset.arm)
        config = mr.MeshRenderConfig(covering=covering, seed=seed)
        measurements, kept, errors, track_time, frames, off, skipped = [], [], [], 0.0, 0, 0, []
        for k in range(len(dataset)):
            if len(kept) == POSES:
                break
            try:  # a pose whose hand is hidden behind the arm (or outside the image) is not rendered
                spin = mr.render_mesh_measurement(dataset, truth, k, config, meshes=meshes)
            except InputError as why:
                skipped.append(f"{k}: {why}")
                continue
            images = list(spin.frames())
            start = time.perf_counter()
            result = Tracker(params).run(images)
            track_time += time.perf_counter() - start
            frames += len(images)
            tracks = result.tracks
            kept.append(len(tracks))
            if tracks:
                e = mr.track_errors(tracks, spin)
                off += len(e.off_links)
                ok = np.isfinite(e.rms_px)
                errors.append((np.sum(e.rms_px[ok] ** 2 * e.n_compared[ok]), np.sum(e.n_compared[ok]),
                               np.median(e.rms_px[ok]) if ok.any() else np.nan))
            measurements.append(Measurement(dataset[k].joint_angles, tracks) if tracks else None)
    except RotIdError as error:
        out["failed"] = f"{type(error).__name__}: {error}"
        return out
    out.update(kept=kept, fps=frames / max(track_time, 1e-9), off_links=off, skipped=skipped)
    n_compared = sum(n for _, n, _ in errors)
    out["track_rms_px"] = float(np.sqrt(sum(s for s, _, _ in errors) / n_compared)) if n_compared else float("nan")
    out["track_median_px"] = float(np.nanmedian([m for _, _, m in errors])) if errors else float("nan")
    usable_measurements = [m for m in measurements if m is not None]
    try:
        result = calibrate(Dataset(dataset.arm, dataset.camera, usable_measurements, metadata=dataset.metadata))
    except RotIdError as error:
        out["refused"] = f"{type(error).__name__}: {error}"
        return out
    e = result.error_to(truth.arm_T_camera)
    R = truth.arm_T_camera.rotation().matrix()
    out.update(err_mm=float(np.max(np.abs(R @ e[3:]))) * 1000.0, err_deg=float(np.degrees(np.max(np.abs(e[:3])))),
               sigma_mm=float(np.max(result.sigma_mm_arm)), sigma_deg=float(np.max(result.sigma_deg)),
               usable=bool(result.covariance_usable), untrusted=list(result.untrusted),
               words=untrusted_words(result) if result.untrusted else [])
    try:
        out["chi2"] = float(e @ np.linalg.solve(result.covariance, e))
    except np.linalg.LinAlgError:
        out["chi2"] = float("inf")
    return out


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--robots", default="kinova,ur5,panda")
    parser.add_argument("--coverings", default="photo,text,dots")
    parser.add_argument("--seeds", default="0")
    parser.add_argument("--duration", type=float, default=20.0, help="spin length per arm pose (s)")
    parser.add_argument("--features", default=None, help="TrackerParams.features (default: the tracker's default)")
    parser.add_argument("--jobs", type=int, default=1)
    parser.add_argument("--quick", action="store_true", help="one 3 s scene: checks that it runs")
    args = parser.parse_args(argv)
    if args.quick:
        args.robots, args.coverings, args.seeds, args.duration = "kinova", "photo", "0", 3.0
    params = TrackerParams() if args.features is None else TrackerParams(features=args.features)
    scenes = list(itertools.product(args.robots.split(","), args.coverings.split(","),
                                    [int(s) for s in args.seeds.split(",")]))
    print(f"{len(scenes)} scenes, {args.duration:g} s spins, tracker features={params.features!r}", flush=True)
    started = time.perf_counter()
    if args.jobs > 1:
        from joblib import Parallel, delayed
        rows = Parallel(n_jobs=args.jobs)(delayed(run_scene)(r, c, s, args.duration, params) for r, c, s in scenes)
    else:
        rows = [run_scene(r, c, s, args.duration, params) for r, c, s in scenes]
    print("| robot | covering | seed | tracks kept per pose | tracker fps | tracks off the hand | tracked RMS px "
          "(median track) | error mm (1σ) | error ° (1σ) | χ² of the error | covariance |")
    print("| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |")
    usable_chi2 = []
    for row in rows:
        head = f"| {row['robot']} | {row['covering']} | {row['seed']} |"
        if "failed" in row:
            print(f"{head} not rendered: {row['failed'][:120]} |")
            continue
        kept = ", ".join(str(k) for k in row["kept"]) + (f" ({len(row['skipped'])} poses skipped: not renderable)"
                                                          if row["skipped"] else "")
        track = (f" {kept} | {row['fps']:.0f} | {row['off_links']} | {row['track_rms_px']:.3f} "
                 f"({row['track_median_px']:.3f}) |")
        if "refused" in row:
            print(f"{head}{track} refused: {row['refused'][:160]} | | | |")
            continue
        verdict = "usable" if row["usable"] else "NOT usable (" + (", ".join(row["untrusted"]) or "undetermined") + ")"
        print(f"{head}{track} {row['err_mm']:.2f} ({row['sigma_mm']:.2f}) | {row['err_deg']:.3f} "
              f"({row['sigma_deg']:.3f}) | {row['chi2']:.3g} | {verdict} |")
        if row["usable"]:
            usable_chi2.append(row["chi2"])
    if usable_chi2:
        low, high = chi2_mean_interval(6, len(usable_chi2))
        outside = sum(c > CHI2_999_6DOF for c in usable_chi2)
        nees = float(np.mean(usable_chi2))
        print(f"\nNEES over the {len(usable_chi2)} scenes called usable: {nees:.2f} (95 % interval [{low:.2f}, "
              f"{high:.2f}]: {'inside' if low <= nees <= high else 'OUTSIDE'}); {outside} outside their 99.9 % region")
    else:
        print("\nno scene's covariance is called usable")
    print(f"{time.perf_counter() - started:.0f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())

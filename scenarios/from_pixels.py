"""From pixels: render -> track -> calibrate on the reference scene (the pixel pipeline of issue 4, end to end).

The simulator gives the arm poses, the camera and the true ``arm_T_camera`` of the reference scene (Kinova Jaco2,
Xtion-like 640x480 camera, six wrist spins at 30 fps); the renderer draws each spin as 8-bit frames (dots of 4-9 mm
on the end effector, a textured background, image noise); the tracker turns the frames into tracks, and the
estimator (``joint``) sees only those tracks (``gtsam_rotid.pixels.dataset_from_video``, then ``calibrate``). The
criteria are the issue's targets: tracked points within 0.1 px RMS of the renderer's true dot centres, and a
calibration within 1 mm and 0.05 deg of the truth on every axis. The scenario also asks whether the error lies
inside the reported 99.9 % region: the tracker's sub-pixel errors are not white (a bias that follows a dot along its
track, and one shared by a measurement's tracks), so the covariance is cluster-robust over tracks and scaled by the
image axes' disagreement with the estimate (``result.axis_consistency``, which the scenario shows); it compares with
the same scene calibrated from the simulator's own tracks (its features, with 1.5 px² white noise).

Run: ``python scenarios/from_pixels.py [--quick] [--out DIR] [--seed N]``. ``--quick`` renders the demo's
20 s spins instead of 60 s.
"""

from __future__ import annotations

import sys

import numpy as np
from _common import (
    CHI2_6_999,
    TANGENT_LABELS,
    TANGENT_UNITS,
    Verdict,
    error_lines,
    header,
    mahalanobis2,
    new_figure,
    parse_args,
    position_error_mm,
    print_observability,
    rotation_error_deg,
    run_calibration,
    save_figure,
    tangent_error,
)

from gtsam_rotid import simulate
from gtsam_rotid.demo import DEMO_DURATION
from gtsam_rotid.pixels import dataset_from_video
from gtsam_rotid.plots import plot_pose_3d, plot_residual_histograms, save_overlays
from gtsam_rotid.report import make_report
from gtsam_rotid.words import axis_consistency_sentence

#: the issue's targets (benchmarks/tracking.py): tracked points vs the rendered truth, calibration error per axis
TARGET_RMS_PX = 0.1
TARGET_MM = 1.0
TARGET_DEG = 0.05


def axis_errors(result, truth_pose) -> tuple[np.ndarray, np.ndarray]:
    """(rotation error about the camera axes in deg, translation error in mm: arm-frame position then camera-frame
    translation, six values): what the targets bound per axis."""
    e = tangent_error(result.arm_T_camera, truth_pose) * TANGENT_UNITS
    return e[:3], np.concatenate([position_error_mm(result.arm_T_camera, truth_pose), e[3:]])


def comparison_figure(results: dict, truth_pose):
    """Per Pose3 tangent axis: |error| of each calibration (bars), its reported 1σ (black ticks), and the targets
    (dashed), on one log scale (rotation in degrees, translation in mm)."""
    fig = new_figure(8.0, 4.4)
    ax = fig.subplots()
    x = np.arange(len(TANGENT_LABELS))
    width = 0.8 / len(results)
    for i, (label, result) in enumerate(results.items()):
        at = x - 0.4 + width * (i + 0.5)
        ax.bar(at, np.abs(tangent_error(result.arm_T_camera, truth_pose)) * TANGENT_UNITS, width, alpha=0.85,
               label=f"{label}: |error|")
        ax.plot(at, np.sqrt(np.diag(result.covariance)) * TANGENT_UNITS, "_", color="k", ms=14, mew=2,
                label="reported 1σ" if i == 0 else None)
    ax.hlines([TARGET_DEG, TARGET_MM], [-0.45, 2.55], [2.45, 5.45], colors="0.4", linestyles="--",
              label=f"targets ({TARGET_DEG} deg, {TARGET_MM:g} mm)")
    ax.set_xticks(x, TANGENT_LABELS)
    ax.set_yscale("log")
    ax.set_ylabel("deg (rotation) / mm (translation, camera frame)")
    ax.set_title("reference scene: calibrated from rendered and tracked pixels vs from the simulator's tracks",
                 fontsize=8)
    ax.legend(fontsize=7)
    return fig


def main(argv=None) -> int:
    args = parse_args("from_pixels", __doc__.split("\n\n")[0], argv)
    duration = DEMO_DURATION if args.quick else 60.0
    header(args, "render -> track -> calibrate on the reference scene",
           [f"Kinova Jaco2, Xtion-like 640x480 camera, six {duration:g} s wrist spins rendered at 30 fps, tracked "
            "and calibrated (joint); compared with the simulator's own tracks (sigma^2 = 1.5 px^2)"])
    dataset, truth = simulate.reference_scene(seed=args.seed, duration=duration)
    print(f"simulated {len(dataset)} arm poses; the simulator's tracks: {dataset.n_tracks} tracks, "
          f"{sum(m.n_observations for m in dataset)} pixels")
    print("rendering and tracking...", flush=True)
    scene = dataset_from_video(dataset, truth, progress=sys.stderr.isatty())
    print(scene.summary())
    accuracy = scene.total_accuracy
    tracked = scene.dataset
    print(f"tracked dataset: {tracked.n_tracks} tracks, {sum(m.n_observations for m in tracked)} pixels")

    verdict = Verdict(args)
    results = {}
    for label, data in (("from pixels", tracked), ("simulated tracks", dataset)):
        result, seconds, failure = run_calibration(data, "joint")
        print(f"\n{label}: calibrated (joint) in {seconds:.1f} s")
        if failure:
            print(f"  calibrate FAILED: {failure}")
            verdict.check(False, f"{label}: calibrate returns an estimate")
            continue
        results[label] = result
        rejected = sum(len(m.rejected_tracks) for m in result.measurements)
        print(f"  pixel sigma estimated from the residuals {result.sigma_px:.3f} px; stage 1 rejected {rejected} of "
              f"{data.n_tracks} tracks ({100 * rejected / data.n_tracks:.1f} %)")
        for line in error_lines(result, truth.arm_T_camera):
            print(line)

    pixels, simulated = results.get("from pixels"), results.get("simulated tracks")
    # per calibration: the camera position error (mm, arm frame) and the rotation error (deg), both as magnitudes
    errors = {label: (float(np.linalg.norm(position_error_mm(r.arm_T_camera, truth.arm_T_camera))),
                      rotation_error_deg(r.arm_T_camera, truth.arm_T_camera)) for label, r in results.items()}
    if pixels is not None:
        print("\nfrom pixels, the report (observability and fit consistency):")
        print_observability(pixels, tracked)
        print("  report: " + make_report(pixels, tracked).chi2.sentence())
        if pixels.axis_consistency is not None:
            print("  report: " + axis_consistency_sentence(pixels.axis_consistency))

    print("\nchecks:")
    verdict.check(accuracy.rms_px <= TARGET_RMS_PX,
                  f"tracking: {accuracy.n_matched} tracked points within {accuracy.rms_px:.3f} px RMS of the "
                  f"rendered dot centres (<= {TARGET_RMS_PX} px; {100 * accuracy.matched_fraction:.2f} % matched)")
    if pixels is not None:
        verdict.check(pixels.converged and pixels.covariance_usable,
                      "from pixels: converged, all six degrees of freedom determined")
        rot, trans = axis_errors(pixels, truth.arm_T_camera)
        worst_deg, worst_mm = float(np.max(np.abs(rot))), float(np.max(np.abs(trans)))
        verdict.check(worst_deg <= TARGET_DEG, f"from pixels: rotation error <= {TARGET_DEG} deg about every camera "
                      f"axis (worst {worst_deg:.4f} deg)")
        verdict.check(worst_mm <= TARGET_MM, f"from pixels: position error <= {TARGET_MM:g} mm on every axis, arm "
                      f"and camera frames (worst {worst_mm:.4f} mm)")
        if pixels.covariance_usable:
            error = tangent_error(pixels.arm_T_camera, truth.arm_T_camera)
            d2 = mahalanobis2(error, pixels.covariance)
            # one draw, judged at full size only (benchmarks/pixels_honesty.py measures it over 13 scenes)
            verdict.check(d2 <= CHI2_6_999, f"from pixels: error inside the reported 99.9 % region (e^T Sigma^-1 e "
                          f"= {d2:.2f} <= {CHI2_6_999:.1f})", robust_when_quick=False)
            test = pixels.axis_consistency
            if test is not None and test.scale > 1.0:
                raw = mahalanobis2(error, pixels.covariance / test.scale)
                print(f"  (the image axes disagree beyond their pixel noise, so the covariance was scaled by "
                      f"{test.scale:.3g}; without that scale the error's chi-square would be {raw:.2f})")
    if pixels is not None and simulated is not None:
        ratio = np.sqrt(np.diag(pixels.covariance) / np.diag(simulated.covariance))
        verdict.check(np.all(ratio < 1.0), f"from pixels the reported 1 sigma is below the simulated tracks' on every "
                      f"axis ({ratio.min():.3f}-{ratio.max():.3f}x: the tracker is far more precise than 1.2 px)")
        (p_pix, r_pix), (p_sim, r_sim) = errors["from pixels"], errors["simulated tracks"]
        verdict.check(p_pix < p_sim and r_pix < r_sim, f"from pixels the error is below the simulated tracks' "
                      f"(position {p_pix:.4f} vs {p_sim:.4f} mm, rotation {r_pix:.5f} vs {r_sim:.5f} deg)")
        if simulated.covariance_usable:
            d2 = mahalanobis2(tangent_error(simulated.arm_T_camera, truth.arm_T_camera), simulated.covariance)
            verdict.check(d2 <= CHI2_6_999, f"for comparison, simulated tracks (white noise): error inside the "
                          f"reported 99.9 % region (e^T Sigma^-1 e = {d2:.2f}; reference_jaco2 judges this)",
                          judge=False)

    figures = []
    if results:
        figures.append(save_figure(comparison_figure(results, truth.arm_T_camera), args.out, "errors.png"))
    if pixels is not None:
        frames = {}
        for k, spin in enumerate(scene.spins):
            position = scene.busiest_frame(k)
            frames[k] = (int(spin.frame_indices[position]), spin.frame(position))
        # the quad view per measurement (its panels 3 and 4 are the tracks and the fitted circles of plot_tracks)
        figures += save_overlays(pixels, tracked, frames, args.out, overwrite=True)
        figures.append(save_figure(plot_pose_3d(pixels, tracked), args.out, "pose_3d.png"))
        figures.append(save_figure(plot_residual_histograms(pixels, tracked), args.out, "residuals.png"))

    summary = f"reference scene: tracked {accuracy.rms_px:.3f} px RMS" + "".join(
        f"; {label}: error {p:.4f} mm, {r:.5f} deg" for label, (p, r) in errors.items())
    return verdict.finish(summary, figures)


if __name__ == "__main__":
    sys.exit(main())

"""The graph-building API inside a larger graph: a CAD prior on ``arm_T_camera`` fused with the rotation factors.

A SLAM user owns the factor graph: ``arm_T_camera`` is their variable ``X(0)``, with their own factors on it (here
a prior from the CAD drawing of the mount: 1 deg and 10 mm, 1σ), and ``gtsam_rotid.graph.RotIdGraph`` adds each
wrist spin's variables and factors to that graph with the user's symbols. Two scenes:

1. the reference scene: the rotation factors determine everything; the fused covariance is the information sum
   of the prior and the rotation factors (checked against the prediction ``(Σ_rot⁻¹ + Σ_cad⁻¹)⁻¹``);
2. a single crossing: the rotation factors leave the camera's position along its ray to the crossing point
   undetermined, the CAD prior fills in exactly that direction (fused 1σ along it ≈ the prior's), the rest keeps the
   rotation factors' precision.

In both the fused estimate must lie inside its reported 99.9 % region. The builder must also refuse to add a
measurement twice (its keys already exist).

Run: ``python scenarios/slam_graph.py [--quick] [--out DIR] [--seed N]``.
"""

from __future__ import annotations

import sys

import gtsam
import numpy as np
from _common import (
    CHI2_6_999,
    Verdict,
    header,
    information,
    mahalanobis2,
    new_figure,
    parse_args,
    position_error_mm,
    rotation_error_deg,
    run_calibration,
    save_figure,
    tangent_error,
)
from gtsam.symbol_shorthand import X

from gtsam_rotid import simulate
from gtsam_rotid.errors import InputError
from gtsam_rotid.estimate import CalibrationOptions
from gtsam_rotid.graph import RotIdGraph, lm_params, track_huber

NOISE_VAR = 1.5
CAD_SIGMA = np.array([np.radians(1.0)] * 3 + [0.010] * 3)  # rad, m (Pose3 tangent)


def fuse(dataset, start, cad_pose=None):
    """The user's graph: X(0) = arm_T_camera (with the CAD prior if given) plus every measurement through the
    builder. Returns (estimate, covariance of X(0), number of factors, keys of measurement 0, builder, graph,
    values)."""
    graph, values = gtsam.NonlinearFactorGraph(), gtsam.Values()
    values.insert(X(0), start.arm_T_camera)
    if cad_pose is not None:
        graph.add(gtsam.PriorFactorPose3(X(0), cad_pose, gtsam.noiseModel.Diagonal.Sigmas(CAD_SIGMA)))
    builder = RotIdGraph(dataset.arm, dataset.camera, pose_key=X(0), line_symbol="w", circle_symbol="q",
                         track_sigma_px=start.sigma_px, robust=track_huber)
    first = None
    for k, measurement in enumerate(dataset):
        rejected = start.measurements[k].rejected_tracks
        keys = builder.add_measurement(graph, values, k, measurement, skip_tracks=set(rejected))
        first = keys if first is None else first
    optimizer = gtsam.LevenbergMarquardtOptimizer(graph, values, lm_params())
    result = optimizer.optimize()
    try:
        covariance = gtsam.Marginals(graph, result).marginalCovariance(X(0))
    except RuntimeError:  # indeterminate (no prior on a degenerate scene)
        covariance = None
    return result.atPose3(X(0)), covariance, graph.size(), first, builder, graph, values


def ray_sigma_mm(covariance, pose, direction_arm) -> float:
    u = pose.rotation().matrix().T @ direction_arm
    return 1000.0 * float(np.sqrt(u @ covariance[3:, 3:] @ u))


def scene(verdict, name, dataset, truth, rng, ray=None):
    """Calibrate, fuse with a CAD prior drawn around the truth, print and check; returns the figure's rows."""
    # the builder's default graph (model "line") compares each pixel with the nearest point of its circle (a free
    # phase per observation): the start's information, which predicts the fusion, must be that of the same factors
    start, seconds, failure = run_calibration(dataset, "joint", CalibrationOptions(spin_model="free"))
    print(f"  calibrate (the start, and the rotation factors alone): {seconds:.1f} s")
    if failure:
        print(f"  calibrate FAILED: {failure}")
        verdict.check(False, f"{name}: calibrate gives a start")
        return None
    r0 = rotation_error_deg(start.arm_T_camera, truth.arm_T_camera)
    print(f"  start: position error {np.linalg.norm(position_error_mm(start.arm_T_camera, truth.arm_T_camera)):.2f} "
          f"mm, rotation error {r0:.3f} deg, covariance {'usable' if start.covariance_usable else 'NOT usable'}")
    cad_pose = truth.arm_T_camera.retract(rng.normal(size=6) * CAD_SIGMA)
    print(f"  CAD prior: {np.linalg.norm(position_error_mm(cad_pose, truth.arm_T_camera)):.2f} mm and "
          f"{rotation_error_deg(cad_pose, truth.arm_T_camera):.3f} deg from the truth (1σ 10 mm, 1 deg per axis)")
    fused, covariance, n_factors, keys0, builder, graph, values = fuse(dataset, start, cad_pose)
    print(f"  fused graph: {n_factors} factors; measurement 0 made line key "
          f"{gtsam.DefaultKeyFormatter(keys0.line_key)} and {len(keys0.circles)} circle keys "
          f"({gtsam.DefaultKeyFormatter(keys0.circles[0])}, ...)")
    if covariance is None:
        verdict.check(False, f"{name}: the fused graph has a covariance")
        return None
    e = tangent_error(fused, truth.arm_T_camera)
    d2 = mahalanobis2(e, covariance)
    sigma_f = np.sqrt(np.diag(covariance))
    print(f"  fused: position error {np.linalg.norm(position_error_mm(fused, truth.arm_T_camera)):.3f} mm, rotation "
          f"error {rotation_error_deg(fused, truth.arm_T_camera):.4f} deg, e^T Sigma^-1 e = {d2:.2f}")
    verdict.check(d2 <= CHI2_6_999, f"{name}: fused error inside its reported 99.9 % region ({d2:.2f} <= "
                  f"{CHI2_6_999:.1f})")
    rows = {"CAD prior": CAD_SIGMA, "fused": sigma_f}
    # the rotation factors' information (singular on a degenerate scene) plus the prior's
    predicted = np.linalg.inv(information(start) + np.diag(CAD_SIGMA**-2))
    ratio = sigma_f / np.sqrt(np.diag(predicted))
    if start.covariance_usable:
        rows["rotation factors alone"] = np.sqrt(np.diag(start.covariance))
    print("  fused 1 sigma / (I_rot + Sigma_cad^-1)^-1 prediction: " + " ".join(f"{v:.3f}" for v in ratio))
    verdict.check(np.all(np.abs(ratio - 1.0) < 0.15), f"{name}: the fused covariance is the information sum of the "
                  f"prior and the rotation factors (1 sigma within 15 %: {ratio.min():.3f}-{ratio.max():.3f})")
    if ray is not None:
        along = ray_sigma_mm(covariance, fused, ray)
        print(f"  fused 1 sigma along the camera's ray to P: {along:.2f} mm (the CAD prior alone: 10 mm; the rotation "
              f"factors: none)")
        verdict.check(9.0 < along <= 10.0, f"{name}: the CAD prior determines the camera's position along its ray "
                      f"to P, which the rotation factors leave free (fused 1 sigma {along:.2f} mm, the prior's 10 mm)")
    # the builder refuses to add measurement 0 again: its keys exist
    try:
        builder.add_measurement(graph, values, 0, dataset[0])
        refused = False
    except InputError as error:
        refused = "already exists" in str(error)
        print(f"  adding measurement 0 twice: InputError: {error}")
    verdict.check(refused, f"{name}: the builder refuses to reuse existing keys")
    return rows


def sigma_figure(panels):
    fig = new_figure(10.0, 4.0)
    axes = fig.subplots(1, len(panels), squeeze=False)[0]
    labels = ("rx", "ry", "rz", "tx", "ty", "tz")
    units = np.array([np.degrees(1.0)] * 3 + [1000.0] * 3)
    for ax, (title, rows) in zip(axes, panels, strict=True):
        width = 0.8 / len(rows)
        for i, (name, sigma) in enumerate(rows.items()):
            ax.bar(np.arange(6) - 0.4 + width * (i + 0.5), np.asarray(sigma) * units, width, label=name)
        ax.set_xticks(np.arange(6), labels)
        ax.set_yscale("log")
        ax.set_ylabel("1σ (deg for r, mm for t; Pose3 tangent)")
        ax.set_title(title, fontsize=9)
        ax.legend(fontsize=7)
    fig.suptitle("a CAD prior on arm_T_camera fused with the rotation factors in the user's graph", fontsize=9)
    return fig


def main(argv=None) -> int:
    args = parse_args("slam_graph", __doc__.split("\n\n")[0])
    duration = 10.0 if args.quick else 60.0
    header(args, "RotIdGraph inside the user's graph, fused with a CAD prior",
           [f"Kinova Jaco2 reference camera, six {duration:g} s spins, sigma^2 = {NOISE_VAR} px^2"])
    verdict = Verdict(args)
    rng = np.random.default_rng(args.seed + 100)
    panels = []

    print("1) reference scene")
    dataset, truth = simulate.reference_scene(seed=args.seed, duration=duration, noise_var=NOISE_VAR)
    rows = scene(verdict, "reference", dataset, truth, rng)
    if rows:
        panels.append(("reference scene", rows))

    print("\n2) single crossing (every wrist axis through P)")
    dataset, truth = simulate.single_crossing_scene(seed=args.seed, duration=duration, noise_var=NOISE_VAR)
    P = np.array(truth.config["crossing_point"])
    camera = np.asarray(truth.arm_T_camera.translation())
    rows = scene(verdict, "single crossing", dataset, truth, rng, ray=(P - camera) / np.linalg.norm(P - camera))
    if rows:
        panels.append(("single crossing", rows))
    figures = [save_figure(sigma_figure(panels), args.out, "sigmas.png")] if panels else []
    return verdict.finish("slam graph: the CAD prior and the rotation factors fuse as information adds; on a single "
                          "crossing the prior supplies exactly the undetermined direction", figures)


if __name__ == "__main__":
    sys.exit(main())

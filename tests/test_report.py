"""The calibration report: simulate -> calibrate -> report, numbers checked against independent computation."""

import argparse
import copy
import json
import re

import gtsam
import numpy as np
import pytest

from gtsam_rotid import Line3
from gtsam_rotid.cli import add_report_parser
from gtsam_rotid.errors import OutputError
from gtsam_rotid.estimate import calibrate
from gtsam_rotid.report import (
    CalibrationReport,
    axis_geometry,
    chi2_sf,
    make_report,
)
from gtsam_rotid.words import summary


@pytest.fixture(scope="module")
def reference(reference_weighted):
    return reference_weighted


@pytest.fixture(scope="module")
def crossing(single_crossing):
    dataset, truth = single_crossing
    return dataset, truth, calibrate(dataset, method="weighted")


def parent_frame_covariance(pose, covariance):
    """(x, y, z, rotation about the arm axes) from GTSAM's (w, rho) camera-frame tangent, written out here."""
    R = pose.rotation().matrix()
    J = np.block([[np.zeros((3, 3)), R], [R, np.zeros((3, 3))]])
    return J @ covariance @ J.T


def numbers(text):
    return [float(x) for x in re.findall(r"[-+]?\d+\.\d+", text)]


# ---------------------------------------------------------------------------------------------------
# the reference scene


def test_reference_report_numbers(reference):
    _, _, result = reference
    report = make_report(result)
    assert isinstance(report, CalibrationReport)
    pose = result.arm_T_camera
    R = pose.rotation().matrix()
    np.testing.assert_allclose(report.translation_mm, 1000 * pose.translation(), atol=1e-9)
    roll, pitch, yaw = (np.arctan2(R[2, 1], R[2, 2]), -np.arcsin(R[2, 0]), np.arctan2(R[1, 0], R[0, 0]))
    np.testing.assert_allclose(report.rpy_deg, np.degrees([roll, pitch, yaw]), atol=1e-9)
    x, y, z, w = report.quaternion_xyzw
    Rq = np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                   [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                   [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])
    np.testing.assert_allclose(Rq, R, atol=1e-12)
    assert abs(np.linalg.norm(report.quaternion_xyzw) - 1) < 1e-12

    cov = parent_frame_covariance(pose, result.covariance)
    np.testing.assert_allclose(report.covariance, cov, rtol=1e-12, atol=1e-20)
    sigma = np.sqrt(np.diag(cov))
    np.testing.assert_allclose(report.sigma_position_mm, 1000 * sigma[:3], rtol=1e-12)
    np.testing.assert_allclose(report.sigma_position_mm, result.sigma_mm_arm, rtol=1e-9)
    np.testing.assert_allclose(report.bound95_position_mm, 1.96 * 1000 * sigma[:3], rtol=1e-3)
    np.testing.assert_allclose(report.sigma_rotation_arm_deg, np.degrees(sigma[3:]), rtol=1e-12)
    np.testing.assert_allclose(report.bound95_rotation_arm_deg, 1.96 * np.degrees(sigma[3:]), rtol=1e-3)
    np.testing.assert_allclose(report.sigma_rotation_camera_deg, result.sigma_deg, rtol=1e-12)
    assert report.determined.all() and report.covariance_usable

    corr = cov / np.outer(sigma, sigma)
    np.testing.assert_allclose(report.correlation, corr, atol=1e-12)
    labels = ["x", "y", "z", "rX", "rY", "rZ"]
    strong = {(labels[i], labels[j]) for i in range(6) for j in range(i + 1, 6) if abs(corr[i, j]) > 0.8}
    assert {(a, b) for a, b, _ in report.strong_correlations} == strong
    # 95 % ellipsoid: chi-square 3 dof at 95 % is 7.8147 (table value)
    np.testing.assert_allclose(np.sort(report.ellipsoid95_mm),
                               np.sort(1000 * np.sqrt(7.8147 * np.linalg.eigvalsh(cov[:3, :3]))), rtol=1e-4)


def test_rpy_sigma_matches_sampled_rotations(reference):
    _, _, result = reference
    report = make_report(result)
    rng = np.random.default_rng(0)
    rotation = result.arm_T_camera.rotation()
    cov = parent_frame_covariance(result.arm_T_camera, result.covariance)[3:, 3:]
    samples = rng.multivariate_normal(np.zeros(3), cov, size=20000)
    rpy = np.array([gtsam.Rot3.Expmap(d).compose(rotation).rpy() for d in samples])
    np.testing.assert_allclose(report.sigma_rpy_deg, np.degrees(rpy.std(axis=0)), rtol=0.03)


def test_reference_report_chi2_words_and_measurements(reference):
    _, _, result = reference
    report = make_report(result)
    used = [m for m in result.measurements if m.weight > 0]
    assert report.chi2.chi2 == pytest.approx(2 * result.final_error)
    assert report.chi2.dof == 2 * len(used) - 6
    assert report.chi2.consistent is True
    text = report.to_text()
    assert "all six degrees of freedom of arm_T_camera are determined" in text
    assert f"{result.observability.condition_number:.3g}" in text
    assert "SUGGESTION" not in text
    for m in result.measurements:
        assert re.search(rf"^\s+{m.index}\s+{m.n_tracks}\s+{m.n_points}\s+{m.residual_rms_px:.3f}\s+{m.weight:.2f}",
                         text, re.M)
        for j, why in m.rejected_tracks.items():
            assert f"measurement {m.index}, track {j}: {why}" in text
    # the table shows the values and their 1.96-sigma bounds
    row = next(line for line in text.splitlines() if line.strip().startswith("x (mm)"))
    value, sigma, bound = numbers(row)[:3]
    assert value == pytest.approx(1000 * result.arm_T_camera.translation()[0], abs=0.01)
    assert bound == pytest.approx(1.96 * sigma, rel=0.01)
    markdown = report.to_markdown()
    assert "| x (mm) |" in markdown and "## Observability" in markdown and "## Correlation" in markdown


def test_report_to_dict_is_strict_json(reference):
    _, _, result = reference
    data = json.loads(json.dumps(make_report(result).to_dict(), allow_nan=False))
    assert data["format"] == "gtsam_rotid.report"
    np.testing.assert_allclose(data["sigma"]["position_mm"], result.sigma_mm_arm, rtol=1e-9)
    assert data["chi2"]["dof"] == 6
    assert len(data["measurements"]) == len(result.measurements)
    assert data["observability"]["crossing_point_mm"] is None


def test_chi2_upper_tail_against_table_values():
    for x, dof in ((3.841459, 1), (5.991465, 2), (7.814728, 3), (12.591587, 6), (18.307038, 10)):
        assert chi2_sf(x, dof) == pytest.approx(0.05, abs=1e-6)
    assert chi2_sf(1.0, 2) == pytest.approx(np.exp(-0.5), rel=1e-12)
    # large dof (Wilson-Hilferty): the 95 % point of chi-square with 1000 dof is 1074.679
    assert chi2_sf(1074.679, 1000) == pytest.approx(0.05, abs=1e-3)


# ---------------------------------------------------------------------------------------------------
# the single crossing: what is not determined and what pose to add


def test_single_crossing_report_names_the_point_and_the_pose_to_add(crossing):
    dataset, truth, result = crossing
    report = make_report(result, dataset)
    P_true = 1000 * np.array(truth.config["crossing_point"])
    np.testing.assert_allclose(report.crossing_point_mm, P_true, atol=0.01)
    assert not report.covariance_usable
    assert not report.determined[:3].all()
    text = report.to_text()
    line = next(w for w in report.observability if "wrist axes pass within" in w)
    assert "not determined" in line and "the line through P and the camera" in line
    stated_P = np.array(numbers(line[line.index("P = ("):])[:3])
    np.testing.assert_allclose(stated_P, P_true, atol=0.06)  # printed to 0.1 mm
    # the stated direction is the ray from the true camera to P (the camera can slide along it)
    direction = np.array(numbers(line[line.index("direction ("):])[:3])
    ray = P_true - 1000 * truth.arm_T_camera.translation()
    assert abs(direction @ ray) / (np.linalg.norm(direction) * np.linalg.norm(ray)) > 0.999
    assert "add a pose whose wrist axis misses P" in report.suggestion and "5 cm" in report.suggestion
    assert "SUGGESTION: add a pose whose wrist axis misses P" in text
    assert "not determined" in next(r for r in text.splitlines() if r.strip().startswith("x (mm)"))


def test_single_crossing_without_wrist_axes_still_says_what_to_do(crossing):
    """A result without the wrist axes (an older file) and no dataset: P cannot be located, the advice stands."""
    _, _, result = crossing
    stripped = copy.deepcopy(result)
    for m in stripped.measurements:
        m.axis_point = m.axis_direction = None
    report = make_report(stripped)
    assert report.crossing_point_mm is None
    assert any("single crossing" in w for w in report.observability)
    assert "add a pose whose wrist axis misses" in report.suggestion


def test_wrist_axes_carried_by_the_result_locate_the_crossing(crossing):
    """The result carries each measurement's wrist axis: no dataset is needed to locate P."""
    dataset, truth, result = crossing
    for m in result.measurements:
        axis = dataset.arm.wrist_axis(dataset.joint_angles(m.index))
        np.testing.assert_allclose(m.axis_point, axis.point)
        np.testing.assert_allclose(m.axis_direction, axis.direction)
    report = make_report(result)
    np.testing.assert_allclose(report.crossing_point_mm, 1000 * np.array(truth.config["crossing_point"]), atol=0.01)


def test_near_crossing_is_reported_with_the_sigma_along_the_ray(reference):
    """Determined, but every wrist axis passes within a few mm of one point: the words say so, with the 1σ of the
    position along the camera's ray to that point (here the axes are replaced by lines through a chosen P)."""
    _, _, result = reference
    near = copy.deepcopy(result)
    P = np.array([0.35, 0.05, 0.3])
    rng = np.random.default_rng(2)
    for m in near.measurements:
        d = rng.normal(size=3)
        offset = np.cross(d, [0.0, 0.0, 1.0])
        m.axis_point = (P + 0.003 * offset / np.linalg.norm(offset)).tolist()
        m.axis_direction = d.tolist()
    report = make_report(near)
    line = next(w for w in report.observability if "wrist axes pass within" in w)
    assert "close to a single crossing" in line
    # the point nearest to all the lines (least squares), computed here
    A, b = np.zeros((3, 3)), np.zeros(3)
    for m in near.measurements:
        a = np.array(m.axis_direction) / np.linalg.norm(m.axis_direction)
        A += np.eye(3) - np.outer(a, a)
        b += (np.eye(3) - np.outer(a, a)) @ np.array(m.axis_point)
    nearest = np.linalg.solve(A, b)
    np.testing.assert_allclose(report.crossing_point_mm, 1000 * nearest, atol=1e-6)
    u = nearest - near.arm_T_camera.translation()
    u /= np.linalg.norm(u)
    cov = parent_frame_covariance(near.arm_T_camera, near.covariance)[:3, :3]
    sigma_mm = 1000 * np.sqrt(u @ cov @ u)
    assert f"1σ {sigma_mm:.3g} mm" in line
    assert "misses P by at least 5 cm" in report.suggestion


def test_axis_geometry_crossing_and_parallel():
    P = np.array([0.3, -0.1, 0.5])
    rng = np.random.default_rng(1)
    directions = rng.normal(size=(5, 3))
    # every line misses P by 2 mm (offset perpendicular to its direction)
    near = [Line3(P + 0.002 * np.cross(d, [0, 0, 1]) / np.linalg.norm(np.cross(d, [0, 0, 1])), d) for d in directions]
    np.testing.assert_allclose([line.distance_to(P)[0] for line in near], 0.002)
    geometry = axis_geometry(near)
    assert geometry.is_crossing and not geometry.is_parallel
    assert np.linalg.norm(geometry.point - P) < 0.002
    assert np.max(geometry.miss) < 0.004
    far = [*near, Line3(P + [0.0, 0.0, 0.08], [1.0, 0.0, 0.0])]
    assert not axis_geometry(far).is_crossing
    parallel = [Line3([0.1 * k, 0.0, 0.0], [0.0, 0.01 * k, 1.0]) for k in range(4)]
    geometry = axis_geometry(parallel)
    assert geometry.is_parallel and geometry.spread_deg == pytest.approx(np.degrees(np.arctan(0.03)), rel=1e-6)


# ---------------------------------------------------------------------------------------------------
# command line, as a user runs it: calibrate -o result.json, then report


def run_report(argv):
    parser = argparse.ArgumentParser(prog="gtsam-rotid")
    add_report_parser(parser.add_subparsers(dest="command"))
    args = parser.parse_args(["report", *argv])
    return args.func(args)


def test_cli_report_formats_and_overwrite(reference, tmp_path, capsys):
    _, _, result = reference
    path = tmp_path / "result.json"
    result.save(path)
    assert run_report([str(path)]) == 0
    assert "gtsam_rotid calibration report" in capsys.readouterr().out
    assert run_report([str(path), "--format", "json"]) == 0
    assert json.loads(capsys.readouterr().out)["method"] == "weighted"
    out = tmp_path / "report.md"
    assert run_report([str(path), "--format", "markdown", "-o", str(out)]) == 0
    assert out.read_text().startswith("# Calibration report")
    with pytest.raises(OutputError, match="overwrite"):
        run_report([str(path), "-o", str(out)])
    assert out.read_text().startswith("# Calibration report")


def test_cli_report_with_dataset_and_plots(crossing, tmp_path, capsys):
    dataset, _, result = crossing
    path = tmp_path / "result.json"
    result.save(path)
    dataset.save(tmp_path / "dataset")
    plots = tmp_path / "plots"
    assert run_report([str(path), "--dataset", str(tmp_path / "dataset"), "--plots", str(plots)]) == 0
    captured = capsys.readouterr()
    assert "add a pose whose wrist axis misses P" in captured.out
    assert (plots / "pose_3d.png").read_bytes()[:4] == b"\x89PNG"
    assert (plots / "tracks_m0.png").exists() and (plots / "residuals.png").exists()
    assert "wrote" in captured.err  # progress on stderr while the report goes to stdout
    with pytest.raises(OutputError, match="overwrite"):
        run_report([str(path), "--plots", str(plots)])
    assert run_report([str(path), "--plots", str(plots), "--overwrite"]) == 0


# ---------------------------------------------------------------------------------------------------
# an ambiguous result (several poses fit: e.g. three measurements)


def test_ambiguous_result_is_reported_as_such_and_survives_json(reference):
    from gtsam_rotid.estimate import AMBIGUITY_CHI2, Alternative, CalibrationResult

    dataset, _, result = reference
    assert not result.ambiguous and result.covariance_usable
    other = result.arm_T_camera.compose(gtsam.Pose3(gtsam.Rot3.Rz(np.radians(120.0)), np.array([0.3, 0.0, 0.1])))
    far = Alternative(result.arm_T_camera.compose(gtsam.Pose3(gtsam.Rot3.Rx(1.0), np.zeros(3))), 500.0)
    clear = copy.copy(result)
    clear.alternatives = [far]  # a clearly worse alternative leaves the result as it was
    assert not clear.ambiguous and clear.covariance_usable
    assert not make_report(clear, dataset).ambiguous
    ambiguous = copy.copy(result)
    ambiguous.alternatives = [far, Alternative(other, 0.5 * AMBIGUITY_CHI2, left_out=3, instead_of=1)]
    assert ambiguous.ambiguous and not ambiguous.covariance_usable
    assert "AMBIGUOUS" in summary(ambiguous)
    report = make_report(ambiguous, dataset)
    assert report.ambiguous and not report.covariance_usable and not report.determined.any()
    text = report.to_text()
    assert "AMBIGUOUS: 1 other pose" in text and "not determined" in text and "SUGGESTION: add" in text
    # the other pose is located in the words (its camera position in mm)
    assert f"{round(1000 * other.translation()[0], 1)}" in text
    assert json.loads(report.to_json())["ambiguous"] is True
    back = CalibrationResult.from_dict(json.loads(json.dumps(ambiguous.to_dict())))
    assert back.ambiguous and len(back.alternatives) == 2
    np.testing.assert_allclose(back.alternatives[1].arm_T_camera.matrix(), other.matrix(), atol=1e-12)
    assert back.alternatives[1].delta_chi2 == pytest.approx(0.5 * AMBIGUITY_CHI2)
    assert (back.alternatives[1].left_out, back.alternatives[1].instead_of) == (3, 1)
    assert back.alternatives[0].left_out is None and back.alternatives[0].instead_of is None


def test_joint_chi2_judges_the_solve_not_a_p_value(reference):
    """The joint graph's pixel noise comes from its own residuals: over ~1e4 residuals a P value would call a 2 %
    difference of χ²/dof from 1 inconsistent; the report judges χ²/dof within JOINT_REDUCED_TOLERANCE of 1."""
    from gtsam_rotid.report import JOINT_REDUCED_TOLERANCE, chi2_check

    dataset, _, _ = reference
    joint = calibrate(dataset, method="joint")
    check = chi2_check(joint)
    assert check.dof > 5000 and check.consistent is (abs(check.reduced - 1.0) <= JOINT_REDUCED_TOLERANCE)
    for factor, verdict in ((0.98, True), (1.02, True), (0.85, False), (1.2, False)):
        shifted = copy.copy(joint)
        shifted.final_error = 0.5 * factor * check.dof
        assert chi2_check(shifted).consistent is verdict, factor
    words = chi2_check(shifted).sentence()
    assert "INCONSISTENT: the residuals are larger" in words


def test_untrusted_result_is_reported_as_such_and_survives_json(reference):
    """A determined result whose covariance the estimator does not trust (``result.untrusted``) is not reported
    with usable 1-sigma: the words name the weak measurement, its evidence and what to do."""
    from gtsam_rotid.estimate import CalibrationResult

    dataset, _, result = reference
    assert result.covariance_usable and not result.untrusted
    untrusted = copy.deepcopy(result)
    untrusted.measurements[2].weak = True
    untrusted.measurements[2].arc_span_deg = 41.0
    untrusted.untrusted = {"thin_evidence": [2]}
    assert not untrusted.covariance_usable
    assert "COVARIANCE UNUSABLE" in summary(untrusted) and "measurement 2 (" in summary(untrusted)
    report = make_report(untrusted, dataset)
    assert not report.covariance_usable and not report.determined.any()
    text = report.to_text()
    assert "NOT TRUSTED" in text and "longest arc 41°" in text and "not the joint angles" in text
    assert "the arm poses do not determine" not in text  # it is not a degenerate set of poses
    data = json.loads(report.to_json())
    assert data["untrusted"] == ["thin_evidence"] and data["measurements"][2]["weak"] is True
    back = CalibrationResult.from_dict(json.loads(json.dumps(untrusted.to_dict())))
    assert back.untrusted == {"thin_evidence": [2]} and not back.covariance_usable and back.measurements[2].weak

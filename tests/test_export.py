"""Exports of arm_T_camera: the covariance conversion (checked by sampling) and a round trip per format."""

import argparse
import ast
import json
import re
import shlex
import xml.etree.ElementTree as ET
from dataclasses import replace

import gtsam
import numpy as np
import pytest
import yaml

from gtsam_rotid import InputError, OutputError, RotIdError
from gtsam_rotid.arm import Arm
from gtsam_rotid.calibration.result import Alternative, CalibrationResult
from gtsam_rotid.cli import add_export_parser, main
from gtsam_rotid.export import (
    ExportRefused,
    Transform,
    export_result,
    gtsam_covariance,
    load_result,
    ros_covariance,
)

#: YAML 1.1's float pattern (PyYAML's resolver): a YAML 1.1 loader reads only these as floats.
YAML11_FLOAT = re.compile(r"^[-+]?([0-9][0-9_]*)?\.[0-9.]*([eE][-+][0-9]+)?$")


@pytest.fixture(scope="module")
def recorded(reference_weighted):
    """A result that records its robot (the Jaco2: root link ``base``)."""
    return reference_weighted[2]


@pytest.fixture(scope="module")
def result(recorded):
    """The same as a result file of before the robot was recorded: any parent frame name is taken as given."""
    return replace(recorded, robot={})


# ---------------------------------------------------------------------------------------------------
# independent helpers (not the code under test)


def rx(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[1, 0, 0], [0, c, -s], [0, s, c]])


def ry(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])


def rz(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])


def rotation_from_quaternion(x, y, z, w):
    n = np.sqrt(x * x + y * y + z * z + w * w)
    x, y, z, w = x / n, y / n, z / n, w / n
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
        [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
        [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
    ])


def expected_ros_covariance(pose, covariance):
    """The conversion written out in the test: y = (R rho, R w) for xi = (w, rho)."""
    R = pose.rotation().matrix()
    J = np.block([[np.zeros((3, 3)), R], [R, np.zeros((3, 3))]])
    return J @ covariance @ J.T


def parse_yaml(text: str) -> dict:
    """A tiny parser for the YAML subset the exporter writes: comments, block mappings indented by two spaces,
    plain and double-quoted scalars, and flow sequences (possibly spanning lines)."""

    def scalar(token: str):
        token = token.strip()
        if token.startswith("["):
            inner = token[1:token.rindex("]")]
            return [scalar(t) for t in inner.split(",") if t.strip()]
        if token.startswith('"'):
            return json.loads(token)
        if token in ("true", "false"):
            return token == "true"
        if re.fullmatch(r"[-+]?[0-9]+", token):
            return int(token)
        if YAML11_FLOAT.match(token):
            return float(token)
        raise AssertionError(f"not a YAML scalar this parser knows: {token!r}")

    lines = [line for line in text.splitlines() if line.strip() and not line.lstrip().startswith("#")]
    merged, pending = [], None
    for line in lines:
        if pending is not None:
            pending += " " + line.strip()
            if "]" in line:
                merged.append(pending)
                pending = None
            continue
        _, _, rest = line.partition(":")
        if rest.strip().startswith("[") and "]" not in rest:
            pending = line.rstrip()
            continue
        merged.append(line)
    assert pending is None, "unterminated flow sequence"
    root: dict = {}
    stack = [(-1, root)]
    for line in merged:
        indent = len(line) - len(line.lstrip())
        key, _, rest = line.strip().partition(":")
        while stack[-1][0] >= indent:
            stack.pop()
        parent = stack[-1][1]
        if rest.strip():
            parent[key] = scalar(rest)
        else:
            parent[key] = {}
            stack.append((indent, parent[key]))
    return root


def pose_and_covariance_from_dict(data: dict):
    p, q = data["pose"]["position"], data["pose"]["orientation"]
    R = rotation_from_quaternion(q["x"], q["y"], q["z"], q["w"])
    return R, np.array([p["x"], p["y"], p["z"]]), np.array(data["covariance"]).reshape(6, 6)


# ---------------------------------------------------------------------------------------------------
# the covariance conversion


def random_covariance(rng, sigmas):
    A = rng.normal(size=(6, 6))
    C = A @ A.T + 6 * np.eye(6)
    d = np.sqrt(np.diag(C))
    return (C / np.outer(d, d)) * np.outer(sigmas, sigmas)


def sampled_ros_errors(pose, covariance, rng, n, child=None):
    """Sample xi ~ N(0, Sigma) in GTSAM's tangent, perturb with GTSAM's own retract, and measure the errors the
    ROS layout defines: (t_sample - t, Log(R_sample R^T)), in the parent frame."""
    child = gtsam.Pose3() if child is None else child
    nominal = pose.compose(child)
    R0 = nominal.rotation().matrix()
    t0 = nominal.translation()
    L = np.linalg.cholesky(covariance)
    out = np.empty((n, 6))
    for i, xi in enumerate(rng.normal(size=(n, 6)) @ L.T):
        sample = pose.retract(xi).compose(child)
        out[i, :3] = sample.translation() - t0
        out[i, 3:] = gtsam.Rot3.Logmap(gtsam.Rot3(sample.rotation().matrix() @ R0.T))
    return out


def assert_covariance_close(sample_cov, expected, tolerance):
    """Whitened comparison: W S W^T = I for W = expected^-1/2, entry by entry within ``tolerance``."""
    w, V = np.linalg.eigh(expected)
    W = V @ np.diag(w**-0.5) @ V.T
    np.testing.assert_allclose(W @ sample_cov @ W.T, np.eye(6), atol=tolerance)


def test_ros_covariance_matches_sampled_gtsam_perturbations():
    rng = np.random.default_rng(3)
    pose = gtsam.Pose3(gtsam.Rot3.RzRyRx(0.4, -1.1, 2.5), np.array([0.3, -0.7, 1.2]))
    covariance = random_covariance(rng, np.array([2e-3, 1e-3, 3e-3, 2e-3, 4e-3, 1e-3]))
    errors = sampled_ros_errors(pose, covariance, rng, 20000)
    converted = ros_covariance(pose, covariance)
    assert_covariance_close(np.cov(errors.T), converted, 0.05)
    # the conversion is not the identity or a plain permutation: the sample tells them apart
    with pytest.raises(AssertionError):
        assert_covariance_close(np.cov(errors.T), covariance[[3, 4, 5, 0, 1, 2]][:, [3, 4, 5, 0, 1, 2]], 0.05)
    np.testing.assert_allclose(converted, expected_ros_covariance(pose, covariance), atol=1e-18)
    np.testing.assert_allclose(gtsam_covariance(pose, converted), covariance, atol=1e-18)


def test_body_frame_child_keeps_the_parent_frame_covariance():
    """Turning the child frame by a fixed rotation changes the pose but not the parent-frame covariance."""
    rng = np.random.default_rng(4)
    pose = gtsam.Pose3(gtsam.Rot3.RzRyRx(-0.3, 0.2, 1.0), np.array([-0.5, 0.2, 0.9]))
    covariance = random_covariance(rng, np.array([1e-3, 2e-3, 1e-3, 3e-3, 1e-3, 2e-3]))
    optical_T_body = gtsam.Pose3(gtsam.Rot3(np.array([[0, -1, 0], [0, 0, -1], [1, 0, 0.0]])), np.zeros(3))
    errors = sampled_ros_errors(pose, covariance, rng, 20000, child=optical_T_body)
    assert_covariance_close(np.cov(errors.T), ros_covariance(pose, covariance), 0.05)


def test_covariance_shape_is_checked():
    with pytest.raises(InputError, match="6x6"):
        ros_covariance(gtsam.Pose3(), np.eye(5))


# ---------------------------------------------------------------------------------------------------
# round trips


def test_json_round_trip(result):
    data = json.loads(export_result(result, "json"))
    R, t, cov = pose_and_covariance_from_dict(data)
    np.testing.assert_allclose(R, result.arm_T_camera.rotation().matrix(), atol=1e-12)
    np.testing.assert_allclose(t, result.arm_T_camera.translation(), atol=1e-12)
    np.testing.assert_allclose(cov, expected_ros_covariance(result.arm_T_camera, result.covariance), rtol=1e-12,
                               atol=1e-20)
    np.testing.assert_allclose(gtsam_covariance(result.arm_T_camera, cov), result.covariance, rtol=1e-9, atol=1e-18)
    assert (data["parent_frame"], data["child_frame"]) == ("base_link", "camera_optical_frame")
    assert data["covariance_usable"] is True
    assert data["pose"]["orientation"]["w"] >= 0
    np.testing.assert_allclose(rz(data["rpy"][2]) @ ry(data["rpy"][1]) @ rx(data["rpy"][0]), R, atol=1e-12)


def test_yaml_round_trip_and_yaml11_floats(result):
    text = export_result(result, "yaml", parent_frame="root", child_frame="xtion_rgb_optical_frame")
    data = parse_yaml(text)
    assert data == json.loads(export_result(result, "json", parent_frame="root",
                                            child_frame="xtion_rgb_optical_frame"))
    R, t, cov = pose_and_covariance_from_dict(data)
    np.testing.assert_allclose(R, result.arm_T_camera.rotation().matrix(), atol=1e-12)
    np.testing.assert_allclose(t, result.arm_T_camera.translation(), atol=1e-15)
    np.testing.assert_allclose(cov, expected_ros_covariance(result.arm_T_camera, result.covariance), rtol=1e-12,
                               atol=1e-20)
    assert (data["parent_frame"], data["child_frame"]) == ("root", "xtion_rgb_optical_frame")
    # every number in the covariance reads as a float in YAML 1.1 too (1e-05 would be a string there)
    block = text[text.index("covariance: ["):]
    block = block[:block.index("]") + 1]
    numbers = re.findall(r"[-+0-9.eE]+", block[block.index("[") + 1:])
    assert len(numbers) == 36
    assert all(YAML11_FLOAT.match(n) for n in numbers)


def test_urdf_round_trip(result):
    text = export_result(result, "urdf", parent_frame="j2s6s200_link_base", joint_name="xtion_joint")
    joint = ET.fromstring(text[text.index("<joint"):])  # after the comment line
    assert joint.get("name") == "xtion_joint" and joint.get("type") == "fixed"
    assert joint.find("parent").get("link") == "j2s6s200_link_base"
    assert joint.find("child").get("link") == "camera_optical_frame"
    origin = joint.find("origin")
    xyz = np.array(origin.get("xyz").split(), dtype=float)
    roll, pitch, yaw = np.array(origin.get("rpy").split(), dtype=float)
    np.testing.assert_allclose(xyz, result.arm_T_camera.translation(), atol=1e-11)
    np.testing.assert_allclose(rz(yaw) @ ry(pitch) @ rx(roll), result.arm_T_camera.rotation().matrix(), atol=1e-10)


def test_urdf_body_frame_points_x_along_the_optical_axis(result):
    text = export_result(result, "urdf", camera_frame="body")
    origin = ET.fromstring(text[text.index("<joint"):]).find("origin")
    assert 'link="camera_link"' in text
    roll, pitch, yaw = np.array(origin.get("rpy").split(), dtype=float)
    R_body = rz(yaw) @ ry(pitch) @ rx(roll)
    R_optical = result.arm_T_camera.rotation().matrix()
    np.testing.assert_allclose(R_body[:, 0], R_optical[:, 2], atol=1e-10)  # body x = forward = optical z
    np.testing.assert_allclose(R_body[:, 1], -R_optical[:, 0], atol=1e-10)  # body y = left = -optical x
    np.testing.assert_allclose(R_body[:, 2], -R_optical[:, 1], atol=1e-10)  # body z = up = -optical y


def test_ros2_command_round_trip(result):
    text = export_result(result, "ros2", parent_frame="base_link", child_frame="camera_color_optical_frame")
    argv = shlex.split(text)
    assert argv[:4] == ["ros2", "run", "tf2_ros", "static_transform_publisher"]
    parser = argparse.ArgumentParser()
    for flag in ("--x", "--y", "--z", "--qx", "--qy", "--qz", "--qw"):
        parser.add_argument(flag, type=float, required=True)
    parser.add_argument("--frame-id", required=True)
    parser.add_argument("--child-frame-id", required=True)
    args = parser.parse_args(argv[4:])  # every argument is a known Humble+ flag
    np.testing.assert_allclose([args.x, args.y, args.z], result.arm_T_camera.translation(), atol=1e-11)
    np.testing.assert_allclose(rotation_from_quaternion(args.qx, args.qy, args.qz, args.qw),
                               result.arm_T_camera.rotation().matrix(), atol=1e-10)
    assert (args.frame_id, args.child_frame_id) == ("base_link", "camera_color_optical_frame")


def test_matrix_round_trip(result):
    M = np.loadtxt(export_result(result, "matrix").splitlines())
    np.testing.assert_allclose(M, result.arm_T_camera.matrix(), atol=1e-11)


def test_frame_names_are_checked(result):
    with pytest.raises(InputError, match="frame"):
        export_result(result, "urdf", child_frame='cam"era')
    with pytest.raises(InputError, match="differ"):
        export_result(result, "json", parent_frame="x", child_frame="x")
    with pytest.raises(InputError, match="format"):
        Transform.from_result(result).to_text("csv")


# ---------------------------------------------------------------------------------------------------
# command line


def run_export(argv):
    parser = argparse.ArgumentParser(prog="gtsam-rotid")
    add_export_parser(parser.add_subparsers(dest="command"))
    args = parser.parse_args(["export", *argv])
    return args.func(args)


def test_cli_export_to_stdout_and_file(result, tmp_path, capsys):
    path = tmp_path / "result.json"
    result.save(path)
    assert run_export([str(path), "--to", "matrix"]) == 0
    np.testing.assert_allclose(np.loadtxt(capsys.readouterr().out.splitlines()), result.arm_T_camera.matrix(),
                               atol=1e-11)
    out = tmp_path / "camera.yaml"
    assert run_export([str(path), "--to", "yaml", "-o", str(out), "--parent", "world"]) == 0
    assert f"wrote {out}" in capsys.readouterr().out
    data = parse_yaml(out.read_text())
    assert data["parent_frame"] == "world"
    before = out.read_text()
    with pytest.raises(OutputError, match="overwrite"):
        run_export([str(path), "--to", "json", "-o", str(out)])
    assert out.read_text() == before
    assert run_export([str(path), "--to", "json", "-o", str(out), "--overwrite"]) == 0
    assert json.loads(out.read_text())["parent_frame"] == "base_link"


def test_cli_export_errors_are_typed(tmp_path):
    with pytest.raises(InputError, match="no such file"):
        run_export([str(tmp_path / "missing.json"), "--to", "json"])
    bad = tmp_path / "bad.json"
    bad.write_text("{not json")
    with pytest.raises(InputError, match="not valid JSON"):
        run_export([str(bad), "--to", "json"])
    other = tmp_path / "other.json"
    other.write_text('{"format": "something else"}')
    with pytest.raises(RotIdError, match="not a gtsam_rotid calibration result"):
        run_export([str(other), "--to", "json"])
    with pytest.raises(OutputError, match="does not exist"):
        run_export([str(other), "--to", "json", "-o", str(tmp_path / "no" / "x.json")])


def unfit(result):
    """Results not fit to export, each with the words its refusal must use."""
    return {
        "untrusted": (replace(result, untrusted={"thin_evidence": [2]}), "not to be trusted (thin_evidence: "
                      "measurement(s) 2"),
        "nan": (replace(result, covariance=np.full((6, 6), np.nan)), "the covariance has NaN or infinite entries"),
        "ambiguous": (replace(result, alternatives=[Alternative(result.arm_T_camera, 0.5)]), "ambiguous"),
        "not converged": (replace(result, converged=False), "the solver did not converge"),
    }


@pytest.mark.parametrize("case", ["untrusted", "nan", "ambiguous", "not converged"])
def test_a_result_unfit_to_export_is_refused_unless_forced_and_then_says_so(result, case, tmp_path, capsys):
    bad, words = unfit(result)[case]
    for fmt in ("yaml", "json", "urdf", "ros2", "matrix"):
        with pytest.raises(ExportRefused, match=re.escape(words) + ".*--force"):
            export_result(bad, fmt)
        text = export_result(bad, fmt, force=True)
        assert "WARNING: exported although " in text and words in text
    assert any(words in w for w in json.loads(export_result(bad, "json", force=True))["warnings"])
    assert any(words in w for w in yaml.safe_load(export_result(bad, "yaml", force=True))["warnings"])
    if case != "nan":  # the forced files still read back
        np.testing.assert_allclose(np.loadtxt(export_result(bad, "matrix", force=True).splitlines()),
                                   result.arm_T_camera.matrix(), atol=1e-11)
        ET.fromstring("<robot>" + export_result(bad, "urdf", force=True) + "</robot>")
    assert "warnings" not in json.loads(export_result(result, "json"))  # a fit result carries none
    path, out = tmp_path / "result.json", tmp_path / "camera.yaml"
    bad.save(path)
    assert main(["export", str(path), "--to", "yaml", "-o", str(out)]) == 1
    assert "--force" in capsys.readouterr().err and not out.exists()  # nothing written
    assert main(["export", str(path), "--to", "yaml", "-o", str(out), "--force"]) == 0
    assert "warning: exported although" in capsys.readouterr().err and "WARNING" in out.read_text()


@pytest.mark.parametrize("change, words", [
    (lambda M: M @ np.diag([1.1, 1.0, 1.0, 1.0]), "not orthonormal"),
    (lambda M: M @ np.diag([-1.0, 1.0, 1.0, 1.0]), "reflection"),
    (lambda M: M + np.array([[0, 0, 0, 0]] * 3 + [[0, 0, 0.5, 0]]), "last row"),
])
def test_a_result_file_whose_pose_is_not_rigid_is_refused_by_name(result, tmp_path, change, words):
    data = result.to_dict()
    data["arm_T_camera"] = change(np.array(data["arm_T_camera"])).tolist()
    path = tmp_path / "result.json"
    path.write_text(json.dumps(data))
    with pytest.raises(InputError, match=f"result.json: arm_T_camera is not a rigid transform: .*{words}"):
        load_result(path)
    assert CalibrationResult.from_dict(result.to_dict()).arm_T_camera.equals(result.arm_T_camera, 1e-12)


def test_the_parent_is_the_robots_root_link_or_a_link_fixed_to_it(recorded):
    arm = Arm.from_robot("kinova")
    assert recorded.robot["root_link"] == arm.root_link == "base" and recorded.robot["name"] == "kinova"
    data = json.loads(export_result(recorded, "json"))
    assert data["parent_frame"] == "base"
    R, t, _ = pose_and_covariance_from_dict(data)
    np.testing.assert_allclose(t, recorded.arm_T_camera.translation(), atol=1e-12)
    # the arm's base link is turned 90 degrees about z from the root: the pose is re-expressed in it
    link = json.loads(export_result(recorded, "json", parent_frame="j2s6s200_link_base"))
    R_link, t_link, _ = pose_and_covariance_from_dict(link)
    root_T_link = arm.static_links()["j2s6s200_link_base"]
    np.testing.assert_allclose(root_T_link.compose(gtsam.Pose3(gtsam.Rot3(R_link), t_link)).matrix(),
                               recorded.arm_T_camera.matrix(), atol=1e-10)
    assert not np.allclose(R_link, R, atol=1e-3)
    with pytest.raises(InputError, match="no link 'base_link' fixed to its root 'base'.*j2s6s200_link_base"):
        export_result(recorded, "yaml", parent_frame="base_link")
    with pytest.raises(InputError, match="moves with the arm"):
        export_result(recorded, "yaml", parent_frame="j2s6s200_link_3")
    assert json.loads(export_result(recorded.from_dict({**recorded.to_dict(), "robot": {}}), "json"))[
        "parent_frame"] == "base_link"  # a result file that records no robot


def test_the_camera_drivers_transform_is_composed_with_its_covariance(recorded):
    rng = np.random.default_rng(7)
    link_T_optical = gtsam.Pose3(gtsam.Rot3.RzRyRx(-1.2, 0.3, -1.4), np.array([0.3, -0.2, 0.4]))  # a long lever
    covariance = random_covariance(rng, np.array([2e-3, 1e-3, 3e-3, 2e-3, 4e-3, 1e-3]))
    wide = replace(recorded, covariance=covariance)
    data = json.loads(export_result(wide, "json", driver=("camera_link", link_T_optical)))
    assert (data["parent_frame"], data["child_frame"]) == ("base", "camera_link")
    R, t, ros = pose_and_covariance_from_dict(data)
    parent_T_link = gtsam.Pose3(gtsam.Rot3(R), t)
    np.testing.assert_allclose(parent_T_link.compose(link_T_optical).matrix(), recorded.arm_T_camera.matrix(),
                               atol=1e-10)
    errors = sampled_ros_errors(recorded.arm_T_camera, covariance, rng, 20000, child=link_T_optical.inverse())
    assert_covariance_close(np.cov(errors.T), ros, 0.05)
    with pytest.raises(AssertionError):  # the driver's lever arm and turn matter: not the optical frame's
        assert_covariance_close(np.cov(errors.T), ros_covariance(recorded.arm_T_camera, covariance), 0.05)
    with pytest.raises(InputError, match="child frame is its link"):
        export_result(wide, "json", driver=("camera_link", link_T_optical), camera_frame="body")


def test_easy_handeye_and_launch_files(recorded):
    data = yaml.safe_load(export_result(recorded, "easy_handeye"))
    p, tr = data["parameters"], data["transformation"]
    assert p["eye_on_hand"] is False and p["robot_base_frame"] == "base"
    assert p["tracking_base_frame"] == "camera_optical_frame" and p["robot_effector_frame"] == "j2s6s200_end_effector"
    np.testing.assert_allclose([tr["x"], tr["y"], tr["z"]], recorded.arm_T_camera.translation(), atol=1e-11)
    np.testing.assert_allclose(rotation_from_quaternion(tr["qx"], tr["qy"], tr["qz"], tr["qw"]),
                               recorded.arm_T_camera.rotation().matrix(), atol=1e-10)
    text = export_result(recorded, "launch")
    tree = ast.parse(text)  # a Python launch file
    call = next(n for n in ast.walk(tree) if isinstance(n, ast.Call) and getattr(n.func, "id", "") == "Node")
    keywords = {k.arg: ast.literal_eval(k.value) for k in call.keywords}
    assert keywords["package"] == "tf2_ros" and keywords["executable"] == "static_transform_publisher"
    args = keywords["arguments"]
    values = {args[i]: args[i + 1] for i in range(0, len(args), 2)}
    assert (values["--frame-id"], values["--child-frame-id"]) == ("base", "camera_optical_frame")
    np.testing.assert_allclose([float(values[k]) for k in ("--x", "--y", "--z")],
                               recorded.arm_T_camera.translation(), atol=1e-11)


def test_the_command_line_takes_the_driver_and_the_report_finds_the_dataset(noisy_scene, tmp_path, capsys):
    dataset, _ = noisy_scene
    folder = tmp_path / "ds"
    dataset.save(folder)
    result_path = tmp_path / "result.json"
    assert main(["calibrate", str(folder), "-o", str(result_path)]) == 0
    saved = load_result(result_path)
    assert saved.dataset["path"] == str(folder.resolve()) and len(saved.dataset["sha256"]) == 64
    capsys.readouterr()
    assert main(["export", str(result_path), "--to", "urdf", "--driver", "camera_link", "0.01", "0", "0.02",
                 "0", "0", "0", "1"]) == 0
    assert 'child link="camera_link"' in capsys.readouterr().out
    assert main(["export", str(result_path), "--to", "urdf", "--driver", "camera_link", "0", "0", "0",
                 "0", "0", "0", "2"]) == 1
    assert "not of unit length" in capsys.readouterr().err
    assert main(["report", str(result_path)]) == 0
    assert f"dataset {folder.resolve()} (recorded in the result)" in capsys.readouterr().err
    with open(folder / "dataset.json", "a") as handle:
        handle.write(" ")
    assert main(["report", str(result_path)]) == 0
    assert "changed since the calibration; not used" in capsys.readouterr().err


def test_a_damaged_robot_record_a_robot_link_as_child_and_a_bad_covariance_are_refused(recorded):
    damaged = replace(recorded, robot={**recorded.robot, "static_links": {
        **recorded.robot["static_links"], "j2s6s200_link_base": (2.0 * np.eye(4)).tolist()}})
    with pytest.raises(InputError, match="record of the link 'j2s6s200_link_base' is not a rigid transform"):
        export_result(damaged, "yaml", parent_frame="j2s6s200_link_base")
    with pytest.raises(InputError, match="'j2s6s200_link_4' is a link of the robot"):
        export_result(recorded, "yaml", child_frame="j2s6s200_link_4")
    with pytest.raises(InputError, match="is a link of the robot"):
        export_result(recorded, "yaml", driver=("j2s6s200_end_effector", gtsam.Pose3()))
    negative = replace(recorded, covariance=-recorded.covariance)
    with pytest.raises(ExportRefused, match="not positive semi-definite"):
        export_result(negative, "json")
    with pytest.raises(ExportRefused, match="not 6x6"):
        export_result(replace(recorded, covariance=np.eye(5)), "matrix")

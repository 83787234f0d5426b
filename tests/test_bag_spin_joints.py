"""A ROS bag holding spins of two joints at each arm pose (the joint before the wrist, then the wrist): with
``spin_joints`` (``track --bag --spin-joints``) each spin is a measurement of its own joint, with that joint's
readings, and the dataset calibrates with the offsets refined; without, the wrist's spins alone, and a note names
the other joint's."""

from __future__ import annotations

import numpy as np
import pytest
from bag_scene import FPS, write_bag

from gtsam_rotid import simulate
from gtsam_rotid.bagdataset import dataset_from_bag
from gtsam_rotid.calibration import CalibrationOptions
from gtsam_rotid.cli import main
from gtsam_rotid.dataset import Dataset
from gtsam_rotid.errors import InputError
from gtsam_rotid.estimate import calibrate
from gtsam_rotid.render import RenderedSpin, dot_covering
from gtsam_rotid.renderconfig import RenderConfig

OFFSET_S = 0.071
CHI2_6_999 = 22.458


@pytest.fixture(scope="module")
def two_joint_bag(tmp_path_factory):
    """Four arm poses, each spun about the Jaco2's joint 5 and then its wrist (joint 6), 4 s each, rendered dots:
    the renderer's dotted cylinder coaxial with the spinning joint (for joint 5 a stand-in for the hand, which
    render_measurement refuses to draw: its circles about that joint's axis are what the calibration needs)."""
    dataset, truth = simulate.reference_scene(seed=5, duration=4.0, fps=FPS, n_measurements=4,
                                              spin_joints=("j2s6s200_joint_5", "j2s6s200_joint_6"))
    config = RenderConfig(seed=5)
    spins = []
    for k, mt in enumerate(truth.measurements):
        frames = np.arange(len(mt.spin_angles))
        spins.append(RenderedSpin(k, dataset.camera, truth.arm_T_camera.inverse(), mt.axis_point, mt.axis_direction,
                                  mt.e1, mt.e2, mt.spin_angles, frames, dot_covering(config), config, FPS))
    path = write_bag(tmp_path_factory.mktemp("bag") / "two", "sqlite3", dataset, spins, offset_s=OFFSET_S)
    return dataset, truth, path


def test_spins_of_two_joints_in_one_bag_are_measurements_of_their_own_joints(two_joint_bag, capsys):
    dataset, truth, path = two_joint_bag
    arm = dataset.arm
    j5, j6 = arm.joint_names[4], arm.joint_names[5]
    made = dataset_from_bag(path, arm, spin_joints=[j5, j6], progress=False)
    assert [m.spin_joint for m in made] == [j5, None] * 4
    assert made.metadata["recording"]["spin_joints"] == [j5, j6] * 4
    for ours, theirs, span in zip(made, dataset, made.metadata["recording"]["spans"], strict=True):
        np.testing.assert_allclose(ours.joint_angles, theirs.joint_angles, atol=1e-9)  # still joints; the spun one
        readings = ours.spin_readings  # at its start; the readings are the spun joint's (4 s at 0.5 rad/s)
        inside = (readings.times >= span[0]) & (readings.times <= span[1])
        assert np.ptp(readings.angles[inside]) == pytest.approx(4.0 * 0.5, rel=0.05)
        assert len(ours.tracks) >= 4
    assert abs(made.metadata["recording"]["time_offset_s"] - OFFSET_S) < 0.1 / FPS
    result = calibrate(made, options=CalibrationOptions(joint_offsets=True))
    error = result.error_to(truth.arm_T_camera)
    assert result.covariance_usable, result.untrusted
    assert float(error @ np.linalg.solve(result.covariance, error)) < CHI2_6_999
    assert np.allclose(list(result.joint_offsets.values()), 0.0, atol=np.radians(0.3))  # exact kinematics

    wrist_only = dataset_from_bag(path, arm, progress=False)  # the default: the wrist's spins alone
    assert len(wrist_only) == 4 and all(m.spin_joint is None for m in wrist_only)
    assert f"{j5!r} turned alone 4 time(s)" in capsys.readouterr().err


def test_the_track_command_reads_spins_of_named_joints_and_refuses_a_joint_the_arm_has_not(two_joint_bag, tmp_path,
                                                                                            capsys):
    dataset, _, path = two_joint_bag
    j5, j6 = dataset.arm.joint_names[4], dataset.arm.joint_names[5]
    out = tmp_path / "d"
    assert main(["track", "--bag", str(path), "--robot", "kinova", "--spin-joints", j5, j6, "-o", str(out),
                 "--no-progress"]) == 0
    assert f"8 spin(s) (4 of {j5}, 4 of {j6})" in capsys.readouterr().out
    assert [m.spin_joint for m in Dataset.load(out)] == [j5, None] * 4
    with pytest.raises(InputError, match="spin_joints: spinning joint 'elbow' is not a revolute joint"):
        dataset_from_bag(path, dataset.arm, spin_joints=["elbow"], progress=False)
    with pytest.raises(InputError, match="names a joint more than once"):
        dataset_from_bag(path, dataset.arm, spin_joints=[j5, j5], progress=False)
    j3 = dataset.arm.joint_names[2]  # named, but it never spins in this bag: said, not left out quietly
    assert [m.spin_joint for m in dataset_from_bag(path, dataset.arm, spin_joints=[j3, j5], progress=False)] == [j5] * 4
    err = capsys.readouterr().err
    assert f"no spin of {j3!r}" in err and f"the dataset holds the spins of {j5!r} only" in err
    assert main(["track", "--bag", str(path), "--robot", "kinova", "--spin-joints", "elbow", "-o",
                 str(tmp_path / "e"), "--no-progress"]) == 1
    assert "'elbow' is not a revolute joint" in capsys.readouterr().err
    assert not (tmp_path / "e").exists()

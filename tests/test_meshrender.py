"""The mesh renderer (gtsam_rotid.meshrender) against ground truth computed independently (Arm kinematics,
Camera.project), and its determinism, moving region, coverings, renderability checks and config validation."""

from __future__ import annotations

import gtsam
import numpy as np
import pytest
from urdf_arm import URDF_3_JOINTS

from gtsam_rotid import ArmError, InputError, Track, simulate
from gtsam_rotid import meshrender as mr
from gtsam_rotid.arm import Arm
from gtsam_rotid.geometry import look_at


@pytest.fixture(scope="module")
def scene():
    dataset, truth = simulate.reference_scene(0, duration=1.0)  # 30 frames per spin
    return dataset, truth, mr.load_arm_meshes(dataset.arm)


@pytest.fixture(scope="module")
def spin(scene):
    dataset, truth, meshes = scene
    return mr.render_mesh_measurement(dataset, truth, 0, mr.MeshRenderConfig(noise_sigma=0.0), meshes=meshes)


def _hand_pixels(spin, frame=0, count=40, seed=0):
    ys, xs = np.nonzero(spin.moving_mask(frame))
    pick = np.random.default_rng(seed).choice(len(xs), size=min(count, len(xs)), replace=False)
    return np.column_stack([xs[pick], ys[pick]]).astype(float)


def test_surface_points_project_through_the_arm_kinematics(scene, spin):
    dataset, truth, _ = scene
    arm, camera = dataset.arm, dataset.camera
    pixels = _hand_pixels(spin)
    points = spin.surface_points(0, pixels)
    assert np.all(np.isfinite(points))
    frames = np.array([0, 7, 19, 29])
    projected, visible = spin.project_points(points, frames)
    assert projected.shape == (4, len(points), 2) and visible.shape == (4, len(points))
    # frame 0: the points project back onto the pixels they were cast from, and are seen
    assert np.max(np.abs(projected[0] - pixels)) < 1e-4
    assert visible[0].mean() > 0.9
    # independently: camera_T_arm * arm_T_link(q with the wrist turned by the spin) * p
    mt = truth.measurements[0]
    camera_T_arm = truth.arm_T_camera.inverse()
    for row, f in enumerate(frames):
        q = np.array(mt.joint_angles, dtype=float)
        q[arm.wrist_index] += mt.spin_angles[f]
        arm_T_link = arm.arm_T_joint(q, arm.wrist_joint)
        expected = camera.project(np.array([camera_T_arm.transformFrom(arm_T_link.transformFrom(p)) for p in points]))
        np.testing.assert_allclose(projected[row], expected, atol=1e-6)
        link = spin.arm_T_link(int(f))
        assert np.allclose(link.matrix(), arm_T_link.matrix())
    # the wrist origin sits on the simulator's axis
    assert np.allclose(spin.arm_T_link(0).translation(), mt.axis_point, atol=1e-9)


def test_background_pixels_see_no_spinning_link(spin):
    region = spin.moving_region()
    ys, xs = np.nonzero(~region)
    pixels = np.column_stack([xs[::997], ys[::997]]).astype(float)
    assert np.all(np.isnan(spin.surface_points(3, pixels)))
    mask = spin.moving_mask(3)
    assert mask.any() and not np.any(mask & ~region)


def test_track_errors_of_exact_tracks_are_zero(spin):
    points = spin.surface_points(0, _hand_pixels(spin, count=12, seed=1))
    frames = np.arange(30)
    projected, visible = spin.project_points(points, frames)
    tracks = []
    for j in range(len(points)):
        run = np.flatnonzero(visible[:, j])
        run = run[: np.argmax(np.diff(np.append(run, -9)) != 1) + 1]  # the first run of visible frames
        if len(run) >= 8:
            tracks.append(Track(projected[run, j], frames[run]))
    assert len(tracks) >= 5
    # two tracks exact for their first 5 points (which locate the surface point), then 0.5 px off
    shifted = [Track(t.pixels + np.where(np.arange(len(t))[:, None] < 5, 0.0, [0.3, 0.4]), t.frames)
               for t in tracks[:2]]
    background = Track(np.array([[2.0, 2.0], [3.0, 2.0], [4.0, 2.0]]), np.array([0, 1, 2]))
    result = mr.track_errors(tracks + shifted + [background], spin)
    exact = slice(0, len(tracks))
    assert np.all(result.on_links[exact])
    assert np.nanmax(result.rms_px[exact]) < 1e-3
    assert np.all(result.n_compared[exact] == [len(t) for t in tracks])
    np.testing.assert_allclose(result.median_px[len(tracks):-1], 0.5, atol=1e-3)
    assert list(result.off_links) == [len(tracks) + 2]
    assert result.pooled_rms_px > 0 and np.isfinite(result.pooled_median_px)
    # exact tracks are rigid points' tracks; the whole-track fit absorbs nothing more than it should
    assert np.nanmax(result.rigid_rms_px[exact]) < 1e-3
    # a track whose first points (which locate the truth) are off, the rest exact: the located point is wrong,
    # so its error grows along the track, while the track itself is a rigid point's track but for those points
    t = max(tracks, key=len)
    early = Track(t.pixels + np.where(np.arange(len(t))[:, None] < 5, [0.6, -0.4], 0.0), t.frames)
    located = mr.track_errors([early], spin)
    assert located.rigid_rms_px[0] < 0.5 * located.rms_px[0], (located.rigid_rms_px, located.rms_px)
    assert located.rigid_rms_px[0] <= np.sqrt(5 / len(t)) * 0.73 + 1e-3   # at most the 5 points' own offset


def test_a_frame_renders_the_same_alone_or_in_sequence(scene):
    dataset, truth, meshes = scene
    config = mr.MeshRenderConfig(covering="fabric", noise_sigma=3.0, supersample=1)
    full = mr.render_mesh_measurement(dataset, truth, 1, config, meshes=meshes, frames=slice(0, 6))
    sequence = list(full.frames())
    alone = mr.render_mesh_measurement(dataset, truth, 1, config, meshes=meshes, frames=[5])
    assert np.array_equal(alone.frame(0), sequence[5])
    assert np.array_equal(full.frame(5), sequence[5])
    assert sequence[5].dtype == np.uint8 and sequence[5].shape == (480, 640)
    colour = full.frame(2, color=True)
    assert colour.shape == (480, 640, 3)
    assert not np.array_equal(sequence[4], sequence[5])


def test_the_moving_region_holds_every_changing_pixel(scene, spin):
    a, b = spin.frame(0, color=True), spin.frame(12, color=True)
    changed = np.any(a != b, axis=2)
    assert changed.sum() > 200
    assert not np.any(changed & ~spin.moving_region())
    # motion blur also changes only the moving region, and differs from the sharp frame
    dataset, truth, meshes = scene
    blurred = mr.render_mesh_measurement(dataset, truth, 0, spin.config.with_(exposure=1.0, blur_samples=3),
                                         meshes=meshes, frames=[12])
    c = blurred.frame(0, color=True)
    diff = np.any(c != b, axis=2)
    assert diff.any() and not np.any(diff & ~spin.moving_region())


def test_every_covering_renders_and_differs_on_the_hand(scene):
    import cv2

    dataset, truth, meshes = scene
    images, variance = {}, {}  # variance: median |high-pass| on the hand
    mask = None
    for covering in mr.COVERINGS:
        config = mr.MeshRenderConfig(covering=covering, noise_sigma=0.0, supersample=1, specular=0.0)
        s = mr.render_mesh_measurement(dataset, truth, 0, config, meshes=meshes, frames=[0])
        if mask is None:
            mask = cv2.erode(s.moving_mask(0).astype(np.uint8), np.ones((5, 5), np.uint8)).astype(bool)
        grey = s.frame(0).astype(float)
        images[covering] = grey
        detail = grey - cv2.GaussianBlur(grey, (0, 0), 1.5)
        variance[covering] = float(np.median(np.abs(detail[mask])))  # robust to the shape's own edges
    assert mask.sum() > 500
    for i, a in enumerate(mr.COVERINGS):
        for b in mr.COVERINGS[i + 1:]:
            assert np.mean(np.abs(images[a][mask] - images[b][mask]) > 5.0) > 0.02, (a, b)
    for covering in ("photo", "text", "fabric"):
        assert variance[covering] > 3.0 * variance["plain"], variance
    # half the texture: the plain part equals the plain rendering on some hand pixels, the photo on others
    config = mr.MeshRenderConfig(covering="photo", covered_fraction=0.5, noise_sigma=0.0, supersample=1,
                                 specular=0.0)
    half = mr.render_mesh_measurement(dataset, truth, 0, config, meshes=meshes, frames=[0]).frame(0).astype(float)
    same_plain = np.abs(half[mask] - images["plain"][mask]) < 0.5
    same_photo = np.abs(half[mask] - images["photo"][mask]) < 0.5
    assert same_plain.mean() > 0.03 and same_photo.mean() > 0.3 and (same_plain | same_photo).mean() > 0.95


def test_unrenderable_poses_are_named(scene):
    dataset, truth, meshes = scene
    arm, camera = dataset.arm, dataset.camera
    q = truth.measurements[0].joint_angles
    assert mr.pose_problem(arm, camera, truth.arm_T_camera, q, meshes=meshes) is None
    wrist = arm.wrist_axis(q)
    inside = look_at(wrist.point + 0.01 * wrist.direction, wrist.point + 0.5 * wrist.direction + [0, 0, 0.1])
    assert "inside" in mr.pose_problem(arm, camera, inside, q, meshes=meshes)
    away = look_at(truth.arm_T_camera.translation(), 2 * truth.arm_T_camera.translation() - wrist.point)
    problem = mr.pose_problem(arm, camera, away, q, meshes=meshes)
    assert problem is not None and "behind the camera" in problem
    moved = simulate.GroundTruth(away, truth.measurements, truth.config)
    with pytest.raises(InputError, match="measurement 2: .*behind the camera"):
        mr.render_mesh_measurement(dataset, moved, 2, meshes=meshes)


def test_config_validation_names_the_field():
    for field, value in (("covering", "velvet"), ("covered_fraction", 0.0), ("covered_fraction", 1.5),
                         ("supersample", 0), ("supersample", 2.5), ("exposure", -0.1), ("blur_samples", 0),
                         ("noise_sigma", -1.0), ("hand_color", (300, 0, 0)), ("arm_color", "red"),
                         ("background", "sky"), ("background_distance", 0.0), ("light_direction", (0, 0, 0)),
                         ("texel_mm", -1.0), ("seed", -1), ("floor", "yes"), ("min_visible_fraction", 2.0)):
        with pytest.raises(InputError, match=f"MeshRenderConfig.{field}"):
            mr.MeshRenderConfig(**{field: value})
    assert mr.MeshRenderConfig().with_(covering="dots").covering == "dots"


def test_bad_inputs_raise_typed_errors(scene, spin):
    dataset, truth, meshes = scene
    with pytest.raises(InputError, match="measurement index"):
        mr.render_mesh_measurement(dataset, truth, 6, meshes=meshes)
    with pytest.raises(InputError, match="frame number"):
        spin.surface_points(30, [[1.0, 2.0]])
    with pytest.raises(InputError, match="frame position"):
        spin.frame(30)
    with pytest.raises(InputError, match="config must be a MeshRenderConfig"):
        mr.render_mesh_measurement(dataset, truth, 0, config={"covering": "photo"}, meshes=meshes)
    with pytest.raises(ArmError, match="no geometry"):
        mr.load_arm_meshes(Arm.from_urdf_string(URDF_3_JOINTS))
    missing = URDF_3_JOINTS.replace(
        '<link name="wrist_link"/>',
        '<link name="wrist_link"><visual><geometry><mesh filename="package://nowhere/hand.stl"/></geometry>'
        '</visual></link>')
    with pytest.raises(ArmError, match="package_dirs"):
        mr.load_arm_meshes(Arm.from_urdf_string(missing))


def test_a_urdf_arm_with_its_own_meshes(tmp_path):
    import trimesh

    trimesh.creation.cylinder(radius=0.04, height=0.08).apply_translation([0, 0, 0.04]).export(tmp_path / "hand.stl")
    trimesh.creation.box(extents=(0.05, 0.05, 0.25)).apply_translation([0, 0, 0.125]).export(tmp_path / "arm.stl")
    urdf = URDF_3_JOINTS.replace(
        '<link name="wrist_link"/>',
        f'<link name="wrist_link"><visual><geometry><mesh filename="{tmp_path / "hand.stl"}"/></geometry>'
        '</visual></link>').replace(
        '<link name="forearm"/>',
        f'<link name="forearm"><visual><geometry><mesh filename="{tmp_path / "arm.stl"}"/></geometry>'
        '</visual></link>')
    arm = Arm.from_urdf_string(urdf)
    meshes = mr.load_arm_meshes(arm)
    assert len(meshes) == 2
    q = np.array([0.3, 0.6, 0.0])
    wrist = arm.wrist_axis(q)
    camera_pose = look_at(wrist.point + np.array([0.5, -0.3, 0.35]), wrist.point + 0.04 * wrist.direction)
    from gtsam_rotid import Camera

    camera = Camera.from_fov(160, 120, 60.0, dist=(-0.2, 0.05, 0.0, 0.0))
    assert mr.pose_problem(arm, camera, camera_pose, q, meshes=meshes) is None
    spin = mr.MeshSpin(0, arm, camera, camera_pose, q, np.linspace(0, 1, 10), np.arange(10),
                       mr.MeshRenderConfig(covering="dots", noise_sigma=0.0), None, meshes)
    assert spin.moving_links == (meshes.names[1],) or len(spin.moving_links) == 1
    pixels = _hand_pixels(spin, frame=4, count=10)
    points = spin.surface_points(4, pixels)
    # the points lie on the hand cylinder (radius 4 cm about the wrist axis, or its caps)
    radial = np.hypot(points[:, 0], points[:, 1])
    side = (radial > 0.04 * np.cos(np.pi / 32) - 1e-6) & (radial < 0.04 + 1e-6)
    assert np.all(side | (np.abs(points[:, 2] - 0.08) < 1e-6) | (np.abs(points[:, 2]) < 1e-6))
    projected, visible = spin.project_points(points, [4])
    assert np.max(np.abs(projected[0] - pixels)) < 1e-4 and visible.all()
    assert isinstance(spin.arm_T_link(4), gtsam.Pose3)

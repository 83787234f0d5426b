"""Tests of gtsam_rotid.render against ground truth computed here, from the scene and the dot parameters."""

import types

import cv2
import numpy as np
import pytest

from gtsam_rotid import Camera, InputError, RotIdError, simulate
from gtsam_rotid.geometry import circle_points
from gtsam_rotid.render import (
    OutputExistsError,
    RenderConfig,
    RenderedSpin,
    Section,
    VideoWriteError,
    dot_covering,
    render_measurement,
    render_scene,
    save_truth,
    write_video,
)

DISTORTED = Camera([[570.0, 0.0, 319.5], [0.0, 570.0, 239.5], [0.0, 0.0, 1.0]], 640, 480,
                   dist=(-0.2, 0.05, 0.0, 0.0, 0.0))
QUIET = RenderConfig(noise_sigma=0.0)


@pytest.fixture(scope="module")
def scene():
    return simulate.reference_scene(seed=0, duration=2.0)


@pytest.fixture(scope="module")
def distorted_scene():
    return simulate.reference_scene(seed=1, duration=2.0, n_measurements=3, camera=DISTORTED)


# ------------------------------------------------------------------------------------ independent truth
def dot_points(truth, k, dots, spin):
    """Dot centres, outward normals and rims (arm frame), from simulate's circle convention."""
    m = truth.measurements[k]
    centres = np.stack([circle_points(m.axis_point + d * m.axis_direction, m.axis_direction, r, phase + spin,
                                      m.e1, m.e2) for r, d, phase in zip(dots.radius, dots.offset, dots.phase,
                                                                          strict=True)], axis=1)
    angle = dots.phase[None, :] + spin[:, None]
    normal = np.cos(angle)[..., None] * m.e1 + np.sin(angle)[..., None] * m.e2
    tangent = np.cross(m.axis_direction, normal)  # (e1, e2, axis) is right handed: axis x e1 = e2
    beta = np.linspace(0.0, 2.0 * np.pi, 32, endpoint=False)
    rims = centres[..., None, :] + dots.size[None, :, None, None] * (
        np.cos(beta)[:, None] * tangent[..., None, :] + np.sin(beta)[:, None] * m.axis_direction)
    return centres, normal, rims


def to_camera(truth, points):
    camera_T_arm = truth.arm_T_camera.inverse()
    R, t = camera_T_arm.rotation().matrix(), camera_T_arm.translation()
    return points @ R.T + t


def pinhole(K, points_camera):
    return np.stack([K[0, 0] * points_camera[..., 0] / points_camera[..., 2] + K[0, 2],
                     K[1, 1] * points_camera[..., 1] / points_camera[..., 2] + K[1, 2]], axis=-1)


def hidden_by_other_section(truth, k, config, dots, points, grow):
    """Ray march from each point (F, N, S, 3) towards the camera: does it enter another section's solid
    cylinder, grown by ``grow`` metres (negative: shrunk)? Returns (F, N, S) bool."""
    m = truth.measurements[k]
    camera = truth.arm_T_camera.translation()
    t = np.linspace(1e-4, 0.25, 600)  # metres from the point (the end effector is ~0.12 m across), 0.4 mm apart
    hidden = np.zeros(points.shape[:-1], dtype=bool)
    for f in range(points.shape[0]):
        ray = camera - points[f]
        ray /= np.linalg.norm(ray, axis=-1, keepdims=True)
        march = points[f][..., None, :] + t[:, None] * ray[..., None, :]  # (N, S, T, 3)
        rel = march - m.axis_point
        axial = rel @ m.axis_direction
        radial = np.linalg.norm(rel - axial[..., None] * m.axis_direction, axis=-1)
        for i, s in enumerate(config.sections):
            inside = ((axial > s.start - grow) & (axial < s.stop + grow) & (radial < s.radius + grow)).any(axis=-1)
            hidden[f] |= inside & (dots.section != i)[:, None]
    return hidden


def isolated_dot_centroids(spin, truth, k):
    """Intensity-weighted centroid of |frame - background| around every visible dot that lies wholly on the body
    (its pixels replace the body grey only), with no other drawn dot in its window: list of (frame, dot, centroid)."""
    background = spin.background.astype(float)
    spin_angles = truth.measurements[k].spin_angles[spin.frame_indices]
    centres, _, _ = dot_points(truth, k, spin.dots, spin_angles)
    focal = spin.camera.K[0, 0] * 1.1  # a little more than fx, for the lens distortion
    reach = focal * spin.dots.size[None, :] / to_camera(truth, centres)[..., 2]  # dot radius in px, at most
    out = []
    for i in range(spin.n_frames):
        image = spin.frame(i).astype(float)
        drawn = np.flatnonzero(spin.facing[i] > 0)
        for j in np.flatnonzero(spin.visible[i]):
            c = spin.truth_pixels[i, j]
            half = int(np.ceil(reach[i, j])) + 2
            others = drawn[drawn != j]
            gaps = np.max(np.abs(spin.truth_pixels[i, others] - c), axis=1) - reach[i, others]
            if np.any(gaps < half + 1):
                continue
            x0, y0 = int(round(c[0])) - half, int(round(c[1])) - half
            x1, y1 = x0 + 2 * half + 1, y0 + 2 * half + 1
            if x0 < 0 or y0 < 0 or x1 > image.shape[1] or y1 > image.shape[0]:
                continue
            weight = np.abs(image[y0:y1, x0:x1] - background[y0:y1, x0:x1])
            if weight.sum() == 0 or np.any(background[y0:y1, x0:x1][weight > 0] != round(spin.config.body_grey)):
                continue  # part of the dot lies off the body (a flat disc at a grazing angle)
            yy, xx = np.mgrid[y0:y1, x0:x1]
            out.append((i, j, np.array([(weight * xx).sum(), (weight * yy).sum()]) / weight.sum()))
    return out


# ------------------------------------------------------------------------------------ frames
def test_frames_are_lazy_8_bit_images_and_repeatable(scene):
    dataset, truth = scene
    spin = render_measurement(dataset, truth, 0, frames=slice(0, 4))
    assert isinstance(spin, RenderedSpin) and spin.n_frames == len(spin) == 4
    np.testing.assert_array_equal(spin.frame_indices, [0, 1, 2, 3])
    assert spin.fps == dataset.metadata["fps"]
    frames = spin.frames()
    assert isinstance(frames, types.GeneratorType)
    images = list(frames)
    assert len(images) == 4
    for image in images:
        assert image.dtype == np.uint8 and image.shape == (480, 640)
    colour = spin.frame(2, color=True)
    assert colour.shape == (480, 640, 3)
    np.testing.assert_array_equal(colour[..., 0], images[2])
    np.testing.assert_array_equal(colour[..., 2], images[2])
    # a frame renders the same alone (noise is seeded by the frame number) and differs from its neighbour
    alone = render_measurement(dataset, truth, 0, frames=[2])
    np.testing.assert_array_equal(next(alone.frames()), images[2])
    assert np.any(images[1] != images[2])
    n_frames = len(truth.measurements[0].spin_angles)
    assert render_measurement(dataset, truth, 0).n_frames == n_frames


def test_noise_has_the_configured_sigma(scene):
    dataset, truth = scene
    quiet = render_measurement(dataset, truth, 1, QUIET, frames=[5, 6])
    noisy = render_measurement(dataset, truth, 1, QUIET.with_(noise_sigma=3.0), frames=[5, 6])
    for i in range(2):
        difference = noisy.frame(i).astype(float) - quiet.frame(i).astype(float)
        assert abs(difference.mean()) < 0.05
        assert 2.85 < difference.std() < 3.15  # 8-bit rounding adds ~1/12 grey level^2
    d0 = noisy.frame(0).astype(float) - quiet.frame(0)
    d1 = noisy.frame(1).astype(float) - quiet.frame(1)
    assert abs(np.corrcoef(d0.ravel(), d1.ravel())[0, 1]) < 0.05


def test_covering_follows_the_config():
    config = RenderConfig()
    dots = dot_covering(config)
    assert len(dots) == sum(s.n_dots for s in config.sections)
    gap = config.dot_gap_mm / 1000
    for i, s in enumerate(config.sections):
        mine = dots.section == i
        assert np.all(dots.radius[mine] == s.radius)
        assert np.all(dots.offset[mine] - dots.size[mine] - gap >= s.start - 1e-12)
        assert np.all(dots.offset[mine] + dots.size[mine] + gap <= s.stop + 1e-12)
        d, p, size = dots.offset[mine], dots.phase[mine], dots.size[mine]
        arc = s.radius * np.abs(np.angle(np.exp(1j * (p[:, None] - p[None, :]))))
        distance = np.hypot(d[:, None] - d[None, :], arc)
        np.fill_diagonal(distance, np.inf)
        assert np.all(distance >= size[:, None] + size[None, :] + gap - 1e-12)  # no two dots touch
    assert np.all((dots.size >= 0.004) & (dots.size <= 0.009))
    magnitude = np.abs(dots.contrast)
    assert np.all((magnitude >= 50) & (magnitude <= 100))
    assert np.any(dots.contrast < 0) and np.any(dots.contrast > 0)  # dark and bright dots
    again, other = dot_covering(config), dot_covering(config.with_(seed=1))
    np.testing.assert_array_equal(again.phase, dots.phase)
    assert not np.array_equal(other.phase, dots.phase)


# ------------------------------------------------------------------------------------ ground truth
def test_truth_pixels_are_the_projected_dot_centres(scene):
    dataset, truth = scene
    spins = render_scene(dataset, truth, QUIET, frames=slice(0, None, 7))
    assert len(spins) == len(dataset)
    K = dataset.camera.K
    for k, spin in enumerate(spins):
        spin_angles = truth.measurements[k].spin_angles[spin.frame_indices]
        np.testing.assert_array_equal(spin.dots.phase, spins[0].dots.phase)  # one covering for the scene
        centres, normal, _ = dot_points(truth, k, spin.dots, spin_angles)
        np.testing.assert_allclose(spin.truth_pixels, pinhole(K, to_camera(truth, centres)), atol=1e-9)
        to_cam = truth.arm_T_camera.translation() - centres
        facing = np.einsum("fni,fni->fn", normal, to_cam) / np.linalg.norm(to_cam, axis=-1)
        np.testing.assert_allclose(spin.facing, facing, atol=1e-12)
        assert not np.any(spin.visible & (facing <= QUIET.visibility_cos))
        # what a blob detector would see is the image of a finite disc: close to the centre, not on it
        bias = np.linalg.norm(spin.centroid_pixels - spin.truth_pixels, axis=-1)[spin.visible]
        assert np.max(bias) < 0.08


def test_visibility_accounts_for_the_far_side_and_the_other_section(scene):
    dataset, truth = scene
    n_clearly_hidden = 0
    for k in range(len(dataset)):
        spin = render_measurement(dataset, truth, k, QUIET, frames=slice(0, None, 10))
        spin_angles = truth.measurements[k].spin_angles[spin.frame_indices]
        centres, _, rims = dot_points(truth, k, spin.dots, spin_angles)
        points = np.concatenate([centres[:, :, None, :], rims[:, :, ::2]], axis=2)  # centre and 16 rim points
        clearly_hidden = hidden_by_other_section(truth, k, QUIET, spin.dots, points[:, :, :1], -0.001)[..., 0]
        maybe_hidden = hidden_by_other_section(truth, k, QUIET, spin.dots, points, 0.001).any(axis=-1)
        pixels = dataset.camera.project(to_camera(truth, rims.reshape(-1, 3))).reshape(*rims.shape[:-1], 2)
        inside = np.all((pixels >= -0.5) & (pixels <= [639.5, 479.5]), axis=(-1, -2))
        facing = spin.facing > QUIET.visibility_cos
        assert not np.any(spin.visible & clearly_hidden)
        np.testing.assert_array_equal(spin.visible[facing & ~maybe_hidden & inside], True)
        n_clearly_hidden += np.count_nonzero(clearly_hidden & facing)
    assert n_clearly_hidden > 0  # the scene does put dots behind the wider hand


def test_hidden_dots_are_not_drawn_and_visible_ones_are(scene):
    dataset, truth = scene
    checked_hidden = checked_visible = 0
    for k in range(len(dataset)):
        spin = render_measurement(dataset, truth, k, QUIET, frames=slice(0, None, 10))
        background = spin.background
        spin_angles = truth.measurements[k].spin_angles[spin.frame_indices]
        centres, _, _ = dot_points(truth, k, spin.dots, spin_angles)
        clearly_hidden = hidden_by_other_section(truth, k, QUIET, spin.dots, centres[:, :, None], -0.001)[..., 0]
        depth = to_camera(truth, centres)[..., 2]
        size_px = 570.0 * spin.dots.size[None, :] / depth
        for i in range(spin.n_frames):
            image = spin.frame(i)
            drawn = np.flatnonzero(spin.facing[i] > 0)
            hidden = np.flatnonzero((spin.facing[i] < -0.05) | clearly_hidden[i])
            for j in hidden:
                c = spin.truth_pixels[i, j]
                near = np.linalg.norm(spin.truth_pixels[i, drawn] - c, axis=1) < size_px[i, drawn] + 2
                u, v = np.round(c).astype(int)
                if np.any(near) or not (0 <= u < 640 and 0 <= v < 480):
                    continue
                assert image[v, u] == background[v, u], (k, i, j)
                checked_hidden += 1
            for j in np.flatnonzero(spin.visible[i] & (spin.facing[i] > 0.5) & (size_px[i] > 2.5)):
                u, v = np.round(spin.truth_pixels[i, j]).astype(int)
                assert abs(int(image[v, u]) - (QUIET.body_grey + spin.dots.contrast[j])) <= 2, (k, i, j)
                checked_visible += 1
    assert checked_hidden > 100 and checked_visible > 100


def test_rendered_dot_centroids_match_the_truth_pixels(scene):
    dataset, truth = scene
    found = []
    for k in range(len(dataset)):
        spin = render_measurement(dataset, truth, k, QUIET, frames=slice(0, None, 4))
        found += [(spin, i, j, c) for i, j, c in isolated_dot_centroids(spin, truth, k)]
    assert len(found) > 50
    to_truth = np.array([c - spin.truth_pixels[i, j] for spin, i, j, c in found])
    to_centroid = np.array([c - spin.centroid_pixels[i, j] for spin, i, j, c in found])
    # measured: RMS ~0.011 px and max ~0.03 px per axis against either
    assert np.max(np.abs(to_centroid)) < 0.05
    assert np.max(np.abs(to_truth)) < 0.05
    assert np.sqrt(np.mean(to_truth**2)) < 0.02
    assert np.all(np.abs(to_truth.mean(axis=0)) < 0.01)


def test_distorted_camera(distorted_scene):
    dataset, truth = distorted_scene
    found, largest_distortion = [], 0.0
    for k in range(len(dataset)):
        spin = render_measurement(dataset, truth, k, QUIET, frames=slice(0, None, 2))
        spin_angles = truth.measurements[k].spin_angles[spin.frame_indices]
        centres, _, _ = dot_points(truth, k, spin.dots, spin_angles)
        centres_camera = to_camera(truth, centres).reshape(-1, 3)
        expected = DISTORTED.project(centres_camera).reshape(spin.truth_pixels.shape)
        np.testing.assert_allclose(spin.truth_pixels, expected, atol=1e-9)
        ideal = pinhole(DISTORTED.K, centres_camera).reshape(expected.shape)
        largest_distortion = max(largest_distortion, np.max(np.linalg.norm(ideal - expected, axis=-1)))
        found += [c - spin.truth_pixels[i, j] for i, j, c in isolated_dot_centroids(spin, truth, k)]
    assert largest_distortion > 1.0  # the lens matters in this scene...
    assert len(found) > 20
    assert np.max(np.abs(found)) < 0.05  # ...and the rendered dots follow it


# ------------------------------------------------------------------------------------ output
def test_mp4_and_lossless_video_round_trip(scene, tmp_path):
    dataset, truth = scene
    spin = render_measurement(dataset, truth, 0, frames=slice(0, 6))
    originals = list(spin.frames())
    for name, lossless in (("spin.mp4", False), ("spin.mkv", True)):
        path = write_video(spin.frames(), tmp_path / name, spin.fps)
        capture = cv2.VideoCapture(str(path))
        read = []
        while True:
            ok, image = capture.read()
            if not ok:
                break
            read.append(image)
        capture.release()
        assert len(read) == 6
        for image, original in zip(read, originals, strict=True):
            assert image.shape == (480, 640, 3)
            error = np.abs(image[..., 1].astype(int) - original)
            assert np.max(error) == 0 if lossless else np.mean(error) < 8
        with pytest.raises(OutputExistsError):
            write_video(spin.frames(), path, spin.fps)
        write_video(originals[:2], path, spin.fps, overwrite=True)
        capture = cv2.VideoCapture(str(path))
        assert capture.isOpened() and capture.read()[0] and capture.read()[0] and not capture.read()[0]
        capture.release()


def test_image_folder_round_trip_never_loses_files(scene, tmp_path):
    dataset, truth = scene
    spin = render_measurement(dataset, truth, 2, frames=slice(0, 3))
    originals = list(spin.frames(color=True))
    folder = write_video(spin.frames(color=True), tmp_path / "frames", 30)
    names = sorted(p.name for p in folder.iterdir())
    assert names == ["frame_000000.png", "frame_000001.png", "frame_000002.png"]
    for name, original in zip(names, originals, strict=True):
        np.testing.assert_array_equal(cv2.imread(str(folder / name), cv2.IMREAD_UNCHANGED), original)
    with pytest.raises(OutputExistsError, match="overwrite=True"):
        write_video(originals, folder, 30)
    write_video(originals[:1], folder, 30, overwrite=True)
    assert sorted(p.name for p in folder.iterdir()) == ["frame_000000.png"]
    (folder / "notes.txt").write_text("mine")
    with pytest.raises(OutputExistsError, match="other than"):
        write_video(originals, folder, 30, overwrite=True)
    assert (folder / "notes.txt").read_text() == "mine"
    a_file = tmp_path / "plain"
    a_file.write_text("keep")
    with pytest.raises(OutputExistsError):
        write_video(originals, a_file, 30, overwrite=True)
    assert a_file.read_text() == "keep"
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]  # no staging left behind


def test_save_truth(scene, tmp_path):
    dataset, truth = scene
    spin = render_measurement(dataset, truth, 1, frames=slice(3, 9))
    path = save_truth(spin, tmp_path / "truth.npz")
    with np.load(path) as data:
        np.testing.assert_array_equal(data["truth_pixels"], spin.truth_pixels)
        np.testing.assert_array_equal(data["visible"], spin.visible)
        np.testing.assert_array_equal(data["frame_indices"], np.arange(3, 9))
        np.testing.assert_array_equal(data["dot_phase"], spin.dots.phase)
        assert int(data["measurement"]) == 1
    with pytest.raises(OutputExistsError):
        save_truth(spin, path)
    save_truth(spin, path, overwrite=True)


def test_video_writer_failure_is_a_typed_error(scene, tmp_path, monkeypatch):
    class ClosedWriter:
        def __init__(self, *args):
            pass

        def isOpened(self):  # noqa: N802 - OpenCV's name
            return False

        def release(self):
            pass

    monkeypatch.setattr(cv2, "VideoWriter", ClosedWriter)
    with pytest.raises(VideoWriteError, match="cannot open"):
        write_video([np.zeros((4, 4), np.uint8)], tmp_path / "x.mp4", 30)
    assert not list(tmp_path.iterdir())


# ------------------------------------------------------------------------------------ bad input
def test_bad_input_raises_typed_errors(scene, tmp_path):
    dataset, truth = scene
    with pytest.raises(InputError, match="measurement index 6"):
        render_measurement(dataset, truth, 6)
    with pytest.raises(InputError, match="measurement 1: frame 60 is outside"):
        render_measurement(dataset, truth, 1, frames=[0, 60])
    with pytest.raises(InputError, match="measurement 0: .*empty"):
        render_measurement(dataset, truth, 0, frames=slice(5, 5))
    with pytest.raises(InputError, match="integer frame numbers"):
        render_measurement(dataset, truth, 0, frames=[0.5])
    with pytest.raises(InputError, match="frame position 4"):
        render_measurement(dataset, truth, 0, frames=slice(0, 4)).frame(4)
    short_truth = simulate.GroundTruth(truth.arm_T_camera, truth.measurements[:2])
    with pytest.raises(InputError, match="describes 2 measurements"):
        render_measurement(dataset, short_truth, 0)
    with pytest.raises(InputError, match="RenderConfig"):
        render_measurement(dataset, truth, 0, config={"noise_sigma": 1.0})
    with pytest.raises(InputError, match="overlap"):
        RenderConfig(sections=(Section(0.03, 0.0, 0.06, 5), Section(0.05, 0.05, 0.1, 5)))
    with pytest.raises(InputError, match="noise_sigma"):
        RenderConfig(noise_sigma=-1.0)
    with pytest.raises(InputError, match="8-bit range"):
        RenderConfig(body_grey=200.0, dot_contrast=(50.0, 100.0))
    with pytest.raises(InputError, match="section 0 .* holds only"):
        dot_covering(RenderConfig(sections=(Section(0.035, 0.0, 0.05, 200),)))
    frame = np.zeros((48, 64), np.uint8)
    with pytest.raises(InputError, match="unknown video suffix"):
        write_video([frame], tmp_path / "x.gif", 30)
    with pytest.raises(InputError, match="fps"):
        write_video([frame], tmp_path / "x.mp4", 0)
    with pytest.raises(InputError, match="no frames"):
        write_video([], tmp_path / "y.mp4", 30)
    with pytest.raises(InputError, match="frame 1: shape"):
        write_video([frame, np.zeros((48, 65), np.uint8)], tmp_path / "z", 30)
    with pytest.raises(InputError, match="frame 0: expected a uint8"):
        write_video([frame.astype(float)], tmp_path / "w", 30)
    assert issubclass(OutputExistsError, RotIdError) and issubclass(OutputExistsError, FileExistsError)
    assert not list(tmp_path.iterdir())

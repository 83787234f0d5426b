import cv2
import numpy as np
import pytest

from gtsam_rotid import Camera, CameraError, RotIdError

K = [[600.0, 0.0, 640.0], [0.0, 610.0, 360.0], [0.0, 0.0, 1.0]]
DIST = [-0.28, 0.09, 0.001, -0.0008, -0.012]


def random_points(rng, n=200):
    return np.column_stack([rng.uniform(-0.5, 0.5, n), rng.uniform(-0.3, 0.3, n), rng.uniform(0.8, 2.0, n)])


def test_projection_matches_opencv_project_points():
    rng = np.random.default_rng(1)
    camera = Camera(K, 1280, 720, DIST)
    points = random_points(rng)
    expected, _ = cv2.projectPoints(points, np.zeros(3), np.zeros(3), np.array(K), np.array(DIST))
    np.testing.assert_allclose(camera.project(points), expected.reshape(-1, 2), atol=1e-9)


def test_undistort_inverts_distortion():
    rng = np.random.default_rng(2)
    camera = Camera(K, 1280, 720, DIST)
    points = random_points(rng)
    ideal = camera.project(points, distort=False)
    raw = camera.project(points)
    assert np.max(np.abs(raw - ideal)) > 1.0  # the distortion is not negligible
    np.testing.assert_allclose(camera.undistort_pixels(raw), ideal, atol=1e-6)
    rays = camera.rays(raw)
    np.testing.assert_allclose(rays, points / np.linalg.norm(points, axis=1, keepdims=True), atol=1e-9)


def test_no_distortion_is_plain_pinhole():
    camera = Camera.xtion()
    assert camera.dist is None and not camera.has_distortion
    uv = camera.project([[0.1, -0.2, 2.0]])
    np.testing.assert_allclose(uv, [[319.5 + 570 * 0.05, 239.5 - 570 * 0.1]])
    np.testing.assert_allclose(camera.normalize(uv), [[0.05, -0.1]])


def test_points_behind_camera_are_nan():
    uv = Camera.xtion().project([[0.0, 0.0, -1.0], [0.0, 0.0, 1.0]])
    assert np.all(np.isnan(uv[0])) and np.all(np.isfinite(uv[1]))


def test_in_image_mask():
    camera = Camera.xtion()
    mask = camera.in_image([[0, 0], [639, 479], [-1, 10], [10, 480], [320, 240]], margin=0.0)
    assert mask.tolist() == [True, True, False, False, True]
    assert camera.in_image([[5, 5]], margin=10.0).tolist() == [False]


def test_dict_round_trip_and_equality():
    camera = Camera(K, 1280, 720, DIST)
    assert Camera.from_dict(camera.to_dict()) == camera
    assert Camera.from_dict(camera.to_dict()) != Camera(K, 1280, 720)
    assert Camera(K, 1280, 720, DIST[:4]).dist.tolist() == DIST[:4] + [0.0]


def test_from_fov():
    camera = Camera.from_fov(640, 480, 90.0)
    assert camera.K[0, 0] == pytest.approx(320.0)


@pytest.mark.parametrize(
    "kwargs, fragment",
    [
        (dict(K=np.eye(2), width=640, height=480), "3x3"),
        (dict(K=[[500, 0, 320], [0, 500, 240], [0, 1, 1]], width=640, height=480), "form"),
        (dict(K=[[-500, 0, 320], [0, 500, 240], [0, 0, 1]], width=640, height=480), "focal"),
        (dict(K=[[np.nan, 0, 320], [0, 500, 240], [0, 0, 1]], width=640, height=480), "NaN"),
        (dict(K=K, width=0, height=480), "width"),
        (dict(K=K, width=640.5, height=480), "width"),
        (dict(K=K, width=640, height=-3), "height"),
        (dict(K=K, width=640, height=480, dist=[0.1, 0.2, 0.3]), "distortion"),
        (dict(K=K, width=640, height=480, dist=[0.1, np.inf, 0, 0, 0]), "distortion"),
    ],
)
def test_malformed_camera_rejected(kwargs, fragment):
    with pytest.raises(CameraError, match=fragment) as info:
        Camera(**kwargs)
    assert isinstance(info.value, RotIdError) and isinstance(info.value, ValueError)


def test_bad_point_shape_rejected():
    with pytest.raises(CameraError, match=r"shape \(N, 3\)"):
        Camera.xtion().project(np.zeros((4, 2)))


@pytest.mark.parametrize("cx, cy", [(900.0, 240.0), (320.0, -3.0), (240.0, 640.0)])
def test_a_principal_point_outside_the_image_is_refused(cx, cy):
    with pytest.raises(CameraError, match=r"principal point .* outside the 640x480 image"):
        Camera(np.array([[570.0, 0.0, cx], [0.0, 570.0, cy], [0.0, 0.0, 1.0]]), 640, 480)


def test_a_camera_with_its_intrinsics_changed_keeps_the_rest():
    camera = Camera(np.array([[500.0, 0.0, 320.0], [0.0, 510.0, 240.0], [0.0, 0.0, 1.0]]), 640, 480,
                    np.array([0.1, -0.05, 0.0, 0.0]))
    changed = camera.with_intrinsics_changed(1.05, 20.0, -10.0)
    np.testing.assert_allclose(changed.K, [[525.0, 0.0, 340.0], [0.0, 535.5, 230.0], [0.0, 0.0, 1.0]])
    assert (changed.width, changed.height) == (640, 480)
    np.testing.assert_array_equal(changed.dist, camera.dist)
    assert camera.K[0, 0] == 500.0  # the original is untouched

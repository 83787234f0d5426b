"""Tests of the corner tracker for ambient texture (gtsam_rotid.corners via TrackerParams(features=...)) on
synthetic clips whose true surface-point trajectories are known exactly (tests/ambient_scenes.py)."""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest
from ambient_scenes import TEXTURE, spin_clip

from gtsam_rotid import InputError, tracking
from gtsam_rotid.dataset import Track
from gtsam_rotid.patterns import render_dots, spin_dots
from gtsam_rotid.recordings import load_tracker_params
from gtsam_rotid.spinfilter import spin_filter
from gtsam_rotid.tracking import Tracker, TrackerParams

CORNERS = TrackerParams(features="corners")


@pytest.fixture(scope="module")
def photo():
    clip = spin_clip("photo", 90, omega=0.015, seed=0)
    tracker = Tracker(CORNERS)
    return clip, tracker, tracker.run(clip.frames)


def per_track_rms(clip, tracks) -> np.ndarray:
    return np.array([np.sqrt(np.mean(np.sum((t.pixels - clip.truth(t)) ** 2, axis=1))) for t in tracks])


def test_photo_texture_tracks_follow_their_surface_points(photo):
    clip, _, result = photo
    assert len(result.tracks) >= 30
    rms = per_track_rms(clip, result.tracks)
    # most tracks stay on their surface point to a few tenths of a pixel over a 2.7 rad arc
    assert np.median(rms) < 0.6, np.quantile(rms, [0.5, 0.9])
    assert np.mean(rms < 1.0) > 0.6
    # tracks end where their patch has turned by ~0.5 (max_template_warp): arcs too short here for the shared shape
    if np.isfinite(result.spin_rate):
        assert abs(result.spin_rate - clip.omega) < 0.05 * clip.omega


def test_background_and_still_links_never_seed(photo):
    clip, tracker, result = photo
    raw, _, _ = tracker._corners.raw_tracks()
    near_disc = cv2.dilate(clip.moving_region.astype(np.uint8), np.ones((9, 9), np.uint8)) > 0
    seeds = np.rint(np.array([t.pixels[0] for t in raw])).astype(int)
    assert near_disc[seeds[:, 1], seeds[:, 0]].all()         # every seed is where the image moves
    # no kept track starts away from the turning disc
    starts = np.rint(np.array([t.pixels[0] for t in result.tracks])).astype(int)
    assert near_disc[starts[:, 1], starts[:, 0]].all()


@pytest.fixture(scope="module")
def barred():
    """A text-covered disc under a static bar, tracked; with the tracks the spin filter was given."""
    clip = spin_clip("text", 90, omega=0.03, bar=True, seed=1)
    seen = {}

    def spy(tracks, params):
        seen["tracks"] = list(tracks)
        return spin_filter(tracks, params)

    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(tracking, "spin_filter", spy)
        result = Tracker(CORNERS).run(clip.frames)
    return clip, result, seen["tracks"]


def test_occluding_edges_leave_no_sliding_track(barred):
    clip, result, _ = barred
    rms = per_track_rms(clip, result.tracks)
    assert np.median(rms) < 0.8
    assert rms.max() < 1.0, np.sort(rms)[-5:]        # nothing kept slides along the bar's edges
    # good short arcs near the bar are kept: their own turning rate is not what decides (it scatters)
    x0, y0, x1, y1 = clip.bar
    near = [t for t in result.tracks if np.any(np.abs(t.pixels[:, 1] - y0) < 4)]
    assert near


def test_spin_filter_keeps_good_short_arcs(barred):
    """A short arc's turning rate about its own centre scatters far beyond any useful tolerance (here 0.7-1.5
    times the spin's for 10-20 point arcs): no track that follows its surface point is rejected for its rate."""
    clip, _, given = barred
    kept, rejected, fit = spin_filter(given, CORNERS)
    assert fit.model is not None and len(given) > 100
    wrongly = [t for code, t, _ in rejected if code == "rate" and per_track_rms(clip, [t])[0] < 0.3]
    assert not wrongly, f"{len(wrongly)} good tracks rejected for their rate"


def _texture_point_at(clip, angles, point):
    """Pixels of texture point ``point`` turned to ``angles`` (rad, one per frame) instead of the disc's own."""
    c = (TEXTURE - 1) / 2
    centre = np.array([[1, 0, -c], [0, 1, -c], [0, 0, 1.0]])
    out = []
    for i, a in enumerate(angles):
        turn = a - clip.omega * i
        r = np.array([[np.cos(turn), -np.sin(turn), 0], [np.sin(turn), np.cos(turn), 0], [0, 0, 1]])
        p = clip.matrices[i] @ np.linalg.inv(centre) @ r @ centre @ np.array([*point, 1.0])
        out.append(p[:2] / p[2])
    return np.array(out)


@pytest.mark.parametrize("kind", ["stop-and-go", "edge slide"])
def test_spin_filter_rejects_points_that_do_not_turn_with_the_surface(barred, kind):
    clip, _, given = barred
    frames = np.arange(len(clip.frames))
    w = clip.omega
    if kind == "stop-and-go":     # turns, is caught on an edge for a second, turns again
        angles = np.concatenate([w * frames[:30], np.full(30, w * 29), w * (frames[60:] - 30)])
        pixels = _texture_point_at(clip, angles, (TEXTURE / 2 + 70, TEXTURE / 2 + 20))
    else:                         # a T-junction running along the bar's top edge
        pixels = np.column_stack([100 + 0.8 * frames, np.full(len(frames), clip.bar[1] - 0.5)])
    slider = Track(pixels, frames)
    kept, rejected, fit = spin_filter(given + [slider], CORNERS)
    assert fit.model is not None
    assert [code for code, t, _ in rejected if t is slider] in (["rate"], ["ellipse"])
    assert all(detail for _, _, detail in rejected)
    # the good tracks stay (the spin filter alone; the bar's clip has no sliding track of its own)
    assert len(kept) >= 0.95 * len(given)


def test_auto_on_dots_keeps_only_blob_tracks():
    frames, truth = render_dots(spin_dots(), 60)
    blobs = Tracker(TrackerParams(features="blobs")).run(frames)
    auto = Tracker(TrackerParams(features="auto")).run(frames)
    assert len(auto.tracks) == len(blobs.tracks)
    for a, b in zip(auto.tracks, blobs.tracks, strict=True):
        np.testing.assert_array_equal(a.pixels, b.pixels)


@pytest.mark.parametrize("changes, field", [({"features": "sift"}, "features"), ({"link": 1}, "link"),
                                            ({"corner_quality": 1.5}, "corner_quality"),
                                            ({"max_corners": 0}, "max_corners"),
                                            ({"corner_max_anisotropy": 0.5}, "corner_max_anisotropy")])
def test_bad_corner_params(changes, field):
    with pytest.raises(InputError, match=field):
        TrackerParams(**changes)


def test_tracker_params_file(tmp_path):
    yaml = tmp_path / "tracker.yaml"
    yaml.write_text("features: corners\nmax_corners: 120\ncorner_quality: 0.02\n")
    params = load_tracker_params(yaml, min_length=20, max_corners=None)
    assert (params.features, params.max_corners, params.corner_quality, params.min_length) == \
        ("corners", 120, 0.02, 20)
    as_json = tmp_path / "tracker.json"
    as_json.write_text(json.dumps({"features": "auto", "ellipse_sigmas": 5}))
    assert load_tracker_params(as_json, features="corners").features == "corners"     # the flag wins
    assert load_tracker_params(as_json).ellipse_sigmas == 5.0
    bad = tmp_path / "bad.yaml"
    bad.write_text("features: corners\nmax_cornerz: 3\n")
    with pytest.raises(InputError, match=r"bad\.yaml.*max_cornerz"):
        load_tracker_params(bad)
    wrong = tmp_path / "wrong.yaml"
    wrong.write_text("features: sift\n")
    with pytest.raises(InputError, match=r"wrong\.yaml.*features"):
        load_tracker_params(wrong)
    listing = tmp_path / "list.yaml"
    listing.write_text("- 1\n- 2\n")
    with pytest.raises(InputError, match="mapping"):
        load_tracker_params(listing)


def test_track_command_takes_tracker_settings(tmp_path):
    from gtsam_rotid import cli

    parser = cli.build_parser()
    args = parser.parse_args(["track", "--video", "v.mp4", "--joints", "j.csv", "--camera", "c.yaml", "--robot",
                              "kinova", "-o", str(tmp_path / "d"), "--features", "corners", "--max-corners", "50",
                              "--min-track-length", "30", "--tracker-params", str(tmp_path / "t.yaml")])
    assert (args.features, args.max_corners, args.min_track_length) == ("corners", 50, 30)
    with pytest.raises(SystemExit):
        parser.parse_args(["track", "--video", "v.mp4", "--joints", "j.csv", "--camera", "c.yaml", "--robot",
                           "kinova", "-o", "d", "--features", "sift"])


@pytest.fixture(scope="module")
def mesh_photo():
    """75 frames of the reference scene's first measurement (Jaco2, 640x480), the hand covered by a photograph."""
    from gtsam_rotid import meshrender as mr
    from gtsam_rotid import simulate

    dataset, truth = simulate.reference_scene(seed=0, duration=20.0)
    spin = mr.render_mesh_measurement(dataset, truth, 0, mr.MeshRenderConfig(covering="photo", seed=0),
                                      frames=slice(0, 75))
    frames = list(spin.frames())
    tracker = Tracker(CORNERS)
    return spin, tracker, tracker.run(frames)


def test_mesh_rendered_photo_tracks_are_accurate(mesh_photo):
    from gtsam_rotid import meshrender as mr

    spin, _, result = mesh_photo
    assert len(result.tracks) >= 5
    errors = mr.track_errors(result.tracks, spin)
    assert len(errors.off_links) == 0                         # background and still links never kept
    rms = errors.rms_px[np.isfinite(errors.rms_px)]
    # measured: pooled 0.53 px, median track 0.14 px, one of 6 tracks above 1 px (the 2 % target is not met)
    assert errors.pooled_rms_px < 0.6, errors.pooled_rms_px
    assert np.median(rms) < 0.25 and np.sum(rms > 1.0) <= 1, np.quantile(rms, [0.5, 0.9, 1.0])


def test_mesh_rendered_silhouette_corners_are_not_kept(mesh_photo):
    """Every kept track starts on the spinning links, at least a pixel inside their silhouette (a window
    straddling the silhouette is partly still background: such corners do not start tracks)."""
    spin, tracker, result = mesh_photo
    raw, _, _ = tracker._corners.raw_tracks()
    masks = {}
    for t in raw + result.tracks:
        f = int(t.frames[0])
        if f not in masks:
            inside = spin.moving_mask(f).astype(np.uint8)
            masks[f] = cv2.distanceTransform(inside, cv2.DIST_L2, 3)
        u, v = np.rint(t.pixels[0]).astype(int)
        assert masks[f][v, u] >= 1.0, (f, t.pixels[0])


def test_mesh_rendered_text_shading_gradient_reduces_drift():
    """120 frames of the reference scene's first measurement with printed text on the hand: the photometric model
    with a brightness gradient across the patch (shading_gradient, the default) drifts less from the true surface
    points than gain and offset alone (the shading across a patch changes as its surface turns)."""
    from gtsam_rotid import meshrender as mr
    from gtsam_rotid import simulate

    dataset, truth = simulate.reference_scene(seed=0, duration=20.0)
    spin = mr.render_mesh_measurement(dataset, truth, 0, mr.MeshRenderConfig(covering="text", seed=0),
                                      frames=slice(0, 120))
    frames = list(spin.frames())
    medians = {}
    for gradient in (True, False):
        result = Tracker(TrackerParams(features="corners", shading_gradient=gradient)).run(frames)
        errors = mr.track_errors(result.tracks, spin)
        rms = errors.rms_px[np.isfinite(errors.rms_px)]
        assert len(result.tracks) >= 20 and len(errors.off_links) == 0
        medians[gradient] = float(np.median(rms))
        if gradient:
            # measured: 32 tracks, pooled 0.18 px, median track 0.09 px, 90 % 0.19 px (without: 0.19 / 0.13 / 0.28)
            assert errors.pooled_rms_px < 0.22, errors.pooled_rms_px
            assert np.quantile(rms, 0.9) < 0.25 and rms.max() < 1.0, np.quantile(rms, [0.5, 0.9, 1.0])
    assert medians[True] < 0.9 * medians[False], medians


def test_edge_like_patches_are_anisotropic():
    """The templates' anisotropy (larger over smaller eigenvalue of the translation's Hessian): near 1 at a
    checkerboard corner, large on a straight edge, whatever the contrast."""
    from gtsam_rotid.corners import _Templates

    image = np.full((60, 60), 60.0, np.float32)
    image[:30, :30] = image[30:, 30:] = 200.0                     # a checkerboard corner at (29.5, 29.5)
    edge = np.full((60, 60), 100.0, np.float32)
    edge[:, 30:] = 120.0                                          # a faint straight vertical edge
    edge = cv2.GaussianBlur(edge, (0, 0), 1.0) + np.random.default_rng(0).normal(0.0, 0.5, edge.shape).astype(
        np.float32)
    tpl = _Templates(4, 0.5, plane=True)
    *_, corner_strength, corner_ratio = tpl.make(cv2.GaussianBlur(image, (0, 0), 1.0), np.array([[29.5, 29.5]]))
    *_, edge_strength, edge_ratio = tpl.make(edge, np.array([[29.5, 29.5]]))
    assert corner_ratio[0] < 2.0, corner_ratio
    assert edge_ratio[0] > 20.0, edge_ratio
    assert edge_strength[0] < corner_strength[0]


def test_mesh_rendered_photo_edge_like_corners_drift_less():
    """200 frames of the reference scene's first measurement, the hand covered by a photograph: with edge-like
    corners left out (``corner_max_anisotropy=5``) the tracks lie closer to their best rigid point's
    circle than with every corner kept (an edge-like patch slides along its edge, across its motion, as the
    surface turns: a smooth error a short arc turns into a wrong image axis)."""
    from gtsam_rotid import meshrender as mr
    from gtsam_rotid import simulate

    dataset, truth = simulate.reference_scene(seed=0, duration=20.0)
    spin = mr.render_mesh_measurement(dataset, truth, 0, mr.MeshRenderConfig(covering="photo", seed=0),
                                      frames=slice(0, 200))
    frames = list(spin.frames())
    rigid = {}
    for limit in (5.0, 1e30):
        result = Tracker(TrackerParams(features="corners", corner_max_anisotropy=limit)).run(frames)
        errors = mr.track_errors(result.tracks, spin)
        assert len(result.tracks) >= 10 and len(errors.off_links) == 0
        rigid[limit] = errors.pooled_rigid_rms_px
    # measured: 27 tracks, 0.112 px about their best rigid points (every corner kept: 32 tracks, 0.169 px)
    assert rigid[5.0] < 0.85 * rigid[1e30], rigid

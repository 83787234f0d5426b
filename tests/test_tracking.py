"""Tests of gtsam_rotid.tracking on synthetic frames whose exact dot centres the tracker never sees."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from gtsam_rotid import InputError, Track
from gtsam_rotid.patterns import Dot, render_dots, spin_dots
from gtsam_rotid.tracking import (
    RejectReason,
    Tracker,
    TrackerParams,
    filter_tracks,
    frame_source,
    refine_centres,
    split_at_jumps,
    track,
)

# ---------------------------------------------------------------------------------------------- generator


# ---------------------------------------------------------------------------------------------- scoring
def match(tracks: list[Track], truth: np.ndarray, gate: float = 3.0):
    """Per track: the truth dot each point is nearest to (-1 if none within ``gate`` px) and the error."""
    out = []
    for t in tracks:
        candidates = truth[t.frames]                                    # (N, n_dots, 2)
        dist = np.linalg.norm(candidates - t.pixels[:, None, :], axis=2)
        dist = np.where(np.isnan(dist), np.inf, dist)
        nearest = np.argmin(dist, axis=1)
        error = dist[np.arange(len(t)), nearest]
        nearest[error > gate] = -1
        out.append((nearest, error))
    return out


def rms_error(tracks, truth) -> tuple[float, float]:
    """(RMS px over matched points, fraction of points matched)."""
    matched = match(tracks, truth)
    errors = np.concatenate([e[n >= 0] for n, e in matched])
    total = sum(len(n) for n, _ in matched)
    return float(np.sqrt(np.mean(errors**2))), len(errors) / total


def coverage(tracks, truth, min_run: int = 10) -> float:
    """Fraction of the frames of every visible run (>= min_run frames) of every dot that a track covers."""
    covered = np.zeros(truth.shape[:2], bool)
    for t, (nearest, _) in zip(tracks, match(tracks, truth), strict=True):
        ok = nearest >= 0
        covered[t.frames[ok], nearest[ok]] = True
    visible = ~np.isnan(truth[..., 0])
    hit = total = 0
    for j in range(truth.shape[1]):
        v = np.concatenate([[False], visible[:, j], [False]]).astype(int)
        starts, ends = np.flatnonzero(np.diff(v) == 1), np.flatnonzero(np.diff(v) == -1)
        for s, e in zip(starts, ends, strict=True):
            if e - s >= min_run:
                hit += covered[s:e, j].sum()
                total += e - s
    return hit / total


# ---------------------------------------------------------------------------------------------- fixtures
@pytest.fixture(scope="module")
def spin():
    frames, truth = render_dots(spin_dots(), 150)
    return frames, truth


@pytest.fixture(scope="module")
def spin_result(spin):
    frames, _ = spin
    return Tracker().run(frames)


def pure(tracks, truth) -> bool:
    """Every track follows one dot: all its points are matched, and to the same dot."""
    return all(np.all(n >= 0) and len(np.unique(n)) == 1 for n, _ in match(tracks, truth))


# ---------------------------------------------------------------------------------------------- accuracy
def test_tracks_synthetic_discs_to_a_tenth_of_a_pixel(spin, spin_result):
    frames, truth = spin
    tracks = spin_result.tracks
    assert len(tracks) >= 8
    rms, matched = rms_error(tracks, truth)
    assert matched == 1.0                      # every tracked point lies on a true dot ...
    assert rms < 0.1                           # ... within a tenth of a pixel (RMS)
    assert pure(tracks, truth)                 # and no track hops between dots
    starts = [int(t.frames[0]) for t in tracks]
    assert starts == sorted(starts)
    for t in tracks:
        assert t.frames.dtype == np.int64 and np.all(np.diff(t.frames) > 0)
        assert 0 <= t.frames[0] and t.frames[-1] < len(frames)
        assert len(t) >= TrackerParams().min_length


def test_every_visible_arc_is_covered(spin, spin_result):
    _, truth = spin
    assert coverage(spin_result.tracks, truth) > 0.9
    # each stretch of 20+ frames during which a dot is visible is mostly inside one track
    matched = match(spin_result.tracks, truth)
    visible = ~np.isnan(truth[..., 0])
    for j in range(truth.shape[1]):
        v = np.concatenate([[0], visible[:, j].astype(int), [0]])
        for s, e in zip(np.flatnonzero(np.diff(v) == 1), np.flatnonzero(np.diff(v) == -1), strict=True):
            if e - s < 20:
                continue
            best = max(np.sum((t.frames >= s) & (t.frames < e) & (n == j))
                       for t, (n, _) in zip(spin_result.tracks, matched, strict=True))
            assert best >= 0.8 * (e - s), (j, s, e, best)


def test_rendered_reference_scene_to_a_tenth_of_a_pixel():
    from gtsam_rotid import render, simulate

    dataset, truth = simulate.reference_scene(seed=0, duration=3.0)
    spin = render.render_measurement(dataset, truth, 0)
    tracks = track(spin.frames())                                       # a generator of 640x480 frames
    # every point is matched to a drawn dot, partly hidden ones included: none escapes the RMS
    drawn = np.where(spin.facing[..., None] > 0, spin.truth_pixels, np.nan)
    rms, matched = rms_error(tracks, drawn)
    assert matched == 1.0 and rms < 0.1
    assert pure(tracks, drawn)
    # dots seen at least half face-on are tracked
    clear = np.where((spin.visible & (spin.facing > 0.5))[..., None], spin.truth_pixels, np.nan)
    assert coverage(tracks, clear) > 0.85


def test_refine_centres_finds_sub_pixel_disc_centres():
    rng = np.random.default_rng(5)
    centres = np.column_stack([rng.uniform(30, 90, 6), rng.uniform(30, 50, 6)]) + [[0, 0]] * 6
    centres[:, 0] = 20 + 25 * np.arange(6) + rng.uniform(-0.5, 0.5, 6)
    radii = np.array([2.5, 3.0, 4.0, 5.0, 6.0, 3.5])
    dots = [Dot(tuple(c), (0.0, 0.0), r, level, speed=0.0)
            for c, r, level in zip(centres, radii, [20, 230, 40, 200, 10, 250], strict=True)]
    frames, truth = render_dots(dots, 1, 180, 80, noise=0.0, background=np.full((80, 180), 128.0))
    start = truth[0] + rng.uniform(-1.0, 1.0, (6, 2))          # where LK might have left the points
    found = refine_centres(frames[0], start, radii)
    assert np.all(found.ok)
    assert np.abs(found.centres - truth[0]).max() < 0.05          # the pixel grid alone: no noise here
    np.testing.assert_array_equal(found.polarity, [-1, 1, -1, 1, -1, 1])
    np.testing.assert_allclose(found.radius, radii, atol=0.4)
    assert np.all(found.skewness < 0.1)
    # a disc cut by an occluding edge is lopsided
    cut = frames[0].copy()
    column = int(np.rint(truth[0, 3, 0]))
    cut[:, column + 2:column + 8] = 128
    lopsided = refine_centres(cut, truth[0, 3], radii[3])
    assert lopsided.skewness[0] > TrackerParams().max_skewness


# ---------------------------------------------------------------------------------------------- rejection
def test_static_blob_is_rejected_as_barely_moving():
    dots = spin_dots(4, seed=3, hide=False)
    dots.append(Dot((40.0, 40.0), (0.0, 0.0), 4.0, 20.0, speed=0.0))          # painted on the background
    frames, truth = render_dots(dots, 80, seed=2)
    result = Tracker().run(frames)
    static = truth[0, -1]
    for t in result.tracks:
        assert np.linalg.norm(t.pixels - static, axis=1).min() > 5
    reasons = [r.reason for r in result.rejected if np.linalg.norm(r.track.pixels[0] - static) < 1]
    assert reasons == [RejectReason.STATIC]
    assert rms_error(result.tracks, truth[:, :-1])[0] < 0.1


def test_a_teleporting_disc_never_joins_one_track():
    dots = [Dot((160.0, 120.0), (60.0, 40.0), 4.0, 30.0, speed=0.03, jumps={50: (7.0, 0.0)}),
            Dot((160.0, 120.0), (30.0, 20.0), 3.5, 230.0, speed=0.04, phase=2.0)]
    frames, truth = render_dots(dots, 100, seed=4)
    tracks = track(frames)
    assert rms_error(tracks, truth)[0] < 0.1
    for t in tracks:
        steps = np.linalg.norm(np.diff(t.pixels, axis=0), axis=1)
        assert steps.max() < 3.0                 # no track bridges the 7 px jump
    around = [t for t in tracks if np.linalg.norm(t.pixels[0] - truth[t.frames[0], 0]) < 1]
    assert any(t.frames[-1] < 50 for t in around) and any(t.frames[0] >= 50 for t in around)


def test_discs_that_pass_each_other_never_swap_tracks():
    # two discs on the same ellipse, one overtaking the other: they meet and part again
    dots = [Dot((160.0, 120.0), (70.0, 50.0), 4.0, 25.0, speed=0.05, phase=0.0),
            Dot((160.0, 120.0), (70.0, 50.0), 4.0, 35.0, speed=0.02, phase=0.9)]
    frames, truth = render_dots(dots, 120, seed=6)
    gap = np.linalg.norm(truth[:, 0] - truth[:, 1], axis=1)
    assert gap.min() < 3.0                       # they do meet
    tracks = track(frames)
    assert pure(tracks, truth)
    assert coverage(tracks, truth) > 0.6


def test_split_at_jumps_splits_steps_and_drops_lone_outliers():
    rng = np.random.default_rng(0)
    frames = np.arange(100)
    theta = 0.03 * frames
    arc = np.column_stack([100 + 40 * np.cos(theta), 80 + 25 * np.sin(theta)]) + rng.normal(0, 0.05, (100, 2))
    pieces, jumps, bad = split_at_jumps(frames, arc)
    assert (len(pieces), jumps, bad) == (1, 0, 0)
    outlier = arc.copy()
    outlier[30] += [2.0, -1.5]
    pieces, jumps, bad = split_at_jumps(frames, outlier)
    assert len(pieces) == 1 and jumps == 0 and 30 not in pieces[0] and 1 <= bad <= 5
    step = arc.copy()
    step[60:] += [6.0, 0.0]                      # onto a neighbouring feature
    pieces, jumps, _ = split_at_jumps(frames, step)
    assert jumps == 1 and len(pieces) == 2
    assert pieces[0].max() < 60 <= pieces[1].min()
    assert len(pieces[0]) > 50 and len(pieces[1]) > 30


def test_filter_tracks_reasons():
    rng = np.random.default_rng(1)
    theta = 0.05 * np.arange(60)
    arc = Track(np.column_stack([50 + 30 * np.cos(theta), 50 + 30 * np.sin(theta)]), np.arange(60) + 7)
    static = Track(np.array([[20.0, 30.0]]) + rng.normal(0, 0.05, (60, 2)), np.arange(60))
    short = Track(arc.pixels[:6], arc.frames[:6])
    jumpy = np.vstack([arc.pixels[:30], arc.pixels[30:36] + [8.0, 0.0]])     # a 6-point tail after a jump
    accepted, rejected = filter_tracks([arc, static, short, jumpy])
    assert len(accepted) == 2 and arc in accepted
    head = next(t for t in accepted if t.frames is None)                    # the jumpy track before its jump
    np.testing.assert_allclose(head.pixels, arc.pixels[:len(head)])
    assert len(head) >= 20
    reasons = [r.reason for r in rejected]
    assert reasons.count(RejectReason.STATIC) == 1 and reasons.count(RejectReason.SHORT) == 2
    assert any("jump" in r.detail for r in rejected)


def test_too_short_tracks_are_dropped(spin):
    frames, truth = spin
    params = TrackerParams(min_length=100)
    result = Tracker(params).run(frames)
    assert result.tracks and all(len(t) >= 100 for t in result.tracks)
    short = [r for r in result.rejected if r.reason is RejectReason.SHORT]
    assert short and all(len(r.track) < 100 for r in short)
    assert rms_error(result.tracks, truth)[0] < 0.1


# ---------------------------------------------------------------------------------------------- input
def same_tracks(a: list[Track], b: list[Track]) -> bool:
    return len(a) == len(b) and all(x == y for x, y in zip(a, b, strict=True))


def test_grey_bgr_list_array_and_generator_inputs_agree(spin):
    frames = spin[0][:60]
    reference = track(frames)
    assert reference
    bgr = np.repeat(frames[..., None], 3, axis=3)
    assert same_tracks(track(bgr), reference)
    assert same_tracks(track(list(frames)), reference)
    assert same_tracks(track(f for f in bgr), reference)
    assert same_tracks(track(frames[..., None]), reference)            # (F, H, W, 1)


def test_image_folder_and_video_inputs(spin, tmp_path):
    frames, truth = spin
    frames, truth = frames[:60], truth[:60]
    folder = tmp_path / "frames"
    folder.mkdir()
    for i, image in enumerate(frames):
        assert cv2.imwrite(str(folder / f"frame_{i:04d}.png"), image)
    (folder / "notes.txt").write_text("not an image")                  # ignored
    assert same_tracks(track(folder), track(frames))                    # PNG is lossless
    assert same_tracks(track(str(folder)), track(frames))
    video = tmp_path / "spin.avi"
    writer = cv2.VideoWriter(str(video), cv2.VideoWriter_fourcc(*"MJPG"), 30.0, (frames.shape[2], frames.shape[1]))
    assert writer.isOpened()
    for image in frames:
        writer.write(cv2.cvtColor(image, cv2.COLOR_GRAY2BGR))
    writer.release()
    tracks = track(video)                                               # compressed: pixels differ a little
    assert len(tracks) >= 5
    rms, matched = rms_error(tracks, truth)
    assert matched > 0.99 and rms < 0.5


def test_progress_bar(spin, capsys):
    track(spin[0][:20], progress=True)
    assert "20/20" in capsys.readouterr().err


def grey(h=40, w=50, value=128):
    return np.full((h, w), value, np.uint8)


@pytest.mark.parametrize(("frames", "message"), [
    ([], "no frames"),
    (np.zeros((0, 40, 50), np.uint8), "no frames"),
    ([grey(), grey().astype(np.float32)], "frame 1: expected an 8-bit image (dtype uint8), got dtype float32"),
    ([grey(), grey(41, 50)], "frame 1 is 50x41 but the first frame is 50x40"),
    ([grey(), "a string"], "frame 1: expected an 8-bit image (a numpy uint8 array), got str"),
    ([np.zeros((40, 50, 2), np.uint8)], "frame 0: expected a grey (H, W) or BGR (H, W, 3) image"),
    ([grey(8, 50)], "too small"),
    (np.zeros((40, 50, 3), np.uint8), "got one (40, 50, 3) image, not a sequence of frames"),
    (np.zeros(5, np.uint8), "must have shape (F, H, W)"),
    (42, "frames must be an iterable of 8-bit images"),
    (b"bytes", "not bytes"),
    ("/nonexistent/spin.mp4", "does not exist"),
])
def test_bad_input_raises_input_error(frames, message):
    with pytest.raises(InputError) as info:
        track(frames)
    assert message in str(info.value)


def test_bad_files_raise_input_error(tmp_path):
    empty = tmp_path / "empty"
    empty.mkdir()
    with pytest.raises(InputError, match="holds no image files"):
        track(empty)
    broken = tmp_path / "broken"
    broken.mkdir()
    cv2.imwrite(str(broken / "a.png"), grey())
    (broken / "b.png").write_bytes(b"not a png")
    with pytest.raises(InputError, match=r"frame 1: cannot read the image .*b\.png"):
        track(broken)
    deep = tmp_path / "deep"
    deep.mkdir()
    cv2.imwrite(str(deep / "a.png"), np.full((40, 50), 1000, np.uint16))
    image, where = next(frame_source(deep)[0])   # the one frame reader scales 16-bit images to 8 bits
    assert image.dtype == np.uint8 and int(image[0, 0]) == 1000 >> 8 and where.startswith("frame 0 of ")
    not_video = tmp_path / "spin.mp4"
    not_video.write_text("this is not a video")
    with pytest.raises(InputError, match="cannot open the video"):
        track(not_video)


@pytest.mark.parametrize("changes", [dict(min_length=2), dict(lk_window=14), dict(jump_window=4),
                                     dict(fb_threshold=0.0), dict(max_area=5.0), dict(recentre="yes"),
                                     dict(detect_every=2.5), dict(min_contrast=float("nan")),
                                     dict(centroid_level=1.0), dict(max_threshold=5.0)])
def test_bad_params_raise_input_error(changes):
    with pytest.raises(InputError, match="TrackerParams"):
        TrackerParams(**changes)
    with pytest.raises(InputError, match="TrackerParams"):
        Tracker("not params")

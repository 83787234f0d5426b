"""The rigid-spin factor synced with the spinning joint's readings (factors.rigid_line.EncoderPrior): a prior on
every frame's angle, the clocks' offset an outer variable. Checked against numerical derivatives and the truth of a
simulated spin that speeds up and slows down (so that the readings date the frames)."""

from __future__ import annotations

import gtsam
import numpy as np
import pytest
from gtsam.symbol_shorthand import K, L, T
from gtsam.utils.numerical_derivative import (
    numericalDerivative21,
    numericalDerivative22,
    numericalDerivative31,
    numericalDerivative32,
    numericalDerivative33,
)

from gtsam_rotid.dataset import Track
from gtsam_rotid.factors import (
    EncoderPrior,
    RigidTracks,
    cal3_s2,
    closest_phases,
    initial_spin,
    make_rigid_line_factor,
    rot3_from_line,
)
from gtsam_rotid.simulate import reference_scene

SIGMA = 1.0
OFFSET = 0.03  # s: the encoder's clock ahead of the camera's
ENCODER_SIGMA = np.radians(0.02)
TIME = T(0)


class Spin:
    """One measurement of a simulated scene with readings: ideal pixels (noisy and exact), frames, the true line,
    circles and spin angles, and the readings."""

    def __init__(self, dataset, truth, k=0):
        camera, m_truth, m_data = dataset.camera, truth.measurements[k], dataset.measurements[k]
        camera_T_arm = truth.arm_T_camera.inverse()
        point = camera_T_arm.transformFrom(m_truth.axis_point)
        self.direction = camera_T_arm.rotation().matrix() @ m_truth.axis_direction
        self.line, distance = rot3_from_line(point, self.direction)
        c1 = self.line.matrix()[:, 1]
        self.circles = np.array([[(t.offset + point @ c1) / distance, t.radius / distance] for t in m_truth.tracks])
        self.K, self.noisy, self.exact, self.frames = camera.K, [], [], []
        for j, track in enumerate(m_data.tracks):
            track = Track.from_any(track)
            self.noisy.append(camera.undistort_pixels(track.pixels))
            points = truth.arm_T_camera.transformTo(m_truth.feature_points(j, track.frames).T).T @ camera.K.T
            self.exact.append(points[:, :2] / points[:, 2:])
            self.frames.append(track.frames)
        self.readings, self.spin_angles = m_data.spin_readings, m_truth.spin_angles
        self.tracks = RigidTracks(list(zip(self.noisy, self.frames, strict=True)))

    def start(self, pixels):
        phases = [closest_phases(self.K, self.line, d, r, p) for (d, r), p in zip(self.circles, pixels, strict=True)]
        tracks = RigidTracks(list(zip(pixels, self.frames, strict=True)))
        first = int(tracks.frame_ids[0])
        init = initial_spin(list(zip(self.frames, phases, strict=True)), int(tracks.frame_ids[-1]) - first + 1, first)
        return tracks, init.phi0, init.theta[0][tracks.frame_ids - first]

    def encoder(self, sign=1.0, sigma=ENCODER_SIGMA, smoothing_s=0.1):
        r = self.readings
        return EncoderPrior(r.frame_times[self.tracks.frame_ids], r.times, r.angles, sigma, sign, smoothing_s)

    def factor(self, pixels, *, sign=1.0, time_key=TIME, intrinsics_key=None, scale=1.0, offset=0.0,
               smoothing_s=0.1):
        tracks, phi0, theta = self.start(pixels)
        return make_rigid_line_factor(L(0), tracks, self.K, self.circles * scale, phi0, theta, sigma_px=SIGMA,
                                      tol=1e-14, encoder=self.encoder(sign, smoothing_s=smoothing_s),
                                      time_key=time_key, intrinsics_key=intrinsics_key, time_offset=offset)


def values_at(line, delta=None, intrinsics=None) -> gtsam.Values:
    values = gtsam.Values()
    values.insert(L(0), line)
    if intrinsics is not None:
        values.insert(K(0), intrinsics)
    if delta is not None:
        values.insert(T(0), np.atleast_1d(np.asarray(delta, dtype=float)))
    return values


@pytest.fixture(scope="module")
def spin() -> Spin:
    dataset, truth = reference_scene(seed=3, duration=6, spin_ramp=2.0, encoder_rate=200, encoder_sigma_deg=0.0,
                                     encoder_time_offset=OFFSET)
    return Spin(dataset, truth)


def test_the_readings_interpolate_smoothly_with_their_derivative():
    """Unsmoothed, the curve passes through the readings (a joint reported in [-pi, pi) unwrapped); smoothed (the
    default), it keeps a quadratic motion exactly; either way its delta derivative is the numerical one, also
    beyond the readings (linear there)."""
    times = np.linspace(0.0, 2.0, 41)
    angles = np.sin(3 * times) + 2 * times
    raw = EncoderPrior(times[[3, 10, 20]] - 0.01, times, np.angle(np.exp(1j * angles)), 1e-3, -1.0, smoothing_s=0.0)
    np.testing.assert_allclose(raw.at(0.01)[0], -angles[[3, 10, 20]], atol=1e-12)
    frames = np.array([0.0137, 0.52, 1.3391, 1.999])
    quadratic = EncoderPrior(frames, times, 0.3 * times**2 + 2 * times + 1, 1e-3)
    value, rate = quadratic.at(0.0)
    np.testing.assert_allclose(value, 0.3 * frames**2 + 2 * frames + 1, atol=1e-12)
    np.testing.assert_allclose(rate, 0.6 * frames + 2, atol=1e-12)
    for prior in (raw, quadratic, EncoderPrior(frames, times, angles, 1e-3)):
        for delta in (0.0123, -0.2, 2.5):  # inside, before and beyond the readings
            h = 1e-6
            numerical = (prior.at(delta + h)[0] - prior.at(delta - h)[0]) / (2 * h)
            np.testing.assert_allclose(prior.at(delta)[1], numerical, rtol=1e-6, atol=1e-8)
    assert raw.covers(0.01) and not raw.covers(-0.2)


def test_smoothing_keeps_the_readings_noise_off_their_rate():
    """Readings at 100 per second with 0.02 deg noise of a steady 0.5 rad/s: finite differences put ~0.05 rad/s of
    noise on the rate at each frame, the smoothed curve a small fraction of that, and its angles are no noisier
    than the readings."""
    rng = np.random.default_rng(4)
    times = np.arange(0.0, 10.0, 0.01)
    noise = np.radians(0.02)
    angles = 0.5 * times + rng.normal(0.0, noise, size=len(times))
    frames = np.arange(1.0, 9.0, 1.0 / 30.0) + 0.0031
    raw = EncoderPrior(frames, times, angles, noise, smoothing_s=0.0).at(0.0)
    smooth = EncoderPrior(frames, times, angles, noise).at(0.0)
    raw_rate, smooth_rate = np.std(raw[1] - 0.5), np.std(smooth[1] - 0.5)
    assert raw_rate > 0.03 and smooth_rate < raw_rate / 5
    assert np.std(smooth[0] - 0.5 * frames) < noise


def test_noise_free_spin_gives_the_truth_and_exact_jacobians(spin):
    """Exact pixels and readings (200 per second, interpolated unsmoothed: the ramps' corners stay sharp) at the true
    line and offset: zero residuals, the frames' angles the readings' (the true spin plus the joint's start angle),
    and every Jacobian (line, time offset; and line, intrinsics, time offset) the numerical derivative."""
    factor = spin.factor(spin.exact, scale=1.01, smoothing_s=0.0)
    values = values_at(spin.line, OFFSET)
    assert factor.factor.keys() == [L(0), T(0)]
    assert factor.factor.dim() == 2 * factor.tracks.n_points + factor.tracks.n_frames
    assert np.abs(factor.residuals(values)).max() < 1e-7
    assert np.abs(factor.encoder_residuals(values)).max() < 1e-9
    np.testing.assert_allclose(factor.circles(values), spin.circles, atol=1e-8)
    turned = factor.spin_angles(values) - spin.spin_angles[factor.tracks.frame_ids]
    assert np.ptp(turned) < 1e-8  # the true spin, less a constant (the joint's angle at the start)
    A, _ = factor.factor.linearize(values).jacobian()
    error = lambda line, delta: factor.factor.unwhitenedError(values_at(line, delta))  # noqa: E731
    J_line = numericalDerivative21(error, spin.line, np.array([OFFSET]), 1e-6)
    # (the offset's step is 1e-5 s: at 1e-6 s the inner solves' own tolerance shows in the difference quotient, at
    # ~2e-5 of its largest entry; at 1e-5 s the quotient agrees to 2e-6)
    J_time = numericalDerivative22(error, spin.line, np.array([OFFSET]), 1e-5)
    assert np.abs(J_time).max() > 1.0  # the speed changes: the offset shows
    np.testing.assert_allclose(A[:, :3], J_line, rtol=0, atol=1e-6 * np.abs(J_line).max())
    np.testing.assert_allclose(A[:, 3:], J_time, rtol=0, atol=1e-5 * np.abs(J_time).max())

    factor = spin.factor(spin.exact, intrinsics_key=K(0), scale=1.01, smoothing_s=0.0)
    truth = cal3_s2(spin.K)
    values = values_at(spin.line, OFFSET, truth)
    assert factor.factor.keys() == [L(0), K(0), T(0)]
    A, _ = factor.factor.linearize(values).jacobian()
    error = lambda line, intrinsics, delta: factor.factor.unwhitenedError(  # noqa: E731
        values_at(line, delta, intrinsics))
    at = (spin.line, truth, np.array([OFFSET]))
    for J, columns, tolerance in ((numericalDerivative31(error, *at, 1e-6), slice(0, 3), 1e-6),
                                  (numericalDerivative32(error, *at, 1e-3), slice(3, 8), 1e-6),
                                  (numericalDerivative33(error, *at, 1e-5), slice(8, 9), 1e-5)):
        np.testing.assert_allclose(A[:, columns], J, rtol=0, atol=tolerance * np.abs(J).max())


def test_a_wrong_sign_or_offset_shows_in_the_error(spin):
    """The readings turn the features right-handed about the line's axis: the other sign cannot fit; an offset 20 ms
    off raises the error from zero as its Jacobian predicts (``|J dt|^2 / 2``: the ramps' angles disagree)."""
    right = spin.factor(spin.exact, smoothing_s=0.0)
    truth = values_at(spin.line, OFFSET)
    assert right.error(truth) < 1e-6
    assert spin.factor(spin.exact, sign=-1.0, smoothing_s=0.0).error(truth) > 1e4
    J = right.factor.linearize(truth).jacobian()[0][:, 3]
    predicted = 0.5 * float(J @ J) * 0.02**2
    assert predicted > 1.0
    assert abs(right.error(values_at(spin.line, OFFSET + 0.02)) / predicted - 1.0) < 0.1


def test_lm_recovers_the_clocks_offset(spin):
    """Noisy pixels, exact readings: LM on the line and the offset (from 0, prior 0 +- 1 s) finds the offset within
    its marginal 3 sigma, itself below a frame (1/30 s) from one 6 s spin of a few tracks."""
    factor = spin.factor(spin.noisy)
    graph = gtsam.NonlinearFactorGraph()
    graph.add(factor.factor)
    graph.add(gtsam.PriorFactorVector(T(0), np.zeros(1), gtsam.noiseModel.Isotropic.Sigma(1, 1.0)))
    values = values_at(spin.line, 0.0)
    result = gtsam.LevenbergMarquardtOptimizer(graph, values, gtsam.LevenbergMarquardtParams()).optimize()
    delta = float(result.atVector(T(0))[0])
    sigma = float(np.sqrt(gtsam.Marginals(graph, result).marginalCovariance(T(0))[0, 0]))
    assert abs(delta - OFFSET) < 3 * sigma
    assert sigma < 1.0 / 30


def test_input_checks(spin):
    tracks, phi0, theta = spin.start(spin.noisy)
    with pytest.raises(ValueError, match="needs the encoder's readings"):
        make_rigid_line_factor(L(0), tracks, spin.K, spin.circles, phi0, theta, time_key=T(0))
    short = EncoderPrior(spin.readings.frame_times[:3], spin.readings.times, spin.readings.angles, 1e-3)
    with pytest.raises(ValueError, match="one encoder frame time per frame seen"):
        make_rigid_line_factor(L(0), tracks, spin.K, spin.circles, phi0, theta, encoder=short)
    with pytest.raises(ValueError, match="strictly increasing: reading 2"):
        EncoderPrior([0.0], [0.0, 1.0, 1.0], [0.0, 1.0, 2.0], 1e-3)
    with pytest.raises(ValueError, match="at least 2 readings"):
        EncoderPrior([0.0], [0.0], [0.0], 1e-3)
    with pytest.raises(ValueError, match="sigma_rad"):
        EncoderPrior([0.0], [0.0, 1.0], [0.0, 1.0], 0.0)
    with pytest.raises(ValueError, match="sign"):
        EncoderPrior([0.0], [0.0, 1.0], [0.0, 1.0], 1e-3, sign=0.5)


def test_the_readings_rate_noise_is_zero_without_a_full_running_mean():
    """EncoderPrior.rate_noise with exactly twice the running mean's frames has no rate with a full mean on each
    side: 0 (it was the median of nothing, NaN, which made a synced offset's 1 sigma NaN)."""
    times = np.linspace(0.0, 2.0, 201)
    prior = EncoderPrior(np.linspace(0.5, 1.5, 30), times, 0.3 * times**2, np.radians(0.05))
    assert prior.rate_noise(0.0, frames=15) == 0.0
    assert np.isfinite(EncoderPrior(np.linspace(0.5, 1.5, 31), times, 0.3 * times**2, np.radians(0.05))
                       .rate_noise(0.0, frames=15))

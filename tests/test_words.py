"""The report layer's sentences (gtsam_rotid.words), on results and observability analyses built by hand: the
numbers a user reads, the reason named and the advice given, not the sentences verbatim."""

import itertools
import re
from types import SimpleNamespace

import gtsam
import numpy as np
import pytest

from gtsam_rotid.calibration.options import MIN_MEASUREMENTS
from gtsam_rotid.calibration.result import (
    AMBIGUITY_CHI2,
    UNTRUSTED_KINDS,
    Alternative,
    AxisConsistency,
    CalibrationResult,
    MeasurementReport,
)
from gtsam_rotid.calibration.run import _untrusted
from gtsam_rotid.calibration.tuning import MAX_CONSISTENCY_SCALE, MAX_RELATIVE_SIGMA, MAX_SIGMA_DEG, RESTART_P
from gtsam_rotid.uncertainty import analyse_observability
from gtsam_rotid.words import (
    ambiguity_words,
    axis_consistency_sentence,
    evidence_words,
    kinematics_words,
    observability_words,
    outlier_words,
    summary,
    tracking_words,
    untrusted_words,
    verdict,
)

#: the camera, turned well away from the arm frame so that a camera-frame vector printed as an arm-frame one shows
POSE = gtsam.Pose3(gtsam.Rot3.Ypr(0.4, -0.3, 2.0), np.array([-0.4497, 0.2485, 0.9506]))
#: 1σ about the camera axes (deg) and along them (mm)
SIGMA_DEG = np.array([0.07, 0.05, 0.06])
SIGMA_MM = np.array([0.7, 0.9, 0.5])
COVARIANCE = np.diag(np.concatenate([np.radians(SIGMA_DEG), SIGMA_MM / 1000.0]) ** 2)

NUMBER = r"[-+]?(?:\d+\.?\d*|\.\d+)(?:e[-+]?\d+)?"


def floats(text: str) -> list[float]:
    return [float(x) for x in re.findall(NUMBER, text)]


def after(text: str, label: str) -> float:
    """The number that follows ``label`` in ``text``."""
    match = re.search(re.escape(label) + r"\s*(" + NUMBER + ")", text)
    assert match, f"{label!r} not followed by a number in: {text}"
    return float(match.group(1))


def line_starting(text: str, head: str) -> str:
    return next(line for line in text.splitlines() if line.strip().startswith(head))


def measurement(index: int, n_tracks: int = 12, *, weak=False, outlier=False, **kw) -> MeasurementReport:
    defaults = {"n_points": 100 * n_tracks + index, "residual_rms_px": 1.2 + 0.01 * index, "weight": 1.0,
                "arc_span_deg": 140.0}
    defaults.update(kw)
    return MeasurementReport(index=index, n_tracks=n_tracks, outlier=outlier, weak=weak, **defaults)


def measurements(n: int = 6) -> list[MeasurementReport]:
    return [measurement(k) for k in range(n)]


def result(covariance: np.ndarray = COVARIANCE, information: np.ndarray | None = None, **kw) -> CalibrationResult:
    """A weighted result at POSE whose observability comes from ``information`` (default: the covariance's)."""
    information = np.linalg.inv(covariance) if information is None else information
    fields = {"arm_T_camera": POSE, "covariance": covariance, "method": "weighted", "converged": True,
              "iterations": 9, "final_error": 3.0, "measurements": measurements(),
              "observability": analyse_observability(information, POSE), "sigma_px": 1.2214}
    fields.update(kw)
    return CalibrationResult(**fields)


def information(eigenvalues, rotation_basis=None, translation_basis=None) -> np.ndarray:
    """A 6x6 information whose eigenvectors are pure rotations (columns of ``rotation_basis``, first three
    eigenvalues) and pure translations (camera frame; the last three); the bases default to the axes."""
    V = np.zeros((6, 6))
    V[:3, :3] = np.eye(3) if rotation_basis is None else rotation_basis
    V[3:, 3:] = np.eye(3) if translation_basis is None else translation_basis
    return V @ np.diag(eigenvalues) @ V.T


def with_null(null: np.ndarray, others=(1e6, 2e6, 5e6, 1e7, 3e7)) -> np.ndarray:
    """A 6x6 information with the unit vector ``null`` as its only exact null direction."""
    basis, _, _ = np.linalg.svd(null.reshape(6, 1), full_matrices=True)  # first column: ±null
    return basis @ np.diag([0.0, *others]) @ basis.T


def arm_rpy_deg(pose: gtsam.Pose3) -> np.ndarray:
    R = pose.rotation().matrix()
    return np.degrees([np.arctan2(R[2, 1], R[2, 2]), -np.arcsin(R[2, 0]), np.arctan2(R[1, 0], R[0, 0])])


def bracketed(text: str, label: str) -> np.ndarray:
    """The numbers in the first [...] after ``label``."""
    match = re.search(re.escape(label) + r"\s*\[([^\]]*)\]", text)
    assert match, f"no [...] after {label!r} in: {text}"
    return np.array(floats(match.group(1)))


# ---------------------------------------------------------------------------------------------------
# observability_words


def test_a_determined_pose_is_one_sentence_with_its_condition_number():
    obs = analyse_observability(information([1e8 / 1234.0, 3e5, 2e6, 4e6, 7e7, 1e8]), POSE)
    words = observability_words(obs)
    assert len(words) == 1
    assert "all six degrees of freedom" in words[0] and "DEGENERATE" not in words[0]
    assert after(words[0], "condition number") == pytest.approx(1234.0, rel=5e-3)  # three significant digits


def test_a_null_translation_is_named_by_its_direction_in_the_arm_frame():
    t = np.array([0.6, -0.2, -0.7]) / np.linalg.norm([0.6, -0.2, -0.7])
    obs = analyse_observability(with_null(np.concatenate([np.zeros(3), t])), POSE)
    words = observability_words(obs)
    assert len(words) == 2
    # the verdict first, with the advice: a pose whose axis is unlike the others
    assert words[0].startswith("DEGENERATE") and "add a pose" in words[0] and "misses their common point" in words[0]
    assert "camera position" in words[1] and "not determined at all" in words[1] and "combined" not in words[1]
    printed = bracketed(words[1], "direction")
    in_arm = POSE.rotation().matrix() @ t
    assert abs(printed @ in_arm) == pytest.approx(1.0, abs=2e-3)  # the arm-frame direction, up to its sign
    assert abs(printed @ t) < 0.9  # ... not the camera-frame one


def test_a_null_rotation_with_translation_is_named_as_a_turn_with_its_shift_per_degree_in_the_arm_frame():
    null = np.array([0.3, 0.0, 0.0, 0.0, 0.5, 0.2])
    null /= np.linalg.norm(null)
    obs = analyse_observability(with_null(null), POSE)
    words = observability_words(obs)
    assert words[0].startswith("DEGENERATE") and len(words) == 2
    assert words[1].startswith("turning the camera") and "not determined at all" in words[1]
    assert "eigenvector" not in words[1]
    R = POSE.rotation().matrix()
    axis, shift = bracketed(words[1], "axis"), bracketed(words[1], "direction")
    rotation, translation = R @ null[:3], R @ null[3:]
    sign = np.sign(axis @ rotation)
    np.testing.assert_allclose(axis, sign * rotation / np.linalg.norm(rotation), atol=1e-3)
    # the same sign: one direction of the tangent, a turn and the shift that goes with it
    np.testing.assert_allclose(shift, sign * translation / np.linalg.norm(translation), atol=1e-3)
    per_degree = 1000 * np.linalg.norm(translation) / np.degrees(np.linalg.norm(rotation))
    assert after(words[1], "moving it") == pytest.approx(per_degree, rel=5e-3)  # printed to 3 digits


def test_a_poorly_determined_direction_gives_its_sigma_and_one_within_the_limit_is_not_named():
    # translation with 1σ 0.1 m (beyond UNOBSERVABLE_SIGMA_M = 0.05 m); rotation with 1σ 0.08 rad (under 5°)
    rotations = gtsam.Rot3.Rz(0.5).matrix()
    translations = gtsam.Rot3.Rx(0.7).matrix()
    obs = analyse_observability(information([1 / 0.08**2, 1e8, 1e8, 100.0, 1e8, 1e8], rotations, translations),
                                POSE)
    words = observability_words(obs)
    assert len(words) == 2 and words[0].startswith("DEGENERATE")
    assert "poorly determined" in words[1] and "not determined at all" not in words[1]
    assert after(words[1], "1-sigma") == pytest.approx(100.0, rel=1e-3)  # in mm
    printed = bracketed(words[1], "direction")
    assert abs(printed @ (POSE.rotation().matrix() @ translations[:, 0])) == pytest.approx(1.0, abs=2e-3)


def test_a_poorly_determined_sigma_has_its_unit_mm_for_translation_degrees_for_rotation():
    translation = analyse_observability(information([1e8, 1e8, 1e8, 100.0, 1e8, 1e8]), POSE)  # 1σ 0.1 m
    words = observability_words(translation)[1]
    assert "camera position" in words and re.search(r"1-sigma 100 mm\b", words)
    rotation = analyse_observability(information([1 / 0.2**2, 1e8, 1e8, 1e8, 1e8, 1e8]), POSE)  # 1σ 0.2 rad
    words = observability_words(rotation)[1]
    assert "poorly determined" in words and after(words, "1-sigma") == pytest.approx(np.degrees(0.2), rel=5e-3)
    assert re.search(r"1-sigma " + NUMBER + "°", words) and " mm" not in words
    # a pure rotation is named as one, about its arm-frame axis (not "a combined rotation and translation [0 0 0]")
    assert "camera rotation about the arm-frame axis" in words and "translation" not in words
    printed = bracketed(words, "axis")
    assert abs(printed @ POSE.rotation().matrix()[:, 0]) == pytest.approx(1.0, abs=2e-3)


def test_a_poorly_determined_direction_that_mixes_rotation_and_translation_gives_its_sigma_in_degrees_and_mm():
    mixed = np.array([0.3, 0.0, 0.0, 0.0, 0.5, 0.2])
    mixed /= np.linalg.norm(mixed)
    basis, _, _ = np.linalg.svd(mixed.reshape(6, 1), full_matrices=True)
    obs = analyse_observability(basis @ np.diag([1 / 0.2**2, 1e6, 2e6, 5e6, 1e7, 3e7]) @ basis.T, POSE)  # 1σ 0.2
    words = observability_words(obs)[1]
    assert words.startswith("turning the camera") and "poorly determined" in words
    # what that moves: 0.2 x the unit vector's parts, in degrees and mm (no tangent units)
    assert after(words, "1-sigma") == pytest.approx(np.degrees(0.2 * np.linalg.norm(mixed[:3])), rel=1e-2)
    assert after(words, "of that turn with its") == pytest.approx(200 * np.linalg.norm(mixed[3:]), rel=1e-2)
    assert "rad and m" not in words


def test_each_undetermined_direction_has_its_own_sentence():
    obs = analyse_observability(information([1e6, 2e6, 3e6, 0.0, 0.0, 1e7]), POSE)
    words = observability_words(obs)
    assert len(words) == 3 and words[0].startswith("DEGENERATE")
    assert all("camera position" in w and "not determined at all" in w for w in words[1:])
    directions = [bracketed(w, "direction") for w in words[1:]]
    assert abs(directions[0] @ directions[1]) < 1e-2  # two different directions, not one twice


# ---------------------------------------------------------------------------------------------------
# axis_consistency_sentence


def test_consistent_axes_are_said_to_agree_with_their_pixel_noise():
    words = axis_consistency_sentence(AxisConsistency(5.7, 6, 0.457, 1.0))
    assert after(words, "χ² =") == 5.7 and after(words, "for") == 6 and after(words, "P(χ² ≥ this) =") == 0.46
    assert "consistent with the pixel noise" in words
    assert "scaled" not in words and "disagree" not in words and "floor" not in words


def test_axes_left_unscaled_by_a_switched_off_test_are_not_called_consistent():
    words = axis_consistency_sentence(AxisConsistency(50.0, 6, 1e-8, 1.0))  # axis_consistency_p=0
    assert "consistent with the pixel noise" not in words
    assert "disagree beyond their pixel noise" in words and "not scaled" in words and "axis_consistency_p" in words


def test_scaled_axes_give_the_scale_and_its_rule_without_a_floor():
    words = axis_consistency_sentence(AxisConsistency(30.0, 8, 2.1e-4, 5.0))
    assert after(words, "χ² =") == 30 and after(words, "for") == 8
    assert after(words, "P(χ² ≥ this) =") == pytest.approx(2.1e-4)
    assert "disagree beyond their pixel noise" in words and "consistent with" not in words
    assert after(words, "scaled by") == 5.0 and "χ²/(dof − 2)" in words
    # the causes a user can check: errors shared across tracks
    assert "tracker" in words and "joint angles" in words and "intrinsics" in words
    assert "floor" not in words


def test_a_floor_on_the_axes_is_given_in_pixels_with_why():
    words = axis_consistency_sentence(AxisConsistency(30.0, 8, 2.1e-4, 5.0, floor_px=0.27))
    assert after(words, "scaled by") == 5.0
    assert after(words, "a floor of") == 0.27 and "0.27 px" in words
    assert "does not shrink with more tracks" in words


def test_with_two_dof_the_scale_is_the_birge_ratio():
    words = axis_consistency_sentence(AxisConsistency(14.0, 2, 9.1e-4, 7.0))
    assert after(words, "for") == 2 and after(words, "scaled by") == 7.0
    assert "(χ²/dof)" in words and "dof − 2" not in words


# ---------------------------------------------------------------------------------------------------
# evidence_words, untrusted_words


def test_evidence_counts_tracks_and_points_and_rounds_the_longest_arc():
    one = evidence_words(measurement(3, 1, n_points=80, arc_span_deg=None))
    assert re.search(r"\b1 track\b", one) and "1 tracks" not in one and after(one, "track,") == 80
    assert "arc" not in one  # an unknown arc is not invented
    weak = evidence_words(measurement(2, 3, n_points=240, arc_span_deg=41.4))
    assert "3 tracks" in weak and after(weak, "tracks,") == 240 and after(weak, "longest arc") == 41


def thin(c: AxisConsistency | None, ms=None) -> CalibrationResult:
    ms = ms or [measurement(0), measurement(1), measurement(2, 3, n_points=240, arc_span_deg=41.0, weak=True),
                measurement(3), measurement(4), measurement(5)]
    return result(measurements=ms, axis_consistency=c,
                  untrusted={"thin_evidence": [m.index for m in ms if m.weak]})


def assert_names_the_weak_and_blames_the_tracking(words: str, weak: list[int], strong: list[int]) -> None:
    for k in weak:
        assert f"measurement {k} (" in words
    for k in strong:
        assert f"measurement {k} " not in words
    assert "not the joint angles" in words and "tracking" in words
    assert "Spin the wrist longer" in words and "more texture" in words and "add arm poses" in words


def test_thin_evidence_with_axes_that_disagree_gives_the_test_and_blames_the_tracking():
    c = AxisConsistency(40.0, 6, 1e-5, 10.0)
    assert c.p_value < RESTART_P
    words = untrusted_words(thin(c))
    assert len(words) == 1
    assert after(words[0], "χ² =") == 40 and after(words[0], "for") == 6 and after(words[0], "P =") == 1e-5
    assert "(3 tracks, 240 points, longest arc 41°)" in words[0]  # the weak measurement's evidence
    assert_names_the_weak_and_blames_the_tracking(words[0], [2], [0, 1, 3, 4, 5])
    assert "too few measurements" not in words[0] and "strong evidence" not in words[0]


def test_thin_evidence_with_nothing_to_test_the_axes_says_so():
    ms = [measurement(0), measurement(1), measurement(2, 2, arc_span_deg=30.0, weak=True)]
    words = untrusted_words(thin(None, ms))
    assert len(words) == 1
    assert "nothing tests the image axes" in words[0] and "too few measurements" in words[0]
    assert "χ²" not in words[0]
    assert_names_the_weak_and_blames_the_tracking(words[0], [2], [0, 1])


def test_thin_evidence_with_too_few_strong_measurements_counts_them():
    ms = [measurement(0), measurement(1), measurement(2, 3, weak=True), measurement(3, 5, arc_span_deg=60.0, weak=True),
          measurement(4, outlier=True, weight=0.0, outlier_kind="disagrees", outlier_values={"limit": 13.8})]
    c = AxisConsistency(2.0, 4, 0.74, 1.0)
    assert c.p_value >= RESTART_P
    words = untrusted_words(thin(c, ms))
    assert len(words) == 1
    # two strong (the outlier does not count), and MIN_MEASUREMENTS are needed without the weak ones
    assert after(words[0], "only") == 2 and after(words[0], "evidence;") == MIN_MEASUREMENTS
    assert "χ²" not in words[0]
    assert_names_the_weak_and_blames_the_tracking(words[0], [2, 3], [0, 1, 4])


@pytest.mark.parametrize("factor", [0.5, 2.0])
def test_thin_evidence_blames_disagreeing_axes_only_below_the_restart_level(factor):
    words = untrusted_words(thin(AxisConsistency(20.0, 6, factor * RESTART_P, 5.0)))[0]
    assert ("disagree with the estimate" in words) is (factor < 1.0)
    assert ("strong evidence" in words) is (factor > 1.0)


def test_thin_evidence_names_only_measurements_of_the_result():
    r = thin(AxisConsistency(40.0, 6, 1e-5, 10.0))
    r.untrusted = {"thin_evidence": [2, 99]}
    words = untrusted_words(r)
    assert "measurement 2 (" in words[0] and "measurement 99" not in words[0]


@pytest.mark.parametrize("c", [AxisConsistency(40.0, 6, 1e-5, 10.0), None, AxisConsistency(2.0, 4, 0.74, 1.0)])
@pytest.mark.parametrize("ks", [[], [99]])
def test_thin_evidence_naming_no_measurement_of_the_result_prints_no_empty_list(c, ks):
    r = thin(c)
    r.untrusted = {"thin_evidence": ks}  # e.g. a result file written by another version
    words = untrusted_words(r)
    assert len(words) == 1
    assert not re.search(r":\s*\.", words[0]) and "Gaussian: " not in words[0]  # not "...Gaussian: . Few..."
    assert "these measurements" not in words[0]  # nothing to point at
    assert "measurement 99" not in words[0] and "measurement 2 (" not in words[0]
    assert "too little evidence" in words[0] and "Few or short arcs" in words[0]
    assert_names_the_weak_and_blames_the_tracking(words[0], [], [0, 1, 2, 3, 4, 5])


#: what ``calibration.run._untrusted`` reads of the setup: the wrist axes (the camera's distance to them)
SETUP = SimpleNamespace(axes=[SimpleNamespace(point=np.zeros(3))])


def left_out(index: int, n_tracks: int = 2, **kw) -> MeasurementReport:
    """A weak measurement the estimate did not use (an outlier, weight 0)."""
    return measurement(index, n_tracks, weak=True, outlier=True, weight=0.0, arc_span_deg=20.0,
                       outlier_kind="thin", outlier_values={"used": 4}, **kw)


def test_thin_evidence_names_the_weak_measurements_used_not_the_weak_ones_left_out():
    ms = [measurement(0), measurement(1), measurement(2, 3, n_points=240, arc_span_deg=41.0, weak=True), left_out(3),
          measurement(4), left_out(5)]
    r = result(measurements=ms, axis_consistency=AxisConsistency(40.0, 6, 1e-5, 10.0))
    r.untrusted = _untrusted(r, SETUP)
    assert r.untrusted == {"thin_evidence": [2]}
    words = untrusted_words(r)
    assert len(words) == 1 and "measurement 2 (3 tracks, 240 points, longest arc 41°)" in words[0]
    assert "measurement 3 " not in words[0] and "measurement 5 " not in words[0]


@pytest.mark.parametrize("c", [None, AxisConsistency(40.0, 6, 1e-5, 10.0), AxisConsistency(2.0, 4, 0.74, 1.0)])
def test_thin_evidence_is_set_as_before_and_never_with_an_empty_list(c):
    """Each of strong, weak used, weak left out, strong left out and weak called an outlier for its residual RMS
    alone (still used: weight > 0) in each of five measurements: the flag is set exactly where the rule sets it
    (weak measurements used, and the axes disagree, or nothing tests them, or too few strong ones), and it then
    names the weak ones used, never none. The weak outlier by RMS counts as used (it was taken as unused)."""
    kinds = {"strong": lambda k: measurement(k), "weak": lambda k: measurement(k, 3, weak=True),
             "weak out": left_out, "strong out": lambda k: measurement(k, outlier=True, weight=0.0),
             "weak rms": lambda k: measurement(k, 3, weak=True, outlier=True, weight=0.3,
                                               outlier_kind="residual", outlier_values={"ratio": 3.0, "median": 1.2})}
    for combo in itertools.product(kinds, repeat=5):
        r = result(measurements=[kinds[kind](k) for k, kind in enumerate(combo)], axis_consistency=c)
        weak_used = [k for k, kind in enumerate(combo) if kind in ("weak", "weak rms")]
        rule = bool(weak_used) and (c is None or c.p_value < RESTART_P or combo.count("strong") < MIN_MEASUREMENTS)
        untrusted = _untrusted(r, SETUP)
        assert ("thin_evidence" in untrusted) is rule, combo
        if rule:
            assert untrusted["thin_evidence"] == weak_used, combo


def test_a_camera_error_and_a_used_measurement_that_explain_the_axes_alike_make_the_result_untrusted():
    """The intrinsics check undecided (a plausible camera change explains the axes, and one wrong measurement as
    well): where the estimate left that measurement out it acted on the rival and nothing is flagged; where it
    still uses it the result is not trusted, the measurement and the camera's reading named."""
    check = {"exact_chi2": 27.9, "exact_dof": 6, "exact_p": 1e-4, "chi2": 0.02, "dof": 3, "p_value": 0.99,
             "focal_percent": -2.3, "cx_px": 2.4, "cy_px": -4.3, "one_out_chi2": 1.7, "one_out_measurement": 1,
             "one_out_moved_chi2": 48.6, "undecided": True, "measurements": [0, 1, 2, 3, 4, 5], "likely": False}
    c = AxisConsistency(27.9, 6, 1e-4, 7.0, intrinsics=check)
    r = result(axis_consistency=c)
    r.untrusted = _untrusted(r, SETUP)
    assert r.untrusted == {"camera_or_measurement": [1]} and not r.covariance_usable
    words = untrusted_words(r)
    assert len(words) == 1 and "without measurement 1" in words[0] and "-2.3 % in focal length" in words[0]
    assert "Check measurement 1's joint readings and tracks, and the intrinsics" in words[0]
    ms = measurements()
    ms[1] = measurement(1, outlier=True, weight=0.0, outlier_kind="disagrees", outlier_values={"limit": 30.0})
    assert _untrusted(result(measurements=ms, axis_consistency=c), SETUP) == {}
    assert _untrusted(result(axis_consistency=AxisConsistency(27.9, 6, 1e-4, 7.0, intrinsics={
        **check, "undecided": False})), SETUP) == {}


def test_inconsistent_axes_give_their_reduced_chi2_and_the_model_errors_to_check():
    r = result(axis_consistency=AxisConsistency(1200.0, 6, 0.0, 300.0), untrusted={"inconsistent": [0, 1, 2]})
    words = untrusted_words(r)
    assert len(words) == 1
    assert after(words[0], "χ²/dof =") == pytest.approx(200.0) and f"{MAX_CONSISTENCY_SCALE:g}x" in words[0]
    assert "the model does not describe the data" in words[0]
    for cause in ("intrinsics", "joint angles", "moved camera", "not on the hand"):
        assert cause in words[0]


def test_a_runaway_pose_whose_axes_do_not_project_is_said_so_not_scaled_by_inf():
    c = AxisConsistency(np.inf, 6, 0.0, np.inf)
    sentence = axis_consistency_sentence(c)
    assert "do not project" in sentence and "inf" not in sentence
    words = untrusted_words(result(axis_consistency=c, untrusted={"inconsistent": [0, 1, 2]}))
    assert len(words) == 1 and "do not even project" in words[0] and "poor minimum" in words[0]
    assert "inf" not in words[0]
    r = result(untrusted={"too_uncertain": []})
    r.covariance = np.full((6, 6), np.inf)
    words = untrusted_words(r)
    assert words == [w for w in words if "not finite" in w and "inf" not in w] and len(words) == 1


def test_a_reason_this_version_does_not_know_is_still_said():
    words = untrusted_words(result(untrusted={"future_reason": [1]}))
    assert len(words) == 1 and "'future_reason'" in words[0] and "measurement 1 (" in words[0]


def test_unmeasured_scatter_counts_the_measurements_and_asks_for_more_poses():
    r = result(measurements=measurements(4), axis_consistency=AxisConsistency(14.0, 2, 9.1e-4, 7.0),
               untrusted={"unmeasured_scatter": [0, 1, 2, 3]})
    words = untrusted_words(r)
    assert len(words) == 1
    assert after(words[0], "χ² =") == 14 and after(words[0], "for") == 2 and after(words[0], "P =") == 9.1e-4
    assert after(words[0], "only") == 4 and "measurements are used" in words[0]
    assert "no covariance can be given" in words[0] and "add arm poses" in words[0]


def test_too_uncertain_gives_the_largest_sigmas_and_the_limits():
    # 80 mm along the camera's x and 3° about its y; the position's 1σ is given in the arm frame
    covariance = np.diag(np.concatenate([np.radians([1.0, 3.0, 0.5]), [0.08, 0.01, 0.02]]) ** 2)
    R = POSE.rotation().matrix()
    arm_mm = 1000 * np.sqrt(np.diag(R @ covariance[3:, 3:] @ R.T))
    assert abs(arm_mm.max() - 80.0) > 5.0
    r = result(covariance, untrusted={"too_uncertain": []})
    words = untrusted_words(r)
    assert len(words) == 1
    assert after(words[0], "1σ (") == pytest.approx(arm_mm.max(), rel=5e-3)
    assert after(words[0], "mm,") == pytest.approx(3.0)
    assert f"{100 * MAX_RELATIVE_SIGMA:g} %" in words[0] and f"{MAX_SIGMA_DEG:g}°" in words[0]
    assert "add arm poses" in words[0]


def test_every_kind_of_distrust_has_words_one_sentence_each_in_order():
    c = AxisConsistency(1200.0, 6, 0.0, 300.0)
    ms = measurements()
    ms[2].weak = True
    r = result(measurements=ms, axis_consistency=c)
    for kind in UNTRUSTED_KINDS:
        r.untrusted = {kind: [2]}
        assert len(untrusted_words(r)) == 1, kind
    r.untrusted = {"inconsistent": [0, 1, 2, 3, 4, 5], "thin_evidence": [2]}
    first, second = untrusted_words(r)
    assert "χ²/dof" in first and "not the joint angles" in second
    r.untrusted = {}
    assert untrusted_words(r) == []


# ---------------------------------------------------------------------------------------------------
# kinematics_words, tracking_words


@pytest.mark.parametrize("sigma", [0.05, 0.25, 1.5])
def test_kinematics_with_joint_noise_give_its_sigma(sigma):
    words = kinematics_words(sigma)
    assert after(words, "uncertain by") == sigma and "propagated into the covariance" in words
    assert "exact" not in words


def test_kinematics_without_joint_noise_say_they_are_taken_as_exact_and_how_to_declare_it():
    words = kinematics_words(0.0)
    assert "taken as exact" in words and "not in this covariance" in words
    assert "joint_sigma_deg" in words and "--joint-sigma-deg" in words
    assert not floats(words)


@pytest.mark.parametrize("floor", [0.1, 0.3, 2.0])
def test_tracking_with_a_floor_gives_it_in_pixels(floor):
    words = tracking_words(floor)
    assert after(words, "at least") == floor and f"{floor:g} px" in words
    assert "independent" not in words


@pytest.mark.parametrize("floor", [0.0, 0.09])
def test_tracking_with_track_offsets_gives_them_in_pixels(floor):
    words = tracking_words(floor, 0.15)
    assert "an image offset of its own, 0.15 px" in words and "--track-offset-px" in words
    assert ("at least" in words) == (floor > 0.0) and "independent, no floor" not in words


def test_tracking_without_a_floor_says_the_errors_are_taken_as_independent_and_how_to_declare_one():
    words = tracking_words(0.0)
    assert "independent" in words and "no floor" in words
    assert "axis_floor_px" in words and "--axis-floor-px" in words
    assert not floats(words)


# ---------------------------------------------------------------------------------------------------
# ambiguity_words


def moved(angle_deg: float, shift_m) -> gtsam.Pose3:
    return POSE.compose(gtsam.Pose3(gtsam.Rot3.Rz(np.radians(angle_deg)), np.asarray(shift_m, dtype=float)))


def test_ambiguity_locates_each_close_pose_best_first_and_leaves_out_the_far_ones():
    closer, close, far = moved(120.0, [0.3, 0.0, 0.1]), moved(30.0, [0.0, 0.05, 0.0]), moved(90.0, [0.5, 0.0, 0.0])
    r = result(alternatives=[Alternative(close, 3.0), Alternative(far, 500.0), Alternative(closer, 1.0)])
    words = ambiguity_words(r)
    assert "2 other poses" in words
    parts = words.split("camera at")[1:]
    assert len(parts) == 2  # the far one is not among them
    first, second = parts
    np.testing.assert_allclose(bracketed(first, ""), 1000 * closer.translation(), atol=0.05)  # lowest Δχ² first
    np.testing.assert_allclose(bracketed(second, ""), 1000 * close.translation(), atol=0.05)
    assert after(first, "mm,") == round(1000 * np.linalg.norm(closer.translation() - POSE.translation()))
    assert after(first, "mm and") == pytest.approx(120.0, abs=0.05)
    assert after(first, "chi-square only") == 1.0
    assert after(second, "mm,") == round(1000 * np.linalg.norm(close.translation() - POSE.translation()))
    assert after(second, "mm and") == pytest.approx(30.0, abs=0.05)
    assert after(second, "chi-square only") == 3.0
    assert after(words, "a difference below") == pytest.approx(AMBIGUITY_CHI2, abs=0.05)
    assert "cannot tell them apart" in words and "neither this estimate nor its covariance" in words
    assert "do not single one out" in words and "With three arm poses" not in words
    assert "add arm poses" in words and "tilted" in words


def test_ambiguity_with_three_measurements_explains_the_several_exact_solutions():
    r = result(measurements=measurements(MIN_MEASUREMENTS), alternatives=[Alternative(moved(60.0, [0.1, 0, 0]), 0.2)])
    words = ambiguity_words(r)
    assert re.search(r"\b1 other pose of\b", words)  # one pose, not "poses"
    assert "With three arm poses" in words and "several exact solutions" in words
    assert "do not single one out" not in words


def test_ambiguity_with_a_pose_that_fits_better_says_so_not_only_zero_worse():
    better, worse = moved(60.0, [0.1, 0.0, 0.0]), moved(20.0, [0.0, 0.02, 0.0])
    r = result(alternatives=[Alternative(worse, 2.5), Alternative(better, -4.0)])
    words = ambiguity_words(r)
    first, second = words.split("camera at")[1:]
    np.testing.assert_allclose(bracketed(first, ""), 1000 * better.translation(), atol=0.05)  # lowest Δχ² first
    assert "worse" not in first and "only 0" not in first
    assert after(first, "chi-square") == 4.0 and "lower" in first and "fits better" in first
    assert after(second, "chi-square only") == 2.5 and "worse" in second
    assert "almost as well or better" in words
    alone = ambiguity_words(result(alternatives=[Alternative(better, -4.0)]))
    assert "almost" not in alone and "as well or better" in alone and "worse" not in alone
    tie = ambiguity_words(result(alternatives=[Alternative(better, 0.0)]))
    assert "worse" not in tie and "fits as well as this estimate" in tie


def test_ambiguity_explains_three_poses_by_the_measurements_used_not_the_outliers():
    ms = [*measurements(MIN_MEASUREMENTS), measurement(MIN_MEASUREMENTS, 2, outlier=True, weight=0.0)]
    r = result(measurements=ms, alternatives=[Alternative(moved(60.0, [0.1, 0, 0]), 0.2)])
    words = ambiguity_words(r)
    assert "With three arm poses" in words and "several exact solutions" in words
    assert "do not single one out" not in words


def test_ambiguity_from_leaving_out_another_measurement_names_the_pair_not_the_pose_geometry():
    r = result(alternatives=[Alternative(moved(10.0, [0.02, 0.0, 0.0]), 1.5, left_out=2, instead_of=4),
                             Alternative(moved(90.0, [0.5, 0.0, 0.0]), 500.0, left_out=1, instead_of=4)])
    words = ambiguity_words(r)
    assert "(leaving out measurement 2 instead of measurement 4)" in words
    assert "measurement 4 or 2" in words and "measurement 4 or 1" not in words  # the far one is not a suspect
    assert "joint angles and tracks" in words and "tilted" not in words
    assert "one of measurement 4 or 2 is wrong" in verdict(r) and "tilted" not in verdict(r)
    assert "tilted" in verdict(result(alternatives=[Alternative(moved(60.0, [0.1, 0, 0]), 0.2)]))
    mixed = ambiguity_words(result(alternatives=[Alternative(moved(10.0, [0.02, 0, 0]), 1.5, left_out=2, instead_of=4),
                                                 Alternative(moved(60.0, [0.1, 0, 0]), 0.2)]))
    assert "measurement 4 or 2" in mixed and mixed.count("leaving out measurement") == 1
    assert "do not single one out" in mixed  # the other minimum of the same measurements still gets its advice
    swaps = [Alternative(moved(10.0 + i, [0.02, 0, 0]), fit, left_out=k, instead_of=3)
             for i, (fit, k) in enumerate([(3.0, 2), (0.1, 0), (5.0, 1)])]
    several = ambiguity_words(result(alternatives=swaps))
    assert "(measurement 3, 0, 2 or 1)" in several  # the estimate's left-out one, then the others best fit first


def test_a_result_that_is_not_ambiguous_has_no_ambiguity_words():
    assert not result().ambiguous and not ambiguity_words(result())
    far = result(alternatives=[Alternative(moved(90.0, [0.5, 0.0, 0.0]), 500.0)])
    assert not far.ambiguous and not ambiguity_words(far)  # not "0 other pose of the camera fit ..."


# ---------------------------------------------------------------------------------------------------
# summary


def test_summary_prints_the_pose_its_sigma_and_each_measurement():
    ms = [measurement(0, 14, n_points=1730, residual_rms_px=1.2291, weight=0.994),
          measurement(1, 12, n_points=1598, residual_rms_px=1.2049, weight=1.031, rejected_tracks={3: "short"}),
          measurement(2, 12, rejected_tracks={1: "a", 4: "b"}),
          measurement(3, 1, outlier=True, weight=0.0, outlier_kind="disagrees", outlier_values={"limit": 13.8},
                      axis_chi2=40.0)]
    r = result(measurements=ms, iterations=17, sigma_px=1.2214)
    text = summary(r)
    head = text.splitlines()[1]  # after the verdict
    assert "weighted" in head and "converged" in head and "NOT" not in head
    assert after(head, "converged,") == 17 and after(head, "pixel sigma") == 1.221
    np.testing.assert_allclose(floats(line_starting(text, "translation (mm):")), 1000 * POSE.translation(),
                               atol=0.005)
    np.testing.assert_allclose(floats(line_starting(text, "roll/pitch/yaw (deg):")), arm_rpy_deg(POSE), atol=5e-4)
    # 1σ of the position in the arm frame, computed here from the camera-frame covariance
    R = POSE.rotation().matrix()
    arm_mm = 1000 * np.sqrt(np.diag(R @ COVARIANCE[3:, 3:] @ R.T))
    assert not np.allclose(arm_mm, SIGMA_MM, atol=0.01)  # the frame matters for this pose
    position = line_starting(text, "1-sigma position, arm frame (mm):").split(":")[1]
    np.testing.assert_allclose(floats(position), arm_mm, atol=5e-4)
    np.testing.assert_allclose(floats(line_starting(text, "1-sigma rotation (deg):").split(":")[1]), SIGMA_DEG,
                               atol=5e-5)
    assert "all six degrees of freedom" in text
    assert "COVARIANCE UNUSABLE" not in text and "AMBIGUOUS" not in text and "image axes vs" not in text
    lines = {k: line_starting(text, f"measurement {k}:") for k in range(4)}
    assert floats(lines[0]) == [0, 14, 1730, 1.229, 0.99, 0]
    assert floats(lines[1]) == [1, 12, 1598, 1.205, 1.03, 1]
    assert "1 track rejected" in lines[1] and "2 tracks rejected" in lines[2]
    assert ("OUTLIER (left out: its image axis disagrees with the FK axis projected by the estimate (chi-square 40 > "
            "13.8, 2 dof); check its joint angles)") in lines[3]
    assert not any("OUTLIER" in lines[k] for k in range(3))


def test_summary_says_when_the_solver_did_not_converge():
    assert "NOT converged" in summary(result(converged=False)).splitlines()[1]


def test_summary_states_what_the_covariance_assumes_of_kinematics_and_tracking():
    text = summary(result(joint_sigma_deg=0.2, axis_floor_px=0.35))
    assert after(line_starting(text, "kinematics:"), "uncertain by") == 0.2
    assert after(line_starting(text, "tracking:"), "at least") == 0.35
    text = summary(result())
    assert "taken as exact" in line_starting(text, "kinematics:")
    assert "no floor" in line_starting(text, "tracking:")


def test_summary_shows_the_axis_test_only_when_it_changed_the_covariance():
    scaled = summary(result(axis_consistency=AxisConsistency(30.0, 8, 2.1e-4, 5.0, floor_px=0.27)))
    line = line_starting(scaled, "image axes vs")
    assert after(line, "scaled by") == 5.0 and after(line, "a floor of") == 0.27
    assert "1-sigma position" in scaled  # scaled, the covariance is still given
    assert "image axes vs" not in summary(result(axis_consistency=AxisConsistency(5.7, 6, 0.457, 1.0)))


def test_summary_of_an_untrusted_result_gives_the_reasons_not_the_sigmas():
    ms = measurements()
    ms[2] = measurement(2, 3, n_points=240, arc_span_deg=41.0, weak=True)
    r = result(measurements=ms, axis_consistency=AxisConsistency(40.0, 6, 1e-5, 10.0),
               untrusted={"thin_evidence": [2], "too_uncertain": []})
    text = summary(r)
    assert "1-sigma position" not in text and "1-sigma rotation" not in text
    unusable = [line.strip() for line in text.splitlines() if "COVARIANCE UNUSABLE" in line]
    assert unusable == ["COVARIANCE UNUSABLE: " + w for w in untrusted_words(r)] and len(unusable) == 2
    assert "the arm poses do not determine" not in text and "one of several poses" not in text


def test_summary_of_an_ambiguous_result_says_so_first_and_gives_no_sigma():
    r = result(alternatives=[Alternative(moved(120.0, [0.3, 0.0, 0.1]), 1.0)], untrusted={"too_uncertain": []})
    text = summary(r)
    assert "AMBIGUOUS: " + ambiguity_words(r) in text
    assert "one of several poses that fit the data" in text
    assert "1-sigma position" not in text
    assert untrusted_words(r)[0] not in text  # the ambiguity is the reason given, not a second one
    assert text.index("AMBIGUOUS") < text.index("COVARIANCE UNUSABLE")


def test_summary_of_undetermined_poses_blames_the_poses_and_names_the_direction():
    t = np.array([0.0, 0.0, 0.0, 0.0, 0.6, 0.8])
    r = result(information=with_null(t))
    assert not r.observability.is_observable and not r.covariance_usable
    text = summary(r)
    assert "COVARIANCE UNUSABLE: the arm poses do not determine the calibration" in text
    assert "DEGENERATE" in text and "camera position along the arm-frame direction" in text
    assert "1-sigma position" not in text


def test_summary_of_a_calibration_prints_its_numbers(reference_weighted):
    _, _, r = reference_weighted
    text = summary(r)
    np.testing.assert_allclose(floats(line_starting(text, "translation (mm):")), 1000 * r.arm_T_camera.translation(),
                               atol=0.005)
    position = line_starting(text, "1-sigma position, arm frame (mm):").split(":")[1]
    np.testing.assert_allclose(floats(position), r.sigma_mm_arm, atol=5e-4)
    assert after(text, "condition number") == pytest.approx(r.observability.condition_number, rel=5e-3)
    for m in r.measurements:
        line = line_starting(text, f"measurement {m.index}:")
        assert floats(line)[:4] == [m.index, m.n_tracks, m.n_points, round(m.residual_rms_px, 3)]


@pytest.mark.parametrize("kind, values, extra, expected, blames_joints", [
    ("few_tracks", {}, {}, "left out: only 1 usable track(s), need at least 2", False),
    ("thin", {"used": 5}, {"weak": True, "arc_span_deg": 41.0},
     "left out: too little evidence for a reliable image axis (1 track, 100 points, longest arc 41°); the 5 stronger",
     False),
    ("disagrees", {"limit": 13.8}, {"axis_chi2": 52.0}, "(chi-square 52 > 13.8, 2 dof); check its joint angles", True),
    ("disagrees", {"limit": 13.8, "miss_px": 3.2, "joint_deg": 0.21, "tracking_bias_px": 1.0}, {"axis_chi2": 52.0},
     "it passes 3.2 px from that axis, where a joint error of 0.21° would put it, farther than a tracker's shared bias "
     "(up to 1 px) moves an axis: check its joint angles", True),
    ("disagrees", {"limit": 13.8, "miss_px": 0.6, "joint_deg": 0.04, "tracking_bias_px": 1.0}, {"axis_chi2": 52.0},
     "it passes 0.6 px from that axis, where a joint error of 0.04° would put it, but a shift its tracks share of "
     "that size", False),
    ("disagrees", {"limit": 13.8}, {"axis_chi2": 52.0, "weak": True}, "its own evidence is thin", False),
    ("disagrees", {"limit": 13.8, "short_arc_deg": 48.0}, {"axis_chi2": 52.0},
     "its tracks or its joint angles are off. The arcs of measurement(s) 3: 48° (longest) are short", True),
    ("residual", {"ratio": 3.0, "median": 1.2}, {"residual_rms_px": 4.0}, "residual RMS 4.00 px > 3x the median 1.20",
     False),
    ("text", {"text": "an older file's words"}, {}, "an older file's words", False),
])
def test_outlier_words_say_each_kind_with_its_numbers(kind, values, extra, expected, blames_joints):
    m = measurement(3, 1, n_points=100, outlier=True, weight=0.0, outlier_kind=kind, outlier_values=values, **extra)
    words = outlier_words(m)
    assert expected in words
    assert ("joint angles" in words and "only if that does not help" not in words
            and "check its tracking first" not in words) is blames_joints
    assert outlier_words(measurement(3)) == ""


def test_a_result_file_of_before_the_outlier_kinds_keeps_its_words():
    ms = [measurement(0), measurement(1, outlier=True, weight=0.0, outlier_kind="disagrees",
                                      outlier_values={"limit": 13.8}, axis_chi2=40.0)]
    data = result(measurements=ms).to_dict()
    again = CalibrationResult.from_dict(data)
    assert again.measurements[1].outlier_kind == "disagrees" and outlier_words(again.measurements[1]) == outlier_words(
        ms[1])
    for m in data["measurements"]:  # as version 1 files of before the kinds wrote them
        m.pop("outlier_kind"), m.pop("outlier_values")
        m["outlier_reason"] = "axis far from the others" if m["outlier"] else ""
    old = CalibrationResult.from_dict(data)
    assert outlier_words(old.measurements[1]) == "axis far from the others" and old.measurements[0].outlier_kind == ""

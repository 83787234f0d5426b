"""Shared helpers of the scenario scripts (issue 6): command line, checks and verdict, figures, errors.

Every scenario is run as ``python scenarios/NAME.py [--quick] [--out DIR] [--seed N]``. It prints what it does,
the numbers, the report's observability words, one line per check and a final ``VERDICT: PASS — ...`` or
``VERDICT: FAIL — ...`` line, and writes its figures (PNG) into ``--out`` (default ``out/scenarios/NAME``).
The exit code is 1 when a judged check fails. With ``--quick`` (short spins, few trials: the test suite runs
every scenario this way) the checks that are not robust at that size are printed as ``info`` and not judged.
"""

from __future__ import annotations

import argparse
import importlib.util
import time
from dataclasses import dataclass
from pathlib import Path

import gtsam
import numpy as np

from gtsam_rotid.errors import InputError, RotIdError, SimulationError, ValidationError
from gtsam_rotid.plots import DPI
from gtsam_rotid.report import make_report
from gtsam_rotid.simulate import simulate

ROOT = Path(__file__).resolve().parents[1]
#: 99.9 % point of the chi-square distribution with 6 dof: a 6-D error beyond it is a confident wrong number.
CHI2_6_999 = 22.457744484825326
#: tangent (rad, m) -> (deg, mm)
TANGENT_UNITS = np.array([np.degrees(1.0)] * 3 + [1000.0] * 3)
TANGENT_LABELS = ("rx deg", "ry deg", "rz deg", "tx mm", "ty mm", "tz mm")


# ---------------------------------------------------------------------------------------------------
# command line


def parse_args(name: str, description: str, argv=None, *, seed: int = 0, extra=None) -> argparse.Namespace:
    """``--quick``, ``--out DIR`` (created), ``--seed N``, and whatever ``extra(parser)`` adds."""
    parser = argparse.ArgumentParser(prog=f"scenarios/{name}.py", description=description)
    parser.add_argument("--quick", action="store_true",
                        help="short spins and few trials (about a minute); checks not robust at that size are "
                             "printed but not judged")
    parser.add_argument("--out", type=Path, default=Path("out") / "scenarios" / name,
                        help="directory for the figures (default: %(default)s)")
    parser.add_argument("--seed", type=int, default=seed, help="seed of the simulated scene (default: %(default)s)")
    if extra is not None:
        extra(parser)
    args = parser.parse_args(argv)
    args.out.mkdir(parents=True, exist_ok=True)
    args.name = name
    args.started = time.perf_counter()
    return args


def header(args, title: str, lines=()) -> None:
    size = "--quick (short spins, few trials)" if args.quick else "full size"
    print(f"== scenario {args.name}: {title}")
    for line in lines:
        print(f"   {line}")
    print(f"   {size}, seed {args.seed}, figures in {args.out}")
    print()


# ---------------------------------------------------------------------------------------------------
# checks and verdict


@dataclass
class Check:
    ok: bool
    text: str
    judged: bool


class Verdict:
    """Named pass/fail checks; :meth:`finish` prints them and the verdict line and returns the exit code."""

    def __init__(self, args):
        self.args = args
        self.checks: list[Check] = []

    def check(self, ok, text: str, *, robust_when_quick: bool = True, judge: bool = True) -> bool:
        """Record a check. With ``--quick``, a check that is not ``robust_when_quick`` is shown but not judged;
        ``judge=False`` shows it without judging it at any size (the scenario says why)."""
        ok = bool(ok)
        judged = judge and (robust_when_quick or not self.args.quick)
        self.checks.append(Check(ok, text, judged))
        tag = ("PASS" if ok else "FAIL") if judged else ("info: holds" if ok else "info: does not hold")
        print(f"  [{tag}] {text}")
        return ok

    @property
    def passed(self) -> bool:
        return all(c.ok for c in self.checks if c.judged)

    def finish(self, summary: str, figures=()) -> int:
        """Print the figures written, the run time and ``VERDICT: PASS|FAIL — summary``; return the exit code."""
        for path in figures:
            print(f"wrote {path}")
        failed = [c.text for c in self.checks if c.judged and not c.ok]
        judged = sum(c.judged for c in self.checks)
        seconds = time.perf_counter() - self.args.started
        print(f"\n{judged} checks judged, {len(failed)} failed; {seconds:.0f} s")
        if failed:
            print(f"VERDICT: FAIL — {summary}; failed: " + "; ".join(failed))
            return 1
        print(f"VERDICT: PASS — {summary}")
        return 0


# ---------------------------------------------------------------------------------------------------
# figures


def save_figure(fig, out: Path, name: str) -> Path:
    """Write a matplotlib figure (Agg canvas, as :mod:`gtsam_rotid.plots` makes them) as ``out/name``."""
    path = Path(out) / name
    fig.savefig(path, dpi=DPI)
    return path


def new_figure(width: float = 7.0, height: float = 5.0):
    from gtsam_rotid.plots import new_figure as make

    return make(width, height)


# ---------------------------------------------------------------------------------------------------
# errors against the truth


def tangent_error(estimate: gtsam.Pose3, truth: gtsam.Pose3) -> np.ndarray:
    """Pose3 tangent error (rotation rad about the camera axes, translation m in the camera frame)."""
    return truth.localCoordinates(estimate)


def mahalanobis2(error: np.ndarray, covariance: np.ndarray) -> float:
    """e^T Sigma^-1 e (chi-square with 6 dof when Sigma is honest)."""
    return float(error @ np.linalg.solve(covariance, error))


def position_error_mm(estimate: gtsam.Pose3, truth: gtsam.Pose3) -> np.ndarray:
    """Camera position error in the arm-base frame, mm."""
    return 1000.0 * (np.asarray(estimate.translation()) - np.asarray(truth.translation()))


def rotation_error_deg(estimate: gtsam.Pose3, truth: gtsam.Pose3) -> float:
    """Angle (deg) of the rotation between the estimated and the true camera orientation."""
    return float(np.degrees(np.linalg.norm(truth.rotation().localCoordinates(estimate.rotation()))))


def error_lines(result, truth_pose: gtsam.Pose3, indent: str = "  ") -> list[str]:
    """Error per tangent axis, its ratio to the reported 1σ, and the 6-D Mahalanobis distance."""
    e = tangent_error(result.arm_T_camera, truth_pose)
    sigma = np.sqrt(np.diag(result.covariance))
    lines = [indent + f"{'':18}" + "".join(f" {a:>9}" for a in TANGENT_LABELS),
             indent + f"{'error':18}" + "".join(f" {v:9.4f}" for v in e * TANGENT_UNITS),
             indent + f"{'reported 1 sigma':18}" + "".join(_fmt_sigma(v) for v in sigma * TANGENT_UNITS),
             indent + f"{'error / sigma':18}" + "".join(f" {v:9.2f}" for v in e / sigma)]
    p = position_error_mm(result.arm_T_camera, truth_pose)
    lines.append(indent + f"camera position error {np.linalg.norm(p):.3f} mm (arm frame x, y, z: "
                 f"{p[0]:+.3f}, {p[1]:+.3f}, {p[2]:+.3f} mm), rotation error "
                 f"{rotation_error_deg(result.arm_T_camera, truth_pose):.4f} deg")
    if result.covariance_usable:
        d2 = mahalanobis2(e, result.covariance)
        lines.append(indent + f"Mahalanobis e^T Sigma^-1 e = {d2:.2f} (chi-square, 6 dof: mean 6, 99.9 % point "
                     f"{CHI2_6_999:.1f})")
    else:
        lines.append(indent + "covariance NOT usable (the report says which direction is undetermined)")
    return lines


def _fmt_sigma(value: float) -> str:
    return f" {value:9.4f}" if value < 1e4 else f" {'undeterm.':>9}"


def within_3_sigma(result, truth_pose: gtsam.Pose3) -> tuple[bool, float]:
    """(honest, d2): the 6-D Mahalanobis distance of the error is below the chi-square 99.9 % point."""
    d2 = mahalanobis2(tangent_error(result.arm_T_camera, truth_pose), result.covariance)
    return d2 <= CHI2_6_999, d2


def sigma_along(result, direction_arm: np.ndarray) -> float:
    """Reported 1σ (mm) of the camera position along a unit arm-frame direction."""
    R = result.arm_T_camera.rotation().matrix()
    u = R.T @ (direction_arm / np.linalg.norm(direction_arm))  # the same direction in the camera frame
    return 1000.0 * float(np.sqrt(max(u @ result.covariance[3:, 3:] @ u, 0.0)))


def information(result) -> np.ndarray:
    """The pose information (Pose3 tangent) whose eigen-analysis is the result's observability verdict."""
    obs = result.observability
    return (obs.eigenvectors * np.maximum(obs.eigenvalues, 0.0)) @ obs.eigenvectors.T


def run_calibration(dataset, method: str = "joint", options=None):
    """(result, seconds, None) or (None, seconds, message) when ``calibrate`` refuses with a RotIdError."""
    from gtsam_rotid.estimate import calibrate

    start = time.perf_counter()
    try:
        result = calibrate(dataset, method=method, options=options)
    except RotIdError as error:
        return None, time.perf_counter() - start, f"{type(error).__name__}: {error}"
    return result, time.perf_counter() - start, None


def calibrate_and_print(verdict, dataset, truth_pose: gtsam.Pose3, method: str, label: str, *,
                        heading: str = "  ", indent: str = "  "):
    """Calibrate ``dataset`` with ``method`` and print its time (``{heading}{method}: ... s``) and its error against
    ``truth_pose``; when ``calibrate`` refuses, print why and record the failed check ``{label}: calibrate returns
    an estimate``. Returns the result, or None."""
    result, seconds, failure = run_calibration(dataset, method)
    print(f"{heading}{method}: {seconds:.1f} s")
    if failure:
        print(f"{indent}calibrate FAILED: {failure}")
        verdict.check(False, f"{label}: calibrate returns an estimate")
        return None
    for line in error_lines(result, truth_pose, indent=indent):
        print(line)
    return result


def print_observability(result, dataset=None, indent: str = "  ") -> list[str]:
    """Print (and return) the report's observability words and suggestion."""
    report = make_report(result, dataset)
    words = list(report.observability)
    if report.suggestion:
        words.append(f"SUGGESTION: {report.suggestion}")
    for line in words:
        print(indent + "report: " + line)
    return words


# ---------------------------------------------------------------------------------------------------
# Cramér-Rao bound (benchmarks/accuracy.py's, imported from there)


_ACCURACY = None


def accuracy_module():
    """``benchmarks/accuracy.py`` as a module (the benchmarks directory is not a package)."""
    global _ACCURACY
    if _ACCURACY is None:
        spec = importlib.util.spec_from_file_location("gtsam_rotid_benchmarks_accuracy",
                                                      ROOT / "benchmarks" / "accuracy.py")
        module = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(module)
        _ACCURACY = module
    return _ACCURACY


def crlb(dataset, truth, noise_var: float) -> np.ndarray:
    """Cramér-Rao bound (6x6, Pose3 tangent) of ``arm_T_camera`` for this scene (``benchmarks/accuracy.crlb``)."""
    return accuracy_module().crlb(dataset, truth, noise_var)


# ---------------------------------------------------------------------------------------------------
# arm poses


def pose_problem(arm, config, joint_angles) -> str | None:
    """Why the simulator would refuse this arm pose for this scene (None when it accepts it).

    The simulator checks explicit poses before it spins anything; a one-second spin keeps the check cheap.
    """
    probe = config.with_(joint_angles=(tuple(np.asarray(joint_angles, dtype=float)),), n_measurements=1,
                         duration=1.0, min_track_length=2, noise_var=0.0, outlier_fraction=0.0)
    try:
        simulate(probe, seed=0, arm=arm)
    except SimulationError as error:
        return str(error)
    except (ValidationError, InputError):  # no feature visible during the probe's second: the pose itself is fine
        return None
    return None


def solve_axis(arm, config, point, direction, starts, rng, tries: int = 20) -> np.ndarray | None:
    """Joint angles that put the wrist joint origin at ``point`` with its axis along ``direction`` and that the
    simulator accepts, by IK from each of ``starts`` and then from random perturbations of them; None if none."""
    from gtsam_rotid.errors import ArmError

    candidates = [np.asarray(s, dtype=float) for s in starts]
    candidates += [candidates[i % len(candidates)] + rng.normal(scale=0.3, size=arm.dof) for i in range(tries)]
    for start in candidates:
        try:
            q = arm.solve_wrist_axis(point, direction, start)
        except ArmError:
            continue
        if pose_problem(arm, config, q) is None:
            return q
    return None


def perpendicular(direction: np.ndarray, rng) -> np.ndarray:
    """A random unit vector perpendicular to ``direction``."""
    d = direction / np.linalg.norm(direction)
    v = rng.normal(size=3)
    v -= (v @ d) * d
    return v / np.linalg.norm(v)


def rotate_towards(direction: np.ndarray, other: np.ndarray, angle_rad: float) -> np.ndarray:
    """``direction`` turned by ``angle_rad`` towards the perpendicular unit vector ``other``."""
    return np.cos(angle_rad) * direction + np.sin(angle_rad) * other


def subset(dataset, indices):
    """A dataset with only the given measurements (same arm and camera)."""
    from gtsam_rotid.dataset import Dataset

    return Dataset(dataset.arm, dataset.camera, [dataset[k] for k in indices], metadata=dict(dataset.metadata))



def bound_along(bound: np.ndarray | None, truth_pose: gtsam.Pose3, direction_arm: np.ndarray) -> float:
    """Cramér-Rao 1σ (mm) of the camera position along a unit arm-frame direction (inf when undetermined)."""
    if bound is None:
        return float("inf")
    u = truth_pose.rotation().matrix().T @ (direction_arm / np.linalg.norm(direction_arm))
    value = float(u @ bound[3:, 3:] @ u)
    return 1000.0 * np.sqrt(value) if np.isfinite(value) and 0.0 <= value < 1e6 else float("inf")


def safe_crlb(dataset, truth, noise_var: float) -> np.ndarray | None:
    """:func:`crlb`, or None when the scene does not determine the pose (singular information)."""
    try:
        bound = crlb(dataset, truth, noise_var)
    except np.linalg.LinAlgError:
        return None
    return bound if np.all(np.isfinite(bound)) else None


# ---------------------------------------------------------------------------------------------------
# a weak direction's 1σ as the scene nears a degeneracy (parallel_axes, near_degenerate)


@dataclass
class SweepScene:
    """One scene of a sweep towards a degenerate geometry (:func:`sweep_scene`): the simulated ``dataset`` and
    ``truth``, the wrist axes' ``geometry``, the Cramér-Rao bound (None when singular) and its 1σ along the weak
    direction ``crlb`` (mm, inf when singular), and the joint calibration: ``result`` (None and ``failure`` when
    ``calibrate`` refused), ``seconds``, its ``report``, the reported 1σ along the direction ``sigma`` (mm, inf when
    the covariance is unusable) and the error along it ``along`` (mm, signed)."""

    dataset: object
    truth: object
    geometry: object
    bound: np.ndarray | None
    crlb: float
    result: object
    seconds: float
    failure: str | None
    report: object = None
    sigma: float | None = None
    along: float | None = None

    def print_along(self, what: str) -> None:
        """Print the report's observability words and the error and 1σ (reported, Cramér-Rao) along the
        direction, which ``what`` names."""
        for line in self.report.observability:
            print("  report: " + line)
        print(f"  {what}: error {self.along:+.2f} mm, reported 1 sigma "
              + (f"{self.sigma:.3g} mm" if np.isfinite(self.sigma) else "not determined")
              + ", Cramér-Rao 1 sigma " + (f"{self.crlb:.3g} mm" if np.isfinite(self.crlb) else "infinite (singular)"))


def sweep_scene(config, poses, direction: np.ndarray, *, seed: int, arm, noise_var: float) -> SweepScene:
    """Simulate the scene of these arm poses (``config`` with explicit joint angles, pixel noise ``noise_var``),
    compute its Cramér-Rao bound, calibrate it (``joint``) and measure it along the unit arm-frame ``direction``."""
    from gtsam_rotid.report import axis_geometry

    dataset, truth = simulate(config.with_(joint_angles=tuple(tuple(q) for q in poses), n_measurements=len(poses)),
                              seed=seed, arm=arm)
    geometry = axis_geometry([m.axis for m in truth.measurements])
    bound = safe_crlb(dataset, truth, noise_var)
    result, seconds, failure = run_calibration(dataset, "joint")
    scene = SweepScene(dataset, truth, geometry, bound, bound_along(bound, truth.arm_T_camera, direction), result,
                       seconds, failure)
    if result is not None:
        scene.report = make_report(result, dataset)
        scene.sigma = sigma_along(result, direction) if result.covariance_usable else float("inf")
        scene.along = float(position_error_mm(result.arm_T_camera, truth.arm_T_camera) @ direction)
    return scene


@dataclass(frozen=True)
class Growth:
    """The scenes whose parameter ``x`` (the distance from the degenerate scene at x = 0, e.g. a tilt or a miss)
    is positive and whose reported 1σ along the weak direction is finite, in the order they ran (x increasing):
    that 1σ (mm), the Cramér-Rao 1σ (mm) and the |error| (mm) along the same direction."""

    x: np.ndarray
    sigma: np.ndarray
    bound: np.ndarray
    error: np.ndarray

    @classmethod
    def of(cls, rows) -> Growth | None:
        """From ``(x, sigma, bound, error)`` per scene (sigma None: calibrate failed; inf: not determined); None
        when fewer than two scenes qualify."""
        kept = [(x, s, c, abs(e)) for x, s, c, e in rows if x > 0 and s is not None and np.isfinite(s)]
        return cls(*np.array(kept, dtype=float).T) if len(kept) >= 2 else None

    @property
    def slope(self) -> float:
        """Log-log slope of the reported 1σ between the two smallest x (-1: it goes as 1 / x)."""
        return float(np.log(self.sigma[1] / self.sigma[0]) / np.log(self.x[1] / self.x[0]))

    def check(self, verdict: Verdict, slope_range: tuple[float, float], grows_text: str, slope_text: str) -> None:
        """Two checks: the 1σ at the smallest x exceeds twice that at the largest, and :attr:`slope` lies inside
        the open ``slope_range``."""
        verdict.check(self.sigma[0] > 2.0 * self.sigma[-1], grows_text)
        verdict.check(slope_range[0] < self.slope < slope_range[1], slope_text)


def growth_cells(sigma: float | None, bound: float, error: float | None) -> tuple[str, str, str]:
    """Table cells of one scene: the reported 1σ ('failed', 'not determined' or mm), the Cramér-Rao 1σ (mm, 'inf'
    when singular) and the signed error (mm; empty when calibrate failed)."""
    s = "failed" if sigma is None else (f"{sigma:.3g}" if np.isfinite(sigma) else "not determined")
    c = f"{bound:.3g}" if np.isfinite(bound) else "inf"
    return s, c, "" if error is None else f"{error:+.2f}"


def growth_figure(growth: Growth, *, along: str, variable: str, x_label: str, y_label: str, title: str):
    """Log-log: the reported 1σ, the Cramér-Rao 1σ and the |error| along the weak direction (``along``, e.g.
    'along a') against x, with a line through the first point that goes as 1 / ``variable``."""
    fig = new_figure(6.0, 4.2)
    ax = fig.subplots()
    x = growth.x
    ax.loglog(x, growth.sigma, "o-", label=f"reported 1σ {along}")
    ax.loglog(x, growth.bound, "s--", label=f"Cramér-Rao 1σ {along}")
    ax.loglog(x, growth.error, "x", ms=8, label=f"|error| {along}")
    ax.loglog(x, growth.sigma[0] * x[0] / x, ":", color="0.5", label=f"∝ 1 / {variable}")
    ax.set_xlabel(x_label)
    ax.set_ylabel(y_label)
    ax.set_title(title, fontsize=8)
    ax.legend(fontsize=7)
    return fig

"""The paper's Monte Carlo: pixel noise σ² ∈ {0.1, 0.5, 1.0, 1.5} px², six wrist spins, 100 trials per level.

Every trial simulates the reference scene (the arm poses of ``--seed`` held fixed; trial i draws its features and
noise from seed ``--first-seed + i``, the same at every level) and calibrates it with ``paper``, ``weighted`` and
``joint``. Figures, as in the paper, with the Cramér-Rao bound drawn on each:

- ``line_fit_stage1.png``: the image-axis (slope, intercept) errors of the stage-1 fits (the paper's line-fit
  figure; shared by the three methods), with the bound of each measurement's axis as a 95 % ellipse;
  ``line_fit_METHOD.png``: the image axes implied by each method's estimate (the FK axis projected by it);
- ``cartesian_METHOD.png`` and ``angular_METHOD.png``: the camera position errors (x, y, z in the arm frame, mm) and
  the roll, pitch, yaw errors (deg), per noise level.

A table gives, per level and method, RMSE / CRLB on the six Pose3 tangent axes and the NEES (mean of e^T Σ⁻¹ e
with the reported Σ; 6 when honest) with its interval. Verdict (full size): ``joint`` and ``weighted`` at the bound
(RMSE / CRLB <= 1.15 on every axis at every level) with an honest covariance (NEES inside its 99.9 % interval),
every trial calibrated. With ``--quick`` (2 trials, 10 s spins) only what a few trials can show is judged: every
trial calibrates, no trial's error lies outside its reported 99.9 % region, and the reported 1σ is within 25 % of
the bound.

Trials run in parallel processes (joblib's loky backend, ``--jobs``, default: all CPUs) or, with ``--scheduler
ADDRESS``, on a Dask cluster (joblib's dask backend), with a progress bar that ticks once per finished trial. Both
come with the ``scenarios`` extra (``pip install -e ".[scenarios]"``; ``.[test]`` includes it). Every trial draws from
its own seed, so the numbers do not depend on where or in which order the trials ran. CustomFactors cannot be
pickled: every worker builds its own graphs. The Dask workers need ``gtsam_rotid`` installed and this checkout's
``scenarios/`` directory at the same path (the same machine or a shared file system) or on their ``PYTHONPATH``.

Run: ``python scenarios/noise_monte_carlo.py [--quick] [--out DIR] [--seed N] [--trials 100] [--jobs N]
[--duration 60] [--scheduler ADDRESS]``.
"""

from __future__ import annotations

import os
import sys
import time
from pathlib import Path

import numpy as np
from _common import (
    CHI2_6_999,
    TANGENT_LABELS,
    TANGENT_UNITS,
    Verdict,
    header,
    new_figure,
    parse_args,
    save_figure,
)
from tqdm import tqdm

from gtsam_rotid.uncertainty import chi2_mean_interval

NOISE_VARS = (0.1, 0.5, 1.0, 1.5)
METHODS = ("paper", "weighted", "joint")
#: This directory (the trials import ``_common`` from it, also inside Dask workers).
SCENARIO_DIR = str(Path(__file__).resolve().parent)
#: Dask: seconds to wait for the scheduler to answer, and then for a worker.
SCHEDULER_TIMEOUT = 10.0
#: Normal quantile of the judged NEES interval (99.9 %, two-sided).
Z999 = 3.290527


# ---------------------------------------------------------------------------------------------------
# one trial (runs in a worker process)


def slope_intercept_or_nan(line) -> np.ndarray:
    from gtsam_rotid.errors import InputError
    from gtsam_rotid.plots import slope_intercept

    try:
        return np.array(slope_intercept(line))
    except InputError:  # a vertical image line has no slope-intercept form
        return np.full(2, np.nan)


def mb_jacobian(line) -> np.ndarray:
    """d(m, b)/d(l1, l2, l3) of ``v = m u + b`` for the line ``l1 u + l2 v + l3 = 0``."""
    a, b, c = line
    return np.array([[-1.0 / b, a / b**2, 0.0], [0.0, c / b**2, -1.0 / b]])


def projected_axis(camera, pose, axis) -> np.ndarray:
    """Homogeneous image line (ideal pixels) of a wrist axis seen by a camera at ``pose`` (arm_T_camera)."""
    from gtsam_rotid.graph import axis_test_points

    points = np.array([pose.transformTo(p) for p in axis_test_points(axis)])
    pixels = camera.project(points, distort=False)
    return np.cross(np.append(pixels[0], 1.0), np.append(pixels[1], 1.0))


def implied_axes_mb(camera, pose, axes) -> np.ndarray:
    """(measurements, 2) slope and intercept of the FK axes projected by ``pose``."""
    return np.array([slope_intercept_or_nan(projected_axis(camera, pose, a)) for a in axes])


def implied_axes_bound(camera, pose, axes, bound: np.ndarray, step: float = 1e-7) -> np.ndarray:
    """(measurements, 2, 2) covariance of those slopes and intercepts for a pose covariance ``bound`` (tangent)."""
    base = implied_axes_mb(camera, pose, axes)
    J = np.zeros((len(axes), 2, 6))
    for i in range(6):
        xi = np.zeros(6)
        xi[i] = step
        J[:, :, i] = (implied_axes_mb(camera, pose.retract(xi), axes) - base) / step
    return np.einsum("kai,ij,kbj->kab", J, bound, J)


def stage1_line_bounds(dataset, truth, noise_var: float) -> np.ndarray:
    """(measurements, 2, 2) Cramér-Rao covariance of each measurement's image-axis slope and intercept from its own
    tracks (stage 1: the line and every circle free, linearised at the truth)."""
    import gtsam

    from gtsam_rotid.factors import image_line_from_rot3
    from gtsam_rotid.graph import RotIdGraph
    from gtsam_rotid.uncertainty import marginal_information

    pose = truth.arm_T_camera
    builder = RotIdGraph(dataset.arm, dataset.camera, track_sigma_px=float(np.sqrt(noise_var)))
    out = []
    for k, (measurement, m_truth) in enumerate(zip(dataset, truth.measurements, strict=True)):
        point_cam = pose.transformTo(m_truth.axis_point)
        direction_cam = pose.rotation().unrotate(m_truth.axis_direction)
        along = point_cam @ direction_cam
        scale = float(m_truth.axis.distance_to(pose.translation())[0])
        circles = {j: np.array([(t.offset + along) / scale, t.radius / scale]) for j, t in enumerate(m_truth.tracks)}
        graph, values = gtsam.NonlinearFactorGraph(), gtsam.Values()
        keys = builder.add_measurement(graph, values, k, measurement, arm_T_camera=pose, tie=False,
                                       initial_circles=circles, refine_circles=False)
        info = marginal_information(graph, values, keys.line_key, 3)
        line, J = image_line_from_rot3(dataset.camera.K, values.atRot3(keys.line_key))
        cov_line = J @ np.linalg.inv(info) @ J.T
        G = mb_jacobian(line)
        out.append(G @ cov_line @ G.T)
    return np.array(out)


def trial(noise_var: float, seed: int, duration: float, joint_angles, methods) -> dict:
    """Simulate, bound and calibrate one trial; plain arrays only (the result crosses a process boundary)."""
    if SCENARIO_DIR not in sys.path:  # a Dask worker started elsewhere than this script
        sys.path.append(SCENARIO_DIR)
    from _common import crlb

    from gtsam_rotid import simulate
    from gtsam_rotid.errors import RotIdError
    from gtsam_rotid.estimate import calibrate
    from gtsam_rotid.report import rpy_jacobian

    dataset, truth = simulate.reference_scene(seed=seed, noise_var=noise_var, duration=duration,
                                              joint_angles=joint_angles)
    pose = truth.arm_T_camera
    R = pose.rotation().matrix()
    bound = crlb(dataset, truth, noise_var)
    J_rpy = rpy_jacobian(pose.rotation()) @ R  # d(roll, pitch, yaw) / d(tangent rotation)
    axes = [m.axis for m in truth.measurements]
    true_mb = implied_axes_mb(dataset.camera, pose, axes)
    out = {
        "noise_var": noise_var, "seed": seed, "crlb": bound,
        "crlb_position_mm": 1000.0 * np.sqrt(np.diag(R @ bound[3:, 3:] @ R.T)),
        "crlb_rpy_deg": np.degrees(np.sqrt(np.diag(J_rpy @ bound[:3, :3] @ J_rpy.T))),
        "line_bound_stage1": stage1_line_bounds(dataset, truth, noise_var),
        "line_bound_implied": implied_axes_bound(dataset.camera, pose, axes, bound),
        "points": sum(m.n_observations for m in dataset),
    }
    rpy_true = np.asarray(pose.rotation().rpy())
    for method in methods:
        start = time.perf_counter()
        try:
            result = calibrate(dataset, method=method)
        except RotIdError as error:
            out[method] = {"failed": f"{type(error).__name__}: {error}"}
            continue
        estimate = result.arm_T_camera
        d_rpy = np.asarray(estimate.rotation().rpy()) - rpy_true
        stage1 = np.array([slope_intercept_or_nan(m.image_axis) if m.image_axis is not None else np.full(2, np.nan)
                           for m in result.measurements])
        out[method] = {
            "error": pose.localCoordinates(estimate),
            "covariance": result.covariance,
            "usable": result.covariance_usable,
            "position_mm": 1000.0 * (np.asarray(estimate.translation()) - np.asarray(pose.translation())),
            "rpy_deg": np.degrees(np.mod(d_rpy + np.pi, 2 * np.pi) - np.pi),
            "line_stage1": stage1 - true_mb,
            "line_implied": implied_axes_mb(dataset.camera, estimate, axes) - true_mb,
            "seconds": time.perf_counter() - start,
        }
    return out


# ---------------------------------------------------------------------------------------------------
# running the trials


class SchedulerError(ConnectionError):
    """``--scheduler ADDRESS``: no Dask scheduler answers at that address, or it has no worker."""


def make_tasks(seed: int, noise_vars, trials: int, first_seed: int, duration: float, methods=METHODS) -> list[tuple]:
    """The arguments of :func:`trial` for every (noise level, trial): the arm poses of the reference scene of
    ``seed``, trial i with seed ``first_seed + i`` at every level."""
    from gtsam_rotid import simulate

    _, scene = simulate.reference_scene(seed=seed, duration=1.0, min_track_length=2)
    joint_angles = tuple(tuple(m.joint_angles.tolist()) for m in scene.measurements)
    return [(float(v), first_seed + i, float(duration), joint_angles, tuple(methods))
            for v in noise_vars for i in range(trials)]


def indexed_trial(index: int, task: tuple) -> tuple[int, dict]:
    return index, trial(*task)


def run_trials(tasks, jobs: int = 1, scheduler: str | None = None, *, timeout: float | None = None,
               progress: bool = True) -> list[dict]:
    """Every task's :func:`trial`, in task order, with a progress bar (one tick per finished trial).

    Without ``scheduler``: in ``jobs`` worker processes (joblib, loky backend; in this process when ``jobs`` is 1).
    With ``scheduler``: on the Dask cluster at that address (joblib's dask backend, every worker thread of the
    cluster); raises :class:`SchedulerError` when the scheduler does not answer within ``timeout`` seconds
    (default ``SCHEDULER_TIMEOUT``) or has no worker.
    """
    results: list[dict | None] = [None] * len(tasks)
    with tqdm(total=len(tasks), desc="trials", unit="trial", disable=not progress) as bar:
        def collect(finished) -> None:
            for index, result in finished:
                results[index] = result
                bar.update()

        indexed = list(enumerate(tasks))
        if scheduler:
            run_on_dask(indexed, scheduler, timeout or SCHEDULER_TIMEOUT, collect)
        else:
            collect(parallel(jobs, "loky")(indexed))
    return results


def parallel(n_jobs: int, backend: str | None):
    """``run(indexed_tasks)`` -> generator of (index, result) in the order the trials finish."""
    from joblib import Parallel, delayed

    runner = Parallel(n_jobs=n_jobs, backend=backend, batch_size=1, return_as="generator_unordered")
    return lambda indexed: runner(delayed(indexed_trial)(i, task) for i, task in indexed)


def connect(address: str, timeout: float):
    """A ``distributed.Client`` of the scheduler at ``address`` that has at least one worker, or SchedulerError."""
    from distributed import Client

    try:
        client = Client(address, timeout=timeout, set_as_default=False)
    except Exception as error:  # refused, timed out, not an address, or not a Dask scheduler answering
        raise SchedulerError(f"cannot reach the Dask scheduler at {address!r} within {timeout:g} s "
                             f"({type(error).__name__}: {error}); start one with `dask scheduler` and workers "
                             "with `dask worker ADDRESS`, and pass the address it prints") from error
    try:
        client.wait_for_workers(1, timeout=timeout)
    except (TimeoutError, OSError) as error:
        client.close()
        raise SchedulerError(f"the Dask scheduler at {address!r} has no worker after {timeout:g} s; start one with "
                             f"`dask worker {address}`") from error
    return client


def run_on_dask(indexed, address: str, timeout: float, collect) -> None:
    """Run ``indexed`` (index, task) pairs on the Dask cluster at ``address``, passing what finishes to ``collect``."""
    from joblib import parallel_config

    with connect(address, timeout) as client, parallel_config(backend="dask", client=client):
        collect(parallel(-1, None)(indexed))


def extra_arguments(parser) -> None:
    parser.add_argument("--trials", type=int, help="trials per noise level (default 100; --quick 2)")
    parser.add_argument("--jobs", type=int, default=os.cpu_count() or 1,
                        help="worker processes (joblib, loky; default %(default)s; 1: in this process; not used "
                             "with --scheduler)")
    parser.add_argument("--duration", type=float, help="seconds of spin per measurement (default 60; --quick 10)")
    parser.add_argument("--first-seed", type=int, default=1000, help="seed of trial 0 (default %(default)s)")
    parser.add_argument("--noise-vars", default=",".join(f"{v:g}" for v in NOISE_VARS),
                        help="comma-separated pixel noise variances, px^2 (default %(default)s)")
    parser.add_argument("--scheduler", metavar="ADDRESS",
                        help="run the trials on the Dask cluster of this scheduler (e.g. tcp://HOST:8786), on "
                             "every worker thread")


# ---------------------------------------------------------------------------------------------------
# summary, checks and figures


def level_stats(results: list[dict], method: str) -> dict | None:
    ok = [r for r in results if "error" in r[method]]
    if not ok:
        return None
    errors = np.array([r[method]["error"] for r in ok])
    bound = np.sqrt(np.mean([np.diag(r["crlb"]) for r in ok], axis=0))
    usable = [r[method] for r in ok if r[method]["usable"]]
    nees = np.array([o["error"] @ np.linalg.solve(o["covariance"], o["error"]) for o in usable])
    reported = np.sqrt(np.mean([np.diag(r[method]["covariance"]) for r in ok if r[method]["usable"]], axis=0)) \
        if usable else np.full(6, np.nan)
    return {"n": len(ok), "failed": len(results) - len(ok),
            "failures": [r[method]["failed"] for r in results if "failed" in r[method]],
            "rmse": np.sqrt(np.mean(errors**2, axis=0)), "mean": np.mean(errors, axis=0), "bound": bound,
            "nees": nees, "reported": reported, "seconds": float(np.median([r[method]["seconds"] for r in ok]))}


def print_table(by_level: dict, methods) -> dict:
    stats = {}
    for noise_var, results in by_level.items():
        n = len(results)
        bound = np.sqrt(np.mean([np.diag(r["crlb"]) for r in results], axis=0)) * TANGENT_UNITS
        print(f"\nsigma^2 = {noise_var:g} px^2: {n} trials, ~{int(np.mean([r['points'] for r in results]))} pixels "
              "per trial")
        print(f"  {'':22}" + "".join(f"{a:>9}" for a in TANGENT_LABELS) + "     NEES (ideal 6)")
        print(f"  {'CRLB (1 sigma)':22}" + "".join(f"{v:9.4f}" for v in bound))
        for method in methods:
            s = level_stats(results, method)
            stats[noise_var, method] = s
            if s is None:
                print(f"  {method:22} every trial FAILED: {results[0][method]['failed']}")
                continue
            low, high = chi2_mean_interval(6, max(len(s["nees"]), 1))
            nees = float(np.mean(s["nees"])) if len(s["nees"]) else float("nan")
            where = "inside" if low <= nees <= high else "OUTSIDE"
            fails = f", {s['failed']} FAILED" if s["failed"] else ""
            print(f"  {method + ' RMSE / CRLB':22}" + "".join(f"{v:9.3f}" for v in s["rmse"] / s["bound"])
                  + f"     {nees:.2f} ({where} 95 % [{low:.2f}, {high:.2f}]){fails}; median {s['seconds']:.1f} s")
    return stats


def figures(by_level: dict, methods, out) -> list:
    noise_vars = list(by_level)
    written = []
    from gtsam_rotid.plots import plot_angular_errors, plot_cartesian_errors, plot_line_fit_errors

    def stacked(method, key):
        return [np.array([r[method][key] for r in by_level[v] if key in r[method]]) for v in noise_vars]

    def usable_levels(arrays):
        return all(len(a) for a in arrays)

    line_bound_stage1 = [np.mean([r["line_bound_stage1"] for r in by_level[v]], axis=0) for v in noise_vars]
    line_bound_implied = [np.mean([r["line_bound_implied"] for r in by_level[v]], axis=0) for v in noise_vars]
    crlb_mm = [np.sqrt(np.mean([r["crlb_position_mm"] ** 2 for r in by_level[v]], axis=0)) for v in noise_vars]
    crlb_deg = [np.sqrt(np.mean([r["crlb_rpy_deg"] ** 2 for r in by_level[v]], axis=0)) for v in noise_vars]
    first = next((m for m in ("joint", "weighted", "paper") if m in methods), methods[0])
    stage1 = stacked(first, "line_stage1")
    if usable_levels(stage1):
        fig = plot_line_fit_errors(stage1, noise_vars, crlb=line_bound_stage1)
        fig.suptitle("stage-1 image-axis fit errors (shared by the three methods; ellipses: 95 % of the bound)",
                     fontsize=10)
        written.append(save_figure(fig, out, "line_fit_stage1.png"))
    for method in methods:
        implied = stacked(method, "line_implied")
        if usable_levels(implied):
            fig = plot_line_fit_errors(implied, noise_vars, crlb=line_bound_implied)
            fig.suptitle(f"{method}: errors of the image axes implied by the estimate (ellipses: 95 % of the bound)",
                         fontsize=10)
            written.append(save_figure(fig, out, f"line_fit_{method}.png"))
        position = stacked(method, "position_mm")
        if usable_levels(position):
            fig = plot_cartesian_errors(position, noise_vars, crlb_mm=crlb_mm)
            fig.suptitle(f"{method}: camera position errors, arm frame (red: Cramér-Rao bound)", fontsize=10)
            written.append(save_figure(fig, out, f"cartesian_{method}.png"))
        angles = stacked(method, "rpy_deg")
        if usable_levels(angles):
            fig = plot_angular_errors(angles, noise_vars, crlb_deg=crlb_deg)
            fig.suptitle(f"{method}: roll, pitch, yaw errors (red: Cramér-Rao bound)", fontsize=10)
            written.append(save_figure(fig, out, f"angular_{method}.png"))
    written.append(save_figure(ratio_figure(by_level, methods), out, "rmse_over_crlb.png"))
    return written


def ratio_figure(by_level, methods):
    fig = new_figure(10.0, 4.0)
    axes = fig.subplots(1, 2)
    noise_vars = np.array(list(by_level))
    for method in methods:
        ratios, nees = [], []
        for v in by_level:
            s = level_stats(by_level[v], method)
            ratios.append(np.full(6, np.nan) if s is None else s["rmse"] / s["bound"])
            nees.append(np.nan if s is None or not len(s["nees"]) else float(np.mean(s["nees"])))
        ratios = np.array(ratios)
        axes[0].plot(noise_vars, np.max(ratios, axis=1), "o-", label=f"{method}: worst axis")
        axes[0].plot(noise_vars, np.min(ratios, axis=1), "x:", color=axes[0].lines[-1].get_color(),
                     label=f"{method}: best axis")
        axes[1].semilogy(noise_vars, nees, "o-", label=method)
    axes[0].axhline(1.0, color="k", lw=0.8)
    axes[0].set_xlabel("pixel noise variance (px²)")
    axes[0].set_ylabel("RMSE / Cramér-Rao bound")
    axes[0].legend(fontsize=7)
    axes[1].axhline(6.0, color="k", lw=0.8)
    axes[1].set_xlabel("pixel noise variance (px²)")
    axes[1].set_ylabel("NEES (6 when the covariance is honest)")
    axes[1].legend(fontsize=7)
    fig.suptitle("efficiency and honesty per noise level", fontsize=9)
    return fig


def main(argv=None) -> int:
    args = parse_args("noise_monte_carlo", __doc__.split("\n\n")[0], argv, extra=extra_arguments)
    trials = args.trials or (2 if args.quick else 100)
    duration = args.duration or (10.0 if args.quick else 60.0)
    noise_vars = [float(v) for v in args.noise_vars.split(",") if v]
    jobs = max(1, args.jobs)
    methods = METHODS
    header(args, "pixel-noise Monte Carlo against the Cramér-Rao bound (the paper's figures)",
           [f"reference scene (arm poses of seed {args.seed}), six {duration:g} s spins, sigma^2 in "
            f"{noise_vars} px^2, {trials} trials per level (seeds {args.first_seed}-{args.first_seed + trials - 1}), "
            f"methods {', '.join(methods)}, "
            + (f"on the Dask cluster at {args.scheduler}" if args.scheduler else f"{jobs} worker processes")])
    tasks = make_tasks(args.seed, noise_vars, trials, args.first_seed, duration, methods)
    start = time.perf_counter()
    try:
        results = run_trials(tasks, jobs, args.scheduler)
    except SchedulerError as error:
        print(f"error: {error}", file=sys.stderr)
        return 2
    wall = time.perf_counter() - start
    by_level = {v: sorted([r for r in results if r["noise_var"] == v], key=lambda r: r["seed"]) for v in noise_vars}
    print(f"{len(tasks)} trials in {wall:.0f} s wall")
    stats = print_table(by_level, methods)
    save_raw(by_level, methods, args.out / "trials.npz")

    verdict = Verdict(args)
    print("\nchecks:")
    for method in ("joint", "weighted"):
        failures = [f for v in noise_vars for f in (stats[v, method] or {"failures": ["all"]})["failures"]]
        verdict.check(not failures, f"{method}: every trial calibrates ({len(failures)} failed"
                      + (f", e.g. {failures[0]}" if failures else "") + ")")
        worst = max((float(np.max(s["nees"])) for v in noise_vars if (s := stats[v, method]) and len(s["nees"])),
                    default=float("nan"))
        verdict.check(worst <= CHI2_6_999, f"{method}: no trial's error outside its reported 99.9 % region "
                      f"(largest e^T Sigma^-1 e {worst:.2f} <= {CHI2_6_999:.1f})")
        ratios = [s["reported"] / s["bound"] for v in noise_vars if (s := stats[v, method])]
        if ratios:
            ratios = np.array(ratios)
            verdict.check(np.all((ratios > 0.8) & (ratios < 1.25)),
                          f"{method}: reported 1 sigma within 0.8-1.25x the bound at every level "
                          f"({np.nanmin(ratios):.2f}-{np.nanmax(ratios):.2f})")
        worst_ratio = max((float(np.max(s["rmse"] / s["bound"])) for v in noise_vars if (s := stats[v, method])),
                          default=float("nan"))
        verdict.check(worst_ratio <= 1.15, f"{method}: RMSE / CRLB <= 1.15 on every axis at every level (worst "
                      f"{worst_ratio:.2f})", robust_when_quick=False)
        outside = []
        for v in noise_vars:
            s = stats[v, method]
            if s is None or not len(s["nees"]):
                continue
            low, high = chi2_mean_interval(6, len(s["nees"]), Z999)
            nees = float(np.mean(s["nees"]))
            if not low <= nees <= high:
                outside.append(f"{v:g} px^2: {nees:.2f} not in [{low:.2f}, {high:.2f}]")
        verdict.check(not outside, f"{method}: NEES inside its 99.9 % interval at every level"
                      + (f" ({'; '.join(outside)})" if outside else ""), robust_when_quick=False)
    paper_nees = [float(np.mean(s["nees"])) for v in noise_vars if (s := stats[v, "paper"]) and len(s["nees"])]
    if paper_nees:
        listed = ", ".join(f"{v:.2g}" for v in paper_nees)
        verdict.check(min(paper_nees) > 12 or max(paper_nees) < 3,
                      f"paper: its (J^T J)^-1 covariance is not honest (NEES {listed})", robust_when_quick=False)
    written = figures(by_level, methods, args.out)
    joint = [stats[v, "joint"] for v in noise_vars if stats[v, "joint"]]
    summary = (f"noise Monte Carlo, {trials} trials x {len(noise_vars)} levels: joint RMSE / CRLB "
               f"{min(float(np.min(s['rmse'] / s['bound'])) for s in joint):.2f}-"
               f"{max(float(np.max(s['rmse'] / s['bound'])) for s in joint):.2f}, NEES "
               + ", ".join(f"{float(np.mean(s['nees'])):.2f}" for s in joint)) if joint else "noise Monte Carlo"
    return verdict.finish(summary, written + [args.out / "trials.npz"])


def save_raw(by_level, methods, path) -> None:
    arrays = {}
    for v, results in by_level.items():
        tag = f"{v:g}".replace(".", "p")
        arrays[f"s{tag}_seeds"] = np.array([r["seed"] for r in results])
        arrays[f"s{tag}_crlb"] = np.array([r["crlb"] for r in results])
        for method in methods:
            ok = [r for r in results if "error" in r[method]]
            arrays[f"s{tag}_{method}_seeds"] = np.array([r["seed"] for r in ok])
            for key in ("error", "covariance", "position_mm", "rpy_deg", "line_stage1", "line_implied"):
                arrays[f"s{tag}_{method}_{key}"] = np.array([r[method][key] for r in ok])
    np.savez(path, **arrays)


if __name__ == "__main__":
    sys.exit(main())

"""Plots of a calibration (matplotlib, PNG through the Agg canvas; pyplot and its global state are not used).

Every function returns a ``matplotlib.figure.Figure``; ``fig.savefig("x.png")`` writes it.

- :func:`plot_tracks`: one measurement's tracks with the circles fitted about the wrist axis projected by the
  estimate, and that projected axis (the paper's simulated-view figure), in raw pixels.
- :func:`plot_residual_histograms`: per measurement, the tracks' pixel residuals against those circles, with
  the normal density at the reported residual RMS.
- :func:`plot_pose_3d`: the wrist axes, the camera frustum and its 95 % position ellipsoid (magnified to be
  visible; the legend says by how much), in the arm-base frame.
- Monte Carlo (the paper's error-distribution figures, from arrays): :func:`plot_line_fit_errors` (image-axis
  slope and intercept errors per measurement) and :func:`plot_pose_errors` / :func:`plot_cartesian_errors` /
  :func:`plot_angular_errors` (errors per noise level with the Cramér-Rao bound drawn).

- :func:`plot_overlay`: the paper's "quad view" of one measurement on a video frame: the frame, the features
  tracked in it, the tracked arcs, and the fitted circles with the projected axis (:func:`save_overlays`).

:func:`save_plots` writes the report's set (``gtsam-rotid report --plots DIR``).
"""

from __future__ import annotations

import io
import math
import os
from collections.abc import Sequence
from pathlib import Path

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from matplotlib.lines import Line2D
from matplotlib.patches import Ellipse

from .dataset import Track
from .diagnosis import axis_geometry, wrist_axes
from .errors import InputError, OutputError
from .factors import circle_points, line_points
from .files import check_outputs, staged
from .fits import TrackFit, fit_tracks  # noqa: F401 (re-export: plots draw what the calibration layer fits)
from .geometry import ros_covariance
from .report import CHI2_95_3DOF, Z95
from .words import intrinsics_suspected, kinematics_suspected, outlier_words

#: 95 % point of the χ² distribution with 2 dof (2-D confidence ellipses).
CHI2_95_2DOF = 5.991464547107979
#: Length (m) of the drawn wrist-axis segments and depth of the camera frustum relative to the scene size.
AXIS_HALF_LENGTH = 0.15
FRUSTUM_FRACTION = 0.15
#: The position ellipsoid is magnified until its largest semi-axis is this fraction of the scene size.
ELLIPSOID_FRACTION = 0.04
DPI = 110


def new_figure(width: float = 7.0, height: float = 5.0) -> Figure:
    """A figure on its own Agg canvas (no pyplot, no global backend change)."""
    fig = Figure(figsize=(width, height), layout="constrained")
    FigureCanvasAgg(fig)
    return fig


def _project_curve(camera, points_camera: np.ndarray, margin: float = 50.0) -> np.ndarray:
    """Raw pixels of camera-frame points; points behind the camera or off the image (plus ``margin``) become
    NaN, so that a plotted curve breaks there instead of jumping. Only points whose ideal projection is near the
    image are distorted (far outside it the distortion polynomial can fold points back in)."""
    out = np.full((len(points_camera), 2), np.nan)
    ideal = camera.project(points_camera, distort=False)
    near = camera.in_image(ideal, -0.5 * max(camera.width, camera.height))
    if np.any(near):
        pixels = camera.project(points_camera[near])
        pixels[~camera.in_image(pixels, -margin)] = np.nan
        out[near] = pixels
    return out


def _track_colours(n: int):
    from matplotlib import colormaps

    cmap = colormaps["tab20"]
    return [cmap(i % 20) for i in range(n)]


def plot_tracks(result, dataset, k: int, *, fit: TrackFit | None = None, ax=None, zoom: bool = False) -> Figure:
    """Measurement ``k``: its tracks (raw pixels), the circles fitted about the estimated wrist axis, that axis
    projected into the image, and rejected tracks in grey (the paper's simulated-view figure).

    Without ``ax``: two panels, the whole image and a zoom on the tracks; with ``ax``: one panel drawn into it
    (zoomed if ``zoom``). ``fit`` reuses :func:`fit_tracks`' work.
    """
    fit = fit_tracks(result, dataset, k) if fit is None else fit
    if ax is not None:
        _draw_tracks(ax, result, dataset, k, fit, zoom)
        return ax.figure
    fig = new_figure(12.0, 5.0)
    full, zoomed = fig.subplots(1, 2)
    _draw_tracks(full, result, dataset, k, fit, False)
    _draw_tracks(zoomed, result, dataset, k, fit, True, legend=False)
    fig.suptitle(_measurement_title(result, k, f"{len(fit.circles)} of {len(dataset[k].tracks)} tracks fitted",
                                    fit, 2), fontsize=9)
    return fig


def _measurement_title(result, k: int, what: str, fit: TrackFit, digits: int) -> str:
    """``measurement k: what``, its residual RMS, weight and outlier status, and the fit's problem if any."""
    report = result.measurements[k] if k < len(result.measurements) else None
    title = f"measurement {k}: {what}"
    if report is not None:
        untrusted = result.untrusted or {}
        why = outlier_words(report, intrinsics_suspected(untrusted), kinematics_suspected(untrusted))
        title += (f", residual RMS {report.residual_rms_px:.{digits}f} px, weight {report.weight:.2f}"
                  + (f", OUTLIER ({why})" if report.outlier else ""))
    if fit.problem:
        title += f"\n{fit.problem}"
    return title


def _spin_axis_name(dataset, k: int) -> str:
    """``wrist axis``, or ``axis of <joint>`` where measurement ``k`` spins another joint."""
    joint = dataset[k].spin_joint
    if dataset.arm.spins_wrist(joint):
        return "wrist axis"
    return f"axis of {dataset.arm.joint_names[dataset.arm.spin_index(joint)]}"


def _draw_tracks(ax, result, dataset, k: int, fit: TrackFit, zoom: bool, legend: bool = True) -> None:
    camera = dataset.camera
    tracks = [Track.from_any(t).pixels for t in dataset[k].tracks]
    colours = _track_colours(len(tracks))
    phases = np.linspace(0.0, 2.0 * np.pi, 361)
    for j, pixels in enumerate(tracks):
        if j in fit.circles:
            ax.plot(pixels[:, 0], pixels[:, 1], ".", ms=2.0 if not zoom else 3.0, color=colours[j], alpha=0.6)
            curve = _project_curve(camera, circle_points(fit.line, *fit.circles[j], phases))
            ax.plot(curve[:, 0], curve[:, 1], "-", lw=1.0, color=colours[j])
        else:
            ax.plot(pixels[:, 0], pixels[:, 1], "x", ms=3.0, color="0.6", alpha=0.7)
    handles = [Line2D([], [], ls="", marker=".", color="tab:blue", label="tracks (raw pixels)"),
               Line2D([], [], color="tab:blue", label="circles fitted about the estimated axis")]
    if fit.line is not None:
        s = np.concatenate([-np.geomspace(1e3, 1e-3, 600), [0.0], np.geomspace(1e-3, 1e3, 600)])
        axis = _project_curve(camera, line_points(fit.line, s))
        ax.plot(axis[:, 0], axis[:, 1], "-", lw=2.0, color="tab:green")
        handles.append(Line2D([], [], color="tab:green", lw=2.0,
                              label=f"{_spin_axis_name(dataset, k)} projected by the estimate"))
    image_axis = result.measurements[k].image_axis if k < len(result.measurements) else None
    if image_axis is not None:  # the stage-1 image axis, when the result carries it (ideal pixels)
        _draw_image_line(ax, camera, np.asarray(image_axis, dtype=float))
        handles.append(Line2D([], [], color="tab:red", ls="--", label="image axis fitted to the tracks"))
    if len(fit.circles) < len(tracks):
        handles.append(Line2D([], [], ls="", marker="x", color="0.6", label="rejected tracks"))
    if zoom and tracks:
        points = np.vstack(tracks)
        lo, hi = points.min(axis=0), points.max(axis=0)
        centre, half = 0.5 * (lo + hi), 0.5 * (hi - lo) * 1.15 + 5.0
        half = np.maximum(half, half[::-1] * np.array([camera.width / camera.height, camera.height / camera.width]))
        ax.set_xlim(centre[0] - half[0], centre[0] + half[0])
        ax.set_ylim(centre[1] + half[1], centre[1] - half[1])
    else:
        ax.set_xlim(-0.5, camera.width - 0.5)
        ax.set_ylim(camera.height - 0.5, -0.5)  # image rows grow downwards
    ax.set_aspect("equal")
    ax.set_xlabel("u (px)")
    ax.set_ylabel("v (px)")
    ax.set_title("zoom on the tracks" if zoom else f"measurement {k}: the whole image", fontsize=9)
    if legend:
        ax.legend(handles=handles, loc="upper right", fontsize=7, framealpha=0.8)


def _draw_image_line(ax, camera, line: np.ndarray) -> None:
    """A homogeneous line of ideal pixels, drawn across the image (straight: distortion is not applied)."""
    a, b, c = line
    w, h = camera.width, camera.height
    if abs(b) > abs(a):
        u = np.array([-0.5, w - 0.5])
        ax.plot(u, -(a * u + c) / b, "--", color="tab:red", lw=1.2)
    else:
        v = np.array([-0.5, h - 0.5])
        ax.plot(-(b * v + c) / a, v, "--", color="tab:red", lw=1.2)


def plot_residual_histograms(result, dataset, *, fits: Sequence[TrackFit] | None = None, bins: int = 60) -> Figure:
    """Per measurement, a histogram of the kept tracks' residuals against circles about the estimated axis, with
    the normal density at the measurement's reported residual RMS."""
    fits = [fit_tracks(result, dataset, k) for k in range(len(dataset))] if fits is None else list(fits)
    n = len(fits)
    cols = min(3, n)
    rows = math.ceil(n / cols)
    fig = new_figure(3.4 * cols, 2.7 * rows)
    grid = fig.subplots(rows, cols, squeeze=False)
    for ax in grid.ravel()[n:]:
        ax.set_visible(False)
    for ax, fit in zip(grid.ravel(), fits, strict=False):
        e = fit.all_residuals
        report = result.measurements[fit.index] if fit.index < len(result.measurements) else None
        if len(e):
            ax.hist(e, bins=bins, density=True, color="tab:blue", alpha=0.7)
            sigma = report.residual_rms_px if report is not None else float(np.sqrt(np.mean(e**2)))
            if sigma > 0:
                x = np.linspace(-4 * sigma, 4 * sigma, 200)
                ax.plot(x, np.exp(-0.5 * (x / sigma) ** 2) / (sigma * np.sqrt(2 * np.pi)), color="tab:red", lw=1.2)
            rms = float(np.sqrt(np.mean(e**2)))
            title = f"measurement {fit.index}: RMS {rms:.2f} px"
        else:
            title = f"measurement {fit.index}: no fitted tracks"
        if report is not None:
            title += f"\nreported {report.residual_rms_px:.2f} px, weight {report.weight:.2f}"
            title += ", OUTLIER" if report.outlier else ""
        ax.set_title(title, fontsize=8)
        ax.set_xlabel("residual (px)", fontsize=8)
        ax.tick_params(labelsize=7)
    fig.suptitle("pixel residuals against circles about the estimated wrist axis (red: normal at the reported RMS)",
                 fontsize=9)
    return fig


# ---------------------------------------------------------------------------------------------------
# 3-D view


def _ellipsoid_surface(centre: np.ndarray, cov: np.ndarray, scale: float, n: int = 24):
    w, V = np.linalg.eigh(0.5 * (cov + cov.T))
    radii = scale * np.sqrt(np.maximum(w, 0.0))
    u, v = np.meshgrid(np.linspace(0, 2 * np.pi, n), np.linspace(0, np.pi, n // 2))
    sphere = np.stack([np.cos(u) * np.sin(v), np.sin(u) * np.sin(v), np.cos(v)], axis=-1)
    points = (sphere * radii) @ V.T + centre
    return points[..., 0], points[..., 1], points[..., 2]


def draw_camera(ax, pose, camera, depth: float, label: str) -> None:
    """A camera's frustum (its image corners at ``depth`` m; a 60 x 45 degree view without ``camera``) and its x, y,
    z axes (red, green, blue) at ``pose`` (arm frame), on a 3-D axes."""
    R, C = pose.rotation().matrix(), np.asarray(pose.translation(), dtype=float)
    if camera is not None:
        w, h = camera.width, camera.height
        corners = np.array([[-0.5, -0.5, 1], [w - 0.5, -0.5, 1], [w - 0.5, h - 0.5, 1], [-0.5, h - 0.5, 1.0]])
        rays = corners @ np.linalg.inv(camera.K).T
    else:
        rays = np.array([[-0.58, -0.41, 1], [0.58, -0.41, 1], [0.58, 0.41, 1], [-0.58, 0.41, 1.0]])
    far = C + depth * rays @ R.T
    for corner in far:
        ax.plot(*np.column_stack([C, corner]), color="0.3", lw=0.8)
    ax.plot(*np.vstack([far, far[:1]]).T, color="0.3", lw=0.8, label=label)
    for i, colour in enumerate(("tab:red", "tab:green", "tab:blue")):
        ax.plot(*np.column_stack([C, C + 0.5 * depth * R[:, i]]), color=colour, lw=1.5)


def cube_axes(ax, points: np.ndarray, size: float) -> None:
    """Equal-scaled 3-D axes (metres) around ``points``, ``size`` across."""
    centre, half = 0.5 * (points.min(axis=0) + points.max(axis=0)), 0.55 * size
    ax.set_xlim(centre[0] - half, centre[0] + half)
    ax.set_ylim(centre[1] - half, centre[1] + half)
    ax.set_zlim(centre[2] - half, centre[2] + half)
    ax.set_box_aspect((1, 1, 1))
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.set_zlabel("z (m)")


def plot_pose_3d(result, dataset=None, *, ax=None, magnify: float | None = None) -> Figure:
    """Wrist axes (from the dataset, or from the result if it carries them), the camera frustum and axes, and the
    95 % position ellipsoid, in the arm-base frame (metres). The ellipsoid is magnified (``magnify``, default:
    until it is visible) and the legend gives the factor; with an unusable covariance the undetermined position
    directions are drawn through the camera centre instead."""
    axes = wrist_axes(result, dataset)
    pose = result.arm_T_camera
    R = pose.rotation().matrix()
    C = np.asarray(pose.translation(), dtype=float)
    fig = new_figure(7.0, 6.0) if ax is None else ax.figure
    ax = fig.add_subplot(projection="3d") if ax is None else ax
    points = [C, np.zeros(3)]
    used = {m.index for m in result.measurements if m.weight > 0}
    if axes:
        colours = _track_colours(len(axes))
        for i, (k, line) in enumerate(sorted(axes.items())):
            seg = line.points_at([-AXIS_HALF_LENGTH, AXIS_HALF_LENGTH])
            ax.plot(*seg.T, "-" if k in used else ":", color=colours[i], lw=2.0,
                    label=f"wrist axis {k}" + ("" if k in used else " (left out)"))
            ax.scatter(*line.point, color=colours[i], s=12)
            points.extend(seg)
    points = np.array(points)
    size = float(np.max(np.ptp(points, axis=0))) or 1.0
    ax.scatter(0.0, 0.0, 0.0, color="k", marker="s", s=20, label="arm base")
    depth = FRUSTUM_FRACTION * size
    draw_camera(ax, pose, dataset.camera if dataset is not None else None, depth, "camera frustum")
    cov = ros_covariance(pose, result.covariance)[:3, :3]
    if result.covariance_usable:
        largest = math.sqrt(CHI2_95_3DOF * max(np.linalg.eigvalsh(cov).max(), 1e-30))
        if magnify is None:
            magnify = max(1.0, ELLIPSOID_FRACTION * size / largest)
        X, Y, Z = _ellipsoid_surface(C, cov, magnify * math.sqrt(CHI2_95_3DOF))
        ax.plot_wireframe(X, Y, Z, color="tab:purple", lw=0.4, alpha=0.7)
        label = "95 % position ellipsoid" + (f" (x{magnify:.3g})" if magnify > 1.0 else "")
        ax.plot([], [], color="tab:purple", label=label)
    else:
        for d in result.observability.unobservable_directions:
            if np.linalg.norm(d[3:]) > 0.5:
                u = R @ d[3:] / np.linalg.norm(d[3:])
                reach = (points - C) @ u  # the line spans the scene (through the axes' common point, if any)
                ends = [C + (reach.min() - 0.1 * size) * u, C + (reach.max() + 0.1 * size) * u]
                ax.plot(*np.column_stack(ends), "--", color="tab:purple")
        ax.plot([], [], "--", color="tab:purple", label="line along which the camera position is not determined")
    geometry = None if not axes else axis_geometry([axes[k] for k in sorted(axes) if k in used])
    if geometry is not None and geometry.is_crossing:
        ax.scatter(*geometry.point, color="tab:red", marker="*", s=80, label="common point P of the wrist axes")
    cube_axes(ax, points, size)
    ax.set_title("arm_T_camera in the arm-base frame (camera axes: x red, y green, z blue)", fontsize=9)
    ax.legend(loc="upper left", fontsize=7)
    return fig


# ---------------------------------------------------------------------------------------------------
# Monte Carlo figures (the paper's error distributions)


def slope_intercept(line) -> tuple[float, float]:
    """The paper's ``(m, b)`` of an image line ``l . (u, v, 1) = 0`` written ``v = m u + b`` (not vertical)."""
    a, b, c = np.asarray(line, dtype=float)
    if abs(b) < 1e-12 * max(abs(a), 1.0):
        raise InputError("a vertical image line has no slope-intercept form")
    return float(-a / b), float(-c / b)


def _levels(errors, noise_vars, width: int) -> list[np.ndarray]:
    arrays = [np.asarray(e, dtype=float) for e in errors]
    if len(arrays) != len(noise_vars):
        raise InputError(f"got errors for {len(arrays)} noise levels but {len(noise_vars)} noise variances")
    for i, a in enumerate(arrays):
        if a.ndim < 2 or a.shape[-1] != width:
            raise InputError(f"noise level {i}: errors must have shape (trials, ..., {width}), got {a.shape}")
    return arrays


def plot_line_fit_errors(errors, noise_vars: Sequence[float], *, crlb=None) -> Figure:
    """The paper's line-fit error figure: per noise level, the image-axis errors of each measurement.

    Args:
        errors: per noise level, an array (trials, measurements, 2) of the slope error (px⁻¹) and intercept
            error (px) of each measurement's image axis (:func:`slope_intercept` of the estimate minus the truth).
        noise_vars: the pixel noise variance (px²) of each level.
        crlb: optional, per noise level, (measurements, 2, 2) covariances of (slope, intercept) drawn as 95 %
            ellipses (the bound, or the covariance the estimator reports).
    """
    arrays = _levels(errors, noise_vars, 2)
    n = len(arrays)
    fig = new_figure(4.2 * n, 4.0)
    axes = fig.subplots(1, n, squeeze=False)[0]
    for i, (ax, e) in enumerate(zip(axes, arrays, strict=True)):
        e = e.reshape(e.shape[0], -1, 2)
        colours = _track_colours(e.shape[1])
        for k in range(e.shape[1]):
            ax.scatter(e[:, k, 0], e[:, k, 1], s=6, color=colours[k], alpha=0.6, label=f"measurement {k}")
            if crlb is not None:
                cov = np.asarray(crlb[i], dtype=float).reshape(-1, 2, 2)[k]
                w, V = np.linalg.eigh(cov)
                angle = np.degrees(np.arctan2(V[1, 1], V[0, 1]))
                width, height = 2 * np.sqrt(CHI2_95_2DOF * np.maximum(w[::-1], 0.0))
                ax.add_patch(Ellipse((0.0, 0.0), width, height, angle=angle, fill=False, color=colours[k], lw=1.0))
        ax.axhline(0.0, color="0.7", lw=0.5)
        ax.axvline(0.0, color="0.7", lw=0.5)
        ax.set_title(f"σ² = {noise_vars[i]:g} px²", fontsize=9)
        ax.set_xlabel("slope error m (px⁻¹)", fontsize=8)
        ax.set_ylabel("intercept error b (px)", fontsize=8)
        ax.tick_params(labelsize=7)
    axes[0].legend(fontsize=6, markerscale=2)
    fig.suptitle("image-axis fit errors" + (" (ellipses: 95 % of the bound)" if crlb is not None else ""), fontsize=10)
    return fig


def plot_pose_errors(errors, noise_vars: Sequence[float], *, labels: Sequence[str], unit: str, crlb=None,
                     bins: int = 30, title: str = "") -> Figure:
    """Histograms of pose errors: one row per noise level, one column per component.

    Args:
        errors: per noise level, an array (trials, 3) of errors (estimate minus truth) in ``unit``.
        noise_vars: the pixel noise variance (px²) of each level.
        labels: the three component names.
        crlb: optional, per noise level, the three 1σ bounds (Cramér-Rao) in ``unit``: drawn as the normal
            density and its ±1.96σ interval; the panel titles give RMSE / bound.
    """
    arrays = _levels(errors, noise_vars, 3)
    n = len(arrays)
    fig = new_figure(10.0, 2.4 * n + 0.6)
    grid = fig.subplots(n, 3, squeeze=False)
    for i, e in enumerate(arrays):
        e = e.reshape(-1, 3)
        bound = None if crlb is None else np.asarray(crlb[i], dtype=float).reshape(3)
        for c in range(3):
            ax = grid[i, c]
            x = e[:, c]
            ax.hist(x, bins=bins, density=True, color="tab:blue", alpha=0.7)
            rmse = float(np.sqrt(np.mean(x**2)))
            text = f"{labels[c]}, σ² = {noise_vars[i]:g} px²: RMSE {rmse:.3g} {unit}"
            if bound is not None and bound[c] > 0:
                s = bound[c]
                grid_x = np.linspace(-4 * s, 4 * s, 200)
                ax.plot(grid_x, np.exp(-0.5 * (grid_x / s) ** 2) / (s * np.sqrt(2 * np.pi)), color="tab:red", lw=1.2)
                for sign in (-1, 1):
                    ax.axvline(sign * Z95 * s, color="tab:red", ls="--", lw=0.8)
                text += f" ({rmse / s:.2f}x bound)"
            ax.axvline(float(np.mean(x)), color="k", lw=0.8)
            ax.set_title(text, fontsize=7)
            ax.set_xlabel(f"error ({unit})", fontsize=7)
            ax.tick_params(labelsize=6)
    suffix = " (red: Cramér-Rao bound, ±1.96σ dashed; black: mean)" if crlb is not None else " (black: mean)"
    fig.suptitle((title or "pose errors") + suffix, fontsize=9)
    return fig


def plot_cartesian_errors(errors_mm, noise_vars: Sequence[float], *, crlb_mm=None, bins: int = 30) -> Figure:
    """The paper's Cartesian error figures: camera position errors x, y, z (mm, arm frame) per noise level."""
    return plot_pose_errors(errors_mm, noise_vars, labels=("x", "y", "z"), unit="mm", crlb=crlb_mm, bins=bins,
                            title="Cartesian position errors")


def plot_angular_errors(errors_deg, noise_vars: Sequence[float], *, crlb_deg=None,
                        labels: Sequence[str] = ("roll", "pitch", "yaw"), bins: int = 30) -> Figure:
    """The paper's angular error figures (deg) per noise level; ``labels`` names the three angles."""
    return plot_pose_errors(errors_deg, noise_vars, labels=labels, unit="deg", crlb=crlb_deg, bins=bins,
                            title="angular errors")


# ---------------------------------------------------------------------------------------------------
# the report's set of files


def plot_files(result, dataset, directory: str | os.PathLike) -> list[Path]:
    """The PNG files :func:`save_plots` writes."""
    directory = Path(directory)
    names = ["pose_3d.png"]
    if dataset is not None:
        names += [f"tracks_m{k}.png" for k in range(len(dataset))] + ["residuals.png"]
    return [directory / name for name in names]


def _report_figures(result, dataset) -> list[Figure]:
    """The report's figures, in :func:`plot_files` order."""
    figures = [plot_pose_3d(result, dataset)]
    if dataset is not None:
        fits = [fit_tracks(result, dataset, k) for k in range(len(dataset))]
        figures += [plot_tracks(result, dataset, k, fit=fit) for k, fit in enumerate(fits)]
        figures.append(plot_residual_histograms(result, dataset, fits=fits))
    return figures


def report_pngs(result, dataset=None) -> list[tuple[str, bytes]]:
    """The report's figures as (name, PNG bytes), in :func:`plot_files` order: for a page that embeds them."""
    out = []
    for fig, path in zip(_report_figures(result, dataset), plot_files(result, dataset, "."), strict=True):
        buffer = io.BytesIO()
        fig.savefig(buffer, format="png", dpi=DPI)
        out.append((path.stem, buffer.getvalue()))
    return out


def save_plots(result, dataset, directory: str | os.PathLike, *, overwrite: bool = False) -> list[Path]:
    """Write the 3-D view and, with the dataset, each measurement's tracks and the residual histograms, as PNG.

    Refuses (before drawing) to replace existing files unless ``overwrite``. Returns the paths written.
    """
    directory = Path(directory)
    if not directory.is_dir():
        raise OutputError(f"{directory} is not a directory")
    paths = check_outputs(plot_files(result, dataset, directory), overwrite)
    for fig, path in zip(_report_figures(result, dataset), paths, strict=True):
        with staged(path, overwrite) as staging:
            fig.savefig(staging, dpi=DPI)
    return paths


# ---------------------------------------------------------------------------------------------------
# the quad view on a video frame


def _zoom_box(camera, tracks: list[np.ndarray]) -> tuple[tuple[float, float], tuple[float, float]]:
    """(x limits, y limits, rows downwards) of a box around the tracks with the image's aspect ratio."""
    if not tracks:
        return (-0.5, camera.width - 0.5), (camera.height - 0.5, -0.5)
    points = np.vstack(tracks)
    lo, hi = points.min(axis=0), points.max(axis=0)
    centre, half = 0.5 * (lo + hi), 0.5 * (hi - lo) * 1.15 + 5.0
    half = np.maximum(half, half[::-1] * np.array([camera.width / camera.height, camera.height / camera.width]))
    return (centre[0] - half[0], centre[0] + half[0]), (centre[1] + half[1], centre[1] - half[1])


def _show_frame(ax, frame: np.ndarray, camera, alpha: float = 1.0) -> None:
    image = np.asarray(frame)
    extent = (-0.5, camera.width - 0.5, camera.height - 0.5, -0.5)
    if image.ndim == 3:  # OpenCV's BGR
        ax.imshow(image[..., ::-1], extent=extent, alpha=alpha, interpolation="nearest")
    else:
        ax.imshow(image, cmap="gray", vmin=0, vmax=255, extent=extent, alpha=alpha, interpolation="nearest")


def plot_overlay(frame, result, dataset, k: int, *, frame_number: int | None = None,
                 fit: TrackFit | None = None) -> Figure:
    """Measurement ``k`` over one of its video frames, in four panels (the paper's "quad view"):

    1. the frame as recorded (the box shows where the other panels zoom in);
    2. the features tracked in that frame (``frame_number``: the frame's number in the tracks' ``frames``), a
       ring per tracked point, coloured by track;
    3. every track's arc over the whole spin, tracks the estimator rejected in grey;
    4. the circles fitted about the wrist axis projected by the estimate, that projected axis, and the stage-1
       image axis (as :func:`plot_tracks`).

    ``frame``: uint8 grey (H, W) or BGR (H, W, 3) image of the camera's size; ``fit`` reuses :func:`fit_tracks`.
    """
    camera = dataset.camera
    image = np.asarray(frame)
    if image.shape[:2] != (camera.height, camera.width):
        raise InputError(f"the frame is {image.shape[1]}x{image.shape[0]} but the camera's image is "
                         f"{camera.width}x{camera.height}")
    fit = fit_tracks(result, dataset, k) if fit is None else fit
    tracks = [Track.from_any(t) for t in dataset[k].tracks]
    colours = _track_colours(len(tracks))
    kept = set(fit.circles) if fit.line is not None else set(range(len(tracks)))
    xlim, ylim = _zoom_box(camera, [t.pixels for t in tracks])
    fig = new_figure(11.0, 8.6)
    (raw, detected), (arcs, fitted) = fig.subplots(2, 2)

    _show_frame(raw, image, camera)
    raw.plot([xlim[0], xlim[1], xlim[1], xlim[0], xlim[0]], [ylim[0], ylim[0], ylim[1], ylim[1], ylim[0]], "-",
             color="tab:orange", lw=1.0)
    raw.set_xlim(-0.5, camera.width - 0.5)
    raw.set_ylim(camera.height - 0.5, -0.5)
    where = "" if frame_number is None else f" {frame_number}"
    raw.set_title(f"1. frame{where} of the video (box: the zoom of the other panels)", fontsize=9)

    _show_frame(detected, image, camera)
    n_here = 0
    if frame_number is not None:
        for j, t in enumerate(tracks):
            if t.frames is None:
                continue
            i = np.searchsorted(t.frames, frame_number)
            if i < len(t.frames) and t.frames[i] == frame_number:
                n_here += 1
                detected.plot(*t.pixels[i], "o", ms=11.0, mfc="none", mew=1.4, color=colours[j])
    detected.set_title(f"2. features tracked in this frame: {n_here}", fontsize=9)

    _show_frame(arcs, image, camera, alpha=0.45)
    for j, t in enumerate(tracks):
        if j in kept:
            arcs.plot(t.pixels[:, 0], t.pixels[:, 1], "-", lw=1.2, color=colours[j])
        else:
            arcs.plot(t.pixels[:, 0], t.pixels[:, 1], "-", lw=0.8, color="0.5")
    arcs.set_title(f"3. tracked arcs over the spin: {len(kept)} kept, {len(tracks) - len(kept)} rejected (grey)",
                   fontsize=9)

    _show_frame(fitted, image, camera, alpha=0.45)
    _draw_tracks(fitted, result, dataset, k, fit, True)
    fitted.set_title(f"4. circles fitted about the {_spin_axis_name(dataset, k)}, and that axis, projected by the "
                     "estimate", fontsize=9)

    for ax in (detected, arcs, fitted):
        ax.set_xlim(*xlim)
        ax.set_ylim(*ylim)
    for ax in (raw, detected, arcs, fitted):
        ax.set_aspect("equal")
        ax.tick_params(labelsize=7)
    fig.suptitle(_measurement_title(result, k, f"{len(tracks)} tracks", fit, 3), fontsize=10)
    return fig


def overlay_files(directory: str | os.PathLike, measurements) -> list[Path]:
    """The PNG files :func:`save_overlays` writes for these measurement indices."""
    return [Path(directory) / f"overlay_m{k}.png" for k in measurements]


def save_overlays(result, dataset, frames, directory: str | os.PathLike, *, overwrite: bool = False) -> list[Path]:
    """Write :func:`plot_overlay` of each measurement as ``overlay_m{k}.png`` in ``directory``.

    ``frames``: a mapping ``k -> (frame_number, image)`` (measurements without a frame are skipped). Refuses
    (before drawing) to replace existing files unless ``overwrite``. Returns the paths written.
    """
    directory = Path(directory)
    if not directory.is_dir():
        raise OutputError(f"{directory} is not a directory")
    order = sorted(frames)
    paths = check_outputs(overlay_files(directory, order), overwrite)
    for k, path in zip(order, paths, strict=True):
        frame_number, image = frames[k]
        fig = plot_overlay(image, result, dataset, k, frame_number=frame_number)
        with staged(path, overwrite) as staging:
            fig.savefig(staging, dpi=DPI)
    return paths

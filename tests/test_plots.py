"""Plots: figures are drawn headless (Agg), files are not replaced (the fitted circles they draw: test_fits.py)."""

import dataclasses
import io

import numpy as np
import pytest
from matplotlib.figure import Figure

from gtsam_rotid import InputError
from gtsam_rotid.errors import OutputError
from gtsam_rotid.plots import (
    fit_tracks,
    plot_angular_errors,
    plot_cartesian_errors,
    plot_line_fit_errors,
    plot_pose_3d,
    plot_residual_histograms,
    plot_tracks,
    save_plots,
    slope_intercept,
)
from gtsam_rotid.uncertainty import analyse_observability


@pytest.fixture(scope="module")
def reference(reference_8s_weighted):
    return reference_8s_weighted


def png_bytes(fig: Figure) -> bytes:
    buffer = io.BytesIO()
    fig.savefig(buffer, format="png", dpi=40)
    return buffer.getvalue()


def test_tracks_and_residual_figures(reference):
    dataset, _, result = reference
    fits = [fit_tracks(result, dataset, k) for k in range(2)]
    fig = plot_tracks(result, dataset, 1, fit=fits[1])
    assert isinstance(fig, Figure) and len(fig.axes) == 2  # the whole image and the zoom
    assert png_bytes(fig)[:4] == b"\x89PNG"
    fig = plot_residual_histograms(result, dataset, fits=fits)
    assert sum(ax.get_visible() for ax in fig.axes) == 2
    assert png_bytes(fig)[:4] == b"\x89PNG"


def test_pose_3d_figure_usable_and_degenerate(reference):
    dataset, _, result = reference
    fig = plot_pose_3d(result, dataset)
    labels = [t.get_text() for t in fig.axes[0].get_legend().get_texts()]
    assert any(label.startswith("95 % position ellipsoid") for label in labels)
    assert sum(label.startswith("wrist axis") for label in labels) == len(dataset)
    assert png_bytes(fig)[:4] == b"\x89PNG"
    # the same result with the position along one direction made undetermined
    info = np.linalg.inv(result.covariance)
    d = np.array([0.0, 0.0, 0.0, 0.6, 0.0, 0.8])
    P = np.eye(6) - np.outer(d, d)
    degenerate = dataclasses.replace(result, observability=analyse_observability(P @ info @ P, result.arm_T_camera))
    assert not degenerate.covariance_usable
    fig = plot_pose_3d(degenerate)  # no dataset: no wrist axes, a default frustum
    labels = [t.get_text() for t in fig.axes[0].get_legend().get_texts()]
    assert any("not determined" in label for label in labels)
    assert not any("ellipsoid" in label for label in labels)
    assert png_bytes(fig)[:4] == b"\x89PNG"


def test_monte_carlo_figures_from_arrays():
    rng = np.random.default_rng(0)
    noise_vars = [0.1, 1.5]
    bound_mm = np.array([[0.1, 0.2, 0.1], [0.4, 0.8, 0.4]])
    errors_mm = [rng.normal(size=(200, 3)) * b for b in bound_mm]
    fig = plot_cartesian_errors(errors_mm, noise_vars, crlb_mm=bound_mm)
    assert len(fig.axes) == 6
    title = fig.axes[4].get_title()  # level 1, y
    ratio = np.sqrt(np.mean(errors_mm[1][:, 1] ** 2)) / bound_mm[1, 1]
    assert f"({ratio:.2f}x bound)" in title
    assert png_bytes(fig)[:4] == b"\x89PNG"
    fig = plot_angular_errors([e * 0.01 for e in errors_mm], noise_vars)
    assert fig.axes[0].get_title().startswith("roll")
    line_errors = [rng.normal(size=(100, 6, 2)) * [1e-3, 0.5] for _ in noise_vars]
    crlb = [np.tile(np.diag([1e-6, 0.25]), (6, 1, 1)) for _ in noise_vars]
    fig = plot_line_fit_errors(line_errors, noise_vars, crlb=crlb)
    assert len(fig.axes) == 2 and len(fig.axes[0].patches) == 6  # one 95 % ellipse per measurement
    assert png_bytes(fig)[:4] == b"\x89PNG"
    with pytest.raises(InputError, match="noise levels"):
        plot_cartesian_errors(errors_mm, [0.1])
    with pytest.raises(InputError, match="shape"):
        plot_cartesian_errors([np.zeros((10, 2))], [0.1])


def test_slope_intercept_of_a_line_through_two_points():
    u = np.array([[10.0, 20.0, 1.0], [110.0, 70.0, 1.0]])
    line = np.cross(u[0], u[1])
    m, b = slope_intercept(line / np.hypot(*line[:2]))
    assert m == pytest.approx(0.5) and b == pytest.approx(15.0)
    with pytest.raises(InputError, match="vertical"):
        slope_intercept([1.0, 0.0, -5.0])


def test_save_plots_refuses_to_overwrite(reference, tmp_path):
    _, _, result = reference
    written = save_plots(result, None, tmp_path)
    assert [p.name for p in written] == ["pose_3d.png"]
    before = written[0].read_bytes()
    with pytest.raises(OutputError, match="overwrite"):
        save_plots(result, None, tmp_path)
    assert written[0].read_bytes() == before
    assert save_plots(result, None, tmp_path, overwrite=True) == written

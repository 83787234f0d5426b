"""The picture of a plan (report layer): the planned wrist axes, the arm in each pose and the camera in 3-D, and
the predicted image of each spin's arcs."""

from __future__ import annotations

import numpy as np
from matplotlib.figure import Figure

from .arm import Arm
from .camera import Camera
from .planning import Prediction
from .plots import AXIS_HALF_LENGTH, FRUSTUM_FRACTION, _track_colours, cube_axes, draw_camera, new_figure


def plot_plan(arm: Arm, camera: Camera, prediction: Prediction, spins: list, recorded=()) -> Figure:
    """Left: each pose's wrist axis (solid) and arm skeleton (thin), the camera's frustum and axes, and the wrist
    axes of poses already ``recorded`` (joint angles; dashed grey), in the arm-base frame. Right: the arcs the camera
    would see of a typical texture in each pose (``spins``: from :func:`gtsam_rotid.planning.predicted_spins`), one
    colour per pose, over the image."""
    fig = new_figure(12.0, 5.5)
    ax = fig.add_subplot(1, 2, 1, projection="3d")
    image = fig.add_subplot(1, 2, 2)
    colours = _track_colours(len(prediction.joint_angles))
    pose = prediction.arm_T_camera
    points = [np.asarray(pose.translation(), dtype=float), np.zeros(3)]
    for k, q in enumerate(prediction.joint_angles):
        axis = arm.wrist_axis(q)
        segment = axis.points_at([-AXIS_HALF_LENGTH, AXIS_HALF_LENGTH])
        skeleton = np.vstack([np.zeros(3), arm.joint_origins(q)])
        ax.plot(*skeleton.T, "-o", color=colours[k], lw=0.8, ms=2, alpha=0.5)
        ax.plot(*segment.T, color=colours[k], lw=2.5, label=f"pose {k}")
        points.extend(segment)
        points.extend(skeleton)
    for k, q in enumerate(recorded):
        segment = arm.wrist_axis(q).points_at([-AXIS_HALF_LENGTH, AXIS_HALF_LENGTH])
        ax.plot(*segment.T, "--", color="0.5", lw=1.5, label="recorded poses" if k == 0 else None)
        points.extend(segment)
    points = np.array(points)
    size = float(np.max(np.ptp(points, axis=0))) or 1.0
    draw_camera(ax, pose, camera, FRUSTUM_FRACTION * size, "camera (guess)")
    ax.scatter(0.0, 0.0, 0.0, color="k", marker="s", s=20, label="arm base")
    cube_axes(ax, points, size)
    ax.legend(loc="upper left", fontsize=7)
    s = prediction.sigma
    title = (f"planned wrist axes; predicted 1σ {s[:3].max():.3g}° / {s[3:].max():.3g} mm (worst axes)"
             if prediction.observability.is_observable else
             "planned wrist axes: DEGENERATE, they do not determine the calibration")
    ax.set_title(title, fontsize=9)
    for k, spin in enumerate(spins):
        if spin is None:
            continue
        for track in spin.tracks:
            image.plot(track.pixels[:, 0], track.pixels[:, 1], ".", ms=1.0, color=colours[k])
        image.plot([], [], "o", ms=4, color=colours[k], label=f"pose {k}")
    image.set_xlim(-0.5, camera.width - 0.5)
    image.set_ylim(camera.height - 0.5, -0.5)
    image.set_aspect("equal")
    image.set_xlabel("u (px)")
    image.set_ylabel("v (px)")
    image.set_title("predicted arcs of a typical texture (noise-free), per pose", fontsize=9)
    image.legend(loc="upper right", fontsize=7)
    return fig

"""Custom GTSAM factors of gtsam_rotid (a low-level layer: imports only numpy and gtsam).

Variables (all in the camera frame of one measurement; the stage-1 scene is known only up to scale):

- **Line variable** ``gtsam.Rot3`` ``R`` with columns ``(c0, c1, c2)``: the wrist axis is ``{c0 + s c1}``. ``c0`` is
  the foot of the perpendicular from the camera centre at unit distance (fixes the scale gauge: camera-to-axis
  distance = 1, and the slide gauge: offsets are measured from the foot), ``c1`` the axis direction and
  ``c2 = c0 x c1`` the normal of the plane through the camera centre that contains the axis; its image line is
  ``l ∝ K^-T c2``. Retraction is GTSAM's ``R * Exp(w)``, so ``gtsam.Marginals`` is well posed.
- **Circle variable** (one per track) 2-vector ``(d, r)``: offset ``d`` along ``c1`` from the foot, radius ``r``.
  Its point at phase ``phi`` is ``X(phi) = R @ (1 + r sin(phi), d, r cos(phi))``.
- **arm_T_camera** ``gtsam.Pose3`` (GTSAM tangent: rotation first, translation in the camera frame, perturbation
  on the right).

Pixels are ideal (undistorted): ``u = pi(K X)``. Image lines are homogeneous ``l`` with ``l1^2 + l2^2 = 1``; the
signed distance of pixel ``u`` is ``l . (u, 1)``. :func:`rot3_from_line` converts a metric camera-frame line into a
line variable and the scale (camera-to-axis distance) that converts metric offsets and radii.

Factories (thin ``gtsam.CustomFactor`` wrappers over the pure functions in :mod:`.geometry` and
:mod:`.circle_track`):

- :func:`make_circle_point_factor` — one track's pixels vs. its projected circle (keys: line, circle); its maths is
  :class:`CircleTrack` (closed-form residuals and Jacobians, warm-started closest phases).
- :func:`make_axis_to_line_factor` — projected FK axis test points vs. a measured image line (key: pose).
- :func:`make_axis_to_line_variable_factor` — the same vs. a line variable's image (keys: pose, line).
- :func:`make_axis_offsets_to_line_factor`, :func:`make_axis_offsets_to_line_variable_factor` — the same two with
  the FK axis a function of joint offsets (one more key: the offsets vector).
- :func:`make_pose_circle_point_factor` — one track's pixels vs. its projected circle about the FK axis mapped
  by the pose (keys: pose, circle): the joint model with exact kinematics, no line variable.
- :func:`make_rigid_circle_factor` (:mod:`.rigid`) — the rigid-spin model: one track's 2-D reprojection errors
  at phase ``theta_f + phi0_j`` with the spin angles ``theta_f`` shared by all tracks of the measurement
  (keys: line, track ``(d, r, phi0)``, spin-angle chunks); :func:`initial_spin` and :func:`spin_priors` start
  it and fix its gauge (the whole rigid graph: tests and small problems).
- :func:`make_rigid_line_factor` (:mod:`.rigid_line`) — the same model with every track's ``(d, r, phi0)`` and
  the spin angles projected out (key: line): what the estimators use.
- :func:`make_coaxial_line_factor` (:mod:`.coaxial`) — all tracks of one measurement, their circles projected out
  (key: line), over a :class:`CoaxialTracks`.

Modules: :mod:`.geometry` (parametrisation, projection, image lines, projected circles, FK axis points);
:mod:`.circle_track` (one track's certified closest phases, residuals and Jacobians) with :mod:`.ellipse` (the
image conic's certificates); :mod:`.coaxial_tracks` (all tracks of a measurement at once) with
:mod:`.coaxial_coefficients` (its per-track coefficient tables), :mod:`.coaxial_layout` (its padded pixel layout)
and :mod:`.coaxial_solve` (the circles projected out); :mod:`.coaxial` (the variable-projection line factor); the
factor modules :mod:`.circle`, :mod:`.axis`, :mod:`.pose_circle`, :mod:`.rigid` and :mod:`.rigid_line`.
"""

from .axis import (
    axis_offsets_residuals,
    make_axis_offsets_to_line_factor,
    make_axis_offsets_to_line_variable_factor,
    make_axis_to_line_factor,
    make_axis_to_line_variable_factor,
)
from .circle import make_circle_point_factor
from .circle_track import CircleTrack, circle_point_residuals, closest_phases
from .coaxial import CoaxialLineFactor, make_coaxial_line_factor
from .coaxial_tracks import CoaxialTracks
from .geometry import (
    axis_point_residuals,
    cal3_s2,
    circle_coordinates,
    circle_points,
    image_line_from_rot3,
    line_distance_covariance,
    line_distances,
    line_points,
    project,
    projected_circle,
    rot3_from_line,
    transform_to_camera,
)
from .pose_circle import FKAxis, line_from_pose, make_pose_circle_point_factor
from .rigid import (
    SpinInit,
    chunk_segments,
    initial_spin,
    make_rigid_circle_factor,
    rigid_spin_residuals,
    spin_chunk_index,
    spin_priors,
)
from .rigid_line import (
    EncoderPrior,
    RigidLineFactor,
    RigidTracks,
    closest_spin,
    make_rigid_line_factor,
    readings_cover,
)

__all__ = [
    "EncoderPrior",
    "CircleTrack",
    "CoaxialLineFactor",
    "CoaxialTracks",
    "FKAxis",
    "RigidLineFactor",
    "RigidTracks",
    "SpinInit",
    "axis_offsets_residuals",
    "axis_point_residuals",
    "cal3_s2",
    "chunk_segments",
    "circle_coordinates",
    "circle_point_residuals",
    "circle_points",
    "closest_phases",
    "closest_spin",
    "image_line_from_rot3",
    "initial_spin",
    "line_distance_covariance",
    "line_distances",
    "line_from_pose",
    "line_points",
    "make_axis_offsets_to_line_factor",
    "make_axis_offsets_to_line_variable_factor",
    "make_axis_to_line_factor",
    "make_axis_to_line_variable_factor",
    "make_circle_point_factor",
    "make_coaxial_line_factor",
    "make_pose_circle_point_factor",
    "make_rigid_circle_factor",
    "make_rigid_line_factor",
    "project",
    "projected_circle",
    "readings_cover",
    "rigid_spin_residuals",
    "rot3_from_line",
    "spin_chunk_index",
    "spin_priors",
    "transform_to_camera",
]

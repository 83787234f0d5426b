"""Ray casting of the arm's meshes (Embree through trimesh), shading, the scene geometry of one spin, and whether
a pose can be rendered (:func:`pose_problem`).
"""

from __future__ import annotations

import cv2
import numpy as np

from .arm import Arm
from .armmeshes import ArmMeshes, load_arm_meshes
from .camera import Camera
from .errors import ArmError
from .geometry import perpendicular_basis, rotation_about_axis
from .meshconfig import MeshRenderConfig, _bgr
from .meshtextures import _floor_texture, _hand_texture, _sample, _texture_shape, _wall_texture

_CAP_COS = 0.75  # faces with |normal . axis| above this get the planar (cap) mapping
_NEAR = 0.01  # m: the spinning links must stay this far in front of the camera
_CHECK_ANGLES = 8


# --------------------------------------------------------------------------------------------- ray casting
class _Caster:
    """One Embree scene of triangles (float32 vertices), with per-face unit normals and owners."""

    def __init__(self, vertices: list[np.ndarray], faces: list[np.ndarray], owners: list[int]):
        from embreex import mesh_construction, rtcore_scene

        offsets = np.cumsum([0] + [len(v) for v in vertices])
        self.vertices = np.vstack(vertices).astype(np.float64)
        self.faces = np.vstack([f + o for f, o in zip(faces, offsets[:-1], strict=True)]).astype(np.int32)
        self.owner = np.concatenate([np.full(len(f), o, np.int32) for f, o in zip(faces, owners, strict=True)])
        a, b, c = (self.vertices[self.faces[:, i]] for i in range(3))
        normal = np.cross(b - a, c - a)
        norm = np.linalg.norm(normal, axis=1, keepdims=True)
        self.normals = np.where(norm > 0, normal / np.maximum(norm, 1e-300), 0.0).astype(np.float32)
        self._scene = rtcore_scene.EmbreeScene()
        self._mesh = mesh_construction.TriangleMesh(scene=self._scene, vertices=self.vertices.astype(np.float32),
                                                    indices=self.faces)

    def cast(self, origin: np.ndarray, directions: np.ndarray, far: np.ndarray | None = None):
        """First hits of rays from one ``origin`` along unit ``directions`` (N, 3): (t, face); t = inf and
        face = -1 where nothing is hit (before ``far``, when given)."""
        n = len(directions)
        if n == 0:
            return np.zeros(0), np.zeros(0, np.int64)
        origins = np.empty((n, 3), np.float32)
        origins[:] = np.asarray(origin, dtype=np.float32)
        dirs = np.ascontiguousarray(directions, dtype=np.float32)
        if far is None:
            result = self._scene.run(origins, dirs, output=1)
        else:
            limit = np.ascontiguousarray(np.minimum(far, 1e30), dtype=np.float32)
            result = self._scene.run(origins, dirs, dists=limit, output=1)
        face = result["primID"].astype(np.int64)
        hit = result["geomID"] >= 0
        face[~hit] = -1
        t = np.where(hit, result["tfar"].astype(np.float64), np.inf)
        return t, face


def _cell_corners(points: np.ndarray, cell: float) -> np.ndarray:
    """Corners (float32) of the ``cell``-sized grid cubes that hold ``points``: a few hundred points whose
    convex hull contains every point (conservative bounds at a fraction of the cost of all vertices)."""
    index = np.unique(np.floor(points / cell).astype(np.int64), axis=0)
    offsets = np.array([[i, j, k] for i in (0, 1) for j in (0, 1) for k in (0, 1)])
    corners = np.unique((index[:, None, :] + offsets[None]).reshape(-1, 3), axis=0)
    return (corners * cell).astype(np.float32)


def _shade(albedo: np.ndarray, normal: np.ndarray, view: np.ndarray, light: np.ndarray,
           config: MeshRenderConfig) -> np.ndarray:
    """Ambient + Lambert + Blinn-Phong of (N, 3) BGR albedos; ``view`` runs from the camera to the surface."""
    cos_view = np.einsum("ij,ij->i", normal, view)
    normal = np.where((cos_view > 0)[:, None], -normal, normal)
    ndl = normal @ light
    half = light[None, :] - view
    half /= np.maximum(np.linalg.norm(half, axis=1, keepdims=True), 1e-9)
    ndh = np.maximum(np.einsum("ij,ij->i", normal, half), 0.0)
    lit = ndl > 0
    diffuse = np.float32(config.ambient) + np.float32(config.diffuse) * np.maximum(ndl, 0.0)
    highlight = np.where(lit, np.float32(config.specular * 255.0) * ndh ** np.float32(config.shininess), 0.0)
    return (albedo * diffuse[:, None] + highlight[:, None]).astype(np.float32)


class _Geometry:
    """One measurement's scene: the still part in the camera frame, the spinning part in the frame of the spinning
    joint (``spin_joint``, default the wrist: the meshes of that joint and of every joint after it turn with it)."""

    def __init__(self, arm: Arm, meshes: ArmMeshes, camera: Camera, arm_T_camera, joint_angles,
                 config: MeshRenderConfig, spin_joint: str | None = None, wall_arm_T_camera=None):
        self.camera = camera
        self.config = config
        q = arm.joint_angle_vector(joint_angles)
        self.joint_angles = q
        model = arm.model
        self.spin_index = arm.spin_index(spin_joint)  # (an ArmError names a joint the arm does not have)
        self.spin_joint = arm.joint_names[self.spin_index]
        spinning = model.getJointId(self.spin_joint)
        moving_joints = set()
        for jid in range(model.njoints):
            j = jid
            while j > 0 and j != spinning:
                j = model.parents[j]
            if j == spinning:
                moving_joints.add(jid)
        camera_T_arm = arm_T_camera.inverse()
        self.cam_R_arm = camera_T_arm.rotation().matrix()
        self.cam_t_arm = camera_T_arm.translation()
        # the back wall faces the camera whose pose is wall_arm_T_camera (default this one): (rotation of that
        # camera's frame into this one, this camera's centre in that frame), or None when it is this camera
        self.wall = None
        if wall_arm_T_camera is not None:
            here_T_wall = camera_T_arm * wall_arm_T_camera
            R = here_T_wall.rotation().matrix()
            self.wall = (R, -R.T @ here_T_wall.translation())
        arm_T_link = arm.arm_T_joint(q, self.spin_joint)
        self.arm_R_link = arm_T_link.rotation().matrix()
        self.arm_t_link = arm_T_link.translation()
        link_T_camera = arm_T_link.inverse() * arm_T_camera
        self.link_R_cam = link_T_camera.rotation().matrix()  # at spin 0
        self.link_t_cam = link_T_camera.translation()  # camera centre in the link frame at spin 0
        self.axis = arm.wrist_axis_local(self.spin_joint)
        self.e1, self.e2 = perpendicular_basis(self.axis)
        placements = {}
        for jid in set(meshes.joint_ids):
            placements[jid] = arm.arm_T_joint(q, model.names[jid])
        still_v, still_f, still_o, move_v, move_f, move_o = [], [], [], [], [], []
        self.still_boxes, self.moving_names = [], []
        for i, (jid, v, f) in enumerate(zip(meshes.joint_ids, meshes.vertices, meshes.faces, strict=True)):
            pose = placements[jid]
            R, t = pose.rotation().matrix(), pose.translation()
            arm_v = v @ R.T + t
            if jid in moving_joints:
                move_v.append((arm_v - self.arm_t_link) @ self.arm_R_link)
                move_f.append(f)
                move_o.append(i)
                self.moving_names.append(meshes.names[i])
            else:
                still_v.append(arm_v @ self.cam_R_arm.T + self.cam_t_arm)
                still_f.append(f)
                still_o.append(i)
                centre_local = (np.asarray(arm_T_camera.translation()) - t) @ R
                self.still_boxes.append((meshes.names[i], v.min(axis=0), v.max(axis=0), centre_local))
        if not move_v:
            raise ArmError(f"no visual geometry is attached to the spinning joint {self.spin_joint!r} or after it")
        self.moving = _Caster(move_v, move_f, move_o)
        self.still = _Caster(still_v, still_f, still_o) if still_v else None
        arm_color = None if config.arm_color is None else _bgr(config.arm_color)
        self.still_albedo = np.array([arm_color if arm_color is not None else _bgr(c * 255.0)
                                      for c in meshes.colors], np.float32)
        mv = self.moving.vertices
        axial = mv @ self.axis
        self.axial_range = (float(axial.min()), float(axial.max()))
        self.max_radius = float(np.max(np.linalg.norm(mv - np.outer(axial, self.axis), axis=1)))
        self.hull_points = _cell_corners(mv, 0.01)  # their hull holds every vertex: bounds a frame's projection
        cap = np.abs(self.moving.normals @ self.axis.astype(np.float32)) > _CAP_COS
        self.cap_face = cap
        self.light_arm = (np.asarray(config.light_direction, float) / np.linalg.norm(config.light_direction))
        self.light_cam = (self.cam_R_arm @ self.light_arm).astype(np.float32)

    # ------------------------------------------------------------------ frames of the spinning link
    def link_rotation(self, spin: float) -> np.ndarray:
        """R(spin) about the spinning joint's local axis: link(spin) = link(0) * R(spin)."""
        return rotation_about_axis(self.axis, [spin])[0]

    def camera_in_link(self, spin: float) -> tuple[np.ndarray, np.ndarray]:
        """(link_R_camera, camera centre in the link frame) at a spin angle."""
        Rt = self.link_rotation(spin).T
        return Rt @ self.link_R_cam, Rt @ self.link_t_cam

    def link_to_camera(self, spins: np.ndarray, points: np.ndarray) -> np.ndarray:
        """Link-frame points (N, 3) at spin angles (F,) -> camera-frame points (F, N, 3)."""
        rotations = rotation_about_axis(self.axis, spins)  # (F, 3, 3)
        rotated = np.einsum("fij,nj->fni", rotations, points) - self.link_t_cam
        return rotated @ self.link_R_cam  # link_R_cam^T applied on the left

    # ------------------------------------------------------------------ casting
    def cast_still(self, dirs_cam: np.ndarray):
        """Still scene along camera-frame unit rays: (t, kind, face): kind 0 mesh, 1 floor, 2 wall."""
        n = len(dirs_cam)
        if self.still is not None:
            t, face = self.still.cast(np.zeros(3), dirs_cam)
        else:
            t, face = np.full(n, np.inf), np.full(n, -1, np.int64)
        kind = np.zeros(n, np.int8)
        with np.errstate(divide="ignore", invalid="ignore"):
            if self.wall is None:
                t_wall = np.where(dirs_cam[:, 2] > 1e-9, self.config.background_distance / dirs_cam[:, 2], np.inf)
            else:  # (the wall of another camera pose: the plane z = distance of that camera's frame)
                R, centre = self.wall
                dz = dirs_cam @ R[:, 2]
                t_wall = np.where(dz > 1e-9, (self.config.background_distance - centre[2]) / dz, np.inf)
                t_wall = np.where(t_wall > 0, t_wall, np.inf)
            t_floor = np.full(n, np.inf)
            if self.config.floor:
                dirs_arm_z = dirs_cam @ self.cam_R_arm[:, 2]  # z component in the arm frame
                centre_z = float((-self.cam_R_arm.T @ self.cam_t_arm)[2])
                t_floor = np.where(np.abs(dirs_arm_z) > 1e-12, (self.config.floor_height - centre_z) / dirs_arm_z,
                                   np.inf)
                t_floor = np.where(t_floor > 0, t_floor, np.inf)
        floor = (t_floor < t) & (t_floor <= t_wall)
        wall = (t_wall < t) & (t_wall < t_floor)
        t = np.where(floor, t_floor, np.where(wall, t_wall, t))
        kind[floor] = 1
        kind[wall] = 2
        face[floor | wall] = -1
        return t, kind, face

    def cast_moving(self, spin: float, dirs_cam: np.ndarray, far: np.ndarray | None = None):
        """Spinning links along camera-frame unit rays at a spin angle: (t, face, link-frame directions, origin)."""
        R, origin = self.camera_in_link(spin)
        dirs = (dirs_cam @ R.T).astype(np.float32)
        t, face = self.moving.cast(origin, dirs, far)
        return t, face, dirs, origin

    # ------------------------------------------------------------------ colours
    def still_colors(self, dirs_cam: np.ndarray, t: np.ndarray, kind: np.ndarray, face: np.ndarray) -> np.ndarray:
        cfg = self.config
        out = np.zeros((len(dirs_cam), 3), np.float32)
        mesh = face >= 0
        if np.any(mesh):
            albedo = self.still_albedo[self.still.owner[face[mesh]]]
            out[mesh] = _shade(albedo, self.still.normals[face[mesh]], dirs_cam[mesh].astype(np.float32),
                               self.light_cam, cfg)
        floor = kind == 1
        if np.any(floor):
            points_cam = dirs_cam[floor] * t[floor, None]
            points_arm = (points_cam - self.cam_t_arm) @ self.cam_R_arm
            albedo = _sample(_floor_texture(cfg.seed), points_arm[:, 0] / 0.002, points_arm[:, 1] / 0.002)
            lit = np.float32(cfg.ambient + cfg.diffuse * max(float(self.light_arm[2]), 0.0))
            out[floor] = albedo * lit
        wall = kind == 2
        if np.any(wall):
            texture, per_texel = _wall_texture(cfg.background, cfg.seed)
            height, width = texture.shape[:2]
            points = dirs_cam[wall] * t[wall, None]
            if self.wall is not None:  # (in the frame of the camera the wall faces)
                R, centre = self.wall
                points = centre + points @ R
            albedo = _sample(texture, points[:, 0] / per_texel + (width - 1) / 2.0,
                             points[:, 1] / per_texel + (height - 1) / 2.0, border=cv2.BORDER_REFLECT_101)
            out[wall] = albedo * np.float32(cfg.ambient + 0.7 * cfg.diffuse)
        return out

    def texture_coordinates(self, points_link: np.ndarray, faces: np.ndarray):
        """Texel coordinates and the covered flag of link-frame surface points on the given faces."""
        axial = points_link @ self.axis
        x1, x2 = points_link @ self.e1, points_link @ self.e2
        phi = np.arctan2(x2, x1)
        height, width = _texture_shape(self.config)
        texel = self.config.texel_mm / 1000.0
        cap = self.cap_face[faces]
        tx = np.where(cap, x1 / texel, (phi + np.pi) / (2 * np.pi) * width - 0.5)
        ty = np.where(cap, x2 / texel, (self.axial_range[1] - axial) / texel)  # rows run against the axis
        covered = np.mod(phi + np.pi, 2 * np.pi) < 2 * np.pi * self.config.covered_fraction
        return tx, ty, covered

    def moving_colors(self, points_link: np.ndarray, faces: np.ndarray, dirs_link: np.ndarray,
                      light_link: np.ndarray) -> np.ndarray:
        cfg = self.config
        n = len(faces)
        albedo = np.empty((n, 3), np.float32)
        albedo[:] = _bgr(cfg.hand_color)
        if cfg.covering != "plain" and n:
            tx, ty, covered = self.texture_coordinates(points_link, faces)
            if np.any(covered):
                texture = _hand_texture(cfg.covering, tuple(float(c) for c in cfg.hand_color), float(cfg.texel_mm),
                                        int(cfg.seed))
                albedo[covered] = _sample(texture, tx[covered], ty[covered])
        return _shade(albedo, self.moving.normals[faces], dirs_link, light_link, cfg)

    def light_in_link(self, spin: float) -> np.ndarray:
        return (self.link_rotation(spin).T @ (self.arm_R_link.T @ self.light_arm)).astype(np.float32)


# --------------------------------------------------------------------------------------------- renderability
def _renderability(geometry: _Geometry) -> str | None:
    """Why the scene cannot be rendered, or None."""
    cfg, camera = geometry.config, geometry.camera
    for name, low, high, centre in geometry.still_boxes:
        if np.all(centre > low) and np.all(centre < high):
            return f"the camera is inside the bounding box of the still mesh {name!r}"
    centre = geometry.link_t_cam
    axial = float(centre @ geometry.axis)
    radial = float(np.linalg.norm(centre - axial * geometry.axis))
    lo, hi = geometry.axial_range
    if lo <= axial <= hi and radial <= geometry.max_radius:
        return "the camera is inside the volume the spinning links sweep"
    swept = _swept_points(geometry)
    depth = swept @ geometry.link_R_cam[:, 2] - geometry.link_t_cam @ geometry.link_R_cam[:, 2]
    if np.min(depth) <= _NEAR:
        return (f"the spinning links reach behind the camera (or within {_NEAR * 100:g} cm of it): least depth "
                f"{np.min(depth):.3f} m")
    spins = np.linspace(0.0, 2.0 * np.pi, _CHECK_ANGLES, endpoint=False)
    points = geometry.hull_points.astype(float)
    step = max(1, len(points) // 4000)
    cam = geometry.link_to_camera(spins, points[::step]).reshape(-1, 3)
    inside = camera.in_image(camera.project(cam))
    if inside.mean() < cfg.min_in_image:
        return (f"only {inside.mean():.1%} of the spinning links' projected vertices lie inside the image over a "
                f"whole turn (min_in_image {cfg.min_in_image:.0%})")
    # occlusion by the still links: a coarse grid of the swept region
    pixels = _region_pixels(geometry, step=3)
    if len(pixels) == 0:
        return "the spinning links do not appear in the image"
    dirs = camera.rays(pixels)
    t_still, _, _ = geometry.cast_still(dirs)
    seen, drawn = 0, 0
    for spin in spins:
        t, face, _, _ = geometry.cast_moving(float(spin), dirs)
        hit = face >= 0
        drawn += int(hit.sum())
        seen += int((hit & (t < t_still)).sum())
    if drawn == 0:
        return "the spinning links do not appear in the image"
    if seen / drawn < cfg.min_visible_fraction:
        return (f"the still links hide {1 - seen / drawn:.0%} of the spinning links over the spin "
                f"(min_visible_fraction {cfg.min_visible_fraction:.0%})")
    return None


def _swept_points(geometry: _Geometry, samples: int = 128) -> np.ndarray:
    """Points (link frame) whose convex hull contains the solid the spinning links sweep about the spin axis."""
    phi = np.linspace(0.0, 2.0 * np.pi, samples, endpoint=False)
    radius = geometry.max_radius / np.cos(np.pi / samples) * 1.001 + 1e-4
    ring = radius * (np.cos(phi)[:, None] * geometry.e1 + np.sin(phi)[:, None] * geometry.e2)
    lo, hi = geometry.axial_range
    return np.vstack([ring + (lo - 1e-4) * geometry.axis, ring + (hi + 1e-4) * geometry.axis])


def _swept_polygon(geometry: _Geometry) -> np.ndarray:
    """Convex polygon (undistorted normalised image coordinates) containing the swept solid's projection."""
    swept = _swept_points(geometry)
    cam = (swept - geometry.link_t_cam) @ geometry.link_R_cam
    xy = (cam[:, :2] / cam[:, 2:3]).astype(np.float32)
    return cv2.convexHull(xy.reshape(-1, 1, 2)).reshape(-1, 2).astype(float)


def _inside_convex(polygon: np.ndarray, xy: np.ndarray) -> np.ndarray:
    """Points (N, 2) inside (or on) a convex polygon (V, 2), either orientation."""
    edges = np.roll(polygon, -1, axis=0) - polygon
    area = np.sum(polygon[:, 0] * np.roll(polygon[:, 1], -1) - np.roll(polygon[:, 0], -1) * polygon[:, 1])
    sign = 1.0 if area >= 0 else -1.0
    (x0, y0), (x1, y1) = polygon.min(axis=0), polygon.max(axis=0)
    rows = np.flatnonzero((xy[:, 0] >= x0) & (xy[:, 0] <= x1) & (xy[:, 1] >= y0) & (xy[:, 1] <= y1))
    x, y = xy[rows, 0], xy[rows, 1]
    keep = np.ones(len(rows), bool)
    for p, e in zip(polygon, edges, strict=True):
        keep &= sign * (e[0] * (y - p[1]) - e[1] * (x - p[0])) >= -1e-12
    inside = np.zeros(len(xy), bool)
    inside[rows[keep]] = True
    return inside


def _region_pixels(geometry: _Geometry, step: int = 1) -> np.ndarray:
    """Pixel centres (every ``step``-th) whose rays fall inside the swept polygon."""
    camera = geometry.camera
    ys, xs = np.mgrid[0:camera.height:step, 0:camera.width:step]
    pixels = np.column_stack([xs.ravel(), ys.ravel()]).astype(float)
    xy = camera.normalize(pixels)
    return pixels[_inside_convex(_swept_polygon(geometry), xy)]


def pose_problem(arm: Arm, camera: Camera, arm_T_camera, joint_angles, config: MeshRenderConfig | None = None, *,
                 meshes: ArmMeshes | None = None, package_dirs=None, spin_joint: str | None = None) -> str | None:
    """Why the mesh renderer cannot render the arm at ``joint_angles`` seen from ``arm_T_camera`` spinning
    ``spin_joint`` (default the wrist), or None when it can: the camera inside a mesh's bounding box or inside the
    spinning links' swept volume, the spinning links behind the camera, less than ``min_in_image`` of their
    projected vertices inside the image, or more than 1 - ``min_visible_fraction`` of their projected area hidden by
    still links (8 spin angles of a whole turn)."""
    config = MeshRenderConfig() if config is None else config
    meshes = load_arm_meshes(arm, package_dirs) if meshes is None else meshes
    return _renderability(_Geometry(arm, meshes, camera, arm_T_camera, joint_angles, config, spin_joint))

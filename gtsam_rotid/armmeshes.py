"""The arm's visual meshes (example-robot-data's or a URDF's, loaded by trimesh / pycollada), per link.
"""

from __future__ import annotations

import functools
import os
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from .arm import Arm
from .errors import ArmError, InputError


# --------------------------------------------------------------------------------------------- meshes
@dataclass(frozen=True, eq=False)
class ArmMeshes:
    """The arm's visual meshes, one entry per geometry object of the Pinocchio visual model.

    ``vertices[i]`` (V, 3) are in the frame of the parent joint ``joint_ids[i]`` (mesh scale and the
    geometry's placement applied), ``faces[i]`` (T, 3) int, ``colors[i]`` RGB in [0, 1].
    """

    names: tuple[str, ...]
    joint_ids: tuple[int, ...]
    vertices: tuple[np.ndarray, ...]
    faces: tuple[np.ndarray, ...]
    colors: tuple[np.ndarray, ...]

    def __len__(self) -> int:
        return len(self.names)


def _load_mesh_file(path: str, name: str):
    import trimesh  # imported here: only the mesh renderer needs it

    if not path or not os.path.isfile(path):
        raise ArmError(f"visual geometry {name!r}: mesh file {path!r} not found; pass package_dirs so that the "
                       f"URDF's mesh paths resolve")
    try:
        mesh = trimesh.load(path, force="mesh", process=False)
    except Exception as exc:  # trimesh raises many kinds
        raise ArmError(f"visual geometry {name!r}: trimesh cannot load {path!r} ({exc})") from None
    if not hasattr(mesh, "faces") or len(mesh.faces) == 0:
        raise ArmError(f"visual geometry {name!r}: {path!r} holds no triangles")
    return np.asarray(mesh.vertices, dtype=float), np.asarray(mesh.faces, dtype=np.int64)


def _meshes_from_geometry_model(model, visual_model) -> ArmMeshes:
    import pinocchio as pin

    names, joints, vertices, faces, colors = [], [], [], [], []
    for g in visual_model.geometryObjects:
        path = getattr(g, "meshPath", "")
        if not path:
            raise ArmError(f"visual geometry {g.name!r} is not a mesh (primitive shapes are not supported)")
        v, f = _load_mesh_file(path, g.name)
        v = v * np.asarray(g.meshScale, dtype=float)
        placement: pin.SE3 = g.placement
        v = v @ np.asarray(placement.rotation).T + np.asarray(placement.translation)
        color = np.asarray(getattr(g, "meshColor", (0.5, 0.5, 0.5, 1.0)), dtype=float)[:3]
        if not np.all(np.isfinite(color)) or np.all(color == 0):
            color = np.array([0.5, 0.5, 0.5])
        names.append(g.name)
        joints.append(int(g.parentJoint))
        vertices.append(v)
        faces.append(f)
        colors.append(np.clip(color, 0.0, 1.0))
    if not names:
        raise ArmError("the arm's visual model holds no geometry")
    for array in (*vertices, *faces):
        array.setflags(write=False)
    return ArmMeshes(tuple(names), tuple(joints), tuple(vertices), tuple(faces), tuple(colors))


@functools.lru_cache(maxsize=8)
def _robot_meshes(name: str) -> ArmMeshes:
    import example_robot_data as erd

    try:
        robot = erd.load(name)
    except Exception as exc:
        raise ArmError(f"example-robot-data cannot load {name!r} ({exc})") from None
    return _meshes_from_geometry_model(robot.model, robot.visual_model)


def load_arm_meshes(arm: Arm, package_dirs: Sequence[str | os.PathLike] | None = None) -> ArmMeshes:
    """The visual meshes of ``arm``: example-robot-data's for a named robot (cached), else the URDF's,
    resolved through ``package_dirs`` (``package://`` paths). Raises :class:`ArmError` when a mesh is missing."""
    if not isinstance(arm, Arm):
        raise InputError(f"arm must be a gtsam_rotid Arm, got {type(arm).__name__}")
    source = arm.to_dict()
    if "robot" in source:
        meshes = _robot_meshes(source["robot"])
    else:
        meshes = _meshes_from_geometry_model(arm.model, arm.urdf_geometry("visual", package_dirs))
    if max(meshes.joint_ids) >= arm.model.njoints:
        raise ArmError("the visual model does not belong to the arm's kinematic model")
    return meshes

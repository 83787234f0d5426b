"""The arm's collision geometry (Pinocchio + coal): self-collision, a floor or table plane, and the lines of sight
from a camera to the spinning links that the arm's other links block.

The collision meshes are example-robot-data's for a named robot, else the URDF's ``<collision>`` elements
(``package://`` paths resolved through ``package_dirs``). Pairs of geometries on the same joint or on a joint and
its parent are never tested (they touch by construction; the MoveIt setup assistant disables them too), nor are
pairs an SRDF of the robot disables when example-robot-data ships one.
"""

from __future__ import annotations

import functools
import os
from collections.abc import Sequence

import numpy as np

from .arm import Arm
from .errors import ArmError

#: Radius (m) of the line of sight from the camera to a feature: thinner blockers (cables) are ignored.
SIGHT_RADIUS = 0.002
#: The last part of a line of sight (m) that is not tested: a feature sits on the spinning link's surface, and
#: the link after it touches the still ones at the joint.
SIGHT_END_MARGIN = 0.01


@functools.lru_cache(maxsize=8)
def _robot_geometry(name: str):
    import example_robot_data as erd

    try:
        return erd.load(name).collision_model
    except Exception as exc:
        raise ArmError(f"example-robot-data cannot load {name!r}'s collision model ({exc})") from None


def _hull(geometry) -> np.ndarray | None:
    """The convex hull's vertices (V, 3) of a mesh geometry (its own frame), None for a primitive shape."""
    if not hasattr(geometry, "vertices"):
        return None
    import trimesh

    vertices = np.asarray(geometry.vertices(), dtype=float)
    try:
        return np.asarray(trimesh.convex.convex_hull(vertices).vertices, dtype=float)
    except Exception:  # degenerate (flat) meshes: all their vertices
        return vertices


class ArmCollisions:
    """Collision checks of one arm. Build it once (loading the meshes takes a moment) and reuse it.

    Args:
        arm: the arm.
        package_dirs: where a URDF's ``package://`` mesh paths resolve.
        floor_height: z (m, arm-base frame) of a floor or table plane that no link below the first joint's child
            may pass; None: no plane.
    """

    def __init__(self, arm: Arm, package_dirs: Sequence[str | os.PathLike] | None = None,
                 floor_height: float | None = 0.0):
        import coal
        import pinocchio as pin

        self.arm = arm
        source = arm.to_dict()
        if "robot" in source:
            full = _robot_geometry(source["robot"])
        else:
            full = arm.urdf_geometry("collision", package_dirs)
            full.addAllCollisionPairs()
        if full.ngeoms == 0:
            raise ArmError("the arm's URDF has no <collision> geometry to check collisions with")
        model = arm.model
        parents = model.parents
        self.model = pin.GeometryModel()
        for geometry in full.geometryObjects:
            if geometry.parentJoint >= model.njoints:
                raise ArmError("the collision model does not belong to the arm's kinematic model")
            self.model.addGeometryObject(geometry)
        for pair in full.collisionPairs:
            a = full.geometryObjects[pair.first].parentJoint
            b = full.geometryObjects[pair.second].parentJoint
            if a == b or parents[a] == b or parents[b] == a:
                continue
            self.model.addCollisionPair(pin.CollisionPair(pair.first, pair.second))
        self._data = pin.GeometryData(self.model)
        self._kinematics = model.createData()
        wrist = model.getJointId(arm.wrist_joint)
        self._moving = np.array([self._in_subtree(g.parentJoint, wrist) for g in self.model.geometryObjects])
        self.floor_height = floor_height
        self._floor = None if floor_height is None else coal.Halfspace(np.array([0.0, 0.0, 1.0]), float(floor_height))
        # links on the root or the first joint stand on the floor by design
        self._above_floor = np.array([g.parentJoint > 1 for g in self.model.geometryObjects])
        self._hulls = [_hull(g.geometry) for g in self.model.geometryObjects]

    def spinning_points(self, count: int = 40) -> np.ndarray:
        """Points (count, 3) on the convex hulls of the links that spin with the wrist, in the wrist joint's frame:
        where features can be. Deterministic (evenly spaced in hull-vertex order)."""
        import pinocchio as pin

        model = self.arm.model
        wrist = model.getJointId(self.arm.wrist_joint)
        points = []
        for g, geometry in enumerate(self.model.geometryObjects):
            hull = self._hulls[g]
            if not self._moving[g] or hull is None:
                continue
            # geometry frame -> its joint's frame -> the wrist joint's frame (joints between them at neutral)
            joint_T_geometry = geometry.placement
            wrist_T_joint = pin.SE3.Identity()
            joint = geometry.parentJoint
            while joint != wrist:
                wrist_T_joint = model.jointPlacements[joint] * wrist_T_joint
                joint = model.parents[joint]
            placement = wrist_T_joint * joint_T_geometry
            points.append(hull @ np.array(placement.rotation).T + np.array(placement.translation))
        if not points:
            raise ArmError("no collision mesh spins with the wrist: cannot tell where the end effector is")
        points = np.vstack(points)
        return points[np.linspace(0, len(points) - 1, min(count, len(points))).astype(int)]

    def _in_subtree(self, joint: int, root: int) -> bool:
        while joint > 0:
            if joint == root:
                return True
            joint = self.arm.model.parents[joint]
        return False

    def _place(self, joint_angles) -> list:
        import coal
        import pinocchio as pin

        q = self.arm.configuration(joint_angles)
        pin.updateGeometryPlacements(self.arm.model, self._kinematics, self.model, self._data, q)
        return [coal.Transform3s(np.array(m.rotation), np.array(m.translation)) for m in self._data.oMg]

    def self_collision(self, joint_angles) -> tuple[str, str] | None:
        """The names of two of the arm's links that collide at these joint angles, or None."""
        import pinocchio as pin

        q = self.arm.configuration(joint_angles)
        if not pin.computeCollisions(self.arm.model, self._kinematics, self.model, self._data, q, True):
            return None
        for pair, result in zip(self.model.collisionPairs, self._data.collisionResults, strict=False):
            if result.isCollision():
                return (self.model.geometryObjects[pair.first].name, self.model.geometryObjects[pair.second].name)
        return ("?", "?")  # pragma: no cover - computeCollisions said there was one

    def below_floor(self, joint_angles) -> str | None:
        """The name of a link (not the base's) that reaches below the floor plane, or None."""
        import coal

        if self._floor is None:
            return None
        placements = self._place(joint_angles)
        request, identity = coal.CollisionRequest(), coal.Transform3s()
        for g, geometry in enumerate(self.model.geometryObjects):
            if not self._above_floor[g]:
                continue
            hull = self._hulls[g]
            if hull is not None:  # a mesh: its lowest vertex (the halfspace test of a mesh is ~100x slower)
                low = np.min(hull @ placements[g].getRotation()[2]) + placements[g].getTranslation()[2]
                below = low < self.floor_height
            else:
                below = coal.collide(geometry.geometry, placements[g], self._floor, identity, request,
                                     coal.CollisionResult())
            if below:
                return geometry.name
        return None

    def hidden(self, joint_angles, camera_centre, points) -> np.ndarray:
        """Which of ``points`` (N, 3, arm frame; on the spinning links) the arm's still links hide from a camera at
        ``camera_centre``: (N,) bool."""
        import coal

        placements = self._place(joint_angles)
        centre = np.asarray(camera_centre, dtype=float)
        points = np.asarray(points, dtype=float).reshape(-1, 3)
        still = [g for g in range(self.model.ngeoms) if not self._moving[g]]
        request = coal.CollisionRequest()
        out = np.zeros(len(points), dtype=bool)
        for i, point in enumerate(points):
            ray = point - centre
            length = float(np.linalg.norm(ray)) - SIGHT_END_MARGIN
            if length <= 0:
                continue
            z = ray / np.linalg.norm(ray)
            x = np.cross(z, [1.0, 0.0, 0.0] if abs(z[0]) < 0.9 else [0.0, 1.0, 0.0])
            x /= np.linalg.norm(x)
            sight = coal.Capsule(SIGHT_RADIUS, length)
            pose = coal.Transform3s(np.column_stack([x, np.cross(z, x), z]), centre + 0.5 * length * z)
            for g in still:
                result = coal.CollisionResult()
                if coal.collide(self.model.geometryObjects[g].geometry, placements[g], sight, pose, request, result):
                    out[i] = True
                    break
        return out

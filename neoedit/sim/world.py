"""A PyBullet tabletop world: table + fixed robot arm + named objects, settled by physics.

World frame: z-up, metres, origin on the table top (the paper registers scans with ArUco
markers on the table; here registration is exact by construction).
"""

from __future__ import annotations

import functools
from pathlib import Path

import numpy as np
import pybullet_data
from scipy.spatial.transform import Rotation

from neoedit.errors import SpecError
from neoedit.geometry import OrientedBox, rot_z, yaw_of_rotation
from neoedit.geometry.transforms import apply_transform, make_transform
from neoedit.sim._pybullet import pb
from neoedit.sim.collision import concave_urdf, obj_parts
from neoedit.sim.markers import add_markers
from neoedit.sim.spec import ActionSpec, ObjectSpec, SceneSpec

BACKGROUND_ID = 0
TABLE_ID = 1
ROBOT_ID = 2
FIRST_OBJECT_ID = 3
PHYSICS_HZ = 240


def resolve_asset(ref: str, spec_dir: Path | None, objects_dir: Path | None) -> Path:
    """Turn an asset reference of a spec into a file path (see :class:`ObjectSpec`)."""
    if ref.startswith("pybullet_data:"):
        path = Path(pybullet_data.getDataPath()) / ref.removeprefix("pybullet_data:")
    elif ref.startswith("objects_dir:"):
        if objects_dir is None:
            raise SpecError(f"{ref!r} needs --objects-dir")
        path = Path(objects_dir) / ref.removeprefix("objects_dir:")
    else:
        path = Path(ref) if spec_dir is None or Path(ref).is_absolute() else Path(spec_dir) / ref
    if path.is_dir():
        path = path / "model.urdf"
    if not path.is_file():
        raise SpecError(f"asset not found: {ref!r} (looked for {path})")
    return path


@functools.lru_cache(maxsize=64)
def _obj_vertices(path: str) -> np.ndarray:
    return np.concatenate(obj_parts(path))


def _pose_matrix(client: int, pos: tuple, orn: tuple) -> np.ndarray:
    rot = np.asarray(pb.getMatrixFromQuaternion(orn, physicsClientId=client)).reshape(3, 3)
    return make_transform(rot, np.asarray(pos))


class SimWorld:
    """Owns one PyBullet client (DIRECT, no display). Use as a context manager."""

    def __init__(
        self, spec: SceneSpec, spec_dir: Path | None = None, objects_dir: Path | None = None
    ):
        self.spec = spec
        self.spec_dir, self.objects_dir = spec_dir, objects_dir
        self.client = pb.connect(pb.DIRECT)
        pb.setGravity(0, 0, -9.81, physicsClientId=self.client)
        pb.setTimeStep(1.0 / PHYSICS_HZ, physicsClientId=self.client)
        self.bodies: dict[str, int] = {}  # object name -> body id
        self.instance_ids: dict[str, int] = {}  # object name -> instance id in label images
        self._load_static()
        for k, obj in enumerate(spec.objects):
            self._load_object(obj, FIRST_OBJECT_ID + k)
        self.settle()
        self._check_on_table()  # the scene as placed (an action may knock one off later)

    # -- construction ------------------------------------------------------------------------
    def _load_static(self) -> None:
        setup = self.spec.setup
        table = resolve_asset(setup.table_urdf, self.spec_dir, self.objects_dir)
        self.table = pb.loadURDF(
            str(table), [0, 0, -setup.table_top_m], useFixedBase=True, physicsClientId=self.client
        )
        if setup.table_rgba is not None:
            pb.changeVisualShape(
                self.table, -1, rgbaColor=setup.table_rgba, physicsClientId=self.client
            )
        self.markers = add_markers(self.client, setup.markers)
        robot = resolve_asset(setup.robot_urdf, self.spec_dir, self.objects_dir)
        orn = pb.getQuaternionFromEuler([0, 0, np.deg2rad(setup.robot_yaw_deg)])
        self.robot = pb.loadURDF(
            str(robot),
            list(setup.robot_base_m),
            orn,
            useFixedBase=True,
            physicsClientId=self.client,
        )
        movable = [
            j
            for j in range(pb.getNumJoints(self.robot, physicsClientId=self.client))
            if pb.getJointInfo(self.robot, j, physicsClientId=self.client)[2] != pb.JOINT_FIXED
        ]
        for j, q in zip(movable, setup.robot_joints_rad, strict=False):
            pb.resetJointState(self.robot, j, q, physicsClientId=self.client)
            pb.setJointMotorControl2(
                self.robot,
                j,
                pb.POSITION_CONTROL,
                targetPosition=q,
                force=500,
                physicsClientId=self.client,
            )

    def _load_object(self, obj: ObjectSpec, instance_id: int) -> None:
        path = resolve_asset(obj.urdf, self.spec_dir, self.objects_dir)
        if obj.concave:
            path = concave_urdf(path)
        rot = rot_z(obj.yaw_deg) @ _euler_deg_to_matrix(obj.rpy_deg)
        orn = _matrix_to_quaternion(rot)
        body = pb.loadURDF(
            str(path), [0, 0, 1.0], orn, globalScaling=obj.scale, physicsClientId=self.client
        )
        if obj.rgba is not None:
            for vs in pb.getVisualShapeData(body, physicsClientId=self.client):
                pb.changeVisualShape(body, vs[1], rgbaColor=obj.rgba, physicsClientId=self.client)
        # Drop from just above the table: the lowest point starts position_m[2] above z = 0.
        lo = self.object_vertices_world_for(body).min(0)
        pos, _ = pb.getBasePositionAndOrientation(body, physicsClientId=self.client)
        x, y, drop = obj.position_m
        new_pos = [pos[0] + x, pos[1] + y, pos[2] - lo[2] + max(drop, 0.002)]
        pb.resetBasePositionAndOrientation(body, new_pos, orn, physicsClientId=self.client)
        pb.changeDynamics(
            body,
            -1,
            lateralFriction=0.9,
            rollingFriction=0.002,
            spinningFriction=0.002,
            physicsClientId=self.client,
        )
        self.bodies[obj.name] = body
        self.instance_ids[obj.name] = instance_id

    def settle(self, seconds: float | None = None) -> None:
        """Step physics until objects rest (or the time budget ``settle_s`` is used)."""
        steps = int((self.spec.settle_s if seconds is None else seconds) * PHYSICS_HZ)
        for i in range(steps):
            pb.stepSimulation(physicsClientId=self.client)
            if i > PHYSICS_HZ // 4 and i % 24 == 0 and self._at_rest():
                break

    def _check_on_table(self, below_m: float = 0.05) -> None:
        """Every object placed by the spec rests on the table: one placed beyond its edge
        falls out of every view, and a scan of it would edit nothing anyone can see."""
        for name, body in self.bodies.items():
            low = float(self.object_vertices_world_for(body)[:, 2].min())
            if low < -below_m:
                raise SpecError(
                    f"object {name!r} fell off the table (it came to rest {-low:.2f} m below "
                    "the table top): place it on the table (its position_m x, y)"
                )

    def _at_rest(self, tol: float = 1e-3) -> bool:
        for body in self.bodies.values():
            lin, ang = pb.getBaseVelocity(body, physicsClientId=self.client)
            if np.linalg.norm(lin) > tol or np.linalg.norm(ang) > 10 * tol:
                return False
        return True

    # -- queries -----------------------------------------------------------------------------
    def object_pose(self, name: str) -> np.ndarray:
        """(4,4) world pose of the object's URDF link frame."""
        return self._link_pose(self.bodies[name])

    def _link_pose(self, body: int) -> np.ndarray:
        """(4,4) world pose of a body's base URDF link frame (PyBullet reports the
        centre-of-mass frame; undo the link's inertial offset)."""
        com = _pose_matrix(
            self.client, *pb.getBasePositionAndOrientation(body, physicsClientId=self.client)
        )
        info = pb.getDynamicsInfo(body, -1, physicsClientId=self.client)
        return com @ np.linalg.inv(_pose_matrix(self.client, info[3], info[4]))

    def object_vertices_world_for(self, body: int) -> np.ndarray:
        """(N,3) world points on the visual geometry of a body's base link."""
        link = self._link_pose(body)
        points = []
        for vs in pb.getVisualShapeData(body, physicsClientId=self.client):
            geom, dims, mesh_file = vs[2], np.asarray(vs[3]), vs[4].decode()
            if geom == pb.GEOM_MESH and mesh_file.endswith(".obj"):
                local = _obj_vertices(mesh_file) * dims
            elif geom == pb.GEOM_BOX:
                local = (
                    np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)])
                    * dims
                    / 2
                )
            elif geom == pb.GEOM_SPHERE:
                d = np.random.default_rng(0).normal(size=(512, 3))
                local = d / np.linalg.norm(d, axis=1, keepdims=True) * dims[0]
            else:
                raise SpecError(f"unsupported visual geometry type {geom} ({mesh_file}) for boxes")
            visual = _pose_matrix(self.client, vs[5], vs[6])
            points.append(apply_transform(link @ visual, local))
        return np.concatenate(points)

    def collision_parts_world(self, name: str) -> list[np.ndarray]:
        """(N,3) world vertices of each convex part the physics collides with (a mesh's
        convex hull, or each part of a ``concave`` object's decomposition)."""
        body = self.bodies[name]
        com = _pose_matrix(
            self.client, *pb.getBasePositionAndOrientation(body, physicsClientId=self.client)
        )
        parts = []
        for cs in pb.getCollisionShapeData(body, -1, physicsClientId=self.client):
            geom, dims, mesh_file = cs[2], np.asarray(cs[3]), cs[4].decode()
            if geom != pb.GEOM_MESH:  # a primitive: its visual vertices bound it
                parts.append(self.object_vertices_world_for(body))
                continue
            if not mesh_file.endswith(".obj"):
                raise SpecError(f"{name}: collision mesh {mesh_file} is not an .obj file")
            local = _pose_matrix(self.client, cs[5], cs[6])
            parts += [apply_transform(com @ local, p * dims) for p in obj_parts(mesh_file)]
        return parts

    def object_box(self, name: str) -> OrientedBox:
        """Box of the object's visual geometry, aligned with the object's own heading.

        The yaw follows the object (its rotation relative to its upright base orientation
        ``rpy_deg``), so the box moves rigidly with the object; a tilted object still gets
        a box that holds all of it.
        """
        spec = next(o for o in self.spec.objects if o.name == name)
        relative = self.object_pose(name)[:3, :3] @ _euler_deg_to_matrix(spec.rpy_deg).T
        return OrientedBox.fit_with_yaw(
            self.object_vertices_world_for(self.bodies[name]), yaw_of_rotation(relative)
        )

    def aabb_m(self) -> np.ndarray:
        """(2,3) bounds of everything in the world (table, robot, objects)."""
        boxes = []
        for body in [self.table, self.robot, *self.bodies.values()]:
            for link in range(-1, pb.getNumJoints(body, physicsClientId=self.client)):
                boxes.append(np.asarray(pb.getAABB(body, link, physicsClientId=self.client)))
        b = np.stack(boxes)
        return np.stack([b[:, 0].min(0), b[:, 1].max(0)])

    # -- actions -----------------------------------------------------------------------------
    def remove(self, name: str) -> None:
        pb.removeBody(self.bodies.pop(name), physicsClientId=self.client)
        self.instance_ids.pop(name)
        self.settle()

    def move(
        self, name: str, translate_m: tuple[float, float, float], yaw_deg: float
    ) -> np.ndarray:
        """Move an object (rotate about the vertical through its box centre, then translate),
        let it settle, and return the realised (4,4) world transform T (new pose = T @ old)."""
        body = self.bodies[name]
        before = self.object_pose(name)
        centre = np.asarray(self.object_box(name).center_m)
        motion = make_transform(
            rot_z(yaw_deg), centre + np.asarray(translate_m) - rot_z(yaw_deg) @ centre
        )
        motion[2, 3] += (
            0.003  # release just above the support so it does not start interpenetrating
        )
        com = _pose_matrix(
            self.client, *pb.getBasePositionAndOrientation(body, physicsClientId=self.client)
        )
        target = motion @ com
        pb.resetBasePositionAndOrientation(
            body,
            target[:3, 3].tolist(),
            _matrix_to_quaternion(target[:3, :3]),
            physicsClientId=self.client,
        )
        pb.resetBaseVelocity(body, [0, 0, 0], [0, 0, 0], physicsClientId=self.client)
        self.settle()
        return self.object_pose(name) @ np.linalg.inv(before)

    def apply(self, action: ActionSpec) -> np.ndarray | None:
        """Perform one scene action (remove, or move by its translation and yaw); the realised
        world transform of a move, None for a removal."""
        if action.type == "remove":
            self.remove(action.object)
            return None
        return self.move(action.object, action.translate_m, action.yaw_deg)

    def close(self) -> None:
        if pb.isConnected(self.client):
            pb.disconnect(self.client)

    def __enter__(self) -> SimWorld:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def _euler_deg_to_matrix(rpy_deg: tuple[float, float, float]) -> np.ndarray:
    """Roll-pitch-yaw in degrees (extrinsic x, y, z as in PyBullet) -> (3,3)."""
    return Rotation.from_euler("xyz", rpy_deg, degrees=True).as_matrix()


def _matrix_to_quaternion(rot: np.ndarray) -> list[float]:
    """(3,3) rotation -> PyBullet quaternion (x, y, z, w)."""
    return Rotation.from_matrix(rot).as_quat().tolist()

"""A simulated Panda that executes a pick-and-place: reach a planned grasp along its
approach, close, lift, carry the object by a world transform, place, release, retreat.

Every stage reports why it failed (unreachable pose, collision on the approach, object not
held or slipped), so a prediction can be checked against what a robot really does. The
KUKA setup is not supported: pybullet_data's iiwa model has no gripper.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pybullet as pb

from neoedit.errors import NeoError
from neoedit.grasp.gripper import GripperConfig, opening
from neoedit.sim.spec import ActionSpec, SceneSpec
from neoedit.sim.world import PHYSICS_HZ, SimWorld

EE_LINK = "panda_grasptarget"


@dataclass
class ExecuteConfig:
    pregrasp_m: float = 0.10
    """The hand starts this far back along the approach."""
    lift_m: float = 0.10
    """Lift height after closing (and while carrying)."""
    ee_offset_m: float = 0.008
    """The hand's grasp target sits this far beyond the grasp centre along the approach
    (the planner's centre is short of the fingertips)."""
    segment_s: float = 1.0
    """Duration of each straight motion."""
    hold_s: float = 1.0
    """Hold after lifting (the success check), then a short shake."""
    grip_force_n: float = 60.0
    reach_tolerance_m: float = 0.015
    """An arm that ends farther than this from a waypoint could not reach it."""
    coupled_fingers: bool = True
    """The fingers move as one, mirrored about the hand's axis, as the Franka Hand's do (a
    gear constraint); off: each finger is driven on its own, so the first to touch pushes
    the object until the other meets it."""


@dataclass
class Execution:
    success: bool
    stage: str
    """The last stage reached: reach, approach, close, lift, carry, place, retreat, done."""
    cause: str = ""
    transform: np.ndarray | None = None
    """Realised world transform of the object (new pose = T @ old), when it was placed."""
    log: list[str] = field(default_factory=list)

    def to_dict(self) -> dict[str, Any]:
        t = None if self.transform is None else np.round(self.transform, 6).tolist()
        return {"success": self.success, "stage": self.stage, "cause": self.cause, "transform": t}


class PandaArm:
    """The Panda of a :class:`SimWorld` driven by position control and inverse kinematics."""

    def __init__(self, world: SimWorld, cfg: ExecuteConfig):
        self.world, self.cfg, self.c, self.robot = world, cfg, world.client, world.robot
        names = {
            pb.getJointInfo(self.robot, j, physicsClientId=self.c)[12].decode(): j
            for j in range(pb.getNumJoints(self.robot, physicsClientId=self.c))
        }
        if EE_LINK not in names:
            raise NeoError(
                "the scene's robot has no parallel gripper (pybullet_data's KUKA iiwa model has "
                "none): execution needs the Panda setup"
            )
        self.ee = names[EE_LINK]
        self.fingers = [names["panda_leftfinger"], names["panda_rightfinger"]]
        movable = [
            j
            for j in range(pb.getNumJoints(self.robot, physicsClientId=self.c))
            if pb.getJointInfo(self.robot, j, physicsClientId=self.c)[2] != pb.JOINT_FIXED
        ]
        self.arm = [j for j in movable if j not in self.fingers]
        info = [pb.getJointInfo(self.robot, j, physicsClientId=self.c) for j in self.arm]
        self.limits = np.array([(i[8], i[9]) for i in info])
        self.home = self.joints()
        for f in self.fingers:
            pb.changeDynamics(self.robot, f, lateralFriction=1.2, physicsClientId=self.c)

    def couple_fingers(self) -> int:
        """Mirror the fingers with a gear constraint; returns its id (remove it when done)."""
        gear = pb.createConstraint(
            self.robot, self.fingers[0], self.robot, self.fingers[1], pb.JOINT_GEAR,
            [1, 0, 0], [0, 0, 0], [0, 0, 0], physicsClientId=self.c,
        )  # fmt: skip
        pb.changeConstraint(gear, gearRatio=-1, erp=0.1, maxForce=50, physicsClientId=self.c)
        return gear

    def joints(self) -> np.ndarray:
        states = pb.getJointStates(self.robot, self.arm, physicsClientId=self.c)
        return np.array([s[0] for s in states])

    def ee_pose(self) -> tuple[np.ndarray, np.ndarray]:
        s = pb.getLinkState(
            self.robot, self.ee, computeForwardKinematics=True, physicsClientId=self.c
        )
        return np.array(s[4]), np.array(pb.getMatrixFromQuaternion(s[5])).reshape(3, 3)

    def ik(self, pos: np.ndarray, rot: np.ndarray) -> np.ndarray:
        """Joint angles that put the hand at a pose (from the current joints), within the
        joints' limits."""
        from neoedit.sim.world import _matrix_to_quaternion

        q = pb.calculateInverseKinematics(
            self.robot, self.ee, pos.tolist(), _matrix_to_quaternion(rot),
            maxNumIterations=300, residualThreshold=1e-5, physicsClientId=self.c,
        )  # fmt: skip
        return np.clip(np.asarray(q[: len(self.arm)]), self.limits[:, 0], self.limits[:, 1])

    def solve(self, pos: np.ndarray, rot: np.ndarray, passes: int = 3) -> np.ndarray:
        """Joint angles for a hand pose: inverse kinematics from the current joints, refined
        ``passes - 1`` times from its own (limit-clipped) solution, the refinement
        :func:`reach_error` uses too. The arm is put back where it was, velocities included,
        so a motion can solve its next waypoint without losing its state. (The check still
        starts each stage from the last exact solution, a motion from the arm's real joints,
        which lag under load, and through extra points every 4 cm: it stays a little
        optimistic.)"""
        states = pb.getJointStates(self.robot, self.arm, physicsClientId=self.c)
        q = self.ik(pos, rot)
        try:
            for _ in range(passes - 1):
                self.set_joints(q)
                q = self.ik(pos, rot)
        finally:
            for j, st in zip(self.arm, states, strict=True):
                pb.resetJointState(self.robot, j, st[0], st[1], physicsClientId=self.c)
        return q

    def set_joints(self, q: np.ndarray) -> None:
        """Put the arm at ``q`` at once (no motion, no physics step)."""
        for j, qj in zip(self.arm, q, strict=True):
            pb.resetJointState(self.robot, j, qj, physicsClientId=self.c)

    def fingers_to(self, opening_m: float, force: float = 40.0) -> None:
        for f in self.fingers:
            pb.setJointMotorControl2(
                self.robot, f, pb.POSITION_CONTROL, targetPosition=opening_m / 2,
                force=force, physicsClientId=self.c,
            )  # fmt: skip

    def move_to(self, pos: np.ndarray, rot: np.ndarray, seconds: float) -> tuple[float, list[int]]:
        """Drive the hand to a pose through waypoints (every 4 cm / 15 degrees, inverse
        kinematics from the last solution); (final position error, bodies other than the
        robot touched on the way)."""
        from scipy.spatial.transform import Rotation, Slerp

        p0, r0 = self.ee_pose()
        turn = float(
            np.degrees((Rotation.from_matrix(r0).inv() * Rotation.from_matrix(rot)).magnitude())
        )
        n = int(max(1, np.ceil(np.linalg.norm(pos - p0) / 0.04), np.ceil(turn / 15.0)))
        slerp = Slerp([0.0, 1.0], Rotation.from_matrix(np.stack([r0, rot])))
        touched: set[int] = set()
        for k in range(1, n + 1):
            f = k / n
            touched |= self._drive(
                p0 + f * (pos - p0), slerp(f).as_matrix(), max(seconds / n, 0.25)
            )
        for _ in range(int(0.3 * PHYSICS_HZ)):  # let position control settle on the goal
            pb.stepSimulation(physicsClientId=self.c)
        return float(np.linalg.norm(self.ee_pose()[0] - pos)), sorted(touched)

    def _drive(self, pos: np.ndarray, rot: np.ndarray, seconds: float) -> set[int]:
        start, goal = self.joints(), self.solve(pos, rot)
        steps = max(1, int(seconds * PHYSICS_HZ))
        touched: set[int] = set()
        for k in range(1, steps + 1):
            q = start + (goal - start) * min(1.0, k / (0.8 * steps))
            pb.setJointMotorControlArray(
                self.robot, self.arm, pb.POSITION_CONTROL, targetPositions=q.tolist(),
                forces=[200.0] * len(self.arm), physicsClientId=self.c,
            )  # fmt: skip
            pb.stepSimulation(physicsClientId=self.c)
            for cp in pb.getContactPoints(bodyA=self.robot, physicsClientId=self.c):
                touched.add(cp[2])
        return touched

    def holds(self, body: int) -> bool:
        """Both fingers touch ``body``."""
        return all(
            pb.getContactPoints(self.robot, body, linkIndexA=f, physicsClientId=self.c)
            for f in self.fingers
        )

    def reset_home(self) -> None:
        self.set_joints(self.home)
        pb.setJointMotorControlArray(
            self.robot, self.arm, pb.POSITION_CONTROL, targetPositions=self.home.tolist(),
            physicsClientId=self.c,
        )  # fmt: skip
        self.fingers_to(0.04)


def check_grasp(grasp: dict[str, Any]) -> None:
    """A clear error for a grasp that is not a position and a 3x3 rotation."""
    try:
        pos = np.asarray(grasp["position_m"], dtype=np.float64)
        rot = np.asarray(grasp["rotation"], dtype=np.float64)
    except (KeyError, TypeError, ValueError):
        raise NeoError("a grasp needs position_m (3 numbers) and rotation (3x3)") from None
    if pos.shape != (3,) or not np.isfinite(pos).all():
        raise NeoError("the grasp's position_m must be 3 finite numbers")
    if rot.shape != (3, 3) or not np.allclose(rot.T @ rot, np.eye(3), atol=1e-3):
        raise NeoError("the grasp's rotation must be a 3x3 orthonormal matrix")
    widest = GripperConfig().max_width_m
    for key in ("width_m", "opening_m"):
        if key in grasp and not (isinstance(grasp[key], int | float) and 0 < grasp[key] <= widest):
            raise NeoError(f"the grasp's {key} must be a number in (0, {widest}] m")


def hand_pose(grasp: dict[str, Any], cfg: ExecuteConfig) -> tuple[np.ndarray, np.ndarray]:
    """(position, rotation) of the Panda grasp target for a planned grasp (columns of the
    grasp rotation: closing, finger, approach axes; the hand's y is its closing axis)."""
    rot = np.asarray(grasp["rotation"], dtype=np.float64)
    closing, approach = rot[:, 0], rot[:, 2]
    hand = np.stack([np.cross(closing, approach), closing, approach], -1)
    return np.asarray(grasp["position_m"], dtype=np.float64) + cfg.ee_offset_m * approach, hand


def _hand_for(
    arm: PandaArm, grasp: dict[str, Any], cfg: ExecuteConfig
) -> tuple[np.ndarray, np.ndarray]:
    """The hand pose for ``grasp``, turned half a turn about its approach when that needs
    less wrist turn from where the hand is (two symmetric fingers: the same grasp)."""
    pos, rot = hand_pose(grasp, cfg)
    flip = np.diag([-1.0, -1.0, 1.0])
    now = arm.ee_pose()[1]
    if np.trace(now.T @ (rot @ flip)) > np.trace(now.T @ rot):
        rot = rot @ flip
    return pos, rot


def _waypoints(
    pos: np.ndarray, rot: np.ndarray, transform: np.ndarray, cfg: ExecuteConfig
) -> list[tuple[str, np.ndarray, np.ndarray]]:
    """(stage, position, rotation) of the hand at the end of every motion of a pick-and-place."""
    up = np.array([0.0, 0.0, cfg.lift_m])
    goal_pos = transform[:3, :3] @ pos + transform[:3, 3]
    goal_rot = transform[:3, :3] @ rot
    return [
        ("reach", pos - cfg.pregrasp_m * rot[:, 2], rot),
        ("approach", pos, rot),
        ("lift", pos + up, rot),
        ("carry", goal_pos + up, goal_rot),
        ("place", goal_pos + np.array([0.0, 0.0, 0.004]), goal_rot),
        ("retreat", goal_pos - cfg.pregrasp_m * goal_rot[:, 2], goal_rot),
    ]


def reach_error(
    world: SimWorld, grasp: dict[str, Any], transform: np.ndarray, cfg: ExecuteConfig
) -> tuple[float, str]:
    """Kinematic check, before any motion: the largest distance between a waypoint of the
    pick-and-place and where inverse kinematics (chained from the arm's joints, as the motion goes)
    puts the hand, and the stage where it is largest. No physics step is taken and the arm
    is put back where it was."""
    check_grasp(grasp)
    arm = PandaArm(world, cfg)
    pos, rot = _hand_for(arm, grasp, cfg)
    worst, where = 0.0, ""
    try:
        for stage, p, r in _waypoints(pos, rot, transform, cfg):
            arm.set_joints(arm.solve(p, r))  # refined as the motion's waypoints are
            err = float(np.linalg.norm(arm.ee_pose()[0] - p))
            if not err <= worst:  # a NaN counts as the worst
                worst, where = err, stage
    finally:
        arm.set_joints(arm.home)
    return worst, where


def execute_move(
    world: SimWorld, name: str, grasp: dict[str, Any], transform: np.ndarray, cfg: ExecuteConfig
) -> Execution:
    """Pick ``name`` with ``grasp``, carry it by the world ``transform`` and place it."""
    arm = PandaArm(world, cfg)
    gear = arm.couple_fingers() if cfg.coupled_fingers else None
    try:
        return _pick_and_place(world, arm, name, grasp, transform, cfg)
    finally:
        if gear is not None:
            pb.removeConstraint(gear, physicsClientId=world.client)


def _pick_and_place(
    world: SimWorld,
    arm: PandaArm,
    name: str,
    grasp: dict[str, Any],
    transform: np.ndarray,
    cfg: ExecuteConfig,
) -> Execution:
    body = world.bodies[name]
    others = {world.table} | {b for n, b in world.bodies.items() if n != name}
    before = world.object_pose(name)
    pos, rot = _hand_for(arm, grasp, cfg)
    # the hand moves rigidly with the object while carrying, by the same world transform
    way = {stage: (p, r) for stage, p, r in _waypoints(pos, rot, transform, cfg)}
    ex = Execution(False, "reach")

    def step(stage: str, avoid: set[int]) -> bool:
        ex.stage = stage
        err, touched = arm.move_to(*way[stage], cfg.segment_s)
        if err > cfg.reach_tolerance_m:
            # stopped short against something (the object held is touched on purpose), or
            # out of the arm's reach
            against = set(touched) - ({body} if stage in ("lift", "carry", "place") else set())
            ex.cause = (
                f"{stage}: the hand stopped {err * 100:.1f} cm short of the pose, against "
                f"{_names(world, against)}"
                if against
                else f"{stage}: the arm cannot reach the pose ({err * 100:.1f} cm off)"
            )
            return False
        hit = avoid.intersection(touched)
        if hit:
            ex.cause = f"{stage}: collision with {_names(world, hit)}"
            return False
        return True

    # as wide as the planner checked (a grasp written without it: the planner's default)
    width = float(grasp.get("width_m", 0.06))
    arm.fingers_to(float(grasp.get("opening_m", opening(GripperConfig(), width))))
    if not step("reach", others | {body}) or not step("approach", others):
        return ex
    ex.stage = "close"
    arm.fingers_to(0.0, cfg.grip_force_n)
    _wait(world, 0.5)
    if not arm.holds(body):
        ex.cause = "close: the fingers do not both touch the object"
        return ex
    if not step("lift", set()):
        return ex
    _wait(world, cfg.hold_s)
    lifted = world.object_pose(name)[2, 3] - before[2, 3]
    if not arm.holds(body) or lifted < 0.5 * cfg.lift_m:
        ex.cause = f"lift: the object slipped (raised {lifted * 100:.1f} cm)"
        return ex
    if not step("carry", set()) or not step("place", set()):
        return ex
    ex.stage = "release"
    arm.fingers_to(0.08)
    _wait(world, 0.4)
    placed = world.object_pose(name)
    if not step("retreat", set()):
        return ex
    dragged = float(np.linalg.norm(world.object_pose(name)[:3, 3] - placed[:3, 3]))
    if dragged > 0.01:
        ex.cause = f"retreat: the hand dragged the object {dragged * 100:.1f} cm"
        return ex
    arm.reset_home()
    world.settle()
    ex.success, ex.stage = True, "done"
    ex.transform = world.object_pose(name) @ np.linalg.inv(before)
    return ex


def _wait(world: SimWorld, seconds: float) -> None:
    for _ in range(int(seconds * PHYSICS_HZ)):
        pb.stepSimulation(physicsClientId=world.client)


def _names(world: SimWorld, bodies: set[int]) -> str:
    names = {b: n for n, b in world.bodies.items()} | {world.table: "the table"}
    return ", ".join(names.get(b, f"body {b}") for b in sorted(bodies))


def _scene_action(scene_dir: Path, action: int) -> tuple[SceneSpec, ActionSpec, np.ndarray]:
    """(spec, the move, its world transform) of action ``action`` (1-based) of a NEO-Sim
    scene folder; a clear error for anything else."""
    from neoedit.sim.spec import scene_spec_from_dict

    try:
        meta = json.loads((Path(scene_dir) / "scene.json").read_text())
        spec = scene_spec_from_dict(meta["spec"], source=str(scene_dir))
    except (OSError, ValueError, KeyError) as e:
        raise NeoError(f"{scene_dir} is not a NEO-Sim scene folder: {e}") from None
    if not 1 <= action <= len(spec.actions):
        raise NeoError(f"--action must be in 1..{len(spec.actions)} for {scene_dir}")
    todo = spec.actions[action - 1]
    if todo.type != "move":
        raise NeoError(f"action {action} is a {todo.type}, not a move")
    try:
        transform = np.asarray(meta["actions"][action - 1]["transform_world"], dtype=np.float64)
    except (KeyError, IndexError, TypeError, ValueError):
        raise NeoError(
            f"{scene_dir}/scene.json has no transform_world for action {action}"
        ) from None
    return spec, todo, transform


def reachable_first(
    scene_dir: Path, action: int, grasps: list[dict[str, Any]], cfg: ExecuteConfig
) -> list[tuple[int, float, str]]:
    """The grasps as (index, reach error [m], worst stage), those whose every waypoint the
    arm reaches within ``cfg.reach_tolerance_m`` first (:func:`reach_error`; the planner's
    order is kept within each group). The planner knows the scene, not the robot: this is
    where the robot's reach comes in."""
    spec, _, transform = _scene_action(scene_dir, action)
    for g in grasps:
        check_grasp(g)
    with SimWorld(spec) as world:
        for a in spec.actions[: action - 1]:
            world.apply(a)
        errors = [(i, *reach_error(world, g, transform, cfg)) for i, g in enumerate(grasps)]
    return sorted(errors, key=lambda e: (not e[1] <= cfg.reach_tolerance_m, e[0]))


def execute_action(
    scene_dir: Path,
    action: int,
    grasp: dict[str, Any],
    out: Path,
    cfg: ExecuteConfig,
    overwrite: bool = False,
) -> Execution:
    """Rebuild the NEO-Sim scene at ``scene_dir``, replay its actions before ``action``
    (1-based), execute that move with ``grasp``, and scan the outcome into ``out`` with the
    cameras of the scene's scans (``out/scan``, ``out/execution.json``)."""
    from neoedit.sim.capture import capture_scan
    from neoedit.utils.io import atomic_directory, atomic_write_json

    spec, todo, transform = _scene_action(scene_dir, action)
    check_grasp(grasp)
    with (
        atomic_directory(Path(out), overwrite=overwrite, kind="execution") as tmp,
        SimWorld(spec) as world,
    ):
        for a in spec.actions[: action - 1]:  # the state before the action, as simulated
            world.apply(a)
        ex = execute_move(world, todo.object, grasp, transform, cfg)
        if ex.success:
            capture_scan(world, spec.scan, tmp / "scan", label="executed")
        record = {**ex.to_dict(), "object": todo.object, "intended": transform.tolist()}
        if ex.transform is not None:
            record["placement_error"] = placement_error(ex.transform, transform, world, todo.object)
        atomic_write_json(tmp / "execution.json", record)
    return ex


def placement_error(
    realised: np.ndarray, intended: np.ndarray, world: SimWorld, name: str
) -> dict[str, float]:
    """Position (of the object's box centre) and yaw errors of a placement [m, degrees]."""
    centre = np.append(world.object_box(name).center_m, 1.0)
    before = np.linalg.inv(realised) @ centre
    err = np.linalg.norm((intended @ before)[:3] - centre[:3])
    delta = intended[:3, :3].T @ realised[:3, :3]
    yaw = abs(float(np.degrees(np.arctan2(delta[1, 0], delta[0, 0]))))
    return {"position_m": round(float(err), 5), "yaw_deg": round(yaw, 2)}

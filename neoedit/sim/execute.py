"""A simulated Panda that executes a pick-and-place: reach a planned grasp along its
approach, close, lift, carry the object by a world transform, place, release, retreat.

Every stage reports why it failed (unreachable pose, collision on the approach, object not
held or slipped), so a prediction can be checked against what a robot really does. The
KUKA setup is not supported: pybullet_data's iiwa model has no gripper.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np

from neoedit.errors import NeoError
from neoedit.grasp.gripper import GripperConfig, opening
from neoedit.sim._pybullet import pb
from neoedit.sim.arm import ExecuteConfig, Motion, PandaArm
from neoedit.sim.spec import ActionSpec, SceneSpec
from neoedit.sim.world import PHYSICS_HZ, SimWorld
from neoedit.utils.userfile import read_data_file

__all__ = ["ExecuteConfig", "Execution", "PandaArm", "execute_action", "execute_move"]


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
    run = _Run(world, arm, name, cfg, Execution(False, "reach"))
    before = world.object_pose(name)
    pos, rot = _hand_for(arm, grasp, cfg)
    # the hand moves rigidly with the object while carrying, by the same world transform
    way = {stage: (p, r) for stage, p, r in _waypoints(pos, rot, transform, cfg)}
    # as wide as the planner checked (a grasp written without it: the planner's default)
    width = float(grasp.get("width_m", 0.06))
    arm.fingers_to(float(grasp.get("opening_m", opening(GripperConfig(), width))))
    if not run.step("reach", way, run.others | {run.body}) or not run.step(
        "approach", way, run.others
    ):
        return run.ex
    if not run.close() or not run.step("lift", way) or not run.hold_and_shake(way, before):
        return run.ex
    if not run.step("carry", way) or not run.place(way):
        return run.ex
    run.ex.stage = "release"
    arm.fingers_to(0.08)
    _wait(world, 0.4)
    placed = world.object_pose(name)
    if not run.step("retreat", way):
        return run.ex
    dragged = float(np.linalg.norm(world.object_pose(name)[:3, 3] - placed[:3, 3]))
    if dragged > 0.01:
        run.ex.cause = f"retreat: the hand dragged the object {dragged * 100:.1f} cm"
        return run.ex
    arm.reset_home()
    world.settle()
    run.ex.success, run.ex.stage = True, "done"
    run.ex.transform = world.object_pose(name) @ np.linalg.inv(before)
    return run.ex


Waypoints = dict[str, tuple[np.ndarray, np.ndarray]]


class _Run:
    """The stages of one pick-and-place; each returns False with ``ex.cause`` set when the
    stage fails."""

    def __init__(
        self, world: SimWorld, arm: PandaArm, name: str, cfg: ExecuteConfig, ex: Execution
    ):
        self.world, self.arm, self.cfg, self.ex, self.name = world, arm, cfg, ex, name
        self.body = world.bodies[name]
        self.others = {world.table} | {b for n, b in world.bodies.items() if n != name}

    def step(
        self, stage: str, way: Waypoints, avoid: frozenset[int] | set[int] = frozenset()
    ) -> bool:
        """Move the hand to the stage's pose; touching a body in ``avoid`` fails."""
        self.ex.stage = stage
        return self._check(stage, self.arm.move_to(*way[stage], self.cfg.segment_s), avoid)

    def _check(self, stage: str, motion: Motion, avoid: frozenset[int] | set[int]) -> bool:
        err, touched = motion.error_m, set(motion.touched)
        if err > self.cfg.reach_tolerance_m:
            # stopped short against something (the object held is touched on purpose), or
            # out of the arm's reach
            against = touched - ({self.body} if stage in ("lift", "carry", "place") else set())
            self.ex.cause = (
                f"{stage}: the hand stopped {err * 100:.1f} cm short of the pose, against "
                f"{_names(self.world, against)}"
                if against
                else f"{stage}: the arm cannot reach the pose ({err * 100:.1f} cm off)"
            )
            return False
        hit = set(avoid) & touched
        if hit:
            self.ex.cause = f"{stage}: collision with {_names(self.world, hit)}"
            return False
        return True

    def close(self) -> bool:
        self.ex.stage = "close"
        self.arm.fingers_to(0.0, self.cfg.grip_force_n)
        _wait(self.world, 0.5)
        if not self.arm.holds(self.body):
            self.ex.cause = "close: the fingers do not both touch the object"
            return False
        return True

    def hold_and_shake(self, way: Waypoints, before: np.ndarray) -> bool:
        """Hold, shake, and check the object is still between the fingers and lifted."""
        _wait(self.world, self.cfg.hold_s)
        pos, rot = way["lift"]
        for dx, dy in ((1, 0), (-1, 0), (0, 1), (0, -1), (0, 0)):
            shift = self.cfg.shake_m * np.array([dx, dy, 0.0])
            hit = self.others & set(self.arm.move_to(pos + shift, rot, 0.25).touched)
            if hit:
                self.ex.cause = f"lift: the shake hit {_names(self.world, hit)}"
                return False
        lifted = self.world.object_pose(self.name)[2, 3] - before[2, 3]
        if not self.arm.holds(self.body) or lifted < 0.5 * self.cfg.lift_m:
            self.ex.cause = (
                f"lift: the object slipped (raised {lifted * 100:.1f} cm after the shake)"
            )
            return False
        return True

    def place(self, way: Waypoints) -> bool:
        """Down towards the target pose until the object meets a support (a guarded move),
        which must happen near the target: met higher up, the object would be dropped."""
        self.ex.stage = "place"
        goal, rot = way["place"]
        motion = self.arm.move_to(
            goal, rot, self.cfg.segment_s, self._supported, self.cfg.place_step_m
        )
        if not motion.stopped:
            return self._check("place", motion, frozenset())
        above = float(self.arm.ee_pose()[0][2] - goal[2])
        if above > self.cfg.place_above_m:
            touching = {cp[2] for cp in self._contacts()} - {self.arm.robot}
            self.ex.cause = (
                f"place: the object met {_names(self.world, touching)} {above * 100:.1f} cm "
                "above its target"
            )
            return False
        return True

    def _contacts(self) -> tuple:
        return pb.getContactPoints(bodyA=self.body, physicsClientId=self.world.client)

    def _supported(self) -> bool:
        """The held object rests on something besides the robot: a contact whose normal
        points up into the object (a neighbour brushed from the side does not count)."""
        return any(cp[2] != self.arm.robot and cp[7][2] > 0.5 for cp in self._contacts())


def _wait(world: SimWorld, seconds: float) -> None:
    for _ in range(int(seconds * PHYSICS_HZ)):
        pb.stepSimulation(physicsClientId=world.client)


def _names(world: SimWorld, bodies: set[int]) -> str:
    names = {b: n for n, b in world.bodies.items()} | {world.table: "the table"}
    return ", ".join(names.get(b, f"body {b}") for b in sorted(bodies))


def _scene_action(scene_dir: Path, action: int) -> tuple[SceneSpec, ActionSpec, np.ndarray]:
    """(spec, the move, its world transform) of action ``action`` (1-based) of a NEO-Sim
    scene folder; a clear error for anything else."""
    from neoedit.sim.specfile import scene_spec_from_dict

    meta = read_data_file(Path(scene_dir) / "scene.json", "NEO-Sim scene record")
    if not isinstance(meta, dict) or "spec" not in meta:
        raise NeoError(f"{scene_dir} is not a NEO-Sim scene folder (scene.json has no 'spec')")
    spec = scene_spec_from_dict(meta["spec"], source=str(scene_dir))
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


class Reach(NamedTuple):
    grasp: int
    """The grasp's place in the list given."""
    error_m: float
    """The largest distance between a waypoint and where the arm puts the hand."""
    stage: str
    """The stage of that largest error."""


def reachable_first(
    scene_dir: Path, action: int, grasps: list[dict[str, Any]], cfg: ExecuteConfig
) -> list[Reach]:
    """The grasps, those whose every waypoint the arm reaches within
    ``cfg.reach_tolerance_m`` first (:func:`reach_error`; the planner's order is kept within
    each group). The planner knows the scene, not the robot: this is where the robot's
    reach comes in."""
    spec, _, transform = _scene_action(scene_dir, action)
    for g in grasps:
        check_grasp(g)
    with SimWorld(spec) as world:
        for a in spec.actions[: action - 1]:
            world.apply(a)
        out = [Reach(i, *reach_error(world, g, transform, cfg)) for i, g in enumerate(grasps)]
    return sorted(out, key=lambda r: (not r.error_m <= cfg.reach_tolerance_m, r.grasp))


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

"""The Panda of a :class:`~neoedit.sim.world.SimWorld` as a robot: inverse kinematics,
straight motions of the hand through waypoints (optionally stopped by a contact, as a
force-guarded move is), the two fingers, and the grasp check."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from neoedit.errors import NeoError
from neoedit.sim._pybullet import pb
from neoedit.sim.world import PHYSICS_HZ, SimWorld, _matrix_to_quaternion

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
    """Hold after lifting, then a short shake; the grasp holds if the object is still
    between the fingers and lifted after both."""
    shake_m: float = 0.03
    """The shake: quick moves of the hand this far along x and y and back."""
    grip_force_n: float = 60.0
    reach_tolerance_m: float = 0.015
    """An arm that ends farther than this from a waypoint could not reach it."""
    place_step_m: float = 0.005
    """The place is a guarded move: the hand descends in steps of this size (at least
    0.25 s each) and stops when the object meets a support (or at the target pose), and
    releases there."""
    place_above_m: float = 0.03
    """A support met farther than this above the target pose is not the target's: the
    place fails there rather than drop the object."""
    coupled_fingers: bool = True
    """The fingers move as one, mirrored about the hand's axis, as the Franka Hand's do (a
    gear constraint); off: each finger is driven on its own, so the first to touch pushes
    the object until the other meets it."""


class Motion(NamedTuple):
    error_m: float
    """Distance between the hand and the goal at the end."""
    touched: list[int]
    """Bodies other than the robot it touched on the way."""
    stopped: bool = False
    """The ``until`` condition ended the motion before the goal."""


class PandaArm:
    """The Panda of a :class:`SimWorld` driven by position control and inverse kinematics."""

    def __init__(self, world: SimWorld, cfg: ExecuteConfig):
        self.c, self.robot = world.client, world.robot
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
        q = pb.calculateInverseKinematics(
            self.robot, self.ee, pos.tolist(), _matrix_to_quaternion(rot),
            maxNumIterations=300, residualThreshold=1e-5, physicsClientId=self.c,
        )  # fmt: skip
        return np.clip(np.asarray(q[: len(self.arm)]), self.limits[:, 0], self.limits[:, 1])

    def solve(self, pos: np.ndarray, rot: np.ndarray, passes: int = 3) -> np.ndarray:
        """Joint angles for a hand pose: inverse kinematics from the current joints, refined
        ``passes - 1`` times from its own (limit-clipped) solution, the refinement
        :func:`neoedit.sim.execute.reach_error` uses too. The arm is put back where it was,
        velocities included, so a motion can solve its next waypoint without losing its
        state. (The check still
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

    def move_to(
        self,
        pos: np.ndarray,
        rot: np.ndarray,
        seconds: float,
        until: Callable[[], bool] | None = None,
        step_m: float = 0.04,
    ) -> Motion:
        """Drive the hand to a pose through waypoints (every ``step_m`` / 15 degrees,
        inverse kinematics from the last solution). With ``until``, the motion ends (the arm
        holds where it is) as soon as it returns True, checked every 1/60 s."""
        from scipy.spatial.transform import Rotation, Slerp

        p0, r0 = self.ee_pose()
        turn = float(
            np.degrees((Rotation.from_matrix(r0).inv() * Rotation.from_matrix(rot)).magnitude())
        )
        n = int(max(1, np.ceil(np.linalg.norm(pos - p0) / step_m), np.ceil(turn / 15.0)))
        slerp = Slerp([0.0, 1.0], Rotation.from_matrix(np.stack([r0, rot])))
        touched: set[int] = set()
        for k in range(1, n + 1):
            f = k / n
            hit, stopped = self._drive(
                p0 + f * (pos - p0), slerp(f).as_matrix(), max(seconds / n, 0.25), until
            )
            touched |= hit
            if stopped:
                self.hold()
                return Motion(float(np.linalg.norm(self.ee_pose()[0] - pos)), sorted(touched), True)
        for _ in range(int(0.3 * PHYSICS_HZ)):  # let position control settle on the goal
            pb.stepSimulation(physicsClientId=self.c)
        return Motion(float(np.linalg.norm(self.ee_pose()[0] - pos)), sorted(touched))

    def _drive(
        self, pos: np.ndarray, rot: np.ndarray, seconds: float, until: Callable[[], bool] | None
    ) -> tuple[set[int], bool]:
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
            if until is not None and k % (PHYSICS_HZ // 60) == 0 and until():
                return touched, True
        return touched, False

    def hold(self) -> None:
        """Keep the arm where it is now (position control on its current joints)."""
        pb.setJointMotorControlArray(
            self.robot, self.arm, pb.POSITION_CONTROL, targetPositions=self.joints().tolist(),
            forces=[200.0] * len(self.arm), physicsClientId=self.c,
        )  # fmt: skip

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

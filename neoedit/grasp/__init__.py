"""Parallel-jaw grasps planned on a scene version's own radiance field (no mesh, no GPU):
surface and normals from the density (:mod:`.surface`), the Franka hand as boxes
(:mod:`.gripper`), antipodal sampling in a friction cone with collision checks against the
whole scene (:mod:`.antipodal`)."""

from neoedit.grasp.antipodal import Grasp, GraspConfig, plan_grasps
from neoedit.grasp.gripper import GripperConfig

__all__ = ["Grasp", "GraspConfig", "GripperConfig", "plan_grasps"]

"""Grasps drawn over a render: finger and palm wireframes, the approach line."""

from __future__ import annotations

import cv2
import numpy as np

from neoedit.cameras import Cameras
from neoedit.grasp.antipodal import Grasp
from neoedit.grasp.gripper import GripperConfig, box_corners, gripper_boxes
from neoedit.viz.boxes import BOX_EDGES

RANK_COLOURS = [(40, 220, 40), (250, 210, 30), (250, 140, 30), (230, 60, 60), (200, 60, 200)]


def draw_grasps(
    image: np.ndarray,
    cameras: Cameras,
    index: int,
    grasps: list[Grasp],
    gripper: GripperConfig,
    thickness: int = 1,
) -> np.ndarray:
    """Copy of ``image`` with each grasp drawn (best first: green, then yellow, orange, ...)."""
    out = np.ascontiguousarray(image.copy())
    for rank in range(len(grasps) - 1, -1, -1):  # the best drawn last, on top
        g = grasps[rank]
        colour = RANK_COLOURS[min(rank, len(RANK_COLOURS) - 1)]
        segments = []
        for centre, half in gripper_boxes(gripper, g.width_m):
            corners = box_corners(centre, half)
            segments += [(corners[a], corners[b]) for a, b in BOX_EDGES]
        segments.append((np.zeros(3), np.array([0.0, 0.0, -0.12])))  # the approach
        for a, b in segments:
            pts = np.stack([a, b]) @ g.rotation.T + g.position_m
            uv, depth = cameras.project(index, pts)
            if (depth <= 1e-3).any():
                continue
            pa, pb = (tuple(int(round(c)) for c in p) for p in uv)
            cv2.line(out, pa, pb, colour, thickness, cv2.LINE_AA)
    return out


def facing_view(cameras: Cameras, candidates: np.ndarray, point: np.ndarray) -> int:
    """The camera of ``candidates`` that looks most directly at ``point``."""
    centres = cameras.camera_to_world[candidates, :3, 3]
    to_point = point - centres
    to_point /= np.linalg.norm(to_point, axis=1, keepdims=True)
    forward = -cameras.camera_to_world[candidates, :3, 2]
    return int(candidates[int(np.argmax(np.sum(forward * to_point, axis=1)))])

"""The parallel-jaw gripper as boxes in its grasp frame.

Grasp frame (the ``rotation`` columns of a grasp): x = closing axis (from one finger to the
other), y = finger axis (across a finger pad), z = approach axis (the direction the hand
moves to reach the object, palm to fingertips). The origin is the grasp centre, midway
between the contacts, ``tip_inset_m`` short of the fingertips. Defaults: the Franka Emika
hand (8 cm maximum opening; pads ~2 cm wide; fingers ~5 cm long; palm ~20 x 6 x 7 cm).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass
class GripperConfig:
    max_width_m: float = 0.08
    """Largest opening between the finger pads."""
    finger_length_m: float = 0.05
    """Finger length along the approach axis."""
    finger_width_m: float = 0.02
    """Finger pad size along the finger axis."""
    finger_thickness_m: float = 0.01
    """Finger size along the closing axis."""
    tip_inset_m: float = 0.012
    """How far the fingertips reach beyond the grasp centre."""
    palm_size_m: tuple[float, float, float] = (0.2, 0.06, 0.07)
    """Palm (hand body) size along closing, finger and approach axes."""
    open_margin_m: float = 0.015
    """The fingers approach opened this much wider than the object (each side; the
    executor opens them as far as the planner checked, ``opening_m``)."""


def opening(cfg: GripperConfig, width_m: float) -> float:
    """How far apart the finger pads are on the approach to an object ``width_m`` wide."""
    return min(width_m + 2 * cfg.open_margin_m, cfg.max_width_m)


def gripper_boxes(cfg: GripperConfig, width_m: float) -> list[tuple[np.ndarray, np.ndarray]]:
    """(centre (3,), half extents (3,)) in the grasp frame of the two fingers (opened to
    :func:`opening`) and the palm."""
    open_w = opening(cfg, width_m)
    half_f = np.array([cfg.finger_thickness_m, cfg.finger_width_m, cfg.finger_length_m]) / 2
    z_f = cfg.tip_inset_m - cfg.finger_length_m / 2
    x_f = open_w / 2 + cfg.finger_thickness_m / 2
    half_p = np.asarray(cfg.palm_size_m, dtype=np.float64) / 2
    z_p = cfg.tip_inset_m - cfg.finger_length_m - half_p[2]
    return [
        (np.array([-x_f, 0.0, z_f]), half_f),
        (np.array([x_f, 0.0, z_f]), half_f),
        (np.array([0.0, 0.0, z_p]), half_p),
    ]


def box_lattice(center: np.ndarray, half: np.ndarray, step_m: float) -> np.ndarray:
    """(K,3) points filling a box (frame coordinates) every ~``step_m``, faces included."""
    axes = [np.linspace(-h, h, max(2, int(np.ceil(2 * h / step_m)) + 1)) for h in half]
    grid = np.stack(np.meshgrid(*axes, indexing="ij"), -1).reshape(-1, 3)
    return grid + center


def box_corners(center: np.ndarray, half: np.ndarray) -> np.ndarray:
    """(8,3) corners (bit k of the index = sign of axis k), frame coordinates."""
    signs = np.array([[(i >> k) & 1 for k in range(3)] for i in range(8)], dtype=np.float64)
    return center + (2 * signs - 1) * half

"""Small rigid-transform helpers (world frame z-up, metres, angles in degrees in names)."""

from __future__ import annotations

import numpy as np


def rot_z(yaw_deg: float) -> np.ndarray:
    """(3,3) rotation about +z by ``yaw_deg`` (counter-clockwise seen from above)."""
    a = np.deg2rad(yaw_deg)
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def yaw_of_rotation(rotation: np.ndarray) -> float:
    """Yaw in degrees of the x axis of ``rotation`` (3,3) projected on the ground plane."""
    return float(np.rad2deg(np.arctan2(rotation[1, 0], rotation[0, 0])))


def make_transform(rotation: np.ndarray, translation: np.ndarray) -> np.ndarray:
    """(4,4) homogeneous transform from a (3,3) rotation and a (3,) translation."""
    t = np.eye(4)
    t[:3, :3] = rotation
    t[:3, 3] = translation
    return t


def apply_transform(transform: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Apply a (4,4) transform to points (N,3)."""
    return points @ transform[:3, :3].T + transform[:3, 3]


def wrap_deg(angle_deg: float) -> float:
    """Wrap an angle to (-180, 180]."""
    a = (angle_deg + 180.0) % 360.0 - 180.0
    return 180.0 if a == -180.0 else a


def is_rigid(transform: np.ndarray, tol: float = 1e-4) -> bool:
    """Whether ``transform`` is a finite (4,4) proper rigid motion (orthonormal rotation with
    determinant +1, last row 0 0 0 1)."""
    t = np.asarray(transform, dtype=np.float64)
    if t.shape != (4, 4) or not np.isfinite(t).all():
        return False
    rot = t[:3, :3]
    return (
        bool(np.allclose(rot.T @ rot, np.eye(3), atol=tol))
        and float(np.linalg.det(rot)) > 0
        and bool(np.allclose(t[3], [0.0, 0.0, 0.0, 1.0], atol=tol))
    )


def motion_about(center_m: np.ndarray, translate_m: np.ndarray, yaw_deg: float) -> np.ndarray:
    """(4,4) world motion that turns by ``yaw_deg`` about the vertical axis through
    ``center_m`` and then translates by ``translate_m``: x' = R (x - c) + c + t."""
    rot = rot_z(yaw_deg)
    c = np.asarray(center_m, dtype=np.float64)
    return make_transform(rot, c - rot @ c + np.asarray(translate_m, dtype=np.float64))


def invert_rigid(transform: np.ndarray) -> np.ndarray:
    """Inverse of a rigid (4,4) transform."""
    rot = transform[:3, :3]
    return make_transform(rot.T, -rot.T @ transform[:3, 3])

"""Pinhole cameras in the OpenGL / nerfstudio convention.

Camera frame: x right, y up, the camera looks down -z. ``camera_to_world`` maps camera
coordinates to the world frame (z-up, metres). Pixel (row v, column u) has its centre at
(u + 0.5, v + 0.5) in image coordinates, whose origin is the top-left corner.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from neoedit.errors import DataError


def look_at(eye_m: np.ndarray, target_m: np.ndarray, up: np.ndarray | None = None) -> np.ndarray:
    """(4,4) camera-to-world (OpenGL) for a camera at ``eye_m`` looking at ``target_m``."""
    eye = np.asarray(eye_m, dtype=np.float64)
    up_vec = np.array([0.0, 0.0, 1.0]) if up is None else np.asarray(up, dtype=np.float64)
    back = eye - np.asarray(target_m, dtype=np.float64)
    back /= np.linalg.norm(back)
    right = np.cross(up_vec, back)
    if np.linalg.norm(right) < 1e-8:  # looking straight down/up: pick any right vector
        right = np.cross(np.array([0.0, 1.0, 0.0]), back)
    right /= np.linalg.norm(right)
    true_up = np.cross(back, right)
    c2w = np.eye(4)
    c2w[:3, 0], c2w[:3, 1], c2w[:3, 2], c2w[:3, 3] = right, true_up, back, eye
    return c2w


@dataclass
class Cameras:
    """A set of N pinhole cameras (intrinsics in pixels, per camera)."""

    camera_to_world: np.ndarray  # (N, 4, 4) float64, OpenGL convention
    fx: np.ndarray  # (N,) pixels; a scalar is broadcast to all cameras
    fy: np.ndarray  # (N,)
    cx: np.ndarray  # (N,)
    cy: np.ndarray  # (N,)
    width: np.ndarray  # (N,) int
    height: np.ndarray  # (N,) int

    @classmethod
    def shared(
        cls,
        camera_to_world: np.ndarray,
        fx: float,
        fy: float,
        cx: float,
        cy: float,
        width: int,
        height: int,
    ) -> Cameras:
        """N cameras with one set of intrinsics."""
        n = len(np.asarray(camera_to_world).reshape(-1, 4, 4))
        full = lambda v: np.full(n, v)  # noqa: E731
        return cls(
            camera_to_world, full(fx), full(fy), full(cx), full(cy), full(width), full(height)
        )

    def __post_init__(self) -> None:
        self.camera_to_world = np.asarray(self.camera_to_world, dtype=np.float64).reshape(-1, 4, 4)
        n = len(self.camera_to_world)
        for name in ("fx", "fy", "cx", "cy"):
            setattr(
                self,
                name,
                np.broadcast_to(np.asarray(getattr(self, name), np.float64), (n,)).copy(),
            )
        for name in ("width", "height"):
            setattr(
                self, name, np.broadcast_to(np.asarray(getattr(self, name), np.int64), (n,)).copy()
            )

    def __len__(self) -> int:
        return len(self.camera_to_world)

    def with_poses(self, camera_to_world: np.ndarray) -> Cameras:
        """New cameras at ``camera_to_world`` (N,4,4) with the intrinsics of camera 0."""
        return Cameras.shared(
            camera_to_world,
            self.fx[0],
            self.fy[0],
            self.cx[0],
            self.cy[0],
            int(self.width[0]),
            int(self.height[0]),
        )

    def subset(self, indices: np.ndarray | list[int]) -> Cameras:
        idx = np.asarray(indices, dtype=np.int64)
        return Cameras(
            self.camera_to_world[idx],
            self.fx[idx],
            self.fy[idx],
            self.cx[idx],
            self.cy[idx],
            self.width[idx],
            self.height[idx],
        )

    def scaled(self, scale: float) -> Cameras:
        """The same cameras with images resized by ``scale`` (intrinsics scaled)."""
        w = np.maximum((self.width * scale).round().astype(np.int64), 1)
        h = np.maximum((self.height * scale).round().astype(np.int64), 1)
        sx, sy = w / self.width, h / self.height
        return Cameras(
            self.camera_to_world, self.fx * sx, self.fy * sy, self.cx * sx, self.cy * sy, w, h
        )

    @staticmethod
    def concat(sets: list[Cameras]) -> Cameras:
        """One camera set from several, in order."""
        if len(sets) == 1:
            return sets[0]
        fields = ("camera_to_world", "fx", "fy", "cx", "cy", "width", "height")
        return Cameras(*(np.concatenate([getattr(c, f) for c in sets]) for f in fields))

    def to_record(self) -> dict[str, list]:
        """JSON-able record (lists) of the cameras; :meth:`from_record` reads it back."""
        return {
            "camera_to_world": self.camera_to_world.round(9).tolist(),
            **{f: getattr(self, f).tolist() for f in ("fx", "fy", "cx", "cy", "width", "height")},
        }

    @classmethod
    def from_record(cls, record: dict[str, list]) -> Cameras:
        fields = ("camera_to_world", "fx", "fy", "cx", "cy", "width", "height")
        return cls(*(np.asarray(record[f]) for f in fields))

    def pixel_directions_camera(self, i: int) -> np.ndarray:
        """(H, W, 3) camera-frame ray directions through pixel centres, with z = -1."""
        w, h = int(self.width[i]), int(self.height[i])
        u, v = np.meshgrid(np.arange(w) + 0.5, np.arange(h) + 0.5)
        x = (u - self.cx[i]) / self.fx[i]
        y = -(v - self.cy[i]) / self.fy[i]
        return np.stack([x, y, -np.ones_like(x)], axis=-1)

    def backproject_depth(self, i: int, depth_z_m: np.ndarray) -> np.ndarray:
        """World points (H, W, 3) of a z-depth image (metres along the optical axis)."""
        dirs = self.pixel_directions_camera(i) * depth_z_m[..., None]
        c2w = self.camera_to_world[i]
        return dirs @ c2w[:3, :3].T + c2w[:3, 3]

    def project(self, i: int, points_world: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Project world points (N,3) into camera i -> (pixel coords (N,2) as (u, v), z-depth (N,)).

        z-depth is positive in front of the camera.
        """
        w2c = np.linalg.inv(self.camera_to_world[i])
        pc = np.asarray(points_world, dtype=np.float64) @ w2c[:3, :3].T + w2c[:3, 3]
        depth = -pc[:, 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            u = self.fx[i] * pc[:, 0] / depth + self.cx[i]
            v = -self.fy[i] * pc[:, 1] / depth + self.cy[i]
        return np.stack([u, v], axis=-1), depth


def orbit_center(cameras: Cameras) -> np.ndarray:
    """Least-squares point closest to all optical axes (where the cameras look)."""
    origins = cameras.camera_to_world[:, :3, 3]
    dirs = -cameras.camera_to_world[:, :3, 2]
    a = np.zeros((3, 3))
    b = np.zeros(3)
    for o, d in zip(origins, dirs, strict=True):
        p = np.eye(3) - np.outer(d, d)
        a += p
        b += p @ o
    return np.linalg.lstsq(a, b, rcond=None)[0]


def validate_pose(c2w: np.ndarray, where: str) -> np.ndarray:
    """Check a (4,4) camera-to-world matrix: finite, rigid, invertible. Returns it as float64."""
    try:
        m = np.asarray(c2w, dtype=np.float64)
    except (TypeError, ValueError) as e:
        raise DataError(f"{where}: transform_matrix is not a numeric matrix") from e
    if m.shape == (3, 4):
        m = np.vstack([m, [0, 0, 0, 1]])
    if m.shape != (4, 4):
        raise DataError(f"{where}: transform_matrix must be 4x4 (or 3x4), got shape {m.shape}")
    if not np.all(np.isfinite(m)):
        raise DataError(f"{where}: transform_matrix has non-finite values")
    det = np.linalg.det(m[:3, :3])
    if abs(det) < 1e-6:
        raise DataError(
            f"{where}: transform_matrix is not invertible (det of rotation = {det:.3g})"
        )
    return m

"""Oriented 3-D box with yaw about the vertical (z) axis: the paper's b = (c, theta).

Serialised everywhere (objects.json, scene.json, ``neo query`` output) as
``{"center": [x, y, z], "size": [sx, sy, sz], "yaw_deg": theta}`` in world metres.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import torch

from neoedit.errors import NeoError
from neoedit.geometry.transforms import rot_z, wrap_deg, yaw_of_rotation
from neoedit.utils.userfile import read_data_file


def _vec3(values: Any) -> tuple[float, float, float]:
    x, y, z = (float(v) for v in values)
    return (x, y, z)


@dataclass(frozen=True)
class OrientedBox:
    """Box of ``size_m`` (sx, sy, sz) centred at ``center_m``, rotated by ``yaw_deg`` about +z."""

    center_m: tuple[float, float, float]
    size_m: tuple[float, float, float]
    yaw_deg: float = 0.0

    def __post_init__(self) -> None:
        if len(self.center_m) != 3 or len(self.size_m) != 3:
            raise NeoError("box center and size need 3 values each")
        if not all(np.isfinite(v) for v in (*self.center_m, *self.size_m, self.yaw_deg)):
            raise NeoError(
                f"box has non-finite values: center {list(self.center_m)}, size "
                f"{list(self.size_m)}, yaw {self.yaw_deg} deg"
            )
        if min(self.size_m) <= 0:
            raise NeoError(f"box size must be positive, got {self.size_m}")

    # -- serialisation -------------------------------------------------------------------
    def to_dict(self) -> dict[str, Any]:
        return {
            "center": [round(float(v), 6) for v in self.center_m],
            "size": [round(float(v), 6) for v in self.size_m],
            "yaw_deg": round(float(self.yaw_deg), 4),
        }

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> OrientedBox:
        try:
            center = _vec3(d["center"])
            size = _vec3(d["size"])
            yaw = float(d.get("yaw_deg", 0.0))
        except (KeyError, TypeError, ValueError) as e:
            raise NeoError(
                f"bad box {dict(d)!r}: expected {{'center': [x,y,z], 'size': [sx,sy,sz], 'yaw_deg': deg}}"
            ) from e
        return cls(center, size, yaw)

    # -- geometry ------------------------------------------------------------------------
    @property
    def rotation(self) -> np.ndarray:
        return rot_z(self.yaw_deg)

    @property
    def half_extents(self) -> np.ndarray:
        return np.asarray(self.size_m, dtype=np.float64) / 2.0

    @property
    def volume_m3(self) -> float:
        return float(np.prod(self.size_m))

    def world_to_local(self, points: np.ndarray) -> np.ndarray:
        """Points (N,3) world -> box frame (centre at origin, axes aligned)."""
        return (np.asarray(points, dtype=np.float64) - np.asarray(self.center_m)) @ self.rotation

    def contains(self, points: np.ndarray, margin_m: float = 0.0) -> np.ndarray:
        """Boolean (N,) of points (N,3) inside the box grown by ``margin_m``."""
        local = self.world_to_local(points)
        return np.all(np.abs(local) <= self.half_extents + margin_m, axis=-1)

    def corners(self) -> np.ndarray:
        """(8,3) corners in world frame; index bits (x,y,z) -> sign (-,+)."""
        signs = np.array([[(i >> 0) & 1, (i >> 1) & 1, (i >> 2) & 1] for i in range(8)]) * 2 - 1
        return (signs * self.half_extents) @ self.rotation.T + np.asarray(self.center_m)

    def grown(self, margin_m: float) -> OrientedBox:
        """The box grown by ``margin_m`` on every face (bottom included)."""
        sx, sy, sz = (float(s) + 2 * margin_m for s in self.size_m)
        return OrientedBox(self.center_m, (sx, sy, sz), self.yaw_deg)

    def lifted_bottom(self, lift_m: float) -> OrientedBox:
        """The box with its bottom face raised by ``lift_m`` (top kept)."""
        return self.with_bottom(self.center_m[2] - self.size_m[2] / 2 + lift_m)

    def extended_down(self, z_m: float) -> OrientedBox:
        """The box with its bottom lowered to ``z_m`` (unchanged if it already reaches it)."""
        return self.with_bottom(min(self.center_m[2] - self.size_m[2] / 2, z_m))

    def with_bottom(self, z_m: float) -> OrientedBox:
        """The box with its bottom face moved to height ``z_m`` (top kept; z-up boxes)."""
        top = self.center_m[2] + self.size_m[2] / 2
        if z_m >= top:
            raise NeoError(f"bottom {z_m:.4f} m is not below the box top {top:.4f} m")
        (cx, cy, _), (sx, sy, _) = self.center_m, self.size_m
        return OrientedBox((cx, cy, (top + z_m) / 2), (sx, sy, top - z_m), self.yaw_deg)

    def transformed(self, transform: np.ndarray) -> OrientedBox:
        """The box moved by a rigid (4,4) world transform whose rotation is about z."""
        rot = transform[:3, :3]
        center = rot @ np.asarray(self.center_m) + transform[:3, 3]
        yaw = wrap_deg(self.yaw_deg + yaw_of_rotation(rot))
        return OrientedBox(tuple(center.tolist()), self.size_m, yaw)

    @classmethod
    def fit_with_yaw(
        cls, points: np.ndarray, yaw_deg: float, trim: float | tuple[float, float, float] = 0.0
    ) -> OrientedBox:
        """Tightest box of a given yaw around points (N,3); ``trim`` > 0 leaves that fraction
        of the points out on each side of each axis (robust to stragglers), one value for all
        three axes or one per axis (local x, y, z)."""
        rot = rot_z(yaw_deg)
        local = np.asarray(points, dtype=np.float64) @ rot  # into the yaw-aligned frame
        frac = np.broadcast_to(np.asarray(trim, dtype=np.float64), (3,))
        lo = np.array([np.quantile(local[:, k], frac[k]) for k in range(3)])
        hi = np.array([np.quantile(local[:, k], 1.0 - frac[k]) for k in range(3)])
        center = rot @ ((lo + hi) / 2)
        return cls(
            tuple(center.tolist()), tuple(np.maximum(hi - lo, 1e-4).tolist()), wrap_deg(yaw_deg)
        )

    @classmethod
    def fit_to_points(cls, points: np.ndarray) -> OrientedBox:
        """Tightest yaw-only box around points (N,3).

        Yaw and footprint come from the minimum-area rectangle of the points projected on
        the ground plane (OpenCV), height from their z range.
        """
        pts = np.asarray(points, dtype=np.float64)
        if pts.ndim != 2 or pts.shape[1] != 3 or len(pts) < 3:
            raise NeoError("fitting a box needs at least 3 points (N,3)")
        (cx, cy), (w, h), angle = cv2.minAreaRect(pts[:, :2].astype(np.float32))
        z0 = float(pts[:, 2].min())
        z1 = float(pts[:, 2].max())
        # Keep sx >= sy so the yaw is the direction of the long side, in (-90, 90].
        yaw = float(angle)
        if w < h:
            w, h, yaw = h, w, yaw + 90.0
        yaw = wrap_deg(yaw)
        if yaw <= -90.0:
            yaw += 180.0
        elif yaw > 90.0:
            yaw -= 180.0
        eps = 1e-4
        return cls(
            (float(cx), float(cy), (z0 + z1) / 2),
            (max(float(w), eps), max(float(h), eps), max(z1 - z0, eps)),
            yaw,
        )


def _clip_convex(subject: np.ndarray, clip: np.ndarray) -> np.ndarray:
    """Sutherland-Hodgman: the part of convex polygon ``subject`` (K,2) inside convex ``clip``
    (M,2), both counter-clockwise."""
    out = subject
    for k in range(len(clip)):
        if len(out) == 0:
            break
        a, b = clip[k], clip[(k + 1) % len(clip)]
        edge = b - a
        side = edge[0] * (out[:, 1] - a[1]) - edge[1] * (out[:, 0] - a[0])  # >= 0: inside
        nxt = []
        for i in range(len(out)):
            p, q, sp, sq = out[i], out[(i + 1) % len(out)], side[i], side[(i + 1) % len(out)]
            if sp >= 0:
                nxt.append(p)
            if (sp >= 0) != (sq >= 0):
                nxt.append(p + (q - p) * (sp / (sp - sq)))
        out = np.asarray(nxt).reshape(-1, 2)
    return out


def _polygon_area(poly: np.ndarray) -> float:
    if len(poly) < 3:
        return 0.0
    x, y = poly[:, 0], poly[:, 1]
    return 0.5 * abs(float(np.dot(x, np.roll(y, -1)) - np.dot(y, np.roll(x, -1))))


def box_local(points: torch.Tensor, box: OrientedBox) -> torch.Tensor:
    """(N,3) world points (a tensor on any device) in the box's frame: its centre at the
    origin, its axes the frame's. The tensor counterpart of :meth:`OrientedBox.world_to_local`."""
    return (points - points.new_tensor(box.center_m)) @ points.new_tensor(box.rotation)


def points_in_box(points: torch.Tensor, box: OrientedBox) -> torch.Tensor:
    """(N,) bool: which world points (N,3) (a tensor on any device) lie inside the oriented
    box (faces included). The tensor counterpart of :meth:`OrientedBox.contains`."""
    return (box_local(points, box).abs() <= points.new_tensor(box.half_extents)).all(-1)


def points_in_boxes(points: torch.Tensor, boxes: Sequence[OrientedBox]) -> torch.Tensor:
    """(N,) bool: which world points (N,3) lie inside any of ``boxes`` (none: all False)."""
    inside = torch.zeros(len(points), dtype=torch.bool, device=points.device)
    for box in boxes:
        inside |= points_in_box(points, box)
    return inside


def box_iou_3d(a: OrientedBox, b: OrientedBox) -> float:
    """3-D IoU of two yaw-only boxes: ground-plane polygon overlap times z overlap."""
    pa = a.corners()[[0, 1, 3, 2], :2]  # counter-clockwise footprint
    pb = b.corners()[[0, 1, 3, 2], :2]
    area = _polygon_area(_clip_convex(pa, pb))
    za = (a.center_m[2] - a.size_m[2] / 2, a.center_m[2] + a.size_m[2] / 2)
    zb = (b.center_m[2] - b.size_m[2] / 2, b.center_m[2] + b.size_m[2] / 2)
    dz = max(0.0, min(za[1], zb[1]) - max(za[0], zb[0]))
    inter = area * dz
    union = a.volume_m3 + b.volume_m3 - inter
    return inter / union if union > 0 else 0.0


def load_boxes(path: Path) -> list[OrientedBox]:
    """Read one box or a list of boxes from a JSON file (also accepts ``{"box": {...}}``)."""
    data = read_data_file(Path(path), "box file")
    items = data if isinstance(data, list) else [data]
    if not items:
        raise NeoError(f"{path} holds an empty list: give a box, or a list of boxes")
    boxes = []
    for i, d in enumerate(items, 1):
        try:
            boxes.append(OrientedBox.from_dict(d.get("box", d) if isinstance(d, dict) else {}))
        except NeoError as e:  # the message names the file (and the item) it came from
            where = f"{path}: box {i}" if len(items) > 1 else str(path)
            raise NeoError(f"{where}: {e}") from None
    return boxes


def yaw_error_deg(pred: OrientedBox, truth: OrientedBox, square_tolerance: float = 0.15) -> float:
    """Yaw error [deg] modulo the box's symmetry: the angle between the long sides (modulo
    180), or modulo 90 when the true footprint is nearly square (sides within
    ``square_tolerance`` of each other), where the long side is not defined."""

    def long_side_yaw(box: OrientedBox) -> float:
        return box.yaw_deg if box.size_m[0] >= box.size_m[1] else box.yaw_deg + 90.0

    sx, sy = truth.size_m[0], truth.size_m[1]
    period = 90.0 if abs(sx - sy) <= square_tolerance * max(sx, sy) else 180.0
    d = (long_side_yaw(pred) - long_side_yaw(truth)) % period
    return float(min(d, period - d))

"""Image regions of 3-D boxes: the pixels whose ray passes through a box.

:func:`box_mask` is the exact per-pixel ray-box slab test (it also works for boxes partly
behind the camera); :func:`project_box_mask` rasterises the projected faces, which is
faster and equal to it (property-tested).
"""

from __future__ import annotations

import cv2
import numpy as np

from neoedit.cameras import Cameras
from neoedit.cameras.rays import CameraTensors
from neoedit.geometry.box import OrientedBox
from neoedit.geometry.rays import ray_oriented_box


def box_mask(cameras: Cameras, index: int, box: OrientedBox) -> np.ndarray:
    """(H, W) bool: pixels of camera ``index`` whose ray hits ``box`` in front of the camera."""
    h, w = int(cameras.height[index]), int(cameras.width[index])
    rays = CameraTensors(cameras.subset([index])).image_rays(0, h, w)
    t_in, t_out = ray_oriented_box(rays.origins.double(), rays.directions.double(), box)
    return ((t_out > t_in) & (t_out > 0)).reshape(h, w).numpy()


def masks_for_boxes(cameras: Cameras, index: int, boxes: list[OrientedBox]) -> np.ndarray:
    """Union of :func:`box_mask` over several boxes."""
    h, w = int(cameras.height[index]), int(cameras.width[index])
    out = np.zeros((h, w), dtype=bool)
    for box in boxes:
        out |= box_mask(cameras, index, box)
    return out


def project_box_mask(cameras: Cameras, index: int, box: OrientedBox) -> np.ndarray:
    """(H, W) bool: the box's silhouette in camera ``index``, rasterised from its projected
    faces: a pixel counts when its centre is inside the convex hull of the 8 projected
    corners (the union of the projected faces). Boxes reaching behind the camera fall back to
    the per-pixel ray-box test."""
    h, w = int(cameras.height[index]), int(cameras.width[index])
    uv, depth = cameras.project(index, box.corners())
    if np.any(depth <= 1e-6):
        return box_mask(cameras, index, box)
    hull = cv2.convexHull(uv.astype(np.float32))[:, 0, :].astype(np.float64)  # (K,2)
    mask = np.zeros((h, w), bool)
    lo = np.clip(np.floor(hull.min(0)).astype(int), 0, [w, h])
    hi = np.clip(np.ceil(hull.max(0)).astype(int) + 1, 0, [w, h])
    if np.any(hi <= lo):
        return mask
    u, v = np.meshgrid(np.arange(lo[0], hi[0]) + 0.5, np.arange(lo[1], hi[1]) + 0.5)
    inside = np.ones(u.shape, bool)
    signed_area = np.sum(
        hull[:, 0] * np.roll(hull[:, 1], -1) - np.roll(hull[:, 0], -1) * hull[:, 1]
    )
    orient = 1.0 if signed_area >= 0 else -1.0
    for a, b in zip(hull, np.roll(hull, -1, axis=0), strict=True):
        # pixel centres on the inner side of every hull edge
        inside &= orient * ((b[0] - a[0]) * (v - a[1]) - (b[1] - a[1]) * (u - a[0])) >= 0
    mask[lo[1] : hi[1], lo[0] : hi[0]] = inside
    return mask


def box_pixels(cameras: Cameras, boxes: list[OrientedBox]) -> np.ndarray:
    """(P,3) int64 rows (camera, v, u) of every pixel whose ray crosses one of ``boxes``."""
    rows = [np.zeros((0, 3), np.int64)]
    for i in range(len(cameras)):
        mask = np.zeros((int(cameras.height[i]), int(cameras.width[i])), bool)
        for box in boxes:
            mask |= project_box_mask(cameras, i, box)
        vu = np.argwhere(mask)
        rows.append(np.column_stack([np.full(len(vu), i), vu]))
    return np.concatenate(rows).astype(np.int64)

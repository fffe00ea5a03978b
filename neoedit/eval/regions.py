"""Image regions of 3-D boxes: the pixels whose ray passes through the box.

This is the exact rasterisation of the projected box (its silhouette), computed per pixel
with a ray-box slab test, so it also works for boxes partly behind the camera.
"""

from __future__ import annotations

import numpy as np

from neoedit.cameras import Cameras
from neoedit.cameras.rays import CameraTensors
from neoedit.geometry import OrientedBox
from neoedit.rendering.intervals import ray_oriented_box


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

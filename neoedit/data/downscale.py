"""Train and evaluate at a lower resolution than the photos (nerfstudio's ``--downscale-factor``).

A 1080x1920 phone capture trains on 2 CPU cores far faster, and hardly worse, at a quarter of
its size. :func:`downscale` shrinks every per-pixel array of a :class:`SceneData` (area
averaging for colour and opacity, nearest neighbour for depth, labels and masks) and scales
the intrinsics to match. (nerfstudio's pre-shrunk ``images_N/`` folders are not read yet:
the full-size photos are shrunk on load.)
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import overload

import cv2
import numpy as np

from neoedit.cameras import Cameras
from neoedit.data.scene_data import SceneData
from neoedit.errors import DataError
from neoedit.utils.options import at_least


@dataclass
class DataConfig:
    """How a dataset is read for training, evaluation or ``neo info``."""

    downscale: int = 1
    """Shrink the images by this integer factor (nerfstudio: --downscale-factor)."""
    max_width: int | None = at_least(8)
    """Or shrink by the smallest integer factor that makes the images at most this wide."""
    skip_missing: bool = False
    """Drop the frames whose image file is missing (with a warning) instead of refusing the
    dataset."""

    def check(self) -> None:
        if isinstance(self.downscale, bool) or self.downscale < 1:
            raise DataError(f"--downscale must be a whole number >= 1, got {self.downscale}")
        if self.max_width is not None and self.max_width < 8:
            raise DataError(f"--max-width must be at least 8 pixels, got {self.max_width}")

    def factor(self, width: int) -> int:
        """The downscale factor for images ``width`` pixels wide."""
        factor = self.downscale
        if self.max_width is not None:
            factor = max(factor, -(-width // self.max_width))
        return factor


@overload
def _resize(stack: np.ndarray, size: tuple[int, int], nearest: bool) -> np.ndarray: ...
@overload
def _resize(stack: None, size: tuple[int, int], nearest: bool) -> None: ...
def _resize(stack: np.ndarray | None, size: tuple[int, int], nearest: bool) -> np.ndarray | None:
    if stack is None:
        return None
    interp = cv2.INTER_NEAREST if nearest else cv2.INTER_AREA
    dtype = stack.dtype
    work = stack.astype(np.uint8) if dtype == np.bool_ else stack
    out = np.stack([cv2.resize(a, size, interpolation=interp) for a in work])
    return out.astype(bool) if dtype == np.bool_ else out


def downscale(data: SceneData, factor: int) -> SceneData:
    """``data`` with images ``factor`` times smaller (rounded down), intrinsics scaled alike
    (a pixel's centre keeps its ray). Factor 1 returns ``data`` unchanged."""
    if factor == 1:
        return data
    h, w = data.height // factor, data.width // factor
    if h < 8 or w < 8:
        raise DataError(
            f"downscaling {data.width}x{data.height} images by {factor} leaves {w}x{h} pixels"
        )
    sx, sy = w / data.width, h / data.height
    c = data.cameras
    cameras = Cameras(
        c.camera_to_world,
        c.fx * sx,
        c.fy * sy,
        c.cx * sx,
        c.cy * sy,
        np.full(len(c.fx), w),
        np.full(len(c.fx), h),
    )
    ids = data.instance_ids
    return dataclasses.replace(
        data,
        images=_resize(data.images, (w, h), nearest=False),
        cameras=cameras,
        depth_m=_resize(data.depth_m, (w, h), nearest=True),
        alpha=_resize(data.alpha, (w, h), nearest=False),
        loss_mask=_resize(data.loss_mask, (w, h), nearest=True),
        instance_ids=None if ids is None else _resize(ids.astype(np.int32), (w, h), True),
    )

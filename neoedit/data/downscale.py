"""Train and evaluate at a lower resolution than the photos (nerfstudio's ``--downscale-factor``).

A 1080x1920 phone capture trains on 2 CPU cores far faster, and hardly worse, at a quarter of
its size. :func:`downscale` shrinks every per-pixel array of a :class:`SceneData` (area
averaging for colour and opacity, nearest neighbour for depth, labels and masks) and scales
the intrinsics to match. Where a nerfstudio dataset has its photos pre-shrunk by that
factor (``images_N/``, and ``masks_N/`` / ``depths_N/`` for the frames' masks and depths, as
nerfstudio's ``ns-process-data`` writes them), :func:`pre_shrunk` has them read instead.
"""

from __future__ import annotations

import dataclasses
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import Any, overload

import cv2
import numpy as np

from neoedit.cameras import Cameras
from neoedit.data.images import image_size
from neoedit.data.scene_data import SceneData
from neoedit.data.undistort import Lens
from neoedit.errors import DataError, NeoWarning
from neoedit.utils.options import at_least


@dataclass
class DataConfig:
    """How a dataset is read for training, evaluation or ``neo info``."""

    downscale: int = 1
    """Shrink the images by this integer factor (nerfstudio: --downscale-factor); nerfstudio's
    pre-shrunk images_N/ copies are read where they hold every frame."""
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
        downscaled=data.downscaled * factor,
    )


PRE_SHRUNK_FOLDERS = {"file_path": "images_", "mask_path": "masks_", "depth_file_path": "depths_"}
"""A frame's file key -> nerfstudio's folder prefix for its copies shrunk N times."""


def pre_shrunk(
    root: Path, frames: list[tuple[int, dict[str, Any]]], lenses: list[Lens], factor: int
) -> tuple[list[tuple[int, dict[str, Any]]], list[Lens]] | None:
    """The frames pointed at nerfstudio's pre-shrunk copies (``images_N/NAME`` for
    ``file_path``, ``masks_N/`` and ``depths_N/`` for masks and depths, N = ``factor``) and
    their lenses scaled to the copies' size; None (read the full-size photos and shrink them
    in memory) without an ``images_N/`` folder, or with a warning when it does not hold every
    file at 1/N of the size."""
    folder = root / f"images_{factor}"
    if factor == 1 or not folder.is_dir():
        return None
    found = _copies(root, frames, lenses, factor)
    if isinstance(found, str):
        warnings.warn(
            f"{folder} is not used ({found}); the full-size photos are shrunk instead",
            NeoWarning,
            stacklevel=3,
        )
        return None
    return found


def _copies(
    root: Path, frames: list[tuple[int, dict[str, Any]]], lenses: list[Lens], factor: int
) -> tuple[list[tuple[int, dict[str, Any]]], list[Lens]] | str:
    """:func:`pre_shrunk`'s frames and lenses, or why the copies cannot be used."""
    moved_frames, scaled = [], []
    taken: dict[str, int] = {}
    for (i, frame), lens in zip(frames, lenses, strict=True):
        moved = dict(frame)
        for key, prefix in PRE_SHRUNK_FOLDERS.items():
            if key in frame:
                copy = Path(f"{prefix}{factor}") / Path(frame[key]).name
                if not (root / copy).is_file():
                    return f"it has no {copy.as_posix()} (frame {i})"
                if taken.setdefault(copy.as_posix(), i) != i:  # cam0/1.png and cam1/1.png
                    return (
                        f"frames {taken[copy.as_posix()]} and {i} would both read {copy.as_posix()}"
                    )
                moved[key] = copy.as_posix()
        if "instance_path" in frame:
            return "the frames' instance images have no shrunk copies"
        w, h = image_size(root / moved["file_path"])
        if abs(w - lens.width / factor) >= 1 or abs(h - lens.height / factor) >= 1:
            return f"{moved['file_path']} is {w}x{h}, not 1/{factor} of {lens.width}x{lens.height}"
        sx, sy = w / lens.width, h / lens.height
        scaled.append(
            dataclasses.replace(
                lens, fx=lens.fx * sx, fy=lens.fy * sy, cx=lens.cx * sx, cy=lens.cy * sy,
                width=w, height=h,
            )
        )  # fmt: skip
        moved_frames.append((i, moved))
    return moved_frames, scaled

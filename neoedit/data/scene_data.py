"""In-memory form of a posed image dataset, whatever format it came from."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from neoedit.cameras import Cameras


@dataclass
class SceneData:
    """Posed images with optional metric depth and instance labels.

    All images share one size (H, W). Index arrays in ``split`` select frames.
    """

    root: Path
    file_paths: list[str]  # as written in the dataset file, relative to ``root``
    images: np.ndarray  # (N, H, W, 3) uint8, alpha already composited
    cameras: Cameras
    split: dict[str, np.ndarray]  # "train" / "test" -> frame indices
    depth_m: np.ndarray | None = None  # (N, H, W) float32 z-depth in metres, 0 = no data
    alpha: np.ndarray | None = (
        None  # (N, H, W) uint8 opacity from RGBA images (255 = object, 0 = background)
    )
    loss_mask: np.ndarray | None = None  # (N, H, W) bool, nerfstudio mask_path (True = use)
    instance_ids: np.ndarray | None = None  # (N, H, W) int32 instance id per pixel
    instance_names: dict[int, str] = field(default_factory=dict)  # id -> name
    objects: list[dict[str, Any]] = field(default_factory=list)  # objects.json entries
    background_rgb: tuple[float, float, float] | None = None  # in [0, 1]
    scene_aabb_m: np.ndarray | None = None  # (2, 3) min / max corner of the scene
    levelled: bool = False  # +z is a measured up: `neo import` levelled it (data.orient)
    downscaled: int = 1  # the images were shrunk by this factor at load (data.downscale)
    pre_shrunk: bool = False  # ...by reading nerfstudio's images_N/ copies, not the photos
    lens_note: str = "pinhole (no distortion)"  # the lenses as the dataset describes them

    def __len__(self) -> int:
        return len(self.file_paths)

    @property
    def height(self) -> int:
        return int(self.images.shape[1])

    @property
    def width(self) -> int:
        return int(self.images.shape[2])

    def indices(self, split: str) -> np.ndarray:
        if split == "all":
            return np.arange(len(self))
        return self.split[split]

    def camera_aabb_m(self) -> np.ndarray:
        """(2,3) bounds of the camera centres."""
        centres = self.cameras.camera_to_world[:, :3, 3]
        return np.stack([centres.min(0), centres.max(0)])

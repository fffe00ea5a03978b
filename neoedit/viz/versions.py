"""Pictures of scene versions side by side: the same cameras rendered through each version
(``neo diff``, a plan's strip, the assembly figure)."""

from __future__ import annotations

import numpy as np
import torch

from neoedit.cameras import Cameras
from neoedit.cameras.rays import CameraTensors
from neoedit.scene import Scene


def pick_views(scene: Scene, n: int, split: str = "test") -> np.ndarray:
    """``n`` scan camera indices spread over ``split`` (train when the scan has none)."""
    cameras, _, splits = scene.scan_cameras()
    pool = splits.get(split)
    if pool is None or len(pool) == 0:
        pool = splits.get("train", np.arange(len(cameras)))
    pool = np.asarray(pool)
    return pool[np.linspace(0, len(pool) - 1, min(n, len(pool))).round().astype(int)]


@torch.no_grad()
def render_rgb(scene: Scene, cameras: Cameras, index: int) -> np.ndarray:
    """uint8 RGB render of camera ``index`` of ``cameras`` through ``scene``."""
    cams = CameraTensors(cameras.subset([index]), scene.field.aabb.device)
    h, w = int(cameras.height[index]), int(cameras.width[index])
    rgb = scene.render_image(cams, 0, h, w)["rgb"].clamp(0, 1).cpu().numpy()
    return (rgb * 255).round().astype(np.uint8)


def render_versions(
    versions: list[Scene], views: np.ndarray, max_width: int = 240
) -> list[list[np.ndarray]]:
    """uint8 RGB renders, ``[view][version]``, of scan cameras ``views`` of the first
    version (every version of one scene shares its scan), at most ``max_width`` px wide."""
    cameras, _, _ = versions[0].scan_cameras()
    cameras = cameras.scaled(min(1.0, max_width / float(np.max(cameras.width))))
    return [[render_rgb(v, cameras, int(i)) for v in versions] for i in views]


def difference_image(a: np.ndarray, b: np.ndarray, scale: float = 4.0) -> np.ndarray:
    """|a - b| (uint8 RGB images), mean over channels, amplified ``scale`` x, as a heat map."""
    import matplotlib

    d = np.abs(a.astype(np.float32) - b.astype(np.float32)).mean(-1) / 255.0
    heat = matplotlib.colormaps["inferno"](np.clip(d * scale, 0, 1))[..., :3]
    return (heat * 255).round().astype(np.uint8)

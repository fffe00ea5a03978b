"""Pictures of 3-D boxes and relevancy: box wireframes over renders, relevancy heat maps."""

from __future__ import annotations

import cv2
import numpy as np

from neoedit.cameras import Cameras
from neoedit.geometry import OrientedBox

# the 12 edges of a box as pairs of corner indices (corner bits = x, y, z sign)
BOX_EDGES = [(a, b) for a in range(8) for b in range(a + 1, 8) if bin(a ^ b).count("1") == 1]


def draw_box(
    image: np.ndarray,
    cameras: Cameras,
    index: int,
    box: OrientedBox,
    color: tuple[int, int, int] = (255, 40, 40),
    thickness: int = 2,
) -> np.ndarray:
    """Copy of ``image`` (H,W,3) uint8 with the box's edges drawn (edges behind the camera
    are skipped)."""
    out = np.ascontiguousarray(image.copy())
    uv, depth = cameras.project(index, box.corners())
    for a, b in BOX_EDGES:
        if depth[a] <= 1e-3 or depth[b] <= 1e-3:
            continue
        pa = tuple(int(round(c)) for c in uv[a])
        pb = tuple(int(round(c)) for c in uv[b])
        cv2.line(out, pa, pb, color, thickness, cv2.LINE_AA)
    return out


def relevancy_overlay(
    rgb: np.ndarray,
    relevancy: np.ndarray,
    valid: np.ndarray,
    lo: float = 0.5,
    hi: float | None = None,
) -> np.ndarray:
    """Turbo colour map of relevancy (H,W) over a dimmed grey render where ``valid``; values
    at or below ``lo`` stay grey."""
    grey = rgb.mean(-1, keepdims=True).repeat(3, -1) * 0.6
    hi = float(relevancy[valid].max()) if hi is None and valid.any() else (hi or lo + 0.1)
    norm = np.clip((relevancy - lo) / max(hi - lo, 1e-6), 0.0, 1.0)
    import matplotlib  # lazy

    heat = matplotlib.colormaps["turbo"](norm)[..., :3] * 255
    show = valid & (relevancy > lo)
    alpha = (0.35 + 0.65 * norm)[..., None] * show[..., None]
    return (grey * (1 - alpha) + heat * alpha).round().clip(0, 255).astype(np.uint8)

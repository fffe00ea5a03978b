"""Scene bounds from the data itself: the visual hull of RGBA silhouettes.

A dataset with transparent backgrounds (the Blender synthetic convention, nerfstudio
captures with masks baked into alpha) says where the object is: a point that projects onto
a transparent pixel in any view is empty. Carving a coarse lattice by every view leaves the
visual hull, whose bounds are a far tighter scene box than a cube around the cameras (the
Blender scenes fill about +-1.5 of a +-4 camera cube: the cube spends two thirds of the
occupancy grid's and hash grid's resolution on nothing).
"""

from __future__ import annotations

import cv2
import numpy as np

from neoedit.cameras import Cameras


def alpha_hull_box(
    cameras: Cameras,
    alpha: np.ndarray,
    views: np.ndarray,
    search_box: np.ndarray,
    resolution: int = 64,
    max_views: int = 64,
    dilate_px: int = 3,
    min_kept: int = 8,
) -> np.ndarray | None:
    """(2,3) bounds of the visual hull of ``alpha`` (N,H,W uint8, 0 = background) over the
    frames ``views``, searched on a ``resolution``^3 lattice over ``search_box`` (2,3) and
    grown by one lattice cell; None when the silhouettes carve nothing away (opaque images)
    or leave fewer than ``min_kept`` lattice points (poses that disagree with the masks).

    A view carves the points it sees (in front of the camera, inside the image) on a pixel
    whose alpha is 0 even after dilating the silhouette by ``dilate_px`` pixels (tolerance
    for pose error and antialiased edges). A view whose silhouette stays clear of the image
    border holds the whole object, so it also carves every point outside its frame; a view
    cut by the border keeps what it does not see."""
    views = np.asarray(views)
    if len(views) == 0 or not (alpha[views] == 0).any():
        return None
    if len(views) > max_views:
        views = views[np.linspace(0, len(views) - 1, max_views).round().astype(int)]
    lo, hi = np.asarray(search_box, dtype=np.float64)
    axes = [lo[k] + (np.arange(resolution) + 0.5) / resolution * (hi[k] - lo[k]) for k in range(3)]
    points = np.stack(np.meshgrid(*axes, indexing="ij"), -1).reshape(-1, 3)
    keep = np.ones(len(points), dtype=bool)
    kernel = np.ones((2 * dilate_px + 1, 2 * dilate_px + 1), np.uint8)
    for i in views:
        silhouette = cv2.dilate((alpha[i] > 0).astype(np.uint8), kernel) > 0
        h, w = silhouette.shape
        uv, depth = cameras.project(int(i), points)
        uv = np.where(np.isfinite(uv) & (depth[:, None] > 0), np.floor(uv), -1.0)
        u, v = uv[:, 0].astype(np.int64), uv[:, 1].astype(np.int64)
        seen = (u >= 0) & (u < w) & (v >= 0) & (v < h)
        border = silhouette[0].any() or silhouette[-1].any()
        border = border or silhouette[:, 0].any() or silhouette[:, -1].any()
        carved = np.zeros_like(keep) if border else ~seen
        carved[seen] = ~silhouette[v[seen], u[seen]]
        keep &= ~carved
    if keep.sum() < min_kept or keep.all():
        return None
    cell = (hi - lo) / resolution
    kept = points[keep]
    return np.stack([np.maximum(kept.min(0) - cell, lo), np.minimum(kept.max(0) + cell, hi)])

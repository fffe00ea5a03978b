"""Sparse depth from structure-from-motion: each photo's z-depth at the pixels where its
sparse points project, a depth prior for training on captures without a depth sensor
(as DS-NeRF and nerfstudio's ``--use-sfm-depth`` do).

A real capture trained on colour alone learns a plain floor as a bowl and a can as haze
(benchmarks/RESULTS.md, issue 16): the sparse points COLMAP triangulated from the same
photos pin the surfaces where they really are. Only points a photo itself observes are
written into its depth image (no occlusion test needed); pixels without a point are 0
("no depth"), the convention of nerfstudio's depth images and of
:class:`~neoedit.data.scene_data.SceneData`.
"""

from __future__ import annotations

import numpy as np
import torch

MAX_PNG = 65535
SPARSE_DEPTH_FRACTION = 0.05
"""Depth on fewer pixels than this is sparse (structure-from-motion points), not a sensor's."""


def project_points(
    points: np.ndarray, camera_to_world: np.ndarray, k: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Pixel coordinates (P,2) (u right, v down, pixel centres at +0.5) and z-depth (P,) of
    world points (P,3) in a pinhole camera (OpenGL camera-to-world (4,4), K (3,3))."""
    rot, centre = camera_to_world[:3, :3], camera_to_world[:3, 3]
    cam = (points - centre) @ rot  # OpenGL camera axes: x right, y up, z back
    z = -cam[:, 2]
    safe = np.where(z > 1e-9, z, np.inf)
    u = k[0, 0] * cam[:, 0] / safe + k[0, 2]
    v = -k[1, 1] * cam[:, 1] / safe + k[1, 2]
    return np.stack([u, v], 1), z


def sparse_depth_image(
    points: np.ndarray, camera_to_world: np.ndarray, k: np.ndarray, size: tuple[int, int]
) -> np.ndarray:
    """(H,W) float32 z-depth image [scene units] of the points (P,3) the photo observes; 0
    where no point lands; the nearest point where several share a pixel."""
    w, h = size
    depth = np.zeros((h, w), np.float32)
    if not len(points):
        return depth
    uv, z = project_points(points, camera_to_world, k)
    col, row = np.floor(uv[:, 0]).astype(np.int64), np.floor(uv[:, 1]).astype(np.int64)
    ok = (z > 0) & (col >= 0) & (col < w) & (row >= 0) & (row < h)
    col, row, z = col[ok], row[ok], z[ok]
    order = np.argsort(-z)  # far first, so the nearest point is written last
    depth[row[order], col[order]] = z[order]
    return depth


def observed_points(
    points: np.ndarray, tracks: list[np.ndarray], photos: int, min_track: int
) -> list[np.ndarray]:
    """Per photo, the indices of the points (with at least ``min_track`` observers) it sees."""
    seen: list[list[int]] = [[] for _ in range(photos)]
    for i, track in enumerate(tracks):
        observers = np.unique(track)
        if len(observers) >= min_track:
            for j in observers:
                seen[int(j)].append(i)
    return [np.asarray(s, np.int64) for s in seen]


def depth_unit(max_depth: float) -> float:
    """The uint16 PNG unit [scene units per count]: millimetres (nerfstudio's default
    ``depth_unit_scale_factor``, so its depth methods read the images as written) unless
    ``max_depth`` needs a coarser power of ten."""
    exponent = int(np.ceil(np.log10(max(max_depth, 1e-6) / MAX_PNG)))
    return float(10.0 ** min(max(exponent, -3), 3))


def to_png(depth: np.ndarray, unit: float) -> np.ndarray:
    """(H,W) uint16 counts of ``unit``; 0 stays 0 (no depth), values below one count become 1."""
    counts = np.round(depth / unit)
    counts = np.where(depth > 0, np.clip(counts, 1, MAX_PNG), 0)
    return counts.astype(np.uint16)


def sparse_pixels(depth: torch.Tensor, mask: torch.Tensor | None = None) -> torch.Tensor | None:
    """(K,3) image index, row, column of the pixels of ``depth`` (N,H,W) that have a depth
    (and pass ``mask``), when they are sparse; None when the depth is dense or empty."""
    valid = depth > 0
    if mask is not None:
        valid &= mask.bool()
    if not valid.any() or float(valid.float().mean()) >= SPARSE_DEPTH_FRACTION:
        return None
    return valid.nonzero()

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

from pathlib import Path

import numpy as np
import torch

from neoedit.cameras.cameras import Cameras
from neoedit.errors import DataError

MAX_PNG = 65535
SPARSE_DEPTH_FRACTION = 0.05
"""Depth on fewer pixels than this is sparse (structure-from-motion points), not a sensor's."""


def sparse_depth_image(
    points: np.ndarray,
    camera_to_world: np.ndarray,
    k: np.ndarray,
    size: tuple[int, int],
    min_depth: float = 1e-9,
) -> np.ndarray:
    """(H,W) float32 z-depth image [scene units] of the points (P,3) the photo observes; 0
    where no point lands (or only points nearer than ``min_depth``); the nearest point
    where several share a pixel."""
    w, h = size
    depth = np.full((h, w), np.inf, np.float32)
    if len(points):
        camera = Cameras.shared(camera_to_world[None], k[0, 0], k[1, 1], k[0, 2], k[1, 2], w, h)
        uv, z = camera.project(0, points)
        col, row = np.floor(uv[:, 0]), np.floor(uv[:, 1])
        ok = (z > max(min_depth, 1e-9)) & (col >= 0) & (col < w) & (row >= 0) & (row < h)
        rows, cols = row[ok].astype(np.int64), col[ok].astype(np.int64)
        np.minimum.at(depth, (rows, cols), z[ok].astype(np.float32))
    return np.where(np.isfinite(depth), depth, 0.0).astype(np.float32)


def observed_points(tracks: list[np.ndarray], photos: int, min_track: int) -> list[np.ndarray]:
    """Per photo, the indices of the points (with at least ``min_track`` observers) it sees."""
    seen: list[list[int]] = [[] for _ in range(photos)]
    for i, track in enumerate(tracks):
        observers = np.unique(track)
        if len(observers) >= min_track:
            for j in observers:
                seen[int(j)].append(i)
    return [np.asarray(s, np.int64) for s in seen]


class SparseDepthWriter:
    """Writes each photo's sparse depth PNG from points (P,3) already in the dataset's frame,
    and counts what it wrote. Kept: points inside ``box`` (2,3) (the field cannot put a
    surface beyond it), with a reprojection error up to ``max_error_px`` (when ``errors``
    are known) and at least ``min_track`` observers; per photo, those farther than
    ``min_depth`` (the trainer's near plane)."""

    def __init__(
        self,
        points: np.ndarray,
        tracks: list[np.ndarray],
        centres: np.ndarray,
        box: np.ndarray,
        errors: np.ndarray | None = None,
        min_track: int = 3,
        max_error_px: float = 2.0,
        min_depth: float = 0.0,
    ):
        keep = np.all((points >= box[0]) & (points <= box[1]), axis=1)
        if errors is not None:
            keep &= errors <= max_error_px
        self.points = points[keep]
        self.seen = observed_points(
            [t for t, k in zip(tracks, keep, strict=True) if k], len(centres), min_track
        )
        self.min_depth = min_depth
        reach = max(
            (
                float(np.linalg.norm(self.points[s] - c, axis=1).max())
                for s, c in zip(self.seen, centres, strict=True)
                if len(s)
            ),
            default=1.0,
        )
        self.unit = depth_unit(reach)
        self.pixels: list[int] = []

    def write(
        self, folder: Path, rel: str, j: int, c2w: np.ndarray, k: np.ndarray, size: tuple[int, int]
    ) -> None:
        """Write photo ``j``'s depth image (``size`` = (w, h)) to ``folder / rel``."""
        import cv2

        depth = sparse_depth_image(self.points[self.seen[j]], c2w, k, size, self.min_depth)
        self.pixels.append(int((depth > 0).sum()))
        (folder / rel).parent.mkdir(parents=True, exist_ok=True)
        if not cv2.imwrite(str(folder / rel), to_png(depth, self.unit)):
            raise DataError(f"cannot write {folder / rel}")

    def summary(self) -> dict:
        used = np.unique(np.concatenate(self.seen)) if self.seen else np.zeros(0)
        return {
            "points": int(len(used)),
            "pixels_per_photo_median": int(np.median(self.pixels)) if self.pixels else 0,
            "unit_m": self.unit,
        }


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


def is_sparse(depth: np.ndarray | torch.Tensor) -> bool:
    """Depth (N,H,W) on fewer than SPARSE_DEPTH_FRACTION of the pixels (and on some)."""
    count = int((depth > 0).sum())
    total = depth.numel() if isinstance(depth, torch.Tensor) else depth.size
    return 0 < count < SPARSE_DEPTH_FRACTION * total


def sparse_pixels(
    depth: torch.Tensor, mask: torch.Tensor | None = None
) -> tuple[torch.Tensor, torch.Tensor]:
    """(K,3) image index, row, column and (K,) depth of the pixels of ``depth`` (N,H,W) that
    have one (and pass ``mask``)."""
    valid = depth > 0
    if mask is not None:
        valid &= mask.bool()
    where = valid.nonzero()
    return where, depth[where[:, 0], where[:, 1], where[:, 2]]

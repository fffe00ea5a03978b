"""Contact sheets: many views of a scan in one picture."""

from __future__ import annotations

import math
from pathlib import Path

import cv2
import numpy as np

from neoedit.utils.io import write_png


def tile_images(
    images: list[np.ndarray],
    cols: int | None = None,
    labels: list[str] | None = None,
    pad_px: int = 2,
) -> np.ndarray:
    """Tile (H,W,3) uint8 images into one grid image (white padding, optional labels)."""
    if not images:
        raise ValueError("no images to tile")
    h, w = images[0].shape[:2]
    cols = cols or math.ceil(math.sqrt(len(images) * h / w))
    rows = math.ceil(len(images) / cols)
    sheet = np.full((rows * (h + pad_px) + pad_px, cols * (w + pad_px) + pad_px, 3), 255, np.uint8)
    scale = max(0.4, w / 250)  # labels readable at 240 px tiles and up
    for k, img in enumerate(images):
        r, c = divmod(k, cols)
        y, x = pad_px + r * (h + pad_px), pad_px + c * (w + pad_px)
        tile = np.ascontiguousarray(img[..., :3])
        if labels is not None:
            for colour, thickness in (((0, 0, 0), 2), ((255, 255, 255), 1)):  # outlined text
                org = (3, int(14 * scale) + 2)
                cv2.putText(
                    tile,
                    labels[k],
                    org,
                    cv2.FONT_HERSHEY_SIMPLEX,
                    0.45 * scale,
                    colour,
                    thickness,
                    cv2.LINE_AA,
                )
        sheet[y : y + h, x : x + w] = tile
    return sheet


def write_contact_sheet(
    path: Path, images: list[np.ndarray], labels: list[str], max_views: int = 24
) -> None:
    """Write a grid of at most ``max_views`` evenly chosen views."""
    idx = np.unique(
        np.linspace(0, len(images) - 1, min(max_views, len(images))).round().astype(int)
    )
    write_png(path, tile_images([images[i] for i in idx], labels=[labels[i] for i in idx]))

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
        tile = np.array(img[..., :3], dtype=np.uint8)  # a copy: the label never marks the input
        if labels is not None:
            _label(tile, labels[k], scale)
        sheet[y : y + h, x : x + w] = tile
    return sheet


def _label(tile: np.ndarray, text: str, scale: float) -> None:
    """White text on a dark band in the tile's top-left corner (readable on any render)."""
    font, size = cv2.FONT_HERSHEY_SIMPLEX, 0.45 * scale
    (tw, th), base = cv2.getTextSize(text, font, size, 1)
    pad = max(2, int(3 * scale))
    y1, x1 = min(th + base + 2 * pad, tile.shape[0]), min(tw + 2 * pad, tile.shape[1])
    tile[:y1, :x1] = (tile[:y1, :x1] * 0.35).astype(np.uint8)
    cv2.putText(tile, text, (pad, pad + th), font, size, (255, 255, 255), 1, cv2.LINE_AA)


def write_contact_sheet(
    path: Path, images: list[np.ndarray], labels: list[str], max_views: int = 24
) -> None:
    """Write a grid of at most ``max_views`` evenly chosen views."""
    idx = np.unique(
        np.linspace(0, len(images) - 1, min(max_views, len(images))).round().astype(int)
    )
    write_png(path, tile_images([images[i] for i in idx], labels=[labels[i] for i in idx]))

"""Image, depth and label file readers shared by the parsers."""

from __future__ import annotations

from pathlib import Path

import imageio.v3 as iio
import numpy as np

from neoedit.errors import DataError


def _read(path: Path, what: str) -> np.ndarray:
    try:
        found = path.is_file()
    except OSError as e:
        raise DataError(f"cannot read {what} {path}: {e.strerror or e}") from None
    if not found:
        raise DataError(f"{what} not found: {path}")
    try:
        return np.asarray(iio.imread(path))
    except Exception as e:  # imageio raises many types for corrupt files
        raise DataError(f"cannot read {what} {path}: {e}") from e


def read_rgba(
    path: Path, background_rgb: tuple[float, float, float]
) -> tuple[np.ndarray, np.ndarray | None]:
    """(H, W, 3) uint8 composited over ``background_rgb`` (in [0,1]) and the alpha (H, W) uint8
    (None when the image has no alpha channel)."""
    img = _read(path, "image")
    alpha = (
        img[..., 3].copy()
        if img.ndim == 3 and img.shape[-1] == 4 and img.dtype == np.uint8
        else None
    )
    return read_rgb(path, background_rgb, img), alpha


def read_rgb(
    path: Path, background_rgb: tuple[float, float, float], img: np.ndarray | None = None
) -> np.ndarray:
    """(H, W, 3) uint8; an alpha channel is composited over ``background_rgb`` (in [0,1])."""
    img = _read(path, "image") if img is None else img
    if img.ndim == 2:
        img = np.repeat(img[..., None], 3, axis=-1)
    if img.dtype == np.uint16:
        img = (img / 257.0).round().astype(np.uint8)
    if img.dtype != np.uint8:
        raise DataError(f"image {path}: unsupported pixel type {img.dtype}")
    if img.shape[-1] == 4:
        alpha = img[..., 3:4].astype(np.float32) / 255.0
        bg = np.asarray(background_rgb, np.float32) * 255.0
        img = (
            (img[..., :3].astype(np.float32) * alpha + bg * (1.0 - alpha)).round().astype(np.uint8)
        )
    return img[..., :3]


def read_depth_m(path: Path, unit_scale_m: float) -> np.ndarray:
    """(H, W) float32 metres; ``.npy`` files are read as metres, images are scaled by ``unit_scale_m``."""
    if path.suffix == ".npy":
        if not path.is_file():
            raise DataError(f"depth not found: {path}")
        try:
            raw = np.load(path, allow_pickle=False)
        except (OSError, ValueError, EOFError) as e:  # pickled objects, truncated files
            raise DataError(f"cannot read depth {path}: {e}") from None
        if not isinstance(raw, np.ndarray) or raw.dtype.kind not in "biuf":
            raise DataError(f"depth {path}: expected a numeric array of metres, got {raw.dtype}")
        depth = raw.astype(np.float32)
    else:
        depth = _read(path, "depth").astype(np.float32) * unit_scale_m
    if depth.ndim == 3:
        depth = depth[..., 0]
    if depth.ndim != 2:
        raise DataError(f"depth {path}: expected an (H, W) image, got shape {depth.shape}")
    return np.where(np.isfinite(depth), depth, 0.0).astype(np.float32)  # no value = no depth


def read_label(path: Path, what: str) -> np.ndarray:
    """(H, W) integer label image (first channel if several)."""
    lab = _read(path, what)
    if lab.ndim == 3:
        lab = lab[..., 0]
    return lab.astype(np.int32)

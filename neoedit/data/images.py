"""Image, depth and label file readers shared by the parsers, and :func:`read_frame`: one
nerfstudio frame's images, undistorted to its pinhole camera where its lens distorts."""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import imageio.v3 as iio
import numpy as np

from neoedit.data.undistort import Lens, Undistorter
from neoedit.errors import DataError


def _read_check(path: Path, what: str) -> None:
    try:
        found = path.is_file()
    except OSError as e:
        raise DataError(f"cannot read {what} {path}: {e.strerror or e}") from None
    if not found:
        raise DataError(f"{what} not found: {path}")


def _read(path: Path, what: str) -> np.ndarray:
    _read_check(path, what)
    try:
        return np.asarray(iio.imread(path))
    except Exception as e:  # imageio raises many types for corrupt files
        raise DataError(f"cannot read {what} {path}: {e}") from e


def read_image(path: Path, what: str = "image") -> np.ndarray:
    """The decoded pixels of an image file, as stored (a :class:`DataError` if unreadable)."""
    return _read(path, what)


def image_size(path: Path) -> tuple[int, int]:
    """(width, height) of an image file, from its header where the format allows."""
    _read_check(path, "image")
    try:
        shape = iio.improps(path).shape
    except Exception as e:  # imageio raises many types for corrupt files
        raise DataError(f"cannot read image {path}: {e}") from e
    if len(shape) < 2:
        raise DataError(f"image {path}: expected a 2D image, got shape {shape}")
    return int(shape[1]), int(shape[0])


def read_rgba(
    path: Path, background_rgb: tuple[float, float, float]
) -> tuple[np.ndarray, np.ndarray | None]:
    """(H, W, 3) uint8 composited over ``background_rgb`` (in [0,1]) and the alpha (H, W) uint8
    (None when the image has no alpha channel)."""
    return split_rgba(_read(path, "image"), path, background_rgb)


def split_rgba(
    img: np.ndarray, path: Path, background_rgb: tuple[float, float, float]
) -> tuple[np.ndarray, np.ndarray | None]:
    """:func:`read_rgba` of pixels already read from ``path`` (named in errors)."""
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
            why = "it holds Python objects, which are never loaded" if "pickle" in str(e) else e
            raise DataError(f"cannot read depth {path}: {why}") from None
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


@dataclass
class FrameImages:
    """One frame as loaded: its pinhole camera and its (undistorted) images."""

    pinhole: tuple[float, float, float, float, int, int]
    """(fx, fy, cx, cy, w, h) of the images below."""
    image: np.ndarray
    alpha: np.ndarray | None
    depth_m: np.ndarray | None
    mask: np.ndarray | None
    label: np.ndarray | None
    valid: np.ndarray | None
    """(H, W) bool: the pixels the undistortion could fill (None: all of them)."""


def read_frame(
    root: Path,
    frame: Mapping[str, Any],
    lens: Lens,
    background_rgb: tuple[float, float, float],
    depth_unit_m: float,
    undistorter: Undistorter,
    where: str,
) -> FrameImages:
    """A frame's photo (``file_path``) and optional ``depth_file_path``, ``mask_path`` and
    ``instance_path`` images, all of the lens's size; a distorted lens's photo is undistorted
    (bilinear, cached) and the others remapped alike (nearest neighbour)."""
    photo = root / frame["file_path"]
    w, h = lens.width, lens.height
    rect = undistorter.rectification(lens, where) if lens.distorted else None
    cached = undistorter.cached(photo, lens) if rect is not None else None
    raw = read_image(photo) if cached is None else cached
    if raw.shape[:2] != (h, w):
        raise DataError(f"{where}: image is {raw.shape[1]}x{raw.shape[0]} but w,h say {w}x{h}")
    if rect is not None and cached is None:
        raw = rect.remap(raw)
    image, alpha = split_rgba(raw, photo, background_rgb)  # refuses pixel types we cannot use
    if rect is not None and cached is None:
        undistorter.store(photo, lens, raw)

    def extra(key: str, read: Callable[[Path], np.ndarray]) -> np.ndarray | None:
        if key not in frame:
            return None
        img = read(root / frame[key])
        if img.shape[:2] != (h, w):
            raise DataError(
                f"{where}: a depth, mask or instance image is {img.shape[1]}x{img.shape[0]}, "
                f"the frame {w}x{h}"
            )
        return img if rect is None else rect.remap_nearest(img)

    mask = extra("mask_path", lambda p: read_label(p, "mask"))
    k = (lens.fx, lens.fy, lens.cx, lens.cy) if rect is None else rect.pinhole
    return FrameImages(
        pinhole=(*k, w, h),
        image=image,
        alpha=alpha,
        depth_m=extra("depth_file_path", lambda p: read_depth_m(p, depth_unit_m)),
        mask=None if mask is None else mask > 0,
        label=extra("instance_path", lambda p: read_label(p, "instance image")),
        valid=None if rect is None or rect.valid.all() else rect.valid,
    )

"""Read an LLFF capture (``poses_bounds.npy`` + ``images``) into a :class:`Capture`.

``poses_bounds.npy`` holds one row of 17 numbers per image, in sorted image-name order: a
3x5 matrix [R | t | (h, w, f)] flattened row by row, whose rotation columns are the camera's
(down, right, back) axes in the world, then the near and far depth bounds. The focal length
is for an image of h x w pixels; photos of another size (``images_4`` etc.) scale it.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from neoedit.data.capture import Capture, Lens, read_photo
from neoedit.data.colmap import IMAGE_SUFFIXES
from neoedit.errors import DataError


def _image_size(path: Path) -> tuple[int, int]:
    image = read_photo(path, grey=True)
    return int(image.shape[1]), int(image.shape[0])


def _default_images(root: Path) -> Path:
    """``images/``, else the largest of LLFF's downscaled ``images_N/`` folders (the poses'
    focal length is scaled to the image size, so any of them pairs with the poses)."""
    full = root / "images"
    if full.is_dir():
        return full
    scaled = sorted(
        (int(p.name[7:]), p)
        for p in root.glob("images_*")
        if p.is_dir() and p.name[7:].isdigit() and int(p.name[7:]) > 0
    )
    return scaled[0][1] if scaled else full


def read_llff(src: Path, images: Path | None = None) -> Capture:
    """The capture described by ``src/poses_bounds.npy`` (or that file itself)."""
    src = Path(src)
    path = src if src.is_file() else src / "poses_bounds.npy"
    if not path.is_file():
        raise DataError(f"{src}: no poses_bounds.npy found")
    try:
        table = np.load(path, allow_pickle=False)
    except (OSError, ValueError) as e:
        why = "it holds Python objects, which are never loaded" if "pickle" in str(e) else e
        raise DataError(f"{path}: not a readable .npy array of numbers ({why})") from None
    if table.ndim != 2 or table.shape[1] != 17 or len(table) < 2:
        raise DataError(f"{path}: expected an (N, 17) array with N >= 2, got {table.shape}")
    if not np.all(np.isfinite(table)):
        raise DataError(f"{path}: holds non-finite numbers")
    image_dir = Path(images) if images is not None else _default_images(path.parent)
    if not image_dir.is_dir():
        raise DataError(f"image folder not found: {image_dir} (name it with --images)")
    names = sorted(p.name for p in image_dir.iterdir() if p.suffix in IMAGE_SUFFIXES)
    if len(names) != len(table):
        raise DataError(
            f"{path}: {len(table)} poses but {len(names)} images in {image_dir}; LLFF pairs "
            "them in sorted name order, so the counts must match"
        )
    mats = table[:, :15].reshape(-1, 3, 5)
    h, w, f = mats[0, :, 4]
    if h <= 0 or w <= 0 or f <= 0:
        raise DataError(f"{path}: bad (h, w, focal) = ({h:g}, {w:g}, {f:g})")
    width, height = _image_size(image_dir / names[0])
    if abs(width / height - w / h) > 0.01:
        raise DataError(
            f"{path}: poses are for {w:g}x{h:g} images but {names[0]} is {width}x{height}"
        )
    focal = f * width / w
    down, right, back, t = mats[:, :, 0], mats[:, :, 1], mats[:, :, 2], mats[:, :, 3]
    c2w = np.tile(np.eye(4), (len(table), 1, 1))
    c2w[:, :3, 0], c2w[:, :3, 1], c2w[:, :3, 2], c2w[:, :3, 3] = right, -down, back, t
    rot = c2w[:, :3, :3]
    if np.abs(rot.transpose(0, 2, 1) @ rot - np.eye(3)).max() > 1e-3:
        raise DataError(f"{path}: the rotation parts are not orthonormal")
    lens = Lens("PINHOLE", np.array([focal, focal, width / 2, height / 2]), width, height)
    bounds = table[:, 15:17]
    if np.any(bounds <= 0) or np.any(bounds[:, 1] <= bounds[:, 0]):
        raise DataError(f"{path}: near/far bounds must satisfy 0 < near < far")
    return Capture(
        source=path,
        names=names,
        image_dir=image_dir,
        camera_to_world=c2w,
        lenses=[lens] * len(names),
        bounds=bounds,
    )

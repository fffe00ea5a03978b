"""Object masks for an edit: a folder of 2-D masks (SAM's, a dataset's labels) matched to
the photos of a scan by file name."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from neoedit.cameras import Cameras
from neoedit.data.images import read_label
from neoedit.errors import DataError

MASK_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff")


def read_object_masks(
    folder: Path, file_paths: list[str], cameras: Cameras
) -> dict[int, np.ndarray]:
    """Camera index -> (H, W) bool mask (the object: values over 127, or 1 in a 0/1 mask)
    for every mask in
    ``folder`` whose name (without suffix) is that of a scan photo in ``file_paths``. A mask
    must have its photo's size; photos without a mask are simply not used."""
    folder = Path(folder)
    if not folder.is_dir():
        raise DataError(f"--masks {folder}: not a folder")
    by_stem = {Path(p).stem: i for i, p in enumerate(file_paths)}
    if len(by_stem) != len(file_paths):
        raise DataError(
            f"--masks {folder}: two photos of the scan share a name in different folders; "
            "masks cannot be matched to them by name"
        )
    masks: dict[int, np.ndarray] = {}
    for path in sorted(folder.iterdir()):
        if path.suffix.lower() not in MASK_SUFFIXES or path.stem not in by_stem:
            continue
        i = by_stem[path.stem]
        label = read_label(path, "mask")
        # half the type's range: JPEG noise around 0 is not the object
        mask = label > (127 if label.max() > 1 else 0)
        h, w = int(cameras.height[i]), int(cameras.width[i])
        if mask.shape != (h, w):
            raise DataError(
                f"{path}: the mask is {mask.shape[1]}x{mask.shape[0]}, its photo "
                f"{file_paths[i]} is {w}x{h} in the scan"
            )
        masks[i] = mask
    if not masks:
        raise DataError(
            f"--masks {folder}: no mask is named after a photo of the scan (e.g. "
            f"{Path(file_paths[0]).stem}.png)"
        )
    return masks

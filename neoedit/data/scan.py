"""The scan's cameras as a scene keeps them: poses, intrinsics, image sizes, file names and
splits, so a version renders and edits without its dataset folder."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from neoedit.cameras import Cameras
from neoedit.cameras.pose_correction import corrected_poses
from neoedit.data.load import load_scene_data
from neoedit.data.nerfstudio import load_cameras
from neoedit.errors import NeoError

ScanCameras = tuple[Cameras, list[str], dict[str, np.ndarray]]
"""(cameras, file paths, split name -> camera indices)."""


def dataset_cameras(data_path: Path) -> ScanCameras:
    """Cameras of a dataset (images are not read for nerfstudio data)."""
    if (Path(data_path) / "transforms.json").is_file():
        return load_cameras(Path(data_path))
    data = load_scene_data(Path(data_path))
    return data.cameras, data.file_paths, data.split


def scan_record(cameras: Cameras, file_paths: list[str], split: dict[str, Any]) -> dict[str, Any]:
    """JSON-able record of a scan's cameras (stored in scene.json)."""
    return {
        "cameras": cameras.to_record(),
        "file_paths": list(file_paths),
        "split": {k: np.asarray(v).astype(int).tolist() for k, v in split.items()},
    }


def scan_from_record(record: dict[str, Any], corrected: bool = True) -> ScanCameras:
    """The scan's cameras; with the pose corrections its training learnt applied
    (``pose_corrections``, :mod:`neoedit.training.camera_opt`) unless ``corrected`` is False
    (the poses as the dataset gives them)."""
    try:
        cameras = Cameras.from_record(record["cameras"])
        split = {k: np.asarray(v, dtype=np.int64) for k, v in record["split"].items()}
        fixes = record.get("pose_corrections")
        if corrected and fixes is not None:
            fixes = np.asarray(fixes, dtype=np.float64)
            if fixes.shape != (len(cameras), 6) or not np.isfinite(fixes).all():
                raise ValueError(f"pose_corrections must be {len(cameras)} finite 6-vectors")
            cameras.camera_to_world = corrected_poses(cameras.camera_to_world, fixes)
        return cameras, list(record["file_paths"]), split
    except (KeyError, TypeError, ValueError) as e:
        raise NeoError(f"malformed scan cameras in scene.json: {e}") from None

"""Parser for the Blender synthetic format (NeRF paper): ``transforms_{train,val,test}.json``.

Each file has ``camera_angle_x`` and frames with ``file_path`` (no extension: ``.png`` is
added) and ``transform_matrix`` (camera-to-world, OpenGL). Images are RGBA and are
composited over the background colour (white by default).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from neoedit.cameras import Cameras
from neoedit.cameras.cameras import validate_pose
from neoedit.data.images import read_rgba
from neoedit.data.nerfstudio import read_json
from neoedit.data.scene_data import SceneData
from neoedit.data.validate import check_rotation
from neoedit.errors import DataError

SPLITS = ("train", "val", "test")


def load_blender(
    root: Path, background_rgb: tuple[float, float, float] = (1.0, 1.0, 1.0)
) -> SceneData:
    root = Path(root)
    file_paths: list[str] = []
    images, alphas, poses, focal = [], [], [], []
    split: dict[str, list[int]] = {}
    for name in SPLITS:
        tf = root / f"transforms_{name}.json"
        if not tf.is_file():
            if name == "train":
                raise DataError(f"{tf} not found (Blender format needs transforms_train.json)")
            continue
        meta = read_json(tf)
        angle = meta.get("camera_angle_x") if isinstance(meta, dict) else None
        if not isinstance(angle, (int, float)) or not 0 < angle < np.pi:
            raise DataError(f"{tf}: 'camera_angle_x' must be a number in (0, pi), got {angle!r}")
        frames = meta.get("frames")
        if not isinstance(frames, list) or not frames:
            raise DataError(f"{tf}: needs a non-empty 'frames' list")
        split[name] = []
        for i, frame in enumerate(frames):
            where = f"{tf} frame {i}"
            if not isinstance(frame, dict) or not {"file_path", "transform_matrix"} <= frame.keys():
                raise DataError(f"{where}: needs 'file_path' and 'transform_matrix'")
            if not isinstance(frame["file_path"], str) or not frame["file_path"].strip():
                raise DataError(f"{where}: 'file_path' must be a non-empty path")
            rel = frame["file_path"]
            if not Path(rel).suffix:
                rel += ".png"
            img, alpha = read_rgba(root / rel, background_rgb)
            alphas.append(np.full(img.shape[:2], 255, np.uint8) if alpha is None else alpha)
            poses.append(validate_pose(frame["transform_matrix"], where))
            check_rotation(poses[-1], where)
            focal.append(0.5 * img.shape[1] / np.tan(0.5 * angle))
            split[name].append(len(file_paths))
            file_paths.append(rel)
            images.append(img)
    if len({im.shape for im in images}) != 1:
        raise DataError(f"{root}: all images must share one size")
    h, w = images[0].shape[:2]
    f = np.asarray(focal)
    cameras = Cameras(
        np.stack(poses),
        f,
        f,
        np.full(len(f), w / 2.0),
        np.full(len(f), h / 2.0),
        np.full(len(f), w),
        np.full(len(f), h),
    )
    split_idx = {k: np.asarray(v, dtype=np.int64) for k, v in split.items()}
    if "test" not in split_idx:
        split_idx["test"] = split_idx.get("val", np.empty(0, np.int64))
    return SceneData(
        root=root,
        file_paths=file_paths,
        images=np.stack(images),
        cameras=cameras,
        split=split_idx,
        alpha=np.stack(alphas),
        background_rgb=background_rgb,
    )

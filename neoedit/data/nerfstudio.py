"""Parser for nerfstudio ``transforms.json`` datasets.

Supported keys: global or per-frame ``fl_x, fl_y, cx, cy, w, h``; per frame ``file_path``,
``transform_matrix`` (camera-to-world, OpenGL), optional ``depth_file_path`` (uint16 PNG in
``depth_unit_scale_factor`` metres, default 1e-3, or ``.npy`` in metres), ``mask_path``
(nerfstudio loss mask, non-zero = use) and ``instance_path`` (neoedit: per-pixel instance
id image, names in ``objects.json`` beside the transforms file). Splits come from
``train_filenames`` / ``val_filenames`` / ``test_filenames``; without them every 8th frame
is held out. neoedit extensions: ``background_color`` (RGB in [0,1]) and ``scene_aabb``
(``[[xmin,ymin,zmin],[xmax,ymax,zmax]]`` in metres).
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np

from neoedit.cameras import Cameras
from neoedit.cameras.cameras import validate_pose
from neoedit.data.images import read_depth_m, read_label, read_rgba
from neoedit.data.scene_data import SceneData
from neoedit.data.validate import (
    MAX_COORD_M,
    check_camera_model,
    check_intrinsics,
    check_rotation,
)
from neoedit.errors import DataError

INTRINSIC_KEYS = ("fl_x", "fl_y", "cx", "cy", "w", "h")
DISTORTION_KEYS = ("k1", "k2", "k3", "k4", "p1", "p2")
HOLDOUT_EVERY = 8


def read_json(path: Path) -> Any:
    if not path.is_file():
        raise DataError(f"file not found: {path}")
    try:
        return json.loads(path.read_text())
    except OSError as e:
        raise DataError(f"cannot read {path}: {e.strerror or e}") from None
    except (ValueError, RecursionError) as e:  # JSONDecodeError, UnicodeDecodeError
        raise DataError(f"{path} is not valid JSON: {e}") from None


def _number(d: dict[str, Any], key: str, where: str) -> float:
    value = d.get(key)
    if not isinstance(value, (int, float)) or isinstance(value, bool) or not np.isfinite(value):
        raise DataError(f"{where}: '{key}' must be a finite number, got {value!r}")
    return float(value)


def _intrinsics(meta: dict[str, Any], frame: dict[str, Any], where: str) -> list[float]:
    values = []
    for key in INTRINSIC_KEYS:
        source = frame if key in frame else meta
        if key not in source:
            raise DataError(f"{where}: missing intrinsic '{key}' (neither in the frame nor global)")
        values.append(_number(source, key, where))
    for key in DISTORTION_KEYS:
        source = frame if key in frame else meta
        if key in source and abs(_number(source, key, where)) > 1e-12:
            raise DataError(
                f"{where}: lens distortion ('{key}') is not supported; undistort the images first"
            )
    check_intrinsics(values, where)
    return values


def _split_indices(
    meta: dict[str, Any], file_paths: list[str], path: Path
) -> dict[str, np.ndarray]:
    n = len(file_paths)
    norm = {Path(p).as_posix().removeprefix("./"): i for i, p in enumerate(file_paths)}
    split: dict[str, np.ndarray] = {}
    for name, key in (
        ("train", "train_filenames"),
        ("val", "val_filenames"),
        ("test", "test_filenames"),
    ):
        if key not in meta:
            continue
        if not isinstance(meta[key], list) or not all(isinstance(f, str) for f in meta[key]):
            raise DataError(f"{path}: '{key}' must be a list of file paths")
        idx = []
        for f in meta[key]:
            k = Path(f).as_posix().removeprefix("./")
            if k not in norm:
                raise DataError(f"{path}: '{key}' lists {f!r}, which is not a frame's file_path")
            idx.append(norm[k])
        split[name] = np.asarray(sorted(idx), dtype=np.int64)
    if "train" not in split:
        held = np.arange(0, n, HOLDOUT_EVERY) if n >= HOLDOUT_EVERY else np.empty(0, np.int64)
        split["train"] = np.setdiff1d(np.arange(n), held)
        split.setdefault("test", held)
    if "test" not in split:
        split["test"] = split.get("val", np.empty(0, np.int64))
    if len(split["train"]) == 0:
        raise DataError(f"{path}: no training frames")
    return split


def _read_meta(path: Path) -> tuple[Path, dict[str, Any]]:
    tf_path = Path(path) / "transforms.json" if Path(path).is_dir() else Path(path)
    meta = read_json(tf_path)
    if not isinstance(meta, dict) or not isinstance(meta.get("frames"), list) or not meta["frames"]:
        raise DataError(f"{tf_path}: needs a non-empty 'frames' list")
    return tf_path, meta


def _parse_cameras(tf_path: Path, meta: dict[str, Any]) -> tuple[Cameras, list[str]]:
    poses, intr, file_paths = [], [], []
    for i, frame in enumerate(meta["frames"]):
        where = f"{tf_path} frame {i}"
        if not isinstance(frame, dict) or "file_path" not in frame:
            raise DataError(f"{where}: missing 'file_path'")
        if "transform_matrix" not in frame:
            raise DataError(f"{where}: missing 'transform_matrix'")
        _check_paths(frame, where)
        check_camera_model(meta, frame, where)
        poses.append(validate_pose(frame["transform_matrix"], where))
        check_rotation(poses[-1], where)
        intr.append(_intrinsics(meta, frame, where))
        file_paths.append(frame["file_path"])
    k = np.asarray(intr)
    return Cameras(
        np.stack(poses), k[:, 0], k[:, 1], k[:, 2], k[:, 3], k[:, 4], k[:, 5]
    ), file_paths


def _check_paths(frame: dict[str, Any], where: str) -> None:
    for key in ("file_path", "depth_file_path", "mask_path", "instance_path"):
        if key in frame and (not isinstance(frame[key], str) or not frame[key].strip()):
            raise DataError(f"{where}: '{key}' must be a non-empty path, got {frame[key]!r}")


def _extras(
    meta: dict[str, Any], tf_path: Path
) -> tuple[tuple[float, float, float], float, np.ndarray | None]:
    """The background colour, the depth unit [m] and the scene box of a transforms.json."""
    bg = meta.get("background_color", (1.0, 1.0, 1.0))
    arr = np.asarray(bg, dtype=object)
    if arr.shape != (3,) or not all(_unit_number(v) for v in bg):
        raise DataError(f"{tf_path}: 'background_color' must be 3 numbers in [0, 1], got {bg!r}")
    unit = (
        _number(meta, "depth_unit_scale_factor", str(tf_path))
        if "depth_unit_scale_factor" in meta
        else 1e-3
    )
    if unit <= 0:
        raise DataError(f"{tf_path}: 'depth_unit_scale_factor' must be positive, got {unit:g}")
    aabb = meta.get("scene_aabb")
    if aabb is None:
        return (float(bg[0]), float(bg[1]), float(bg[2])), unit, None
    try:
        box = np.asarray(aabb, dtype=np.float64).reshape(2, 3)
    except (TypeError, ValueError):
        box = np.full((2, 3), np.nan)
    if not np.all(np.abs(box) <= MAX_COORD_M) or not np.all(box[1] > box[0]):
        raise DataError(
            f"{tf_path}: 'scene_aabb' must be [[xmin,ymin,zmin],[xmax,ymax,zmax]] with max > min, got {aabb!r}"
        )
    return (float(bg[0]), float(bg[1]), float(bg[2])), unit, box


def _unit_number(v: Any) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool) and 0.0 <= v <= 1.0


def load_cameras(path: Path) -> tuple[Cameras, list[str], dict[str, np.ndarray]]:
    """Cameras, file paths and splits of a transforms.json, without reading any image."""
    tf_path, meta = _read_meta(path)
    cameras, file_paths = _parse_cameras(tf_path, meta)
    return cameras, file_paths, _split_indices(meta, file_paths, tf_path)


def load_nerfstudio(
    path: Path, background_rgb: tuple[float, float, float] | None = None
) -> SceneData:
    """Load a nerfstudio dataset from a ``transforms.json`` file or the folder holding it."""
    tf_path, meta = _read_meta(path)
    root = tf_path.parent
    cameras, file_paths = _parse_cameras(tf_path, meta)
    meta_bg, unit, aabb = _extras(meta, tf_path)
    bg = background_rgb or meta_bg

    images, alphas, depths, masks, labels = [], [], [], [], []
    for i, frame in enumerate(meta["frames"]):
        where = f"{tf_path} frame {i}"
        img, alpha = read_rgba(root / frame["file_path"], bg)
        w, h = int(cameras.width[i]), int(cameras.height[i])
        if img.shape[:2] != (h, w):
            raise DataError(f"{where}: image is {img.shape[1]}x{img.shape[0]} but w,h say {w}x{h}")
        images.append(img)
        alphas.append(alpha)
        if "depth_file_path" in frame:
            depths.append(_sized(read_depth_m(root / frame["depth_file_path"], unit), h, w, where))
        if "mask_path" in frame:
            masks.append(_sized(read_label(root / frame["mask_path"], "mask"), h, w, where) > 0)
        if "instance_path" in frame:
            labels.append(
                _sized(read_label(root / frame["instance_path"], "instance image"), h, w, where)
            )
    sizes = {im.shape for im in images}
    if len(sizes) != 1:
        raise DataError(f"{tf_path}: all images must share one size, found {sorted(sizes)}")

    def stack_optional(items: list[np.ndarray], what: str) -> np.ndarray | None:
        if not items:
            return None
        if len(items) != len(images):
            raise DataError(
                f"{tf_path}: '{what}' is given for {len(items)} of {len(images)} frames"
            )
        return np.stack(items)

    names, objects = _instance_names(root)
    return SceneData(
        root=root,
        file_paths=file_paths,
        images=np.stack(images),
        cameras=cameras,
        split=_split_indices(meta, file_paths, tf_path),
        depth_m=stack_optional(depths, "depth_file_path"),
        alpha=_stack_alpha(alphas, images),
        loss_mask=stack_optional(masks, "mask_path"),
        instance_ids=stack_optional(labels, "instance_path"),
        instance_names=names,
        objects=objects,
        background_rgb=bg,
        scene_aabb_m=aabb,
    )


def _sized(image: np.ndarray, h: int, w: int, where: str) -> np.ndarray:
    if image.shape[:2] != (h, w):
        raise DataError(
            f"{where}: a depth, mask or instance image is {image.shape[1]}x{image.shape[0]}, the frame {w}x{h}"
        )
    return image


def _stack_alpha(alphas: list[np.ndarray | None], images: list[np.ndarray]) -> np.ndarray | None:
    """(N,H,W) opacity if any image has alpha (frames without it are opaque), else None."""
    if all(a is None for a in alphas):
        return None
    return np.stack(
        [
            np.full(im.shape[:2], 255, np.uint8) if a is None else a
            for a, im in zip(alphas, images, strict=True)
        ]
    )


def _instance_names(root: Path) -> tuple[dict[int, str], list[dict[str, Any]]]:
    path = root / "objects.json"
    if not path.is_file():
        return {}, []
    meta = read_json(path)
    try:
        names = {int(inst["id"]): str(inst["name"]) for inst in meta["instances"]}
    except (KeyError, TypeError, ValueError, OverflowError) as e:
        raise DataError(f"{path}: 'instances' must be a list of {{'id', 'name'}}") from e
    objects = meta.get("objects", [])
    if not isinstance(objects, list) or not all(
        isinstance(o, dict) and "name" in o and "box" in o for o in objects
    ):
        raise DataError(f"{path}: 'objects' must be a list of {{'name', 'box', ...}}")
    return names, objects

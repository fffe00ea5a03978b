"""Parser for nerfstudio ``transforms.json`` datasets (and instant-ngp's, the same format).

Cameras: global or per-frame ``fl_x, fl_y, cx, cy, w, h`` (a frame's own value wins);
``w``/``h`` default to the image's size. Without ``fl_x``/``fl_y``, instant-ngp's
``camera_angle_x``/``camera_angle_y`` (field of view in radians) give them,
``fl = 0.5 * w / tan(angle / 2)`` (one angle alone: square pixels), and ``cx``/``cy`` then
default to the image centre. ``camera_model`` (global or per frame): PINHOLE and
SIMPLE_PINHOLE (no distortion), OPENCV (the default; ``k1 k2 p1 p2``, optionally ``k3``),
SIMPLE_RADIAL, RADIAL, OPENCV_FISHEYE (``k1 k2 k3 k4``; also instant-ngp's ``is_fisheye``).
Frames with lens distortion are undistorted once at load to a pinhole camera of the same
size (:mod:`neoedit.data.undistort`, cached in the user's cache folder, never in the
dataset); the cameras returned are those pinholes, and the frames' depth, mask and
instance images are remapped the same way (nearest neighbour). Pixels the undistortion
cannot fill are left out of the loss (``loss_mask``).

Per frame: ``file_path``, ``transform_matrix`` (camera-to-world, OpenGL), optional
``depth_file_path`` (uint16 PNG in ``depth_unit_scale_factor`` metres, default 1e-3, or
``.npy`` in metres), ``mask_path`` (nerfstudio loss mask, non-zero = use) and
``instance_path`` (neoedit: per-pixel instance id image, names in ``objects.json`` beside the
transforms file). Frames whose image is missing are listed in one error; ``skip_missing``
drops them with a warning. Splits come from ``train_filenames`` / ``val_filenames`` /
``test_filenames``; without them every 8th frame is held out.

Scene box: neoedit's ``scene_aabb`` (``[[xmin,ymin,zmin],[xmax,ymax,zmax]]`` in metres);
without it, instant-ngp's ``aabb_scale`` gives the box instant-ngp would use (the cube of
side ``aabb_scale`` around (0.5, 0.5, 0.5) in its coordinates ``p * scale + offset``, scale
0.33 and offset (0.5, 0.5, 0.5) unless given), in the poses' coordinates. Also
``background_color`` (RGB in [0,1]).
"""

from __future__ import annotations

import json
import math
import warnings
from collections.abc import Callable
from functools import partial
from pathlib import Path
from typing import Any

import numpy as np

from neoedit.cameras import Cameras
from neoedit.cameras.cameras import validate_pose
from neoedit.data.downscale import pre_shrunk
from neoedit.data.images import image_size, read_frame
from neoedit.data.ngp import box_ok, ngp_box
from neoedit.data.orient import levelled_at_import
from neoedit.data.scene_data import SceneData
from neoedit.data.undistort import (
    DISTORTION_KEYS,
    Lens,
    Undistorter,
    camera_model,
    describe_lenses,
    make_lens,
)
from neoedit.data.validate import (
    check_camera_model,
    check_intrinsics,
    check_rotation,
    finite_number,
)
from neoedit.errors import DataError, MissingFramesWarning

INTRINSIC_KEYS = ("fl_x", "fl_y", "cx", "cy", "w", "h")
HOLDOUT_EVERY = 8
MISSING_LISTED = 10
"""Missing frames named in the error (the rest are counted)."""

Frames = list[tuple[int, dict[str, Any]]]
"""(index in the file, frame) of the frames kept."""


def read_json(path: Path) -> Any:
    if not path.is_file():
        raise DataError(f"file not found: {path}")
    try:
        return json.loads(path.read_text())
    except OSError as e:
        raise DataError(f"cannot read {path}: {e.strerror or e}") from None
    except (ValueError, RecursionError) as e:  # JSONDecodeError, UnicodeDecodeError
        raise DataError(f"{path} is not valid JSON: {e}") from None


def _value(meta: dict[str, Any], frame: dict[str, Any], key: str, where: str) -> float | None:
    """The frame's number ``key``, else the global one, else None."""
    source = frame if key in frame else meta
    return finite_number(source, key, where) if key in source else None


def _intrinsics(
    meta: dict[str, Any],
    frame: dict[str, Any],
    where: str,
    size: Callable[[], tuple[int, int]] | None = None,
) -> list[float]:
    """[fl_x, fl_y, cx, cy, w, h] of a frame; ``size`` gives the image's (w, h) if needed."""
    fx, fy, cx, cy, w, h = (_value(meta, frame, key, where) for key in INTRINSIC_KEYS)
    if (w is None or h is None) and size is not None:
        iw, ih = size()
        w, h = (float(iw) if w is None else w), (float(ih) if h is None else h)
    if (fx is None or fy is None) and w is not None and h is not None:
        ax = _angle(meta, frame, "camera_angle_x", where)
        ay = _angle(meta, frame, "camera_angle_y", where)
        if ax is not None or ay is not None:
            fx = fx if fx is not None or ax is None else 0.5 * w / math.tan(0.5 * ax)
            fy = fy if fy is not None or ay is None else 0.5 * h / math.tan(0.5 * ay)
            fx, fy = (fy if fx is None else fx), (fx if fy is None else fy)
            cx, cy = (0.5 * w if cx is None else cx), (0.5 * h if cy is None else cy)
    values = [fx, fy, cx, cy, w, h]
    for j in (4, 5, 0, 1, 2, 3):  # a missing size first: the focal lengths may need it
        if values[j] is None:
            raise DataError(
                f"{where}: missing intrinsic '{INTRINSIC_KEYS[j]}' (neither in the frame nor global)"
            )
    check_intrinsics(values, where)  # type: ignore[arg-type]
    return values  # type: ignore[return-value]


def _angle(meta: dict[str, Any], frame: dict[str, Any], key: str, where: str) -> float | None:
    angle = _value(meta, frame, key, where)
    if angle is not None and not 0 < angle < math.pi:
        raise DataError(f"{where}: '{key}' must be a field of view in (0, pi), got {angle:g}")
    return angle


def _split_indices(
    meta: dict[str, Any], file_paths: list[str], path: Path, dropped: frozenset[str] = frozenset()
) -> dict[str, np.ndarray]:
    """Split name -> frame indices; names in ``dropped`` (skipped frames) are ignored."""
    n = len(file_paths)
    norm = {_norm(p): i for i, p in enumerate(file_paths)}
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
            k = _norm(f)
            if k in dropped:
                continue
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


def _norm(file_path: str) -> str:
    return Path(file_path).as_posix().removeprefix("./")


def _read_meta(path: Path) -> tuple[Path, dict[str, Any]]:
    tf_path = Path(path) / "transforms.json" if Path(path).is_dir() else Path(path)
    meta = read_json(tf_path)
    if not isinstance(meta, dict) or not isinstance(meta.get("frames"), list) or not meta["frames"]:
        raise DataError(f"{tf_path}: needs a non-empty 'frames' list")
    return tf_path, meta


def _frames(tf_path: Path, meta: dict[str, Any]) -> Frames:
    """Every frame, each checked to have a file path and a pose."""
    for i, frame in enumerate(meta["frames"]):
        where = f"{tf_path} frame {i}"
        if not isinstance(frame, dict) or "file_path" not in frame:
            raise DataError(f"{where}: missing 'file_path'")
        if "transform_matrix" not in frame:
            raise DataError(f"{where}: missing 'transform_matrix'")
        for key in ("file_path", "depth_file_path", "mask_path", "instance_path"):
            if key in frame and (not isinstance(frame[key], str) or not frame[key].strip()):
                raise DataError(f"{where}: '{key}' must be a non-empty path, got {frame[key]!r}")
    first: dict[str, int] = {}
    for i, frame in enumerate(meta["frames"]):
        key = str(Path(frame["file_path"]))
        if key in first:
            raise DataError(
                f"{tf_path}: frames {first[key]} and {i} name the same image "
                f"({_short(frame['file_path'])}); list each photo once"
            )
        first[key] = i
    return list(enumerate(meta["frames"]))


def _drop_missing(
    tf_path: Path, frames: Frames, skip_missing: bool
) -> tuple[Frames, frozenset[str]]:
    """The frames whose image exists and the file paths of those dropped; without
    ``skip_missing`` a missing image is one :class:`DataError` naming them all."""
    missing = [
        (i, f["file_path"]) for i, f in frames if not _is_file(tf_path.parent / f["file_path"])
    ]
    if not missing:
        return frames, frozenset()
    shown = ", ".join(f"{i} ({_short(p)})" for i, p in missing[:MISSING_LISTED])
    more = f" and {len(missing) - MISSING_LISTED} more" if len(missing) > MISSING_LISTED else ""
    what = f"{tf_path}: image not found for {len(missing)} of {len(frames)} frames: {shown}{more}"
    if not skip_missing:
        raise DataError(
            f"{what}; fix their file_path, remove them, or pass --skip-missing to train without them"
        )
    if len(missing) == len(frames):
        raise DataError(f"{what}; no frame is left")
    warnings.warn(f"{what}; those frames are skipped", MissingFramesWarning, stacklevel=3)
    gone = {i for i, _ in missing}
    return [(i, f) for i, f in frames if i not in gone], frozenset(_norm(p) for _, p in missing)


def _is_file(path: Path) -> bool:
    try:
        return path.is_file()
    except OSError:
        return True  # exists but unreadable: reading it gives the precise error


def _short(text: str, limit: int = 48) -> str:
    return text if len(text) <= limit else "..." + text[-(limit - 3) :]


def _parse_frames(
    tf_path: Path, meta: dict[str, Any], frames: Frames, with_images: bool
) -> tuple[np.ndarray, list[Lens]]:
    """(N,4,4) poses and the lenses of ``frames``. ``with_images``: the images exist (their
    size fills in a missing w, h) and lens distortion is allowed; else pinholes only."""
    poses, lenses = [], []
    for i, frame in frames:
        where = f"{tf_path} frame {i}"
        model = "PINHOLE"
        model_where = where if "camera_model" in frame else str(tf_path)  # a global key
        if with_images:
            model = camera_model(meta, frame, model_where)
        else:
            check_camera_model(meta, frame, model_where)
        poses.append(validate_pose(frame["transform_matrix"], where))
        check_rotation(poses[-1], where)
        size = partial(image_size, tf_path.parent / frame["file_path"]) if with_images else None
        k = _intrinsics(meta, frame, where, size)
        values = {key: _value(meta, frame, key, where) for key in DISTORTION_KEYS}
        coeffs = {key: v for key, v in values.items() if v is not None and v != 0.0}
        if coeffs and not with_images:
            raise DataError(
                f"{where}: lens distortion ('{next(iter(coeffs))}') is not supported for "
                "cameras without images (cameras to render are pinholes)"
            )
        lenses.append(make_lens(model, k, coeffs, where))
    return np.stack(poses), lenses


def _cameras(poses: np.ndarray, pinholes: list[tuple[float, ...]]) -> Cameras:
    k = np.asarray(pinholes, dtype=np.float64)
    return Cameras(poses, k[:, 0], k[:, 1], k[:, 2], k[:, 3], k[:, 4], k[:, 5])


def _extras(
    meta: dict[str, Any], tf_path: Path
) -> tuple[tuple[float, float, float], float, np.ndarray | None]:
    """The background colour, the depth unit [m] and the scene box of a transforms.json."""
    bg = meta.get("background_color", (1.0, 1.0, 1.0))
    arr = np.asarray(bg, dtype=object)
    if arr.shape != (3,) or not all(_unit_number(v) for v in bg):
        raise DataError(f"{tf_path}: 'background_color' must be 3 numbers in [0, 1], got {bg!r}")
    unit = (
        finite_number(meta, "depth_unit_scale_factor", str(tf_path))
        if "depth_unit_scale_factor" in meta
        else 1e-3
    )
    if unit <= 0:
        raise DataError(f"{tf_path}: 'depth_unit_scale_factor' must be positive, got {unit:g}")
    box = ngp_box(meta, tf_path)
    aabb = meta.get("scene_aabb")
    if aabb is not None:
        try:
            box = np.asarray(aabb, dtype=np.float64).reshape(2, 3)
        except (TypeError, ValueError):
            box = np.full((2, 3), np.nan)
        if not box_ok(box):
            raise DataError(
                f"{tf_path}: 'scene_aabb' must be [[xmin,ymin,zmin],[xmax,ymax,zmax]] with max > "
                f"min, got {aabb!r}"
            )
    return (float(bg[0]), float(bg[1]), float(bg[2])), unit, box


def _unit_number(v: Any) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool) and 0.0 <= v <= 1.0


def load_cameras(path: Path) -> tuple[Cameras, list[str], dict[str, np.ndarray]]:
    """Cameras, file paths and splits of a transforms.json, without reading any image
    (pinhole cameras only: no lens distortion, ``w``/``h`` given)."""
    tf_path, meta = _read_meta(path)
    frames = _frames(tf_path, meta)
    poses, lenses = _parse_frames(tf_path, meta, frames, with_images=False)
    file_paths = [f["file_path"] for _, f in frames]
    cameras = _cameras(poses, [le.intrinsics for le in lenses])
    return cameras, file_paths, _split_indices(meta, file_paths, tf_path)


def load_nerfstudio(
    path: Path,
    background_rgb: tuple[float, float, float] | None = None,
    skip_missing: bool = False,
    factor_for: Callable[[int], int] | None = None,
) -> SceneData:
    """Load a nerfstudio dataset from a ``transforms.json`` file or the folder holding it.
    ``skip_missing``: drop the frames whose image file is missing (with a warning) instead of
    refusing the dataset. ``factor_for(width)``: the factor the caller shrinks the images
    by; nerfstudio's ``images_N/`` copies at that factor are read instead where they exist
    (``SceneData.pre_shrunk``)."""
    tf_path, meta = _read_meta(path)
    root = tf_path.parent
    frames, dropped = _drop_missing(tf_path, _frames(tf_path, meta), skip_missing)
    poses, lenses = _parse_frames(tf_path, meta, frames, with_images=True)
    file_paths = [f["file_path"] for _, f in frames]
    factor = 1 if factor_for is None else factor_for(lenses[0].width)
    shrunk = pre_shrunk(root, frames, lenses, factor)
    if shrunk is not None:
        frames, lenses = shrunk
    meta_bg, unit, aabb = _extras(meta, tf_path)
    bg = background_rgb or meta_bg
    undistorter = Undistorter(root)
    loaded = [
        read_frame(root, frame, lens, bg, unit, undistorter, f"{tf_path} frame {i}")
        for (i, frame), lens in zip(frames, lenses, strict=True)
    ]
    images = [f.image for f in loaded]
    sizes = {im.shape for im in images}
    if len(sizes) != 1:
        raise DataError(f"{tf_path}: all images must share one size, found {sorted(sizes)}")

    def stack_optional(items: list[np.ndarray | None], what: str) -> np.ndarray | None:
        given = [x for x in items if x is not None]
        if given and len(given) != len(images):
            raise DataError(
                f"{tf_path}: '{what}' is given for {len(given)} of {len(images)} frames"
            )
        return np.stack(given) if given else None

    loss_mask = stack_optional([f.mask for f in loaded], "mask_path")
    if any(f.valid is not None for f in loaded):  # leave out what the undistortion left empty
        full = np.ones(images[0].shape[:2], bool)
        valid = np.stack([full if f.valid is None else f.valid for f in loaded])
        loss_mask = valid if loss_mask is None else loss_mask & valid
    names, objects = _instance_names(root)
    return SceneData(
        root=root,
        file_paths=file_paths,
        images=np.stack(images),
        cameras=_cameras(poses, [f.pinhole for f in loaded]),
        split=_split_indices(meta, file_paths, tf_path, dropped),
        depth_m=stack_optional([f.depth_m for f in loaded], "depth_file_path"),
        alpha=_stack_alpha([f.alpha for f in loaded], images),
        loss_mask=loss_mask,
        instance_ids=stack_optional([f.label for f in loaded], "instance_path"),
        instance_names=names,
        objects=objects,
        background_rgb=bg,
        scene_aabb_m=aabb,
        levelled=levelled_at_import(meta),
        downscaled=1 if shrunk is None else factor,
        pre_shrunk=shrunk is not None,
        lens_note=describe_lenses(lenses),
    )


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

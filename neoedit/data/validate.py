"""Checks of camera intrinsics, camera models and poses, shared by the dataset parsers (and
so by ``neo render --cameras``): bad values fail with a clear :class:`DataError`."""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

import numpy as np

from neoedit.errors import DataError

MAX_IMAGE_SIDE = 32768
PRINCIPAL_POINT_MARGIN = 0.5
"""The principal point may lie this fraction of the image size outside the image."""
MAX_COORD_M = 1e6
"""Largest camera or scene-box coordinate accepted (float32 geometry breaks far beyond)."""
ROTATION_TOLERANCE = 5e-3
"""Largest |R^T R - I| entry accepted for the rotation part of a camera-to-world matrix."""
PINHOLE_MODELS = ("OPENCV", "PINHOLE", "SIMPLE_PINHOLE", "SIMPLE_RADIAL", "RADIAL", "PERSPECTIVE")
"""nerfstudio ``camera_model`` values we render as pinholes (lens distortion must be zero)."""


def check_camera_model(meta: Mapping[str, Any], frame: Mapping[str, Any], where: str) -> None:
    """The frame's (or the global) ``camera_model`` must be a pinhole model."""
    model = frame.get("camera_model", meta.get("camera_model", "OPENCV"))
    if not isinstance(model, str) or model.upper() not in PINHOLE_MODELS:
        raise DataError(
            f"{where}: camera_model {model!r} is not supported (supported: "
            f"{', '.join(PINHOLE_MODELS)}; fisheye and equirectangular images must be "
            "undistorted to a pinhole camera first)"
        )


def check_intrinsics(values: list[float], where: str) -> None:
    """``[fl_x, fl_y, cx, cy, w, h]``: focal lengths positive, the size a positive whole
    number of pixels, the principal point inside the image or near it."""
    fx, fy, cx, cy, w, h = values
    if not all(np.isfinite(v) for v in values):
        raise DataError(f"{where}: intrinsics must be finite numbers, got {list(values)}")
    for key, v in (("w", w), ("h", h)):
        if v != int(v) or not 1 <= v <= MAX_IMAGE_SIDE:
            raise DataError(
                f"{where}: '{key}' must be a whole number of pixels in [1, {MAX_IMAGE_SIDE}], got {v:g}"
            )
    for key, v in (("fl_x", fx), ("fl_y", fy)):
        if v <= 0:
            raise DataError(f"{where}: focal length '{key}' must be positive, got {v:g}")
    for key, v, size in (("cx", cx, w), ("cy", cy, h)):
        lo, hi = -PRINCIPAL_POINT_MARGIN * size, (1 + PRINCIPAL_POINT_MARGIN) * size
        if not lo <= v <= hi:
            raise DataError(
                f"{where}: principal point '{key}' = {v:g} is far outside the image "
                f"(0..{size:g} px; accepted {lo:g}..{hi:g})"
            )


def check_rotation(c2w: np.ndarray, where: str) -> None:
    """The rotation part of a camera-to-world matrix must be orthonormal and right-handed
    (no scale, shear or mirror) and its last row (0, 0, 0, 1)."""
    r = np.asarray(c2w, dtype=np.float64)[:3, :3]
    err = float(np.max(np.abs(r.T @ r - np.eye(3))))
    if err > ROTATION_TOLERANCE:
        raise DataError(
            f"{where}: the rotation part of transform_matrix is not orthonormal (|R^T R - I| "
            f"up to {err:.3g}; scaled or sheared poses are not supported)"
        )
    if np.linalg.det(r) < 0:
        raise DataError(f"{where}: transform_matrix is a mirror image (det of rotation < 0)")
    last = np.asarray(c2w, dtype=np.float64)[3]
    if not np.allclose(last, [0.0, 0.0, 0.0, 1.0], atol=1e-6):
        raise DataError(f"{where}: the last row of transform_matrix must be 0 0 0 1")
    if np.max(np.abs(np.asarray(c2w, dtype=np.float64)[:3, 3])) > MAX_COORD_M:
        raise DataError(
            f"{where}: the camera position is beyond {MAX_COORD_M:g} (units of the scene)"
        )


def check_file_path(value: Any, where: str, key: str = "file_path") -> str:
    """A frame's relative file path: a non-empty string that stays inside the dataset."""
    if not isinstance(value, str) or not value.strip():
        raise DataError(f"{where}: '{key}' must be a non-empty relative path, got {value!r}")
    parts = value.replace("\\", "/").split("/")
    if value.startswith(("/", "\\")) or ".." in parts or (len(value) > 1 and value[1] == ":"):
        raise DataError(f"{where}: '{key}' {value!r} must be relative and stay inside the dataset")
    return value


def check_scan_record(record: Any, where: str) -> None:
    """The cameras a scene stores (``scene.json`` 'scan'): N finite pinhole cameras with the
    checks above, N file names and splits indexing them."""
    keys = ("camera_to_world", "fx", "fy", "cx", "cy", "width", "height")
    cams = record.get("cameras") if isinstance(record, Mapping) else None
    try:
        arrays = [np.asarray(cams[k], dtype=np.float64) for k in keys]  # type: ignore[index]
    except (KeyError, TypeError, ValueError):
        raise DataError(f"{where}: 'scan.cameras' needs numeric {', '.join(keys)}") from None
    n = len(arrays[1]) if arrays[1].ndim == 1 else -1
    if arrays[0].shape != (n, 4, 4) or any(a.shape != (n,) for a in arrays[1:]) or n < 1:
        raise DataError(f"{where}: 'scan.cameras' must hold N 4x4 poses and N of each intrinsic")
    for i in range(n):
        at = f"{where}: scan camera {i}"
        check_intrinsics([float(a[i]) for a in arrays[1:]], at)
        if not np.all(np.isfinite(arrays[0][i])):
            raise DataError(f"{at}: the pose has non-finite values")
        check_rotation(arrays[0][i], at)
    fixes = record.get("pose_corrections")
    if fixes is not None:
        try:
            fixes = np.asarray(fixes, dtype=np.float64)
        except (TypeError, ValueError):
            fixes = None
        if fixes is None or fixes.shape != (n, 6) or not np.isfinite(fixes).all():
            raise DataError(
                f"{where}: 'scan.pose_corrections' must be {n} finite 6-vectors (a rotation "
                "vector and a translation per camera)"
            )
    names, split = record.get("file_paths"), record.get("split")
    if not isinstance(names, list) or len(names) != n or not all(isinstance(p, str) for p in names):
        raise DataError(f"{where}: 'scan.file_paths' must be {n} file names")
    ok = isinstance(split, Mapping) and all(
        isinstance(v, list) and all(isinstance(j, int) and 0 <= j < n for j in v)
        for v in split.values()
    )
    if not ok:
        raise DataError(f"{where}: 'scan.split' must map split names to camera indices < {n}")


def finite_number(d: Mapping[str, Any], key: str, where: str) -> float:
    """``d[key]`` as a float: a :class:`DataError` naming it unless it is a finite number."""
    value = d.get(key)
    if not isinstance(value, (int, float)) or not is_finite_number(value):
        shown = repr(value) if len(repr(value)) < 40 else repr(value)[:37] + "..."
        raise DataError(f"{where}: '{key}' must be a finite number, got {shown}")
    return float(value)


def is_finite_number(v: Any) -> bool:
    """A JSON value that is a finite number (not a bool; an integer too large for a float
    is not)."""
    if not isinstance(v, (int, float)) or isinstance(v, bool):
        return False
    try:
        return math.isfinite(float(v))
    except OverflowError:
        return False

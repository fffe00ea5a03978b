"""Camera models of nerfstudio's ``transforms.json`` and lens undistortion to a pinhole.

A frame's ``camera_model`` (its own, else the global one; without either, OPENCV, or
OPENCV_FISHEYE where instant-ngp's ``is_fisheye`` is true) says which distortion
coefficients it has:

- PINHOLE, SIMPLE_PINHOLE: none (a non-zero coefficient is an error);
- OPENCV, PERSPECTIVE: ``k1 k2 p1 p2`` and optionally ``k3``; SIMPLE_RADIAL: ``k1``;
  RADIAL: ``k1 k2`` (OpenCV's radial-tangential model);
- OPENCV_FISHEYE: ``k1 k2 k3 k4`` (OpenCV's equidistant fisheye model).

A frame with distortion is undistorted once, with OpenCV, to a pinhole camera of the same
image size that keeps only valid pixels (``getOptimalNewCameraMatrix`` with alpha 0, or
``fisheye.estimateNewCameraMatrixForUndistortRectify`` with balance 0). Intrinsics follow
nerfstudio's pixel convention (pixel centres at +0.5); OpenCV's centres sit on integers.

Undistorted photos are cached as PNG under ``$NEO_CACHE_DIR/undistorted`` (else
``$NEOEDIT_CACHE/undistorted``, else ``$XDG_CACHE_HOME/neoedit/undistorted``, else
``~/.cache/neoedit/undistorted``), one file per photo named by a hash of the photo's path,
size and modification time and of the camera; files are written atomically and never
into the dataset folder.
"""

from __future__ import annotations

import hashlib
import json
import os
import warnings
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import cv2
import imageio.v3 as iio
import numpy as np

from neoedit.data.validate import PINHOLE_MODELS, check_intrinsics
from neoedit.errors import DataError, NeoWarning
from neoedit.utils.cache import cache_dir
from neoedit.utils.io import write_png

FISHEYE = "OPENCV_FISHEYE"
SUPPORTED_MODELS = (*PINHOLE_MODELS, FISHEYE)
MODEL_KEYS = {
    "PINHOLE": (),
    "SIMPLE_PINHOLE": (),
    "SIMPLE_RADIAL": ("k1",),
    "RADIAL": ("k1", "k2"),
    "OPENCV": ("k1", "k2", "p1", "p2", "k3"),
    "PERSPECTIVE": ("k1", "k2", "p1", "p2", "k3"),
    FISHEYE: ("k1", "k2", "k3", "k4"),
}
"""The distortion coefficients each camera model has (others must be absent or zero)."""
DISTORTION_KEYS = ("k1", "k2", "k3", "k4", "p1", "p2")
MIN_KEPT = 0.25
"""Smallest share of the photo the undistorted image may keep (and of it that is valid)."""
CACHE_ENV = "NEO_CACHE_DIR"
CACHE_FORMAT = 1
"""Version of what the cache holds; a change makes every old entry a miss."""


def camera_model(meta: Mapping[str, Any], frame: Mapping[str, Any], where: str) -> str:
    """The frame's camera model (upper case); an unknown one is a :class:`DataError`."""
    model = frame.get("camera_model", meta.get("camera_model"))
    if model is None:
        fisheye = frame.get("is_fisheye", meta.get("is_fisheye", False))
        return FISHEYE if fisheye is True else "OPENCV"
    if not isinstance(model, str) or model.upper() not in SUPPORTED_MODELS:
        raise DataError(
            f"{where}: camera_model {model!r} is not supported (supported: "
            f"{', '.join(SUPPORTED_MODELS)}; convert equirectangular and other images to a "
            "pinhole camera first)"
        )
    return model.upper()


@dataclass(frozen=True)
class Lens:
    """One frame's camera as the dataset gives it (nerfstudio pixel convention)."""

    model: str
    """``"PINHOLE"`` (no distortion), ``"OPENCV"`` or ``"OPENCV_FISHEYE"``."""
    fx: float
    fy: float
    cx: float
    cy: float
    width: int
    height: int
    dist: tuple[float, ...] = ()
    """OPENCV: (k1, k2, p1, p2, k3); OPENCV_FISHEYE: (k1, k2, k3, k4)."""

    @property
    def distorted(self) -> bool:
        return self.model != "PINHOLE"

    @property
    def intrinsics(self) -> tuple[float, float, float, float, int, int]:
        """(fx, fy, cx, cy, w, h)."""
        return (self.fx, self.fy, self.cx, self.cy, self.width, self.height)

    def describe(self) -> str:
        names = ("k1", "k2", "k3", "k4") if self.model == FISHEYE else MODEL_KEYS["OPENCV"]
        coeffs = ", ".join(f"{k}={v:g}" for k, v in zip(names, self.dist, strict=True) if v)
        return f"camera_model {self.model}, {coeffs}"


def make_lens(model: str, intrinsics: list[float], coeffs: Mapping[str, float], where: str) -> Lens:
    """The :class:`Lens` of ``model`` with ``intrinsics`` [fx, fy, cx, cy, w, h] and the
    frame's distortion ``coeffs`` (key -> value; absent keys are zero)."""
    allowed = MODEL_KEYS[model]
    for key, value in coeffs.items():
        if value != 0.0 and key not in allowed:
            hint = (
                "set camera_model to OPENCV (k1 k2 p1 p2 k3) or OPENCV_FISHEYE (k1 k2 k3 k4) "
                "to have the images undistorted"
                if not allowed
                else f"{model} has {' '.join(allowed)}"
            )
            raise DataError(
                f"{where}: lens distortion '{key}' = {value:g} does not belong to camera_model "
                f"{model} ({hint})"
            )
    fx, fy, cx, cy, w, h = intrinsics
    if not any(coeffs.get(k, 0.0) for k in allowed):
        return Lens("PINHOLE", fx, fy, cx, cy, int(w), int(h))
    kind = FISHEYE if model == FISHEYE else "OPENCV"
    keys = MODEL_KEYS[kind]
    return Lens(kind, fx, fy, cx, cy, int(w), int(h), tuple(coeffs.get(k, 0.0) for k in keys))


@dataclass
class Rectification:
    """How one lens is undistorted: the new pinhole and OpenCV's remap tables."""

    lens: Lens
    pinhole: tuple[float, float, float, float]
    """New (fx, fy, cx, cy), nerfstudio pixel convention."""
    map_x: np.ndarray
    """(H, W) float32: source column (OpenCV convention) of each undistorted pixel."""
    map_y: np.ndarray
    valid: np.ndarray
    """(H, W) bool: undistorted pixels that see the photo (inside it, lens not folded)."""

    def remap(self, image: np.ndarray) -> np.ndarray:
        """A photo (H, W[, C], uint8 or uint16) undistorted with bilinear interpolation."""
        return cv2.remap(
            image, self.map_x, self.map_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE
        )

    def remap_nearest(self, image: np.ndarray) -> np.ndarray:
        """Depth, mask or label image undistorted by nearest neighbour (0 where not valid)."""
        h, w = image.shape[:2]
        col = np.clip(np.floor(self.map_x + 0.5).astype(np.int64), 0, w - 1)
        row = np.clip(np.floor(self.map_y + 0.5).astype(np.int64), 0, h - 1)
        out = image[row, col]
        out[~self.valid] = 0
        return out


def rectify(lens: Lens, where: str) -> Rectification:
    """Undistortion of ``lens`` to a pinhole of the same size; a :class:`DataError` when the
    distortion is so strong that little of the photo would remain."""
    w, h = lens.width, lens.height
    k = np.array([[lens.fx, 0.0, lens.cx - 0.5], [0.0, lens.fy, lens.cy - 0.5], [0, 0, 1.0]])
    dist = np.asarray(lens.dist, dtype=np.float64)
    try:
        if lens.model == FISHEYE:
            new_k = cv2.fisheye.estimateNewCameraMatrixForUndistortRectify(
                k, dist, (w, h), np.eye(3), balance=0.0
            )
            maps = cv2.fisheye.initUndistortRectifyMap(
                k, dist, np.eye(3), new_k, (w, h), cv2.CV_32FC1
            )
        else:
            new_k = cv2.getOptimalNewCameraMatrix(k, dist, (w, h), 0.0, (w, h))[0]
            maps = cv2.initUndistortRectifyMap(k, dist, None, new_k, (w, h), cv2.CV_32FC1)
    except cv2.error as e:
        raise DataError(f"{where}: cannot undistort ({lens.describe()}): {e}") from None
    pinhole = (
        float(new_k[0, 0]),
        float(new_k[1, 1]),
        float(new_k[0, 2]) + 0.5,
        float(new_k[1, 2]) + 0.5,
    )
    valid, kept = _coverage(maps[0], maps[1], w, h)
    share = min(float(valid.mean()), kept)
    if not np.all(np.isfinite(pinhole)) or share < MIN_KEPT:
        raise DataError(
            f"{where}: lens distortion too strong to undistort ({lens.describe()}): the pinhole "
            f"image would keep {100 * share:.0f}% of the photo (at least {100 * MIN_KEPT:.0f}% "
            "needed); check the distortion coefficients"
        )
    check_intrinsics([*pinhole, w, h], f"{where} (undistorted)")
    return Rectification(lens, pinhole, maps[0], maps[1], valid)


def _coverage(map_x: np.ndarray, map_y: np.ndarray, w: int, h: int) -> tuple[np.ndarray, float]:
    """Valid undistorted pixels (they map inside the photo, where the lens does not fold
    over) and the share of the photo's area they show."""
    with np.errstate(invalid="ignore"):
        inside = (map_x >= -0.5) & (map_x <= w - 0.5) & (map_y >= -0.5) & (map_y <= h - 0.5)
        if min(w, h) < 2:
            return inside, float(inside.mean())
        det = np.gradient(map_x, axis=1) * np.gradient(map_y, axis=0) - np.gradient(
            map_x, axis=0
        ) * np.gradient(map_y, axis=1)
        valid = inside & (det > 0)
    return valid, float(np.sum(det[valid]) / (w * h))


def cache_folder() -> Path | None:
    """Where undistorted photos are cached (None when no home folder is known)."""
    if os.environ.get(CACHE_ENV):
        return Path(os.environ[CACHE_ENV]) / "undistorted"
    root = cache_dir()
    return None if root is None else root / "undistorted"


class Undistorter:
    """Undistorts a dataset's photos, reusing the last lens's tables and the cache."""

    def __init__(self, dataset_root: Path) -> None:
        self.root = Path(dataset_root)
        self._folder: Path | None = None
        self._checked = False
        self._last: Rectification | None = None

    @property
    def folder(self) -> Path | None:
        """The cache folder, None when nothing may be cached (checked on first use)."""
        if not self._checked:
            self._checked = True
            self._folder = cache_folder()
            if self._folder is not None and _inside(self._folder, self.root):
                self._disable(f"it is inside the dataset {self.root}", "outside it")
        return self._folder

    def _disable(self, why: str, want: str) -> None:
        warnings.warn(
            f"the undistortion cache {self._folder}: {why}; nothing is cached (set {CACHE_ENV} "
            f"to a folder {want})",
            NeoWarning,
            stacklevel=4,
        )
        self._folder = None

    def rectification(self, lens: Lens, where: str) -> Rectification:
        if self._last is None or self._last.lens != lens:
            self._last = rectify(lens, where)
        return self._last

    def cached(self, photo: Path, lens: Lens) -> np.ndarray | None:
        """The undistorted photo from the cache, None on a miss."""
        path = self._entry(photo, lens)
        if path is None or not path.is_file():
            return None
        try:
            image = np.asarray(iio.imread(path))
        except Exception:  # a damaged entry is a miss; it is rewritten
            return None
        ok = image.shape[:2] == (lens.height, lens.width) and image.dtype in (np.uint8, np.uint16)
        return image if ok else None

    def store(self, photo: Path, lens: Lens, image: np.ndarray) -> None:
        """Cache an undistorted photo (silently skipped when the cache cannot be written)."""
        path = self._entry(photo, lens)
        if path is None or image.dtype not in (np.uint8, np.uint16):
            return
        try:
            write_png(path, image)
        except OSError as e:
            self._disable(f"cannot write it ({e.strerror or e})", "one can write")

    def _entry(self, photo: Path, lens: Lens) -> Path | None:
        """The cache file of ``photo`` seen through ``lens`` (None: no caching)."""
        folder = self.folder
        if folder is None:
            return None
        try:
            st = photo.stat()
        except OSError:
            return None
        key = {
            "format": CACHE_FORMAT,
            "opencv": cv2.__version__,
            "photo": str(photo.resolve()),
            "size": st.st_size,
            "mtime_ns": st.st_mtime_ns,
            "lens": [lens.model, lens.fx, lens.fy, lens.cx, lens.cy, lens.width, lens.height]
            + list(lens.dist),
        }
        digest = hashlib.sha256(json.dumps(key, sort_keys=True).encode()).hexdigest()[:32]
        return folder / f"{digest}.png"


def _inside(path: Path, folder: Path) -> bool:
    try:
        return Path(path).resolve().is_relative_to(Path(folder).resolve())
    except OSError:
        return True  # cannot tell: do not write


def describe_lenses(lenses: list[Lens]) -> str:
    """The frames' lenses in a line: 'pinhole', or the distortion model and coefficients."""
    kinds = sorted({lens.describe() for lens in lenses if lens.distorted})
    if not kinds:
        return "pinhole (no distortion)"
    distorted = sum(lens.distorted for lens in lenses)
    what = kinds[0] if len(kinds) == 1 else f"{len(kinds)} sets of coefficients, e.g. {kinds[0]}"
    return f"{what} on {distorted} of {len(lenses)} frames; undistorted on load to pinholes"

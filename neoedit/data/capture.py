"""A structure-from-motion result before it becomes a dataset: photos, poses, lens models
and the sparse points, in the model's own (arbitrary) frame and scale.

Importers (:mod:`neoedit.data.colmap`, :mod:`neoedit.data.llff`) read one; the importer
pipeline (:mod:`neoedit.data.importer`) checks it, orients and scales it, undistorts the
photos and writes a nerfstudio ``transforms.json`` dataset.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from neoedit.errors import DataError

# lens models we undistort: name -> parameter names in COLMAP's order
LENS_MODELS: dict[str, tuple[str, ...]] = {
    "SIMPLE_PINHOLE": ("f", "cx", "cy"),
    "PINHOLE": ("fx", "fy", "cx", "cy"),
    "SIMPLE_RADIAL": ("f", "cx", "cy", "k1"),
    "RADIAL": ("f", "cx", "cy", "k1", "k2"),
    "OPENCV": ("fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2"),
    "FULL_OPENCV": ("fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2", "k3", "k4", "k5", "k6"),
}


@dataclass
class Lens:
    """One camera's intrinsics: a COLMAP model name and its parameters (pixels)."""

    model: str
    params: np.ndarray
    width: int
    height: int

    def named(self) -> dict[str, float]:
        return dict(zip(LENS_MODELS[self.model], (float(p) for p in self.params), strict=True))

    def matrix(self) -> np.ndarray:
        """3x3 pinhole matrix K (COLMAP's principal point convention: pixel centres at +0.5)."""
        p = self.named()
        fx = p.get("fx", p.get("f"))
        fy = p.get("fy", p.get("f"))
        return np.array([[fx, 0.0, p["cx"]], [0.0, fy, p["cy"]], [0.0, 0.0, 1.0]])

    def distortion(self) -> np.ndarray:
        """OpenCV distortion coefficients (k1, k2, p1, p2[, k3, k4, k5, k6])."""
        p = self.named()
        keys: tuple[str, ...] = ("k1", "k2", "p1", "p2")
        if self.model == "FULL_OPENCV":
            keys += ("k3", "k4", "k5", "k6")
        return np.array([p.get(k, 0.0) for k in keys])

    @property
    def distorted(self) -> bool:
        return bool(np.any(np.abs(self.distortion()) > 0))


@dataclass
class Capture:
    """Registered photos of one capture, in the reconstruction's frame."""

    source: Path
    names: list[str]
    """Image names (relative to ``image_dir``), sorted; the order of every array here."""
    image_dir: Path
    camera_to_world: np.ndarray
    """(N,4,4) camera-to-world, OpenGL axes (x right, y up, z back)."""
    lenses: list[Lens]
    points: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    """(P,3) sparse points (COLMAP); empty for LLFF."""
    point_tracks: list[np.ndarray] = field(default_factory=list)
    """Per point, the indices (into ``names``) of the images that observe it."""
    point_errors: np.ndarray | None = None
    """(P,) mean reprojection error of each point in the model [px] (COLMAP), if known."""
    bounds: np.ndarray | None = None
    """(N,2) near/far depth per image (LLFF), in model units."""
    unregistered: list[str] = field(default_factory=list)
    """Images in ``image_dir`` that the model did not register."""

    def __len__(self) -> int:
        return len(self.names)

    @property
    def centres(self) -> np.ndarray:
        return self.camera_to_world[:, :3, 3]

    def subset(self, index: np.ndarray, whole_tracks: bool = False) -> Capture:
        """The photos at ``index`` (sorted) and the points two of them observe (with
        ``whole_tracks``: only the points no other photo observes)."""
        index = np.sort(np.asarray(index, dtype=np.int64))
        remap = np.full(len(self), -1, np.int64)
        remap[index] = np.arange(len(index))
        keep_pts, tracks = [], []
        for i, track in enumerate(self.point_tracks):
            seen = remap[track]
            if whole_tracks and (seen < 0).any():
                continue
            seen = seen[seen >= 0]
            if len(seen) >= 2:
                keep_pts.append(i)
                tracks.append(seen)
        errors = self.point_errors
        return Capture(
            self.source,
            [self.names[i] for i in index],
            self.image_dir,
            self.camera_to_world[index],
            [self.lenses[i] for i in index],
            self.points[keep_pts] if keep_pts else np.zeros((0, 3)),
            tracks,
            None if errors is None else errors[keep_pts] if keep_pts else np.zeros(0),
            None if self.bounds is None else self.bounds[index],
            self.unregistered,
        )

    def shared_with_next(self) -> np.ndarray:
        """(N-1,) number of sparse points seen by both image i and image i+1."""
        shared = np.zeros(max(len(self) - 1, 0), np.int64)
        for track in self.point_tracks:
            t = np.unique(track)
            consecutive = t[1:][np.diff(t) == 1] - 1
            shared[consecutive] += 1
        return shared


def opencv_to_opengl(camera_to_world: np.ndarray) -> np.ndarray:
    """Flip the camera y and z axes (OpenCV/COLMAP: y down, z forward -> OpenGL)."""
    return camera_to_world @ np.diag([1.0, -1.0, -1.0, 1.0])


def read_photo(path: Path, grey: bool = False) -> np.ndarray:
    """A photo as stored (BGR or grey uint8), EXIF orientation ignored as COLMAP ignores it:
    the pixels the poses and lenses were estimated on."""
    import cv2

    flags = (cv2.IMREAD_GRAYSCALE if grey else cv2.IMREAD_COLOR) | cv2.IMREAD_IGNORE_ORIENTATION
    image = cv2.imread(str(path), flags)
    if image is None:
        raise DataError(f"cannot read image {path}")
    return image

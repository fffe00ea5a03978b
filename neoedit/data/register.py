"""Register a later scan (POST) to an earlier one (PRE) with the ArUco markers both see:
the post scan's cameras are moved into the pre scan's frame (``neo register``)."""

from __future__ import annotations

import json
import shutil
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from neoedit.data.load import load_scene_data
from neoedit.data.markers import dataset_markers, umeyama
from neoedit.errors import DataError
from neoedit.utils.io import atomic_directory, atomic_write_json


@dataclass
class Registration:
    transform: np.ndarray
    """(4,4) similarity: POST frame -> PRE frame."""
    markers: list[int]
    rms_m: float
    """Residual of the matched marker corners after the alignment, in PRE units."""

    @property
    def scale(self) -> float:
        return float(np.cbrt(np.linalg.det(self.transform[:3, :3])))

    @property
    def rotation_deg(self) -> float:
        rot = self.transform[:3, :3] / self.scale
        return float(np.degrees(Rotation.from_matrix(rot).magnitude()))


def register_scans(pre: Path, post: Path, dictionary_name: str = "4X4_50") -> Registration:
    """The similarity that takes POST's marker corners onto PRE's."""
    a = dataset_markers(load_scene_data(pre), dictionary_name)
    b = dataset_markers(load_scene_data(post), dictionary_name)
    common = sorted(set(a.corners) & set(b.corners))
    if len(common) < 2:
        raise DataError(
            f"registration needs 2 or more ArUco markers seen in both scans; {pre} has "
            f"{sorted(a.corners)}, {post} has {sorted(b.corners)} ({dictionary_name})"
        )
    src, dst = b.points(common), a.points(common)
    transform = umeyama(src, dst)
    moved = src @ transform[:3, :3].T + transform[:3, 3]
    rms = float(np.sqrt(((moved - dst) ** 2).sum(1).mean()))
    return Registration(transform, common, rms)


def _safe_relative(name: str, where: Path) -> Path:
    path = Path(name)
    if path.is_absolute() or ".." in path.parts:
        raise DataError(f"{where}: {name!r} is outside the dataset folder; cannot copy it")
    return path


def _transforms_path(dataset: Path) -> Path:
    return Path(dataset) / "transforms.json" if Path(dataset).is_dir() else Path(dataset)


def write_moved(
    src: Path,
    transform: np.ndarray,
    out: Path,
    overwrite: bool = False,
    scene_aabb: list | None = None,
    record: dict | None = None,
) -> None:
    """A copy of the dataset ``src`` with every camera moved by the similarity ``transform``
    (4x4) and depth rescaled with it. Its scene box becomes ``scene_aabb`` (the old one is
    dropped: it would no longer be axis-aligned); instance labels and ``objects.json`` are
    left out (their boxes are in the old frame), and so is how an import oriented the old
    frame (``neoedit_import.orientation``). ``record`` is stored as
    ``neoedit_registration``."""
    src_tf = _transforms_path(src)
    meta = json.loads(src_tf.read_text())
    scale = float(np.cbrt(np.linalg.det(transform[:3, :3])))
    for frame in meta["frames"]:
        c2w = transform @ np.asarray(frame["transform_matrix"], dtype=np.float64)
        c2w[:3, :3] /= scale
        frame["transform_matrix"] = np.round(c2w, 9).tolist()
        frame.pop("instance_path", None)
    meta.pop("scene_aabb", None)
    if isinstance(meta.get("neoedit_import"), dict):
        meta["neoedit_import"].pop("orientation", None)
    if scene_aabb is not None:
        meta["scene_aabb"] = scene_aabb
    if any(str(f.get("depth_file_path", "")).endswith(".png") for f in meta["frames"]):
        meta["depth_unit_scale_factor"] = scale * float(meta.get("depth_unit_scale_factor", 1e-3))
    if record is not None:
        meta["neoedit_registration"] = record
    keys = ("file_path", "depth_file_path", "mask_path")
    names = sorted(
        {str(_safe_relative(f[k], src_tf)) for f in meta["frames"] for k in keys if k in f}
    )
    with atomic_directory(out, overwrite=overwrite, kind="dataset") as tmp:
        for name in names:
            source = src_tf.parent / name
            if not source.is_file():
                raise DataError(f"{src_tf}: {name} not found")
            (tmp / name).parent.mkdir(parents=True, exist_ok=True)
            if name.endswith(".npy"):  # depth in metres: into the new units
                np.save(tmp / name, np.load(source, allow_pickle=False) * scale)
            else:
                shutil.copy2(source, tmp / name)
        atomic_write_json(tmp / "transforms.json", meta)


def write_registered(pre: Path, post: Path, reg: Registration, out: Path, overwrite: bool) -> None:
    """A copy of the POST dataset whose cameras are in PRE's frame (with PRE's scene box)."""
    pre_tf, post_tf = _transforms_path(pre), _transforms_path(post)
    record = {
        "pre": str(pre_tf.parent.resolve()),
        "post": str(post_tf.parent.resolve()),
        "markers": reg.markers,
        "transform": np.round(reg.transform, 9).tolist(),
        "rms_m": reg.rms_m,
    }
    aabb = json.loads(pre_tf.read_text()).get("scene_aabb")
    write_moved(post, reg.transform, out, overwrite, aabb, record)

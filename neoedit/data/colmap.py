"""Read a COLMAP sparse model (binary or text) with ``pycolmap`` into a :class:`Capture`.

Accepted layouts for ``neo import colmap SRC``: SRC is a project folder holding
``sparse/0`` (or ``sparse``) and ``images``; or SRC is the model folder itself
(``cameras.bin|txt``, ``images.bin|txt``, ``points3D.bin|txt``) and ``--images`` names the
photos. Only the largest model is read when ``sparse`` holds several.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from neoedit.data.capture import LENS_MODELS, Capture, Lens, opencv_to_opengl
from neoedit.errors import DataError

MODEL_FILES = ("cameras", "images", "points3D")
IMAGE_SUFFIXES = (".jpg", ".jpeg", ".png", ".JPG", ".JPEG", ".PNG")


def _is_model(folder: Path) -> bool:
    return all(
        (folder / f"{name}.bin").is_file() or (folder / f"{name}.txt").is_file()
        for name in MODEL_FILES
    )


def find_model(src: Path) -> Path:
    """The sparse model folder of ``src`` (the folder itself, ``sparse/N`` or ``sparse``)."""
    src = Path(src)
    if not src.exists():
        raise DataError(f"COLMAP source not found: {src}")
    if _is_model(src):
        return src
    sparse = src / "sparse"
    candidates = sorted(p for p in sparse.glob("*") if p.is_dir() and _is_model(p))
    if candidates:
        # several models: the one with the most registered images (images.bin is largest)
        return max(candidates, key=lambda p: _model_size(p))
    if _is_model(sparse):
        return sparse
    raise DataError(
        f"{src}: no COLMAP model found (expected cameras/images/points3D .bin or .txt in the "
        "folder itself, in sparse/0 or in sparse)"
    )


def _model_size(folder: Path) -> int:
    for name in ("images.bin", "images.txt"):
        if (folder / name).is_file():
            return (folder / name).stat().st_size
    return 0


def find_images(src: Path, model: Path, images: Path | None) -> Path:
    if images is not None:
        if not Path(images).is_dir():
            raise DataError(f"image folder not found: {images}")
        return Path(images)
    for candidate in (src / "images", model.parent.parent / "images", model.parent / "images"):
        if candidate.is_dir():
            return candidate
    raise DataError(f"{src}: no 'images' folder beside the model; name it with --images")


def _lens(camera) -> Lens:  # noqa: ANN001 (pycolmap.Camera)
    model = camera.model.name
    if model not in LENS_MODELS:
        raise DataError(
            f"camera {camera.camera_id}: COLMAP model {model} is not supported (supported: "
            f"{', '.join(LENS_MODELS)}); re-run COLMAP with one of them"
        )
    params = np.asarray(camera.params, dtype=np.float64)
    if len(params) != len(LENS_MODELS[model]) or not np.all(np.isfinite(params)):
        raise DataError(f"camera {camera.camera_id}: bad {model} parameters {params.tolist()}")
    if camera.width <= 0 or camera.height <= 0:
        raise DataError(f"camera {camera.camera_id}: bad size {camera.width}x{camera.height}")
    return Lens(model, params, int(camera.width), int(camera.height))


def read_colmap(src: Path, images: Path | None = None) -> Capture:
    """The registered images of the model in ``src`` (sorted by name), with their poses,
    lenses and the sparse points with their tracks."""
    import pycolmap

    model = find_model(Path(src))
    image_dir = find_images(Path(src), model, images)
    try:
        rec = pycolmap.Reconstruction(str(model))
    except Exception as e:  # pycolmap raises plain RuntimeError/ValueError on bad files
        raise DataError(f"{model}: cannot read the COLMAP model: {e}") from None
    registered = [im for im in rec.images.values() if im.has_pose]
    if len(registered) < 2:
        raise DataError(f"{model}: only {len(registered)} registered image(s); need at least 2")
    registered.sort(key=lambda im: im.name)
    position = {im.image_id: k for k, im in enumerate(registered)}
    poses, lenses = [], []
    for im in registered:
        world_from_cam = np.asarray(im.cam_from_world().inverse().matrix(), dtype=np.float64)
        c2w = np.eye(4)
        c2w[:3, :4] = world_from_cam
        poses.append(opencv_to_opengl(c2w))
        lenses.append(_lens(rec.cameras[im.camera_id]))
        if not (image_dir / im.name).is_file():
            raise DataError(f"{model}: image {im.name} is registered but not in {image_dir}")
    points, tracks, errors = [], [], []
    for p in rec.points3D.values():
        seen = np.unique([position[e.image_id] for e in p.track.elements if e.image_id in position])
        if len(seen) >= 2 and np.all(np.isfinite(p.xyz)):
            points.append(np.asarray(p.xyz, dtype=np.float64))
            tracks.append(seen.astype(np.int64))
            errors.append(float(p.error))
    names = [im.name for im in registered]
    on_disk = sorted(
        str(p.relative_to(image_dir)) for p in image_dir.rglob("*") if p.suffix in IMAGE_SUFFIXES
    )
    return Capture(
        source=model,
        names=names,
        image_dir=image_dir,
        camera_to_world=np.stack(poses),
        lenses=lenses,
        points=np.stack(points) if points else np.zeros((0, 3)),
        point_tracks=tracks,
        point_errors=np.asarray(errors, dtype=np.float64),
        unregistered=sorted(set(on_disk) - set(names)),
    )

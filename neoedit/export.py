"""``neo render``: write renders of a scene as a nerfstudio dataset (RGB, metric depth) plus
colour-mapped depth and an optional video."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import imageio.v3 as iio
import numpy as np

from neoedit.cameras import Cameras, look_at
from neoedit.cameras.cameras import orbit_center
from neoedit.cameras.rays import CameraTensors
from neoedit.data.nerfstudio import load_cameras
from neoedit.data.validate import check_file_path
from neoedit.errors import NeoError
from neoedit.scene import Scene, load_scene
from neoedit.utils.io import (
    IMAGE_SUFFIXES,
    atomic_directory,
    atomic_write_json,
    check_writable_output,
    write_image,
    write_png,
)
from neoedit.utils.progress import track
from neoedit.utils.validate import check_memory

DEPTH_UNIT_M = 1e-3
MAX_FRAMES = 3600
"""Most spiral frames one render writes (two minutes of video at 30 fps)."""
RESERVED_DIRS = ("depth", "depth_vis")
RESERVED_FILES = ("transforms.json", "video.gif", "video.mp4")
"""What a render writes besides the RGB frames (no frame may be named so)."""


def spiral_cameras(cameras: Cameras, n_frames: int) -> Cameras:
    """A full orbit at the median distance and elevation of the cameras, looking at their centre."""
    center = orbit_center(cameras)
    offsets = cameras.camera_to_world[:, :3, 3] - center
    radius = float(np.median(np.linalg.norm(offsets, axis=1)))
    elev = float(np.median(np.arcsin(offsets[:, 2] / np.linalg.norm(offsets, axis=1))))
    az = np.linspace(0, 2 * np.pi, n_frames, endpoint=False)
    eyes = center + radius * np.stack(
        [np.cos(elev) * np.cos(az), np.cos(elev) * np.sin(az), np.full_like(az, np.sin(elev))], -1
    )
    poses = np.stack([look_at(e, center) for e in eyes])
    return cameras.with_poses(poses)


def colorize_depth(depth_m: np.ndarray, lo: float, hi: float) -> np.ndarray:
    """(H,W) metres -> (H,W,3) uint8 with the turbo colour map (0 = no depth: black)."""
    norm = np.clip((depth_m - lo) / max(hi - lo, 1e-6), 0, 1)
    import matplotlib  # lazy

    rgb = matplotlib.colormaps["turbo"](norm)[..., :3]
    rgb[depth_m <= 0] = 0
    return (rgb * 255).round().astype(np.uint8)


def render_to_dataset(
    scene: Scene, cameras: Cameras, names: list[str], out: Path, video: bool = False
) -> int:
    """Render every camera; RGB goes to out/<name> (names are relative file paths)."""
    device = scene.field.aabb.device
    cams = CameraTensors(cameras, device)
    frames, rgbs, depths = [], [], []
    for i in track(range(len(cameras)), "render"):
        r = scene.render_image(cams, i, int(cameras.height[i]), int(cameras.width[i]))
        rgb = (r["rgb"].clamp(0, 1).cpu().numpy() * 255).round().astype(np.uint8)
        depth = np.where(r["accumulation"].cpu().numpy() > 0.5, r["depth_z"].cpu().numpy(), 0.0)
        stem = Path(names[i]).with_suffix("")
        write_image(out / names[i], rgb)
        write_png(
            out / "depth" / f"{stem}.png",
            np.round(depth / DEPTH_UNIT_M).clip(0, 65535).astype(np.uint16),
        )
        frames.append(
            {
                "file_path": names[i],
                "depth_file_path": f"depth/{stem}.png",
                "transform_matrix": cameras.camera_to_world[i].tolist(),
                "fl_x": float(cameras.fx[i]),
                "fl_y": float(cameras.fy[i]),
                "cx": float(cameras.cx[i]),
                "cy": float(cameras.cy[i]),
                "w": int(cameras.width[i]),
                "h": int(cameras.height[i]),
            }
        )
        rgbs.append(rgb)
        depths.append((stem, depth))
    valid = np.concatenate([d[d > 0] for _, d in depths]) if depths else np.zeros(0)
    lo, hi = np.percentile(valid, [2, 98]) if len(valid) else (0.0, 1.0)
    vis = []
    for stem, depth in depths:
        img = colorize_depth(depth, float(lo), float(hi))
        write_png(out / "depth_vis" / f"{stem}.png", img)
        vis.append(img)
    atomic_write_json(
        out / "transforms.json",
        {
            "depth_unit_scale_factor": DEPTH_UNIT_M,
            "background_color": scene.meta.background_rgb,
            "frames": frames,
        },
    )
    if video and rgbs:
        strip = [np.concatenate([a, b], axis=1) for a, b in zip(rgbs, vis, strict=True)]
        iio.imwrite(out / "video.gif", strip, duration=1000 / 15, loop=0)
        if importlib.util.find_spec("imageio_ffmpeg") is not None:  # optional extra [video]
            iio.imwrite(out / "video.mp4", strip, fps=15)
    return len(rgbs)


BYTES_PER_RENDERED_PIXEL = 100
"""Memory one pixel of a view takes while it renders (its ray, the chunks' outputs and the
assembled images, colour and depth pictures), an upper estimate."""


BYTES_PER_KEPT_PIXEL = 20
"""Memory each rendered pixel keeps until the views are written (colour, depth, pictures)."""


def render_command(
    scene_dir: Path,
    out: Path,
    views: str,
    cameras_json: Path | None,
    n_frames: int,
    video: bool,
    device: str,
    overwrite: bool = False,
) -> int:
    """``neo render``: checks the options and OUT first, renders into a temporary folder
    that becomes OUT (marked as a render) only once every view is written."""
    from neoedit.utils.device import resolve_device

    if cameras_json is None and views == "spiral" and not 1 <= n_frames <= MAX_FRAMES:
        raise NeoError(f"--n-frames must be between 1 and {MAX_FRAMES}, got {n_frames}")
    check_writable_output(out, [scene_dir, cameras_json], "render", overwrite)
    if cameras_json is not None:  # checked before the scene loads
        cameras, names, _ = load_cameras(cameras_json)
        _check_names(names, cameras_json)
        _check_image_names(names, cameras_json)
        _check_view_memory(cameras)
    scene = load_scene(scene_dir, resolve_device(device))
    if cameras_json is None:
        data_cams, data_names, split = scene.scan_cameras()
        if views == "spiral":
            cameras = spiral_cameras(data_cams, n_frames)
            names = [f"images/spiral_{k:04d}.png" for k in range(n_frames)]
        else:
            idx = split["train" if views == "train" else "test"]
            if len(idx) == 0:
                raise NeoError(f"the scene's dataset has no '{views}' views")
            cameras = data_cams.subset(idx)
            names = [_as_image_name(data_names[i]) for i in idx]
        _check_names(names, "the scene's dataset")
        _check_view_memory(cameras)
    with atomic_directory(out, overwrite, kind="render") as tmp:
        return render_to_dataset(scene, cameras, names, tmp, video)


def _check_view_memory(cameras: Cameras) -> None:
    """The largest view while it renders, and every view's pictures, which the render keeps
    until it writes them."""
    pixels = cameras.width.astype(np.int64) * cameras.height
    k = int(np.argmax(pixels))
    need = int(pixels[k]) * BYTES_PER_RENDERED_PIXEL + int(pixels.sum()) * BYTES_PER_KEPT_PIXEL
    check_memory(
        need, f"rendering {len(pixels)} views (the largest {cameras.width[k]}x{cameras.height[k]})"
    )


def _check_image_names(names: list[str], where: object) -> None:
    """The names a user's cameras file gives its renders: image names we can write."""
    for name in names:
        if Path(name).suffix.lower() not in IMAGE_SUFFIXES:
            raise NeoError(
                f"{where}: file_path {name!r} is no image name: renders are written as "
                f"{' or '.join(IMAGE_SUFFIXES)}"
            )


def _as_image_name(name: str) -> str:
    """A dataset frame's name for its render: kept when it is a .png / .jpg, else .png (a
    .tif or suffix-less photo is rendered as a PNG under its own stem)."""
    path = Path(name)
    return name if path.suffix.lower() in IMAGE_SUFFIXES else str(path.with_suffix(".png"))


def _check_names(names: list[str], where: object) -> None:
    """Output file names: relative, inside OUT, one per view."""
    for name in names:
        check_file_path(name, f"{where}")
    for name in names:
        parts = Path(name).parts
        parts = parts[1:] if parts[:1] == (".",) else parts
        if parts[:1] and (
            parts[0] in RESERVED_DIRS or (len(parts) == 1 and parts[0] in RESERVED_FILES)
        ):
            raise NeoError(
                f"{where}: file_path {name!r} would overwrite the render's own "
                f"{'/'.join(parts[:1])}; the RGB frames go under another name (e.g. images/...)"
            )
    seen = {Path(n).with_suffix("").as_posix().removeprefix("./") for n in names}
    if len(seen) != len(names):
        raise NeoError(f"{where}: two frames share a file_path; each view needs its own name")
    plain = [Path(n).as_posix().removeprefix("./") for n in names]
    folders = {p.as_posix() for n in plain for p in Path(n).parents}
    for name in plain:
        if name in folders:
            raise NeoError(
                f"{where}: file_path {name!r} is also the folder of another frame's file_path; "
                "each view needs a name of its own"
            )

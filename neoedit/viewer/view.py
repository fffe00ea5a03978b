"""The viewer's cameras and what a camera shows.

viser's cameras follow OpenCV (x right, y down, looking down +z; orientation as a wxyz
quaternion), neoedit's OpenGL (x right, y up, looking down -z): the two camera-to-world
matrices differ by a flip of the y and z axes. A view is rendered through the scene's own
renderer (the fast no-gradient path) in ray chunks, checking between chunks whether the
render loop wants it stopped.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import torch
from scipy.spatial.transform import Rotation

from neoedit.cameras import Cameras
from neoedit.cameras.rays import CameraTensors
from neoedit.export import colorize_depth
from neoedit.language.relevancy import relevancy
from neoedit.rendering.renderer import render_chunked
from neoedit.scene import Scene
from neoedit.viewer.render_loop import RenderInterrupted
from neoedit.viz.boxes import relevancy_overlay

FLIP_YZ = np.diag([1.0, -1.0, -1.0, 1.0])
"""OpenGL camera-to-world @ FLIP_YZ = OpenCV camera-to-world (and back)."""
LANGUAGE_CHUNK = 65536
"""Points per language-field evaluation of the heat map."""


def quat_to_matrix(wxyz: np.ndarray) -> np.ndarray:
    """(3,3) rotation of a quaternion (w, x, y, z) (normalised first)."""
    return Rotation.from_quat(np.asarray(wxyz, dtype=np.float64), scalar_first=True).as_matrix()


def matrix_to_quat(rot: np.ndarray) -> np.ndarray:
    """Unit quaternion (w, x, y, z) of a (3,3) rotation (w >= 0)."""
    q = Rotation.from_matrix(np.asarray(rot, dtype=np.float64)).as_quat(scalar_first=True)
    return q if q[0] >= 0 else -q


def yaw_quat(yaw_deg: float) -> np.ndarray:
    """Quaternion of a rotation by ``yaw_deg`` about world +z."""
    half = math.radians(yaw_deg) / 2
    return np.array([math.cos(half), 0.0, 0.0, math.sin(half)])


def c2w_from_viser(wxyz: np.ndarray, position: np.ndarray) -> np.ndarray:
    """(4,4) OpenGL camera-to-world of a viser camera (OpenCV orientation + position)."""
    c2w = np.eye(4)
    c2w[:3, :3] = quat_to_matrix(wxyz)
    c2w[:3, 3] = np.asarray(position, dtype=np.float64)
    return c2w @ FLIP_YZ


def viser_pose(c2w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(wxyz, position) of an OpenGL camera-to-world as viser places cameras and frustums."""
    cv = np.asarray(c2w, dtype=np.float64) @ FLIP_YZ
    return matrix_to_quat(cv[:3, :3]), cv[:3, 3].copy()


def view_cameras(c2w: np.ndarray, fov_y: float, width: int, height: int) -> Cameras:
    """One pinhole camera (square pixels, centred principal point) of ``width`` x ``height``
    with vertical field of view ``fov_y`` (radians)."""
    if not 1e-3 < fov_y < math.pi - 1e-3:
        raise ValueError(f"field of view {math.degrees(fov_y):.1f} deg is not in (0, 180)")
    fy = height / (2.0 * math.tan(fov_y / 2.0))
    return Cameras.shared(np.asarray(c2w)[None], fy, fy, width / 2, height / 2, width, height)


@dataclass
class ScanView:
    """A camera of the scan, as the page shows it (a frustum; the first view)."""

    index: int
    c2w: np.ndarray = field(repr=False)
    fov_y: float
    aspect: float


def scan_views(scene: Scene, limit: int | None = None) -> list[ScanView]:
    """The scan's training cameras (all of them without any), at most ``limit`` spread
    evenly over them."""
    cameras, _, split = scene.scan_cameras()
    idx = np.asarray(split.get("train", np.arange(len(cameras))), dtype=np.int64)
    if len(idx) == 0:
        idx = np.arange(len(cameras))
    if limit is not None and len(idx) > limit:
        idx = idx[np.linspace(0, len(idx) - 1, limit).round().astype(int)]
    return [
        ScanView(
            int(i),
            cameras.camera_to_world[i],
            2.0 * math.atan(cameras.height[i] / (2.0 * cameras.fy[i])),
            float(cameras.width[i] / cameras.height[i]),
        )
        for i in idx
    ]


@torch.no_grad()
def render_view(
    scene: Scene, cameras: Cameras, should_stop: Callable[[], bool] | None = None
) -> dict[str, np.ndarray]:
    """rgb (H,W,3), depth_z (H,W) [m], accumulation (H,W) of camera 0, as the version
    renders (render-time edits included); :class:`RenderInterrupted` once ``should_stop()``."""
    h, w = int(cameras.height[0]), int(cameras.width[0])
    field_, boxes = scene.renderable()
    rays = CameraTensors(cameras, scene.field.aabb.device).image_rays(0, h, w)

    def check() -> None:
        if should_stop is not None and should_stop():
            raise RenderInterrupted

    out = render_chunked(
        field_, scene.grid, rays, scene.meta.render, scene.background, boxes, before_chunk=check
    )
    return {
        key: value.reshape(h, w, *value.shape[1:]).float().cpu().numpy()
        for key, value in out.items()
    }


@torch.no_grad()
def relevancy_map(
    scene: Scene,
    cameras: Cameras,
    depth_z: np.ndarray,
    valid: np.ndarray,
    embeddings: tuple[torch.Tensor, torch.Tensor],
    should_stop: Callable[[], bool] | None = None,
) -> np.ndarray:
    """(H,W) relevancy of the query at the surface each pixel sees (0 where none)."""
    assert scene.language is not None
    query, canonical = embeddings
    points = cameras.backproject_depth(0, np.where(valid, depth_z, 0.0))[valid]
    device = scene.field.aabb.device
    values = []
    for start in range(0, len(points), LANGUAGE_CHUNK):
        if should_stop is not None and should_stop():
            raise RenderInterrupted
        pts = torch.as_tensor(points[start : start + LANGUAGE_CHUNK], dtype=torch.float32)
        feats = scene.language.language(pts.to(device)).float().cpu()
        values.append(relevancy(feats, query, canonical))
    out = np.zeros(depth_z.shape, np.float32)
    if values:
        out[valid] = torch.cat(values).numpy()
    return out


def render_display(
    scene: Scene,
    c2w: np.ndarray,
    fov_y: float,
    width: int,
    height: int,
    settings: dict[str, Any],
    should_stop: Callable[[], bool] | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """(image (H,W,3) float in [0,1], z-depth (H,W) [m], inf where nothing is hit): the RGB
    render with the relevancy heat map of ``settings['relevancy']`` (query and canonical
    embeddings) when given, or the depth colour-mapped (``settings['mode'] == 'depth'``)."""
    cameras = view_cameras(c2w, fov_y, width, height)
    out = render_view(scene, cameras, should_stop)
    valid = out["accumulation"] > 0.5
    depth = np.where(valid, out["depth_z"], np.inf).astype(np.float32)
    if settings.get("mode") == "depth":
        seen = out["depth_z"][valid]
        lo, hi = np.percentile(seen, [2, 98]) if len(seen) else (0.0, 1.0)
        image = colorize_depth(np.where(valid, out["depth_z"], 0.0), float(lo), float(hi))
        return image.astype(np.float32) / 255.0, depth
    rgb = np.clip(out["rgb"], 0.0, 1.0)
    emb = settings.get("relevancy")
    if emb is not None and scene.language is not None and valid.any():
        rel = relevancy_map(scene, cameras, out["depth_z"], valid, emb, should_stop)
        shown = relevancy_overlay((rgb * 255).round().astype(np.uint8), rel, valid)
        return shown.astype(np.float32) / 255.0, depth
    return rgb.astype(np.float32), depth

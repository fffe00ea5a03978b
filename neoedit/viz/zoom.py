"""Before/after pictures a person can judge: full views of the scan beside a zoom on the
edited object. The zoom is a real render through a virtual camera that sees only the
object's neighbourhood (the scan camera's intrinsics cropped and scaled), so it shows the
field's detail, not enlarged pixels."""

from __future__ import annotations

import numpy as np

from neoedit.cameras import Cameras
from neoedit.geometry import OrientedBox
from neoedit.scene import Scene
from neoedit.viz.boxes import draw_box
from neoedit.viz.versions import pick_views, render_rgb

TILE_PX = 240
"""Width of each tile of a before/after picture (four tiles a row: 968 px)."""


def facing_view(cameras: Cameras, candidates: np.ndarray, point: np.ndarray) -> int:
    """The camera of ``candidates`` that looks most directly at ``point``."""
    centres = cameras.camera_to_world[candidates, :3, 3]
    to_point = point - centres
    to_point /= np.linalg.norm(to_point, axis=1, keepdims=True)
    forward = -cameras.camera_to_world[candidates, :3, 2]
    return int(candidates[int(np.argmax(np.sum(forward * to_point, axis=1)))])


def crop_camera(
    cameras: Cameras, index: int, points_m: np.ndarray, margin: float = 0.25
) -> tuple[Cameras, float] | None:
    """A one-camera set at camera ``index``'s pose, of its image size, that sees only the
    image region around the points' projection (plus ``margin`` of its size each side, the
    view's aspect ratio); with the zoom factor. None when the points are behind the
    camera."""
    uv, depth = cameras.project(index, np.asarray(points_m, dtype=np.float64).reshape(-1, 3))
    if not (depth > 1e-3).any():
        return None
    uv = uv[depth > 1e-3]
    lo, hi = uv.min(0), uv.max(0)
    w, h = float(cameras.width[index]), float(cameras.height[index])
    aspect = h / w
    span = (hi - lo) * (1 + 2 * margin) + 8.0
    crop_w = min(max(span[0], span[1] / aspect), w)
    crop_h = crop_w * aspect
    x0, y0 = (lo + hi) / 2 - np.array([crop_w, crop_h]) / 2
    s = w / crop_w
    cam = Cameras(
        cameras.camera_to_world[index : index + 1],
        np.array([cameras.fx[index] * s]),
        np.array([cameras.fy[index] * s]),
        np.array([(cameras.cx[index] - x0) * s]),
        np.array([(cameras.cy[index] - y0) * s]),
        np.array([int(cameras.width[index])]),
        np.array([int(cameras.height[index])]),
    )
    return cam, s


def edited_boxes(child: Scene) -> list[OrientedBox]:
    """The boxes of the child's own edit (removed, source, shadow and target boxes)."""
    edits = child.meta.edits
    if not edits or edits[-1].version != child.meta.version_id:
        return []
    return edits[-1].boxes("boxes", "source_boxes", "shadow_boxes", "target_boxes")


def report_views(parent: Scene, boxes: list[OrientedBox]) -> np.ndarray:
    """Two training views for a before/after picture: the one that looks most directly at
    the edited boxes and one a third of the scan further on (spread views without boxes)."""
    cameras, _, split = parent.scan_cameras()
    pool = np.asarray(split.get("train", np.arange(len(cameras))))
    if not boxes or len(pool) < 2:
        return pick_views(parent, 2, split="train")
    centre = np.mean([b.center_m for b in boxes], axis=0)
    first = facing_view(cameras, pool, centre)
    k = list(pool).index(first)
    return np.array([first, int(pool[(k + len(pool) // 3) % len(pool)])])


def before_after(
    parent: Scene, child: Scene, views: np.ndarray, width: int = TILE_PX
) -> tuple[list[np.ndarray], list[str], int]:
    """Tiles and labels of a before/after picture: per view, before | after (the whole view,
    the edited boxes outlined) and, when the edit has boxes, before | after zoomed on them;
    with the number of columns."""
    cameras, _, _ = parent.scan_cameras()
    # small scans render larger (up to 2x: the demo's 128 px scan fills the 240 px tiles)
    cameras = cameras.scaled(min(2.0, width / float(np.max(cameras.width))))
    boxes = edited_boxes(child)
    corners = np.concatenate([b.corners() for b in boxes]) if boxes else None
    tiles, labels = [], []
    for i in (int(v) for v in views):
        full = [render_rgb(s, cameras, i) for s in (parent, child)]
        for box in boxes:
            full = [draw_box(img, cameras, i, box, (255, 60, 60), 1) for img in full]
        tiles += full
        labels += [f"before (view {i})", f"after (view {i})"]
        crop = None if corners is None else crop_camera(cameras, i, corners)
        if crop is not None:
            cam, factor = crop
            tiles += [render_rgb(s, cam, 0) for s in (parent, child)]
            labels += [f"before, zoom {factor:.1f}x", f"after, zoom {factor:.1f}x"]
    return tiles, labels, 4 if corners is not None else 2

"""Grasps drawn over a render: finger and palm wireframes, the approach line."""

from __future__ import annotations

import cv2
import numpy as np

from neoedit.cameras import Cameras
from neoedit.geometry import OrientedBox
from neoedit.grasp.antipodal import Grasp
from neoedit.grasp.gripper import GripperConfig, box_corners, gripper_boxes
from neoedit.scene import Scene
from neoedit.viz.boxes import BOX_EDGES, draw_box
from neoedit.viz.contact_sheet import tile_images
from neoedit.viz.versions import render_rgb
from neoedit.viz.zoom import crop_camera, report_views

RANK_COLOURS = [(40, 220, 40), (250, 210, 30), (250, 140, 30), (230, 60, 60), (200, 60, 200)]


def draw_grasps(
    image: np.ndarray,
    cameras: Cameras,
    index: int,
    grasps: list[Grasp],
    gripper: GripperConfig,
    thickness: int = 1,
) -> np.ndarray:
    """Copy of ``image`` with each grasp drawn (best first: green, then yellow, orange, ...)."""
    out = np.ascontiguousarray(image.copy())
    for rank in range(len(grasps) - 1, -1, -1):  # the best drawn last, on top
        g = grasps[rank]
        colour = RANK_COLOURS[min(rank, len(RANK_COLOURS) - 1)]
        segments = []
        for centre, half in gripper_boxes(gripper, g.width_m):
            corners = box_corners(centre, half)
            segments += [(corners[a], corners[b]) for a, b in BOX_EDGES]
        segments.append((np.zeros(3), np.array([0.0, 0.0, -0.12])))  # the approach
        for a, b in segments:
            pts = np.stack([a, b]) @ g.rotation.T + g.position_m
            uv, depth = cameras.project(index, pts)
            if (depth <= 1e-3).any():
                continue
            pa, pb = (tuple(int(round(c)) for c in p) for p in uv)
            cv2.line(out, pa, pb, colour, thickness, cv2.LINE_AA)
    return out


SHOWN = 3
"""Grasps drawn in the picture (the best ones; the JSON lists every planned grasp)."""


def legend(grasps: list[Grasp], width: int) -> np.ndarray:
    """A white band, ``width`` px wide: one line per grasp, its rank colour, score, width
    and approach angle."""
    line = 26
    band = np.full((line * len(grasps) + 8, width, 3), 255, np.uint8)
    for rank, g in enumerate(grasps):
        y = 6 + rank * line
        colour = RANK_COLOURS[min(rank, len(RANK_COLOURS) - 1)]
        cv2.rectangle(band, (8, y + 4), (40, y + line - 6), colour, -1)
        text = (
            f"#{rank + 1}: score {g.score:.2f}, grip width {100 * g.width_m:.1f} cm, "
            f"approach {g.approach_deg:.0f} deg from vertical"
        )
        cv2.putText(
            band, text, (50, y + line - 8), cv2.FONT_HERSHEY_SIMPLEX, 0.55, (0, 0, 0), 1,
            cv2.LINE_AA,
        )  # fmt: skip
    return band


def grasp_picture(
    scene: Scene, box: OrientedBox, grasps: list[Grasp], gripper: GripperConfig, width: int = 320
) -> np.ndarray:
    """The view that faces the object (whole, object boxed, best grasps drawn) beside zooms
    on the object from it and from a third of the scan further on, with a legend: rank
    colours, scores and widths of the best :data:`SHOWN` grasps."""
    cameras = scene.scan_cameras()[0]
    cameras = cameras.scaled(width / float(np.max(cameras.width)))
    views = [int(v) for v in report_views(scene, [box])]
    first = views[0]
    best = grasps[:SHOWN]
    full = draw_box(render_rgb(scene, cameras, first), cameras, first, box, (90, 90, 255), 1)
    tiles = [draw_grasps(full, cameras, first, best, gripper)]
    labels = [f"view {first}"]
    reach = box.grown(0.03).corners()  # the object and the finger pads around it
    for i in dict.fromkeys(views):  # one zoom per view (a one-view scan: one)
        crop = crop_camera(cameras, i, reach, margin=0.1)
        if crop is None:
            continue
        cam, factor = crop
        tiles.append(draw_grasps(render_rgb(scene, cam, 0), cam, 0, best, gripper, 2))
        labels.append(f"view {i}, zoom {factor:.1f}x")
    sheet = tile_images(tiles, cols=len(tiles), labels=labels)
    return np.concatenate([sheet, legend(best, sheet.shape[1])], axis=0)

"""Virtual views around a removal box (paper Sec. III-B).

Cameras on a hemisphere centred on the box, optical axes through its centre, at four
opposing azimuths per turn (0, 90, 180, 270 deg + the turn's offset) and rising elevations:
a short upward spiral. With the defaults: 8 views in two turns from 25 to 60 deg elevation,
at the median distance of the training cameras to the box centre (so pixels cover the same
area as in the scan), with the intrinsics of the first training camera, at half its
resolution, or finer where the box would be small in them (:func:`view_scale`). Views of one
turn share a similar elevation, which the 2x2 grid inpainting relies on.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from neoedit.cameras import Cameras
from neoedit.cameras.cameras import look_at
from neoedit.geometry import OrientedBox
from neoedit.utils.options import at_least_one


@dataclass
class VirtualViewConfig:
    turns: int = at_least_one(2, most=16)
    """Turns of the spiral; each turn has 4 views at opposing azimuths."""
    elevation_min_deg: float = 25.0
    elevation_max_deg: float = 60.0
    radius_m: float = -1.0
    """Distance to the box centre; negative = median distance of the scan's cameras."""
    azimuth_offset_deg: float = 45.0
    """Azimuth of the first view (the next turn is shifted by half the spacing, 45 deg)."""
    image_scale: float = 0.5
    """Resolution of the virtual views relative to the scan's (half: 4x fewer rays to render,
    the completed surface is smooth anyway)."""
    min_box_px: float = 18.0
    """Finer views (up to ``max_scale``) where the longer side of the box's footprint (the
    hole left on the support) would span fewer pixels than this: an inpainter given a hole a few pixels wide fills it with the blur of its
    border. Measured on the README demo's soccer ball (128x96 scan, its box 6 px wide at
    half scale): its footprint came out 20/255 darker than the table around it; 6/255 with
    this (1.5 times the scan's scale), 7/255 with 24 or 32 px. 0: always ``image_scale``."""
    max_scale: float = 4.0
    """The most ``min_box_px`` may raise the views' scale to, relative to the scan's
    resolution (like ``image_scale``)."""


def virtual_views(
    boxes: list[OrientedBox],
    reference: Cameras,
    cfg: VirtualViewConfig | None = None,
    scale: float | None = None,
) -> Cameras:
    """The :func:`virtual_cameras` around each of ``boxes``, in order, all at one resolution:
    ``scale`` (None: :func:`view_scale`)."""
    cfg = cfg or VirtualViewConfig()
    scale = view_scale(boxes, reference, cfg) if scale is None else scale
    return Cameras.concat([virtual_cameras(b, reference, cfg, scale) for b in boxes])


def view_scale(boxes: list[OrientedBox], reference: Cameras, cfg: VirtualViewConfig) -> float:
    """The virtual views' scale relative to ``reference[0]``: ``cfg.image_scale``, raised
    (to ``cfg.max_scale`` at most) until the longer side of the smallest box's footprint
    spans ``cfg.min_box_px`` pixels at the views' distance."""
    scale = cfg.image_scale
    if cfg.min_box_px <= 0:
        return scale
    for box in boxes:
        span_px = float(reference.fx[0]) * float(max(box.size_m[:2])) / _radius(box, reference, cfg)
        scale = max(scale, min(cfg.max_scale, cfg.min_box_px / max(span_px, 1e-9)))
    return scale


def _radius(box: OrientedBox, reference: Cameras, cfg: VirtualViewConfig) -> float:
    """The views' distance to the box centre: ``cfg.radius_m``, or (negative) the median
    distance of the ``reference`` cameras."""
    if cfg.radius_m > 0:
        return cfg.radius_m
    centre = np.asarray(box.center_m, dtype=np.float64)
    return float(np.median(np.linalg.norm(reference.camera_to_world[:, :3, 3] - centre, axis=1)))


def virtual_cameras(
    box: OrientedBox,
    reference: Cameras,
    cfg: VirtualViewConfig | None = None,
    scale: float | None = None,
) -> Cameras:
    """4 * turns cameras looking at the box centre (intrinsics of ``reference[0]``, scaled by
    ``scale``; None: :func:`view_scale` of this box)."""
    cfg = cfg or VirtualViewConfig()
    center = np.asarray(box.center_m, dtype=np.float64)
    radius = _radius(box, reference, cfg)
    scale = view_scale([box], reference, cfg) if scale is None else scale
    n = 4 * max(cfg.turns, 1)
    k = np.arange(n)
    turn = k // 4
    azimuth = np.radians(cfg.azimuth_offset_deg + 90.0 * (k % 4) + 45.0 * turn)
    elevation = np.radians(np.linspace(cfg.elevation_min_deg, cfg.elevation_max_deg, n))
    eyes = center + radius * np.stack(
        [
            np.cos(elevation) * np.cos(azimuth),
            np.cos(elevation) * np.sin(azimuth),
            np.sin(elevation),
        ],
        -1,
    )
    poses = np.stack([look_at(e, center) for e in eyes])
    full = reference.with_poses(poses)
    return full.scaled(scale) if scale != 1.0 else full

"""Virtual views around a removal box (paper Sec. III-B).

Cameras on a hemisphere centred on the box, optical axes through its centre, at four
opposing azimuths per turn (0, 90, 180, 270 deg + the turn's offset) and rising elevations:
a short upward spiral. With the defaults: 8 views in two turns from 25 to 60 deg elevation,
at the median distance of the training cameras to the box centre (so pixels cover the same
area as in the scan), with the intrinsics of the first training camera. Views of one turn
share a similar elevation, which the 2x2 grid inpainting relies on.
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


def virtual_cameras(
    box: OrientedBox, reference: Cameras, cfg: VirtualViewConfig | None = None
) -> Cameras:
    """4 * turns cameras looking at the box centre (intrinsics of ``reference[0]``, scaled by
    ``cfg.image_scale``)."""
    cfg = cfg or VirtualViewConfig()
    center = np.asarray(box.center_m, dtype=np.float64)
    radius = cfg.radius_m
    if radius <= 0:
        radius = float(
            np.median(np.linalg.norm(reference.camera_to_world[:, :3, 3] - center, axis=1))
        )
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
    return full.scaled(cfg.image_scale) if cfg.image_scale != 1.0 else full


def concat_cameras(sets: list[Cameras]) -> Cameras:
    """One camera set from several (virtual views around several boxes, in order)."""
    return Cameras.concat(sets)

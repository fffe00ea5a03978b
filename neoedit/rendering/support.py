"""The support (table, floor) around a box, rendered on a grid in the box's frame.

Each grid cell is rendered by one ray that comes down to the box's bottom plane from
outside, at a given elevation, heading towards the box: the object does not stand in front
of the support it shades, and a floor learnt from oblique photos is seen as they saw it.
Used to find the shadow an object casts (:mod:`neoedit.edit.shadow`);
:func:`footprint_distance` also places the support points of the removal-footprint metric
(:mod:`neoedit.eval.footprint`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from neoedit.cameras import Cameras
from neoedit.fields.radiance import Field
from neoedit.geometry import OrientedBox
from neoedit.rendering.volume import render_weights

N_SAMPLES = 64
CHUNK = 1 << 16
MAX_CELLS = 256
"""Cells per side at most: a large box gets coarser cells (memory grows with their square)."""


@dataclass
class SupportView:
    """The support around a box on an (n, n) grid of cells in the box's frame."""

    rgb: np.ndarray
    """(n, n, 3) colour in [0, 1] of the surface each cell's ray meets (the light it
    stopped, divided by its opacity)."""
    opacity: np.ndarray
    """(n, n) the share of the ray's light stopped within the search window."""
    height_m: np.ndarray
    """(n, n) height of the surface met above the box's bottom [m] (its expected depth)."""
    axis: np.ndarray
    """(n,) the cells' coordinates along the box's x and y axes [m]."""

    @property
    def cell_m(self) -> float:
        """The cells' spacing [m] (coarser than asked for on large boxes)."""
        return float(self.axis[1] - self.axis[0]) if len(self.axis) > 1 else 0.0

    def away_m(self, box: OrientedBox) -> np.ndarray:
        """(n, n) horizontal distance of each cell from the box's footprint (0 inside)."""
        gx, gy = np.meshgrid(self.axis, self.axis, indexing="ij")
        return footprint_distance(gx, gy, box)

    def on_support(self, band_m: float) -> np.ndarray:
        """(n, n) cells whose ray ends opaque within ``band_m`` of the box's bottom."""
        return (self.opacity > 0.9) & (np.abs(self.height_m) < band_m)

    def luminance(self) -> np.ndarray:
        """(n, n) the cells' luminance (Rec. 601 weights)."""
        return self.rgb @ np.array([0.299, 0.587, 0.114])


def footprint_distance(x: np.ndarray, y: np.ndarray, box: OrientedBox) -> np.ndarray:
    """Horizontal distance [m] of points at (``x``, ``y``) in ``box``'s frame from its
    footprint (0 inside it)."""
    dx = np.maximum(np.abs(x) - box.half_extents[0], 0.0)
    dy = np.maximum(np.abs(y) - box.half_extents[1], 0.0)
    return np.hypot(dx, dy)


@torch.no_grad()
def support_around(
    field: Field,
    box: OrientedBox,
    half_extent_m: float,
    cell_m: float,
    band_m: float,
    elevation_deg: float,
) -> SupportView:
    """Render the support around ``box`` (``half_extent_m`` each way from its centre,
    ``cell_m`` apart, or coarser: at most :data:`MAX_CELLS` a side), each cell's ray
    sampled from 4 ``band_m`` above the box's bottom plane to 2 below it, coming down at
    ``elevation_deg``."""
    cell_m = max(cell_m, 2.0 * half_extent_m / (MAX_CELLS - 1))
    axis = np.arange(-half_extent_m, half_extent_m + 1e-9, cell_m)
    gx, gy = np.meshgrid(axis, axis, indexing="ij")
    bottom = box.center_m[2] - box.size_m[2] / 2
    local = np.stack([gx.ravel(), gy.ravel()], 1)
    xy = local @ box.rotation[:2, :2].T + box.center_m[:2]
    out = xy - box.center_m[:2]
    out[np.linalg.norm(out, axis=1) < 1e-9] = (1.0, 0.0)  # the centre cell: any heading
    out /= np.linalg.norm(out, axis=1, keepdims=True)
    el = np.radians(elevation_deg)
    heading = np.concatenate([-np.cos(el) * out, np.full((len(xy), 1), -np.sin(el))], 1)
    ends = np.concatenate([xy, np.full((len(xy), 1), bottom)], 1)
    reach_up, reach_down = 4 * band_m / np.sin(el), 2 * band_m / np.sin(el)
    t = -reach_up + (reach_up + reach_down) * (np.arange(N_SAMPLES) + 0.5) / N_SAMPLES
    pts = ends[:, None, :] + t[None, :, None] * heading[:, None, :]
    device = field.aabb.device
    points = torch.as_tensor(pts.reshape(-1, 3), dtype=torch.float32, device=device)
    dirs = torch.as_tensor(np.repeat(heading, N_SAMPLES, 0), dtype=torch.float32, device=device)
    aabb = field.aabb.to(device)
    inside = ((points >= aabb[0]) & (points <= aabb[1])).all(-1)
    sigma = torch.zeros(len(points), device=device)
    rgb = torch.zeros(len(points), 3, device=device)
    for s in range(0, len(points), CHUNK):
        part = slice(s, s + CHUNK)
        keep = inside[part]
        if keep.any():
            sg, cl = field(points[part][keep], dirs[part][keep])
            sigma[part][keep], rgb[part][keep] = sg.float(), cl.float()
    sigma, rgb = sigma.reshape(-1, N_SAMPLES), rgb.reshape(-1, N_SAMPLES, 3)
    weights = render_weights(sigma, torch.full_like(sigma, (reach_up + reach_down) / N_SAMPLES))
    acc = weights.sum(1)
    colour = (weights[..., None] * rgb).sum(1) / acc.clamp_min(1e-6)[:, None]
    z = torch.as_tensor(pts[..., 2], dtype=torch.float32, device=device)
    height = (weights * z).sum(1) / acc.clamp_min(1e-6) - bottom
    n = len(axis)
    return SupportView(
        colour.reshape(n, n, 3).cpu().numpy(),
        acc.reshape(n, n).cpu().numpy(),
        height.reshape(n, n).cpu().numpy(),
        axis,
    )


def scan_elevation_deg(cameras: Cameras, box: OrientedBox) -> float:
    """Median elevation [deg] of the scan's cameras seen from the box's bottom centre,
    kept within 15-75 deg."""
    foot = np.asarray(box.center_m, dtype=np.float64) - [0.0, 0.0, box.size_m[2] / 2]
    rel = cameras.camera_to_world[:, :3, 3] - foot
    el = np.degrees(np.arctan2(rel[:, 2], np.linalg.norm(rel[:, :2], axis=1)))
    return float(np.clip(np.median(el), 15.0, 75.0))

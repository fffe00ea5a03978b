"""The shadow an object casts on its support (beyond the paper, which leaves it in place).

A removal's box holds the object and the support under its footprint; the darkening the
object cast on the support *around* its footprint lies outside the box, so a removal left a
ghost of the object on the table (56 % of removal_1's Out pixels are that table; RESULTS).
:func:`shadow_slab` finds it in the field itself: rays over a grid around the footprint,
coming down from outside at the scan's elevation, render the support, and the cells darker
than the support further out,
connected to the footprint, are the shadow. The slab — a thin box on the support holding
them — joins the removal's region, so the patch re-learns that table from the inpainted
views like the table under the object.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.ndimage
import torch

from neoedit.cameras import Cameras
from neoedit.errors import NeoError
from neoedit.fields.composed import MaskedField
from neoedit.fields.radiance import Field
from neoedit.geometry import OrientedBox
from neoedit.rendering.volume import render_weights
from neoedit.scene import Scene

SLAB_LIFT_M = 0.002
"""A shadow slab starts this far above the support (the table itself is not cut)."""


@dataclass
class ShadowConfig:
    enabled: bool = True
    """Find the object's shadow on its support and remove it with the object."""
    reach: float = 1.0
    """How far from the footprint a shadow is looked for, in footprint sizes (the longer
    side of the box)."""
    ring: float = 0.5
    """Width of the ring beyond the reach whose median brightness is the unshadowed
    support's, in footprint sizes."""
    darker: float = 0.12
    """A support cell is in shadow when its luminance is at least this fraction below the
    ring's median."""
    cell_m: float = 0.004
    """Grid spacing of the vertical rays [m]."""
    band_m: float = 0.01
    """The support's rendered depth must lie within this of the box's bottom; the slab is
    this high."""

    def check(self, where: str = "--shadow") -> None:
        for name in ("reach", "ring", "darker", "cell_m", "band_m"):
            if not getattr(self, name) > 0:
                raise NeoError(f"{where}.{name.replace('_', '-')} must be > 0")
        if self.darker >= 1:
            raise NeoError(f"{where}.darker must be < 1")


@torch.no_grad()
def support_around(
    field: Field,
    box: OrientedBox,
    half_extent_m: float,
    cfg: ShadowConfig,
    elevation_deg: float,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Render the support around ``box`` on a grid in the box's frame (``half_extent_m``
    each way, ``cfg.cell_m`` apart), each cell by a ray that comes down at
    ``elevation_deg`` from outside, heading towards the box (so the object does not stand
    in front of the support it shades, and a floor learnt from oblique photos is seen as
    they saw it): (luminance (n,n), on_support (n,n) bool: the ray ends opaque within
    ``cfg.band_m`` of the box's bottom, grid coordinates (n,))."""
    axis = np.arange(-half_extent_m, half_extent_m + 1e-9, cfg.cell_m)
    gx, gy = np.meshgrid(axis, axis, indexing="ij")
    bottom = box.center_m[2] - box.size_m[2] / 2
    local = np.stack([gx.ravel(), gy.ravel()], 1)
    xy = local @ box.rotation[:2, :2].T + box.center_m[:2]
    out = xy - box.center_m[:2]
    out /= np.maximum(np.linalg.norm(out, axis=1, keepdims=True), 1e-9)
    el = np.radians(elevation_deg)
    heading = np.concatenate([-np.cos(el) * out, np.full((len(xy), 1), -np.sin(el))], 1)
    ends = np.concatenate([xy, np.full((len(xy), 1), bottom)], 1)
    # from 4 bands above the support down to 2 bands below it, along the ray
    reach_up, reach_down, n_samples = 4 * cfg.band_m / np.sin(el), 2 * cfg.band_m / np.sin(el), 64
    t = -reach_up + (reach_up + reach_down) * (np.arange(n_samples) + 0.5) / n_samples
    pts = ends[:, None, :] + t[None, :, None] * heading[:, None, :]
    device = field.aabb.device
    points = torch.as_tensor(pts.reshape(-1, 3), dtype=torch.float32, device=device)
    dirs = torch.as_tensor(np.repeat(heading, n_samples, 0), dtype=torch.float32, device=device)
    aabb = field.aabb.to(device)
    inside = ((points >= aabb[0]) & (points <= aabb[1])).all(-1)
    sigma = torch.zeros(len(points), device=device)
    rgb = torch.zeros(len(points), 3, device=device)
    for s in range(0, len(points), 1 << 16):
        part = slice(s, s + (1 << 16))
        keep = inside[part]
        if keep.any():
            sg, cl = field(points[part][keep], dirs[part][keep])
            sigma[part][keep], rgb[part][keep] = sg.float(), cl.float()
    sigma, rgb = sigma.reshape(-1, n_samples), rgb.reshape(-1, n_samples, 3)
    weights = render_weights(sigma, torch.full_like(sigma, (reach_up + reach_down) / n_samples))
    acc = weights.sum(1)
    colour = (weights[..., None] * rgb).sum(1) / acc.clamp_min(1e-6)[:, None]
    z = torch.as_tensor(pts[..., 2], dtype=torch.float32, device=device)
    depth = (weights * z).sum(1) / acc.clamp_min(1e-6)
    lum = colour @ torch.tensor([0.299, 0.587, 0.114], device=device)
    on_support = (acc > 0.9) & ((depth - bottom).abs() < cfg.band_m)
    n = len(axis)
    return lum.reshape(n, n).cpu().numpy(), on_support.reshape(n, n).cpu().numpy(), axis


def shadow_slab(
    field: Field, box: OrientedBox, cfg: ShadowConfig, elevation_deg: float = 45.0
) -> OrientedBox | None:
    """A thin box (the yaw of ``box``, on the support at its bottom) holding the support
    cells around the footprint that the object darkens, or None when nothing around it is
    darker than the support further out (or too little support is seen to tell)."""
    size = float(max(box.size_m[0], box.size_m[1]))
    reach = cfg.reach * size
    half = float(max(box.half_extents[:2])) + reach + cfg.ring * size
    lum, support, axis = support_around(field, box, half, cfg, elevation_deg)
    gx, gy = np.meshgrid(axis, axis, indexing="ij")
    # distance from the footprint (0 inside it), in the box's frame
    dx = np.maximum(np.abs(gx) - box.half_extents[0], 0.0)
    dy = np.maximum(np.abs(gy) - box.half_extents[1], 0.0)
    away = np.hypot(dx, dy)
    ring = support & (away > reach)
    if ring.sum() < 20:
        return None
    dark = support & (away > 0) & (away <= reach) & (lum < (1 - cfg.darker) * np.median(lum[ring]))
    footprint = away == 0
    labels, _ = scipy.ndimage.label(dark | footprint, structure=np.ones((3, 3)))
    touching = np.unique(labels[footprint])
    shadow = np.isin(labels, touching[touching > 0]) & dark
    if not shadow.any():
        return None
    cells = np.concatenate(
        [np.stack([gx[shadow], gy[shadow]], 1), [[-1, -1], [1, 1]] * box.half_extents[:2]]
    )
    lo, hi = cells.min(0) - cfg.cell_m, cells.max(0) + cfg.cell_m
    centre_xy = (lo + hi) / 2 @ box.rotation[:2, :2].T + box.center_m[:2]
    # from 2 mm over the support to a band over that: the removal preview's cut keeps the
    # table, whose points under the slab's footprint are inpainted as a box's low points
    # are (RefineConfig.support_band_m), and the patch's region reaches under it
    bottom = box.center_m[2] - box.size_m[2] / 2 + SLAB_LIFT_M
    return OrientedBox(
        (float(centre_xy[0]), float(centre_xy[1]), float(bottom + cfg.band_m / 2)),
        (float(hi[0] - lo[0]), float(hi[1] - lo[1]), cfg.band_m),
        box.yaw_deg,
    )


def scan_elevation_deg(cameras: Cameras, box: OrientedBox) -> float:
    """Median elevation [deg] of the scan's cameras seen from the box's bottom centre,
    kept within 15-75 deg."""
    foot = np.asarray(box.center_m, dtype=np.float64) - [0.0, 0.0, box.size_m[2] / 2]
    rel = cameras.camera_to_world[:, :3, 3] - foot
    el = np.degrees(np.arctan2(rel[:, 2], np.linalg.norm(rel[:, :2], axis=1)))
    return float(np.clip(np.median(el), 15.0, 75.0))


def shadow_slabs(
    field: Field, boxes: list[OrientedBox], cfg: ShadowConfig, cameras: Cameras | None = None
) -> list[OrientedBox]:
    """:func:`shadow_slab` of every box that casts one (none when ``cfg.enabled`` is off),
    each support seen at the elevation the scan's ``cameras`` saw it from (45 deg without)."""
    if not cfg.enabled:
        return []
    slabs = [
        shadow_slab(field, b, cfg, 45.0 if cameras is None else scan_elevation_deg(cameras, b))
        for b in boxes
    ]
    return [s for s in slabs if s is not None]


def scene_shadows(scene: Scene, boxes: list[OrientedBox], cfg: ShadowConfig) -> list[OrientedBox]:
    """:func:`shadow_slabs` of ``scene`` as it renders (its occupancy grid applied), the
    support seen at the elevation of its scan's cameras."""
    if not cfg.enabled:
        return []
    shown = MaskedField(scene.field, scene.grid.is_occupied)
    return shadow_slabs(shown, boxes, cfg, scene.scan_cameras()[0])

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

from neoedit.cameras import Cameras
from neoedit.errors import NeoError
from neoedit.fields.composed import MaskedField
from neoedit.fields.radiance import Field
from neoedit.geometry import OrientedBox
from neoedit.rendering.support import scan_elevation_deg, support_around
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
    """Grid spacing of the support's rays [m] (coarser around large boxes: at most 256
    cells a side)."""
    band_m: float = 0.01
    """The support's rendered depth must lie within this of the box's bottom; the slab is
    this high."""

    def check(self, where: str = "--shadow") -> None:
        for name in ("reach", "ring", "darker", "cell_m", "band_m"):
            if not getattr(self, name) > 0:
                raise NeoError(f"{where}.{name.replace('_', '-')} must be > 0")
        if self.darker >= 1:
            raise NeoError(f"{where}.darker must be < 1")


def shadow_slab(
    field: Field, box: OrientedBox, cfg: ShadowConfig, elevation_deg: float = 45.0
) -> OrientedBox | None:
    """A thin box (the yaw of ``box``, on the support at its bottom) holding the support
    cells around the footprint that the object darkens, or None when nothing around it is
    darker than the support further out (or too little support is seen to tell)."""
    size = float(max(box.size_m[0], box.size_m[1]))
    reach = cfg.reach * size
    half = float(max(box.half_extents[:2])) + reach + cfg.ring * size
    view = support_around(field, box, half, cfg.cell_m, cfg.band_m, elevation_deg)
    lum, support, axis = view.luminance(), view.on_support(cfg.band_m), view.axis
    gx, gy = np.meshgrid(axis, axis, indexing="ij")
    away = view.away_m(box)  # from the footprint (0 inside it), in the box's frame
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
    lo, hi = cells.min(0) - view.cell_m, cells.max(0) + view.cell_m
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

"""Does a removal's footprint look like the support around it?

Where an object stood, a good removal shows the table or floor as it continues around the
footprint; a poor one leaves a lighter or darker disc, a ghost of the object's base, or a
hole. :func:`footprint_contrast` renders the support around the removed box with
:func:`~neoedit.rendering.support.support_around` (rays coming down at the scan's
elevation: :func:`removal_footprint` for a scene version) and compares the median colour inside the footprint with the median colour of a
ring around it, beyond the reach of the object's shadow.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

from neoedit.fields.composed import MaskedField
from neoedit.fields.radiance import Field
from neoedit.fields.suppressed import with_removals
from neoedit.geometry import OrientedBox
from neoedit.rendering.support import scan_elevation_deg, support_around
from neoedit.scene import Scene


@dataclass
class FootprintContrast:
    """Median colours (0-255) of the footprint and of the ring, their largest channel
    difference, and the mean opacity the support rays found in each."""

    footprint_rgb: list[float]
    ring_rgb: list[float]
    delta: float
    """max over R, G, B of |footprint - ring| (0-255): 0 is a seamless footprint."""
    footprint_opacity: float
    ring_opacity: float

    def to_dict(self) -> dict:
        return asdict(self)


def footprint_contrast(
    field: Field,
    box: OrientedBox,
    elevation_deg: float = 45.0,
    inner: float = 0.8,
    ring: tuple[float, float] = (1.0, 1.5),
    cell_m: float = 0.004,
    band_m: float = 0.01,
) -> FootprintContrast:
    """The footprint (``box``'s bottom face shrunk to ``inner`` of its size) against the
    ring from ``ring[0]`` to ``ring[1]`` footprint sizes (the longer side) away from it,
    the support seen at ``elevation_deg``."""
    size = float(max(box.size_m[0], box.size_m[1]))
    half = float(max(box.half_extents[:2])) + ring[1] * size
    view = support_around(field, box, half, cell_m, band_m, elevation_deg)
    gx, gy = np.meshgrid(view.axis, view.axis, indexing="ij")
    foot = (np.abs(gx) <= inner * box.half_extents[0]) & (np.abs(gy) <= inner * box.half_extents[1])
    away = view.away_m(box)
    around = (away > ring[0] * size) & (away <= ring[1] * size)
    foot_rgb = 255.0 * np.median(view.rgb[foot], 0)
    ring_rgb = 255.0 * np.median(view.rgb[around], 0)
    return FootprintContrast(
        footprint_rgb=np.round(foot_rgb, 1).tolist(),
        ring_rgb=np.round(ring_rgb, 1).tolist(),
        delta=round(float(np.abs(foot_rgb - ring_rgb).max()), 1),
        footprint_opacity=round(float(view.opacity[foot].mean()), 3),
        ring_opacity=round(float(view.opacity[around].mean()), 3),
    )


def removal_footprint(scene: Scene, box: OrientedBox) -> FootprintContrast:
    """:func:`footprint_contrast` of ``scene`` as it renders (occupancy grid and render-time
    removals applied), the support seen at the elevation of its scan's cameras."""
    field, cut = scene.renderable()
    field, _ = with_removals(MaskedField(field, scene.grid.is_occupied), [], cut)
    elevation = scan_elevation_deg(scene.scan_cameras()[0], box)
    return footprint_contrast(field, box, elevation)

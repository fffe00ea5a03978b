"""The shadow an object casts on its support (beyond the paper, which leaves it in place).

A removal's box holds the object and the support under its footprint; the darkening the
object cast on the support *around* its footprint lies outside the box, so a removal left a
ghost of the object on the table (56 % of removal_1's Out pixels are that table; RESULTS).
:func:`find_shadow` finds it in the field itself: rays over a grid around the footprint,
coming down from outside at the scan's elevation, render the support, and the cells darker
than the support further out (blurred a little, of the support's hue, on a support not
patterned more strongly than a shadow), connected to the footprint, are the shadow. The
slab — a thin box on the support holding them — joins the removal's region, so the patch
re-learns that table from the inpainted views like the table under the object. A move also lays the shadow down again where the
object goes: :meth:`Shadow.shade_at` gives the ratio map (the shadowed support's luminance
over the lit support's) translated under the motion, which the field applies as a shade
(:mod:`neoedit.fields.shade`).
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
from neoedit.rendering.support import SupportView, scan_elevation_deg, support_around
from neoedit.scene import Scene
from neoedit.utils.options import spelt

SLAB_LIFT_M = 0.002
"""A shadow slab starts this far above the support (the table itself is not cut)."""
MAX_CHROMA_SHIFT = 0.08
"""A shadow cell's channel shares (r, g, b over their sum) stay within this (L1) of the lit
support's: a darker cell of another hue is an object's base, not its shadow."""
MIN_RATIO = 0.35
"""Inside the box's footprint, support darker than this share of the lit support is taken
for the object's own base, not its shadow (a shadow keeps the room's ambient light)."""


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
    darker: float = 0.05
    """A support cell is in shadow when its luminance (smoothed) is at least this fraction
    below the ring's median."""
    smooth_cells: float = 1.5
    """Gaussian blur of the support's luminance before the comparison, in cells: a table's
    grain is as dark as a soft shadow cell by cell, not on average."""
    max_texture: float = 0.25
    """No shadow is looked for on a support whose own pattern darkens a tenth of the lit ring
    by more than this fraction of its brightest tenth (a checkerboard, tiles): a soft shadow
    cannot be told from it. Measured on NEO-Sim's checker tables (removal_4, _5), the search took
    squares for shadows and cost 1.5 and 0.3 dB Out-PSNR; wood grain darkens a tenth of
    the ring by 10-15 %."""
    cell_m: float = 0.004
    """Grid spacing of the support's rays [m] (coarser around large boxes: at most 256
    cells a side)."""
    band_m: float = 0.01
    """The support's rendered depth must lie within this of the box's bottom; the slab is
    this high."""

    def check(self, where: str = "") -> None:
        """Refuse settings the search cannot run with; ``where``: the options' prefix on the
        command line ('': none)."""
        if not self.smooth_cells >= 0:
            raise NeoError(f"{spelt(where, 'smooth_cells')} must be >= 0")
        for name in ("reach", "ring", "darker", "max_texture", "cell_m", "band_m"):
            if not getattr(self, name) > 0:
                raise NeoError(f"{spelt(where, name)} must be > 0")
        if self.darker >= 1:
            raise NeoError(f"{spelt(where, 'darker')} must be < 1")
        if self.max_texture > 1:
            raise NeoError(f"{spelt(where, 'max_texture')} must be <= 1")


@dataclass
class Shadow:
    """The shadow found around an object's ``box``: the cells of the support it darkens and
    the shading ratio there (the support's luminance over the unshadowed support's)."""

    box: OrientedBox
    slab: OrientedBox
    """A thin box (the yaw of ``box``, on the support at its bottom) holding the shadowed
    cells and the footprint: what a removal re-learns with the object."""
    axis: np.ndarray
    """(n,) the cells' coordinates along the box's x and y axes [m]."""
    ratio: np.ndarray
    """(n, n) the shading ratio in (0, 1] per cell (1 where nothing is shadowed; under the
    footprint, that of the shadow beside it)."""
    support_z_m: float
    """Height of the support's surface around the box (the lit ring's median) [m]."""
    band_m: float

    def shade_at(self, motion: np.ndarray) -> tuple[OrientedBox, np.ndarray]:
        """The slab and ratio map of this shadow laid down where the rigid ``motion`` (4, 4)
        takes the object. The light stays where it was: the map is translated with the
        object, not turned (exact for a yaw-symmetric object, an approximation for others)."""
        span = float(self.axis[-1] - self.axis[0])
        mid = (float(self.axis[0]) + float(self.axis[-1])) / 2  # the map's centre, box frame
        centre = np.asarray(self.box.center_m[:2]) + self.box.rotation[:2, :2] @ [mid, mid]
        foot = np.array([*centre, self.support_z_m, 1.0])
        x, y, z = (float(v) for v in (np.asarray(motion, dtype=np.float64) @ foot)[:3])
        slab = OrientedBox((x, y, z), (span, span, 2 * self.band_m), self.box.yaw_deg)
        return slab, self.ratio.astype(np.float32)


def find_shadow(
    field: Field, box: OrientedBox, cfg: ShadowConfig, elevation_deg: float = 45.0
) -> Shadow | None:
    """The support cells around the footprint of ``box`` that the object darkens (its
    luminance, smoothed, at least ``cfg.darker`` below the ring's median, connected to the
    footprint), or None when there are none, too little support is seen to tell, or the
    support's own pattern is stronger than a shadow (``cfg.max_texture``)."""
    size = float(max(box.size_m[0], box.size_m[1]))
    reach = cfg.reach * size
    half = float(max(box.half_extents[:2])) + reach + cfg.ring * size
    view = support_around(field, box, half, cfg.cell_m, cfg.band_m, elevation_deg)
    support, away = view.on_support(cfg.band_m), view.away_m(box)
    footprint = away == 0
    ring = support & (away > reach)
    if ring.sum() < 20 or _textured(view.luminance()[ring], cfg.max_texture):
        return None
    # a shadow darkens the support's colour but keeps its hue: cells of another hue (the
    # object's own base, another object) are neither shadow nor blurred into it
    chroma = _chroma(view.rgb)
    hue_kept = np.abs(chroma - np.median(chroma[ring], axis=0)).sum(-1) < MAX_CHROMA_SHIFT
    # the support seen inside the box's footprint counts (a box is larger than its object,
    # and the darkest shadow lies next to the object)
    ratio = _smoothed(view.luminance(), support & hue_kept, cfg.smooth_cells)
    ratio = ratio / max(float(np.median(ratio[ring])), 1e-6)
    dark = support & hue_kept & (away <= reach) & (ratio < 1 - cfg.darker)
    dark &= ~footprint | (ratio > MIN_RATIO)
    labels, _ = scipy.ndimage.label(dark | footprint, structure=np.ones((3, 3)))
    touching = np.unique(labels[footprint])
    shadow = np.isin(labels, touching[touching > 0]) & dark
    if not (shadow & ~footprint).any():
        return None
    shade = _shade(ratio, shadow, footprint & ~(support & hue_kept))
    support_z = box.center_m[2] - box.size_m[2] / 2 + float(np.median(view.height_m[ring]))
    return Shadow(box, _slab(view, box, shadow, cfg), view.axis, shade, support_z, cfg.band_m)


def _textured(ring_luminance: np.ndarray, max_texture: float) -> bool:
    """Whether the lit ring's own pattern is too strong to tell a soft shadow from it."""
    low, high = np.percentile(ring_luminance, [10, 90])
    return float(low) < (1.0 - max_texture) * float(high)


def _chroma(rgb: np.ndarray) -> np.ndarray:
    """(..., 3) the colour's shares of its channels' sum (brightness divided out)."""
    return rgb / np.maximum(rgb.sum(-1, keepdims=True), 1e-6)


def _smoothed(values: np.ndarray, valid: np.ndarray, sigma: float) -> np.ndarray:
    """``values`` blurred over the ``valid`` cells only (a normalised Gaussian convolution)."""
    if sigma <= 0:
        return values.copy()
    w = scipy.ndimage.gaussian_filter(valid.astype(np.float64), sigma)
    v = scipy.ndimage.gaussian_filter(np.where(valid, values, 0.0), sigma)
    return np.where(w > 1e-3, v / np.maximum(w, 1e-3), values)


def _shade(ratio: np.ndarray, shadow: np.ndarray, hidden: np.ndarray) -> np.ndarray:
    """The ratio map of a shadow: its darkening on the shadowed cells (edges feathered by a
    cell), none elsewhere; under the object (the ``hidden`` cells) the darkening around it,
    so a turned object does not stand in a lit gap."""
    dark = np.where(shadow, np.clip(1.0 - ratio, 0.0, 0.8), 0.0)
    dark = scipy.ndimage.gaussian_filter(dark, 1.0)
    filled = _smoothed(dark, ~hidden, 3.0)
    dark = np.where(hidden, filled, dark)
    dark[dark < 1e-3] = 0.0  # the blur's tails: the lit support stays exactly as it is
    return np.clip(1.0 - dark, 0.2, 1.0)


def _slab(
    view: SupportView, box: OrientedBox, shadow: np.ndarray, cfg: ShadowConfig
) -> OrientedBox:
    """A thin box (the yaw of ``box``) holding the ``shadow`` cells and the footprint."""
    gx, gy = np.meshgrid(view.axis, view.axis, indexing="ij")
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


def find_shadows(
    field: Field, boxes: list[OrientedBox], cfg: ShadowConfig, cameras: Cameras | None = None
) -> list[Shadow | None]:
    """:func:`find_shadow` per box (all None when ``cfg.enabled`` is off), each support seen
    at the elevation the scan's ``cameras`` saw it from (45 deg without)."""
    if not cfg.enabled:
        return [None] * len(boxes)
    return [
        find_shadow(field, b, cfg, 45.0 if cameras is None else scan_elevation_deg(cameras, b))
        for b in boxes
    ]


def scene_shadows(scene: Scene, boxes: list[OrientedBox], cfg: ShadowConfig) -> list[Shadow | None]:
    """:func:`find_shadows` of ``scene`` as it renders (its occupancy grid applied), the
    support seen at the elevation of its scan's cameras."""
    if not cfg.enabled:
        return [None] * len(boxes)
    shown = MaskedField(scene.field, scene.grid.is_occupied)
    return find_shadows(shown, boxes, cfg, scene.scan_cameras()[0])

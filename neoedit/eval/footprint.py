"""Does a removal's footprint look like the support around it?

Where an object stood, a good removal shows the table or floor as it continues around the
footprint; a poor one leaves a lighter or darker disc, a ghost of the object's base, or a
hole. :func:`footprint_contrast` looks at points of the support plane (the box's bottom)
from the scan's own cameras — one ray from a camera to each point, rendered as a photo of
that camera would be, the background or room included — and compares the median colour
over the footprint with the median colour over a ring around it, beyond the reach of the
object's shadow (1-1.5 footprint sizes: the shadow search's reach and ring). It measures
what the photos would show: where the field leaves the support to a learned background
(low ``ring_opacity``), a footprint that shows the same background matches too.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import asdict, dataclass

import numpy as np
import torch

from neoedit.cameras import Cameras
from neoedit.cameras.rays import RayBundle
from neoedit.errors import NeoError
from neoedit.fields.background import Background
from neoedit.fields.radiance import Field
from neoedit.geometry import OrientedBox
from neoedit.rendering.occupancy import OccupancyGrid
from neoedit.rendering.renderer import RenderConfig, render_chunked
from neoedit.rendering.support import footprint_distance
from neoedit.scene import Scene

MAX_POINTS = 1500
"""Support points per region (footprint, ring): a fixed random subset beyond this."""


@dataclass
class FootprintContrast:
    """Median colours (0-255) of the footprint and of the ring as the scan's cameras see
    them, their largest channel difference, and the mean opacity of the box's field along
    those rays."""

    footprint_rgb: list[float]
    ring_rgb: list[float]
    delta: float
    """max over R, G, B of |footprint - ring| (0-255): 0 is a seamless footprint."""
    footprint_opacity: float
    """How much of the light the box's own field stops (the rest comes from the room or
    background: a support the field never learnt)."""
    ring_opacity: float
    views: int

    def to_dict(self) -> dict:
        return asdict(self)


def support_points(
    box: OrientedBox, inner: float, ring: tuple[float, float], cell_m: float
) -> tuple[np.ndarray, np.ndarray]:
    """World points (N,3) on the plane of ``box``'s bottom: its footprint shrunk to
    ``inner``, and the ring ``ring[0]``-``ring[1]`` footprint sizes (the longer side) away
    (each a fixed random subset of at most :data:`MAX_POINTS`)."""
    size = float(max(box.size_m[0], box.size_m[1]))
    k = int(np.ceil((float(max(box.half_extents[:2])) + ring[1] * size) / cell_m))
    axis = cell_m * np.arange(-k, k + 1)  # the centre is a grid point
    gx, gy = (g.ravel() for g in np.meshgrid(axis, axis, indexing="ij"))
    hx, hy = box.half_extents[:2]
    away = footprint_distance(gx, gy, box)
    foot = (np.abs(gx) <= inner * hx) & (np.abs(gy) <= inner * hy)
    around = (away > ring[0] * size) & (away <= ring[1] * size)
    if not foot.any() or not around.any():
        raise NeoError(f"box {box.size_m} is too small to measure its footprint")
    bottom = box.center_m[2] - box.size_m[2] / 2
    rng = np.random.default_rng(0)

    def world(mask: np.ndarray) -> np.ndarray:
        local = np.stack([gx[mask], gy[mask]], 1)
        if len(local) > MAX_POINTS:
            local = local[np.sort(rng.choice(len(local), MAX_POINTS, replace=False))]
        xy = local @ box.rotation[:2, :2].T + box.center_m[:2]
        return np.concatenate([xy, np.full((len(xy), 1), bottom)], 1)

    return world(foot), world(around)


def facing_views(cameras: Cameras, point: np.ndarray, views: int) -> list[int]:
    """Up to ``views`` cameras, evenly spread over the scan, in whose image ``point`` lies."""
    seen = []
    for i in range(len(cameras.camera_to_world)):
        uv, z = cameras.project(i, point[None])
        u, v = uv[0]
        if z[0] > 0 and 0 <= u < cameras.width[i] and 0 <= v < cameras.height[i]:
            seen.append(i)
    if len(seen) <= views:
        return seen
    return [seen[int(k)] for k in np.linspace(0, len(seen) - 1, views).round()]


def _rays(cameras: Cameras, index: int, points: np.ndarray) -> RayBundle:
    c2w = cameras.camera_to_world[index]
    d = points - c2w[:3, 3]
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    as_t = lambda a: torch.as_tensor(a, dtype=torch.float32)  # noqa: E731
    return RayBundle(
        as_t(np.broadcast_to(c2w[:3, 3], d.shape).copy()), as_t(d), as_t(d @ -c2w[:3, 2])
    )


@torch.no_grad()
def footprint_contrast(
    field: Field,
    grid: OccupancyGrid | None,
    background: Background,
    render: RenderConfig,
    cameras: Cameras,
    box: OrientedBox,
    cut: Sequence[OrientedBox] = (),
    views: int = 8,
    inner: float = 0.8,
    ring: tuple[float, float] = (1.0, 1.5),
    cell_m: float = 0.004,
    exclude: Sequence[OrientedBox] = (),
) -> FootprintContrast:
    """The footprint of ``box`` against the ring around it, seen from ``views`` of
    ``cameras`` (those that have the footprint in their image); ring points under any of
    ``exclude`` are left out (a moved object's new place, near its old one)."""
    foot, around = support_points(box, inner, ring, cell_m)
    around = around[~_under_any(around, exclude)]
    if not len(around):
        raise NeoError("the ring around the footprint lies under the excluded boxes")
    bottom_centre = np.asarray(box.center_m) - [0.0, 0.0, box.size_m[2] / 2]
    chosen = facing_views(cameras, bottom_centre, views)
    if not chosen:
        raise NeoError("no camera of the scan has the footprint in its image")
    device = field.aabb.device
    seen: dict[str, list[torch.Tensor]] = {"rgb_f": [], "rgb_r": [], "acc_f": [], "acc_r": []}
    for i in chosen:
        for key, points in (("f", foot), ("r", around)):
            rays = _rays(cameras, i, points)
            rays = RayBundle(*(t.to(device) for t in (rays.origins, rays.directions, rays.z_scale)))
            out = render_chunked(field, grid, rays, render, background, cut)
            seen[f"rgb_{key}"].append(out["rgb"].float().cpu())
            seen[f"acc_{key}"].append(out["accumulation"].float().cpu())
    rgb_f = 255.0 * torch.cat(seen["rgb_f"]).median(0).values.numpy()
    rgb_r = 255.0 * torch.cat(seen["rgb_r"]).median(0).values.numpy()
    return FootprintContrast(
        footprint_rgb=np.round(rgb_f, 1).tolist(),
        ring_rgb=np.round(rgb_r, 1).tolist(),
        delta=round(float(np.abs(rgb_f - rgb_r).max()), 1),
        footprint_opacity=round(float(torch.cat(seen["acc_f"]).mean()), 3),
        ring_opacity=round(float(torch.cat(seen["acc_r"]).mean()), 3),
        views=len(chosen),
    )


def removal_footprint(
    scene: Scene, box: OrientedBox, views: int = 8, exclude: Sequence[OrientedBox] = ()
) -> FootprintContrast:
    """:func:`footprint_contrast` of ``scene`` as it renders, seen from its scan's cameras."""
    field, cut = scene.renderable()
    cameras = scene.scan_cameras()[0]
    return footprint_contrast(
        field, scene.grid, scene.background, scene.meta.render, cameras, box, cut, views,
        exclude=exclude,
    )  # fmt: skip


def _under_any(points: np.ndarray, boxes: Sequence[OrientedBox]) -> np.ndarray:
    """(N,) bool: the points (N,3) whose x, y lie within the footprint of any of ``boxes``."""
    under = np.zeros(len(points), bool)
    for b in boxes:
        local = b.world_to_local(points)
        under |= footprint_distance(local[:, 0], local[:, 1], b) == 0.0
    return under

"""Render rays of a radiance field: intervals -> grid proposal -> PDF samples -> field -> composite.

``boxes`` are removal boxes (paper Sec. III-A): their segments are cut out of every ray
before sampling, so the preview of a removal needs no training.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import torch

from neoedit.cameras.rays import CameraTensors, RayBundle
from neoedit.fields.background import Background
from neoedit.fields.radiance import Field
from neoedit.geometry import OrientedBox
from neoedit.geometry.rays import ray_aabb
from neoedit.rendering.coarse import fine_edges
from neoedit.rendering.intervals import RayIntervals, cut_boxes, near_far_intervals
from neoedit.rendering.march import march_render
from neoedit.rendering.occupancy import OccupancyGrid
from neoedit.rendering.outside import outside_light
from neoedit.rendering.samplers import pdf_edges, uniform_edges
from neoedit.rendering.volume import composite, render_weights


@dataclass
class RenderConfig:
    n_march_samples: int = 256
    """Evenly spaced candidate bins per ray over its valid domain, checked on the occupancy grid."""
    n_coarse_samples: int = 32
    """Density-only network queries per ray (no gradient), spread over the occupied candidates
    (or evenly spaced before the grid is trained). Their weights drive the PDF pass."""
    n_samples: int = 32
    """Network samples per ray drawn by PDF resampling on the same domain (these are rendered)."""
    near_m: float = -1.0
    """Closest distance from the camera that is rendered; negative = automatic, set at
    training time to a quarter of the median camera distance to the point the cameras look
    at (keeps the field from explaining single views with fog right in front of a camera)."""
    chunk_rays: int = 8192
    """Rays per chunk when rendering whole images."""
    fast_render: bool = True
    """Renders without gradients (images, evaluation, previews, the viewer) march the
    occupancy grid with early ray termination (neoedit.rendering.march) instead of the
    training sampler: measured 8x faster on 2 CPU cores at the same held-out PSNR."""


@dataclass
class RaySamples:
    intervals: RayIntervals
    edges: torch.Tensor  # (N, M+1) bin edges in domain coordinates
    t_mid: torch.Tensor  # (N, M) ray distance of bin midpoints
    deltas: torch.Tensor  # (N, M) bin widths [m]
    points: torch.Tensor  # (N, M, 3) world

    def bin_bounds(self) -> tuple[torch.Tensor, torch.Tensor]:
        """Lower and upper domain coordinates (N, M) of each bin."""
        return self.edges[:, :-1], self.edges[:, 1:]

    @classmethod
    def from_edges(
        cls, rays: RayBundle, intervals: RayIntervals, edges: torch.Tensor
    ) -> RaySamples:
        mid = 0.5 * (edges[:, 1:] + edges[:, :-1])
        t_mid = intervals.domain_to_t(mid)
        points = rays.origins[:, None, :] + t_mid[..., None] * rays.directions[:, None, :]
        return cls(intervals, edges, t_mid, edges[:, 1:] - edges[:, :-1], points)


def ray_intervals(
    field: Field, rays: RayBundle, near_m: float, boxes: Sequence[OrientedBox] = ()
) -> RayIntervals:
    """Valid part of each ray: inside the scene box, beyond ``near_m``, outside every removal box."""
    t0, t1 = ray_aabb(rays.origins, rays.directions, field.aabb)
    t0 = t0.clamp_min(max(near_m, 0.0))  # an unresolved automatic near plane (< 0) means 0
    intervals = near_far_intervals(t0, torch.maximum(t1, t0))
    return cut_boxes(intervals, rays.origins, rays.directions, boxes) if boxes else intervals


def sample_rays(
    field: Field,
    grid: OccupancyGrid | None,
    rays: RayBundle,
    cfg: RenderConfig,
    boxes: Sequence[OrientedBox] = (),
    jitter: bool = False,
    generator: torch.Generator | None = None,
    intervals: RayIntervals | None = None,
) -> RaySamples:
    """Two-stage sampling on each ray's valid domain (paper Sec. III-A).

    1. Coarse: with a grid, march ``n_march_samples`` even bins, skip those in empty cells
       and query the density (no gradient) of up to ``n_coarse_samples`` occupied ones,
       spread over all of them; without a grid, query ``n_coarse_samples`` even bins.
       Empty bins have zero optical depth.
    2. Fine: ``n_samples`` bins by PDF resampling of those weights on the same domain.

    With a grid both stages are :func:`neoedit.rendering.coarse.fine_edges` (compiled on CPU).

    ``intervals`` replaces the valid domain (scene box, near plane, ``boxes`` cut out).
    """
    if intervals is not None and boxes:
        raise ValueError("give removal boxes or the intervals to sample, not both")
    if intervals is None:
        intervals = ray_intervals(field, rays, cfg.near_m, boxes)
    if grid is not None:
        fine = fine_edges(
            field, grid, rays, intervals, cfg.n_march_samples, cfg.n_coarse_samples,
            cfg.n_samples, jitter, generator,
        )  # fmt: skip
        return RaySamples.from_edges(rays, intervals, fine)
    edges = uniform_edges(intervals.total, cfg.n_coarse_samples, jitter, generator)
    coarse = RaySamples.from_edges(rays, intervals, edges)
    with torch.no_grad():
        sigma = field.density(coarse.points.reshape(-1, 3)).reshape(coarse.t_mid.shape)
    weights = render_weights(sigma, coarse.deltas)
    fine = pdf_edges(edges, weights, cfg.n_samples, jitter, generator)
    return RaySamples.from_edges(rays, intervals, fine)


def render_rays(
    field: Field,
    grid: OccupancyGrid | None,
    rays: RayBundle,
    cfg: RenderConfig,
    background: Background,
    boxes: Sequence[OrientedBox] = (),
    jitter: bool = False,
    generator: torch.Generator | None = None,
    intervals: RayIntervals | None = None,
) -> dict[str, torch.Tensor]:
    """rgb (N,3), depth (N,) ray distance [m], depth_z (N,) z-depth [m], accumulation (N,),
    weights (N,M) and the samples (depth and accumulation are the box's; a room background
    in training adds its distortion loss (N,) as ``outside_distortion``: the room's own and,
    with ``joint_distortion``, its terms with the box's samples). With a grid, samples in empty cells skip the network.
    ``intervals``: the domain to sample instead of each ray's valid one."""
    samples = sample_rays(field, grid, rays, cfg, boxes, jitter, generator, intervals)
    n, m = samples.t_mid.shape
    pts = samples.points.reshape(-1, 3)
    dirs = rays.directions[:, None, :].expand(n, m, 3).reshape(-1, 3)
    keep = samples.deltas.reshape(-1) > 0
    if grid is not None:
        keep &= grid.is_occupied(pts)
    idx = torch.nonzero(keep)[:, 0]
    sigma_k, rgb_k = field(pts[idx], dirs[idx])
    sigma = torch.zeros(n * m, device=pts.device, dtype=sigma_k.dtype).index_put((idx,), sigma_k)
    rgb = torch.zeros(n * m, 3, device=pts.device, dtype=rgb_k.dtype).index_put((idx,), rgb_k)
    weights = render_weights(sigma.reshape(n, m), samples.deltas)
    light = outside_light(background, rays.origins, rays.directions, cfg.near_m, jitter, generator)
    out = composite(weights, rgb.reshape(n, m, 3), samples.t_mid, light.back_rgb)
    out["rgb"] = light.around(out["rgb"])
    if light.distortion is not None:
        out["outside_distortion"] = light.distortion
        if light.moments is not None:
            trans = torch.as_tensor(light.front_trans, dtype=weights.dtype)
            out["outside_distortion"] = out["outside_distortion"] + light.moments.box_distortion(
                weights, samples.t_mid, trans
            )
    out["depth_z"] = out["depth"] * rays.z_scale
    out["weights"] = weights
    lo, hi = samples.bin_bounds()
    out["s_lo"], out["s_hi"] = lo, hi
    out["sigma"] = sigma.reshape(n, m)
    out["t_mid"] = samples.t_mid
    return out


@torch.no_grad()
def render_chunked(
    field: Field,
    grid: OccupancyGrid | None,
    rays: RayBundle,
    cfg: RenderConfig,
    background: Background,
    boxes: Sequence[OrientedBox] = (),
    before_chunk: Callable[[], None] | None = None,
) -> dict[str, torch.Tensor]:
    """rgb (N,3), depth_z (N,) [m], accumulation (N,) of many rays, in chunks, no gradients.
    ``before_chunk()`` runs before each chunk (a caller that may abandon the render raises
    there: the viewer, when the camera has moved on)."""
    parts: dict[str, list[torch.Tensor]] = {"rgb": [], "depth_z": [], "accumulation": []}
    for start in range(0, len(rays), cfg.chunk_rays):
        if before_chunk is not None:
            before_chunk()
        chunk = rays[start : start + cfg.chunk_rays]
        if cfg.fast_render and grid is not None:
            intervals = ray_intervals(field, chunk, cfg.near_m, boxes)
            out = march_render(
                field, grid, chunk, intervals, cfg.n_march_samples, background, cfg.near_m
            )
        else:
            out = render_rays(field, grid, chunk, cfg, background, boxes)
        for key in parts:
            parts[key].append(out[key])
    return {key: torch.cat(values) for key, values in parts.items()}


def render_image(
    field: Field,
    grid: OccupancyGrid | None,
    cameras: CameraTensors,
    index: int,
    height: int,
    width: int,
    cfg: RenderConfig,
    background: Background,
    boxes: Sequence[OrientedBox] = (),
) -> dict[str, torch.Tensor]:
    """rgb (H,W,3), depth_z (H,W) [m], accumulation (H,W) of camera ``index``."""
    out = render_chunked(
        field, grid, cameras.image_rays(index, height, width), cfg, background, boxes
    )
    return {key: value.reshape(height, width, *value.shape[1:]) for key, value in out.items()}

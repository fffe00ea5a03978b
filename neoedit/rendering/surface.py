"""Surface points along rays: where the geometry's weights say the surface is."""

from __future__ import annotations

import torch

from neoedit.cameras.rays import RayBundle
from neoedit.fields.radiance import Field
from neoedit.rendering.occupancy import OccupancyGrid
from neoedit.rendering.renderer import RenderConfig, render_rays


def median_depth(weights: torch.Tensor, t_mid: torch.Tensor) -> torch.Tensor:
    """Ray distance (N,) of the sample where the cumulative weight first reaches half the
    accumulation. Unlike the expected depth it is always on a real sample, never halfway
    between a foreground edge and the background behind it."""
    cum = torch.cumsum(weights, -1)
    half = 0.5 * cum[:, -1:]
    idx = torch.searchsorted(cum.contiguous(), half.contiguous()).clamp_max(weights.shape[1] - 1)
    return torch.gather(t_mid, 1, idx)[:, 0]


@torch.no_grad()
def render_surface(
    field: Field, grid: OccupancyGrid | None, rays: RayBundle, cfg: RenderConfig
) -> tuple[torch.Tensor, torch.Tensor]:
    """Surface points (N,3) [m] at the median depth of each ray, and accumulation (N,)."""
    points, accs = [], []
    for start in range(0, len(rays), cfg.chunk_rays):
        chunk = rays[start : start + cfg.chunk_rays]
        out = render_rays(field, grid, chunk, cfg, torch.zeros(3, device=chunk.origins.device))
        t = median_depth(out["weights"], out["t_mid"])
        points.append(chunk.origins + t[:, None] * chunk.directions)
        accs.append(out["accumulation"])
    if not points:
        empty = rays.origins.new_zeros((0,))
        return rays.origins.new_zeros((0, 3)), empty
    return torch.cat(points), torch.cat(accs)

"""Occupancy grid for empty-space skipping (Instant-NGP style).

A coarse grid over the scene box caches the field's density (an exponential moving
maximum). Rendering uses it twice: as a cheap proposal (volume-render the cached density
along many coarse samples, then draw the network samples from those weights) and to skip
network queries in cells that are empty.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import torch
from torch import nn

from neoedit.geometry import OrientedBox, points_in_box


@dataclass
class OccupancyGridConfig:
    resolution: int = 96
    """Cells per axis over the scene box."""
    update_every: int = 16
    """Training steps between grid updates."""
    decay: float = 0.95
    """Per-update decay of the cached density before taking the max with new values."""
    threshold: float = 1.0
    """Density [1/m] above which a cell counts as occupied (capped by the grid's mean); 1/m
    makes a 1 cm step less than 1% opaque."""
    warmup_steps: int = 64
    """During warm-up every cell is refreshed at each update; afterwards a quarter."""


class OccupancyGrid(nn.Module):
    aabb: torch.Tensor  # (2, 3) world metres
    density: torch.Tensor  # (R, R, R) cached density [1/m]
    n_updates: torch.Tensor  # () number of updates so far
    occupied: torch.Tensor  # (R, R, R) bool, derived from density (not saved)
    core: torch.Tensor  # (R, R, R) bool, occupied before dilation (not saved)

    def __init__(self, cfg: OccupancyGridConfig, aabb: torch.Tensor):
        super().__init__()
        self.cfg = cfg
        r = cfg.resolution
        self.register_buffer("aabb", aabb.float().clone())
        self.register_buffer("density", torch.zeros((r, r, r)))
        self.register_buffer("n_updates", torch.zeros((), dtype=torch.long))
        # everything counts as occupied until the first update
        self.register_buffer("occupied", torch.ones((r, r, r), dtype=torch.bool), persistent=False)
        # the cells above the threshold themselves (no dilation): what fast renders march
        self.register_buffer("core", torch.ones((r, r, r), dtype=torch.bool), persistent=False)

    def refresh_mask(self) -> None:
        """Core = cached density above the threshold; occupied = core dilated by one cell, so
        that a cell whose probe point missed a thin surface is still marched in training."""
        if int(self.n_updates) == 0:
            self.occupied.fill_(True)
            self.core.fill_(True)
            return
        thresh = min(self.cfg.threshold, float(self.density.clamp_max(1e3).mean()))
        above = self.density > thresh
        self.core.copy_(above)
        dilated = torch.nn.functional.max_pool3d(above.float()[None, None], 3, stride=1, padding=1)
        self.occupied.copy_(dilated[0, 0] > 0)

    def cell_index(self, points: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Flat cell index (N,) of world points and whether each is inside the box (N,)."""
        r = self.cfg.resolution
        u = (points - self.aabb[0]) / (self.aabb[1] - self.aabb[0])
        inside = ((u >= 0) & (u < 1)).all(-1)
        ijk = (u.clamp(0, 1 - 1e-6) * r).long()
        return ijk[:, 0] * r * r + ijk[:, 1] * r + ijk[:, 2], inside

    def lookup_density(self, points: torch.Tensor) -> torch.Tensor:
        """Cached density (N,) at world points (0 outside the box)."""
        idx, inside = self.cell_index(points)
        return torch.where(
            inside, self.density.reshape(-1)[idx], torch.zeros_like(idx, dtype=torch.float32)
        )

    def is_occupied(self, points: torch.Tensor) -> torch.Tensor:
        idx, inside = self.cell_index(points)
        return inside & self.occupied.reshape(-1)[idx]

    @torch.no_grad()
    def update(
        self,
        density_fn: Callable[[torch.Tensor], torch.Tensor],
        step: int,
        generator: torch.Generator | None = None,
        chunk: int = 1 << 18,
    ) -> None:
        """Refresh cached densities at one jittered point per chosen cell."""
        r = self.cfg.resolution
        n_cells = r**3
        device = self.density.device
        flat = self.density.reshape(-1)
        if step < self.cfg.warmup_steps:
            cells = torch.arange(n_cells, device=device)
        else:
            n = n_cells // 4
            random_cells = torch.randint(0, n_cells, (n,), device=device, generator=generator)
            occupied_cells = torch.nonzero(self.occupied.reshape(-1))[:, 0]
            cells = torch.cat([random_cells, occupied_cells])
        ijk = torch.stack([cells // (r * r), (cells // r) % r, cells % r], -1).float()
        jitter = torch.rand(ijk.shape, device=device, generator=generator)
        points = self.aabb[0] + (ijk + jitter) / r * (self.aabb[1] - self.aabb[0])
        new = torch.cat([density_fn(points[i : i + chunk]) for i in range(0, len(points), chunk)])
        if step < self.cfg.warmup_steps:
            flat.copy_(new.float())  # all cells, in order: forget the untrained network's values
        else:
            flat.mul_(self.cfg.decay)
            flat.scatter_reduce_(0, cells, new.float(), reduce="amax")
        self.n_updates += 1
        self.refresh_mask()


@torch.no_grad()
def refresh_grid(
    grid: OccupancyGrid,
    density_fn: Callable[[torch.Tensor], torch.Tensor],
    cells: torch.Tensor | None = None,
    samples: int = 16,
    seed: int = 0,
    chunk: int = 1 << 18,
) -> None:
    """Replace the cached density of ``cells`` (flat indices; all cells when None) by the
    field's density now — the maximum over the cell centre and ``samples`` - 1 jittered
    points, so a surface thinner than a cell is still found —, then refresh the occupied
    mask. Every edit calls this on its new field, so content that appeared where the grid
    was empty (a moved object's target) is marched."""
    r = grid.cfg.resolution
    device = grid.density.device
    if cells is None:
        cells = torch.arange(r**3, device=device)
    if len(cells) == 0:
        return
    gen = torch.Generator(device=device).manual_seed(seed)
    ijk = torch.stack([cells // (r * r), (cells // r) % r, cells % r], -1).float()
    size = grid.aabb[1] - grid.aabb[0]
    best = torch.zeros(len(cells), device=device)
    offsets = [torch.full_like(ijk, 0.5)]
    offsets += [torch.rand(ijk.shape, device=device, generator=gen) for _ in range(samples - 1)]
    for offset in offsets:
        points = grid.aabb[0] + (ijk + offset) / r * size
        new = torch.cat([density_fn(points[i : i + chunk]) for i in range(0, len(points), chunk)])
        best = torch.maximum(best, new.float())
    grid.density.reshape(-1)[cells] = best
    grid.n_updates.clamp_(min=1)
    grid.refresh_mask()


@torch.no_grad()
def rebuild_grid(
    grid: OccupancyGrid,
    density_fn: Callable[[torch.Tensor], torch.Tensor],
    seed: int = 0,
    coarse_samples: int = 4,
    fine_samples: int = 32,
) -> None:
    """Rebuild the whole grid from the field as it is now (the end of training): every cell
    probed at ``coarse_samples`` points, which drops what the running maximum still
    remembers of densities the field has since removed; then every cell occupied (dilated)
    before or after that pass probed again at ``fine_samples`` points, so a thin surface the
    coarse probes missed in its cell is found again. The fast march renders the undilated
    cells: a surface cell lost here is a hole in every render (issue 39: 4 probes alone cost
    0.7 dB held out on a Blender scene)."""
    before = grid.occupied.clone() if int(grid.n_updates) > 0 else None
    refresh_grid(grid, density_fn, samples=coarse_samples, seed=seed)
    near = grid.occupied if before is None else grid.occupied | before
    cells = torch.nonzero(near.reshape(-1))[:, 0]
    refresh_grid(grid, density_fn, cells=cells, samples=fine_samples, seed=seed + 1)


def cells_in_boxes(
    grid: OccupancyGrid, boxes: Sequence[OrientedBox], margin_cells: int = 1
) -> torch.Tensor:
    """Flat indices of the cells whose centre lies in any of the oriented ``boxes`` grown by
    ``margin_cells`` cells (so a cell cut by a face is included)."""
    r = grid.cfg.resolution
    device = grid.density.device
    size = grid.aabb[1] - grid.aabb[0]
    grow = float((size / r).max()) * margin_cells
    keep = torch.zeros(r**3, dtype=torch.bool, device=device)
    centres = (
        grid.aabb[0]
        + (
            torch.stack(
                torch.meshgrid(*[torch.arange(r, device=device)] * 3, indexing="ij"), -1
            ).reshape(-1, 3)
            + 0.5
        )
        / r
        * size
    )
    for box in boxes:
        keep |= points_in_box(centres, box.grown(grow))
    return torch.nonzero(keep)[:, 0]

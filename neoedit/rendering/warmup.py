"""Compile the CPU kernels once, ahead of their first use.

numba compiles a kernel the first time a process calls it and keeps the machine code in its
cache (``__pycache__`` beside the source, or ``NUMBA_CACHE_DIR``); every later process loads
it from there, until the kernel's source file changes (then the next call compiles again).
The first ``neo train`` after an install would otherwise spend its first seconds compiling
(measured: ~7 s for a training's kernels on the 2-core dev box), and every pytest-xdist
worker of a fresh checkout would do it again. ``make setup`` runs
``python -m neoedit.rendering.warmup``, which calls each kernel once on a few rays through
the same code the training and the renderer use, so the cached signatures are theirs.
Without numba it does nothing (the PyTorch paths need no compiling).
"""

from __future__ import annotations

import time

import torch

from neoedit.cameras.rays import RayBundle
from neoedit.fields.hashgrid import HashGridConfig, HashGridEncoding, numba_available
from neoedit.rendering.coarse import fine_edges
from neoedit.rendering.intervals import near_far_intervals
from neoedit.rendering.march import march_occupied
from neoedit.rendering.occupancy import OccupancyGrid, OccupancyGridConfig


class _Ball(torch.nn.Module):
    """A grey ball of density in the box [-1, 1]^3 (a field for the proposal to sample)."""

    aabb: torch.Tensor

    def __init__(self) -> None:
        super().__init__()
        self.register_buffer("aabb", torch.tensor([[-1.0] * 3, [1.0] * 3]))

    def density(self, pts: torch.Tensor) -> torch.Tensor:
        return 50.0 * torch.exp(-(pts**2).sum(-1) / 0.1)

    def forward(
        self, points: torch.Tensor, directions: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor]:
        return self.density(points), torch.full_like(points, 0.5)


def compile_kernels() -> list[str]:
    """Call every compiled CPU kernel once (compiling it into numba's cache, or loading it
    from there); the names of the kernels called, none without numba."""
    if not numba_available():
        return []
    gen = torch.Generator().manual_seed(0)
    # the hash encoding, forward and backward
    encoding = HashGridEncoding(
        HashGridConfig(n_levels=2, log2_hashmap_size=8, max_resolution=32, backend="numba")
    )
    encoding(torch.rand(64, 3, generator=gen)).sum().backward()
    # ... and its gradient with respect to the points (pose refinement)
    encoding(torch.rand(64, 3, generator=gen).requires_grad_(True)).sum().backward()
    # the occupancy march of the fast render, and the training sampler's proposal
    n = 32
    origins = torch.tensor([0.0, 0.0, -2.0]).expand(n, 3).contiguous()
    aim = torch.rand(n, 3, generator=gen) * 0.4 - 0.2  # points around the ball's centre
    directions = torch.nn.functional.normalize(aim - origins, dim=-1)
    rays = RayBundle(origins, directions, torch.ones(n))
    intervals = near_far_intervals(torch.full((n,), 1.0), torch.full((n,), 3.0))
    ball = _Ball()
    grid = OccupancyGrid(OccupancyGridConfig(resolution=8), ball.aabb)
    grid.occupied.fill_(True)
    march_occupied(rays, intervals, grid, grid.occupied, 16, backend="numba")
    fine_edges(ball, grid, rays, intervals, 16, 4, 4, True, gen, backend="numba")
    return [
        "hash encoding (forward, backward, point gradient)",
        "occupancy march",
        "training proposal",
    ]


def main() -> None:
    t0 = time.perf_counter()
    names = compile_kernels()
    if not names:
        print("numba is not installed: the PyTorch paths need no compiling")
        return
    print(f"compiled CPU kernels in {time.perf_counter() - t0:.1f} s: {', '.join(names)}")


if __name__ == "__main__":
    main()

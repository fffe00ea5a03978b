"""A carried object's shading turned with the light: a ratio grid over its own coordinates.

A move that carries an object's weights (:meth:`PatchedField.add_carried`) carries the
shading baked into its colours: the side that faced the light still renders lit after a
half turn, while in the world the light did not move. A :class:`Relight` holds, over an
axis-aligned region of the carried weights' own coordinates, the ratio between the shading
a surface point will have under the motion and the shading it had in the scan
(:mod:`neoedit.edit.relight` estimates the light and builds the grid); the carried part
multiplies its colours by it. Outside the region the ratio is 1.
"""

from __future__ import annotations

import torch
from torch import nn


class Relight(nn.Module):
    """A ratio grid ``ratio`` (n, n, n) over the box ``lo``..``hi`` (3,) of the carried
    weights' coordinates (cell centres from corner to corner; axis 0 along x)."""

    ratio: torch.Tensor
    lo: torch.Tensor
    hi: torch.Tensor

    def __init__(self, lo: torch.Tensor, hi: torch.Tensor, ratio: torch.Tensor):
        super().__init__()
        if ratio.ndim != 3 or min(ratio.shape) < 2:
            raise ValueError("a relight grid must be a 3-D grid of at least 2x2x2 cells")
        if not bool((hi > lo).all()):
            raise ValueError("a relight grid's box must have a positive size along every axis")
        self.register_buffer("lo", lo.detach().float().reshape(3).clone())
        self.register_buffer("hi", hi.detach().float().reshape(3).clone())
        self.register_buffer("ratio", ratio.detach().float().contiguous())

    @classmethod
    def like(cls, state: dict[str, torch.Tensor]) -> Relight:
        """An empty grid of the shape a stored state holds (its values then loaded)."""
        return cls(torch.zeros(3), torch.ones(3), torch.ones(tuple(state["ratio"].shape)))

    def ratio_at(self, points: torch.Tensor) -> torch.Tensor:
        """(N,) the ratio (trilinear) at points (N,3) of the weights' coordinates; 1
        outside the grid's box."""
        lo, hi = self.lo.to(points), self.hi.to(points)
        unit = (points - lo) / (hi - lo) * 2 - 1  # [-1, 1] over the box
        inside = (unit.abs() <= 1).all(-1)
        # grid_sample reads (x, y, z) as (last, middle, first) axis of the volume
        grid = unit[:, [2, 1, 0]].reshape(1, -1, 1, 1, 3)
        value = nn.functional.grid_sample(
            self.ratio.to(points)[None, None], grid, align_corners=True, padding_mode="border"
        ).reshape(-1)
        return torch.where(inside, value, torch.ones_like(value))

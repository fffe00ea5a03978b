"""A shadow laid on a field: colours darkened by a map over a thin slab on the support.

A move carries the object's own weights to the target (:meth:`PatchedField.add_carried`),
but the darkening it cast on its support stays in the weights of the support around the
source. A :class:`Shade` re-applies that darkening at the target: a shading-ratio map on
the support plane, found around the source (:mod:`neoedit.edit.shadow`) and moved with the
object, multiplies the colour of the points in its slab. The light does not move with the
object, so the map is translated, never rotated.

A shade darkens only what the parts older than it answer (the base field and the patches
that existed when it was laid): the object carried in by the same move, and any later
patch (a removal that re-learnt the table there), are left as they are.
"""

from __future__ import annotations

from collections.abc import Callable

import torch
from torch import nn

from neoedit.geometry import OrientedBox, points_in_box


class Shade(nn.Module):
    """A ratio map (n, n) in [0, 1] over the local x/y extent of the slab ``box`` (cell
    centres on a regular grid from corner to corner), applied to points inside the slab
    answered by the parts before ``after``."""

    ratio: torch.Tensor

    def __init__(self, box: OrientedBox, ratio: torch.Tensor, after: int):
        super().__init__()
        if ratio.ndim != 2 or min(ratio.shape) < 2:
            raise ValueError("a shade's ratio map must be a 2-D grid of at least 2x2 cells")
        self.box = box
        self.after = int(after)
        self.register_buffer("ratio", ratio.detach().float().clamp(0.0, 1.0).contiguous())

    def ratio_at(self, points: torch.Tensor) -> torch.Tensor:
        """(N,) the map's ratio under world points (N,3) inside the slab (bilinear)."""
        rot = torch.as_tensor(self.box.rotation, dtype=points.dtype, device=points.device)
        centre = torch.as_tensor(self.box.center_m, dtype=points.dtype, device=points.device)
        half = torch.as_tensor(self.box.half_extents[:2], dtype=points.dtype, device=points.device)
        local = ((points - centre) @ rot)[:, :2] / half  # [-1, 1] over the map
        # grid_sample reads x along the last axis (the map's columns: the box's y)
        grid = local[:, [1, 0]].reshape(1, -1, 1, 2)
        ratio = self.ratio.to(points)[None, None]
        value = nn.functional.grid_sample(ratio, grid, align_corners=True, padding_mode="border")
        return value.reshape(-1)


def apply_shades(
    shades: list[Shade],
    points: torch.Tensor,
    rgb: torch.Tensor,
    owner: Callable[[torch.Tensor], torch.Tensor],
) -> torch.Tensor:
    """``rgb`` (N,3) with every shade applied to the points (N,3) inside its slab whose
    answering part (``owner(points)``: -1 for the base) is older than the shade."""
    factor = None
    for shade in shades:
        idx = torch.nonzero(points_in_box(points, shade.box)).squeeze(1)
        if len(idx):
            idx = idx[owner(points[idx]) < shade.after]
        if not len(idx):
            continue
        if factor is None:
            factor = points.new_ones(len(points))
        factor[idx] = factor[idx] * shade.ratio_at(points[idx])
    return rgb if factor is None else rgb * factor[:, None].to(rgb)

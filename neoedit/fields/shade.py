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

from neoedit.geometry import OrientedBox
from neoedit.geometry.box import box_local


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

    def ratio_at(self, local: torch.Tensor) -> torch.Tensor:
        """(N,) the map's ratio (bilinear) under points (N,3) in the slab's frame."""
        xy = local[:, :2] / local.new_tensor(self.box.half_extents[:2])  # [-1, 1] over the map
        # grid_sample reads x along the last axis (the map's columns: the box's y)
        grid = xy[:, [1, 0]].reshape(1, -1, 1, 2)
        ratio = self.ratio.to(local)[None, None]
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
        local = box_local(points, shade.box)
        inside = (local.abs() <= local.new_tensor(shade.box.half_extents)).all(-1)
        idx = torch.nonzero(inside).squeeze(1)
        if len(idx):
            idx = idx[owner(points[idx]) < shade.after]
        if not len(idx):
            continue
        if factor is None:
            factor = points.new_ones(len(points))
        factor[idx] = factor[idx] * shade.ratio_at(local[idx])
    return rgb if factor is None else rgb * factor[:, None].to(rgb)

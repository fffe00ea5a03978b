"""Ray-box intersections (slab tests) for axis-aligned and oriented boxes."""

from __future__ import annotations

import torch

from neoedit.geometry.box import OrientedBox


def ray_aabb(
    origins: torch.Tensor, directions: torch.Tensor, aabb: torch.Tensor
) -> tuple[torch.Tensor, torch.Tensor]:
    """Entry and exit distances (N,) of rays with an axis-aligned box ``aabb`` (2,3); exit < entry
    means no hit."""
    inv = 1.0 / torch.where(
        directions.abs() < 1e-12, torch.full_like(directions, 1e-12), directions
    )
    t0 = (aabb[0] - origins) * inv
    t1 = (aabb[1] - origins) * inv
    t_near = torch.minimum(t0, t1).amax(-1)
    t_far = torch.maximum(t0, t1).amin(-1)
    return t_near, t_far


def ray_oriented_box(
    origins: torch.Tensor, directions: torch.Tensor, box: OrientedBox
) -> tuple[torch.Tensor, torch.Tensor]:
    """Entry and exit distances (N,) of rays with an oriented box (slab test in the box frame)."""
    rot = torch.as_tensor(box.rotation, dtype=origins.dtype, device=origins.device)
    center = torch.as_tensor(box.center_m, dtype=origins.dtype, device=origins.device)
    half = torch.as_tensor(box.half_extents, dtype=origins.dtype, device=origins.device)
    o_local = (origins - center) @ rot
    d_local = directions @ rot
    return ray_aabb(o_local, d_local, torch.stack([-half, half]))

"""Points and rays an edit trains on: uniform points in boxes, the support under a box
(L_keep's targets), original-view rays through a box (the unmasked ablation)."""

from __future__ import annotations

import torch

from neoedit.cameras import Cameras
from neoedit.cameras.rays import CameraTensors, RayBundle
from neoedit.fields.radiance import Field
from neoedit.geometry import OrientedBox
from neoedit.geometry.masks import box_pixels
from neoedit.rendering.renderer import render_chunked
from neoedit.scene import Scene


def box_points(
    box: OrientedBox, n: int, floor_m: float, generator: torch.Generator, device
) -> torch.Tensor:
    """(n,3) uniform points in the box above its lowest ``floor_m``."""
    u = torch.rand(n, 3, generator=generator).to(device) * 2 - 1
    half = torch.as_tensor(box.half_extents, dtype=torch.float32, device=device)
    local = u * half
    lift = min(floor_m, float(half[2]))
    local[:, 2] = local[:, 2] * (half[2] - lift / 2) / half[2] + lift / 2
    rot = torch.as_tensor(box.rotation, dtype=torch.float32, device=device)
    return local @ rot.T + torch.as_tensor(box.center_m, dtype=torch.float32, device=device)


@torch.no_grad()
def support_points(
    field_: Field,
    boxes: list[OrientedBox],
    below_m: float,
    generator: torch.Generator,
    device: torch.device | str,
    n: int = 32768,
) -> tuple[torch.Tensor, torch.Tensor]:
    """``n`` random points in the part of the patch regions under the boxes' bottoms, and
    the unedited field's opacity (over 1 cm) there: the targets of L_keep."""
    pts = []
    for b in boxes:
        bottom = b.center_m[2] - b.size_m[2] / 2
        slab = OrientedBox(
            (b.center_m[0], b.center_m[1], bottom - below_m / 2),
            (b.size_m[0], b.size_m[1], below_m),
            b.yaw_deg,
        )
        pts.append(box_points(slab, n // len(boxes), 0.0, generator, device))
    points = torch.cat(pts)
    return points, 1.0 - torch.exp(-0.01 * field_.density(points))


@torch.no_grad()
def original_box_rays(
    scene: Scene,
    cameras: Cameras,
    boxes: list[OrientedBox],
    n: int,
    generator: torch.Generator,
) -> tuple[RayBundle, torch.Tensor]:
    """``n`` rays of the scan cameras through the boxes' silhouettes and their colour as the
    unedited field renders it (a stand-in for the scan's photos: the object is visible)."""
    device = scene.field.aabb.device
    allpix = torch.as_tensor(box_pixels(cameras, boxes))
    allpix = allpix[torch.randint(0, len(allpix), (n,), generator=generator)].to(device)
    rays = CameraTensors(cameras, device).rays(allpix[:, 0], allpix[:, 1], allpix[:, 2])
    out = render_chunked(scene.field, scene.grid, rays, scene.meta.render, scene.background)
    return rays, out["rgb"]

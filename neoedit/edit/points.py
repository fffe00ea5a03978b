"""Points and rays an edit trains on: uniform points in boxes, the support under a box
(L_keep's targets), original-view rays through a box (the unmasked ablation)."""

from __future__ import annotations

import numpy as np
import torch

from neoedit.cameras import Cameras
from neoedit.cameras.rays import CameraTensors, RayBundle
from neoedit.errors import NeoError
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


def box_from_masks(
    scene: Scene,
    cameras: Cameras,
    masks: dict[int, np.ndarray],
    rays_per_view: int = 1500,
    agreement: float = 0.7,
    seed: int = 0,
) -> OrientedBox:
    """The box around an object marked by 2-D masks (camera index -> (H,W) bool, e.g. SAM's
    or a dataset's labels) in the scene's field: the surface its masked pixels see, kept
    where at least ``agreement`` of the masks that see a point mark it too (depth that
    bleeds onto the background behind a silhouette is voted out), bounded by the 2nd-98th
    percentiles, its yaw from the points' principal axis in the ground plane."""
    if not masks:
        raise NeoError("no masks to find a box from")
    rng = np.random.default_rng(seed)
    dev = scene.field.aabb.device
    cams_t = CameraTensors(cameras, dev)
    found = []
    field_, boxes = scene.renderable()
    for i, mask in masks.items():
        if mask.shape != (int(cameras.height[i]), int(cameras.width[i])):
            raise NeoError(
                f"the mask of camera {i} is {mask.shape[1]}x{mask.shape[0]}, the camera "
                f"{int(cameras.width[i])}x{int(cameras.height[i])}"
            )
        v, u = np.nonzero(mask)
        if len(v) == 0:
            continue
        pick = rng.choice(len(v), min(rays_per_view, len(v)), replace=False)
        cam = torch.full((len(pick),), int(i), dtype=torch.long, device=dev)
        rays = cams_t.rays(
            cam, torch.as_tensor(v[pick], device=dev), torch.as_tensor(u[pick], device=dev)
        )
        black = torch.zeros(3, device=dev)  # depth and opacity only: no background needed
        out = render_chunked(field_, scene.grid, rays, scene.meta.render, black, boxes)
        solid = out["accumulation"] > 0.5
        t = out["depth_z"] / rays.z_scale
        found.append((rays.origins + t[:, None] * rays.directions)[solid].cpu().numpy())
    points = np.concatenate(found) if found else np.zeros((0, 3))
    votes, seen = np.zeros(len(points)), np.zeros(len(points))
    for i, mask in masks.items():
        uv, z = cameras.project(int(i), points)
        h, w = mask.shape
        px = np.floor(uv).astype(np.int64)
        inside = (z > 0) & (px[:, 0] >= 0) & (px[:, 0] < w) & (px[:, 1] >= 0) & (px[:, 1] < h)
        seen += inside
        votes[inside] += mask[px[inside, 1], px[inside, 0]]
    kept = points[votes >= agreement * np.maximum(seen, 1)]
    if len(kept) < 10:
        raise NeoError(
            f"the masks mark no surface the field agrees on ({len(kept)} points); check that "
            "they belong to this scene's cameras"
        )
    xy = kept[:, :2] - kept[:, :2].mean(0)
    axis = np.linalg.eigh(xy.T @ xy)[1][:, -1]
    yaw = float(np.degrees(np.arctan2(axis[1], axis[0])))
    rot = np.array(
        [
            [np.cos(np.radians(yaw)), -np.sin(np.radians(yaw))],
            [np.sin(np.radians(yaw)), np.cos(np.radians(yaw))],
        ]
    )
    local = np.column_stack([xy @ rot, kept[:, 2]])
    lo, hi = np.percentile(local, 2, axis=0), np.percentile(local, 98, axis=0)
    centre_local = 0.5 * (lo + hi)
    centre_xy = kept[:, :2].mean(0) + rot @ centre_local[:2]
    return OrientedBox(
        (float(centre_xy[0]), float(centre_xy[1]), float(centre_local[2])),
        (float(hi[0] - lo[0]), float(hi[1] - lo[1]), float(hi[2] - lo[2])),
        yaw,
    )

"""Which surface points did the scan see? (what a removal must really invent)

A removal box is larger than what its object hid: the table in the box's corners, the
margin, a neighbour behind it were all seen by some scan camera, and the field already
knows them. Only points that every scan camera saw through the object (transmittance of the
*unedited* field below a threshold on the way there) are holes for the inpainter; the rest
keep what the field renders once the box is cut out of the rays.
"""

from __future__ import annotations

import numpy as np
import torch

from neoedit.cameras import Cameras
from neoedit.cameras.rays import CameraTensors
from neoedit.fields.radiance import Field
from neoedit.geometry import OrientedBox
from neoedit.rendering.occupancy import OccupancyGrid
from neoedit.rendering.support import footprint_distance


@torch.no_grad()
def seen_by_cameras(
    field: Field,
    grid: OccupancyGrid | None,
    points_m: torch.Tensor,
    cameras: Cameras,
    near_m: float,
    samples: int = 48,
    stop_short_m: float = 0.01,
    min_transmittance: float = 0.5,
    chunk: int = 4096,
) -> torch.Tensor:
    """(N,) bool: points (N,3) that at least one camera sees, i.e. the transmittance of
    ``field`` on the segment from the camera to ``stop_short_m`` before the point is at
    least ``min_transmittance`` and the point projects into the image in front of it."""
    device = points_m.device
    seen = torch.zeros(len(points_m), dtype=torch.bool, device=device)
    pts_np = points_m.detach().cpu().numpy().astype(np.float64)
    for j in range(len(cameras)):
        uv, depth = cameras.project(j, pts_np)
        w, h = int(cameras.width[j]), int(cameras.height[j])
        in_view = (depth > near_m) & (uv[:, 0] >= 0) & (uv[:, 0] < w) & (uv[:, 1] >= 0)
        in_view &= uv[:, 1] < h
        todo = torch.as_tensor(np.nonzero(in_view)[0], device=device)
        todo = todo[~seen[todo]]
        if len(todo) == 0:
            continue
        origin = torch.as_tensor(cameras.camera_to_world[j, :3, 3], dtype=torch.float32).to(device)
        for start in range(0, len(todo), chunk):
            idx = todo[start : start + chunk]
            offset = points_m[idx] - origin  # (n,3)
            dist = offset.norm(dim=-1, keepdim=True)  # (n,1)
            far = (dist - stop_short_m).clamp_min(near_m)
            t = near_m + (far - near_m) * (torch.arange(samples, device=device) + 0.5) / samples
            pos = origin + offset[:, None, :] / dist[:, None, :] * t[..., None]  # (n,S,3)
            flat = pos.reshape(-1, 3)
            sigma = torch.zeros(len(flat), device=device)
            live = torch.ones(len(flat), dtype=torch.bool, device=device)
            if grid is not None:
                live = grid.is_occupied(flat)
            if live.any():
                sigma[live] = field.density(flat[live]).float()
            delta = (far - near_m) / samples  # (n,1)
            transmittance = torch.exp(-(sigma.reshape(len(idx), samples) * delta).sum(-1))
            seen[idx] |= transmittance >= min_transmittance
    return seen


@torch.no_grad()
def raised_masks(
    cameras: Cameras,
    window: tuple[slice, slice],
    depth_z: torch.Tensor,
    accumulation: torch.Tensor,
    boxes: list[OrientedBox],
    band_m: float,
) -> list[np.ndarray]:
    """Per view (h,w) bool: the pixels of the crop ``window`` of ``cameras`` (z-depths and
    accumulations (V,h,w) rendered there) that show a surface standing more than ``band_m``
    above the support, the bottom of the box whose footprint is nearest the point: a
    neighbour of the removed object, never a source of the support's fill. Rays that stop on
    no surface (accumulation <= 0.5) are not raised."""
    if not boxes:
        return [np.zeros(depth_z.shape[1:], bool) for _ in range(len(depth_z))]
    vcams = CameraTensors(cameras, depth_z.device)
    h, w = depth_z.shape[1:]
    row, col = torch.meshgrid(
        torch.arange(window[0].start, window[0].start + h, device=depth_z.device),
        torch.arange(window[1].start, window[1].start + w, device=depth_z.device),
        indexing="ij",
    )
    out = []
    for v in range(len(depth_z)):
        rays = vcams.rays(
            torch.full((h * w,), v, device=depth_z.device), row.reshape(-1), col.reshape(-1)
        )
        dist = depth_z[v].reshape(-1) / rays.z_scale
        points = (rays.origins + rays.directions * dist[:, None]).cpu().numpy().astype(np.float64)
        solid = accumulation[v].reshape(-1).cpu().numpy() > 0.5
        out.append((solid & (points[:, 2] > _support_under(points, boxes) + band_m)).reshape(h, w))
    return out


def _support_under(points: np.ndarray, boxes: list[OrientedBox]) -> np.ndarray:
    """(N,) the height of the support under each point (N,3): the bottom of the box whose
    footprint is nearest it (boxes may stand on supports at different heights)."""
    away = []
    for b in boxes:
        local = b.world_to_local(points)
        away.append(footprint_distance(local[:, 0], local[:, 1], b))
    bottoms = np.array([b.center_m[2] - b.size_m[2] / 2 for b in boxes])
    return bottoms[np.stack(away, 1).argmin(1)]

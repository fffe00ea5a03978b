"""Rays through pixels, in torch (device-agnostic)."""

from __future__ import annotations

from dataclasses import dataclass

import torch

from neoedit.cameras.cameras import Cameras


@dataclass
class RayBundle:
    origins: torch.Tensor  # (N, 3) world metres
    directions: torch.Tensor  # (N, 3) unit length
    z_scale: torch.Tensor  # (N,) cos(angle to the optical axis): z-depth = ray distance * z_scale

    def __len__(self) -> int:
        return self.origins.shape[0]

    def __getitem__(self, sl: slice | torch.Tensor) -> RayBundle:
        return RayBundle(self.origins[sl], self.directions[sl], self.z_scale[sl])


class CameraTensors:
    """Cameras as torch tensors on a device, for fast batched ray generation."""

    def __init__(self, cameras: Cameras, device: torch.device | str = "cpu"):
        self.c2w = torch.as_tensor(cameras.camera_to_world, dtype=torch.float32, device=device)
        k = [cameras.fx, cameras.fy, cameras.cx, cameras.cy]
        self.intrinsics = torch.as_tensor(
            list(zip(*k, strict=True)), dtype=torch.float32, device=device
        )  # (N, 4)

    def rays(self, cam: torch.Tensor, v_px: torch.Tensor, u_px: torch.Tensor) -> RayBundle:
        """Rays through pixel centres (row ``v_px``, column ``u_px``) of cameras ``cam`` (all (N,))."""
        fx, fy, cx, cy = self.intrinsics[cam].unbind(-1)
        x = (u_px.float() + 0.5 - cx) / fx
        y = -(v_px.float() + 0.5 - cy) / fy
        d_cam = torch.stack([x, y, -torch.ones_like(x)], dim=-1)
        norm = d_cam.norm(dim=-1)
        c2w = self.c2w[cam]
        d_world = (c2w[:, :3, :3] @ d_cam[..., None])[..., 0] / norm[:, None]
        return RayBundle(c2w[:, :3, 3].contiguous(), d_world, 1.0 / norm)

    def image_rays(self, i: int, height: int, width: int) -> RayBundle:
        """All rays of camera ``i`` in row-major pixel order."""
        device = self.c2w.device
        v, u = torch.meshgrid(
            torch.arange(height, device=device), torch.arange(width, device=device), indexing="ij"
        )
        cam = torch.full((height * width,), i, dtype=torch.long, device=device)
        return self.rays(cam, v.reshape(-1), u.reshape(-1))

"""Small rigid corrections of camera poses (a rotation vector and a translation per camera,
applied about the camera's centre), as pose refinement learns them
(:mod:`neoedit.training.camera_opt`) and as a scene's scan record stores them."""

from __future__ import annotations

import numpy as np
import torch

from neoedit.cameras.rays import RayBundle


def so3_exp(w: torch.Tensor) -> torch.Tensor:
    """Rotation matrices (N,3,3) of rotation vectors w (N,3) [rad] (Rodrigues; exact at 0)."""
    theta2 = (w * w).sum(-1, keepdim=True)[..., None]  # (N,1,1)
    k = torch.zeros(w.shape[0], 3, 3, dtype=w.dtype, device=w.device)
    k[:, 0, 1], k[:, 0, 2], k[:, 1, 2] = -w[:, 2], w[:, 1], -w[:, 0]
    k = k - k.transpose(1, 2)  # the cross-product matrix [w]x
    small = theta2 < 1e-8
    theta = theta2.clamp_min(1e-8).sqrt()
    a = torch.where(small, 1.0 - theta2 / 6.0, torch.sin(theta) / theta)
    b = torch.where(small, 0.5 - theta2 / 24.0, (1.0 - torch.cos(theta)) / theta2.clamp_min(1e-8))
    eye = torch.eye(3, dtype=w.dtype, device=w.device).expand_as(k)
    return eye + a * k + b * (k @ k)


def corrected_poses(camera_to_world: np.ndarray, corrections: np.ndarray) -> np.ndarray:
    """Poses (N,4,4) with their corrections (N,6: rotation vector, translation [m]) applied
    about each camera's centre, as :class:`PoseRefinement` applies them to rays."""
    c2w = np.array(camera_to_world, dtype=np.float64, copy=True)
    rot = so3_exp(torch.as_tensor(corrections[:, :3], dtype=torch.float64)).numpy()
    c2w[:, :3, :3] = rot @ c2w[:, :3, :3]
    c2w[:, :3, 3] += corrections[:, 3:]
    return c2w


def corrected_rays(rays: RayBundle, corrections: torch.Tensor, camera: torch.Tensor) -> RayBundle:
    """``rays`` (N) of cameras ``camera`` (N,) as the cameras' ``corrections`` (C,6) cast them:
    origins shifted by t, directions turned by exp(w) (one rotation a camera, not a ray);
    differentiable with respect to ``corrections``."""
    turn = so3_exp(corrections[:, :3])[camera]
    directions = (turn @ rays.directions[..., None])[..., 0]
    return RayBundle(rays.origins + corrections[camera, 3:], directions, rays.z_scale)

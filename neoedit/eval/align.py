"""Held-out cameras aligned to their photos before a pose-refined field is evaluated.

Training with pose refinement (:mod:`neoedit.training.camera_opt`) moves the training
photos' cameras until they agree with each other; the held-out photos keep the dataset's
poses, which carry the same structure-from-motion error the training photos had before
their correction. Rendered at those poses, a sharper field can score lower than a blurred
one: the evaluation then charges the field with the poses' error. Pose-refinement work
(BARF, nerfstudio's camera optimiser evaluations) therefore aligns each test camera to its
photo first, with the field frozen. Here each held-out camera gets a rotation vector and a
translation about its centre, as training's corrections, fitted by the photometric loss
on random pixels of its own photo (no mean removed: the cameras are independent). The
field, grid and background take no gradient and do not change.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import torch

from neoedit.cameras import Cameras
from neoedit.cameras.pose_correction import corrected_poses, corrected_rays
from neoedit.cameras.rays import CameraTensors
from neoedit.data import SceneData
from neoedit.rendering.renderer import render_rays
from neoedit.scene import Scene
from neoedit.utils.fit import fit
from neoedit.utils.optim import frozen, make_adam


@dataclass
class AlignConfig:
    steps: int = 200
    """Optimisation steps (all the aligned cameras together, each on its own photo)."""
    rays: int = 2048
    """Random pixels per step, spread over the aligned photos."""
    lr: float = 3e-3
    """Adam's learning rate for the rotation vectors [rad], decayed 10x over the run."""
    shift_lr: float = 1e-4
    """... and for the translations [m]."""
    seed: int = 0


def align_cameras(
    scene: Scene,
    data: SceneData,
    cameras: Cameras,
    indices: Sequence[int],
    cfg: AlignConfig | None = None,
) -> tuple[Cameras, np.ndarray]:
    """``cameras`` with those at ``indices`` moved to fit their photos in ``data`` as
    ``scene`` renders them, and the corrections (len(indices), 6: rotation vector [rad],
    translation [m]). The scene is unchanged."""
    cfg = cfg or AlignConfig()
    device = scene.field.aabb.device
    idx = torch.as_tensor(list(indices), dtype=torch.long, device=device)
    cams = CameraTensors(cameras, device)
    photos = torch.as_tensor(data.images[list(indices)], device=device)  # (K,H,W,3) uint8
    k, h, w = photos.shape[:3]
    mask = data.loss_mask
    valid = None if mask is None else torch.as_tensor(mask[list(indices)], device=device)
    gen = torch.Generator(device=device).manual_seed(cfg.seed)
    turn = torch.zeros(k, 3, device=device, requires_grad=True)
    shift = torch.zeros(k, 3, device=device, requires_grad=True)
    field_, boxes = scene.renderable()
    background = scene.background

    def loss(_step: int) -> torch.Tensor:
        view = torch.randint(0, k, (cfg.rays,), device=device, generator=gen)
        v = torch.randint(0, h, (cfg.rays,), device=device, generator=gen)
        u = torch.randint(0, w, (cfg.rays,), device=device, generator=gen)
        rays = corrected_rays(cams.rays(idx[view], v, u), torch.cat([turn, shift], 1), view)
        out = render_rays(field_, scene.grid, rays, scene.meta.render, background, boxes, True, gen)
        err = ((out["rgb"] - photos[view, v, u].float() / 255.0) ** 2).mean(-1)
        if valid is None:
            return err.mean()
        keep = valid[view, v, u].float()  # pixels an undistortion left without a photo
        return (err * keep).sum() / keep.sum().clamp_min(1.0)

    with frozen(field_), frozen(background):
        groups: list[dict[str, Any]] = [{"params": [turn]}, {"params": [shift], "lr": cfg.shift_lr}]
        decay = lambda step: 0.1 ** (step / max(cfg.steps - 1, 1))  # noqa: E731
        fit(make_adam(groups, cfg.lr, device), cfg.steps, loss, "align cameras", lr_scale=decay)
    found = torch.cat([turn, shift], 1).detach().cpu().numpy().astype(np.float64)
    c2w = cameras.camera_to_world.copy()
    c2w[list(indices)] = corrected_poses(c2w[list(indices)], found)
    aligned = Cameras(c2w, cameras.fx, cameras.fy, cameras.cx, cameras.cy, cameras.width,
                      cameras.height)  # fmt: skip
    return aligned, found

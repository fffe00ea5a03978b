"""Evaluated cameras aligned to their photos first: the fair measure of a pose-refined field.

Training with pose refinement (:mod:`neoedit.training.camera_opt`) moves the training
photos' cameras until they agree with each other; the held-out photos keep the dataset's
poses, which carry the same structure-from-motion error the training photos had before
their correction. Rendered at those poses, a sharper field can score lower than a blurred
one: the evaluation then charges the field with the poses' error. Pose-refinement work
(BARF, nerfstudio's camera optimiser evaluations) therefore aligns each test camera to its
photo first, with the field frozen. Here each evaluated camera gets a rotation vector and a
translation about its centre, as training's corrections, fitted by the photometric loss
on random pixels of its own photo (no mean removed: the cameras are independent). The
field, grid and background take no gradient and do not change. A refined scan's own
training photos start from their corrected poses: what is reported is then the residual.
Pixels of edited boxes are left out of the fit (there the photo and the edited field may
disagree by design: the metrics must not be bought by moving the camera).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import torch

from neoedit.cameras import Cameras
from neoedit.cameras.pose_correction import corrected_poses, corrected_rays
from neoedit.cameras.rays import CameraTensors
from neoedit.data import SceneData
from neoedit.geometry import OrientedBox
from neoedit.geometry.masks import masks_for_boxes
from neoedit.rendering.renderer import render_rays
from neoedit.scene import Scene
from neoedit.utils.fit import fit
from neoedit.utils.optim import frozen, make_adam


@dataclass
class AlignConfig:
    steps: int = 200
    """Optimisation steps (all the aligned cameras together, each on its own photo)."""
    rays_per_view: int = 512
    """Random pixels of each aligned photo per step."""
    lr: float = 3e-3
    """Adam's learning rate for the rotation vectors [rad], decayed 10x over the run."""
    shift_lr: float = 1e-4
    """... and for the translations, in sizes of the scene box (its largest side) per step."""
    seed: int = 0


def align_cameras(
    scene: Scene,
    data: SceneData,
    cameras: Cameras,
    indices: Sequence[int],
    cfg: AlignConfig | None = None,
    exclude: Sequence[OrientedBox] = (),
) -> tuple[Cameras, np.ndarray]:
    """``cameras`` with those at ``indices`` moved to fit their photos in ``data`` as
    ``scene`` renders them, and the corrections (len(indices), 6: rotation vector [rad],
    translation [m]); pixels of the ``exclude`` boxes (at the starting cameras) are left
    out. The scene is unchanged."""
    cfg = cfg or AlignConfig()
    device = scene.field.aabb.device
    idx = torch.as_tensor(list(indices), dtype=torch.long, device=device)
    cams = CameraTensors(cameras, device)
    photos = torch.as_tensor(data.images[list(indices)], device=device)  # (K,H,W,3) uint8
    k, h, w = photos.shape[:3]
    keep = np.ones((k, h, w), bool) if data.loss_mask is None else data.loss_mask[list(indices)]
    if exclude:
        keep = keep & ~np.stack([masks_for_boxes(cameras, i, list(exclude)) for i in indices])
    valid = torch.as_tensor(keep, device=device)
    n_rays = cfg.rays_per_view * k
    shift_lr = cfg.shift_lr * float((scene.field.aabb[1] - scene.field.aabb[0]).max())
    gen = torch.Generator(device=device).manual_seed(cfg.seed)
    turn = torch.zeros(k, 3, device=device, requires_grad=True)
    shift = torch.zeros(k, 3, device=device, requires_grad=True)
    field_, boxes = scene.renderable()
    background = scene.background

    def loss(_step: int) -> torch.Tensor:
        view = torch.randint(0, k, (n_rays,), device=device, generator=gen)
        v = torch.randint(0, h, (n_rays,), device=device, generator=gen)
        u = torch.randint(0, w, (n_rays,), device=device, generator=gen)
        rays = corrected_rays(cams.rays(idx[view], v, u), torch.cat([turn, shift], 1), view)
        out = render_rays(field_, scene.grid, rays, scene.meta.render, background, boxes, True, gen)
        err = ((out["rgb"] - photos[view, v, u].float() / 255.0) ** 2).mean(-1)
        use = valid[view, v, u].float()  # not the edited boxes, nor pixels without a photo
        return (err * use).sum() / use.sum().clamp_min(1.0)

    with torch.enable_grad(), frozen(field_), frozen(background):
        groups: list[dict[str, Any]] = [{"params": [turn]}, {"params": [shift], "lr": shift_lr}]
        decay = lambda step: 0.1 ** (step / max(cfg.steps - 1, 1))  # noqa: E731
        fit(make_adam(groups, cfg.lr, device), cfg.steps, loss, "align cameras", lr_scale=decay)
    found = torch.cat([turn, shift], 1).detach().cpu().numpy().astype(np.float64)
    c2w = cameras.camera_to_world.copy()
    c2w[list(indices)] = corrected_poses(c2w[list(indices)], found)
    return dataclasses.replace(cameras, camera_to_world=c2w), found


def alignment_summary(fixes: np.ndarray, cfg: AlignConfig) -> dict[str, Any]:
    """What an alignment moved (the JSON's ``aligned``): medians over the cameras."""
    return {
        "views": len(fixes),
        "median_turn_deg": round(float(np.degrees(np.median(np.linalg.norm(fixes[:, :3], axis=1)))), 4),
        "median_shift_mm": round(float(1e3 * np.median(np.linalg.norm(fixes[:, 3:], axis=1))), 3),
        "steps": cfg.steps,
    }  # fmt: skip

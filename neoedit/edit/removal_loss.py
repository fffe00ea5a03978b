"""The loss of one training step of a removal's patch (paper eq. 4-5, see
:mod:`neoedit.edit.refine`): the inpainted virtual views' colour and depth, L_reg (no
density inside the box), L_keep (the support under it keeps at least the unedited density) and, in
the ablation without mask conditioning, the original views through the box.

Three things keep a step cheap:

* virtual rays are sampled on the part that crosses the patch's region only; what lies in
  front of and behind it is frozen and was marched once (:mod:`neoedit.rendering.span`);
* the regulariser points ride along in the rendered samples' network query, so the patch's
  hash table gets one gradient per step instead of two (:class:`DensityRider`; the ablation
  without mask conditioning renders a second batch, a second query);
* with a one-box region, every queried point lies in the patch's region, so the patch is
  queried directly rather than through the composed field's ownership tests.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import TYPE_CHECKING

import torch

from neoedit.cameras.rays import CameraTensors, RayBundle
from neoedit.edit.points import box_points
from neoedit.fields.radiance import Field
from neoedit.geometry import OrientedBox
from neoedit.rendering.renderer import render_rays
from neoedit.rendering.span import OutsideSegments, outside_segments, render_span
from neoedit.rendering.volume import opacity_penalty
from neoedit.scene import Scene

if TYPE_CHECKING:
    from neoedit.edit.refine import RefineConfig


class DensityRider:
    """``field`` (same interface), whose first colour query also evaluates the density at
    ``extra`` points in the same network pass; that density is left in ``sigma``. (The
    colour MLP runs on the extra points too: cheaper than a second hash-table lookup.)"""

    def __init__(self, field: Field, extra: torch.Tensor):
        self.field = field
        self.extra = extra
        self.sigma: torch.Tensor | None = None

    @property
    def aabb(self) -> torch.Tensor:
        return self.field.aabb

    def density(self, points: torch.Tensor) -> torch.Tensor:
        return self.field.density(points)

    def __call__(
        self, points: torch.Tensor, directions: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor]:
        if self.sigma is not None:
            return self.field(points, directions)
        n = len(points)
        up = torch.zeros_like(self.extra)
        up[:, 2] = 1.0
        sigma, rgb = self.field(torch.cat([points, self.extra]), torch.cat([directions, up]))
        self.sigma = sigma[n:]
        return sigma[:n], rgb[:n]


def support_loss(sigma: torch.Tensor, kept_alpha: torch.Tensor) -> torch.Tensor:
    """L_keep at points under the boxes: the opacity over 1 cm that the patch's densities
    ``sigma`` [1/m] take away from the unedited field's ``kept_alpha`` (mean, L1). Adding is
    free: the support under an object was hidden by it, and where no camera saw it the
    unedited field left it part empty (a ball's contact: 74 % opaque in the README demo's
    field, a pale disc after the removal when L_keep held it there)."""
    alpha = 1.0 - torch.exp(-0.01 * sigma)
    return torch.mean(torch.relu(kept_alpha - alpha))


@dataclass(eq=False, repr=False)
class RemovalLoss:
    """Callable loss of the patch of ``scene``; the caller fills ``targets`` (V,h,w,3) each
    round and ``target_depth`` (V,h,w) once. ``pix`` (P,3) are the (view, row, col) pixels of
    M_v in the crop ``window`` of the virtual cameras ``vcams``."""

    scene: Scene
    cfg: RefineConfig
    boxes: list[OrientedBox]
    region: list[OrientedBox]
    vcams: CameraTensors
    window: tuple[slice, slice]
    pix: torch.Tensor
    targets: torch.Tensor
    target_depth: torch.Tensor
    keep_pts: torch.Tensor
    keep_alpha: torch.Tensor
    originals: tuple[RayBundle, torch.Tensor] | None
    gen: torch.Generator
    train_gen: torch.Generator
    outside: OutsideSegments | None = dataclasses.field(default=None, init=False)
    """The frozen parts of every M_v ray (:meth:`march_outside`); None: whole rays."""

    def __post_init__(self) -> None:
        self.device = self.pix.device
        # Every point a step queries lies in the region: the span samples (between the first
        # entry into a region box and the last exit: inside the box when the region is one
        # box), L_reg's points (in the boxes) and L_keep's (under them, in the region). The
        # newest patch answers everywhere in its region, so with one box the patch can be
        # queried directly, skipping the composed field's ownership tests and scatters.
        self.patch: Field = self.scene.patched().renderer_of(self.region)  # the one trained
        self.span_field: Field = self.patch if len(self.region) == 1 else self.scene.field
        n = self.cfg.span_samples
        self.span_cfg = dataclasses.replace(self.scene.meta.render, n_coarse_samples=n, n_samples=n)
        self.march_outside()

    def march_outside(self) -> None:
        """(Re)march the frozen parts of every M_v ray (after the grid changes)."""
        if self.cfg.span_only and len(self.pix):
            self.outside = outside_segments(
                self.scene.field,
                self.scene.grid,
                self.pixel_rays(self.pix),
                self.scene.meta.render,
                self.scene.background,
                self.region,
            )

    def pixel_rays(self, pick: torch.Tensor) -> RayBundle:
        rows, cols = self.window
        return self.vcams.rays(pick[:, 0], pick[:, 1] + rows.start, pick[:, 2] + cols.start)

    def draw(self, n: int, high: int) -> torch.Tensor:
        return torch.randint(0, high, (n,), generator=self.gen).to(self.device)

    def regulariser_points(self) -> tuple[torch.Tensor, torch.Tensor | None]:
        """L_reg's points in the boxes, then L_keep's on the support (their indices)."""
        cfg = self.cfg
        pts = torch.cat(
            [
                box_points(
                    b, cfg.reg_points // len(self.boxes), cfg.reg_floor_m, self.gen, self.device
                )
                for b in self.boxes
            ]
        )
        if cfg.lambda_keep <= 0 or not len(self.keep_pts):
            return pts, None
        pick_k = self.draw(cfg.reg_points, len(self.keep_pts))
        return torch.cat([pts, self.keep_pts[pick_k]]), pick_k

    def __call__(self) -> torch.Tensor:
        cfg, scene = self.cfg, self.scene
        loss = torch.zeros((), device=self.device)
        reg_pts, pick_k = self.regulariser_points()
        # whole rays (span_only off) leave the region: they need the composed field
        net = self.span_field if self.outside is not None else scene.field
        field = DensityRider(net, reg_pts)
        if len(self.pix):
            chosen = self.draw(cfg.virtual_rays, len(self.pix))
            pick = self.pix[chosen]
            rays = self.pixel_rays(pick)
            if self.outside is not None:
                out = render_span(
                    field,
                    scene.grid,
                    rays,
                    self.span_cfg,
                    self.outside[chosen],
                    True,
                    self.train_gen,
                )
            else:
                out = render_rays(
                    field, scene.grid, rays, scene.meta.render, scene.background,
                    jitter=True, generator=self.train_gen,
                )  # fmt: skip
            loss = loss + torch.mean(
                (out["rgb"] - self.targets[pick[:, 0], pick[:, 1], pick[:, 2]]) ** 2
            )
            if cfg.lambda_depth > 0:
                depth = self.target_depth[pick[:, 0], pick[:, 1], pick[:, 2]]
                loss = loss + cfg.lambda_depth * torch.mean(torch.abs(out["depth_z"] - depth))
        if self.originals is not None:
            o_rays, o_rgb = self.originals
            pick_o = self.draw(cfg.original_rays, len(o_rgb))
            out_o = render_rays(  # whole rays: through the composed field
                scene.field, scene.grid, o_rays[pick_o], scene.meta.render, scene.background,
                jitter=True, generator=self.train_gen,
            )  # fmt: skip
            loss = loss + torch.mean((out_o["rgb"] - o_rgb[pick_o]) ** 2)
        sigma = field.sigma if field.sigma is not None else net.density(reg_pts)
        n_reg = len(reg_pts) - (len(pick_k) if pick_k is not None else 0)
        loss = loss + cfg.lambda_reg * opacity_penalty(sigma[:n_reg])
        if pick_k is not None:
            loss = loss + cfg.lambda_keep * support_loss(sigma[n_reg:], self.keep_alpha[pick_k])
        return loss

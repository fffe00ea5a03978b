"""Render only the part of each ray that crosses an edit's region; the rest is rendered once.

A local edit trains a patch that answers inside a few boxes only; along a training ray
everything in front of those boxes and behind them belongs to frozen fields, so its
contribution never changes. Splitting each ray at the region's entry ``s0`` and exit ``s1``
(the union of the boxes' slabs, clipped to the ray's valid domain [a, b]):

    C = C_front + T_front * (C_span + (1 - A_span) * C_back)

with ``C_front`` / ``T_front`` the premultiplied colour and transmittance of [a, s0],
``C_back`` the colour of [s1, b] composited over the background and ``C_span``, ``A_span``
the (trainable) premultiplied colour and opacity of [s0, s1]. Front and back are marched
once, without gradients (:func:`outside_segments`); each training step samples and queries
the network on the span only (:func:`render_span`). On NEO-Sim virtual views most of a
ray's samples are behind the region (the table seen through the removed object), so the
patch's training steps skip most of their field queries.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from dataclasses import dataclass

import torch

from neoedit.cameras.rays import RayBundle
from neoedit.fields.background import Background
from neoedit.fields.radiance import Field
from neoedit.geometry import OrientedBox
from neoedit.geometry.rays import ray_oriented_box
from neoedit.rendering.intervals import near_far_intervals
from neoedit.rendering.march import march_render
from neoedit.rendering.occupancy import OccupancyGrid
from neoedit.rendering.outside import outside_light
from neoedit.rendering.renderer import RenderConfig, ray_intervals, render_rays


@dataclass
class OutsideSegments:
    """What the frozen fields contribute to each of N rays outside the region."""

    span_start: torch.Tensor  # (N,) s0: ray distance where the region's span begins [m]
    span_end: torch.Tensor  # (N,) s1 >= s0 (equal: the ray misses the region)
    front_rgb: torch.Tensor  # (N,3) premultiplied colour of [a, s0]
    front_trans: torch.Tensor  # (N,) transmittance through [a, s0]
    front_depth: torch.Tensor  # (N,) sum of weight * ray distance over [a, s0]
    back_rgb: torch.Tensor  # (N,3) colour of [s1, b] over the background
    back_acc: torch.Tensor  # (N,) opacity of [s1, b]
    back_depth: torch.Tensor  # (N,) sum of weight * ray distance over [s1, b] (unit light)
    room_rgb: torch.Tensor  # (N,3) premultiplied colour of a room in front of the box (or 0)
    room_trans: torch.Tensor  # (N,) the fraction of the box that room lets through (or 1)

    def __getitem__(self, index: torch.Tensor | slice) -> OutsideSegments:
        return OutsideSegments(*(getattr(self, f.name)[index] for f in dataclasses.fields(self)))


def region_span(
    rays: RayBundle, boxes: Sequence[OrientedBox], start: torch.Tensor, end: torch.Tensor
) -> tuple[torch.Tensor, torch.Tensor]:
    """(s0, s1) (N,): the smallest segment of each ray's valid [start, end] holding every
    part of it inside ``boxes``; s0 = s1 = end for rays that miss them there."""
    lo = torch.full_like(start, float("inf"))
    hi = torch.full_like(start, -float("inf"))
    for box in boxes:
        t_in, t_out = ray_oriented_box(rays.origins, rays.directions, box)
        t_in, t_out = torch.maximum(t_in, start), torch.minimum(t_out, end)
        hit = t_out > t_in  # within the valid domain (not behind the camera, not past b)
        lo = torch.where(hit, torch.minimum(lo, t_in), lo)
        hi = torch.where(hit, torch.maximum(hi, t_out), hi)
    s0 = torch.minimum(lo, end)  # a miss: lo = inf -> s0 = end
    return s0, torch.maximum(hi, s0)


@torch.no_grad()
def outside_segments(
    field: Field,
    grid: OccupancyGrid,
    rays: RayBundle,
    cfg: RenderConfig,
    background: Background,
    boxes: Sequence[OrientedBox],
) -> OutsideSegments:
    """March the parts of ``rays`` before and after the region ``boxes`` (what renders see:
    the grid's occupied cells, early termination), in chunks of ``cfg.chunk_rays``."""
    parts: list[OutsideSegments] = []
    for i in range(0, len(rays), cfg.chunk_rays):
        chunk = rays[i : i + cfg.chunk_rays]
        valid = ray_intervals(field, chunk, cfg.near_m)
        a, b = valid.starts[:, 0], valid.ends[:, 0]
        s0, s1 = region_span(chunk, boxes, a, b)
        # a room around the box is outermost: its front is kept apart (render_span puts it
        # over the rest; accumulation and depth stay the box's), its back is behind the box
        light = outside_light(background, chunk.origins, chunk.directions, cfg.near_m)
        black = torch.zeros(3, device=a.device)
        front = march_render(
            field, grid, chunk, near_far_intervals(a, s0), cfg.n_march_samples, black
        )
        back = march_render(
            field, grid, chunk, near_far_intervals(s1, b), cfg.n_march_samples, light.back_rgb
        )
        parts.append(
            OutsideSegments(
                s0,
                s1,
                front["rgb"],
                1.0 - front["accumulation"],
                front["depth"] * front["accumulation"],
                back["rgb"],
                back["accumulation"],
                back["depth"] * back["accumulation"],
                torch.as_tensor(light.front_rgb, device=a.device).expand(len(a), 3),
                torch.as_tensor(light.front_trans, device=a.device).expand(len(a)),
            )
        )
    return OutsideSegments(
        *(
            torch.cat([getattr(p, f.name) for p in parts])
            for f in dataclasses.fields(OutsideSegments)
        )
    )


def render_span(
    field: Field,
    grid: OccupancyGrid | None,
    rays: RayBundle,
    cfg: RenderConfig,
    outside: OutsideSegments,
    jitter: bool = False,
    generator: torch.Generator | None = None,
) -> dict[str, torch.Tensor]:
    """rgb (N,3), depth (N,) expected ray distance [m], depth_z (N,) and accumulation (N,)
    of whole rays, the network sampled (``cfg``'s coarse pass and PDF samples) on their
    region span only and ``outside`` (of the same rays) composited around it.
    Differentiable in the field's answers on the span."""
    span = near_far_intervals(outside.span_start, outside.span_end)
    zero = torch.zeros(3, device=rays.origins.device)
    inner = render_rays(
        field, grid, rays, cfg, zero, jitter=jitter, generator=generator, intervals=span
    )
    acc_in = inner["accumulation"]
    weighted_in = (inner["weights"] * inner["t_mid"]).sum(-1)
    t_front = outside.front_trans
    box_rgb = outside.front_rgb + t_front[:, None] * (
        inner["rgb"] + (1.0 - acc_in)[:, None] * outside.back_rgb
    )
    rgb = outside.room_rgb + outside.room_trans[:, None] * box_rgb  # depth, acc: the box's
    acc = (1.0 - t_front) + t_front * (acc_in + (1.0 - acc_in) * outside.back_acc)
    weighted = outside.front_depth + t_front * (weighted_in + (1.0 - acc_in) * outside.back_depth)
    depth = weighted / acc.clamp_min(1e-6)
    return {"rgb": rgb, "depth": depth, "depth_z": depth * rays.z_scale, "accumulation": acc}

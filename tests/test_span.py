"""Span rendering (neoedit.rendering.span): a ray rendered on the region's span with the
frozen parts in front and behind composited around it equals the whole ray rendered at
once; the density rider of the removal loss answers what two separate queries would."""

from __future__ import annotations

import torch

from neoedit.cameras.rays import RayBundle
from neoedit.edit.removal_loss import DensityRider
from neoedit.geometry import OrientedBox, points_in_box
from neoedit.rendering.march import march_render
from neoedit.rendering.occupancy import OccupancyGrid, OccupancyGridConfig, refresh_grid
from neoedit.rendering.renderer import RenderConfig, ray_intervals, render_rays
from neoedit.rendering.span import outside_segments, region_span, render_span

CENTRES = torch.tensor([[0.0, 0.0, -1.0], [0.0, 0.0, 0.0], [0.05, 0.0, 1.0]])
COLOURS = torch.tensor([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]])
REGION = [OrientedBox((0.0, 0.0, 0.0), (1.0, 1.0, 0.8), 0.0)]


class ThreeBalls(torch.nn.Module):
    """Three semi-transparent balls on the z axis (red in front of the region, green in it,
    blue behind), each of radius 0.3 and density 3 /m."""

    def __init__(self):
        super().__init__()
        self.register_buffer("aabb", torch.tensor([[-2.0, -2.0, -2.0], [2.0, 2.0, 2.0]]))

    def forward(self, pts, dirs):
        d = torch.cdist(pts, CENTRES)  # (N, 3)
        inside = (d < 0.3).float()
        sigma = 3.0 * inside.sum(-1)
        rgb = (inside @ COLOURS) / inside.sum(-1, keepdim=True).clamp_min(1.0)
        return sigma, rgb

    def density(self, pts):
        return self.forward(pts, pts)[0]


def _rays(n: int = 300, seed: int = 0) -> RayBundle:
    """Rays from z = -3 towards the balls, some passing beside the region."""
    gen = torch.Generator().manual_seed(seed)
    origins = torch.zeros(n, 3)
    origins[:, :2] = (torch.rand(n, 2, generator=gen) - 0.5) * 0.6
    origins[:, 2] = -3.0
    target = torch.zeros(n, 3)
    target[:, :2] = (torch.rand(n, 2, generator=gen) - 0.5) * 1.6
    target[:, 2] = 1.0
    d = torch.nn.functional.normalize(target - origins, dim=-1)
    return RayBundle(origins, d, d[:, 2].abs())


def test_span_render_equals_the_whole_ray():
    field = ThreeBalls()
    # fine and refreshed at many points per cell, so the march's grid covers the balls
    grid = OccupancyGrid(OccupancyGridConfig(resolution=128), field.aabb)
    refresh_grid(grid, field.density)
    rays = _rays()
    background = torch.tensor([0.9, 0.8, 0.7])
    cfg = RenderConfig(n_march_samples=4096, n_coarse_samples=1024, n_samples=1024, near_m=0.5)
    whole = render_rays(field, None, rays, cfg, background)
    outside = outside_segments(field, grid, rays, cfg, background, REGION)
    span = render_span(field, grid, rays, cfg, outside)
    # every ray sees the red ball's share through the front and the blue one's through the
    # back (the test is not vacuous), and the composite matches the whole ray
    assert (outside.front_trans < 0.99).sum() > 25 and (outside.back_acc > 0.01).sum() > 25
    missed = outside.span_start == outside.span_end
    assert missed.any() and (~missed).sum() > 100
    # the frozen parts are marched over the grid's cells, as renders are: rays grazing a
    # ball lose the sliver of it that the cells shave off, in both renders alike
    marched = march_render(field, grid, rays, ray_intervals(field, rays, 0.5), 4096, background)
    # (the span itself is sampled on the dilated cells, as training samples)
    for reference in (whole, marched):
        for key, atol in (("rgb", 1e-2), ("accumulation", 1e-2), ("depth", 2e-2)):
            error = (span[key] - reference[key]).abs().reshape(len(rays), -1).amax(1)
            assert (error < atol).float().mean() > 0.97 and error.mean() < atol / 3, key


def test_the_span_holds_every_part_of_the_ray_inside_the_boxes():
    rays = _rays(200, 1)
    boxes = [
        REGION[0],
        OrientedBox((0.3, 0.0, 0.5), (0.2, 0.4, 0.2), 30.0),
        OrientedBox((0.0, 0.0, -4.0), (3.0, 3.0, 0.5), 0.0),  # behind the cameras
        OrientedBox((0.0, 0.0, 3.5), (6.0, 6.0, 0.5), 0.0),  # past the end of every ray
    ]
    # valid domains that start before, inside or after the region (the near plane)
    start = torch.linspace(0.5, 3.6, 200)[
        torch.randperm(200, generator=torch.Generator().manual_seed(2))
    ]
    end = torch.full((200,), 6.0)
    s0, s1 = region_span(rays, boxes, start, end)
    t = torch.linspace(0.0, 6.0, 3001)
    pts = rays.origins[:, None, :] + t[None, :, None] * rays.directions[:, None, :]
    inside = torch.zeros(pts.shape[:2], dtype=torch.bool)
    for box in boxes:
        inside |= points_in_box(pts.reshape(-1, 3), box).reshape(inside.shape)
    inside &= (t[None, :] >= start[:, None]) & (t[None, :] <= end[:, None])
    hit = inside.any(1)
    assert hit.sum() > 20 and (~hit).sum() > 20
    assert torch.all(s0[~hit] == s1[~hit]) and torch.all(s0 >= start) and torch.all(s1 <= end)
    first = t[inside.float().argmax(1)]
    last = t[len(t) - 1 - inside.flip(1).float().argmax(1)]
    assert torch.all(s0[hit] <= first[hit] + 1e-3) and torch.all(s1[hit] >= last[hit] - 1e-3)
    assert torch.all(s0[hit] >= first[hit] - 3e-3) and torch.all(s1[hit] <= last[hit] + 3e-3)


def test_the_density_rider_answers_both_queries_in_one_call():
    calls: list[int] = []

    class Counting(ThreeBalls):
        def forward(self, pts, dirs):
            calls.append(len(pts))
            return super().forward(pts, dirs)

    field = Counting()
    pts = torch.randn(50, 3) * 0.5
    extra = torch.randn(20, 3) * 0.5
    rider = DensityRider(field, extra)
    sigma, rgb = rider(pts, torch.nn.functional.normalize(torch.randn(50, 3), dim=-1))
    assert calls == [70]
    ref_sigma, ref_rgb = ThreeBalls()(pts, pts)
    torch.testing.assert_close(sigma, ref_sigma)
    torch.testing.assert_close(rgb, ref_rgb)
    torch.testing.assert_close(rider.sigma, ThreeBalls().density(extra))


def test_the_density_rider_passes_gradients_and_later_calls_through():
    class Scaled(torch.nn.Module):
        def __init__(self):
            super().__init__()
            self.scale = torch.nn.Parameter(torch.tensor(2.0))
            self.register_buffer("aabb", torch.tensor([[-2.0] * 3, [2.0] * 3]))

        def forward(self, pts, dirs):
            sigma = self.scale * pts.norm(dim=-1)
            return sigma, torch.sigmoid(pts)

        def density(self, pts):
            return self.forward(pts, pts)[0]

    field = Scaled()
    extra = torch.tensor([[1.0, 0.0, 0.0], [0.0, 2.0, 0.0]])
    rider = DensityRider(field, extra)
    sigma, _ = rider(torch.zeros((0, 3)), torch.zeros((0, 3)))  # no rendered sample at all
    assert len(sigma) == 0
    again, _ = rider(torch.ones(3, 3), torch.ones(3, 3))
    assert len(again) == 3  # a second query is the field's own
    rider.sigma.sum().backward()
    torch.testing.assert_close(field.scale.grad, torch.tensor(3.0))  # d/ds (s*1 + s*2)

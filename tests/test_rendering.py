"""Samplers, intervals and volume rendering against brute force and closed forms."""

import math

import numpy as np
import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from neoedit.cameras.rays import RayBundle
from neoedit.geometry import OrientedBox
from neoedit.rendering.intervals import RayIntervals, cut_boxes, near_far_intervals
from neoedit.rendering.occupancy import OccupancyGrid, OccupancyGridConfig
from neoedit.rendering.renderer import RenderConfig, render_rays
from neoedit.rendering.samplers import pdf_edges, uniform_edges
from neoedit.rendering.volume import light_missing, render_weights


def _rays(n: int, seed: int) -> tuple[torch.Tensor, torch.Tensor]:
    g = torch.Generator().manual_seed(seed)
    origins = (torch.rand(n, 3, generator=g) - 0.5) * 2.0
    directions = torch.nn.functional.normalize(torch.randn(n, 3, generator=g), dim=-1)
    return origins.double(), directions.double()


box_strategy = st.builds(
    OrientedBox,
    st.tuples(st.floats(-0.6, 0.6), st.floats(-0.6, 0.6), st.floats(-0.6, 0.6)),
    st.tuples(st.floats(0.05, 0.8), st.floats(0.05, 0.8), st.floats(0.05, 0.8)),
    st.floats(-180, 180),
)


N_RAYS = 64


@settings(max_examples=40, deadline=None)
@given(boxes=st.lists(box_strategy, min_size=1, max_size=3), seed=st.integers(0, 10_000))
def test_no_sample_inside_removed_boxes(boxes, seed):
    origins, directions = _rays(N_RAYS, seed)
    near, far = (
        torch.full((N_RAYS,), 0.0, dtype=torch.double),
        torch.full((N_RAYS,), 3.0, dtype=torch.double),
    )
    intervals = cut_boxes(near_far_intervals(near, far), origins, directions, boxes)
    edges = uniform_edges(
        intervals.total, 64, jitter=True, generator=torch.Generator().manual_seed(seed)
    )
    s_mid = 0.5 * (edges[:, 1:] + edges[:, :-1])
    t = intervals.domain_to_t(s_mid)
    pts = (origins[:, None, :] + t[..., None] * directions[:, None, :]).reshape(-1, 3).numpy()
    for box in boxes:
        assert not box.contains(pts, margin_m=-1e-6).any()
    # the domain is the ray minus the chords through the union of boxes (brute force on a fine grid)
    ts = torch.linspace(0, 3, 6001, dtype=torch.double)[:-1] + 0.00025
    dense = (
        (origins[:, None, :] + ts[None, :, None] * directions[:, None, :]).reshape(-1, 3).numpy()
    )
    outside = np.ones(len(dense), bool)
    for box in boxes:
        outside &= ~box.contains(dense)
    expected = outside.reshape(N_RAYS, -1).mean(1) * 3.0
    np.testing.assert_allclose(intervals.total.numpy(), expected, atol=3e-3)


def test_uniform_samples_are_uniform_on_concatenated_domain():
    starts = torch.tensor([[0.0, 2.0]]).repeat(20000, 1)
    ends = torch.tensor([[1.0, 4.0]]).repeat(20000, 1)  # lengths 1 and 2
    intervals = RayIntervals(starts, ends)
    edges = uniform_edges(
        intervals.total, 30, jitter=True, generator=torch.Generator().manual_seed(0)
    )
    t = intervals.domain_to_t(0.5 * (edges[:, 1:] + edges[:, :-1])).reshape(-1)
    assert ((t > 1.0) & (t < 2.0)).sum() == 0
    hist, _ = np.histogram(t.numpy(), bins=[0, 0.5, 1.0, 2.0, 3.0, 4.0])
    density = hist / len(t) / np.array([0.5, 0.5, 1.0, 1.0, 1.0])
    # uniform over the 3 m of domain, nothing in the gap (1, 2)
    np.testing.assert_allclose(density, [1 / 3, 1 / 3, 0.0, 1 / 3, 1 / 3], atol=0.01)
    assert torch.all(edges[:, 1:] >= edges[:, :-1])


def test_pdf_resampling_concentrates_where_weights_are():
    edges = torch.linspace(0, 1, 11).repeat(500, 1)
    weights = torch.full((500, 10), 0.01)
    weights[:, 6] = 1.0
    new = pdf_edges(edges, weights, 32, jitter=True, generator=torch.Generator().manual_seed(0))
    assert torch.all(new[:, 1:] >= new[:, :-1])  # sorted
    inside = ((new >= 0.6) & (new <= 0.7)).float().mean()
    assert inside > 0.85
    assert new.min() >= 0 and new.max() <= 1


class SphereField(torch.nn.Module):
    """Constant density ``sigma`` inside a sphere, colour by hemisphere."""

    def __init__(self, radius: float, sigma: float):
        super().__init__()
        self.register_buffer("aabb", torch.tensor([[-1.0, -1.0, -1.0], [1.0, 1.0, 1.0]]))
        self.radius, self.sigma = radius, sigma

    def forward(self, pts, dirs):
        inside = pts.norm(dim=-1) < self.radius
        rgb = torch.zeros_like(pts)
        rgb[:, 0] = 1.0
        return self.sigma * inside.float(), rgb

    def density(self, pts):
        return self.forward(pts, pts)[0]


def sphere_rays(radius: float, sigma: float, n: int = 200):
    """Rays along +z from z = -3 at impact parameters up to ``radius``, and their closed-form
    accumulation and expected distance through a homogeneous sphere at the origin."""
    offsets = torch.linspace(0.0, 0.98 * radius, n)
    origins = torch.stack([offsets, torch.zeros(n), torch.full((n,), -3.0)], -1)
    rays = RayBundle(origins, torch.tensor([[0.0, 0.0, 1.0]]).repeat(n, 1), torch.ones(n))
    chord = 2 * torch.sqrt(radius**2 - offsets**2)
    acc = 1 - torch.exp(-sigma * chord)
    # entry point + mean of the truncated exponential over the chord
    depth = 3.0 - chord / 2 + 1 / sigma - chord * torch.exp(-sigma * chord) / acc
    return rays, acc, depth


@pytest.mark.parametrize("with_grid", [False, True])
def test_render_sphere_matches_closed_form(with_grid):
    radius, sigma = 0.5, 4.0
    field = SphereField(radius, sigma)
    rays, expected_acc, expected_depth = sphere_rays(radius, sigma)
    grid = None
    if with_grid:
        grid = OccupancyGrid(OccupancyGridConfig(resolution=64, warmup_steps=10), field.aabb)
        grid.update(field.density, step=0)
    cfg = RenderConfig(n_march_samples=2048, n_coarse_samples=2048, n_samples=1024)
    out = render_rays(field, grid, rays, cfg, background=torch.zeros(3))
    torch.testing.assert_close(out["accumulation"], expected_acc, atol=4e-3, rtol=0)
    torch.testing.assert_close(out["rgb"][:, 0], expected_acc, atol=4e-3, rtol=0)
    torch.testing.assert_close(out["depth"], expected_depth, atol=8e-3, rtol=0)


def test_weights_formula():
    sigma = torch.tensor([[0.0, 1.0, 2.0]])
    deltas = torch.tensor([[0.5, 0.5, 0.5]])
    w = render_weights(sigma, deltas)
    expected = [0.0, (1 - math.exp(-0.5)), math.exp(-0.5) * (1 - math.exp(-1.0))]
    torch.testing.assert_close(w[0], torch.tensor(expected))


def test_light_missing_is_the_light_that_does_not_end_in_the_window():
    """Against the weights summed sample by sample (transmittance times opacity)."""
    g = torch.Generator().manual_seed(3)
    sigma = torch.rand(5, 16, generator=g, dtype=torch.double) * 8.0
    deltas = torch.full((5, 16), 0.1, dtype=torch.double)
    t_mid = 0.05 + 0.1 * torch.arange(16, dtype=torch.double).expand(5, 16)
    lo = torch.tensor([-1.0, 0.0, 0.31, 0.5, 2.0], dtype=torch.double)
    hi = torch.tensor([-0.5, 1.6, 0.52, 0.99, 5.0], dtype=torch.double)
    got = light_missing(render_weights(sigma, deltas), t_mid, lo, hi)
    for r in range(5):
        passed, ended = 1.0, 0.0
        for k in range(16):
            alpha = 1.0 - math.exp(-float(sigma[r, k] * deltas[r, k]))
            if lo[r] <= t_mid[r, k] <= hi[r]:
                ended += passed * alpha
            passed *= 1.0 - alpha
        assert abs(float(got[r]) - (1.0 - ended)) < 1e-12
    assert float(got[0]) == 1.0 and float(got[4]) == 1.0  # windows that hold no sample


class RecordingSphere(SphereField):
    def __init__(self, *a):
        super().__init__(*a)
        self.queried: list[torch.Tensor] = []

    def forward(self, pts, dirs):
        self.queried.append(pts.detach().clone())
        return super().forward(pts, dirs)


def test_grid_skipping_queries_the_network_only_in_occupied_cells():
    field = RecordingSphere(0.3, 10.0)
    grid = OccupancyGrid(OccupancyGridConfig(resolution=32, warmup_steps=10), field.aabb)
    grid.update(field.density, step=0)
    field.queried.clear()
    origins, directions = _rays(500, 1)
    rays = RayBundle(origins.float(), directions.float(), torch.ones(500))
    out = render_rays(
        field,
        grid,
        rays,
        RenderConfig(n_march_samples=256, n_coarse_samples=64, n_samples=16),
        torch.zeros(3),
        jitter=True,
    )
    queried = torch.cat(field.queried)
    assert len(queried) > 0 and grid.is_occupied(queried).all()
    # rays that never cross an occupied cell cost nothing and render the background
    t = torch.linspace(0, 4, 800)
    crosses = grid.is_occupied(
        (origins[:, None].float() + t[None, :, None] * directions[:, None].float()).reshape(-1, 3)
    )
    miss = ~crosses.reshape(500, -1).any(-1)
    assert miss.sum() > 10 and torch.all(out["accumulation"][miss] == 0)
    hit_sphere = (origins.float().cross(directions.float(), dim=-1).norm(dim=-1) < 0.25) & (
        (origins.float() * directions.float()).sum(-1) < 0
    )
    assert (
        out["accumulation"][hit_sphere].min() > 0.85
    )  # closed form >= 0.96; 16 samples are coarse

"""The room around the scene box (fields/room.py, rendering/outside.py): the warp, the
light in front of and behind the box against a brute-force integral, the box cut out of the
room's samples, and a room that travels with the scene but not with its patches."""

from __future__ import annotations

import dataclasses

import pytest
import torch

from neoedit.cameras.rays import RayBundle
from neoedit.errors import NeoError
from neoedit.fields.hashgrid import HashGridConfig
from neoedit.fields.radiance import RadianceField
from neoedit.fields.room import RoomConfig, RoomField, contract
from neoedit.geometry import OrientedBox
from neoedit.rendering import outside
from neoedit.rendering.occupancy import OccupancyGrid
from neoedit.rendering.outside import (
    RoomMoments,
    outside_light,
    ray_sphere,
    room_domain,
    unwarp,
    warp,
)
from neoedit.rendering.renderer import render_chunked, render_rays
from tests.conftest import TINY_FIELD, TINY_GRID, TINY_RENDER

BOX = torch.tensor([[-0.2, -0.2, -0.1], [0.2, 0.2, 0.1]])
SMALL_ROOM = RoomConfig(
    hashgrid=HashGridConfig(n_levels=4, log2_hashmap_size=12, max_resolution=64),
    n_coarse_samples=64,
    n_samples=64,
)


class ShellRoom(RoomField):
    """A room with a known answer: a soft shell of density around the box at 1.5 m and a
    colour that changes with the position."""

    def density_and_features(self, points):
        r = points.norm(dim=-1)
        sigma = 4.0 * torch.exp(-(((r - 1.5) / 0.3) ** 2))
        return sigma, torch.cat([points, torch.zeros(len(points), 12)], -1)

    def color(self, geo, directions):
        return 0.5 + 0.4 * torch.tanh(geo[:, :3])


def _brute_force(room, origins, directions, start, end, n=200_000):
    """Premultiplied colour and transmittance of [start, end] of one ray, by a Riemann sum
    evenly spaced in disparity (the far end is hundreds of metres away)."""
    inv = torch.linspace(1.0 / start, 1.0 / end, n + 1, dtype=torch.float64)
    t = 1.0 / inv
    mid, dt = 0.5 * (t[1:] + t[:-1]), t[1:] - t[:-1]
    pts = (origins[None].double() + mid[:, None] * directions[None].double()).float()
    sigma, rgb = room.query(pts, directions[None].expand(n, 3))
    tau = sigma.double() * dt
    trans = torch.exp(-torch.cumsum(torch.cat([torch.zeros(1, dtype=torch.float64), tau[:-1]]), 0))
    colour = ((trans * (1 - torch.exp(-tau)))[:, None] * rgb.double()).sum(0)
    return colour, float(torch.exp(-tau.sum()))


def test_the_warp_is_invertible_and_linear_then_linear_in_disparity():
    t_b = torch.tensor([[2.0]])
    t = torch.tensor([[0.1, 1.0, 1.999, 2.0, 2.001, 5.0, 100.0, 1e4]])
    g = warp(t, t_b)
    torch.testing.assert_close(unwarp(g, t_b), t, rtol=5e-4, atol=1e-5)  # float32 far out
    assert bool((g[:, 1:] > g[:, :-1]).all()) and bool((g < 2 * t_b).all())
    t64, tb64 = t.double(), t_b.double()
    eps = 1e-4 * t64
    slope = (warp(t64 + eps, tb64) - warp(t64 - eps, tb64)) / (2 * eps)
    torch.testing.assert_close(slope[:, :3], torch.ones_like(slope[:, :3]), rtol=1e-6, atol=0)
    torch.testing.assert_close(slope[:, 4:], (tb64 / t64[:, 4:]) ** 2, rtol=1e-3, atol=0)


def test_contraction_keeps_the_unit_ball_and_bounds_everything():
    y = torch.tensor([[0.3, -0.2, 0.1], [3.0, 0.0, 0.0], [0.0, -1e6, 0.0]])
    c = contract(y)
    torch.testing.assert_close(c[0], y[0])
    torch.testing.assert_close(c[1], torch.tensor([2.0 - 1.0 / 3.0, 0.0, 0.0]))
    assert float(c.norm(dim=-1).max()) < 2.0


def test_room_light_matches_a_brute_force_integral_in_front_of_and_behind_the_box():
    room = ShellRoom(SMALL_ROOM, BOX)
    origins = torch.tensor([[0.6, 0.05, 0.02], [0.6, 0.05, 0.02]])
    directions = torch.nn.functional.normalize(
        torch.tensor([[-1.0, 0.0, 0.0], [-1.0, 0.0, 1.5]]), dim=-1
    )  # through the box; past it (misses)
    near = 0.05
    with torch.no_grad():
        light = outside_light(room, origins, directions, near)
        env = room.environment(directions)
    far = float(((origins[0] - room.center).norm() + room.radius) + 1000 * room.radius)
    # ray 0: the room lies in front of the sphere around the box and behind it
    t_in, t_out = ray_sphere(origins[:1], directions[:1], room.center, room.radius)
    front, t_front = _brute_force(room, origins[0], directions[0], near, float(t_in))
    back, t_back = _brute_force(room, origins[0], directions[0], float(t_out), far)
    assert abs(float(light.front_trans[0]) - t_front) < 0.01
    torch.testing.assert_close(light.front_rgb[0].double(), front, atol=0.01, rtol=0)
    torch.testing.assert_close(
        light.back_rgb[0].double(), back + t_back * env[0].double(), atol=0.02, rtol=0
    )
    assert t_back < 0.5  # the shell behind the box is really there
    # ray 1 misses the box: everything is in front, nothing comes from behind it
    whole, t_whole = _brute_force(room, origins[1], directions[1], near, far)
    torch.testing.assert_close(
        light.around(light.back_rgb)[1].double(),
        whole + t_whole * env[1].double(),
        atol=0.02,
        rtol=0,
    )
    assert float(light.back_rgb[1].sub(env[1]).abs().max()) < 1e-5


def test_the_box_room_distortion_terms_match_a_brute_force_double_sum():
    """RoomMoments.box_distortion against sum_ij w_i w_j |x_i - x_j| over the pairs of one
    box sample and one room sample, the whole ray's weights written out sample by sample."""
    gen = torch.Generator().manual_seed(3)
    n, m_room, m_box = 5, 7, 6
    t_b = 1.0 + torch.rand(n, 1, generator=gen)
    g0, span = torch.full((n, 1), 0.05), torch.full((n, 1), 2.5)
    box_t = torch.sort(0.4 + 0.4 * torch.rand(n, m_box, generator=gen), -1).values
    front_g = torch.sort(0.05 + 0.3 * torch.rand(n, m_room, generator=gen), -1).values
    back_g = torch.sort(0.9 + 1.6 * torch.rand(n, m_room, generator=gen), -1).values
    w_box = 0.15 * torch.rand(n, m_box, generator=gen)
    w_front = 0.1 * torch.rand(n, m_room, generator=gen)
    w_back = 0.12 * torch.rand(n, m_room, generator=gen)
    trans = 1.0 - w_front.sum(-1)
    x_front, x_back = (front_g - g0) / span, (back_g - g0) / span
    x_box = (warp(box_t, t_b) - g0) / span
    moments = RoomMoments(
        w_front.sum(-1),
        (w_front * x_front).sum(-1),
        w_back.sum(-1),
        (w_back * x_back).sum(-1),
        t_b,
        g0,
        span,
    )
    got = moments.box_distortion(w_box, box_t, trans)
    for r in range(n):
        whole_box = trans[r] * w_box[r]
        whole_back = trans[r] * (1.0 - w_box[r].sum()) * w_back[r]
        want = 0.0
        for i in range(m_box):
            pairs = [
                *zip(w_front[r], x_front[r], strict=True),
                *zip(whole_back, x_back[r], strict=True),
            ]
            for w_j, x_j in pairs:
                want += 2.0 * float(whole_box[i] * w_j * (x_box[r, i] - x_j).abs())
        assert abs(float(got[r]) - want) < 1e-6 * max(1.0, want)
    assert bool((got > 0).all())


def test_the_joint_distortion_pulls_light_split_between_box_and_room_into_one_of_them():
    """A ray whose light is half in an object in the box and half in the room behind it
    costs more than one whose light ends in either alone."""
    t_b, g0, span = torch.ones(3, 1), torch.zeros(3, 1), torch.full((3, 1), 2.0)
    box_t = torch.tensor([[0.5]]).expand(3, 1)
    box_w = torch.tensor([[0.5], [1.0], [0.0]])
    back_w = torch.tensor([1.0, 0.0, 1.0])  # behind the box, with its own transmittance
    x_back = torch.full((3,), 0.9)
    moments = RoomMoments(torch.zeros(3), torch.zeros(3), back_w, back_w * x_back, t_b, g0, span)
    split, in_box, in_room = moments.box_distortion(box_w, box_t, torch.ones(3)).tolist()
    assert split > 0.1 and in_box == 0.0 and in_room == 0.0


def _count_room_light(m: pytest.MonkeyPatch, calls: list[int]) -> None:
    """Make ``outside.room_light`` record how many rays each of its calls samples."""
    real = outside.room_light

    def counting(room_, o, *args, **kwargs):
        calls.append(len(o))
        return real(room_, o, *args, **kwargs)

    m.setattr(outside, "room_light", counting)


def test_rays_the_box_stops_skip_the_room_only_where_none_of_it_can_show():
    """A camera inside the room's inner sphere sees no room in front of the box: on rays
    the box stops, the room is not sampled (nothing to add); the other rays get exactly the
    light they get without the hint, including opaque rays from a camera outside."""
    room = ShellRoom(SMALL_ROOM, BOX)
    inside = [0.25, 0.05, 0.02]  # within the inner sphere (radius: half the box diagonal)
    origins = torch.tensor([inside, inside, [0.6, 0.05, 0.02], [0.6, 0.05, 0.02]])
    directions = torch.nn.functional.normalize(
        torch.tensor([[-1.0, 0.0, 0.0], [-1.0, 0.2, 0.1], [-1.0, 0.0, 0.0], [-1.0, 0.0, 1.5]]),
        dim=-1,
    )
    opaque = torch.tensor([True, False, True, False])
    calls: list[int] = []
    with torch.no_grad(), pytest.MonkeyPatch.context() as m:
        _count_room_light(m, calls)
        full = outside_light(room, origins, directions, 0.05)
        outside.MEMO.clear()  # else the hinted render takes every ray's light from the memo
        hinted = outside_light(room, origins, directions, 0.05, opaque=opaque)
    assert calls == [4, 3]  # the stopped ray from inside is not sampled
    seen = ~torch.tensor([True, False, False, False])
    for a, b in ((hinted.front_rgb, full.front_rgb), (hinted.back_rgb, full.back_rgb)):
        torch.testing.assert_close(a[seen], b[seen])
    torch.testing.assert_close(hinted.front_trans[seen], full.front_trans[seen])
    assert float(hinted.front_trans[0]) == 1.0 and float(full.front_trans[0]) == 1.0
    assert hinted.back_rgb[0].abs().max() == 0 and hinted.front_rgb[0].abs().max() == 0


def test_no_room_sample_lands_in_the_box():
    room = RoomField(SMALL_ROOM, BOX)
    gen = torch.Generator().manual_seed(0)
    origins = torch.randn(256, 3, generator=gen) * 0.8
    directions = torch.nn.functional.normalize(torch.randn(256, 3, generator=gen), dim=-1)
    seen = []
    original = outside._room_samples

    def spy(room_, o, d, intervals, t_b, g_box, edges, *args):
        mid = intervals.domain_to_t(0.5 * (edges[:, 1:] + edges[:, :-1]))
        t = unwarp(mid, t_b)
        seen.append(o[:, None, :] + t[..., None] * d[:, None, :])
        return original(room_, o, d, intervals, t_b, g_box, edges, *args)

    outside._room_samples = spy
    try:
        with torch.no_grad():
            outside_light(room, origins, directions, 0.0, jitter=True, generator=gen)
    finally:
        outside._room_samples = original
    pts = torch.cat([p.reshape(-1, 3) for p in seen])
    inside = ((pts > BOX[0] + 1e-4) & (pts < BOX[1] - 1e-4)).all(-1)
    assert len(seen) == 2 and not bool(inside.any())
    intervals, _, _ = room_domain(room, origins, directions, 0.0)
    assert bool((intervals.total > 0).all())


def test_a_room_field_renders_the_same_in_both_renderers_and_learns_from_a_loss():
    cfg = dataclasses.replace(TINY_FIELD, learned_background=True, room=True, room_field=SMALL_ROOM)
    field = RadianceField(cfg, BOX)
    assert isinstance(field.background_head, RoomField)
    grid = OccupancyGrid(TINY_GRID, BOX)
    grid.update(field.density, 0)
    gen = torch.Generator().manual_seed(1)
    origins = torch.tensor([[0.7, 0.0, 0.05]]).expand(64, 3).contiguous()
    directions = torch.nn.functional.normalize(
        torch.tensor([-1.0, 0.0, 0.0]) + 0.3 * torch.randn(64, 3, generator=gen), dim=-1
    )
    rays = RayBundle(origins, directions, torch.ones(64))
    slow = render_rays(field, grid, rays, TINY_RENDER, field.background_head)
    fast = render_chunked(field, grid, rays, TINY_RENDER, field.background_head)
    torch.testing.assert_close(slow["rgb"].detach(), fast["rgb"], atol=0.02, rtol=0)
    (slow["rgb"].sum() + slow["outside_distortion"].sum()).backward()
    table = field.background_head.encoding.table.grad
    assert table is not None and float(table.abs().sum()) > 0
    # coupled to the box's samples, the room's distortion loss only grows (its terms with
    # the box are >= 0) and its gradient reaches the box's field
    field.zero_grad()
    field.background_head.cfg = dataclasses.replace(SMALL_ROOM, joint_distortion=1.0)
    coupled = render_rays(field, grid, rays, TINY_RENDER, field.background_head)
    apart = slow["outside_distortion"].detach()
    assert bool((coupled["outside_distortion"].detach() >= apart - 1e-7).all())
    coupled["outside_distortion"].sum().backward()
    assert float(field.encoding.table.grad.abs().sum()) > 0


def test_a_patch_does_not_copy_the_room():
    from neoedit.fields.patched import PatchedField

    cfg = dataclasses.replace(TINY_FIELD, learned_background=True, room=True, room_field=SMALL_ROOM)
    patched = PatchedField(RadianceField(cfg, BOX))
    patch = patched.add_patch([OrientedBox((0.0, 0.0, 0.0), (0.1, 0.1, 0.1), 0.0)])
    assert patch.background_head is None
    assert isinstance(patched.base.background_head, RoomField)


def test_photos_from_outside_the_box_get_a_room_and_photos_from_inside_do_not(tmp_path):
    import numpy as np

    from neoedit.data import load_scene_data
    from neoedit.training.defaults import cameras_outside, field_config
    from tests.test_background import _environment_dataset

    _environment_dataset(tmp_path / "data", n=6)
    data = load_scene_data(tmp_path / "data")
    around_table = np.asarray(data.scene_aabb_m)  # the cameras circle it at 0.6 m
    whole_room = np.array([[-1.0, -1.0, -1.0], [1.0, 1.0, 1.0]])
    assert cameras_outside(data, around_table) == 1.0
    assert cameras_outside(data, whole_room) == 0.0
    auto = dataclasses.replace(TINY_FIELD, room=None)
    assert field_config(auto, data, around_table).room is True
    assert field_config(auto, data, whole_room).room is False
    assert field_config(None, data, around_table).room is False  # opt-in (RoomConfig's doc)
    forced = dataclasses.replace(TINY_FIELD, room=True)
    assert field_config(forced, data, whole_room).room is True
    closed = dataclasses.replace(auto, closed_bottom=True)
    assert field_config(closed, data, around_table).room is False
    for clash in ({"closed_bottom": True}, {"learned_background": False}):
        with pytest.raises(NeoError, match="--field.room True"):
            field_config(dataclasses.replace(forced, **clash), data, around_table)


class FogRoom(RoomField):
    """A room of constant density and colour out to 3 m from the box centre."""

    def density_and_features(self, points):
        sigma = torch.where(points.norm(dim=-1) < 3.0, 0.3, 0.0)
        return sigma, torch.zeros(len(points), 15)

    def color(self, geo, directions):
        return torch.full((len(geo), 3), 0.7)


def test_training_and_rendering_see_the_same_room():
    room = FogRoom(SMALL_ROOM, BOX)
    gen = torch.Generator().manual_seed(0)
    origins = torch.tensor([[2.0, 0.0, 0.0]]).expand(64, 3).contiguous()
    directions = torch.nn.functional.normalize(
        torch.tensor([-1.0, 0.0, 0.0]) + 0.1 * torch.randn(64, 3, generator=gen), dim=-1
    )
    env = room.environment(directions).detach()
    seen = []
    for jitter in (False, True):
        with torch.no_grad():
            light = outside_light(room, origins, directions, 0.1, jitter=jitter, generator=gen)
        # back colour = fog behind the sphere + what passes it times the environment
        seen.append(light.front_trans * ((light.back_rgb - 0.7) / (env - 0.7)).mean(-1))
    _, t_exact = _brute_force(room, origins[0], directions[0], 0.1, 5.0)
    inner = ray_sphere(origins[:1], directions[:1], room.center, room.radius)
    gap = float(inner[1] - inner[0])  # the sphere around the box is not the room's
    exact = t_exact * float(torch.exp(torch.tensor(0.3 * gap)))
    assert abs(float(seen[0][0]) - exact) < 0.03, (seen[0][0], exact)
    assert abs(float(seen[1].mean() - seen[0].mean())) < 0.03

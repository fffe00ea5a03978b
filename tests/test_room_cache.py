"""Renders of a room that is not being trained (fields/room.py's cached grid,
rendering/light_memo.py): the grid holds each cell's largest density, its coarse samples
give light as close to the integral as the network's, the memo serves a second render of
the same rays (from a deep copy too) and never serves light of weights that changed."""

from __future__ import annotations

import copy
import dataclasses

import pytest
import torch

from neoedit.fields.radiance import RadianceField
from neoedit.fields.room import RoomField, contract, uncontract
from neoedit.rendering import outside
from neoedit.rendering.light_memo import LightMemo, RoomLightEntry
from neoedit.rendering.outside import outside_light, ray_sphere
from neoedit.utils.optim import frozen
from tests.conftest import TINY_FIELD
from tests.test_room import BOX, SMALL_ROOM, ShellRoom, _brute_force, _count_room_light


def test_uncontract_inverts_the_contraction_everywhere():
    gen = torch.Generator().manual_seed(0)
    directions = torch.nn.functional.normalize(torch.randn(400, 3, generator=gen), dim=-1)
    radii = torch.logspace(-2, 3, 400)[torch.randperm(400, generator=gen)]
    y = (directions * radii[:, None]).double()
    torch.testing.assert_close(uncontract(contract(y)), y, rtol=1e-6, atol=1e-9)


def _cell_centres(r: int) -> torch.Tensor:
    """Centres (N,3) of the cells of an r^3 grid over the contracted cube, in its coordinates."""
    axis = torch.arange(r, dtype=torch.float32)
    ijk = torch.stack(torch.meshgrid(axis, axis, axis, indexing="ij"), -1).reshape(-1, 3)
    return (ijk + 0.5) / r * 4.0 - 2.0


def test_the_cached_grid_keeps_each_cells_largest_density_out_to_the_far_plane():
    cfg = dataclasses.replace(SMALL_ROOM, grid_resolution=24, grid_probes=3)
    room = RoomField(cfg, BOX, seed=3)
    c = _cell_centres(cfg.grid_resolution)
    c = c[c.norm(dim=-1) < 1.9]  # cell centres inside the contracted ball
    points = room.center + room.radius * uncontract(c)
    with torch.no_grad():
        truth = room.density_and_features(points)[0]
        cached = room.cached_density(points)
    assert room.grid.shape == (24, 24, 24)
    assert bool((cached >= truth - 1e-6).all())  # the centre is one of the probes
    assert float((cached - truth).abs().max()) > 0  # and the jittered ones are others
    # points hundreds of box radii out fall in the cube's corner cells: those are probed
    # too (the density is a softplus: never 0 where the network answers)
    gen = torch.Generator().manual_seed(1)
    far = torch.nn.functional.normalize(torch.randn(2000, 3, generator=gen), dim=-1)
    far = room.center + far * room.radius * torch.logspace(1, 3, 2000)[:, None]
    with torch.no_grad():
        assert bool((room.cached_density(far) > 0).all())


def test_the_grid_and_the_weights_key_follow_every_change_of_the_weights():
    room = RoomField(dataclasses.replace(SMALL_ROOM, grid_resolution=16), BOX, seed=3)
    points = room.center + torch.tensor([[2.0, 0.0, 0.0], [0.0, 5.0, 1.0]])
    with torch.no_grad():
        before = room.cached_density(points).clone()
    key = room.weights_key()
    assert room.weights_key() == key  # reading changes nothing
    state = {k: v + 0.5 if k.endswith("bias") else v for k, v in room.state_dict().items()}
    room.load_state_dict(state)
    assert room.weights_key() != key and room.grid.numel() == 0
    with torch.no_grad():
        after = room.cached_density(points)
    assert not torch.equal(after, before)
    # an optimiser step changes the weights in place
    key = room.weights_key()
    opt = torch.optim.SGD(room.parameters(), lr=0.1)
    room.density_and_features(points)[0].sum().backward()
    opt.step()
    assert room.weights_key() != key
    # a deep copy keeps the key and shares the grid; training the copy renews its key only
    with torch.no_grad():
        room.cached_density(points)
    key = room.weights_key()
    twin = copy.deepcopy(room)
    assert twin.weights_key() == key and twin.grid is room.grid
    with torch.no_grad():
        next(twin.parameters()).add_(1.0)
    assert twin.weights_key() != key and room.weights_key() == key
    # weights changed and then copied at once: the copy is not named as the old weights
    with torch.no_grad():
        next(room.parameters()).add_(1.0)
    assert copy.deepcopy(room).weights_key() != key


def test_renders_from_the_cached_grid_are_as_close_to_the_integral_as_network_renders():
    """Without gradients the coarse samples come from the grid: against a brute-force
    integral of the shell between a far camera and the box, its light must be as good as
    the light from the network's own coarse samples."""
    gen = torch.Generator().manual_seed(4)
    origins = torch.tensor([[2.5, 0.05, 0.02]]).expand(12, 3).contiguous()
    directions = torch.nn.functional.normalize(
        torch.tensor([-1.0, 0.0, 0.0]) + 0.03 * torch.randn(12, 3, generator=gen), dim=-1
    )
    probe = ShellRoom(SMALL_ROOM, BOX)
    t_in, t_out = ray_sphere(origins, directions, probe.center, probe.radius)
    assert bool((t_out > t_in).all())  # every ray crosses the shell, then the box
    truth = [
        _brute_force(probe, o, d, 0.05, float(t), 50_000)
        for o, d, t in zip(origins, directions, t_in, strict=True)
    ]
    colour = torch.stack([c for c, _ in truth]).float()
    trans = torch.tensor([t for _, t in truth])
    assert float(trans.max()) < 0.9  # the shell is really in front
    errors = []
    for res in (0, 128):  # the network's coarse samples; a grid of 128 cells a side
        room = ShellRoom(dataclasses.replace(SMALL_ROOM, grid_resolution=res), BOX)
        with torch.no_grad():
            light = outside_light(room, origins, directions, 0.05)
        errors.append(
            torch.cat(
                [(light.front_rgb - colour).abs().reshape(-1), (light.front_trans - trans).abs()]
            )
        )
    # measured: max 0.006 / 0.011, mean 0.0039 / 0.0044 (64 cells a side: 0.024 / 0.0056)
    assert float(errors[1].max()) < 0.015
    assert float(errors[1].mean()) <= 1.25 * float(errors[0].mean())


def _rays(n=48, seed=0):
    """Rays from a camera outside the room's inner sphere, towards the box and around it."""
    gen = torch.Generator().manual_seed(seed)
    origins = torch.tensor([[0.6, 0.05, 0.02]]).expand(n, 3).contiguous()
    directions = torch.nn.functional.normalize(
        torch.tensor([-1.0, 0.0, 0.0]) + 0.25 * torch.randn(n, 3, generator=gen), dim=-1
    )
    return origins, directions


def test_a_second_render_of_the_same_rays_takes_the_room_from_the_memo_until_the_weights_change():
    cfg = dataclasses.replace(TINY_FIELD, learned_background=True, room=True, room_field=SMALL_ROOM)
    room = RadianceField(cfg, BOX, seed=2).background_head
    origins, directions = _rays(seed=1)
    opaque = torch.zeros(len(origins), dtype=torch.bool)
    opaque[::3] = True  # a camera outside the inner sphere: these still see the room
    calls: list[int] = []
    with torch.no_grad(), pytest.MonkeyPatch.context() as m:
        _count_room_light(m, calls)
        outside.MEMO.clear()
        first = outside_light(room, origins, directions, 0.05, opaque=opaque)
        again = outside_light(copy.deepcopy(room), origins, directions, 0.05, opaque=opaque)
        part = outside_light(room, origins[:10], directions[:10], 0.05)  # other rays: a new key
        outside.MEMO.clear()
        fresh = outside_light(room, origins, directions, 0.05, opaque=opaque)
    assert calls == [48, 10, 48]
    for a, b in ((first.front_rgb, fresh.front_rgb), (first.back_rgb, fresh.back_rgb)):
        assert torch.equal(a, b)
    assert torch.equal(first.front_trans, fresh.front_trans)
    assert torch.equal(again.back_rgb, first.back_rgb)
    torch.testing.assert_close(part.back_rgb, first.back_rgb[:10])
    with pytest.MonkeyPatch.context() as m:
        _count_room_light(m, calls)
        # a frozen room in a render with gradients (an edit's loss) is served from the memo
        with frozen(room):
            outside_light(room, origins, directions, 0.05, opaque=opaque)
        assert calls[3:] == []
        # a room being trained is sampled with gradients, then its weights change
        trained = outside_light(room, origins, directions, 0.05)
        (trained.back_rgb.sum() + trained.front_rgb.sum()).backward()
        with torch.no_grad():
            for p in room.parameters():
                p -= 0.5 * p.grad.sign()
            after = outside_light(room, origins, directions, 0.05, opaque=opaque)
    assert calls[3:] == [48, 48]
    assert float((after.back_rgb - first.back_rgb).abs().max()) > 1e-3


def test_frozen_turns_gradients_off_inside_the_block_and_back_on_after():
    field = torch.nn.Linear(3, 2)
    field.bias.requires_grad_(False)  # already frozen: stays so
    with pytest.raises(RuntimeError, match="inside"), frozen(field):
        assert not any(p.requires_grad for p in field.parameters())
        raise RuntimeError("inside")
    assert field.weight.requires_grad and not field.bias.requires_grad
    with frozen(torch.tensor([0.1, 0.2, 0.3])):  # a constant background: nothing to do
        pass


def test_the_memo_forgets_the_least_recently_used_entries_first():
    one = RoomLightEntry.empty(100, torch.device("cpu"))
    memo = LightMemo(max_bytes=3 * one.nbytes)
    for k in range(3):
        memo.store(("k", k), RoomLightEntry.empty(100, torch.device("cpu")))
    assert memo.lookup(("k", 0)) is not None  # 0 is now the most recently used
    memo.store(("k", 3), one)
    assert len(memo) == 3 and memo.lookup(("k", 1)) is None
    assert all(memo.lookup(("k", k)) is not None for k in (0, 2, 3))
    memo.store(("big",), RoomLightEntry.empty(1000, torch.device("cpu")))  # larger than all
    assert memo.lookup(("big",)) is None and len(memo) == 3

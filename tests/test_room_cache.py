"""Renders of a room that is not being trained (rendering/light_memo.py): the room's
weights key follows every change of its weights, the memo serves a second render of the
same rays (from a deep copy too) and never serves light of weights that changed."""

from __future__ import annotations

import copy
import dataclasses

import pytest
import torch

from neoedit.fields.radiance import RadianceField
from neoedit.fields.room import RoomField
from neoedit.rendering import outside
from neoedit.rendering.light_memo import LightMemo, RoomLightEntry
from neoedit.rendering.outside import outside_light
from neoedit.utils.optim import frozen
from tests.conftest import TINY_FIELD
from tests.test_room import BOX, SMALL_ROOM, _count_room_light


def test_the_weights_key_follows_every_change_of_the_weights():
    room = RoomField(SMALL_ROOM, BOX, seed=3)
    points = room.center + torch.tensor([[2.0, 0.0, 0.0], [0.0, 5.0, 1.0]])
    key = room.weights_key()
    assert room.weights_key() == key  # reading changes nothing
    state = {k: v + 0.5 if k.endswith("bias") else v for k, v in room.state_dict().items()}
    room.load_state_dict(state)
    assert room.weights_key() != key
    # an optimiser step changes the weights in place
    key = room.weights_key()
    opt = torch.optim.SGD(room.parameters(), lr=0.1)
    room.density_and_features(points)[0].sum().backward()
    opt.step()
    assert room.weights_key() != key
    # a deep copy keeps the key; training the copy renews its key only
    key = room.weights_key()
    twin = copy.deepcopy(room)
    assert twin.weights_key() == key
    with torch.no_grad():
        next(twin.parameters()).add_(1.0)
    assert twin.weights_key() != key and room.weights_key() == key
    # weights changed and then copied at once: the copy is not named as the old weights
    with torch.no_grad():
        next(room.parameters()).add_(1.0)
    assert copy.deepcopy(room).weights_key() != key


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

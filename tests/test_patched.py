"""Local edits as patches: outside its region a patched field is its base, exactly."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from neoedit.fields.hashgrid import HashGridConfig
from neoedit.fields.patched import PatchedField, edit_region, inside_box
from neoedit.fields.radiance import RadianceField, RadianceFieldConfig
from neoedit.geometry import OrientedBox
from neoedit.scene import load_scene, save_scene

AABB = torch.tensor([[-0.5, -0.5, -0.1], [0.5, 0.5, 0.4]])
CFG = RadianceFieldConfig(
    hashgrid=HashGridConfig(n_levels=4, log2_hashmap_size=10, max_resolution=64)
)


def perturbed(field: RadianceField, seed: int) -> RadianceField:
    import copy

    other = copy.deepcopy(field)
    gen = torch.Generator().manual_seed(seed)
    with torch.no_grad():
        for p in other.parameters():
            p.add_(torch.randn(p.shape, generator=gen) * 0.5)
    return other


@settings(max_examples=25, deadline=None)
@given(
    cx=st.floats(-0.3, 0.3),
    cy=st.floats(-0.3, 0.3),
    size=st.floats(0.02, 0.3),
    yaw=st.floats(-180, 180),
    seed=st.integers(0, 1000),
)
def test_patched_field_is_base_outside_and_patch_inside(cx, cy, size, yaw, seed):
    base = RadianceField(CFG, AABB, seed=1)
    box = OrientedBox((cx, cy, 0.1), (size, 0.7 * size, size), yaw)
    field = PatchedField(base)
    patch = field.add_patch([box])
    with torch.no_grad():
        patch.load_state_dict(perturbed(base, seed).state_dict())
    gen = torch.Generator().manual_seed(seed)
    pts = AABB[0] + torch.rand(4000, 3, generator=gen) * (AABB[1] - AABB[0])
    dirs = torch.nn.functional.normalize(torch.randn(4000, 3, generator=gen), dim=-1)
    inside = torch.as_tensor(box.contains(pts.numpy()))
    assert torch.equal(inside_box(pts, box), inside)  # torch and numpy containment agree
    with torch.no_grad():
        sigma, rgb = field(pts, dirs)
        sb, cb = base(pts, dirs)
        sp, cp = patch(pts, dirs)
        dens = field.density(pts)
    assert torch.allclose(sigma[~inside], sb[~inside], atol=1e-5, rtol=1e-5)
    assert torch.allclose(rgb[~inside], cb[~inside], atol=1e-6)
    assert torch.allclose(sigma[inside], sp[inside], atol=1e-5, rtol=1e-5)
    assert torch.allclose(rgb[inside], cp[inside], atol=1e-6)
    assert torch.allclose(dens, sigma, atol=1e-5, rtol=1e-5)


def test_later_patches_win_and_start_from_what_renders_their_region():
    base = RadianceField(CFG, AABB, seed=1)
    field = PatchedField(base)
    first = field.add_patch([OrientedBox((0.0, 0.0, 0.1), (0.2, 0.2, 0.2), 0.0)])
    with torch.no_grad():
        first.load_state_dict(perturbed(base, 3).state_dict())
    # overlapping the first patch: starts as a copy of it, not of the base
    second = field.add_patch([OrientedBox((0.05, 0.0, 0.1), (0.1, 0.1, 0.1), 30.0)])
    assert all(
        torch.equal(a, b)
        for a, b in zip(first.state_dict().values(), second.state_dict().values(), strict=True)
    )
    with torch.no_grad():
        second.load_state_dict(perturbed(base, 4).state_dict())
    pts = torch.tensor([[0.05, 0.0, 0.1], [-0.08, -0.08, 0.1], [0.4, 0.4, 0.1]])
    assert field.owner(pts).tolist() == [1, 0, -1]
    with torch.no_grad():
        got = field.density(pts)
        assert torch.allclose(got[0], second.density(pts[:1])[0])
        assert torch.allclose(got[1], first.density(pts[1:2])[0])
        assert torch.allclose(got[2], base.density(pts[2:])[0])
    # a patch elsewhere starts from the base
    third = field.add_patch([OrientedBox((0.35, -0.35, 0.1), (0.05, 0.05, 0.05), 0.0)])
    assert torch.equal(third.encoding.table, base.encoding.table)


def test_gradients_reach_only_the_patch_through_its_region():
    base = RadianceField(CFG, AABB, seed=1).requires_grad_(False)
    field = PatchedField(base)
    box = OrientedBox((0.0, 0.0, 0.1), (0.2, 0.2, 0.2), 0.0)
    patch = field.add_patch([box]).requires_grad_(True)
    outside = torch.tensor([[0.3, 0.3, 0.1], [-0.3, 0.2, 0.0]])
    assert not field.density(outside).requires_grad  # nothing trainable answers out there
    field.density(torch.tensor([[0.01, 0.02, 0.1]])).sum().backward()
    assert patch.encoding.table.grad is not None and patch.encoding.table.grad.abs().sum() > 0


def test_edit_region_reaches_under_the_box():
    box = OrientedBox((0.1, 0.0, 0.05), (0.1, 0.05, 0.1), 20.0)
    region = edit_region(box, 0.03)
    assert region.contains(box.corners(), margin_m=1e-9).all()
    assert region.contains(np.array([[0.1, 0.0, -0.025]]))[0]
    assert not region.contains(np.array([[0.1, 0.0, -0.035]]))[0]


def test_patched_scene_round_trips(trained: Path, tmp_path: Path):
    scene = load_scene(trained)
    region = [OrientedBox((0.0, 0.0, 0.05), (0.1, 0.1, 0.1), 10.0)]
    patch = scene.patched().add_patch(region)
    with torch.no_grad():
        patch.load_state_dict(perturbed(patch, 7).state_dict())
    scene.meta.patches.append({"region": [b.to_dict() for b in region], "version": "x"})
    save_scene(tmp_path / "v", scene)
    again = load_scene(tmp_path / "v")
    assert isinstance(again.field, PatchedField) and len(again.field.patches) == 1
    pts = torch.rand(500, 3) * 0.2 - torch.tensor([0.1, 0.1, 0.0])
    with torch.no_grad():
        assert torch.allclose(again.field.density(pts), scene.field.density(pts))

    # the scan cannot train an edited version further (its patches belong to their edits)
    import pytest

    from neoedit.errors import NeoError
    from neoedit.training.trainer import TrainConfig, train

    with pytest.raises(NeoError, match="edited version"):
        train(
            Path(scene.meta.data_path),
            tmp_path / "v",
            TrainConfig(max_steps=scene.meta.step + 5, eval_every=0),
            resume=True,
        )


@given(st.integers(0, 10_000), st.integers(1, 6))
def test_the_cell_lookup_owner_equals_the_exact_box_tests(seed, n_boxes):
    """ComposedField.owner skips points in cells no box touches; it must agree with testing
    every point against every box."""
    from neoedit.fields.composed import ComposedField, region_owner

    rng = np.random.default_rng(seed)
    aabb = torch.tensor([[-0.5, -0.5, -0.2], [0.5, 0.5, 0.4]])
    regions = [
        [
            OrientedBox(
                tuple(rng.uniform(-0.4, 0.4, 3)),
                tuple(rng.uniform(0.01, 0.3, 3)),
                float(rng.uniform(-180, 180)),
            )
        ]
        for _ in range(n_boxes)
    ]
    comp = ComposedField(
        RadianceField(CFG, aabb, seed=0), [(r, RadianceField(CFG, aabb, seed=1)) for r in regions]
    )
    pts = torch.as_tensor(rng.uniform(-0.5, 0.5, (5000, 3)), dtype=torch.float32)
    pts[:, 2] = pts[:, 2] * 0.6 + 0.1
    assert torch.equal(comp.owner(pts), region_owner(pts, regions))


def _yaw_motion(deg: float, shift: tuple[float, float, float]) -> np.ndarray:
    c, s = np.cos(np.radians(deg)), np.sin(np.radians(deg))
    m = np.eye(4)
    m[:2, :2] = [[c, -s], [s, c]]
    m[:3, 3] = shift
    return m


def test_a_carried_part_is_its_source_under_the_motion_exactly():
    """A carried part answers at x what the field it was copied from answered at T^-1 x,
    seen along R^-1 d; carried again, the motions compose onto the original weights."""
    base = RadianceField(CFG, AABB, seed=1)
    source = OrientedBox((-0.2, 0.0, 0.1), (0.1, 0.1, 0.15), 0.0)
    motion = _yaw_motion(40.0, (0.3, 0.1, 0.0))
    target = source.transformed(motion)
    field = PatchedField(base)
    part = field.add_carried([target], motion, field.renderer_of([source]))
    assert not any(p.requires_grad for p in part.parameters())
    gen = torch.Generator().manual_seed(3)
    local = torch.rand(800, 3, generator=gen) - 0.5
    world = (local.numpy() * target.size_m) @ target.rotation.T + np.asarray(target.center_m)
    inside = torch.as_tensor(world, dtype=torch.float32)
    dirs = torch.nn.functional.normalize(torch.randn(800, 3, generator=gen), dim=-1)
    rot = torch.as_tensor(motion[:3, :3], dtype=torch.float32)
    back = (inside - torch.as_tensor(motion[:3, 3], dtype=torch.float32)) @ rot
    with torch.no_grad():
        sigma, rgb = field(inside, dirs)
        s0, c0 = base(back, dirs @ rot)
    assert torch.allclose(sigma, s0, atol=1e-5, rtol=1e-4)
    assert torch.allclose(rgb, c0, atol=1e-5)
    second = _yaw_motion(-15.0, (-0.05, 0.2, 0.0))
    again = field.add_carried([target.transformed(second)], second, field.renderer_of([target]))
    assert np.allclose(again.matrix(), second @ motion)
    assert again.field is not part.field and isinstance(again.field, RadianceField)


def test_a_carried_part_round_trips(trained: Path, tmp_path: Path):
    scene = load_scene(trained)
    source = OrientedBox((0.0, 0.0, 0.05), (0.1, 0.1, 0.1), 10.0)
    motion = _yaw_motion(30.0, (0.1, -0.05, 0.0))
    patched = scene.patched()
    patched.add_carried([source.transformed(motion)], motion, patched.renderer_of([source]))
    save_scene(tmp_path / "v", scene)
    again = load_scene(tmp_path / "v")
    (transform,) = again.field.part_transforms()
    assert np.allclose(transform, motion)
    target = source.transformed(motion)
    near = (target.corners() - np.asarray(target.center_m)) * 0.9 + np.asarray(target.center_m)
    pts = torch.as_tensor(near, dtype=torch.float32)
    pts = torch.cat([pts, torch.rand(500, 3) * 0.2 - torch.tensor([0.1, 0.1, 0.0])])
    with torch.no_grad():
        assert torch.allclose(again.field.density(pts), scene.field.density(pts))


def test_the_part_inside_a_box_is_the_one_owning_most_of_it():
    """A neighbour's region touching a corner of the box does not make it the box's part."""
    base = RadianceField(CFG, AABB, seed=1)
    field = PatchedField(base)
    box = OrientedBox((0.0, 0.0, 0.1), (0.1, 0.1, 0.1), 0.0)
    corner = field.add_patch([OrientedBox((0.05, 0.05, 0.15), (0.04, 0.04, 0.04), 0.0)])
    assert field.renderer_of([box]) is corner  # any corner: the newest owner
    assert field.renderer_inside(box) is base
    inside = field.add_patch([box.grown(0.01)])
    assert field.renderer_inside(box) is inside


def test_a_carried_part_is_stored_against_the_base_in_a_scene_store():
    from neoedit.storage.blobs import _candidates

    parent = {"field.encoding.table": None, "patch0.encoding.table": None}
    assert "field.encoding.table" in _candidates("patch1.field.encoding.table", parent)
    assert set(_candidates("patch1.encoding.table", parent)) == set(parent)


def _slab_cells(slab: OrientedBox, n: int, z: float) -> torch.Tensor:
    """World points (n*n,3) at the centres of an n x n map over the slab's x/y extent (the
    outer ones a hair inside its faces)."""
    hx, hy = np.asarray(slab.half_extents[:2]) * (1 - 1e-4)
    gx, gy = np.meshgrid(np.linspace(-hx, hx, n), np.linspace(-hy, hy, n), indexing="ij")
    local = np.stack([gx.ravel(), gy.ravel(), np.zeros(n * n)], 1)
    world = local @ slab.rotation.T + np.asarray(slab.center_m) + [0.0, 0.0, z]
    return torch.as_tensor(world, dtype=torch.float32)


def test_a_shade_darkens_what_older_parts_answer_in_its_slab_and_nothing_else():
    """At the map's cell centres the colour is the base's times the cell's ratio; the part
    carried in after the shade (the moved object), and every point outside the slab, are
    answered exactly as without it."""
    base = RadianceField(CFG, AABB, seed=1)
    field = PatchedField(base)
    slab = OrientedBox((0.1, -0.05, 0.0), (0.2, 0.16, 0.02), 30.0)
    n = 6
    ratio = torch.linspace(0.2, 1.0, n * n).reshape(n, n)
    field.add_shade(slab, ratio)
    corner = np.asarray(slab.center_m) + slab.rotation @ [0.07, 0.055, 0.02]
    thing = OrientedBox(tuple(corner), (0.05, 0.05, 0.06), 30.0)  # stands on the slab
    field.add_carried([thing], np.eye(4), base)
    pts = _slab_cells(slab, n, 0.002)
    dirs = torch.nn.functional.normalize(torch.randn(len(pts), 3), dim=-1)
    held = torch.as_tensor(thing.contains(pts.numpy()))
    assert 0 < int(held.sum()) < len(pts)
    with torch.no_grad():
        sigma, rgb = field(pts, dirs)
        s0, c0 = base(pts, dirs)
    factor = torch.where(held, torch.ones(len(pts)), ratio.reshape(-1))
    assert torch.allclose(sigma, s0, atol=1e-6)  # a shade never changes density
    assert torch.allclose(rgb, c0 * factor[:, None], atol=1e-4)
    gen = torch.Generator().manual_seed(4)
    far = AABB[0] + torch.rand(3000, 3, generator=gen) * (AABB[1] - AABB[0])
    far = far[~torch.as_tensor(slab.contains(far.numpy()))]
    far = far[~torch.as_tensor(thing.contains(far.numpy()))]
    fdirs = torch.nn.functional.normalize(torch.randn(len(far), 3, generator=gen), dim=-1)
    with torch.no_grad():
        assert torch.equal(field(far, fdirs)[1], base(far, fdirs)[1])


def test_a_shade_round_trips_with_its_scene(trained: Path, tmp_path: Path):
    scene = load_scene(trained)
    slab = OrientedBox((0.02, 0.0, 0.0), (0.12, 0.12, 0.02), -20.0)
    ratio = torch.rand(9, 9, generator=torch.Generator().manual_seed(2)) * 0.5 + 0.5
    scene.patched().add_shade(slab, ratio)
    save_scene(tmp_path / "v", scene)
    again = load_scene(tmp_path / "v")
    assert again.meta.shades == [
        {"box": slab.to_dict(), "after": 0, "version": scene.meta.version_id}
    ]
    (shade,) = again.field.shades
    assert torch.equal(shade.ratio, ratio) and shade.after == 0
    pts = _slab_cells(slab, 17, 0.0)
    dirs = torch.nn.functional.normalize(torch.ones_like(pts), dim=-1)
    with torch.no_grad():
        assert torch.allclose(again.field(pts, dirs)[1], scene.field(pts, dirs)[1])
        assert not torch.allclose(again.field(pts, dirs)[1], again.field.base(pts, dirs)[1])


def test_a_malformed_shade_record_is_one_clear_error(trained: Path, tmp_path: Path):
    import json

    import pytest

    from neoedit.errors import NeoError

    scene = load_scene(trained)
    slab = OrientedBox((0.02, 0.0, 0.0), (0.12, 0.12, 0.02), 0.0)
    scene.patched().add_shade(slab, torch.full((4, 4), 0.8))
    save_scene(tmp_path / "v", scene)
    meta_file = tmp_path / "v" / "scene.json"
    good = json.loads(meta_file.read_text())
    for bad in ({"after": True}, {"after": 5}, {"after": -1}, {"version": None}):
        record = {**good["shades"][0], **bad}
        record = {k: v for k, v in record.items() if v is not None}
        meta_file.write_text(json.dumps({**good, "shades": [record]}))
        with pytest.raises(NeoError, match=r"shades\[0\]"):
            load_scene(tmp_path / "v")

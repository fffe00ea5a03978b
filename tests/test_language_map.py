"""The language field after an edit: the parent's weights read through the edit's map
(:mod:`neoedit.fields.language_map`), checked against a point-by-point reference, through
save and reload (folder and store), over a chain of edits, and against the paper's
distilled update."""

from __future__ import annotations

import copy
import json
from pathlib import Path

import numpy as np
import pytest
import torch

from neoedit.edit.language_update import LanguageEdit, LanguageUpdateConfig, update_language
from neoedit.errors import NeoError
from neoedit.fields.language_map import LanguageMap, pushed_out_of_footprint
from neoedit.geometry import OrientedBox, points_in_box
from neoedit.geometry.box import box_iou_3d
from neoedit.geometry.transforms import make_transform, rot_z
from neoedit.scene import load_scene, save_scene
from neoedit.storage.store import SceneStore


def test_points_pushed_out_of_a_box_land_just_outside_its_footprint():
    box = OrientedBox((0.1, -0.1, 0.05), (0.08, 0.12, 0.1), 35.0)
    gen = torch.Generator().manual_seed(0)
    local = (torch.rand(500, 3, generator=gen) - 0.5) * torch.tensor(box.size_m) * 0.99
    pts = local @ torch.tensor(box.rotation, dtype=torch.float32).T + torch.tensor(box.center_m)
    pts = pts.float()
    out = pushed_out_of_footprint(pts, box, 0.02)
    assert not points_in_box(out, box).any()
    assert points_in_box(out, box.grown(0.0201)).all()
    assert torch.allclose(out[:, 2], pts[:, 2])  # height kept


def _inside(box: OrientedBox, p: np.ndarray) -> bool:
    local = (p - np.asarray(box.center_m)) @ np.asarray(box.rotation)
    return bool(np.all(np.abs(local) <= np.asarray(box.size_m) / 2))


def _pushed(box: OrientedBox, p: np.ndarray, ring: float) -> np.ndarray:
    """One point out through the nearest side face (the reference, written point by point)."""
    rot = np.asarray(box.rotation)
    local = (p - np.asarray(box.center_m)) @ rot
    half = np.asarray(box.size_m) / 2
    axis = int(np.argmin(half[:2] - np.abs(local[:2])))
    local[axis] = (1.0 if local[axis] >= 0 else -1.0) * (half[axis] + ring)
    return local @ rot.T + np.asarray(box.center_m)


def _reference(pts: np.ndarray, src: OrientedBox, tgt: OrientedBox, motion, ring: float):
    """Where one edit (a source box, a target box under ``motion``) sends each point, one
    point at a time: T^-1 x in the target, pushed out of the source, else the point."""
    inverse = np.linalg.inv(motion)
    out = []
    for p in pts:
        if _inside(tgt, p):
            out.append(inverse[:3, :3] @ p + inverse[:3, 3])
        elif _inside(src, p):
            out.append(_pushed(src, p, ring))
        else:
            out.append(p)
    return np.asarray(out)


def _motion(yaw_deg: float, shift) -> np.ndarray:
    return make_transform(rot_z(yaw_deg), np.asarray(shift, float))


def test_a_map_sends_each_point_where_the_parent_holds_its_content():
    """Inside a target box: T^-1 x; inside a source box: pushed out of its footprint;
    targets over sources where they overlap; elsewhere the point itself."""
    src = OrientedBox((0.0, 0.0, 0.05), (0.1, 0.08, 0.1), 20.0)
    motion = _motion(40.0, (0.06, 0.02, 0.0))
    tgt = OrientedBox((0.06, 0.02, 0.05), (0.1, 0.08, 0.1), 60.0)  # overlaps the source
    edit_map = LanguageMap.of([src], [(tgt, motion)], 0.02)
    rng = np.random.default_rng(0)
    pts = rng.uniform([-0.12, -0.12, -0.02], [0.18, 0.14, 0.14], (3000, 3))
    got = edit_map(torch.as_tensor(pts, dtype=torch.float32)).numpy()
    assert np.allclose(got, _reference(pts, src, tgt, motion, 0.02), atol=2e-5)
    in_tgt = np.array([_inside(tgt, p) for p in pts])
    in_src = np.array([_inside(src, p) for p in pts]) & ~in_tgt
    regions = {"target": in_tgt.sum(), "source": in_src.sum(), "rest": (~in_tgt & ~in_src).sum()}
    assert min(regions.values()) > 100, regions  # every case drawn often
    # no target: a removal; no box at all: the identity (the same tensor back)
    same = torch.rand(10, 3) + 5.0
    assert LanguageMap.of([src], [], 0.02)(same) is same


def test_a_map_is_stored_as_it_looks_points_up_and_bad_entries_are_refused():
    src = OrientedBox((0.0123456789, 0.0, 0.05), (0.1, 0.08, 0.1), 20.123456)
    edit_map = LanguageMap.of([src], [(src, _motion(33.3, (0.1, 0.0, 0.0)))], 0.02)
    again = LanguageMap.from_dict(json.loads(json.dumps(edit_map.to_dict())))
    pts = torch.rand(2000, 3) * 0.3 - 0.15
    assert torch.equal(edit_map(pts), again(pts))  # the rounding happened when it was made
    good = edit_map.to_dict()
    bad_cases = {  # each refused with its reason
        "'sources'": {k: v for k, v in good.items() if k != "sources"},
        "rigid 4x4": {**good, "targets": [{**good["targets"][0], "transform": np.diag([2, 2, 2, 1.0]).tolist()}]},
        "bad box": {**good, "sources": [{"center": [0, 0]}]},
        "ring_m must be": {**good, "ring_m": float("nan")},
    }  # fmt: skip
    for reason, entry in bad_cases.items():
        with pytest.raises(NeoError, match=r"scene.json: language.maps\[0\]") as refused:
            LanguageMap.from_dict(entry, "scene.json: language.maps[0]")
        assert reason in str(refused.value), (reason, str(refused.value))


def _drawn_in(box: OrientedBox, gen: torch.Generator, n: int = 500) -> torch.Tensor:
    local = (torch.rand(n, 3, generator=gen) - 0.5) * torch.tensor(box.size_m) * 0.98
    rot = torch.tensor(box.rotation, dtype=torch.float32)
    return (local.float() @ rot.T + torch.tensor(box.center_m)).float()


def _features(scene, pts: torch.Tensor) -> torch.Tensor:
    return scene.language.language(pts)


def test_a_composed_update_answers_what_the_parent_answers_where_the_content_came_from(
    move_scene: Path, sim_root: Path, tmp_path: Path
):
    """The default update trains nothing: at a moved point the new version's features are
    the parent's at T^-1 x, in the emptied box the table's around it, elsewhere unchanged;
    saved in a folder or a store and reloaded it answers the same, a second edit composes
    over the first, and the paper's distilled update bakes both into new weights."""
    action = json.loads((sim_root / "pick_place_1" / "scene.json").read_text())["actions"][0]
    src = OrientedBox.from_dict(action["source_box"])
    motion = np.asarray(action["transform_world"], dtype=np.float64)
    tgt = OrientedBox.from_dict(action["target_box"])
    parent = load_scene(move_scene)
    child = copy.deepcopy(parent)
    edit = LanguageEdit(source=[src], targets=[(tgt, motion)])
    timings = update_language(parent, child, edit, LanguageUpdateConfig())
    assert "language_loss" not in timings and timings["new_points"] > 0  # nothing trained
    for (name, a), b in zip(child.language.state_dict().items(), parent.language.state_dict().values(), strict=True):  # fmt: skip
        assert torch.equal(a, b), name
    gen = torch.Generator().manual_seed(1)
    around = (torch.rand(3000, 3, generator=gen) - 0.5) * 0.5 + torch.tensor([0.0, 0.0, 0.1])
    pts = torch.cat([around, _drawn_in(src, gen), _drawn_in(tgt, gen)])
    cfg = LanguageUpdateConfig()
    grown = src.grown(cfg.margin_m)  # the map's source: the removal's box and 1 cm around
    sent = _reference(pts.double().numpy(), grown, tgt, motion, cfg.ring_m)
    sent_t = torch.as_tensor(sent, dtype=torch.float32)
    assert torch.allclose(_features(child, pts), _features(parent, sent_t), atol=1e-4)
    in_target = points_in_box(pts, tgt)
    outside = ~in_target & ~points_in_box(pts, grown)
    assert torch.equal(_features(child, pts[outside]), _features(parent, pts[outside]))
    # a folder and a store version reload with their map (a store keeps the weights the
    # version shares with its parent as they were: the same features, bit for bit)
    expected = _features(child, pts)
    save_scene(tmp_path / "folder", child)
    SceneStore.create(tmp_path / "store")
    save_scene(tmp_path / "store" / "parent", parent)
    save_scene(tmp_path / "store" / "child", child)
    for where in ("folder", "store/child"):
        again = load_scene(tmp_path / where)
        assert len(again.language.maps) == 1
        assert torch.equal(_features(again, pts), expected), where
    # a second edit: moved back by the inverse motion, the content is the parent's again
    grandchild = copy.deepcopy(child)
    back = LanguageEdit(source=[tgt], targets=[(src, np.linalg.inv(motion))])
    update_language(child, grandchild, back, LanguageUpdateConfig())
    assert len(grandchild.language.maps) == 2 and len(child.language.maps) == 1
    home = points_in_box(pts, src) & ~points_in_box(pts, tgt)
    assert home.sum() > 100
    assert torch.allclose(_features(grandchild, pts[home]), _features(parent, pts[home]), atol=1e-5)
    # the paper's update: new weights and no maps, drawn towards the composition on the
    # re-rendered surface where the mug is back (away from what the child says there)
    distilled = copy.deepcopy(child)
    cfg = LanguageUpdateConfig(method="distil", steps=30)
    timings = update_language(child, distilled, back, cfg)
    assert timings["language_loss"] > 0 and distilled.language.maps == []
    cloud = distilled.surface_points_m
    cloud = cloud[points_in_box(cloud, src) & ~points_in_box(cloud, tgt)]
    want = _features(grandchild, cloud)
    agree = {
        name: float((_features(s, cloud) * want).sum(-1).mean())
        for name, s in (("distilled", distilled), ("child", child))
    }
    assert len(cloud) > 50 and agree["distilled"] > agree["child"] + 0.1, agree
    # a Python config with a method that does not exist is refused, not distilled
    with pytest.raises(NeoError, match="method must be 'compose' or 'distil'"):
        update_language(child, copy.deepcopy(child), back, LanguageUpdateConfig(method="composed"))  # type: ignore[arg-type]


def test_a_distilled_update_after_composed_ones_keeps_what_they_moved(
    move_scene: Path, sim_root: Path
):
    """The distilled copy drops the parent's maps, so it must learn the earlier edits'
    regions too: after a composed move, a distilled removal somewhere else still says at
    the moved object's new place what the moved version says there."""
    action = json.loads((sim_root / "pick_place_1" / "scene.json").read_text())["actions"][0]
    src = OrientedBox.from_dict(action["source_box"])
    tgt = OrientedBox.from_dict(action["target_box"])
    parent = load_scene(move_scene)
    moved = copy.deepcopy(parent)
    motion = np.asarray(action["transform_world"], dtype=np.float64)
    update_language(parent, moved, LanguageEdit(source=[src], targets=[(tgt, motion)]))
    elsewhere = OrientedBox((-0.15, 0.15, 0.04), (0.06, 0.06, 0.08), 0.0)
    assert box_iou_3d(elsewhere, src) == 0 and box_iou_3d(elsewhere, tgt) == 0
    distilled = copy.deepcopy(moved)
    cfg = LanguageUpdateConfig(method="distil", steps=60)
    update_language(moved, distilled, LanguageEdit(source=[elsewhere], targets=[]), cfg)
    # the query points the move changed: in its boxes, where the base weights disagree
    cloud = distilled.surface_points_m
    cloud = cloud[points_in_box(cloud, tgt) | points_in_box(cloud, src)]
    want = _features(moved, cloud)
    changed = (_features(parent, cloud) * want).sum(-1) < 0.9
    agree = {
        name: float((_features(s, cloud[changed]) * want[changed]).sum(-1).mean())
        for name, s in (("distilled", distilled), ("base weights", parent))
    }
    assert changed.sum() > 30 and agree["distilled"] > 0.9, agree


def test_a_scene_with_a_malformed_language_map_is_refused(move_scene: Path, tmp_path: Path):
    import shutil

    bad = tmp_path / "bad"
    shutil.copytree(move_scene, bad)
    meta = json.loads((bad / "scene.json").read_text())
    meta["language"]["maps"] = [{"sources": [], "targets": [{"box": {"center": [0, 0, 0]}}]}]
    (bad / "scene.json").write_text(json.dumps(meta))
    with pytest.raises(NeoError, match=r"language.maps\[0\]"):
        load_scene(bad)

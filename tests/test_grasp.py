"""Grasp planning on analytic density fields (a box, a cylinder, a table, a neighbour)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import torch

from neoedit.cli import main
from neoedit.geometry import OrientedBox
from neoedit.grasp import GraspConfig, plan_grasps
from neoedit.grasp.antipodal import antipodal_pairs
from neoedit.grasp.gripper import box_corners, gripper_boxes
from neoedit.grasp.surface import object_surface

SOLID = 2000.0  # density [1/m] inside the shapes


def scene_fn(*shapes):
    """A density function: SOLID inside any shape (a callable points -> bool mask)."""

    def density(points: torch.Tensor) -> torch.Tensor:
        inside = torch.zeros(len(points), dtype=torch.bool)
        for s in shapes:
            inside |= s(points)
        return inside.float() * SOLID

    return density


def cuboid(center, size):
    c, h = torch.tensor(center), torch.tensor(size) / 2
    return lambda p: ((p - c).abs() <= h).all(-1)


def cylinder(center, radius, height):
    c = torch.tensor(center)
    return lambda p: (
        ((p[:, :2] - c[:2]).norm(dim=-1) <= radius) & ((p[:, 2] - c[2]).abs() <= height / 2)
    )


TABLE = cuboid((0.0, 0.0, -0.05), (1.0, 1.0, 0.1))  # top at z = 0


def test_antipodal_pairs_on_a_box_have_its_width_and_opposite_normals():
    box = OrientedBox((0.0, 0.0, 0.03), (0.04, 0.05, 0.06), 0.0)
    density = scene_fn(TABLE, cuboid((0.0, 0.0, 0.03), (0.04, 0.05, 0.06)))
    cfg = GraspConfig()
    surface = object_surface(density, box, cfg.surface)
    p1, p2, quality = antipodal_pairs(surface, cfg)
    assert len(p1) > 20
    axis = (p2 - p1) / np.linalg.norm(p2 - p1, axis=1, keepdims=True)
    width = np.linalg.norm(p2 - p1, axis=1)
    along_x = np.abs(axis[:, 0]) > 0.9
    along_y = np.abs(axis[:, 1]) > 0.9
    assert along_x.any() and along_y.any()
    assert np.allclose(width[along_x], 0.04, atol=0.006)  # within 2 voxels of a step edge
    assert np.allclose(width[along_y], 0.05, atol=0.006)
    assert (quality >= np.cos(np.arctan(cfg.friction))).all()


def test_a_cylinder_is_grasped_across_its_diameter_from_above():
    box = OrientedBox((0.1, 0.0, 0.04), (0.05, 0.05, 0.08), 0.0)
    density = scene_fn(TABLE, cylinder((0.1, 0.0, 0.04), 0.025, 0.08))
    grasps = plan_grasps(density, box, GraspConfig(), top_k=5)
    assert grasps and grasps[0].score >= grasps[-1].score
    for g in grasps:
        assert abs(g.width_m - 0.05) < 0.006
        closing = g.rotation[:, 0]
        assert abs(closing[2]) < 0.3  # horizontal: across the diameter
        assert np.allclose(g.rotation.T @ g.rotation, np.eye(3), atol=1e-6)
    assert grasps[0].approach_deg < 30  # top-down wins


def test_grasps_through_the_table_or_a_neighbour_are_rejected():
    box = OrientedBox((0.0, 0.0, 0.02), (0.03, 0.03, 0.04), 0.0)
    neighbour = cuboid((0.045, 0.0, 0.05), (0.03, 0.12, 0.1))  # tall, 1.5 cm to the +x side
    density = scene_fn(TABLE, cuboid((0.0, 0.0, 0.02), (0.03, 0.03, 0.04)), neighbour)
    grasps = plan_grasps(density, box, GraspConfig(), top_k=10)
    assert grasps
    cfg = GraspConfig().gripper
    for g in grasps:
        # no finger or palm corner under the table top, none inside the neighbour
        for centre, half in gripper_boxes(cfg, g.width_m):
            corners = box_corners(centre, half) @ g.rotation.T + g.position_m
            assert corners[:, 2].min() > -0.002
        assert abs(g.rotation[0, 0]) < 0.5  # no closing along x: a finger would hit the neighbour


def test_grasps_that_leave_the_fingers_room_rank_first():
    """A block 4 x 7.2 cm: across its 7.2 cm the open pads (8 cm at most) clear it by 4 mm a
    side, across its 4 cm by the full 1.5 cm; the roomy grasps rank first, and the margin
    each grasp leaves is reported."""
    box = OrientedBox((0.0, 0.0, 0.03), (0.04, 0.072, 0.06), 0.0)
    density = scene_fn(TABLE, cuboid((0.0, 0.0, 0.03), (0.04, 0.072, 0.06)))
    grasps = plan_grasps(density, box, GraspConfig(), top_k=200)
    tight = [g for g in grasps if g.width_m > 0.06]
    assert tight, "the wide side is graspable too"
    assert grasps[0].width_m < 0.05 and abs(grasps[0].margin_m - 0.015) < 1e-6
    assert all(g.margin_m < 0.006 for g in tight)
    assert max(g.score for g in tight) < grasps[0].score
    record = grasps[0].to_dict()
    assert abs(record["margin_m"] - (record["opening_m"] - record["width_m"]) / 2) < 2e-5
    # the score is the documented mix, the margin counted as a share of 1.5 cm
    cfg = GraspConfig()
    for g in grasps:
        margin = min(1.0, g.margin_m / cfg.gripper.open_margin_m)
        vertical = np.cos(np.radians(g.approach_deg))
        mix = 0.5 * g.quality + 0.3 * vertical + 0.2 * g.clearance + cfg.margin_weight * margin
        assert abs(g.score - mix / (1 + cfg.margin_weight)) < 2e-3  # approach_deg is rounded


def test_an_object_wider_than_the_gripper_has_no_grasp(tmp_path: Path, capsys):
    box = OrientedBox((0.0, 0.0, 0.03), (0.12, 0.12, 0.06), 0.0)
    density = scene_fn(TABLE, cuboid((0.0, 0.0, 0.03), (0.12, 0.12, 0.06)))
    assert plan_grasps(density, box, GraspConfig()) == []


def test_neo_grasp_on_a_trained_scene(
    move_scene: Path, sim_root: Path, tmp_path: Path, monkeypatch, capsys
):
    box = json.loads((sim_root / "pick_place_1" / "scene.json").read_text())["actions"][0]
    (tmp_path / "box.json").write_text(json.dumps(box["source_box"]))
    out, js = tmp_path / "g", tmp_path / "g.json"
    args = ["grasp", str(move_scene), "--box", str(tmp_path / "box.json"), "--out", str(out)]
    import neoedit.grasp.antipodal as antipodal

    # no collision-free grasp: a clear message, exit status 1, nothing written
    monkeypatch.setattr(antipodal, "plan_grasps", lambda *a, **k: [])
    assert main([*args, "--json", str(js)]) == 1
    assert "no collision-free grasp" in " ".join(capsys.readouterr().out.split())
    assert not out.exists() and not js.exists()
    # the command's output path, with the planner's grasps of an analytic cylinder
    monkeypatch.undo()

    cylinder_grasps = plan_grasps(
        scene_fn(TABLE, cylinder((0.05, -0.14, 0.04), 0.025, 0.08)),
        OrientedBox((0.05, -0.14, 0.04), (0.05, 0.05, 0.08), 0.0),
        GraspConfig(),
        top_k=3,
    )
    monkeypatch.setattr(antipodal, "plan_grasps", lambda *a, **k: cylinder_grasps)
    assert main([*args, "--json", str(js), "--top", "3"]) == 0
    assert (out / "grasps.png").is_file()
    grasps = json.loads(js.read_text())
    assert len(grasps) == 3 and {"position_m", "rotation", "width_m", "score"} <= grasps[0].keys()
    assert abs(grasps[0]["width_m"] - 0.05) < 0.006
    assert main(["grasp", str(move_scene), "--box", str(tmp_path / "box.json"), "--top", "0"]) == 2
    # the box file is an input: --json may not replace it
    bad = ["grasp", str(move_scene), "--box", str(tmp_path / "box.json"), "--json"]
    assert main([*bad, str(tmp_path / "box.json")]) == 2


def foggy_cuboid(center, size, face=400.0, fog=25.0, wall=0.004):
    """A cube as radiance fields often learn one: dense faces ``wall`` thick, fog inside."""
    c, h = torch.tensor(center), torch.tensor(size) / 2
    inner = h - wall

    def density(p: torch.Tensor) -> torch.Tensor:
        d = (p - c).abs()
        inside = (d <= h).all(-1)
        core = (d <= inner).all(-1)
        return torch.where(core, fog, torch.where(inside, face, 0.0))

    return density


def test_a_cube_with_a_foggy_inside_is_grasped_across_its_faces_not_pinched():
    """Its density's level set is a 4 mm shell: every pair on it would pinch a wall or an
    edge. Seen from outside the cube is opaque, so the planner grasps it whole."""
    cube = foggy_cuboid((0.0, 0.0, 0.025), (0.05, 0.05, 0.05))
    box = OrientedBox((0.0, 0.0, 0.025), (0.05, 0.05, 0.05), 0.0)
    grasps = plan_grasps(
        lambda p: torch.maximum(cube(p), TABLE(p).float() * SOLID), box, GraspConfig(), top_k=10
    )
    assert grasps
    assert all(abs(g.width_m - 0.05) < 0.008 for g in grasps), [g.width_m for g in grasps]
    surface = object_surface(cube, box, GraspConfig().surface)
    assert surface.solid(np.array([[0.0, 0.0, 0.025]]))[0]  # the fog counts as inside


def test_a_cup_keeps_its_cavity_open():
    outer = cylinder((0.0, 0.0, 0.04), 0.03, 0.08)
    cavity = cylinder((0.0, 0.0, 0.045), 0.025, 0.08)  # open at the top, 5 mm floor

    def cup(p: torch.Tensor) -> torch.Tensor:
        return (outer(p) & ~cavity(p)).float() * SOLID

    box = OrientedBox((0.0, 0.0, 0.04), (0.06, 0.06, 0.08), 0.0)
    surface = object_surface(cup, box, GraspConfig().surface)
    inside_cavity, in_wall = [0.0, 0.0, 0.05], [0.0275, 0.0, 0.05]
    assert surface.solid(np.array([inside_cavity, in_wall])).tolist() == [False, True]


def test_every_verb_that_looks_an_object_up_exits_1_when_nothing_matches(
    move_scene: Path, tmp_path: Path, capsys
):
    """No match is a finding, not bad input: query, remove, move and grasp agree on exit
    status 1 (as grep does), say so in one line, and write nothing."""
    prompt = "purple elephant"
    runs = {
        "query": ["--views", "0"],
        "remove": ["--no-inpaint"],
        "move": ["--translate", "0.05", "0", "0", "--preview"],
        "grasp": [],
    }
    for verb, extra in runs.items():
        out = tmp_path / verb
        assert main([verb, str(move_scene), prompt, *extra, "--out", str(out)]) == 1, verb
        said = capsys.readouterr()
        assert f"no object matched '{prompt}'" in " ".join((said.out + said.err).split()), verb
        assert not out.exists(), verb

"""NEO-Sim scans: files, geometry consistency, registration, determinism, spec errors."""

import dataclasses
import hashlib
import json
from pathlib import Path

import numpy as np
import pytest

from neoedit.data import load_scene_data
from neoedit.errors import SpecError
from neoedit.geometry import OrientedBox
from neoedit.sim.run import simulate_scene
from neoedit.sim.specfile import scene_spec_from_dict
from neoedit.sim.suite import benchmark_scenes
from tests.conftest import TINY_SCAN, tiny_scene


def test_scene_layout(sim_root: Path):
    scene = json.loads((sim_root / "removal_1" / "scene.json").read_text())
    assert scene["scans"] == ["pre", "post"]
    for scan in scene["scans"]:
        d = sim_root / "removal_1" / scan
        for name in ("transforms.json", "objects.json", "contact_sheet.png"):
            assert (d / name).is_file()
    data = load_scene_data(sim_root / "removal_1" / "pre")
    assert (
        len(data.split["train"]) == TINY_SCAN.n_train
        and len(data.split["test"]) == TINY_SCAN.n_eval
    )
    assert set(data.split["train"]).isdisjoint(data.split["test"])
    assert data.images.shape == (13, 48, 64, 3)
    assert data.depth_m is not None and data.instance_ids is not None
    assert data.instance_names[1] == "table" and "red mug" in data.instance_names.values()


def test_depth_is_consistent_across_views(sim_root: Path):
    """A surface point seen in view i, back-projected with its depth, is seen at the same depth in view j."""
    data = load_scene_data(sim_root / "removal_1" / "pre")
    cams, errors = data.cameras, []
    for i, j in [(0, 1), (3, 4), (6, 7), (10, 11)]:
        pts = cams.backproject_depth(i, data.depth_m[i])[data.depth_m[i] > 0]
        uv, z = cams.project(j, pts)
        ui, vi = np.floor(uv[:, 0]).astype(int), np.floor(uv[:, 1]).astype(int)
        inside = (ui >= 0) & (ui < data.width) & (vi >= 0) & (vi < data.height) & (z > 0)
        dj = data.depth_m[j][vi[inside], ui[inside]]
        ok = dj > 0
        errors.append(np.abs(dj[ok] - z[inside][ok]))
    err = np.concatenate(errors)
    assert len(err) > 3000
    # Most points are visible in both views; occlusions and pixel-footprint edges make the rest.
    assert np.median(err) < 0.005
    assert np.mean(err < 0.02) > 0.85


def test_instance_masks_agree_with_boxes(sim_root: Path):
    data = load_scene_data(sim_root / "removal_1" / "pre")
    for obj in data.objects:
        box = OrientedBox.from_dict(obj["box"])
        pts = []
        for i in range(len(data)):
            mask = data.instance_ids[i] == obj["id"]
            pts.append(data.cameras.backproject_depth(i, data.depth_m[i])[mask])
        pts = np.concatenate(pts)
        assert len(pts) > 20, obj["name"]
        # depth is quantised to 1 mm and pixels straddle edges: allow a small margin
        assert box.contains(pts, margin_m=0.01).mean() > 0.97, obj["name"]
        # the box is tight: the points reach (nearly) its top
        assert pts[:, 2].max() > box.center_m[2] + box.size_m[2] / 2 - 0.01


def test_removal_post_scan(sim_root: Path):
    scene = json.loads((sim_root / "removal_1" / "scene.json").read_text())
    target = scene["actions"][0]["object"]
    pre = load_scene_data(sim_root / "removal_1" / "pre")
    post = load_scene_data(sim_root / "removal_1" / "post")
    target_id = next(i for i, n in pre.instance_names.items() if n == target)
    assert (pre.instance_ids == target_id).sum() > 50
    assert (post.instance_ids == target_id).sum() == 0
    assert target not in post.instance_names.values()
    np.testing.assert_array_equal(pre.cameras.camera_to_world, post.cameras.camera_to_world)
    # unmoved objects keep their pose (registration is exact)
    pre_poses = {o["name"]: np.asarray(o["pose"]) for o in pre.objects}
    for o in post.objects:
        np.testing.assert_allclose(o["pose"], pre_poses[o["name"]], atol=1e-3)


def test_pick_place_realised_transform(sim_root: Path):
    scene = json.loads((sim_root / "pick_place_1" / "scene.json").read_text())
    action = scene["actions"][0]
    source = OrientedBox.from_dict(action["source_box"])
    target = OrientedBox.from_dict(action["target_box"])
    moved = source.transformed(np.asarray(action["transform_world"]))
    assert np.linalg.norm(np.subtract(moved.center_m, target.center_m)) < 0.005
    # the realised motion is close to the requested one
    shift = np.subtract(target.center_m, source.center_m)
    assert np.allclose(shift[:2], action["requested"]["translate_m"][:2], atol=0.01)
    post = load_scene_data(sim_root / "pick_place_1" / "post")
    obj = next(o for o in post.objects if o["name"] == action["object"])
    assert OrientedBox.from_dict(obj["box"]).center_m == pytest.approx(target.center_m, abs=1e-4)


def _digest(root: Path) -> dict[str, str]:
    return {
        str(p.relative_to(root)): hashlib.sha256(p.read_bytes()).hexdigest()
        for p in sorted(root.rglob("*"))
        if p.is_file()
    }


def test_same_seed_same_files(tmp_path: Path):
    spec = dataclasses.replace(
        tiny_scene("removal_2"), scan=dataclasses.replace(TINY_SCAN, n_train=3, n_eval=1)
    )
    simulate_scene(spec, tmp_path / "a")
    simulate_scene(spec, tmp_path / "b")
    assert _digest(tmp_path / "a") == _digest(tmp_path / "b")


def test_suite_shape_and_determinism():
    scenes = benchmark_scenes("small", seed=3)
    kinds = [s.kind for s in scenes]
    assert (
        kinds.count("removal") == 5
        and kinds.count("pick_place") == 6
        and kinds.count("assembly") == 1
    )
    assert len({s.setup.name for s in scenes}) == 2
    assembly = next(s for s in scenes if s.kind == "assembly")
    assert len(assembly.actions) == 4
    assert [s.to_dict() for s in scenes] == [s.to_dict() for s in benchmark_scenes("small", seed=3)]
    assert [s.to_dict() for s in scenes] != [s.to_dict() for s in benchmark_scenes("small", seed=4)]


@pytest.mark.parametrize(
    "patch, field",
    [
        (
            {
                "objects": [
                    {"name": "mug", "urdf": "pybullet_data:objects/mug.urdf", "position_m": [0, 0]}
                ]
            },
            "objects[0].position_m",
        ),
        ({"scan": {"width": "wide"}}, "scan.width"),
        ({"actions": [{"type": "throw", "object": "mug"}]}, "actions[0].type"),
        ({"actions": [{"type": "remove", "object": "cup"}]}, "actions[0].object"),
        ({"colour": "red"}, "colour"),
        ({"setup": "moon_base"}, "setup"),
    ],
)
def test_spec_errors_name_the_field(patch, field):
    base = {"name": "s", "objects": [{"name": "mug", "urdf": "pybullet_data:objects/mug.urdf"}]}
    with pytest.raises(SpecError, match=field.replace("[", r"\[").replace("]", r"\]")):
        scene_spec_from_dict({**base, **patch})


def test_missing_asset_leaves_no_partial_output(tmp_path: Path):
    spec = scene_spec_from_dict(
        {
            "name": "s",
            "objects": [{"name": "ghost", "urdf": "nowhere/ghost.urdf"}],
            "scan": {"width": 16, "height": 12, "n_train": 2, "n_eval": 0},
        }
    )
    with pytest.raises(SpecError, match="asset not found"):
        simulate_scene(spec, tmp_path / "out")
    assert list(tmp_path.iterdir()) == []


def test_example_spec_is_valid():
    from neoedit.sim.specfile import load_scene_spec

    spec = load_scene_spec(Path(__file__).parent.parent / "examples" / "demo_scene.yaml")
    assert spec.setup.name == "panda_wood" and [a.type for a in spec.actions] == ["remove"]


def test_a_concave_object_keeps_its_inside_open(tmp_path: Path, monkeypatch):
    """pybullet_data's mug collides with a closed body (a lid on the mug); a ``concave``
    object collides with the V-HACD parts of its visual mesh: a ray down the mug's middle
    meets its bottom, not its rim; the parts fill the visual mesh's box, so the mug stands
    where it stood."""
    import pybullet as pb
    import pybullet_data

    from neoedit.sim.catalog import CATALOG
    from neoedit.sim.collision import concave_urdf
    from neoedit.sim.spec import SceneSpec
    from neoedit.sim.world import SimWorld

    monkeypatch.setenv("NEOEDIT_CACHE", str(tmp_path))
    hit_z, n_parts, rest_z = {}, {}, {}
    for concave in (False, True):
        mug = dataclasses.replace(CATALOG["red mug"], position_m=(0.1, 0.0, 0.003), concave=concave)
        with SimWorld(SceneSpec(name="mug", objects=[mug], actions=[])) as world:
            box = world.object_box("red mug")
            (x, y, z), top = box.center_m, box.center_m[2] + box.size_m[2] / 2
            down = pb.rayTest([x, y, 0.3], [x, y, -0.1], physicsClientId=world.client)[0]
            hit_z[concave], rest_z[concave] = down[3][2], z
            parts = world.collision_parts_world("red mug")
            n_parts[concave] = len(parts)
            lo, hi = np.concatenate(parts).min(0), np.concatenate(parts).max(0)
            assert abs(hi[2] - top) < 5e-4 and abs(lo[2] - (2 * z - top)) < 5e-4
    assert n_parts[True] > n_parts[False]  # the model's own: a closed body + handle parts
    assert hit_z[False] > top - 0.005  # the hull: the ray stops at the rim's height
    assert hit_z[True] < 0.02  # the parts: it goes down to the mug's bottom
    assert abs(rest_z[True] - rest_z[False]) < 1e-4  # fitted parts: it stands as it did
    # cached: the same URDF again, and the decomposition is not recomputed
    parts_file = next((tmp_path / "vhacd").glob("*.obj"))
    stamp = parts_file.stat().st_mtime_ns
    urdf = Path(pybullet_data.getDataPath()) / "objects" / "mug.urdf"
    assert concave_urdf(urdf) == concave_urdf(urdf)
    assert parts_file.stat().st_mtime_ns == stamp


def test_a_concave_object_needs_a_visual_mesh(tmp_path: Path, monkeypatch):
    from neoedit.sim.collision import concave_urdf

    monkeypatch.setenv("NEOEDIT_CACHE", str(tmp_path / "cache"))
    box = tmp_path / "box.urdf"
    box.write_text(
        '<robot name="b"><link name="l"><visual><geometry><box size="0.05 0.05 0.05"/>'
        '</geometry></visual><collision><geometry><box size="0.05 0.05 0.05"/></geometry>'
        "</collision></link></robot>"
    )
    with pytest.raises(SpecError, match="needs a link with a visual mesh"):
        concave_urdf(box)
    broken = tmp_path / "broken.urdf"
    broken.write_text("<robot name='b'><link>")
    with pytest.raises(SpecError, match="cannot read the URDF"):
        concave_urdf(broken)

"""The label-free geometric language teacher: discovery and description on synthetic surface
points with known shapes and colours, its targets in the MiniLM space, the teacher choice,
bad options, and a tiny trained NEO-Sim scene end to end with its labels withheld."""

from __future__ import annotations

import json
import shutil
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
import torch

from neoedit.data import load_scene_data
from neoedit.errors import NeoError
from neoedit.geometry import OrientedBox
from neoedit.geometry.box import box_iou_3d
from neoedit.language.describe import colour_name, colour_words, measure_shape
from neoedit.language.geometric import (
    BACKGROUND,
    IGNORED,
    TABLE,
    GeometricConfig,
    GeometricTeacher,
    discover,
)
from neoedit.language.localize import QueryConfig, query_scene
from neoedit.language.relevancy import CANONICAL_PHRASES, relevancy
from neoedit.language.text import TextEncoderSpec, load_text_encoder
from neoedit.language.training import LanguageTrainConfig, resolve_teacher, train_language
from neoedit.scene import load_scene, save_scene

WOOD, RED, BLUE, WHITE = (200, 175, 140), (190, 30, 30), (30, 60, 200), (235, 235, 235)


def _cylinder(rng, n, centre, radius, height):
    """Visible surface of an upright cylinder: its top disc and its side."""
    top = rng.random(n) < 0.35
    ang = rng.uniform(0, 2 * np.pi, n)
    r = np.where(top, radius * np.sqrt(rng.random(n)), radius)
    z = np.where(top, height, rng.uniform(0, height, n))
    return np.c_[centre[0] + r * np.cos(ang), centre[1] + r * np.sin(ang), z]


def _box(rng, n, centre, size):
    """Top and four sides of an axis-aligned box standing on z = 0."""
    half = np.asarray(size) / 2
    local = rng.uniform(-1, 1, (n, 3)) * half
    face = rng.integers(0, 5, n)
    local[face == 0, 2] = half[2]
    for k, (axis, sign) in enumerate([(0, 1), (0, -1), (1, 1), (1, -1)], start=1):
        local[face == k, axis] = sign * half[axis]
    return local + [centre[0], centre[1], half[2]]


def _sphere(rng, n, centre, radius):
    """Upper 80 % of a sphere resting on z = 0 (the part cameras above it see)."""
    v = rng.normal(size=(n, 3))
    v /= np.linalg.norm(v, axis=1, keepdims=True)
    v = v[v[:, 2] > -0.6]
    return v * radius + [centre[0], centre[1], radius]


def _cameras(n=8):
    """OpenGL camera-to-world poses on a half ring on the -y side, looking at the origin."""
    poses = []
    for a in np.linspace(-0.6, 0.6, n):
        eye = np.array([0.8 * np.sin(a), -0.8 * np.cos(a), 0.6])
        back = eye / np.linalg.norm(eye)  # camera +z points away from the target
        right = np.cross([0.0, 0.0, 1.0], back)
        right /= np.linalg.norm(right)
        pose = np.eye(4)
        pose[:3, :3] = np.c_[right, np.cross(back, right), back]
        pose[:3, 3] = eye
        poses.append(pose)
    return np.stack(poses)


def synthetic_scene(seed=0):
    """A wooden table plane with a tall red cylinder (left), a blue box (right) and a white
    ball (back): points (N,3), pixel colours (N,3) and the true object per point (-1 table)."""
    rng = np.random.default_rng(seed)
    table = np.c_[rng.uniform(-0.5, 0.5, (30000, 2)), rng.normal(0, 0.0005, 30000)]
    parts = [
        _cylinder(rng, 3000, (-0.2, 0.0), 0.035, 0.14),
        _box(rng, 3000, (0.2, 0.0), (0.07, 0.07, 0.07)),
        _sphere(rng, 3000, (0.0, 0.25), 0.045),
    ]
    hidden = np.zeros(len(table), bool)
    for c, rad in (((-0.2, 0.0), 0.04), ((0.2, 0.0), 0.05), ((0.0, 0.25), 0.045)):
        hidden |= np.linalg.norm(table[:, :2] - c, axis=1) < rad
    table = table[~hidden]
    points = np.concatenate([table, *parts])
    truth = np.concatenate(
        [np.full(len(table), -1)] + [np.full(len(p), k) for k, p in enumerate(parts)]
    )
    colours = np.array([WOOD, RED, BLUE, WHITE])[truth + 1]
    rgb = np.clip(colours * rng.uniform(0.85, 1.05, (len(points), 1)), 0, 255).astype(np.uint8)
    return points, rgb, truth


@pytest.fixture(scope="module")
def found():
    points, rgb, truth = synthetic_scene()
    return discover(points, rgb, _cameras(), GeometricConfig()), truth


def _match(found_and_truth):
    """Discovered instance index of each true object (majority vote)."""
    found, truth = found_and_truth
    return [
        int(np.bincount(found.labels[truth == k][found.labels[truth == k] >= 0]).argmax())
        for k in range(3)
    ]


def test_discovery_finds_the_objects_and_measures_them(found):
    disc, truth = found
    assert len(disc.instances) == 3
    cyl, box, ball = (disc.instances[i] for i in _match(found))
    assert np.allclose(disc.plane.normal, [0, 0, 1], atol=0.01)
    assert (cyl.shape.kind, box.shape.kind, ball.shape.kind) == ("cylinder", "cube", "sphere")
    assert (cyl.colours, box.colours, ball.colours) == (["red"], ["blue"], ["white"])
    assert cyl.shape.height_m == pytest.approx(0.14, abs=0.01)
    assert box.shape.length_m == pytest.approx(0.07, abs=0.01)
    # relative words: the cylinder is the tall one, on the left; the box on the right
    assert "tall" in cyl.relative and "left" in cyl.relative and "right" in box.relative
    assert "back" in ball.relative  # +y is away from the cameras (they stand on -y)
    assert "red can" in cyl.phrases and cyl.description.startswith("tall red can")
    # every table point is table; nearly every object point is its object
    assert np.all(disc.labels[truth == -1] == TABLE)
    for k, idx in enumerate(_match(found)):
        assert np.mean(disc.labels[truth == k] == idx) > 0.9
        assert np.all(np.isin(disc.labels[truth == k], [idx, TABLE, IGNORED]))


def test_discovery_drops_specks_and_keeps_background():
    points, rgb, truth = synthetic_scene()
    rng = np.random.default_rng(1)
    speck = rng.normal([0.3, 0.3, 0.05], 0.002, (20, 3))  # 20 points: not an object
    below = np.c_[rng.uniform(-0.5, 0.5, (500, 2)), np.full(500, -0.7)]  # the floor
    pts = np.concatenate([points, speck, below])
    colours = np.concatenate([rgb, np.full((520, 3), 90, np.uint8)])
    disc = discover(pts, colours, _cameras(), GeometricConfig())
    assert len(disc.instances) == 3
    assert np.all(disc.labels[-520:] == BACKGROUND)


def test_no_support_plane_is_a_clear_error():
    rng = np.random.default_rng(0)
    pts = rng.normal(size=(3000, 3))
    with pytest.raises(NeoError, match="no support plane") as e:
        discover(pts, np.zeros((3000, 3), np.uint8), _cameras(), GeometricConfig())
    assert "within 6 mm and" in str(e.value) and "within 12 mm of" in str(e.value)  # both looks
    import pickle  # it crosses process boundaries (the bench's workers)

    assert str(pickle.loads(pickle.dumps(e.value))) == str(e.value)


def test_a_rough_support_is_found_with_a_wider_tolerance():
    """A table reconstructed from photos is not flat to 6 mm (spinnerf_1's bench: 12 % of
    the points within 6 mm of a plane): with no plane found at ``inlier_m`` the search is
    made again at ``rough_factor`` times it, and finds the table and the objects on it."""
    points, rgb, truth = synthetic_scene()
    rng = np.random.default_rng(2)
    table = truth == -1
    points = points.copy()
    points[table, 2] += rng.normal(0, 0.008, table.sum())  # rough: ~ 1/2 within 6 mm
    points = np.concatenate([points, rng.uniform(-0.5, 0.5, (80000, 3)) + [0, 0, 0.6]])
    rgb = np.concatenate([rgb, np.full((80000, 3), 90, np.uint8)])  # a cloud of room
    with pytest.raises(NeoError, match="no support plane"):
        discover(points, rgb, _cameras(), GeometricConfig(rough_factor=1.0))
    disc = discover(points, rgb, _cameras(), GeometricConfig())
    assert np.allclose(disc.plane.normal, [0, 0, 1], atol=0.02)
    assert len(disc.instances) == 3
    assert np.mean(disc.labels[: len(truth)][table] == TABLE) > 0.8  # 87 % lie within 12 mm


def test_colour_names():
    assert colour_name(np.array([190, 30, 30])) == "red"
    assert colour_name(np.array([198, 78, 77])) == "pink"
    assert colour_name(np.array([30, 60, 200])) == "blue"
    assert colour_name(np.array([220, 200, 20])) == "yellow"
    assert colour_name(np.array([10, 10, 10])) == "black"
    assert colour_name(np.array([240, 240, 240])) == "white"
    ball = np.array([[240, 240, 240]] * 60 + [[15, 15, 15]] * 40)
    assert colour_words(ball) == ["white", "black"]


def test_teacher_targets_name_the_right_object():
    points, rgb, truth = synthetic_scene()
    text = load_text_encoder(TextEncoderSpec("minilm"))
    teacher = GeometricTeacher(text)
    n = len(points)
    # one "image" column holding every point's pixel: frame 0, row i, column 0
    data = SimpleNamespace(
        images=rgb[None, :, None, :], cameras=SimpleNamespace(camera_to_world=_cameras())
    )
    teacher.prepare(data, np.zeros(1, np.int64))  # type: ignore[arg-type]
    feats, valid = teacher.targets_at(
        torch.as_tensor(points, dtype=torch.float32),
        torch.zeros(n, dtype=torch.long),
        torch.arange(n),
        torch.zeros(n, dtype=torch.long),
    )
    assert feats.shape == (n, text.dim) and valid.float().mean() > 0.95
    assert teacher.names[-2:] == ["table / floor / ground", "background"]
    assert len(teacher.names) == 5
    canon = text.encode(list(CANONICAL_PHRASES))
    per_object = torch.stack([feats[torch.as_tensor(truth == k)][0] for k in range(3)])
    table_feat = feats[torch.as_tensor(truth == -1)][0]
    # each query is most relevant to its object, above the default query threshold
    for query, want in (("can", 0), ("red mug", 0), ("blue box", 1), ("cube", 1), ("ball", 2)):
        rel = relevancy(per_object, text.encode([query])[0], canon)
        assert int(rel.argmax()) == want, query
        assert float(rel[want]) > QueryConfig().threshold, query
    rel_table = relevancy(
        torch.cat([per_object, table_feat[None]]), text.encode(["table"])[0], canon
    )
    assert int(rel_table.argmax()) == 3


def _data(labels: bool):
    return SimpleNamespace(
        instance_ids=np.zeros((1, 2, 2), np.int32) if labels else None,
        instance_names={1: "mug"} if labels else {},
    )


def test_teacher_choice():
    auto = LanguageTrainConfig()
    assert resolve_teacher(auto, _data(labels=True)) == "labels"  # type: ignore[arg-type]
    assert resolve_teacher(auto, _data(labels=False)) == "geometric"  # type: ignore[arg-type]
    clip = LanguageTrainConfig(clip_path="/some/clip")
    assert resolve_teacher(clip, _data(labels=False)) == "clip"  # type: ignore[arg-type]
    geo = LanguageTrainConfig(teacher="geometric")
    assert resolve_teacher(geo, _data(labels=True)) == "geometric"  # type: ignore[arg-type]
    with pytest.raises(NeoError, match="unknown language teacher"):
        resolve_teacher(LanguageTrainConfig(teacher="magic"), _data(True))  # type: ignore[arg-type]
    geo.check()
    bad = LanguageTrainConfig(teacher="geometric", geometric=GeometricConfig(eps_m=-1.0))
    with pytest.raises(NeoError, match="eps-m must be > 0"):
        bad.check()
    bad = LanguageTrainConfig(geometric=GeometricConfig(inlier_m=0.02, above_m=0.01))
    with pytest.raises(NeoError, match="above-m"):
        bad.check()


def test_geometric_teacher_on_a_tiny_trained_scene(trained: Path, sim_root: Path, tmp_path: Path):
    """The tiny removal_1 scan (64x48 px) with its labels withheld: the discovered objects
    are the scene's, and their colour finds them."""
    out = tmp_path / "scene"
    shutil.copytree(trained, out)
    data = load_scene_data(sim_root / "removal_1" / "pre")
    data.instance_ids, data.instance_names = None, {}
    cfg = LanguageTrainConfig(rays=24576, steps=200, batch=2048)
    assert resolve_teacher(cfg, data) == "geometric"
    # the 64x48 scan's table is bumpy (+-2 cm) and its cloud sparse: a thicker plane
    cfg.geometric = GeometricConfig(inlier_m=0.02, above_m=0.025, eps_m=0.02, min_points=20)
    scene = train_language(load_scene(out), data, cfg)
    save_scene(out, scene)
    meta = load_scene(out).meta.language
    assert meta is not None and meta.teacher == "geometric" and meta.vocabulary[-1] == "background"
    objects = json.loads((sim_root / "removal_1" / "pre" / "objects.json").read_text())["objects"]
    truth = {o["name"]: OrientedBox.from_dict(o["box"]) for o in objects}
    assert "red mug" in truth
    assert any("red" in word for word in meta.vocabulary), meta.vocabulary
    # by its colour: at 64x48 px the clusters may merge the mug with its neighbour, and then
    # "mug" names the cylinder-shaped robot base better than the merged blob
    res = query_scene(
        load_scene(out),
        "red object",
        load_text_encoder(meta.text),
        QueryConfig(min_cluster_points=10, min_samples=4, eps_m=0.03),
    )
    # measured 0.23 (one thread, as under make test) and 0.35 (two); another object's box: 0
    ious = {name: box_iou_3d(res.box, box) for name, box in truth.items()}
    assert ious["red mug"] > 0.2 and max(ious, key=ious.__getitem__) == "red mug", ious
    centre = np.asarray(res.box.center_m)
    nearest = min(truth, key=lambda n: np.linalg.norm(np.asarray(truth[n].center_m) - centre))
    assert nearest == "red mug"  # the box sits on the mug, not between it and its neighbour


def test_auto_without_a_support_plane_skips_language(trained: Path, sim_root: Path):
    """'auto' picked the geometric teacher for want of labels: no support plane -> a warning
    and no language field; asked for explicitly -> the error."""
    data = load_scene_data(sim_root / "removal_1" / "pre")
    data.instance_ids, data.instance_names = None, {}
    strict = GeometricConfig(min_support_fraction=0.99)
    cfg = LanguageTrainConfig(rays=4096, steps=10, batch=512, geometric=strict)
    assert train_language(load_scene(trained), data, cfg).language is None
    cfg.teacher = "geometric"
    with pytest.raises(NeoError, match="no support plane"):
        train_language(load_scene(trained), data, cfg)


def test_a_tall_round_object_with_a_neck_is_a_cylinder():
    """A bottle (a 7 cm body 14 cm tall, then a 3 cm neck up to 20 cm) narrows at the top,
    so its top is not flat, but it is far taller than a ball: it is named as a cylinder."""
    rng = np.random.default_rng(1)
    body = _cylinder(rng, 3000, (0.0, 0.0), 0.035, 0.14)
    body = body[body[:, 2] < 0.1399]  # the shoulder is open: the neck rises from it
    neck = _cylinder(rng, 600, (0.0, 0.0), 0.015, 0.06) + [0.0, 0.0, 0.14]
    shape = measure_shape(np.concatenate([body, neck]))
    assert shape.height_m == pytest.approx(0.2, abs=0.01)
    assert shape.kind == "cylinder"

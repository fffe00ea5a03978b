"""Removal: box masks vs brute force, grid tiling, virtual views, inpainters (OpenCV and a
tiny random diffusers pipeline), suppression, and `neo remove` end to end on a tiny scene
(density gone inside the box, unchanged far away, input version untouched)."""

import hashlib
import json
from pathlib import Path

import numpy as np
import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from neoedit.cameras import Cameras
from neoedit.cameras.cameras import look_at
from neoedit.cameras.rays import CameraTensors
from neoedit.cli import main
from neoedit.data import load_scene_data
from neoedit.edit.inpaint import OpenCVInpainter, inpaint_views, make_inpainter, split_2x2, tile_2x2
from neoedit.edit.views import VirtualViewConfig, view_scale, virtual_cameras, virtual_views
from neoedit.edit.visibility import raised_masks
from neoedit.errors import NeoError
from neoedit.fields.suppressed import SuppressedField
from neoedit.geometry import OrientedBox
from neoedit.geometry.masks import box_mask, project_box_mask
from neoedit.scene import load_scene
from tests.conftest import tiny_clip_vocab

REFERENCE = Cameras.shared(np.eye(4)[None].repeat(1, 0), 60.0, 60.0, 40.0, 30.0, 80, 60)


@settings(max_examples=40, deadline=None)
@given(
    cx=st.floats(-0.3, 0.3),
    cy=st.floats(-0.3, 0.3),
    sx=st.floats(0.03, 0.3),
    sy=st.floats(0.03, 0.3),
    sz=st.floats(0.03, 0.3),
    yaw=st.floats(-180, 180),
    radius=st.floats(0.4, 1.5),
)
def test_projected_box_mask_matches_per_pixel_ray_test(cx, cy, sx, sy, sz, yaw, radius):
    box = OrientedBox((cx, cy, sz / 2), (sx, sy, sz), yaw)
    cfg = VirtualViewConfig(radius_m=radius, image_scale=1.0, min_box_px=0)
    cams = virtual_cameras(box, REFERENCE, cfg)
    # plus an off-centre camera that sees the box at an image border
    moved = cams.camera_to_world.copy()
    moved[0, :3, 3] += np.array([0.15, -0.1, 0.05])
    cams = Cameras(moved, cams.fx, cams.fy, cams.cx, cams.cy, cams.width, cams.height)
    for i in range(len(cams)):
        fast, exact = project_box_mask(cams, i, box), box_mask(cams, i, box)
        # equal, up to pixel centres lying exactly on a silhouette edge (float ties), which
        # can only be on the boundary of both masks
        differ = fast != exact
        padded = np.pad(exact, 1, mode="edge")
        boundary = np.zeros_like(exact)
        for dv, du in ((0, 1), (2, 1), (1, 0), (1, 2)):
            boundary |= padded[dv : dv + exact.shape[0], du : du + exact.shape[1]] != exact
        assert not (differ & ~boundary).any() and differ.sum() <= 2


def test_a_small_box_gets_finer_virtual_views_and_every_box_one_resolution():
    cfg = VirtualViewConfig(radius_m=0.8, min_box_px=24)  # half the scan's scale, 24 px at least
    big = OrientedBox((0.0, 0.0, 0.2), (0.8, 0.6, 0.4), 0)  # 60 px wide at the scan's scale
    small = OrientedBox((0.3, 0.1, 0.05), (0.1, 0.06, 0.08), 20)  # 7.5 px wide
    assert view_scale([big], REFERENCE, cfg) == 0.5
    assert view_scale([small], REFERENCE, cfg) == pytest.approx(24 / 7.5)
    assert view_scale([big, small], REFERENCE, cfg) == pytest.approx(24 / 7.5)
    grain = OrientedBox((0.0, 0.0, 0.0005), (0.001, 0.001, 0.001), 0)
    assert view_scale([grain], REFERENCE, cfg) == cfg.max_scale
    off = VirtualViewConfig(radius_m=0.8, min_box_px=0)
    assert view_scale([small], REFERENCE, off) == 0.5
    cams = virtual_views([big, small], REFERENCE, cfg)
    assert len(cams) == 16 and set(cams.width) == {256} and set(cams.height) == {192}
    for i in range(8, 16):  # the small box's views: its silhouette spans at least 24 px
        rows, cols = np.nonzero(project_box_mask(cams, i, small))
        assert np.hypot(np.ptp(rows) + 1, np.ptp(cols) + 1) >= 24


def test_virtual_views_look_at_the_box_on_a_rising_spiral():
    box = OrientedBox((0.2, -0.1, 0.05), (0.1, 0.08, 0.1), 30)
    cams = virtual_cameras(
        box, REFERENCE, VirtualViewConfig(turns=2, radius_m=0.8, image_scale=1.0, min_box_px=0)
    )
    assert len(cams) == 8
    eyes = cams.camera_to_world[:, :3, 3]
    offsets = eyes - np.asarray(box.center_m)
    assert np.allclose(np.linalg.norm(offsets, axis=1), 0.8)
    axes = -cams.camera_to_world[:, :3, 2]  # OpenGL cameras look along -z
    assert np.allclose(axes, -offsets / 0.8, atol=1e-9)
    elevation = np.degrees(np.arcsin(offsets[:, 2] / 0.8))
    assert (
        np.all(np.diff(elevation) > 0)
        and elevation[0] == pytest.approx(25)
        and elevation[-1] == pytest.approx(60)
    )
    azimuth = np.degrees(np.arctan2(offsets[:, 1], offsets[:, 0]))
    assert np.allclose(np.diff(azimuth[:4]) % 360, 90)  # one turn = four opposing azimuths
    # the box is centred in every view
    for i in range(len(cams)):
        uv, _ = cams.project(i, np.asarray([box.center_m]))
        assert np.allclose(uv[0], [cams.cx[i], cams.cy[i]], atol=1e-6)


@settings(max_examples=20, deadline=None)
@given(
    h=st.integers(1, 20),
    w=st.integers(1, 20),
    c=st.sampled_from([None, 1, 3]),
    seed=st.integers(0, 99),
)
def test_grid_tiling_round_trips(h, w, c, seed):
    rng = np.random.default_rng(seed)
    shape = (h, w) if c is None else (h, w, c)
    views = [rng.integers(0, 255, shape, dtype=np.uint8) for _ in range(4)]
    comp = tile_2x2(views)
    assert comp.shape[:2] == (2 * h, 2 * w)
    for a, b in zip(split_2x2(comp), views, strict=True):
        assert np.array_equal(a, b)


@pytest.mark.parametrize("method", ["telea", "ns", "fsr"])
def test_opencv_inpainters_fill_only_the_mask(method):
    img = np.zeros((40, 48, 3), np.uint8)
    img[:] = (200, 150, 100)
    mask = np.zeros((40, 48), bool)
    mask[12:26, 15:30] = True
    holed = img.copy()
    holed[mask] = (255, 0, 255)
    out = OpenCVInpainter(method).inpaint(holed, mask, 1.0)
    assert np.array_equal(out[~mask], holed[~mask])
    assert np.abs(out[mask].astype(int) - (200, 150, 100)).max() <= 3  # a flat colour is continued
    # strength xi blends the inpainted pixels with the given ones
    half = OpenCVInpainter(method).inpaint(holed, mask, 0.5).astype(int)
    assert np.abs(half[mask] - (np.array([255, 0, 255]) + out[mask]) / 2).max() <= 1
    assert np.array_equal(OpenCVInpainter(method).inpaint(holed, mask, 0.0), holed)


def test_grid_inpainting_matches_per_view_shape_and_keeps_unmasked_pixels():
    rng = np.random.default_rng(0)
    views = [rng.integers(0, 255, (20, 24, 3), dtype=np.uint8) for _ in range(5)]
    masks = [np.zeros((20, 24), bool) for _ in range(5)]
    for m in masks:
        m[5:12, 6:14] = True
    out = inpaint_views(OpenCVInpainter("telea"), views, masks, 1.0, grid=True)
    assert len(out) == 5
    for o, v, m in zip(out, views, masks, strict=True):
        assert o.shape == v.shape and np.array_equal(o[~m], v[~m])


@pytest.mark.parametrize("method", ["telea", "fsr"])
def test_the_fill_is_drawn_from_the_support_not_from_the_neighbour_beside_the_hole(method):
    table, duck = np.array([200, 180, 150]), np.array([230, 200, 20])
    views, masks, avoid = [], [], []
    for _ in range(4):
        img = np.tile(table.astype(np.uint8), (40, 48, 1))
        img[10:30, 30:40] = duck  # a neighbour right beside the hole
        hole = np.zeros((40, 48), bool)
        hole[12:28, 14:30] = True
        views.append(img)
        masks.append(hole)
        avoid.append(np.all(img == duck, -1))
    plain = inpaint_views(OpenCVInpainter(method), views, masks, 1.0)
    kept = inpaint_views(OpenCVInpainter(method), views, masks, 1.0, avoid=avoid)
    for p, k, v, m, a in zip(plain, kept, views, masks, avoid, strict=True):
        near = m.copy()
        near[:, :26] = False  # the fill's columns next to the neighbour
        assert np.abs(p[near].astype(int) - table).max() > 20  # yellow bled into the plain fill
        assert np.abs(k[m].astype(int) - table).max() <= 3  # only the table fills the hole
        assert np.array_equal(k[~m], v[~m]) and np.array_equal(k[a], v[a])  # neighbour kept
    # with nothing but the neighbour around the hole, it stays the context
    crowded = [np.ones((40, 48), bool) & ~m for m in masks]
    alone = inpaint_views(OpenCVInpainter(method), views, masks, 1.0, avoid=crowded)
    assert all(np.array_equal(a, p) for a, p in zip(alone, plain, strict=True))


def test_raised_pixels_stand_above_the_support_under_them_in_every_view():
    # two cameras looking down on two supports: a table (z = 0, x < 0) and a shelf (z = 0.1,
    # x > 0.2), each with a box on it; between them a plate stands 3 cm over the table
    cams = Cameras.shared(
        np.stack([look_at(np.array([0.1, y, 0.8]), np.array([0.1, 0.0, 0.0])) for y in (0.0, 0.3)]),
        60.0, 60.0, 24.0, 20.0, 48, 40,
    )  # fmt: skip
    boxes = [
        OrientedBox((-0.1, 0.0, 0.05), (0.1, 0.1, 0.1), 0),
        OrientedBox((0.3, 0.0, 0.15), (0.1, 0.1, 0.1), 0),
    ]
    window = (slice(4, 36), slice(6, 42))
    rows, cols = np.mgrid[4:36, 6:42]
    depth_z, accumulation, expected = [], [], []
    for v in range(2):
        rays = CameraTensors(cams, "cpu").rays(
            torch.full((rows.size,), v),
            torch.as_tensor(rows.ravel()),
            torch.as_tensor(cols.ravel()),
        )
        o, d = rays.origins.numpy(), rays.directions.numpy()

        def hit(z, o=o, d=d):
            return (z - o[:, 2]) / d[:, 2]

        x_table = (o + d * hit(0.0)[:, None])[:, 0]
        shelf, plate = x_table > 0.2, (x_table > -0.04) & (x_table < 0.06)
        t = np.where(shelf, hit(0.1), np.where(plate, hit(0.03), hit(0.0)))
        depth_z.append((t * rays.z_scale.numpy()).reshape(32, 36))
        acc = np.ones((32, 36))
        acc[:3] = 0.2  # rays that stop on nothing are never a neighbour
        accumulation.append(acc)
        want = plate.reshape(32, 36).copy()
        want[:3] = False
        expected.append(want)
    raised = raised_masks(
        cams, window, torch.as_tensor(np.stack(depth_z), dtype=torch.float32),
        torch.as_tensor(np.stack(accumulation), dtype=torch.float32), boxes, 0.01,
    )  # fmt: skip
    for r, want in zip(raised, expected, strict=True):
        assert want.any() and np.array_equal(r, want)  # the shelf is a support, not raised
    assert not any(
        m.any()
        for m in raised_masks(cams, window, torch.zeros(2, 32, 36), torch.ones(2, 32, 36), [], 0.01)
    )


def test_the_margin_stops_at_a_neighbour_not_at_the_support_rising_into_the_contact():
    """Surface points in the margin around a removed box stop it only when their language
    feature is unlike the object's *and* unlike the support's: a short field's table reads
    1-2 cm high next to an object's contact (it stopped a ball's margin on two sides and
    left its fuzzy rim floating: dark specks in the demo plan's removal), a duck beside it
    is a neighbour."""
    from types import SimpleNamespace

    from neoedit.edit.masks import grown_box_clear_of
    from neoedit.edit.remove import RemoveConfig, neighbour_points

    box = OrientedBox((0.0, 0.0, 0.05), (0.08, 0.08, 0.1), 0.0)  # bottom on the table, z = 0
    rng = np.random.default_rng(0)
    inside = rng.uniform((-0.03, -0.03, 0.01), (0.03, 0.03, 0.09), (400, 3))
    table = rng.uniform((-0.05, -0.05, 0.0), (0.05, 0.05, 0.004), (400, 3))
    table = table[np.abs(table[:, :2]).max(1) > 0.041]  # the ring around the footprint
    rising = rng.uniform((0.041, -0.03, 0.012), (0.044, 0.03, 0.02), (60, 3))  # +x: the table
    duck = rng.uniform((-0.03, -0.046, 0.02), (0.03, -0.042, 0.06), (60, 3))  # -y: a neighbour
    pts = np.concatenate([inside, table, rising, duck])

    def language(p: torch.Tensor) -> torch.Tensor:  # object, table, duck: orthogonal features
        x, y, z = p.unbind(-1)
        duck_here = y < -0.041
        object_here = (x.abs() <= 0.04) & (y.abs() <= 0.04) & (z > 0.005)
        kind = torch.where(duck_here, 2, torch.where(object_here, 0, 1))
        return torch.eye(3)[kind]

    scene = SimpleNamespace(
        language=SimpleNamespace(language=language),
        surface_points_m=torch.as_tensor(pts, dtype=torch.float32),
    )
    found = neighbour_points(scene, box, RemoveConfig())  # type: ignore[arg-type]
    assert len(found) == len(duck) and (found[:, 1] < -0.04).all()  # the duck only
    grown = grown_box_clear_of(box, 0.01, found)
    lo = np.asarray(grown.center_m) - np.asarray(grown.size_m) / 2
    hi = np.asarray(grown.center_m) + np.asarray(grown.size_m) / 2
    assert hi[0] == pytest.approx(0.05) and lo[0] == pytest.approx(-0.05)  # +x grows over the table
    assert lo[1] > -0.042  # -y stops short of the duck


def test_unknown_or_missing_inpainters_error(tmp_path: Path):
    with pytest.raises(NeoError, match="unknown inpainter"):
        make_inpainter("photoshop")
    with pytest.raises(NeoError, match="local pipeline directory"):
        make_inpainter("diffusion")
    with pytest.raises(NeoError, match="not found"):
        make_inpainter("diffusion", str(tmp_path))


def write_tiny_inpaint_pipeline(path: Path) -> Path:
    from diffusers import (
        AutoencoderKL,
        DDIMScheduler,
        StableDiffusionInpaintPipeline,
        UNet2DConditionModel,
    )
    from transformers import CLIPTextConfig, CLIPTextModel, CLIPTokenizer

    torch.manual_seed(0)
    unet = UNet2DConditionModel(
        block_out_channels=(32, 64),
        layers_per_block=1,
        sample_size=16,
        in_channels=9,
        out_channels=4,
        down_block_types=("DownBlock2D", "CrossAttnDownBlock2D"),
        up_block_types=("CrossAttnUpBlock2D", "UpBlock2D"),
        cross_attention_dim=32,
        norm_num_groups=8,
        attention_head_dim=4,
    )
    vae = AutoencoderKL(
        block_out_channels=[16, 32],
        in_channels=3,
        out_channels=3,
        down_block_types=["DownEncoderBlock2D"] * 2,
        up_block_types=["UpDecoderBlock2D"] * 2,
        latent_channels=4,
        norm_num_groups=8,
    )
    vocab = tiny_clip_vocab()
    text = CLIPTextModel(
        CLIPTextConfig(
            vocab_size=len(vocab),
            hidden_size=32,
            intermediate_size=37,
            num_hidden_layers=2,
            num_attention_heads=4,
            max_position_embeddings=77,
            bos_token_id=0,
            eos_token_id=1,
            pad_token_id=1,
        )
    )
    pipe = StableDiffusionInpaintPipeline(
        vae=vae,
        text_encoder=text,
        tokenizer=CLIPTokenizer(vocab=vocab, merges=[], model_max_length=77),
        unet=unet,
        scheduler=DDIMScheduler(steps_offset=1),
        safety_checker=None,
        feature_extractor=None,
        requires_safety_checker=False,
    )
    pipe.save_pretrained(path)
    return path


def test_diffusion_inpainter_on_tiny_random_pipeline(tmp_path: Path):
    from neoedit.edit.inpaint import DiffusionInpainter

    path = write_tiny_inpaint_pipeline(tmp_path / "pipe")
    inp = DiffusionInpainter(str(path), steps=2)
    rng = np.random.default_rng(0)
    views = [rng.integers(0, 255, (30, 36, 3), dtype=np.uint8) for _ in range(4)]
    masks = [np.zeros((30, 36), bool) for _ in range(4)]
    for m in masks:
        m[8:20, 10:25] = True
    out = inpaint_views(
        inp, views, masks, 0.8, grid=True
    )  # one 60x72 composite, padded for the UNet
    for o, v, m in zip(out, views, masks, strict=True):
        assert o.shape == v.shape and np.array_equal(o[~m], v[~m])
        assert (o[m] != v[m]).mean() > 0.5  # the masked pixels were generated


def test_suppressed_field_zeroes_density_only_inside(trained: Path):
    scene = load_scene(trained)
    box = OrientedBox((0.0, 0.0, 0.05), (0.2, 0.2, 0.1), 20.0)
    pts = torch.rand(4000, 3) * 0.8 - 0.4
    inside = torch.as_tensor(box.contains(pts.numpy().astype(np.float64)))
    sup = SuppressedField(scene.field, [box])
    with torch.no_grad():
        s0, s1 = scene.field.density(pts), sup.density(pts)
    assert torch.all(s1[inside] == 0) and torch.equal(s1[~inside], s0[~inside])


def tree_digest(path: Path) -> str:
    h = hashlib.sha256()
    for f in sorted(p for p in path.rglob("*") if p.is_file()):
        h.update(str(f.relative_to(path)).encode())
        h.update(f.read_bytes())
    return h.hexdigest()


def test_remove_end_to_end(trained: Path, sim_root: Path, tmp_path: Path, capsys):
    objects = json.loads((sim_root / "removal_1" / "pre" / "objects.json").read_text())["objects"]
    mug = next(o for o in objects if o["name"] == "red mug")
    box_file = tmp_path / "box.json"
    box_file.write_text(json.dumps(mug["box"]))
    box = OrientedBox.from_dict(mug["box"])
    before = tree_digest(trained)
    parent = load_scene(trained)

    # the instant preview: no training, the box is cut out of every ray
    preview = tmp_path / "preview"
    assert (
        main(
            ["remove", str(trained), "--box", str(box_file), "--out", str(preview), "--no-inpaint"]
            + ["--json", str(tmp_path / "preview.json")]
        )
        == 0
    )
    p = load_scene(preview)
    assert p.meta.cut_boxes and p.meta.parent == parent.meta.version_id
    assert p.meta.edits[-1].type == "remove"
    # seen from the scan's cameras, the mug's footprint stood out from the table around it;
    # with the mug cut, the table under it shows
    from neoedit.eval.footprint import removal_footprint

    with_mug, cut = removal_footprint(parent, box), removal_footprint(p, box)
    assert with_mug.views > 0 and cut.views == with_mug.views
    assert cut.delta < 0.5 * with_mug.delta, (cut, with_mug)
    result = json.loads((tmp_path / "preview.json").read_text())  # --json: the same facts
    assert result["version_id"] == p.meta.version_id and result["parent"] == p.meta.parent
    assert result["out"] == str(preview) and result["edit"]["type"] == "remove"
    assert result["edit"]["boxes"] == p.meta.edits[-1].details["boxes"]
    assert "seconds" in result["edit"] and "config" not in result["edit"]
    # an earlier result is replaced only with --overwrite; the box file never
    again = ["remove", str(trained), "--box", str(box_file), "--no-inpaint"]
    again += ["--json", str(tmp_path / "preview.json"), "--out", str(tmp_path / "p1")]
    assert main(again) == 2 and not (tmp_path / "p1").exists()
    assert main([*again, "--overwrite"]) == 0
    assert json.loads((tmp_path / "preview.json").read_text())["out"] == str(tmp_path / "p1")
    box_text = box_file.read_text()
    own = ["--json", str(box_file), "--out", str(tmp_path / "p4"), "--overwrite"]
    assert main(["remove", str(trained), "--box", str(box_file), "--no-inpaint", *own]) == 2
    assert box_file.read_text() == box_text and not (tmp_path / "p4").exists()
    # a result file is never written inside the new version, nor over a user's file
    inside = ["--json", str(tmp_path / "p2" / "r.json"), "--out", str(tmp_path / "p2")]
    assert main(["remove", str(trained), "--box", str(box_file), "--no-inpaint", *inside]) == 2
    assert not (tmp_path / "p2").exists()
    (tmp_path / "mine.txt").write_text("a user's notes")
    mine = ["--json", str(tmp_path / "mine.txt"), "--out", str(tmp_path / "p3"), "--overwrite"]
    assert main(["remove", str(trained), "--box", str(box_file), "--no-inpaint", *mine]) == 2
    assert (tmp_path / "mine.txt").read_text() == "a user's notes"
    assert not (tmp_path / "p3").exists()

    # the full edit: inpainted and trained into the weights
    out = tmp_path / "removed"
    rc = main(
        [
            "remove",
            str(trained),
            "--box",
            str(box_file),
            "--out",
            str(out),
            "--refine.steps",
            "60",
            "--refine.rounds",
            "2",
            "--views.turns",
            "1",
        ]
    )
    assert rc == 0
    assert tree_digest(trained) == before  # the input version is untouched, byte for byte
    edited = load_scene(out)
    assert edited.meta.parent == parent.meta.version_id and not edited.meta.cut_boxes
    assert (out / "report" / "before_after.png").is_file()
    assert (out / "report" / "virtual_views_round_1.png").is_file()

    # density inside the (shrunk) box is gone; far from it the field is as before
    gen = torch.Generator().manual_seed(0)
    inner = OrientedBox(box.center_m, tuple(0.6 * s for s in box.size_m), box.yaw_deg)
    u = (torch.rand(3000, 3, generator=gen) - 0.5) * torch.tensor(inner.size_m)
    pts_in = (
        u @ torch.tensor(inner.rotation, dtype=torch.float32).T + torch.tensor(inner.center_m)
    ).float()
    with torch.no_grad():
        sig_before = parent.field.density(pts_in)
        sig_after = edited.field.density(pts_in)
    assert float(sig_before.mean()) > 20 * max(float(sig_after.mean()), 1e-3)
    # the edit is a local patch: every pixel whose ray misses its region (and the occupancy
    # cells around it, which the edit refreshes) renders exactly as in the parent
    assert len(edited.meta.patches) == 1
    region = OrientedBox.from_dict(edited.meta.patches[0]["region"][0])
    cell = float((edited.grid.aabb[1] - edited.grid.aabb[0]).max()) / edited.grid.cfg.resolution
    refreshed = region.grown(2 * cell)
    assert region.contains(np.array([box.center_m]))[0]
    data = load_scene_data(sim_root / "removal_1" / "pre")
    from neoedit.cameras.rays import CameraTensors

    cams = CameraTensors(data.cameras)
    changed = 0
    for view in np.linspace(0, len(data) - 1, 3).round().astype(int):
        ra = parent.render_image(cams, int(view), data.height, data.width)
        rb = edited.render_image(cams, int(view), data.height, data.width)
        outside = ~torch.as_tensor(project_box_mask(data.cameras, int(view), refreshed))
        assert torch.allclose(ra["rgb"][outside], rb["rgb"][outside], atol=1e-5)
        assert torch.allclose(ra["depth_z"][outside], rb["depth_z"][outside], atol=1e-5)
        changed += int(((ra["rgb"] - rb["rgb"]).abs().amax(-1) > 0.05)[~outside].sum())
    assert changed > 0  # and inside it the mug is gone

    # an edit never writes over its input, and refuses an existing output
    assert main(["remove", str(trained), "--box", str(box_file), "--out", str(trained)]) == 2
    assert "never overwrites" in capsys.readouterr().err
    assert main(["remove", str(trained), "--box", str(box_file), "--out", str(out)]) == 2
    # the edited version is a scene the other verbs accept
    assert (
        main(
            [
                "eval",
                str(out),
                "--data",
                str(sim_root / "removal_1" / "post"),
                "--json",
                str(tmp_path / "m.json"),
            ]
        )
        == 0
    )
    assert json.loads((tmp_path / "m.json").read_text())["full"]["psnr"] > 15


def test_removal_loss_through_the_patch_equals_the_composed_field(trained: Path, sim_root: Path):
    """A removal step queries the trained patch directly (one-box region): every point it
    asks about lies in the patch's region, so the loss and the patch's gradients equal those
    through the composed field, which tests ownership point by point."""
    from neoedit.edit.refine import RefineConfig, _patch_training

    objects = json.loads((sim_root / "removal_1" / "pre" / "objects.json").read_text())["objects"]
    box = OrientedBox.from_dict(next(o for o in objects if o["name"] == "red mug")["box"])
    scene = load_scene(trained)
    cams, _, _ = scene.scan_cameras()
    virtual = virtual_cameras(box, cams, VirtualViewConfig(turns=1))
    loss, _, _ = _patch_training(scene, [box], virtual, RefineConfig(), cams)
    assert loss.span_field is loss.patch and len(loss.pix) > 0
    gen = torch.Generator().manual_seed(3)
    with torch.no_grad():  # the patch differs from the base, so a point outside would show
        table = loss.patch.encoding.table
        table.add_(1e-2 * torch.randn(table.shape, generator=gen))
    loss.targets.copy_(torch.rand(loss.targets.shape, generator=gen))
    loss.target_depth.copy_(torch.rand(loss.target_depth.shape, generator=gen))

    def run(span_field):
        loss.span_field = span_field
        loss.gen.manual_seed(7)
        loss.train_gen.manual_seed(7)
        loss.patch.zero_grad(set_to_none=True)
        value = loss()
        value.backward()
        grads = [p.grad.clone() for p in loss.patch.parameters()]
        return value.detach(), grads

    direct, g_direct = run(loss.patch)
    composed, g_composed = run(scene.field)
    assert torch.allclose(direct, composed, rtol=1e-5, atol=1e-7)
    for a, b in zip(g_direct, g_composed, strict=True):
        assert torch.allclose(a, b, rtol=1e-4, atol=1e-9)
    assert any(bool(g.abs().sum() > 0) for g in g_direct)

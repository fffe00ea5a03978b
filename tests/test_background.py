"""The learned background (environment map) for photos that see beyond the scene box."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import imageio.v3 as iio
import numpy as np
import torch

from neoedit.cameras import Cameras
from neoedit.cameras.cameras import look_at
from neoedit.cameras.rays import CameraTensors
from neoedit.eval.metrics import psnr
from neoedit.fields.background import DirectionalBackground
from neoedit.fields.radiance import RadianceField
from neoedit.rendering.occupancy import OccupancyGrid
from neoedit.rendering.renderer import render_chunked, render_rays
from neoedit.scene import load_scene
from neoedit.training.trainer import TrainConfig, train
from tests.conftest import TINY_FIELD, TINY_GRID, TINY_RENDER, tiny_train

W, H, F = 48, 36, 40.0


def _environment(directions: np.ndarray) -> np.ndarray:
    """A colour that depends on the ray direction only (walls 'at infinity')."""
    d = directions / np.linalg.norm(directions, axis=-1, keepdims=True)
    return np.clip(0.5 + 0.35 * d + 0.1 * np.sin(4 * d[..., [1, 2, 0]]), 0, 1)


FLOOR_RGB = np.array([0.82, 0.8, 0.74])


def _environment_dataset(root: Path, n: int = 16, floor: bool = False) -> None:
    """Photos (RGB, no alpha) of an empty box inside a direction-only environment; with
    ``floor``, a plain floor at z = 0 under a box that reaches below it, seen from above
    (without it the cameras look up, so no ray leaves the box through its bottom)."""
    (root / "images").mkdir(parents=True)
    frames = []
    for i in range(n):
        a = 2 * np.pi * i / n
        height = 0.25 + 0.1 * (i % 3) if floor else 0.02 + 0.03 * (i % 3)
        eye = np.array([0.6 * np.cos(a), 0.6 * np.sin(a), height])
        c2w = look_at(eye, np.array([0.0, 0.0, 0.0 if floor else 0.3]))
        cams = CameraTensors(Cameras.shared(c2w[None], F, F, W / 2, H / 2, W, H))
        rays = cams.image_rays(0, H, W)
        rgb = _environment(rays.directions.numpy()).reshape(H, W, 3)
        if floor:  # a pale floor with a faint texture (its depth must be observable)
            o, d = rays.origins.numpy(), rays.directions.numpy()
            down = d[:, 2] < 0
            hit = o + (-o[:, 2] / np.where(down, d[:, 2], -1.0))[:, None] * d
            shade = 0.08 * (np.floor(hit[:, 0] / 0.05) + np.floor(hit[:, 1] / 0.05)) % 2
            floor_rgb = FLOOR_RGB[None] - shade[:, None]
            rgb.reshape(-1, 3)[down] = floor_rgb[down]
        name = f"images/{i:03d}.png"
        iio.imwrite(root / name, (rgb * 255).round().astype(np.uint8))
        frames.append({"file_path": name, "transform_matrix": c2w.tolist()})
    meta = {"fl_x": F, "fl_y": F, "cx": W / 2, "cy": H / 2, "w": W, "h": H, "frames": frames}
    low = -0.05 if floor else 0.0
    meta["scene_aabb"] = [[-0.2, -0.2, low], [0.2, 0.2, 0.2]]
    (root / "transforms.json").write_text(json.dumps(meta))


def test_both_renderers_give_empty_rays_the_background_module_colour():
    aabb = torch.tensor([[-0.2, -0.2, 0.0], [0.2, 0.2, 0.2]])
    field = RadianceField(TINY_FIELD, aabb)
    with torch.no_grad():
        field.density_mlp[-1].bias[0] = -30.0  # empty box
    grid = OccupancyGrid(TINY_GRID, aabb)
    grid.update(field.density, 0)
    background = DirectionalBackground()
    c2w = look_at(np.array([0.6, 0.1, 0.3]), np.zeros(3))
    rays = CameraTensors(Cameras.shared(c2w[None], F, F, W / 2, H / 2, W, H)).image_rays(0, H, W)
    expected = background(rays.directions).detach()
    slow = render_rays(field, grid, rays, TINY_RENDER, background)["rgb"].detach()
    fast = render_chunked(field, grid, rays, TINY_RENDER, background)["rgb"]
    torch.testing.assert_close(slow, expected, atol=1e-5, rtol=0)
    torch.testing.assert_close(fast, expected, atol=1e-5, rtol=0)
    assert expected.std(0).min() > 1e-3  # the colours really vary with the direction


def test_photos_train_a_learned_background_instead_of_fog(tmp_path: Path):
    """Without alpha the trainer learns the environment map: the held-out views are
    reproduced while the empty box stays (almost) empty; a reload renders the same."""
    data = tmp_path / "env"
    _environment_dataset(data)
    tiny_train(data, tmp_path / "scene", steps=300)
    scene = load_scene(tmp_path / "scene")
    assert scene.meta.field.learned_background is True
    from neoedit.data import load_scene_data

    d = load_scene_data(data)
    cams = CameraTensors(d.cameras)
    scores, acc = [], []
    for i in d.split["test"]:
        out = scene.render_image(cams, int(i), H, W)
        scores.append(psnr(out["rgb"].numpy(), d.images[i] / 255.0))
        acc.append(float(out["accumulation"].mean()))
    assert min(scores) > 28.0, scores
    assert max(acc) < 0.1, acc  # the environment was not painted into the box as fog
    again = load_scene(tmp_path / "scene").render_image(cams, int(d.split["test"][0]), H, W)
    first = scene.render_image(cams, int(d.split["test"][0]), H, W)
    torch.testing.assert_close(again["rgb"], first["rgb"])


def test_rays_leaving_through_the_box_bottom_are_made_opaque_on_a_plain_floor(tmp_path: Path):
    """A plain floor is as well explained by the environment map as by geometry; with the
    closed bottom rays that leave the box through its bottom see black, so the floor gets
    its surface at the right depth."""
    data = tmp_path / "floor"
    _environment_dataset(data, floor=True)
    cfg = TrainConfig(max_steps=300, rays_per_batch=1024, eval_every=0, checkpoint_every=0, lr=2e-2)
    field = dataclasses.replace(TINY_FIELD, closed_bottom=True)
    train(data, tmp_path / "scene", cfg, field, TINY_RENDER, TINY_GRID, device="cpu")
    scene = load_scene(tmp_path / "scene")
    assert scene.meta.field.closed_bottom is True and scene.meta.field.learned_background
    from neoedit.data import load_scene_data

    d = load_scene_data(data)
    cams = CameraTensors(d.cameras)
    i = int(d.split["test"][0])
    out = scene.render_image(cams, i, H, W)
    rays = cams.image_rays(i, H, W)
    o, dirs = rays.origins, rays.directions
    t_floor = -o[:, 2] / dirs[:, 2]
    hit = (dirs[:, 2] < 0) & ((o + t_floor[:, None] * dirs)[:, :2].abs() < 0.12).all(-1)
    acc = out["accumulation"].reshape(-1)[hit]
    depth = out["depth_z"].reshape(-1)[hit]
    true_depth = (t_floor * rays.z_scale)[hit]
    assert float(acc.median()) > 0.7, acc
    assert float((depth - true_depth).abs().median()) < 0.04  # 48x36 px, 300 steps


def test_only_rays_leaving_through_the_box_bottom_see_black():
    from neoedit.fields.background import exits_bottom

    box = torch.tensor([[-1.0, -1.0, -0.1], [1.0, 1.0, 1.0]])
    origins = torch.tensor([[0.0, 0.0, 0.5]] * 3 + [[3.0, 0.0, 0.5]])
    dirs = torch.tensor([[0.0, 0.0, -1.0], [1.0, 0.0, -0.1], [0.6, 0.0, 0.8], [0.0, 0.0, -1.0]])
    dirs = dirs / dirs.norm(dim=-1, keepdim=True)
    # down through the bottom; down but out through a side; up; down but missing the box
    assert exits_bottom(origins, dirs, box).tolist() == [True, False, False, False]
    head = DirectionalBackground(closed_box=box)
    rgb = head(dirs, origins)
    assert rgb[0].abs().max() == 0 and (rgb[1:] > 0).all()
    assert (head(dirs) > 0).all()  # without origins (a bare direction query) nothing is closed

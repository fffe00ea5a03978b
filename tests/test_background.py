"""The learned background (environment map) for photos that see beyond the scene box."""

from __future__ import annotations

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
from tests.conftest import TINY_FIELD, TINY_GRID, TINY_RENDER, tiny_train

W, H, F = 48, 36, 40.0


def _environment(directions: np.ndarray) -> np.ndarray:
    """A colour that depends on the ray direction only (walls 'at infinity')."""
    d = directions / np.linalg.norm(directions, axis=-1, keepdims=True)
    return np.clip(0.5 + 0.35 * d + 0.1 * np.sin(4 * d[..., [1, 2, 0]]), 0, 1)


def _environment_dataset(root: Path, n: int = 16) -> None:
    """Photos (RGB, no alpha) of an empty box inside a direction-only environment."""
    (root / "images").mkdir(parents=True)
    frames = []
    for i in range(n):
        a = 2 * np.pi * i / n
        eye = np.array([0.6 * np.cos(a), 0.6 * np.sin(a), 0.25 + 0.1 * (i % 3)])
        c2w = look_at(eye, np.zeros(3))
        cams = CameraTensors(Cameras.shared(c2w[None], F, F, W / 2, H / 2, W, H))
        rays = cams.image_rays(0, H, W)
        rgb = _environment(rays.directions.numpy()).reshape(H, W, 3)
        name = f"images/{i:03d}.png"
        iio.imwrite(root / name, (rgb * 255).round().astype(np.uint8))
        frames.append({"file_path": name, "transform_matrix": c2w.tolist()})
    meta = {"fl_x": F, "fl_y": F, "cx": W / 2, "cy": H / 2, "w": W, "h": H, "frames": frames}
    meta["scene_aabb"] = [[-0.2, -0.2, 0.0], [0.2, 0.2, 0.2]]
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

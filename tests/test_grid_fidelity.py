"""The end of training and the fast march keep what the field learnt (issue 39, item 0).

A Blender-format RGBA scene (NEO-Sim objects on a transparent background) trains a tiny
field; the grid rebuilt at the end of training must not cost held-out PSNR, and the fast
march must render the field as a converged training sampler does.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest

from neoedit.cameras import Cameras, look_at
from neoedit.data import load_scene_data
from neoedit.data.bounds import alpha_hull_box
from neoedit.sim.blender_scene import BlenderSceneSpec, write_blender_scene
from neoedit.training.defaults import median_camera_distance, scene_box
from neoedit.training.trainer import TrainConfig
from tests.conftest import tiny_trainer


def sphere_views(n: int, size: int, centre: np.ndarray, radius: float):
    """Cameras on a ring at distance 4 and the exact alpha of a sphere seen by them."""
    eyes = [4 * np.array([np.cos(a), np.sin(a), 0.6]) for a in np.linspace(0, 2 * np.pi, n, False)]
    c2w = np.stack([look_at(e, np.zeros(3)) for e in eyes])
    f = np.full(n, 1.2 * size)
    cams = Cameras(
        c2w, f, f, np.full(n, size / 2), np.full(n, size / 2), np.full(n, size), np.full(n, size)
    )
    alpha = np.zeros((n, size, size), np.uint8)
    for i in range(n):
        d = cams.pixel_directions_camera(i) @ c2w[i, :3, :3].T
        d /= np.linalg.norm(d, axis=-1, keepdims=True)
        oc = centre - c2w[i, :3, 3]
        along = d @ oc
        miss = np.linalg.norm(oc) ** 2 - along**2
        alpha[i] = np.where(miss < radius**2, 255, 0)
    return cams, alpha


def test_alpha_hull_box_holds_the_object_and_little_else():
    centre, radius = np.array([0.3, -0.2, 0.1]), 0.5
    cams, alpha = sphere_views(12, 64, centre, radius)
    search = np.array([[-4.0] * 3, [4.0] * 3])
    box = alpha_hull_box(cams, alpha, np.arange(12), search)
    assert box is not None
    cell = 8.0 / 64
    assert np.all(box[0] <= centre - radius) and np.all(box[1] >= centre + radius)
    # a ring of views at one height bounds z loosely, x and y tightly
    assert np.all(box[0][:2] >= centre[:2] - radius - 3 * cell)
    assert np.all(box[1][:2] <= centre[:2] + radius + 3 * cell)
    assert np.all(box[1] - box[0] < 3.0)
    # opaque images say nothing about where the object is
    assert alpha_hull_box(cams, np.full_like(alpha, 255), np.arange(12), search) is None


@pytest.fixture(scope="module")
def blender_root(tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp("blender")
    spec = BlenderSceneSpec(size=48, n_train=30, n_test=4)
    spec.objects = spec.objects[:3]
    write_blender_scene(spec, root)
    return root


def test_blender_scene_box_is_tight(blender_root: Path):
    data = load_scene_data(blender_root)
    lo, hi = (np.asarray(v) for v in scene_box(data))
    # the convention: the object inside +-1.5, cameras at ~4 (a cube around them: +-4)
    assert median_camera_distance(data) > 3.5
    assert np.all(lo >= -1.6) and np.all(hi <= 1.6)


def test_end_of_training_grid_and_fast_march_keep_the_fields_quality(blender_root: Path):
    cfg = TrainConfig(max_steps=300, rays_per_batch=1024, eval_views=4, sparsity_loss_weight=0.01)
    trainer = tiny_trainer(blender_root, 1.0, cfg)
    running = trainer.evaluate()
    trainer.finish_grid()
    rebuilt = trainer.evaluate()
    assert running > 20.0  # the field learnt the scene
    assert rebuilt >= running - 0.05, (running, rebuilt)
    # the march against the training sampler with enough samples to have converged
    trainer.scene.meta.render = dataclasses.replace(
        trainer.scene.meta.render, fast_render=False, n_coarse_samples=192, n_samples=128
    )
    sampler = trainer.evaluate()
    assert abs(rebuilt - sampler) <= 0.1, (rebuilt, sampler)

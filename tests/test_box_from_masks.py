"""box_from_masks (edit/points.py): 2-D masks of an object and the field's depth give the
object's box; depth that a mask's edge lets through to the background is voted out."""

from __future__ import annotations

import types

import numpy as np
import pytest
import torch

from neoedit.cameras import Cameras
from neoedit.cameras.cameras import look_at
from neoedit.edit.points import box_from_masks
from neoedit.errors import NeoError
from neoedit.geometry import OrientedBox
from neoedit.geometry.box import box_iou_3d
from neoedit.geometry.masks import project_box_mask
from neoedit.rendering.renderer import RenderConfig

OBJECT = OrientedBox((0.05, -0.02, 0.06), (0.10, 0.06, 0.12), 30.0)


class TwoBlocks(torch.nn.Module):
    """Opaque analytic field: the object, a wide table top under it and a wall behind."""

    def __init__(self):
        super().__init__()
        self.register_buffer("aabb", torch.tensor([[-0.5, -0.5, -0.1], [0.5, 0.5, 0.5]]))

    def density(self, points):
        c = torch.tensor(OBJECT.center_m)
        yaw = np.radians(OBJECT.yaw_deg)
        rot = torch.tensor(
            [[np.cos(yaw), -np.sin(yaw), 0], [np.sin(yaw), np.cos(yaw), 0], [0, 0, 1]],
            dtype=torch.float32,
        )
        local = (points - c) @ rot
        inside = (local.abs() <= torch.tensor(OBJECT.size_m) / 2).all(-1)
        table = points[:, 2] < 0.0
        wall = points[:, 1] > 0.35
        return 2000.0 * (inside | table | wall).float()

    def forward(self, points, directions):
        return self.density(points), torch.full((len(points), 3), 0.5)


def _scene_and_cameras():
    poses = [
        look_at(
            np.array([0.6 * np.cos(a), 0.6 * np.sin(a) - 0.2, 0.35]), np.array([0.0, 0.0, 0.05])
        )
        for a in np.linspace(-2.5, -0.6, 6)
    ]
    cams = Cameras.shared(np.stack(poses), 60.0, 60.0, 40.0, 30.0, 80, 60)
    field = TwoBlocks()
    scene = types.SimpleNamespace(
        field=field,
        grid=None,
        meta=types.SimpleNamespace(
            render=RenderConfig(near_m=0.05, n_coarse_samples=128, n_samples=64)
        ),
        background=torch.zeros(3),
        renderable=lambda: (field, []),
    )
    return scene, cams


def test_masks_give_the_objects_box():
    scene, cams = _scene_and_cameras()
    masks = {i: project_box_mask(cams, i, OBJECT) for i in range(len(cams))}
    # one mask bleeds: a band beside the object that sees the wall behind it
    masks[0] = masks[0] | np.roll(masks[0], 4, axis=1)
    box = box_from_masks(scene, cams, masks, rays_per_view=800)
    assert box_iou_3d(box, OBJECT) > 0.6, box
    assert np.linalg.norm(np.subtract(box.center_m, OBJECT.center_m)) < 0.02


def test_masks_of_another_scene_are_refused():
    scene, cams = _scene_and_cameras()
    empty = {i: np.zeros((60, 80), bool) for i in range(len(cams))}
    with pytest.raises(NeoError, match="no surface"):
        box_from_masks(scene, cams, empty)


def test_a_masks_folder_is_matched_to_the_scans_photos_by_name(tmp_path):
    import imageio.v3 as iio

    from neoedit.data.masks import read_object_masks
    from neoedit.errors import DataError

    _, cams = _scene_and_cameras()
    paths = [f"images/frame_{i:03d}.jpg" for i in range(len(cams))]
    mask = np.zeros((60, 80), np.uint8)
    mask[10:20, 30:40] = 255
    iio.imwrite(tmp_path / "frame_002.png", mask)
    iio.imwrite(tmp_path / "notes.png", mask)  # no such photo: ignored
    found = read_object_masks(tmp_path, paths, cams)
    assert list(found) == [2] and found[2].sum() == 100 and found[2].dtype == bool
    iio.imwrite(tmp_path / "frame_003.png", np.zeros((30, 40), np.uint8))
    with pytest.raises(DataError, match="40x30"):
        read_object_masks(tmp_path, paths, cams)

"""Parsers: nerfstudio transforms.json and the Blender synthetic format, with their errors."""

import json
import shutil
from pathlib import Path

import imageio.v3 as iio
import numpy as np
import pytest

from neoedit.data import load_scene_data
from neoedit.errors import DataError


def _write_ns(root: Path, frames: list[dict], **meta) -> Path:
    root.mkdir(parents=True, exist_ok=True)
    body = {
        "fl_x": 20.0,
        "fl_y": 20.0,
        "cx": 8.0,
        "cy": 6.0,
        "w": 16,
        "h": 12,
        **meta,
        "frames": frames,
    }
    (root / "transforms.json").write_text(json.dumps(body))
    return root


def _frame(root: Path, name: str, pose=None, rgba=False) -> dict:
    img = np.full((12, 16, 4 if rgba else 3), 100, np.uint8)
    if rgba:
        img[..., 3] = 0  # fully transparent -> background
    iio.imwrite(root / f"{name}.png", img)
    return {
        "file_path": f"{name}.png",
        "transform_matrix": (np.eye(4) if pose is None else pose).tolist(),
    }


def test_nerfstudio_minimal_with_default_split(tmp_path: Path):
    frames = [_frame(tmp_path, f"f{i}") for i in range(10)]
    data = load_scene_data(_write_ns(tmp_path, frames))
    assert data.images.shape == (10, 12, 16, 3)
    assert list(data.split["test"]) == [0, 8]
    assert len(data.split["train"]) == 8
    assert data.depth_m is None and data.instance_ids is None


def test_nerfstudio_per_frame_intrinsics_and_alpha(tmp_path: Path):
    frames = [_frame(tmp_path, "a", rgba=True), _frame(tmp_path, "b")]
    frames[0]["fl_x"] = 33.0
    data = load_scene_data(_write_ns(tmp_path, frames, background_color=[0.0, 1.0, 0.0]))
    assert data.cameras.fx.tolist() == [33.0, 20.0]
    assert data.images[0, 0, 0].tolist() == [0, 255, 0]  # composited over the background colour


def test_nerfstudio_reads_sim_depth_and_labels(sim_root: Path):
    data = load_scene_data(sim_root / "removal_1" / "pre" / "transforms.json")
    assert (
        data.depth_m.dtype == np.float32 and 0.2 < np.median(data.depth_m[data.depth_m > 0]) < 3.0
    )
    assert data.scene_aabb_m.shape == (2, 3)


@pytest.mark.parametrize(
    "mutate, message",
    [
        (lambda m: m.pop("fl_x"), "missing intrinsic 'fl_x'"),
        (lambda m: m["frames"][1].pop("transform_matrix"), "frame 1: missing 'transform_matrix'"),
        (lambda m: m["frames"][0].__setitem__("file_path", "nope.png"), "image not found"),
        (
            lambda m: m["frames"][0].__setitem__("transform_matrix", [[float("nan")] * 4] * 4),
            "non-finite",
        ),
        (
            lambda m: m["frames"][0].__setitem__("transform_matrix", [[0.0] * 4] * 4),
            "not invertible",
        ),
        (lambda m: m.update(camera_model="PINHOLE", k1=0.1), "lens distortion 'k1'"),
        (lambda m: m.__setitem__("camera_model", "EQUIRECTANGULAR"), "'EQUIRECTANGULAR' is not"),
        (lambda m: m.__setitem__("frames", []), "non-empty 'frames'"),
        (lambda m: m.__setitem__("train_filenames", ["other.png"]), "not a frame's file_path"),
        (lambda m: m.__setitem__("w", 99), "but w,h say"),
    ],
)
def test_nerfstudio_errors(tmp_path: Path, mutate, message):
    frames = [_frame(tmp_path, f"f{i}") for i in range(3)]
    _write_ns(tmp_path, frames)
    meta = json.loads((tmp_path / "transforms.json").read_text())
    mutate(meta)
    (tmp_path / "transforms.json").write_text(json.dumps(meta))
    with pytest.raises(DataError, match=message):
        load_scene_data(tmp_path)


def test_bad_json_and_unknown_folder(tmp_path: Path):
    (tmp_path / "transforms.json").write_text("{ not json")
    with pytest.raises(DataError, match="not valid JSON"):
        load_scene_data(tmp_path)
    with pytest.raises(DataError, match="not found"):
        load_scene_data(tmp_path / "missing")
    (tmp_path / "empty").mkdir()
    with pytest.raises(DataError, match="no transforms.json"):
        load_scene_data(tmp_path / "empty")


def test_blender_format(tmp_path: Path):
    angle = 0.69
    for split, n in (("train", 3), ("val", 1), ("test", 2)):
        (tmp_path / split).mkdir()
        frames = []
        for i in range(n):
            img = np.zeros((20, 30, 4), np.uint8)
            img[5:15, 5:25] = (255, 0, 0, 255)  # opaque red square on transparent
            iio.imwrite(tmp_path / split / f"r_{i}.png", img)
            frames.append({"file_path": f"./{split}/r_{i}", "transform_matrix": np.eye(4).tolist()})
        (tmp_path / f"transforms_{split}.json").write_text(
            json.dumps({"camera_angle_x": angle, "frames": frames})
        )
    data = load_scene_data(tmp_path)
    assert (
        len(data) == 6
        and list(data.split["train"]) == [0, 1, 2]
        and list(data.split["test"]) == [4, 5]
    )
    assert data.cameras.fx[0] == pytest.approx(0.5 * 30 / np.tan(0.5 * angle))
    assert data.images[0, 0, 0].tolist() == [255, 255, 255]  # white background
    assert data.images[0, 10, 10].tolist() == [255, 0, 0]
    shutil.rmtree(tmp_path / "train")
    with pytest.raises(DataError, match="image not found"):
        load_scene_data(tmp_path)

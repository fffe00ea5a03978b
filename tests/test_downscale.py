"""--downscale / --max-width: smaller images whose pixels keep their rays (issue 37)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from neoedit.cli import main
from neoedit.data import load_scene_data
from neoedit.data.downscale import DataConfig
from neoedit.errors import DataError


def _write_dataset(root: Path, w: int = 64, h: int = 48) -> None:
    import json

    from neoedit.cameras import look_at
    from neoedit.utils.io import write_png

    frames = []
    rng = np.random.default_rng(0)
    for i in range(4):
        img = rng.integers(0, 255, (h, w, 3), dtype=np.uint8)
        write_png(root / "images" / f"{i}.png", img)
        eye = np.array([2.0 * np.cos(i), 2.0 * np.sin(i), 1.0])
        frames.append(
            {"file_path": f"images/{i}.png", "transform_matrix": look_at(eye, np.zeros(3)).tolist()}
        )
    meta = {"fl_x": 50.0, "fl_y": 52.0, "cx": 31.0, "cy": 23.5, "w": w, "h": h, "frames": frames}
    (root / "transforms.json").write_text(json.dumps(meta))


def test_downscale_shrinks_images_and_keeps_each_pixels_ray(tmp_path: Path):
    _write_dataset(tmp_path)
    full = load_scene_data(tmp_path)
    half = load_scene_data(tmp_path, DataConfig(downscale=2))
    assert half.images.shape == (4, 24, 32, 3)
    # a 2x2 block of the full image averages to one pixel of the half image
    block = full.images[1, 10:12, 20:22].astype(float).mean((0, 1))
    assert np.allclose(half.images[1, 5, 10], block, atol=1.0)
    # the point a full-size pixel corner sees projects to the matching half-size corner
    point = np.array([[0.1, -0.2, 0.3]])
    uv_full, _ = full.cameras.project(2, point)
    uv_half, _ = half.cameras.project(2, point)
    assert np.allclose(uv_half, uv_full / 2, atol=1e-6)


def test_max_width_picks_the_smallest_factor(tmp_path: Path):
    _write_dataset(tmp_path)
    assert load_scene_data(tmp_path, DataConfig(max_width=40)).width == 32  # factor 2
    assert load_scene_data(tmp_path, DataConfig(max_width=64)).width == 64  # factor 1
    assert DataConfig(max_width=20).factor(64) == 4


@pytest.mark.parametrize(
    "cfg, message",
    [(DataConfig(downscale=0), "--downscale"), (DataConfig(max_width=2), "--max-width")],
)
def test_bad_downscale_is_refused(tmp_path: Path, cfg: DataConfig, message: str):
    _write_dataset(tmp_path)
    with pytest.raises(DataError, match=message):
        load_scene_data(tmp_path, cfg)
    with pytest.raises(DataError, match="leaves"):
        load_scene_data(tmp_path, DataConfig(downscale=16))


def test_info_reports_the_downscaled_size_box_and_command(tmp_path: Path, capsys):
    _write_dataset(tmp_path)
    assert main(["info", str(tmp_path), "--downscale", "2"]) == 0
    out = capsys.readouterr().out
    assert "4 frames of 32x24" in out
    assert "scene box:" in out and "cube around" in out
    assert "--downscale 2" in out

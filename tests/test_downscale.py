"""--downscale / --max-width: smaller images whose pixels keep their rays (issue 37)."""

from __future__ import annotations

import dataclasses
import warnings
from pathlib import Path

import numpy as np
import pytest

from neoedit.cli import main
from neoedit.data import load_scene_data
from neoedit.data.downscale import DataConfig
from neoedit.errors import DataError, NeoWarning
from neoedit.utils.io import write_png


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


def _pre_shrink(root: Path, factor: int, folder: str = "images", mark: int = 7) -> None:
    """nerfstudio's ``images_N/`` copies of the photos (``ns-process-data`` writes them),
    each with a marked corner pixel so a test can tell which file was read."""
    import cv2

    for src in sorted((root / folder).glob("*.png")):
        small = cv2.resize(cv2.imread(str(src)), None, fx=1 / factor, fy=1 / factor,
                           interpolation=cv2.INTER_AREA)  # fmt: skip
        small[0, 0] = mark
        (root / f"{folder}_{factor}").mkdir(exist_ok=True)
        cv2.imwrite(str(root / f"{folder}_{factor}" / src.name), small)


def test_nerfstudio_images_n_folders_are_read_when_they_match(tmp_path: Path):
    """--downscale N reads nerfstudio's pre-shrunk images_N/ copies (intrinsics scaled as for
    a shrink in memory); a copy folder that lacks a photo, or holds another size, is not used
    (a warning says why) and the photos are shrunk on load instead."""
    _write_dataset(tmp_path)
    shrunk = load_scene_data(tmp_path, DataConfig(downscale=2))
    _pre_shrink(tmp_path, 2)
    read = load_scene_data(tmp_path, DataConfig(downscale=2))
    assert read.pre_shrunk and read.downscaled == 2 and not shrunk.pre_shrunk
    assert read.images.shape == shrunk.images.shape and (read.images[:, 0, 0] == 7).all()
    assert read.file_paths == shrunk.file_paths  # the splits still name the listed photos
    for key in ("fx", "fy", "cx", "cy"):
        assert np.allclose(getattr(read.cameras, key), getattr(shrunk.cameras, key))
    assert np.abs(read.images[:, 1:, 1:].astype(int) - shrunk.images[:, 1:, 1:]).max() <= 1
    assert not load_scene_data(tmp_path, DataConfig(downscale=4)).pre_shrunk  # no images_4/
    (tmp_path / "images_2" / "3.png").unlink()
    with pytest.warns(NeoWarning, match="images_2 is not used .*no images_2/3.png"):
        data = load_scene_data(tmp_path, DataConfig(downscale=2))
    assert not data.pre_shrunk and data.downscaled == 2 and (data.images[:, 0, 0] != 7).any()


def test_masks_and_depths_come_from_their_own_n_folders(tmp_path: Path):
    """Frames with masks and depths read masks_N/ and depths_N/ beside images_N/; without
    one of them the copies are not used; two frames whose copies share a name neither."""
    import json

    _write_dataset(tmp_path)
    meta = json.loads((tmp_path / "transforms.json").read_text())
    for i, frame in enumerate(meta["frames"]):
        write_png(tmp_path / "masks" / f"{i}.png", np.full((48, 64), 255, np.uint8))
        write_png(tmp_path / "depths" / f"{i}.png", np.full((48, 64), 1000, np.uint16))
        write_png(tmp_path / "masks_2" / f"{i}.png", np.full((24, 32), 255, np.uint8))
        write_png(tmp_path / "depths_2" / f"{i}.png", np.full((24, 32), 2000 + i, np.uint16))
        frame.update(mask_path=f"masks/{i}.png", depth_file_path=f"depths/{i}.png")
    (tmp_path / "transforms.json").write_text(json.dumps(meta))
    _pre_shrink(tmp_path, 2)
    data = load_scene_data(tmp_path, DataConfig(downscale=2))
    assert data.pre_shrunk and data.loss_mask is not None and data.loss_mask.all()
    assert np.allclose(data.depth_m[:, 5, 5], [2.0, 2.001, 2.002, 2.003])  # depths_2/, in m
    (tmp_path / "depths_2" / "1.png").unlink()
    with pytest.warns(NeoWarning, match="no depths_2/1.png"):
        data = load_scene_data(tmp_path, DataConfig(downscale=2))
    assert not data.pre_shrunk and np.allclose(data.depth_m[:, 5, 5], 1.0)
    write_png(tmp_path / "depths_2" / "1.png", np.full((24, 32), 2000, np.uint16))
    meta["frames"][1]["file_path"] = "images/other/0.png"  # another camera's 0.png
    write_png(tmp_path / "images" / "other" / "0.png", np.zeros((48, 64, 3), np.uint8))
    (tmp_path / "transforms.json").write_text(json.dumps(meta))
    with pytest.warns(NeoWarning, match="frames 0 and 1 would both read images_2/0.png"):
        assert not load_scene_data(tmp_path, DataConfig(downscale=2)).pre_shrunk


def test_images_n_of_another_size_is_not_used(tmp_path: Path):
    _write_dataset(tmp_path)
    _pre_shrink(tmp_path, 4)
    (tmp_path / "images_4").rename(tmp_path / "images_2")  # a quarter, named a half
    with pytest.warns(NeoWarning, match="is 16x12, not 1/2 of 64x48"):
        data = load_scene_data(tmp_path, DataConfig(downscale=2))
    assert data.width == 32 and not data.pre_shrunk


def test_info_lists_missing_images_and_prints_warnings_as_lines(tmp_path: Path, capsys):
    """``neo info`` on a dataset with a missing photo reports it (no refusal) and says how
    to train; ``neo train`` refuses it; with --skip-missing the warning is one line."""
    _write_dataset(tmp_path)
    (tmp_path / "images" / "2.png").unlink()
    assert main(["info", str(tmp_path), "--no-check-poses"]) == 0
    out = " ".join(capsys.readouterr().out.split())
    assert "3 frames of 64x48" in out and "missing: " in out and "2 (images/2.png)" in out
    assert "lenses: pinhole (no distortion)" in out
    assert "--skip-missing --out <scene folder>" in out
    (tmp_path / "images" / "2.png").write_bytes((tmp_path / "images" / "1.png").read_bytes())
    _pre_shrink(tmp_path, 2)
    assert main(["info", str(tmp_path), "--downscale", "2", "--no-check-poses"]) == 0
    assert "downscaled 2x (read from images_2/)" in capsys.readouterr().out


@dataclasses.dataclass
class _Warns:
    """A command whose work warns: once in neoedit's own words, once as a library would."""

    def run(self) -> None:
        warnings.warn("3 frames are skipped", NeoWarning, stacklevel=2)
        warnings.warn("a library's own note", UserWarning, stacklevel=2)


def test_neoedits_warnings_print_as_one_line(capsys, monkeypatch):
    from neoedit.cli import _run

    others: list[str] = []
    monkeypatch.setattr(
        warnings, "showwarning", lambda message, *a, **k: others.append(str(message))
    )
    warnings.simplefilter("always")
    assert _run(_Warns(), None) == 0
    err = capsys.readouterr().err
    assert "warning: 3 frames are skipped\n" in err and "NeoWarning" not in err
    assert others == ["a library's own note"]  # shown as Python (or pytest) shows warnings
    assert "a library's own note" not in err

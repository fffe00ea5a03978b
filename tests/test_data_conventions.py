"""transforms.json as users have them (issue 37): nerfstudio camera models with lens
distortion (undistorted at load, cached outside the dataset), per-frame intrinsics,
instant-ngp's keys and missing images. Each test writes a tiny dataset in one convention."""

from __future__ import annotations

import json
import math
import os
import warnings
from pathlib import Path

import cv2
import numpy as np
import pytest

from neoedit.data import load_scene_data
from neoedit.data import undistort as und
from neoedit.data.downscale import DataConfig
from neoedit.data.nerfstudio import load_nerfstudio
from neoedit.errors import DataError
from neoedit.utils.io import write_png

W, H, F = 40, 32, 30.0
CX, CY = 20.3, 15.8
"""Principal point in nerfstudio's convention (pixel centres at +0.5)."""
OPENCV = {"k1": -0.35, "k2": 0.05, "p1": 0.002, "p2": -0.001}
FISHEYE = {"k1": 0.1, "k2": -0.05, "k3": 0.01, "k4": 0.002}
FISHEYE_F = 16.0
"""A wide fisheye (about 100 degrees across), where it bends lines visibly."""


def _lines(spread: float = 1.0) -> np.ndarray:
    """(2, 5, 3): two straight horizontal rows of points 2 m in front of an identity camera,
    in OpenCV's camera frame (x right, y down, z forward)."""
    xs = np.linspace(-1.2, 1.2, 5) * spread
    return np.array([[[x, y * spread, 2.0] for x in xs] for y in (-0.7, 0.7)])


POINTS = _lines().reshape(-1, 3)


@pytest.fixture(autouse=True)
def cache(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    """The undistortion cache of every test: a folder beside (not in) its dataset."""
    folder = tmp_path / "cache"
    monkeypatch.setenv(und.CACHE_ENV, str(folder))
    return folder / "undistorted"


def _distorted_pixels(model: str, dist: dict, points=POINTS, fx=F, fy=F) -> np.ndarray:
    """Where OpenCV's distorted camera sees ``points`` (N, 3): (N, 2) pixel indices (u, v)."""
    k = np.array([[fx, 0.0, CX - 0.5], [0.0, fy, CY - 0.5], [0.0, 0.0, 1.0]])
    rt = (np.zeros(3), np.zeros(3))
    if model == "OPENCV_FISHEYE":
        d = np.array([dist.get(key, 0.0) for key in ("k1", "k2", "k3", "k4")])
        return cv2.fisheye.projectPoints(points[:, None], *rt, k, d)[0][:, 0]
    d = np.array([dist.get(key, 0.0) for key in ("k1", "k2", "p1", "p2", "k3")])
    return cv2.projectPoints(points, *rt, k, d)[0][:, 0]


def _blobs(pixels, sigma: float = 0.8) -> np.ndarray:
    """(H, W, 3) uint8: a bright Gaussian spot at each pixel position on black."""
    u, v = np.meshgrid(np.arange(W), np.arange(H))
    img = np.zeros((H, W))
    for p in pixels:
        img += np.exp(-((u - p[0]) ** 2 + (v - p[1]) ** 2) / (2 * sigma**2))
    grey = (np.clip(img, 0, 1) * 255).round().astype(np.uint8)
    return np.repeat(grey[..., None], 3, axis=-1)


def _centroid(img: np.ndarray, at: np.ndarray, r: int = 2) -> np.ndarray:
    """Intensity-weighted centre (u, v) of the spot near pixel ``at`` (the window is
    re-centred once on the first estimate)."""
    for _ in range(2):
        u0, v0 = np.round(at).astype(int)
        rows = slice(max(v0 - r, 0), min(v0 + r + 1, img.shape[0]))
        cols = slice(max(u0 - r, 0), min(u0 + r + 1, img.shape[1]))
        vv, uu = np.mgrid[rows, cols]
        win = img[rows, cols].astype(float)
        at = np.array([(win * uu).sum(), (win * vv).sum()]) / win.sum()
    return at


def _bend(pixels: np.ndarray) -> float:
    """Largest distance (px) of ``pixels`` (N, 2) from their least-squares line v = a u + b."""
    a = np.c_[pixels[:, 0], np.ones(len(pixels))]
    coef = np.linalg.lstsq(a, pixels[:, 1], rcond=None)[0]
    return float(np.abs(a @ coef - pixels[:, 1]).max())


def _frame(root: Path, name: str, image: np.ndarray, **keys) -> dict:
    write_png(root / f"{name}.png", image)
    return {"file_path": f"{name}.png", "transform_matrix": np.eye(4).tolist(), **keys}


def _write(root: Path, frames: list[dict], **meta) -> Path:
    (root / "transforms.json").write_text(json.dumps({**meta, "frames": frames}))
    return root


def _intrinsics(**extra) -> dict:
    return {"fl_x": F, "fl_y": F, "cx": CX, "cy": CY, "w": W, "h": H, **extra}


def _snapshot(folder: Path) -> dict[str, tuple[int, int]]:
    return {
        str(p.relative_to(folder)): (p.stat().st_size, p.stat().st_mtime_ns)
        for p in sorted(folder.rglob("*"))
    }


def _spots(data, i: int, points=POINTS, tol_px: float = 0.5) -> np.ndarray:
    """Centres of the spots in loaded image i, each checked to lie within ``tol_px`` of
    where the returned pinhole camera projects its point."""
    world = points * np.array([1.0, -1.0, -1.0])  # identity pose, OpenGL camera frame
    expected = data.cameras.project(i, world)[0] - 0.5  # pixel centres at +0.5 -> indices
    found = np.array([_centroid(data.images[i, ..., 0], at) for at in expected])
    assert np.linalg.norm(found - expected, axis=1).max() < tol_px
    return found


@pytest.mark.parametrize(
    "model, dist, focal, spread",
    [
        ("OPENCV", OPENCV, F, 1.0),
        ("OPENCV", {**OPENCV, "k3": 0.01}, F, 1.0),
        ("OPENCV_FISHEYE", FISHEYE, FISHEYE_F, 1.6),
    ],
    ids=["opencv", "opencv-k3", "fisheye"],
)
def test_distorted_photo_becomes_pinhole(tmp_path: Path, model, dist, focal, spread):
    """Points that OpenCV's distorted camera sees at pixels p land, in the undistorted
    image, where the returned pinhole camera projects them; straight rows of points, bent
    in the photo, are straight again."""
    rows = _lines(spread)
    seen = [_distorted_pixels(model, dist, row, focal, focal) for row in rows]
    assert min(_bend(p) for p in seen) > 0.4  # the lens bends the rows
    root = tmp_path / "ds"
    root.mkdir()
    frames = [_frame(root, "a", _blobs(np.concatenate(seen)))]
    meta = _intrinsics(**{**dist, "fl_x": focal, "fl_y": focal})
    data = load_nerfstudio(_write(root, frames, camera_model=model, **meta))
    assert data.images.shape == (1, H, W, 3) and data.cameras.width[0] == W
    assert data.cameras.fx[0] != focal and data.loss_mask is None
    for row in rows:
        assert _bend(_spots(data, 0, row)) < 0.2


def test_per_frame_intrinsics_and_distortion_override_global(tmp_path: Path):
    root = tmp_path / "ds"
    root.mkdir()
    own = {"fl_x": 27.0, "fl_y": 28.0, "k1": -0.25, "p1": 0.0}
    theirs = _distorted_pixels("OPENCV", {**OPENCV, **own}, POINTS, 27, 28)
    frames = [
        _frame(root, "a", _blobs(_distorted_pixels("OPENCV", OPENCV))),
        _frame(root, "b", _blobs(theirs), **own),
    ]
    data = load_nerfstudio(_write(root, frames, camera_model="OPENCV", **_intrinsics(**OPENCV)))
    assert data.cameras.fx[0] != data.cameras.fx[1]
    for i, (fx, fy, d) in enumerate([(F, F, OPENCV), (27.0, 28.0, {**OPENCV, **own})]):
        k = np.array([[fx, 0, CX - 0.5], [0, fy, CY - 0.5], [0, 0, 1]])
        dist = np.array([d["k1"], d["k2"], d["p1"], d["p2"]])
        new_k = cv2.getOptimalNewCameraMatrix(k, dist, (W, H), 0.0, (W, H))[0]
        assert data.cameras.fx[i] == pytest.approx(new_k[0, 0])
        assert data.cameras.cx[i] == pytest.approx(new_k[0, 2] + 0.5)
        _spots(data, i)


@pytest.mark.parametrize("model", ["PINHOLE", "OPENCV", None])
def test_pinhole_frames_are_read_unchanged(tmp_path: Path, cache: Path, monkeypatch, model):
    root = tmp_path / "ds"
    root.mkdir()
    rng = np.random.default_rng(0)
    images = [rng.integers(0, 256, (H, W, 3), dtype=np.uint8) for _ in range(2)]
    frames = [_frame(root, f"f{i}", im) for i, im in enumerate(images)]
    meta = _intrinsics(k1=0.0, p2=0.0) if model is None else _intrinsics(camera_model=model)
    data = load_nerfstudio(_write(root, frames, **meta))
    assert np.array_equal(data.images, np.stack(images))
    assert data.cameras.fx.tolist() == [F, F] and data.cameras.cx.tolist() == [CX, CX]
    assert data.loss_mask is None and not cache.exists()
    monkeypatch.setenv(und.CACHE_ENV, str(root / "cache"))  # unused: no warning about it
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        again = load_nerfstudio(root)
    assert np.array_equal(again.images, data.images)


@pytest.mark.parametrize(
    "alias, same",
    [
        ({"is_fisheye": True, **FISHEYE}, {"camera_model": "OPENCV_FISHEYE", **FISHEYE}),
        ({"camera_model": "SIMPLE_RADIAL", "k1": -0.2}, {"camera_model": "OPENCV", "k1": -0.2}),
        ({"camera_model": "radial", "k1": -0.2, "k2": 0.03}, {"k1": -0.2, "k2": 0.03}),
    ],
)
def test_other_names_of_the_same_lens(tmp_path: Path, alias: dict, same: dict):
    """instant-ngp's is_fisheye and COLMAP's SIMPLE_RADIAL / RADIAL (any case) load as the
    OPENCV_FISHEYE / OPENCV lens they are."""
    loaded = []
    for name, keys in (("a", alias), ("b", same)):
        root = tmp_path / name
        root.mkdir()
        frames = [_frame(root, "f", _blobs(_distorted_pixels("OPENCV", OPENCV)))]
        loaded.append(load_nerfstudio(_write(root, frames, **_intrinsics(**keys))))
    assert np.array_equal(loaded[0].images, loaded[1].images)
    assert loaded[0].cameras.fx[0] == loaded[1].cameras.fx[0] != F


@pytest.mark.parametrize(
    "meta, frame, message",
    [
        (
            {"camera_model": "EQUIRECTANGULAR"},
            {},
            "camera_model 'EQUIRECTANGULAR' is not supported",
        ),
        ({}, {"camera_model": "OPENCV_FISHEY"}, "frame 0: camera_model 'OPENCV_FISHEY'"),
        ({"camera_model": 3}, {}, "camera_model 3 is not supported"),
        ({"camera_model": "PINHOLE", "k1": 0.1}, {}, "lens distortion 'k1' = 0.1 does not belong"),
        ({"camera_model": "OPENCV_FISHEYE", "p1": 0.01}, {}, "'p1' = 0.01 does not belong"),
        ({"camera_model": "OPENCV", "k4": 0.01}, {}, "'k4' = 0.01 does not belong"),
        ({"k1": float("nan")}, {}, "'k1' must be a finite number"),
        ({"fl_x": float("nan")}, {}, "'fl_x' must be a finite number"),
        ({"k1": 20.0}, {}, "too strong to undistort"),
        ({"camera_model": "OPENCV_FISHEYE", "k1": -1.0}, {}, "too strong to undistort"),
    ],
)
def test_camera_model_errors(tmp_path: Path, meta: dict, frame: dict, message: str):
    root = tmp_path / "ds"
    root.mkdir()
    frames = [_frame(root, "a", _blobs([]), **frame)]
    with pytest.raises(DataError, match=message) as err:
        load_nerfstudio(_write(root, frames, **{**_intrinsics(), **meta}))
    if "is not supported" in message:
        assert "OPENCV_FISHEYE" in str(err.value) and "PINHOLE" in str(err.value)


def test_depth_mask_and_instances_follow_the_photo(tmp_path: Path):
    """Labels, masks and depth of a distorted frame are remapped with the photo's map, by
    nearest neighbour (no new label or depth values)."""
    root = tmp_path / "ds"
    root.mkdir()
    points = _lines().reshape(-1, 3)
    photo = _blobs(_distorted_pixels("OPENCV", OPENCV, points), sigma=1.2)
    labels = (photo[..., 0] > 100).astype(np.uint8) * 7
    write_png(root / "ids.png", labels)
    write_png(root / "mask.png", (labels > 0).astype(np.uint8) * 255)
    np.save(root / "depth.npy", np.where(labels > 0, 1.5, 2.5).astype(np.float32))
    paths = {"instance_path": "ids.png", "mask_path": "mask.png", "depth_file_path": "depth.npy"}
    frames = [_frame(root, "a", photo, **paths)]
    data = load_nerfstudio(_write(root, frames, **_intrinsics(**OPENCV)))
    ids, depth, mask = data.instance_ids[0], data.depth_m[0], data.loss_mask[0]
    assert set(np.unique(ids)) <= {0, 7} and set(np.unique(depth)) <= {0.0, 1.5, 2.5}
    assert np.array_equal(mask, ids > 0) and np.array_equal(depth == 1.5, ids > 0)
    world = points * np.array([1.0, -1.0, -1.0])
    for at in data.cameras.project(0, world)[0] - 0.5:
        assert np.linalg.norm(_centroid((ids == 7).astype(float), at) - at) < 1.0


def test_pixels_the_undistortion_cannot_fill_are_left_out_of_the_loss(tmp_path: Path):
    """A lens whose model folds over near the corners: those pixels show nothing of the
    photo, so the loss mask leaves them out (a pinhole frame beside it keeps every pixel)."""
    root = tmp_path / "ds"
    root.mkdir()
    photo = _blobs([])
    frames = [_frame(root, "pinhole", photo, k1=0.0), _frame(root, "folded", photo)]
    data = load_nerfstudio(_write(root, frames, **_intrinsics(k1=-3.0)))
    assert data.loss_mask is not None and data.loss_mask[0].all()
    assert 0.25 < data.loss_mask[1].mean() < 0.9


@pytest.mark.parametrize(
    "keys, box",
    [
        ({"aabb_scale": 4, "scale": 0.5, "offset": [0.5, 0.5, 0.5]}, [[-4.0] * 3, [4.0] * 3]),
        ({"aabb_scale": 1}, [[-0.5 / 0.33] * 3, [0.5 / 0.33] * 3]),
        (
            {"aabb_scale": 2, "scale": 0.25, "offset": [0.3, 0.5, 0.7]},
            [[-3.2, -4.0, -4.8], [4.8, 4.0, 3.2]],
        ),
        ({"aabb_scale": 1, "scale": 1.0, "offset": 0.0}, [[-0.0] * 3, [1.0] * 3]),
        ({"aabb_scale": 1024, "scale": 1.0}, [[-64.0] * 3, [64.0] * 3]),  # ngp's 128 cap
        ({"aabb_scale": 16, "scene_aabb": [[-1, -1, 0], [1, 1, 1]]}, [[-1, -1, 0], [1, 1, 1]]),
        ({"scale": 0.5}, None),
    ],
)
def test_instant_ngp_scene_box(tmp_path: Path, keys: dict, box):
    """The box instant-ngp uses (cube of side aabb_scale about 0.5 in p * scale + offset),
    in the poses' coordinates; neoedit's own scene_aabb wins."""
    root = tmp_path / "ds"
    root.mkdir()
    data = load_nerfstudio(_write(root, [_frame(root, "a", _blobs([]))], **_intrinsics(), **keys))
    if box is None:
        assert data.scene_aabb_m is None
    else:
        assert np.allclose(data.scene_aabb_m, box)


@pytest.mark.parametrize(
    "keys, message",
    [
        ({"scale": 0}, "'scale' must be positive"),
        ({"scale": -0.33}, "'scale' must be positive"),
        ({"scale": "big"}, "'scale' must be a finite number"),
        ({"aabb_scale": 0}, "'aabb_scale' must be a positive number"),
        ({"aabb_scale": "16"}, "'aabb_scale' must be a finite number"),
        ({"aabb_scale": True}, "'aabb_scale' must be a finite number"),
        ({"offset": [0.5, 0.5]}, "'offset' must be 3 finite numbers"),
        ({"offset": [0.5, 0.5, float("inf")]}, "'offset' must be 3 finite numbers"),
        ({"aabb_scale": 1, "scale": 1e-9}, "give a box beyond"),
        ({"camera_angle_x": 4.0, "fl_x": None}, "'camera_angle_x' must be a field of view"),
    ],
)
def test_instant_ngp_bad_values(tmp_path: Path, keys: dict, message: str):
    root = tmp_path / "ds"
    root.mkdir()
    meta = {k: v for k, v in {**_intrinsics(), **keys}.items() if v is not None}
    with pytest.raises(DataError, match=message):
        load_nerfstudio(_write(root, [_frame(root, "a", _blobs([]))], **meta))


@pytest.mark.parametrize(
    "angles, fx, fy",
    [
        ({"camera_angle_x": 0.8}, 0.5 * W / math.tan(0.4), 0.5 * W / math.tan(0.4)),
        ({"camera_angle_y": 0.7}, 0.5 * H / math.tan(0.35), 0.5 * H / math.tan(0.35)),
        (
            {"camera_angle_x": 0.8, "camera_angle_y": 0.7},
            0.5 * W / math.tan(0.4),
            0.5 * H / math.tan(0.35),
        ),
    ],
)
def test_camera_angle_gives_the_focal_length(tmp_path: Path, angles: dict, fx, fy):
    """instant-ngp / Blender style: no fl_x, fl_y, cx, cy, w, h; the image gives the size."""
    root = tmp_path / "ds"
    root.mkdir()
    data = load_nerfstudio(_write(root, [_frame(root, "a", _blobs([]))], **angles))
    cams = data.cameras
    assert cams.fx[0] == pytest.approx(fx) and cams.fy[0] == pytest.approx(fy)
    assert (cams.cx[0], cams.cy[0], cams.width[0], cams.height[0]) == (W / 2, H / 2, W, H)


def _gappy(root: Path, n: int, missing: list[int], **meta) -> Path:
    root.mkdir()
    frames = [_frame(root, f"f{i:02d}", _blobs([])) for i in range(n)]
    for i in missing:
        (root / f"f{i:02d}.png").unlink()
    return _write(root, frames, **_intrinsics(), **meta)


def test_missing_images_are_listed_in_one_error(tmp_path: Path):
    root = _gappy(tmp_path / "ds", 14, list(range(1, 13)))
    with pytest.raises(DataError) as err:
        load_nerfstudio(root)
    text = str(err.value)
    assert "image not found for 12 of 14 frames" in text and "and 2 more" in text
    assert "1 (f01.png)" in text and "10 (f10.png)" in text and "f11.png" not in text
    assert "--skip-missing" in text and text.count("\n") == 0


def test_skip_missing_loads_the_rest_and_fixes_the_split(tmp_path: Path):
    names = [f"f{i:02d}.png" for i in range(6)]
    split = {"train_filenames": names[:4], "test_filenames": names[4:]}
    root = _gappy(tmp_path / "ds", 6, [1, 4], **split)
    with pytest.warns(UserWarning, match="image not found for 2 of 6 frames"):
        data = load_scene_data(root, DataConfig(skip_missing=True))
    assert data.file_paths == ["f00.png", "f02.png", "f03.png", "f05.png"]
    assert data.split["train"].tolist() == [0, 1, 2] and data.split["test"].tolist() == [3]
    assert len(data.images) == len(data.cameras) == 4


def test_skip_missing_with_every_image_missing_is_an_error(tmp_path: Path):
    root = _gappy(tmp_path / "ds", 2, [0, 1])
    with pytest.raises(DataError, match="no frame is left"):
        load_nerfstudio(root, skip_missing=True)


def _distorted_dataset(root: Path, n: int = 2) -> Path:
    root.mkdir()
    frames = [_frame(root, f"f{i}", _blobs(_distorted_pixels("OPENCV", OPENCV))) for i in range(n)]
    return _write(root, frames, **_intrinsics(**OPENCV))


def test_cache_is_outside_the_dataset_and_reused(tmp_path: Path, cache: Path, monkeypatch):
    root = _distorted_dataset(tmp_path / "ds")
    before = _snapshot(root)
    first = load_nerfstudio(root)
    assert _snapshot(root) == before  # nothing written into the dataset folder
    entries = sorted(cache.iterdir())
    assert len(entries) == 2 and all(p.suffix == ".png" for p in entries)
    assert not any(p.name.startswith(".") for p in cache.iterdir())  # no temporaries left

    def fail(*args, **kwargs):
        raise AssertionError("a cached photo was undistorted again")

    monkeypatch.setattr(und.Rectification, "remap", fail)
    second = load_nerfstudio(root)
    assert sorted(cache.iterdir()) == entries and _snapshot(root) == before
    assert np.array_equal(first.images, second.images)
    assert np.array_equal(first.cameras.fx, second.cameras.fx)


def test_cache_follows_a_changed_photo(tmp_path: Path, cache: Path):
    root = _distorted_dataset(tmp_path / "ds", n=1)
    first = load_nerfstudio(root)
    write_png(root / "f0.png", 255 - _blobs(_distorted_pixels("OPENCV", OPENCV)))
    st = (root / "f0.png").stat()
    os.utime(root / "f0.png", ns=(st.st_atime_ns, st.st_mtime_ns + 10**9))
    second = load_nerfstudio(root)
    assert len(list(cache.iterdir())) == 2
    assert np.abs(first.images.astype(int) + second.images - 255).max() <= 1


def test_cache_inside_the_dataset_is_refused(tmp_path: Path, monkeypatch):
    root = _distorted_dataset(tmp_path / "ds", n=1)
    monkeypatch.setenv(und.CACHE_ENV, str(root / "cache"))
    before = _snapshot(root)
    with pytest.warns(UserWarning, match="it is inside the dataset"):
        data = load_nerfstudio(root)
    assert _snapshot(root) == before and data.images.shape == (1, H, W, 3)


def test_unwritable_cache_still_loads(tmp_path: Path, monkeypatch):
    root = _distorted_dataset(tmp_path / "ds", n=1)
    (tmp_path / "file").write_text("not a folder")
    monkeypatch.setenv(und.CACHE_ENV, str(tmp_path / "file"))
    with pytest.warns(UserWarning, match="cannot write it"):
        data = load_nerfstudio(root)
    _spots(data, 0)


def test_cache_folder_follows_xdg(tmp_path: Path, monkeypatch):
    for var in (und.CACHE_ENV, "NEOEDIT_CACHE"):
        monkeypatch.delenv(var, raising=False)
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "xdg"))
    assert und.cache_folder() == tmp_path / "xdg" / "neoedit" / "undistorted"
    monkeypatch.setenv(und.CACHE_ENV, str(tmp_path / "mine"))
    assert und.cache_folder() == tmp_path / "mine" / "undistorted"

"""neo import colmap|llff: synthetic captures with known geometry (tests/capture_support.py)."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pycolmap
import pytest

from neoedit.cli import main
from neoedit.data import load_scene_data
from neoedit.data.colmap import read_colmap
from neoedit.data.importer import ImportConfig, import_capture
from neoedit.data.llff import read_llff
from neoedit.data.orient import OrientConfig
from neoedit.errors import DataError
from tests import capture_support as cs

N = cs.RING_N


def _centres(data_dir: Path) -> np.ndarray:
    return load_scene_data(data_dir).cameras.camera_to_world[:, :3, 3]


def test_colmap_import_recovers_the_metric_z_up_frame(tmp_path):
    src = cs.colmap_project(tmp_path / "cap")
    orient = OrientConfig(camera_distance_m=cs.TRUE_DISTANCE)
    import_capture(read_colmap(src), tmp_path / "ds", ImportConfig(orient=orient))
    data = load_scene_data(tmp_path / "ds")
    centres = data.cameras.camera_to_world[:, :3, 3]
    # cameras back at their true height and radius around the origin (up to a yaw); the
    # floor fit takes in the can's lowest points, which tilts it by well under a millimetre
    np.testing.assert_allclose(centres[:, 2], cs.HEIGHT, atol=5e-4)
    np.testing.assert_allclose(np.linalg.norm(centres[:, :2], axis=1), cs.RADIUS, atol=5e-4)
    # the relative camera geometry is the true one (a rigid motion about z)
    true = cs.ring_c2w(N)[:, :3, 3]
    dist = lambda c: np.linalg.norm(c[:, None] - c[None], axis=-1)  # noqa: E731
    np.testing.assert_allclose(dist(centres), dist(true), atol=1e-6)  # scale is exact
    # orientations are rigid and the cameras still look at the target (0, 0, 0.05)
    rot = data.cameras.camera_to_world[:, :3, :3]
    np.testing.assert_allclose(
        rot.transpose(0, 2, 1) @ rot, np.broadcast_to(np.eye(3), rot.shape), atol=1e-6
    )
    to_target = cs.TARGET - centres
    forward = -rot[:, :, 2]
    cos = (forward * to_target).sum(1) / np.linalg.norm(to_target, axis=1)
    np.testing.assert_allclose(cos, 1.0, atol=1e-5)
    assert len(data.split["test"]) == 2 and len(data.split["train"]) == N - 2
    box = data.scene_aabb_m
    assert box[0, 2] < 0 < 0.12 < box[1, 2] and box[1, 0] > 0.3


def test_binary_and_text_models_import_the_same(tmp_path):
    src = cs.colmap_project(tmp_path / "cap")
    binary = tmp_path / "bin"
    binary.mkdir()
    pycolmap.Reconstruction(str(src / "sparse" / "0")).write_binary(str(binary))
    a = read_colmap(src)
    b = read_colmap(binary, images=src / "images")
    np.testing.assert_allclose(a.camera_to_world, b.camera_to_world, atol=1e-9)
    np.testing.assert_allclose(a.points, b.points, atol=1e-9)
    assert a.names == b.names and [len(t) for t in a.point_tracks] == [
        len(t) for t in b.point_tracks
    ]


def test_undistortion_puts_a_point_where_the_dataset_camera_projects_it(tmp_path):
    """A blob drawn at the *distorted* projection of a 3-D point must, after import
    (undistortion, downscale, orientation), sit where the dataset's pinhole camera sees it."""
    k1, k2, p1, p2 = -0.12, 0.03, 0.002, -0.001
    src = cs.colmap_project(
        tmp_path / "cap",
        "OPENCV",
        [cs.F, cs.F * 1.01, 161.0, 119.0, k1, k2, p1, p2],
        dist=np.array([k1, k2, p1, p2]),
        images=False,
    )
    k = np.array([[cs.F, 0, 161.0], [0, cs.F * 1.01, 119.0], [0, 0, 1]])
    c2w = cs.ring_c2w(N)
    point = np.array([[0.08, -0.05, 0.02]])
    (src / "images").mkdir()
    yy, xx = np.mgrid[0 : cs.H, 0 : cs.W] + 0.5
    for i in range(N):
        u, v = cs.project(c2w[i], k, np.array([k1, k2, p1, p2]), point)[0]
        blob = 40 + 200 * np.exp(-((xx - u) ** 2 + (yy - v) ** 2) / (2 * 3.0**2))
        cv2.imwrite(
            str(src / "images" / f"{i:04d}.png"), np.repeat(blob[..., None], 3, 2).astype(np.uint8)
        )
    out = tmp_path / "ds"
    report = import_capture(read_colmap(src), out, ImportConfig(max_width=200))
    data = load_scene_data(out)
    assert data.width == 200
    transform = np.asarray(report.orientation.transform)
    p = point @ np.eye(3) * 1.0
    p_model = cs.to_model(p)
    p_new = p_model @ transform[:3, :3].T + transform[:3, 3]
    cams = data.cameras
    for i in range(N):
        w2c = np.linalg.inv(cams.camera_to_world[i])
        q = w2c[:3, :3] @ p_new[0] + w2c[:3, 3]
        u = cams.fx[i] * q[0] / -q[2] + cams.cx[i]
        v = -cams.fy[i] * q[1] / -q[2] + cams.cy[i]
        img = data.images[i, :, :, 0].astype(np.float64) - 40
        weight = np.clip(img - 0.3 * img.max(), 0, None)
        yy2, xx2 = np.mgrid[0 : data.height, 0 : data.width] + 0.5
        cu, cv_ = (weight * xx2).sum() / weight.sum(), (weight * yy2).sum() / weight.sum()
        assert abs(cu - u) < 0.25 and abs(cv_ - v) < 0.25, (i, cu, u, cv_, v)


def test_llff_reads_the_same_poses_as_colmap(tmp_path):
    src = cs.colmap_project(tmp_path / "cap")
    colmap = read_colmap(src)
    rows = []
    for c2w in colmap.camera_to_world:
        down, right, back = -c2w[:3, 1], c2w[:3, 0], c2w[:3, 2]
        mat = np.c_[down, right, back, c2w[:3, 3], [cs.H, cs.W, cs.F]]
        rows.append(np.r_[mat.ravel(), 0.5, 5.0])
    np.save(src / "poses_bounds.npy", np.array(rows))
    llff = read_llff(src)
    np.testing.assert_allclose(llff.camera_to_world, colmap.camera_to_world, atol=1e-12)
    np.testing.assert_allclose(llff.lenses[0].matrix(), colmap.lenses[0].matrix(), atol=1e-9)
    assert main(["import", "llff", str(src), "--out", str(tmp_path / "ds")]) == 0
    assert len(load_scene_data(tmp_path / "ds")) == N
    # LLFF as published: no images/, only downscaled images_N/ folders: the largest is used
    (src / "images").rename(src / "images_4")
    (src / "images_8").mkdir()
    (src / "images_x").mkdir()
    assert read_llff(src).image_dir == src / "images_4"


@pytest.mark.parametrize(
    "damage, message",
    [
        ("no_model", "no COLMAP model found"),
        ("fisheye", "not supported"),
        ("missing_image", "not in"),
        ("corrupt_binary", "cannot read the COLMAP model"),
        ("one_image", "need at least 2"),
    ],
)
def test_malformed_colmap_inputs_fail_clearly(tmp_path, capsys, damage, message):
    src = cs.colmap_project(tmp_path / "cap")
    model = src / "sparse" / "0"
    if damage == "no_model":
        (model / "points3D.txt").unlink()
    elif damage == "fisheye":
        (model / "cameras.txt").write_text(
            f"1 OPENCV_FISHEYE {cs.W} {cs.H} 260 260 160 120 0 0 0 0\n"
        )
    elif damage == "missing_image":
        (src / "images" / "0003.png").unlink()
    elif damage == "corrupt_binary":
        for f in model.iterdir():
            f.unlink()
        for name in ("cameras", "images", "points3D"):
            (model / f"{name}.bin").write_bytes(b"\x07" * 37)
    elif damage == "one_image":
        lines = (model / "images.txt").read_text().splitlines()
        (model / "images.txt").write_text("\n".join(lines[:2]) + "\n")
        (model / "points3D.txt").write_text("")
    assert main(["import", "colmap", str(src), "--out", str(tmp_path / "ds")]) == 2
    assert message in " ".join(capsys.readouterr().err.split())
    assert not (tmp_path / "ds").exists()


@pytest.mark.parametrize(
    "table, message",
    [
        (np.zeros((3, 15)), "expected an (N, 17) array"),
        (np.full((N, 17), np.nan), "non-finite"),
        ("count", "poses but"),
        ("bounds", "near/far"),
        ("text", "not a readable .npy"),
    ],
)
def test_malformed_llff_inputs_fail_clearly(tmp_path, capsys, table, message):
    src = cs.colmap_project(tmp_path / "cap")
    good = []
    for c2w in read_colmap(src).camera_to_world:
        mat = np.c_[-c2w[:3, 1], c2w[:3, 0], c2w[:3, 2], c2w[:3, 3], [cs.H, cs.W, cs.F]]
        good.append(np.r_[mat.ravel(), 0.5, 5.0])
    good = np.array(good)
    if isinstance(table, np.ndarray):
        np.save(src / "poses_bounds.npy", table)
    elif table == "count":
        np.save(src / "poses_bounds.npy", good[:-1])
    elif table == "bounds":
        good[:, 15] = 6.0
        np.save(src / "poses_bounds.npy", good)
    else:
        (src / "poses_bounds.npy").write_text("not numpy")
    with pytest.raises(DataError, match=message.replace("(", r"\(").replace(")", r"\)")):
        read_llff(src)
    assert main(["import", "llff", str(src), "--out", str(tmp_path / "ds")]) == 2
    assert message in " ".join(capsys.readouterr().err.split())


def test_import_never_replaces_a_folder_it_did_not_write(tmp_path, capsys):
    src = cs.colmap_project(tmp_path / "cap")
    mine = tmp_path / "mine"
    mine.mkdir()
    (mine / "notes.txt").write_text("keep me")
    assert main(["import", "colmap", str(src), "--out", str(mine), "--overwrite"]) == 2
    assert (mine / "notes.txt").read_text() == "keep me"
    assert main(["import", "colmap", str(src), "--out", str(tmp_path / "ds")]) == 0
    assert main(["import", "colmap", str(src), "--out", str(tmp_path / "ds")]) == 2
    assert main(["import", "colmap", str(src), "--out", str(tmp_path / "ds"), "--overwrite"]) == 0
    assert main(["import", "colmap", str(src), "--out", str(src / "images")]) == 2


def _arc_photos(folder: Path, n: int = 20) -> np.ndarray:
    """``n`` photos of the textured floor over a 90 degree arc; their true camera-to-world."""
    folder.mkdir(parents=True)
    c2w = cs.ring_c2w(n, arc_deg=90)
    tex = cs.floor_texture()
    for i in range(n):
        cv2.imwrite(str(folder / f"{i:04d}.jpg"), cs.render_floor(c2w[i], cs.pinhole_k(), tex))
    return c2w


def _assert_true_cameras(out: Path) -> None:
    """The imported cameras stand at their true height and distance, with the true focal."""
    data = load_scene_data(out)
    centres = data.cameras.camera_to_world[:, :3, 3]
    np.testing.assert_allclose(centres[:, 2], cs.HEIGHT, atol=0.005)
    np.testing.assert_allclose(np.linalg.norm(centres[:, :2], axis=1), cs.RADIUS, atol=0.005)
    np.testing.assert_allclose(data.cameras.fx, cs.F, rtol=0.01)


def test_process_recovers_the_cameras_from_the_photos_alone(tmp_path, capsys):
    """Structure-from-motion (pycolmap, CPU) on rendered photos: the global mapper's model,
    consistent, is kept without a second mapper (the incremental one: the next test)."""
    _arc_photos(tmp_path / "photos")
    out = tmp_path / "ds"
    args = ["process", str(tmp_path / "photos"), "--out", str(out)]
    assert main([*args, "--orient.camera-distance-m", str(cs.TRUE_DISTANCE)]) == 0
    said = " ".join(capsys.readouterr().out.split())
    assert "(global mapper): 20 of 20 photos registered" in said
    assert "mappers tried" not in said  # the global model was consistent: no second mapper
    _assert_true_cameras(out)
    assert (out / "colmap" / "sparse" / "0" / "images.bin").is_file()
    assert not [p for p in tmp_path.iterdir() if ".sfm-" in p.name]  # work folder removed
    meta = json.loads((out / "transforms.json").read_text())
    assert meta["neoedit_import"]["source"] == str(tmp_path / "photos")  # not the work folder


def _poses(model: Path) -> dict:
    rec = pycolmap.Reconstruction(str(model))
    return {im.name: im.cam_from_world().translation for im in rec.images.values()}


def test_process_maps_incrementally_too_when_the_global_model_breaks(tmp_path, capsys, monkeypatch):
    """'auto' keeps the global model unless the consistency check breaks it; then the
    incremental mapper runs as well and the model with the larger consistent piece is the
    one the dataset gets."""
    from neoedit.data import sfm

    _arc_photos(tmp_path / "photos")
    check, seen = sfm._consistent_pieces, {}

    def global_breaks(result, progress):  # noqa: ANN001, ANN202
        pieces = check(result, progress)
        seen[result.mapper] = _poses(result.model)
        if result.mapper == "global":
            return np.array_split(np.concatenate(pieces), 2)  # as if broken in two
        return pieces

    monkeypatch.setattr(sfm, "_consistent_pieces", global_breaks)
    threads: dict[str, list[int]] = {}  # what COLMAP is told: --threads, at every stage

    def recording(name: str):  # noqa: ANN202
        real = getattr(pycolmap, name)

        def call(*args, **kwargs):  # noqa: ANN002, ANN003, ANN202
            options = [a for a in (*args, *kwargs.values()) if hasattr(a, "num_threads")]
            threads[name] = [o.num_threads for o in options]
            return real(*args, **kwargs)

        monkeypatch.setattr(pycolmap, name, call)

    stages = ("extract_features", "match_exhaustive", "global_mapping", "incremental_mapping")
    for name in stages:
        recording(name)
    args = ["process", str(tmp_path / "photos"), "--out", str(tmp_path / "ds"), "--threads", "1"]
    assert main([*args, "--orient.camera-distance-m", str(cs.TRUE_DISTANCE)]) == 0
    assert set(threads) == set(stages) and all(
        threads[s] and set(threads[s]) == {1} for s in stages
    )
    said = " ".join(capsys.readouterr().out.split())
    assert "global: 20 of 20 photos registered, broken into 2 pieces" in said
    assert "incremental: 20 of 20 photos registered, one consistent piece" in said
    assert "(incremental mapper)" in said
    kept = _poses(tmp_path / "ds" / "colmap" / "sparse" / "0")
    for name, t in kept.items():  # the dataset's model is the incremental one
        np.testing.assert_allclose(t, seen["incremental"][name])
    assert not all(np.allclose(t, seen["global"][n]) for n, t in kept.items())
    _assert_true_cameras(tmp_path / "ds")  # and the incremental mapper got them right


def test_process_maps_incrementally_when_the_global_mapper_fails(tmp_path, capsys, monkeypatch):
    from neoedit.data import sfm

    _arc_photos(tmp_path / "photos", n=12)
    run = sfm._run_mapper

    def global_fails(pycolmap, mapper, *args):  # noqa: ANN001, ANN202
        if mapper == "global":
            raise RuntimeError("Check failed: view graph")  # as COLMAP reports a failed check
        return run(pycolmap, mapper, *args)

    monkeypatch.setattr(sfm, "_run_mapper", global_fails)
    assert main(["process", str(tmp_path / "photos"), "--out", str(tmp_path / "ds")]) == 0
    said = " ".join(capsys.readouterr().out.split())
    assert "global: failed (Check failed: view graph)" in said
    assert "(incremental mapper): 12 of 12 photos registered" in said
    args = ["process", str(tmp_path / "photos"), "--out", str(tmp_path / "d2")]
    assert main([*args, "--sfm.mapper", "global"]) == 2  # asked for by name: no fallback
    assert "structure-from-motion failed" in " ".join(capsys.readouterr().err.split())
    assert not (tmp_path / "d2").exists()


def test_process_says_clearly_when_too_few_photos_register(tmp_path, capsys):
    photos = tmp_path / "photos"
    _arc_photos(photos, n=8)
    rng = np.random.default_rng(0)
    for i in range(9):  # photos of nothing the others show: they cannot register
        noise = rng.integers(0, 255, (240, 320, 3), dtype=np.uint8)
        cv2.imwrite(str(photos / f"{100 + i:04d}.jpg"), cv2.GaussianBlur(noise, (5, 5), 0))
    assert main(["process", str(photos), "--out", str(tmp_path / "ds")]) == 2
    assert "registered only 8 of 17" in " ".join(capsys.readouterr().err.split())
    assert not (tmp_path / "ds").exists()
    assert main(["process", str(photos), "--out", str(tmp_path / "ds"), "--sfm.mapper", "x"]) == 2
    assert "--sfm.mapper must be one of auto, global, incremental" in capsys.readouterr().err
    assert not (tmp_path / "ds").exists()
    assert main(["process", str(tmp_path / "nothing"), "--out", str(tmp_path / "ds")]) == 2


MARKERS = [(-0.1, -0.1), (0.1, -0.1), (0.1, 0.1), (-0.1, 0.1)]
MARKER_SIDE = 0.08


def _marker_capture(root: Path, c2w: np.ndarray, model: np.ndarray) -> Path:
    """A COLMAP project of a floor with four ArUco markers, photographed from ``c2w``."""
    pts = cs.scene_points()
    k = cs.pinhole_k()
    tracks = cs.tracks_for(c2w, pts, k, np.zeros(4))
    cs.write_colmap_text(
        root / "sparse" / "0", cs.to_model(c2w, model), cs.to_model(pts, model), tracks
    )
    (root / "images").mkdir(parents=True)
    tex = cs.marker_texture(MARKER_SIDE, MARKERS)
    for i, pose in enumerate(c2w):
        image = cs.render_floor(pose, k, tex, supersample=4)
        cv2.imwrite(str(root / "images" / f"{i:04d}.png"), image)
    return root


def _pose_errors(got: np.ndarray, true: np.ndarray) -> tuple[float, float]:
    """Largest camera-centre distance [m] and rotation difference [deg]."""
    dist = np.linalg.norm(got[:, :3, 3] - true[:, :3, 3], axis=1).max()
    rel = got[:, :3, :3].transpose(0, 2, 1) @ true[:, :3, :3]
    cos = np.clip((np.trace(rel, axis1=1, axis2=2) - 1) / 2, -1, 1)
    return float(dist), float(np.degrees(np.arccos(cos)).max())


def test_aruco_markers_give_the_metric_table_frame(tmp_path):
    """The markers' frame (origin at their centre, z up, x along marker 0's first edge) is
    the world frame here: the imported cameras must be the true ones."""
    true = cs.ring_c2w(12, radius=0.35, height=0.45)
    src = _marker_capture(tmp_path / "cap", true, cs.MODEL)
    orient = OrientConfig(aruco_size_m=MARKER_SIDE)
    report = import_capture(read_colmap(src), tmp_path / "ds", ImportConfig(orient=orient))
    got = load_scene_data(tmp_path / "ds").cameras.camera_to_world
    dist, angle = _pose_errors(got, true)
    assert dist < 0.005 and angle < 0.5, (dist, angle)
    scale_error = report.orientation.scale * cs.MODEL_SCALE - 1.0
    assert abs(scale_error) < 0.005, scale_error


def test_register_moves_a_later_scan_into_the_earlier_frame(tmp_path, capsys):
    pre_true = cs.ring_c2w(12, radius=0.35, height=0.45)
    post_true = cs.ring_c2w(10, arc_deg=300, radius=0.4, height=0.4)
    other = np.eye(4)
    other[:3, :3] = 0.4 * cs.Rotation.from_euler("zyx", [120, 30, -10], degrees=True).as_matrix()
    other[:3, 3] = [-3.0, 1.0, 2.0]
    pre = _marker_capture(tmp_path / "pre_cap", pre_true, cs.MODEL)
    post = _marker_capture(tmp_path / "post_cap", post_true, other)
    aruco = ["--orient.aruco-size-m", str(MARKER_SIDE)]
    assert main(["import", "colmap", str(pre), "--out", str(tmp_path / "pre"), *aruco]) == 0
    assert main(["import", "colmap", str(post), "--out", str(tmp_path / "post")]) == 0
    args = ["register", str(tmp_path / "pre"), str(tmp_path / "post"), "--out"]
    assert main([*args, str(tmp_path / "reg")]) == 0
    assert "corner residual" in capsys.readouterr().out
    got = load_scene_data(tmp_path / "reg").cameras.camera_to_world
    dist, angle = _pose_errors(got, post_true)
    assert dist < 0.005 and angle < 0.5, (dist, angle)
    # a scan without markers cannot be registered: one clear error, nothing written
    plain = cs.colmap_project(tmp_path / "plain_cap")
    assert main(["import", "colmap", str(plain), "--out", str(tmp_path / "plain")]) == 0
    assert (
        main(
            [
                "register",
                str(tmp_path / "pre"),
                str(tmp_path / "plain"),
                "--out",
                str(tmp_path / "reg2"),
            ]
        )
        == 2
    )
    assert "2 or more ArUco markers" in " ".join(capsys.readouterr().err.split())
    assert not (tmp_path / "reg2").exists()


@pytest.mark.parametrize(
    "option",
    [
        ["--piece", "banana"],
        ["--holdout-every", "1"],
        ["--orient.scale", "-2"],
        ["--sparse-depth-min-track", "1"],
    ],
)
def test_bad_options_are_refused_before_structure_from_motion(tmp_path, capsys, option):
    """``neo process`` checks its options before the photos are even read."""
    photos = tmp_path / "photos"
    photos.mkdir()  # empty: any work on it would fail with another message
    assert main(["process", str(photos), "--out", str(tmp_path / "ds"), *option]) == 2
    err = " ".join(capsys.readouterr().err.split())
    assert option[0] in err and "photos" not in err
    assert not (tmp_path / "ds").exists()


def test_sparse_depth_puts_the_sfm_points_on_the_training_rays(tmp_path, capsys):
    """Each photo's depth image holds its observed sparse points: the ray the trainer casts
    through such a pixel, at that z-depth, lands on a true scene point (within half the
    pixel's footprint), through the undistortion and the downscale; the rest of the image
    is 0 (no depth), and ``neo info`` calls it sparse."""
    import torch

    from neoedit.cameras.rays import CameraTensors

    k1, k2, p1, p2 = -0.12, 0.03, 0.002, -0.001
    params = [cs.F, cs.F * 1.01, 161.0, 119.0, k1, k2, p1, p2]
    src = cs.colmap_project(tmp_path / "cap", "OPENCV", params, dist=np.array([k1, k2, p1, p2]))
    orient = OrientConfig(camera_distance_m=cs.TRUE_DISTANCE)
    cfg = ImportConfig(orient=orient, max_width=200)
    report = import_capture(read_colmap(src), tmp_path / "ds", cfg)
    data = load_scene_data(tmp_path / "ds")
    assert data.depth_m is not None and 0 < (data.depth_m > 0).mean() < 0.05
    transform = np.asarray(report.orientation.transform)
    truth = cs.to_model(cs.scene_points()) @ transform[:3, :3].T + transform[:3, 3]
    cams = CameraTensors(data.cameras)
    hits = 0
    for i in range(len(data)):
        v, u = np.nonzero(data.depth_m[i])
        hits += len(v)
        z = data.depth_m[i][v, u]
        rays = cams.rays(torch.full((len(v),), i), torch.as_tensor(v), torch.as_tensor(u))
        at = rays.origins + rays.directions * torch.as_tensor(z)[:, None] / rays.z_scale[:, None]
        gap = np.linalg.norm(at.numpy()[:, None] - truth[None], axis=-1).min(1)
        # the pixel centre is at most 0.71 px from where the point projects
        footprint = 0.75 * z / data.cameras.fx[i] + 1e-3  # + the PNG's 1 mm step
        assert np.all(gap < footprint), (i, gap.max())
    assert hits > 0.5 * len(truth)  # most points land in several photos
    main(["info", str(tmp_path / "ds")])
    assert "depth: sparse" in capsys.readouterr().out
    # stricter tracks keep fewer points; none left (or --no-sparse-depth): no depth at all
    strict = import_capture(
        read_colmap(src), tmp_path / "strict", ImportConfig(orient=orient, sparse_depth_min_track=8)
    )
    assert 0 < strict.sparse_depth["points"] < report.sparse_depth["points"]
    for name, cfg in (
        ("none", ImportConfig(orient=orient, sparse_depth_min_track=N + 1)),
        ("plain", ImportConfig(orient=orient, sparse_depth=False)),
    ):
        assert import_capture(read_colmap(src), tmp_path / name, cfg).sparse_depth is None
        assert load_scene_data(tmp_path / name).depth_m is None
        assert not (tmp_path / name / "depth").exists()


def test_sparse_depth_image_keeps_the_nearest_point_and_round_trips_the_png(tmp_path):
    from neoedit.cameras.cameras import look_at
    from neoedit.data.images import read_depth_m
    from neoedit.data.sparse_depth import depth_unit, sparse_depth_image, to_png

    c2w = look_at(np.array([0.0, -1.0, 0.0]), np.zeros(3))  # looks along +y at the origin
    k = np.array([[100.0, 0, 16.5], [0, 100.0, 12.5], [0, 0, 1]])  # pixel centres
    # two points on the optical axis (the nearer wins), one to the right, one above, and one
    # behind the camera
    pts = np.array([[0, 0, 0.0], [0, -0.5, 0], [0.05, 0, 0], [0, 0, 0.03], [0, -2.0, 0]])
    depth = sparse_depth_image(pts, c2w, k, (32, 24))
    assert depth[12, 16] == pytest.approx(0.5)
    assert depth[12, 21] == pytest.approx(1.0)  # +x is right in the image: u grows
    assert depth[9, 16] == pytest.approx(1.0)  # +z (up) is up in the image: v shrinks
    assert (depth > 0).sum() == 3  # the point behind the camera is left out
    far = sparse_depth_image(pts, c2w, k, (32, 24), min_depth=0.8)
    assert (far > 0).sum() == 3 and far[12, 16] == pytest.approx(1.0)  # 0.5 m: too near
    unit = depth_unit(6.0)
    assert unit == pytest.approx(1e-3) and depth_unit(100.0) == pytest.approx(1e-2)
    png = to_png(depth, unit)
    assert png.dtype == np.uint16 and (png > 0).sum() == 3
    path = tmp_path / "d.png"
    cv2.imwrite(str(path), png)
    np.testing.assert_allclose(read_depth_m(path, unit), depth, atol=unit / 2)


def _forward_facing(root: Path, shrink: int = 4) -> np.ndarray:
    """An LLFF capture the way LLFF is shot: 3x3 photos from a hand moved in a plane across
    the view, every camera looking the same way, down at a textured floor (320x240 px
    divided by ``shrink``)."""
    from neoedit.cameras.cameras import look_at

    ahead = np.array([0.0, 0.4, -0.3])  # 37 deg below the horizon, over the floor
    across = [np.array([1.0, 0.0, 0.0]), np.cross(ahead / np.linalg.norm(ahead), [1.0, 0, 0])]
    eyes = [
        np.array([0.0, -0.4, 0.3]) + a * across[0] + b * across[1]
        for a in (-0.05, 0.0, 0.05)
        for b in (-0.03, 0.0, 0.03)
    ]
    c2w = np.stack([look_at(e, e + ahead) for e in eyes])
    k = cs.pinhole_k()
    (root / "images").mkdir(parents=True)
    tex = cs.floor_texture(size=512)
    rows = []
    for i, pose in enumerate(c2w):
        image = cv2.resize(
            cs.render_floor(pose, k, tex, supersample=2), (cs.W // shrink, cs.H // shrink),
            interpolation=cv2.INTER_AREA,
        )  # fmt: skip
        cv2.imwrite(str(root / "images" / f"{i:04d}.png"), image)
        down, right, back = -pose[:3, 1], pose[:3, 0], pose[:3, 2]
        mat = np.c_[down, right, back, pose[:3, 3], [cs.H // shrink, cs.W // shrink, cs.F / shrink]]
        rows.append(np.r_[mat.ravel(), 0.3, 1.5])
    np.save(root / "poses_bounds.npy", np.array(rows))
    return c2w


def test_a_forward_facing_llff_capture_imports_and_trains(tmp_path):
    """Forward-facing (LLFF-style) photos: no sparse points, the cameras' axes parallel.
    The import finds a scene in front of them and a box holding what they see, and the
    field trains to held-out photos it never saw."""
    from neoedit.eval.evaluate import render_views
    from neoedit.eval.metrics import psnr
    from tests.conftest import tiny_train

    _forward_facing(tmp_path / "cap")
    args = ["import", "llff", str(tmp_path / "cap"), "--out", str(tmp_path / "ds")]
    assert main([*args, "--no-triangulate"]) == 0
    data = load_scene_data(tmp_path / "ds")
    assert data.depth_m is None and len(data.split["test"]) == 2
    # the box holds the point every camera looks at (0.5 m ahead: the assumed distance)
    c2w = data.cameras.camera_to_world
    looked_at = c2w[:, :3, 3] - 0.5 * c2w[:, :3, 2]
    box = data.scene_aabb_m
    assert np.all((looked_at > box[0]) & (looked_at < box[1]))
    scene = tiny_train(tmp_path / "ds", tmp_path / "scene", steps=300)
    test = list(data.split["test"])
    renders = render_views(scene, data, test)
    truth = [data.images[i] / 255.0 for i in test]
    held_out = np.mean([psnr(r["rgb"], t) for r, t in zip(renders, truth, strict=True)])
    flat = np.mean([psnr(np.broadcast_to(t.reshape(-1, 3).mean(0), t.shape), t) for t in truth])
    # measured: 26.9 dB held out, 18.2 dB for the flat-colour guess
    assert held_out > flat + 5.0, (held_out, flat)


def test_a_forward_facing_capture_is_levelled_on_the_points_it_triangulates(tmp_path):
    """LLFF gives poses and no points: without points up is the cameras' mean up axis, which
    tilts back by how far the photos look down (37 deg here). The import triangulates points
    at the known poses (by default), levels the scene on the floor they lie on and, asked
    to, writes their depths."""
    _forward_facing(tmp_path / "cap", shrink=1)
    args = ["import", "llff", str(tmp_path / "cap")]
    for name, extra in (("plain", ["--no-triangulate"]), ("points", ["--sparse-depth"])):
        assert main([*args, "--out", str(tmp_path / name), *extra]) == 0
    plain, levelled = load_scene_data(tmp_path / "plain"), load_scene_data(tmp_path / "points")

    def looks_down_deg(data) -> float:
        view = -data.cameras.camera_to_world[:, :3, 2].mean(0)
        return float(np.degrees(np.arcsin(-view[2] / np.linalg.norm(view))))

    assert abs(looks_down_deg(plain)) < 2.0  # up = the cameras' up: the view is "level"
    # as they were shot, to the plane fit of points from a 10 cm baseline (measured 33.6)
    assert looks_down_deg(levelled) == pytest.approx(36.9, abs=4.0)
    assert plain.depth_m is None and levelled.depth_m is not None
    seen = levelled.depth_m[levelled.depth_m > 0]
    assert len(seen) > 200  # sparse depth of the floor, every photo


def test_a_failed_triangulation_leaves_the_cameras_up(tmp_path, monkeypatch, capsys):
    """Photos without features to triangulate: the LLFF import warns and goes on with the
    cameras' mean up instead of refusing a capture whose poses are fine."""
    import neoedit.data.triangulate as tri
    from neoedit.errors import DataError

    def fails(capture, work, cfg=None):
        raise DataError(f"triangulation failed on {capture.image_dir}: no matches")

    monkeypatch.setattr(tri, "triangulate", fails)
    _forward_facing(tmp_path / "cap")
    assert main(["import", "llff", str(tmp_path / "cap"), "--out", str(tmp_path / "ds")]) == 0
    assert "no matches; up is the cameras' mean up" in " ".join(capsys.readouterr().err.split())
    meta = json.loads((tmp_path / "ds" / "transforms.json").read_text())
    assert meta["neoedit_import"]["orientation"]["up_source"].startswith("mean camera up")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["cap", "ds"]  # no work folder left
    assert not (tmp_path / "ds" / "depth").exists()


@pytest.mark.parametrize("content", ["bounds", "points"])
@pytest.mark.parametrize(("meet", "expected"), [(0.1, 0.3), (0.8, 0.8), (3.0, 1.5)])
def test_a_forward_facing_look_centre_lies_where_the_photos_see_something(meet, expected, content):
    """Nearly parallel optical axes of a forward-facing capture meet wherever the hand's toe-in
    puts them (spinnerf_1's: a third of the way to the nearest thing seen): the look centre
    (and so the scale and the scene box) is moved along the view into the depth range of the
    content — the LLFF bounds, or for photos processed by SfM (no bounds) the sparse points'
    5th..95th depth percentiles — and kept where it lies when it is inside it."""
    from neoedit.cameras.cameras import look_at
    from neoedit.data.capture import Capture
    from neoedit.data.orient import look_centre

    target = np.array([0.0, meet, 0.0])
    # views within 14 degrees of each other even when they meet at 0.1 (forward-facing)
    eyes = [np.array([x, 0.0, z]) for x in (-0.02, 0.0, 0.02) for z in (-0.015, 0.0, 0.015)]
    c2w = np.stack([look_at(e, target) for e in eyes])
    rng = np.random.default_rng(0)
    seen = np.linspace(0.3, 1.5, 101)  # depths straight ahead: 5th..95th percentile 0.36..1.44
    capture = Capture(
        source=Path("cap"),
        names=[f"{i}.png" for i in range(len(eyes))],
        image_dir=Path("cap"),
        camera_to_world=c2w,
        lenses=[],
        bounds=np.tile([0.3, 1.5], (len(eyes), 1)) if content == "bounds" else None,
        points=np.stack([rng.uniform(-0.2, 0.2, 101), seen, rng.uniform(-0.2, 0.2, 101)], 1),
    )
    centre = look_centre(capture)
    assert abs(centre[0]) < 1e-6 and abs(centre[2]) < 1e-6  # straight ahead of the cameras
    if content == "points" and expected != meet:
        expected = float(np.percentile(seen, 5 if meet < expected else 95))
    assert centre[1] == pytest.approx(expected, abs=1e-3)


@pytest.mark.parametrize(
    ("arc_deg", "down_deg", "spread"),
    [(360, 22, 2.0), (360, 70, 0.03), (90, 30, 0.03), (120, 45, 0.03), (180, 60, 0.03)],
)
def test_a_ring_look_centre_is_where_the_axes_meet_whatever_the_points(arc_deg, down_deg, spread):
    """Around an object the optical axes meet at it: the content test is for forward-facing
    captures only — not for rings or arcs, however steeply they look down, nor for a small
    object whose points all lie nearer than the cameras' own distance."""
    from neoedit.cameras.cameras import look_at
    from neoedit.data.capture import Capture
    from neoedit.data.orient import look_centre

    target = np.array([0.1, -0.2, 0.05])
    angles = np.radians(np.linspace(0, arc_deg, 12, endpoint=arc_deg < 360))
    down = np.radians(down_deg)
    eyes = target + np.stack(
        [np.cos(angles) * np.cos(down), np.sin(angles) * np.cos(down), np.full(12, np.sin(down))],
        1,
    )
    capture = Capture(
        source=Path("cap"),
        names=[f"{i}.png" for i in range(12)],
        image_dir=Path("cap"),
        camera_to_world=np.stack([look_at(e, target) for e in eyes]),
        lenses=[],
        points=target + np.random.default_rng(0).normal(0, spread, (200, 3)),
    )
    np.testing.assert_allclose(look_centre(capture), target, atol=1e-6)


def test_a_moved_copy_forgets_how_its_old_frame_was_levelled(sim_root: Path, tmp_path: Path):
    """`neo register` writes the scan moved into another frame: the import's note that its
    +z is a measured up (which the query trusts) describes the old frame and is dropped."""
    import shutil

    from neoedit.data.orient import levelled_at_import
    from neoedit.data.register import write_moved

    src = tmp_path / "src"
    shutil.copytree(sim_root / "removal_1" / "pre", src)
    meta = json.loads((src / "transforms.json").read_text())
    meta["neoedit_import"] = {
        "photos": 13,
        "orientation": {"up_source": "support plane of the sparse points"},
    }
    (src / "transforms.json").write_text(json.dumps(meta))
    assert levelled_at_import(meta)
    tilt = np.eye(4)
    tilt[:3, :3] = [[1.0, 0.0, 0.0], [0.0, 0.8, -0.6], [0.0, 0.6, 0.8]]
    write_moved(src, tilt, tmp_path / "moved")
    moved = json.loads((tmp_path / "moved" / "transforms.json").read_text())
    assert moved["neoedit_import"] == {"photos": 13}
    assert not levelled_at_import(moved)

"""Camera pose refinement (issue 38): the rotation and its pose correction against brute-force
references, the hash grid's gradient with respect to its points against autograd and finite
differences, the corrections stored with the scan and applied by every reader of its
cameras, and a training that pulls a mis-posed photo back toward its true pose."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np
import pytest
import torch
from scipy.spatial.transform import Rotation

from neoedit.cameras.pose_correction import corrected_poses, so3_exp
from neoedit.cameras.rays import RayBundle
from neoedit.errors import NeoError
from neoedit.fields.hashgrid import HashGridConfig, HashGridEncoding, encode_torch
from neoedit.training.camera_opt import PoseRefinement
from tests.test_conventions_train import _write  # the textured-floor ring capture


def test_so3_exp_is_scipys_rotation_at_every_angle():
    rng = np.random.default_rng(0)
    axes = rng.normal(size=(200, 3))
    axes /= np.linalg.norm(axes, axis=1, keepdims=True)
    angles = np.concatenate([[0.0, 1e-9, 1e-5, 1e-3], rng.uniform(0, np.pi, 196)])
    w = axes * angles[:, None]
    ours = so3_exp(torch.as_tensor(w)).numpy()
    assert np.allclose(ours, Rotation.from_rotvec(w).as_matrix(), atol=1e-9)
    # and its gradient is finite at zero (every correction starts there)
    zero = torch.zeros(3, 3, dtype=torch.float64, requires_grad=True)
    so3_exp(zero).sum().backward()
    assert torch.isfinite(zero.grad).all()


def test_a_correction_turns_the_camera_about_its_centre_and_shifts_it():
    c2w = np.stack([np.eye(4), np.eye(4)])
    c2w[1, :3, 3] = [0.3, -0.2, 1.0]
    fix = np.array([[0, 0, 0, 0, 0, 0], [0.0, 0.0, np.pi / 2, 0.01, 0.0, -0.02]])
    out = corrected_poses(c2w, fix)
    assert np.allclose(out[0], c2w[0])
    assert np.allclose(out[1, :3, :3], Rotation.from_rotvec([0, 0, np.pi / 2]).as_matrix())
    assert np.allclose(out[1, :3, 3], [0.31, -0.2, 0.98])  # the centre moves by t only
    # rays: zero corrections change nothing; a correction turns directions, shifts origins
    rays = RayBundle(
        torch.rand(5, 3), torch.nn.functional.normalize(torch.rand(5, 3)), torch.ones(5)
    )
    poses = PoseRefinement(2, 1e-3, torch.device("cpu"))
    same = poses.apply(rays, torch.zeros(5, dtype=torch.long))
    assert torch.equal(same.origins, rays.origins)
    assert torch.allclose(same.directions, rays.directions)
    with torch.no_grad():
        poses.params[1] = torch.as_tensor(fix[1]).float()
    moved = poses.apply(rays, torch.ones(5, dtype=torch.long))
    rot = torch.as_tensor(Rotation.from_rotvec([0, 0, np.pi / 2]).as_matrix()).float()
    assert torch.allclose(moved.directions, rays.directions @ rot.T, atol=1e-6)
    assert torch.allclose(
        moved.origins - rays.origins, torch.tensor(fix[1, 3:]).float().expand(5, 3)
    )


@pytest.mark.parametrize("levels, log2_size, max_res", [(4, 10, 64), (8, 14, 512)])
def test_hashgrid_point_gradient_is_the_reference_one(levels, log2_size, max_res):
    """The compiled kernel's gradient with respect to the points equals autograd through the
    PyTorch encoding (dense and hashed levels; coordinates outside [0, 1] clamped, so their
    gradient is zero axis by axis), and finite differences of it."""
    cfg = HashGridConfig(
        n_levels=levels, log2_hashmap_size=log2_size, max_resolution=max_res, backend="numba"
    )
    enc = HashGridEncoding(cfg)
    gen = torch.Generator().manual_seed(1)
    with torch.no_grad():
        enc.table.uniform_(-1, 1, generator=gen)
    x = (torch.rand(400, 3, generator=gen) * 1.1 - 0.05).requires_grad_(True)
    weights = torch.randn(400, enc.output_dim, generator=gen)
    (enc(x) * weights).sum().backward()
    ours, x.grad = x.grad.clone(), None
    (encode_torch(x, enc.table, enc.resolutions) * weights).sum().backward()
    scale = x.grad.abs().max()
    assert (ours - x.grad).abs().max() < 1e-4 * scale
    assert (ours[(x < 0) | (x > 1)] == 0).all() and (ours != 0).float().mean() > 0.8

    table = enc.table.detach().double()

    def value(p: torch.Tensor) -> float:  # in float64 throughout
        return float((encode_torch(p, table, enc.resolutions) * weights[:1].double()).sum())

    point, eps = torch.tensor([[0.4113, 0.2871, 0.6352]], dtype=torch.float64), 1e-7
    probe = point.float().requires_grad_(True)
    (enc(probe) * weights[:1]).sum().backward()
    for axis in range(3):
        step = torch.zeros(1, 3, dtype=torch.float64)
        step[0, axis] = eps
        numeric = (value(point + step) - value(point - step)) / (2 * eps)
        assert abs(float(probe.grad[0, axis]) - numeric) < 1e-3 * max(1.0, abs(numeric))


def test_corrections_are_stored_with_the_scan_and_applied_on_load(tmp_path: Path):
    from neoedit.data.scan import scan_from_record, scan_record
    from neoedit.data.validate import check_scan_record
    from neoedit.errors import DataError

    _write(tmp_path / "ds", "PINHOLE")
    from neoedit.data import load_scene_data

    data = load_scene_data(tmp_path / "ds")
    record = scan_record(data.cameras, data.file_paths, data.split)
    fixes = np.zeros((len(data.cameras), 6))
    fixes[3] = [0.01, -0.02, 0.005, 0.003, 0.0, -0.001]
    record["pose_corrections"] = fixes.tolist()
    check_scan_record(record, "scene.json")
    cams, _, _ = scan_from_record(record)
    raw, _, _ = scan_from_record(record, corrected=False)
    assert np.allclose(raw.camera_to_world, data.cameras.camera_to_world)
    assert np.allclose(cams.camera_to_world, corrected_poses(data.cameras.camera_to_world, fixes))
    assert not np.allclose(cams.camera_to_world[3], raw.camera_to_world[3])
    assert np.allclose(np.delete(cams.camera_to_world, 3, 0), np.delete(raw.camera_to_world, 3, 0))
    for bad in (fixes[:-1].tolist(), [[float("nan")] * 6] * len(fixes), "x"):
        with pytest.raises(DataError, match="pose_corrections"):
            check_scan_record({**record, "pose_corrections": bad}, "scene.json")
    with pytest.raises(NeoError, match="pose_corrections"):
        scan_from_record({**record, "pose_corrections": fixes[:-1].tolist()})


@pytest.fixture(scope="module")
def mis_posed(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, np.ndarray]:
    """A 128x96 NEO-Sim removal scan (24 training photos) whose training poses are turned
    1.5 degrees about their centres (random axes, as structure from motion errs); the true
    poses."""
    from neoedit.sim.run import simulate_scene
    from neoedit.sim.spec import ScanSpec
    from tests.conftest import tiny_scene

    tmp = tmp_path_factory.mktemp("mis_posed")
    spec = dataclasses.replace(
        tiny_scene("removal_1"), scan=ScanSpec(width=128, height=96, n_train=24, n_eval=3)
    )
    simulate_scene(spec, tmp / "sim")
    meta = json.loads((tmp / "sim" / "pre" / "transforms.json").read_text())
    rng = np.random.default_rng(0)
    truth = []
    for frame in meta["frames"]:
        true = np.array(frame["transform_matrix"])
        truth.append(true)
        if frame["file_path"] in meta["train_filenames"]:
            axis = rng.normal(size=3)
            fix = np.r_[np.deg2rad(1.5) * axis / np.linalg.norm(axis), np.zeros(3)]
            frame["transform_matrix"] = corrected_poses(true[None], fix[None])[0].tolist()
    (tmp / "sim" / "pre" / "transforms.json").write_text(json.dumps(meta))
    return tmp / "sim" / "pre", np.array(truth)


def _angle_deg(a: np.ndarray, b: np.ndarray) -> float:
    cos = (np.trace(a[:3, :3] @ b[:3, :3].T) - 1) / 2
    return float(np.degrees(np.arccos(np.clip(cos, -1.0, 1.0))))


def test_training_turns_mis_posed_photos_back(mis_posed, tmp_path: Path):
    """Trained with pose refinement, the photos' stored poses come back toward the truth
    (measured: mean error 1.5 -> 0.77 deg, held out 24.6 -> 25.8 dB against training
    without); the held-out photos keep their poses; the scene reloads with the corrected
    cameras, and ``--resume`` accepts its dataset and continues from its corrections."""
    from neoedit.data import load_scene_data
    from neoedit.scene import load_scene
    from tests.conftest import tiny_train

    data_path, truth = mis_posed
    data = load_scene_data(data_path)
    scene = tiny_train(data_path, tmp_path / "s", steps=300, pose_refinement=True)
    cams = scene.scan_cameras()[0]
    train, test = data.split["train"], data.split["test"]
    errors = [_angle_deg(cams.camera_to_world[i], truth[i]) for i in train]
    assert np.mean(errors) < 1.0 and max(errors) < 1.5, errors  # all were 1.5
    assert np.allclose(cams.camera_to_world[test], data.cameras.camera_to_world[test])
    fixes = np.asarray(scene.meta.scan["pose_corrections"])
    assert np.allclose(fixes[train].mean(0), 0, atol=1e-6)  # they never drift together
    again = load_scene(tmp_path / "s")
    assert np.allclose(again.scan_cameras()[0].camera_to_world, cams.camera_to_world)
    more = tiny_train(data_path, tmp_path / "s", steps=310, resume=True, pose_refinement=True)
    learnt = np.asarray(more.meta.scan["pose_corrections"])
    assert 0 < np.abs(learnt - fixes).max() < 1e-2  # continued from the saved ones, not zero
    # resumed without the option: the field keeps training at the corrected poses, which stay
    kept = tiny_train(data_path, tmp_path / "s", steps=320, resume=True)
    assert kept.meta.step == 320
    assert np.array_equal(np.asarray(kept.meta.scan["pose_corrections"]), learnt)

"""Held-out cameras aligned to their photos before evaluation (`neo eval --align-poses`): a
camera turned and shifted off its photo is brought back, the metrics at the aligned poses
beat those at the wrong ones, and the scene is untouched."""

from __future__ import annotations

import copy
import dataclasses
from pathlib import Path

import numpy as np
import torch
from scipy.spatial.transform import Rotation

from neoedit.cameras.pose_correction import corrected_poses
from neoedit.data import load_scene_data
from neoedit.eval.align import align_cameras
from neoedit.eval.evaluate import evaluate
from neoedit.scene import load_scene


def _angle_deg(a: np.ndarray, b: np.ndarray) -> float:
    turn = Rotation.from_matrix(a[:3, :3] @ b[:3, :3].T)
    return float(np.degrees(np.linalg.norm(turn.as_rotvec())))


def test_a_mis_posed_held_out_camera_is_brought_back_to_its_photo(trained: Path, sim_root: Path):
    scene = load_scene(trained)
    weights = copy.deepcopy(scene.field.state_dict())
    grid = scene.grid.density.clone()
    data = load_scene_data(sim_root / "removal_1" / "pre")
    views = [int(i) for i in data.indices("test")]
    truth = data.cameras.camera_to_world.copy()
    rng = np.random.default_rng(1)
    axes = rng.normal(size=(len(views), 3))
    axes /= np.linalg.norm(axes, axis=1, keepdims=True)
    error = np.concatenate([axes * np.radians(2.0), rng.normal(size=(len(views), 3)) * 0.004], 1)
    wrong = truth.copy()
    wrong[views] = corrected_poses(truth[views], error)
    off = dataclasses.replace(
        data, cameras=dataclasses.replace(data.cameras, camera_to_world=wrong)
    )

    aligned, fixes = align_cameras(scene, off, off.cameras, views)

    assert fixes.shape == (len(views), 6)
    before = [_angle_deg(wrong[i], truth[i]) for i in views]
    after = [_angle_deg(aligned.camera_to_world[i], truth[i]) for i in views]
    # each camera comes back, most of the way (measured on this 64x48 scan's blurry tiny
    # field: 2 deg -> 0.8-1.4; on NEO-Sim's 320x240 scan with a 1500-step field, 12 held-out
    # cameras: 2 deg -> 0.06-1.6, median 0.5)
    # (a suite run: 2 deg -> 0.80 / 1.61 / 0.29): every camera closer, the median by 40 %
    assert all(a < 0.85 * b for a, b in zip(after, before, strict=True)), (before, after)
    assert np.median(after) < 0.6 * np.median(before), (before, after)
    assert np.mean(after) < 0.65 * np.mean(before), (before, after)
    others = [i for i in range(len(truth)) if i not in views]
    assert np.array_equal(aligned.camera_to_world[others], wrong[others])  # only those asked
    # the metrics at the aligned poses beat those at the wrong ones, near the true poses'
    # (measured: 24.23 dB at the true poses, 22.36 at the wrong ones, 25.22 aligned: the
    # tiny field fits its photos best at poses a little off the simulator's); evaluate's
    # own alignment (its wiring and report) is the CLI test's below
    at_truth = evaluate(scene, data)["full"]["psnr"]
    at_wrong = evaluate(scene, off)["full"]["psnr"]
    at_aligned = evaluate(scene, dataclasses.replace(off, cameras=aligned))["full"]["psnr"]
    assert at_aligned > at_wrong + 2.0, (at_wrong, at_aligned)
    assert at_aligned > at_truth - 0.5, (at_truth, at_aligned)
    # nothing of the scene changed, and it took no gradient: the field is frozen while the
    # cameras move, its parameters trainable again after
    after_weights = scene.field.state_dict()
    assert all(torch.equal(weights[k], after_weights[k]) for k in weights)
    assert torch.equal(scene.grid.density, grid)
    assert all(p.grad is None and p.requires_grad for p in scene.field.parameters())


def test_evaluate_renders_and_measures_at_the_aligned_cameras(trained, sim_root, monkeypatch):
    """evaluate(align=...) renders where the alignment put the cameras (stubbed here: the
    true poses), and leaves the edited boxes' pixels out of the fit."""
    import neoedit.eval.evaluate as evaluate_mod
    from neoedit.eval.align import AlignConfig
    from neoedit.geometry import OrientedBox

    scene = load_scene(trained)
    data = load_scene_data(sim_root / "removal_1" / "pre")
    views = [int(i) for i in data.indices("test")]
    wrong = data.cameras.camera_to_world.copy()
    wrong[views] = corrected_poses(wrong[views], np.tile([0.03, 0.0, 0.0, 0.0, 0.0, 0.0], (3, 1)))
    off = dataclasses.replace(
        data, cameras=dataclasses.replace(data.cameras, camera_to_world=wrong)
    )
    box = OrientedBox((0.0, 0.0, 0.05), (0.1, 0.1, 0.1), 0.0)
    seen = {}

    def stub(scene_, data_, cameras, indices, cfg, exclude=()):
        seen["exclude"], seen["indices"] = list(exclude), list(indices)
        return data.cameras, np.full((len(indices), 6), 0.01)

    monkeypatch.setattr(evaluate_mod, "align_cameras", stub)
    result = evaluate(scene, off, out_boxes=[box], align=AlignConfig(steps=7))
    assert result["full"]["psnr"] == evaluate(scene, data, out_boxes=[box])["full"]["psnr"]
    assert seen == {"exclude": [box], "indices": views}
    assert result["aligned"]["views"] == 3 and result["aligned"]["steps"] == 7


def test_neo_eval_align_poses_reports_the_alignment(trained: Path, sim_root: Path, tmp_path):
    import json

    from neoedit.cli import main

    out = tmp_path / "eval.json"
    data = sim_root / "removal_1" / "pre"
    assert (
        main(["eval", str(trained), "--data", str(data), "--align-poses", "--json", str(out)]) == 0
    )
    result = json.loads(out.read_text())
    assert (
        result["aligned"]["views"] == result["n_views"] == 3 and result["aligned"]["steps"] == 200
    )
    # at the simulator's true poses the tiny field still moves its cameras ~1 deg (it fits
    # its blurry 64x48 photos best a little off them: the first test's 25.2 > 24.2 dB)
    assert 0 < result["aligned"]["median_turn_deg"] < 2.5
    assert result["full"]["psnr"] > 20

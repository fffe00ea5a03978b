"""Render a scan of a :class:`SimWorld` and write it as a nerfstudio dataset."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from neoedit.cameras import Cameras
from neoedit.sim._pybullet import pb
from neoedit.sim.spec import ScanSpec
from neoedit.sim.trajectory import eval_ring_poses, intrinsics, spiral_poses
from neoedit.sim.world import BACKGROUND_ID, ROBOT_ID, TABLE_ID, SimWorld
from neoedit.utils.io import atomic_write_json, write_png
from neoedit.utils.progress import track
from neoedit.viz.contact_sheet import write_contact_sheet

DEPTH_UNIT_M = 1e-3  # depth PNGs are uint16 millimetres (nerfstudio's default scale)
BACKGROUND_RGB = (1.0, 1.0, 1.0)  # PyBullet's tiny renderer clears to white


def render_view(
    world: SimWorld, c2w: np.ndarray, scan: ScanSpec
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Render one view -> RGB (H,W,3) uint8, z-depth (H,W) float32 metres (0 = nothing hit),
    instance ids (H,W) uint8."""
    setup = world.spec.setup
    view = np.linalg.inv(c2w).T.reshape(-1).tolist()  # column-major world->camera (OpenGL)
    proj = pb.computeProjectionMatrixFOV(
        scan.fov_y_deg, scan.width / scan.height, scan.near_m, scan.far_m
    )
    _, _, rgba, zbuf, seg = pb.getCameraImage(
        scan.width,
        scan.height,
        view,
        proj,
        renderer=pb.ER_TINY_RENDERER,
        lightDirection=list(setup.light_direction),
        lightColor=list(setup.light_color),
        lightAmbientCoeff=setup.ambient,
        lightDiffuseCoeff=setup.diffuse,
        lightSpecularCoeff=setup.specular,
        shadow=int(setup.shadows),
        physicsClientId=world.client,
    )
    rgb = np.asarray(rgba, dtype=np.uint8).reshape(scan.height, scan.width, 4)[..., :3]
    zbuf = np.asarray(zbuf, dtype=np.float64).reshape(scan.height, scan.width)
    near, far = scan.near_m, scan.far_m
    depth = far * near / (far - (far - near) * zbuf)
    seg = np.asarray(seg, dtype=np.int64).reshape(scan.height, scan.width)
    hit = seg >= 0
    depth = np.where(hit, depth, 0.0).astype(np.float32)
    labels = np.full(seg.shape, BACKGROUND_ID, np.uint8)
    labels[seg == world.table] = TABLE_ID
    for marker in world.markers:  # markers lie on the table: they are part of it
        labels[seg == marker] = TABLE_ID
    labels[seg == world.robot] = ROBOT_ID
    for name, body in world.bodies.items():
        labels[seg == body] = world.instance_ids[name]
    return rgb, depth, labels


def _backproject(c2w: np.ndarray, scan: ScanSpec, depth: np.ndarray) -> np.ndarray:
    k = intrinsics(scan)
    cams = Cameras.shared(
        c2w[None], k["fl_x"], k["fl_y"], k["cx"], k["cy"], scan.width, scan.height
    )
    return cams.backproject_depth(0, depth)[depth > 0]


def objects_metadata(world: SimWorld) -> dict[str, Any]:
    """objects.json: every instance id with its name, and per object its pose and box."""
    instances = [
        {"id": BACKGROUND_ID, "name": "background", "kind": "background"},
        {"id": TABLE_ID, "name": "table", "kind": "table"},
        {"id": ROBOT_ID, "name": "robot arm", "kind": "robot"},
    ]
    objects = []
    for spec in world.spec.objects:
        if spec.name not in world.bodies:
            continue
        iid = world.instance_ids[spec.name]
        instances.append({"id": iid, "name": spec.name, "kind": "object"})
        objects.append(
            {
                "id": iid,
                "name": spec.name,
                "urdf": spec.urdf,
                "pose": np.round(world.object_pose(spec.name), 6).tolist(),
                "box": world.object_box(spec.name).to_dict(),
            }
        )
    return {"instances": instances, "objects": objects}


def capture_scan(
    world: SimWorld, scan: ScanSpec, out_dir: Path, label: str = "scan"
) -> dict[str, Any]:
    """Render the training spiral and the held-out ring into ``out_dir`` (nerfstudio format)."""
    center = np.asarray(world.spec.setup.workspace_center_m)
    poses = np.concatenate([spiral_poses(scan, center), eval_ring_poses(scan, center)])
    n_train = scan.n_train
    frames: list[dict[str, Any]] = []
    train_files: list[str] = []
    test_files: list[str] = []
    thumbs: list[np.ndarray] = []
    names: list[str] = []
    lo, hi = np.full(3, np.inf), np.full(3, -np.inf)  # bounds of every visible surface point
    for i in track(range(len(poses)), f"render {label}"):
        split = "train" if i < n_train else "eval"
        stem = f"{split}_{i if i < n_train else i - n_train:04d}"
        rgb, depth, labels = render_view(world, poses[i], scan)
        rel = {
            "file_path": f"images/{stem}.png",
            "depth_file_path": f"depth/{stem}.png",
            "instance_path": f"instances/{stem}.png",
        }
        alpha = np.where(depth > 0, 255, 0).astype(np.uint8)  # transparent where nothing was hit
        write_png(out_dir / rel["file_path"], np.concatenate([rgb, alpha[..., None]], axis=-1))
        pts = _backproject(poses[i], scan, depth)
        if len(pts):
            lo, hi = np.minimum(lo, pts.min(0)), np.maximum(hi, pts.max(0))
        write_png(
            out_dir / rel["depth_file_path"], np.round(depth / DEPTH_UNIT_M).astype(np.uint16)
        )
        write_png(out_dir / rel["instance_path"], labels)
        frames.append({**rel, "transform_matrix": np.round(poses[i], 8).tolist()})
        (train_files if split == "train" else test_files).append(rel["file_path"])
        thumbs.append(rgb)
        names.append(stem)
    aabb = np.stack([lo, hi]) if np.isfinite(lo).all() else world.aabb_m()
    transforms = {
        "camera_model": "PINHOLE",
        **intrinsics(scan),
        "depth_unit_scale_factor": DEPTH_UNIT_M,
        "background_color": list(BACKGROUND_RGB),
        "scene_aabb": np.round(aabb, 4).tolist(),
        "train_filenames": train_files,
        "val_filenames": test_files,
        "test_filenames": test_files,
        "frames": frames,
    }
    atomic_write_json(out_dir / "transforms.json", transforms)
    objects = objects_metadata(world)
    atomic_write_json(out_dir / "objects.json", objects)
    write_contact_sheet(out_dir / "contact_sheet.png", thumbs, names)
    return {"n_train": len(train_files), "n_eval": len(test_files), "objects": objects["objects"]}

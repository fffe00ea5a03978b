"""ArUco registration on NEO-Sim against exact ground truth (issue 16 target).

    python benchmarks/bench_aruco.py --out outputs/bench_aruco [--scene pick_place_1] [--seed 0]

Simulates a standard-profile NEO-Sim pick-and-place scene with four 8 cm ArUco markers on
the table (pre and post scans, exact poses), then, as structure-from-motion would, moves
each scan into its own random frame (rotation, translation, scale) and
- orients the pre scan from the markers (``marker_frame``): the recovered frame is the
  simulator's world frame (the markers are centred on its origin, marker 0 along +x);
- registers the post scan to the true pre scan with ``neo register``.
Reports scale error, rotation error (deg) and the largest camera-centre error (mm).
Writes OUT/results.json.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import platform
import shlex
import shutil
import sys
import time
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from neoedit.data import load_scene_data
from neoedit.data.markers import dataset_markers, marker_frame
from neoedit.data.register import write_moved
from neoedit.sim.run import simulate_scene
from neoedit.sim.spec import MarkerSpec
from neoedit.sim.suite import benchmark_scenes

MARKERS = [
    MarkerSpec(0, (-0.3, -0.32), 0.08, 0.0),
    MarkerSpec(1, (0.3, -0.32), 0.08, 0.0),
    MarkerSpec(2, (0.3, 0.32), 0.08, 0.0),
    MarkerSpec(3, (-0.3, 0.32), 0.08, 0.0),
]


def random_similarity(rng: np.random.Generator) -> np.ndarray:
    out = np.eye(4)
    out[:3, :3] = rng.uniform(0.2, 5.0) * Rotation.random(random_state=rng).as_matrix()
    out[:3, 3] = rng.uniform(-3, 3, 3)
    return out


def pose_errors(got: np.ndarray, true: np.ndarray) -> dict:
    dist = np.linalg.norm(got[:, :3, 3] - true[:, :3, 3], axis=1)
    rel = got[:, :3, :3].transpose(0, 2, 1) @ true[:, :3, :3]
    angle = np.degrees(np.arccos(np.clip((np.trace(rel, axis1=1, axis2=2) - 1) / 2, -1, 1)))
    return {
        "max_centre_mm": round(1000 * float(dist.max()), 2),
        "median_centre_mm": round(1000 * float(np.median(dist)), 2),
        "max_rotation_deg": round(float(angle.max()), 3),
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, default=Path("outputs/bench_aruco"))
    ap.add_argument("--scene", default="pick_place_1")
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()
    print(f"# {shlex.join(sys.argv)}  ({platform.node()}, {platform.machine()})")
    spec = next(s for s in benchmark_scenes("standard", seed=0) if s.name == args.scene)
    spec = dataclasses.replace(spec, setup=dataclasses.replace(spec.setup, markers=MARKERS))
    sim_dir = args.out / "sim"
    if not (sim_dir / "scene.json").is_file():
        t0 = time.perf_counter()
        simulate_scene(spec, sim_dir, overwrite=True)
        print(f"simulated {args.scene} with markers in {time.perf_counter() - t0:.0f} s")
    rng = np.random.default_rng(args.seed)
    results = {"scene": args.scene, "markers": [dataclasses.asdict(m) for m in MARKERS]}
    # 1. orientation of a scan in an arbitrary frame from the markers
    sims = {name: random_similarity(rng) for name in ("pre", "post")}
    for name, sim in sims.items():
        moved = args.out / f"{name}_moved"
        shutil.rmtree(moved, ignore_errors=True)
        write_moved(sim_dir / name, sim, moved)
    pre_moved = load_scene_data(args.out / "pre_moved")
    markers = dataset_markers(pre_moved, "4X4_50")
    transform, scale = marker_frame(markers, 0.08, pre_moved.cameras.camera_to_world[:, :3, 3])
    true_pre = load_scene_data(sim_dir / "pre").cameras.camera_to_world
    got = transform[None] @ pre_moved.cameras.camera_to_world
    got[:, :3, :3] /= scale
    true_scale = 1.0 / np.cbrt(np.linalg.det(sims["pre"][:3, :3]))
    results["orientation"] = {
        "markers_seen": {str(k): v for k, v in markers.views.items()},
        "scale_error_pct": round(100 * (scale / true_scale - 1), 3),
        **pose_errors(got, true_pre),
    }
    # 2. neo register: post (arbitrary frame) -> the true pre frame
    reg = args.out / "post_registered"
    cmd = [
        sys.executable,
        "-m",
        "neoedit",
        "register",
        str(sim_dir / "pre"),
        str(args.out / "post_moved"),
        "--out",
        str(reg),
        "--overwrite",
    ]
    import subprocess

    proc = subprocess.run(cmd, capture_output=True, text=True)
    print(proc.stdout + proc.stderr)
    true_post = load_scene_data(sim_dir / "post").cameras.camera_to_world
    got_post = load_scene_data(reg).cameras.camera_to_world
    meta = json.loads((reg / "transforms.json").read_text())["neoedit_registration"]
    reg_scale = float(np.cbrt(np.linalg.det(np.asarray(meta["transform"])[:3, :3])))
    true_reg_scale = 1.0 / float(np.cbrt(np.linalg.det(sims["post"][:3, :3])))
    results["register"] = {
        "exit": proc.returncode,
        "markers": meta["markers"],
        "corner_rms_mm": round(1000 * meta["rms_m"], 2),
        "scale_error_pct": round(100 * (reg_scale / true_reg_scale - 1), 3),
        **pose_errors(got_post, true_post),
        "command": shlex.join(cmd[2:]),
    }
    results["date"] = time.strftime("%Y-%m-%d %H:%M")
    print(json.dumps(results, indent=2))
    (args.out / "results.json").write_text(json.dumps(results, indent=2))


if __name__ == "__main__":
    main()

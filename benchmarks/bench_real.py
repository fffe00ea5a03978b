"""A real phone capture (beer_can, ../shared/data/real/beer_can): import, SfM, poses, training.

    python benchmarks/bench_real.py --capture ../shared/data/real/beer_can --out outputs/bench_real
    python benchmarks/bench_real.py ... --only import process poses     # some sections

Sections (run alone, on an otherwise idle machine; they build on each other):
- import: ``neo import colmap`` of the shipped model (which is folded: it stops and lists the
  pieces), then of its largest consistent piece at 360 px wide; wall time.
- process: ``neo process`` (pycolmap SfM on the 71 photos, sequential matching) at 360 px,
  largest consistent piece; wall time.
- poses: both datasets' cameras on the photos they share, after a similarity alignment
  (Umeyama on the camera centres): largest centre distance and rotation difference.
- train: ``neo train --max-minutes 5`` on the processed dataset (radiance field with the
  sparse structure-from-motion depth the import wrote, then the label-free geometric
  language field); held-out PSNR, the language vocabulary, the geometry probe below, and a
  strip of held-out renders over the photos (OUT/heldout_strip.png).
- train-colour: the same training with ``--depth-loss-weight 0`` (colour only, as before the
  sparse depth existed), into OUT/scene_colour.
- edit: ``neo query SCENE "can"`` (box picture), ``neo remove SCENE "can"`` and
  ``neo move SCENE "can" --translate 0.15 0 0``; wall times, and a strip of held-out views
  before / after the removal / after the move (OUT/edit_strip.png).

Geometry probe (what the label-free teacher sees): surface points of random training pixels
(the teacher's own sampling), the robust spread of the floor's height 10-20 cm from the
look centre, how many points lie within 3.5 cm of the vertical through it (the can) and
how high they reach, and the instances the geometric teacher discovers.
Writes ``OUT/<section>.json``.
"""

from __future__ import annotations

import argparse
import json
import platform
import shlex
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

from neoedit.data import load_scene_data
from neoedit.data.markers import umeyama

SECTIONS = ("import", "process", "poses", "train", "train-colour", "edit")


def run(cmd: list[str]) -> tuple[int, float, str]:
    t0 = time.perf_counter()
    proc = subprocess.run(cmd, capture_output=True, text=True)
    return proc.returncode, time.perf_counter() - t0, proc.stdout + proc.stderr


def neo(*args: str) -> list[str]:
    return [sys.executable, "-m", "neoedit", *args]


def section_import(capture: Path, out: Path) -> dict:
    rc, _, text = run(neo("import", "colmap", str(capture), "--out", str(out / "refused")))
    listed = " ".join(text.split())
    cmd = neo(
        "import",
        "colmap",
        str(capture),
        "--out",
        str(out / "imported"),
        "--piece",
        "largest",
        "--max-width",
        "360",
        "--overwrite",
    )
    rc2, seconds, text2 = run(cmd)
    print(text2)
    return {
        "check_exit": rc,
        "check_message": listed,
        "exit": rc2,
        "seconds": round(seconds, 1),
        "command": shlex.join(cmd[2:]),
    }


def section_process(capture: Path, out: Path) -> dict:
    cmd = neo(
        "process",
        str(capture / "images"),
        "--out",
        str(out / "processed"),
        "--piece",
        "largest",
        "--max-width",
        "360",
        "--overwrite",
    )
    rc, seconds, text = run(cmd)
    print(text)
    return {
        "exit": rc,
        "seconds": round(seconds, 1),
        "output": " ".join(text.split()),
        "command": shlex.join(cmd[2:]),
    }


def _poses(folder: Path) -> dict[str, np.ndarray]:
    data = load_scene_data(folder)
    return {Path(p).stem: data.cameras.camera_to_world[i] for i, p in enumerate(data.file_paths)}


def section_poses(out: Path) -> dict:
    a, b = _poses(out / "imported"), _poses(out / "processed")
    common = sorted(set(a) & set(b))
    pa = np.stack([a[k] for k in common])
    pb = np.stack([b[k] for k in common])
    t = umeyama(pb[:, :3, 3], pa[:, :3, 3])
    scale = float(np.cbrt(np.linalg.det(t[:3, :3])))
    moved_c = pb[:, :3, 3] @ t[:3, :3].T + t[:3, 3]
    moved_r = (t[:3, :3] / scale)[None] @ pb[:, :3, :3]
    dist = np.linalg.norm(moved_c - pa[:, :3, 3], axis=1)
    rel = moved_r.transpose(0, 2, 1) @ pa[:, :3, :3]
    angle = np.degrees(np.arccos(np.clip((np.trace(rel, axis1=1, axis2=2) - 1) / 2, -1, 1)))
    result = {
        "common_photos": len(common),
        "first": common[0],
        "last": common[-1],
        "max_centre_m": round(float(dist.max()), 4),
        "median_centre_m": round(float(np.median(dist)), 4),
        "max_rotation_deg": round(float(angle.max()), 3),
        "median_rotation_deg": round(float(np.median(angle)), 3),
        "note": "metres of the imported dataset (its scale is assumed: median camera distance 0.5 m)",
    }
    print(result)
    return result


def section_train(out: Path, minutes: float, colour_only: bool = False) -> dict:
    scene = out / ("scene_colour" if colour_only else "scene")
    cmd = neo(
        "train",
        str(out / "processed"),
        "--out",
        str(scene),
        "--max-minutes",
        str(minutes),
        "--max-steps",
        "100000",
        "--eval-every",
        "0",
        *(["--depth-loss-weight", "0"] if colour_only else []),
    )
    if scene.exists():
        subprocess.run(["rm", "-rf", str(scene)], check=True)
    rc, seconds, text = run(cmd)
    if rc != 0:
        return {"exit": rc, "output": " ".join(text.split())[-600:], "command": shlex.join(cmd[2:])}
    meta = json.loads((scene / "scene.json").read_text())
    last = meta["history"][-1]
    name = "heldout_strip_colour.png" if colour_only else "heldout_strip.png"
    strip = _strip(scene, out / "processed", out / name)
    lang = meta.get("language") or {}
    result = {
        "exit": rc,
        "wall_s": round(seconds, 1),
        "steps": meta["step"],
        "language_teacher": lang.get("teacher"),
        "language_s": lang.get("seconds"),
        "vocabulary": lang.get("vocabulary"),
        "train_s": round(meta["train_seconds"], 1),
        "heldout_psnr": last.get("eval_psnr"),
        "train_psnr": last.get("train_psnr"),
        "rays_per_s": last.get("rays_per_s"),
        "strip": str(strip),
        "geometry": geometry_probe(scene, out / "processed"),
        "language_output": " ".join(
            line for line in text.splitlines() if "language" in line or "teacher" in line
        )[-400:],
        "command": shlex.join(cmd[2:]),
    }
    print(result)
    return result


def geometry_probe(scene_dir: Path, data_dir: Path) -> dict:
    """What the geometric teacher sees of the field (see the module docstring)."""
    import torch

    from neoedit.cameras.rays import CameraTensors
    from neoedit.errors import NeoError
    from neoedit.language.geometric import GeometricConfig, discover
    from neoedit.language.training import LanguageTrainConfig, sample_surface
    from neoedit.scene import load_scene

    scene, data = load_scene(scene_dir), load_scene_data(data_dir)
    frames = data.split["train"]
    cams = CameraTensors(data.cameras)
    cfg = LanguageTrainConfig()  # the teacher's own sampling: as many rays, same seed
    g = torch.Generator().manual_seed(cfg.seed)
    with torch.no_grad():
        pos, v, u, pts, acc = sample_surface(
            scene, cams, frames, data.height, data.width, cfg.rays, g
        )
    hit = (acc >= cfg.min_accumulation).numpy()
    pts = pts.numpy()[hit].astype(np.float64)
    rgb = data.images[frames[pos.numpy()[hit]], v.numpy()[hit], u.numpy()[hit]]
    r = np.linalg.norm(pts[:, :2], axis=1)
    ring = pts[(r > 0.1) & (r < 0.2), 2]
    axis = pts[r < 0.035, 2]
    result = {
        "surface_points": int(len(pts)),
        "floor_10_20cm_median_z_cm": round(float(np.median(ring)) * 100, 2),
        "floor_10_20cm_robust_sigma_mm": round(
            float(1.4826 * np.median(np.abs(ring - np.median(ring)))) * 1000, 1
        ),
        "points_within_3.5cm_of_axis": int(len(axis)),
        "axis_height_p50_p95_cm": np.round(np.percentile(axis, [50, 95]) * 100, 1).tolist()
        if len(axis)
        else None,
    }
    try:
        found = discover(pts, rgb, data.cameras.camera_to_world[frames], GeometricConfig())
    except NeoError as e:
        result["teacher"] = " ".join(str(e).split())
        return result
    result["teacher_up"] = np.round(found.plane.normal, 3).tolist()
    result["instances"] = [
        f"{inst.description}: {inst.shape.kind}, {inst.shape.length_m * 100:.1f} x "
        f"{inst.shape.width_m * 100:.1f} x {inst.shape.height_m * 100:.1f} cm, {inst.points} points"
        for inst in found.instances
    ]
    return result


def section_edit(out: Path, prompt: str) -> dict:
    scene = out / "scene"
    query = neo("query", str(scene), prompt, "--out", str(out / "query"))
    query += ["--json", str(out / "query_box.json")]
    rc_q, t_q, text_q = run(query)
    print(text_q)
    remove = neo("remove", str(scene), prompt, "--out", str(out / "removed"), "--overwrite")
    rc_r, t_r, text_r = run(remove)
    print(text_r)
    move = neo("move", str(scene), prompt, "--translate", "0.15", "0", "0")
    move += ["--out", str(out / "moved"), "--overwrite"]
    rc_m, t_m, text_m = run(move)
    print(text_m)
    box = json.loads((out / "query_box.json").read_text()) if rc_q == 0 else None
    footprint = None
    if rc_r == 0:  # where the can stood against the floor around it (0: seamless)
        footprint = _footprints(scene, out / "removed")
    scenes = [scene] + [out / d for d, rc in (("removed", rc_r), ("moved", rc_m)) if rc == 0]
    strip = _edit_strip(scenes, out / "processed", out / "edit_strip.png")
    return {
        "prompt": prompt,
        "query_exit": rc_q,
        "query_s": round(t_q, 1),
        "box": box,
        "remove_exit": rc_r,
        "remove_s": round(t_r, 1),
        "remove_output": " ".join(text_r.split())[-600:],
        "removal_footprint": footprint,
        "move_exit": rc_m,
        "move_s": round(t_m, 1),
        "move_output": " ".join(text_m.split())[-600:],
        "strip": str(strip),
        "commands": [shlex.join(c[2:]) for c in (query, remove, move)],
    }


def _footprints(scene_dir: Path, removed_dir: Path) -> dict:
    """The removal's footprint contrast, beside the unedited scene's (the object itself)."""
    from neoedit.errors import NeoError
    from neoedit.eval.footprint import removal_footprint
    from neoedit.geometry import OrientedBox
    from neoedit.scene import load_scene

    removed = load_scene(removed_dir)
    box = OrientedBox.from_dict(removed.meta.edits[-1].details["boxes"][0])
    try:
        return {
            "removed": removal_footprint(removed, box).to_dict(),
            "unedited": removal_footprint(load_scene(scene_dir), box).to_dict(),
        }
    except NeoError as e:  # the edit's figures stand without it
        return {"error": str(e)}


def _edit_strip(scenes: list[Path], data_dir: Path, path: Path, views: int = 3) -> Path:
    """Held-out views (columns) of each scene (rows: before, removed, moved)."""
    import imageio.v3 as iio
    import torch

    from neoedit.cameras.rays import CameraTensors
    from neoedit.scene import load_scene

    data = load_scene_data(data_dir)
    cams = CameraTensors(data.cameras)
    test = data.split["test"][:views]
    rows = []
    for scene_dir in scenes:
        scene = load_scene(scene_dir)
        with torch.no_grad():
            renders = [
                scene.render_image(cams, int(i), data.height, data.width)["rgb"].numpy()
                for i in test
            ]
        rows.append(np.concatenate([(np.clip(r, 0, 1) * 255).astype(np.uint8) for r in renders], 1))
    iio.imwrite(path, np.concatenate(rows, 0)[::2, ::2])
    return path


def _strip(scene_dir: Path, data_dir: Path, path: Path) -> Path:
    """Held-out renders (top) over the photos (bottom)."""
    import imageio.v3 as iio
    import torch

    from neoedit.cameras.rays import CameraTensors
    from neoedit.scene import load_scene

    scene, data = load_scene(scene_dir), load_scene_data(data_dir)
    cams = CameraTensors(data.cameras)
    test = data.split["test"][:6]
    with torch.no_grad():
        renders = [
            scene.render_image(cams, int(i), data.height, data.width)["rgb"].numpy() for i in test
        ]
    top = np.concatenate([(np.clip(r, 0, 1) * 255).astype(np.uint8) for r in renders], 1)
    bottom = np.concatenate([data.images[i] for i in test], 1)
    iio.imwrite(path, np.concatenate([top, bottom], 0)[::2, ::2])
    return path


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--capture", type=Path, default=Path("../shared/data/real/beer_can"))
    ap.add_argument("--out", type=Path, default=Path("outputs/bench_real"))
    ap.add_argument("--only", nargs="*", choices=SECTIONS, default=list(SECTIONS))
    ap.add_argument("--minutes", type=float, default=5.0)
    ap.add_argument("--prompt", default="can")
    args = ap.parse_args()
    if not (args.capture / "images").is_dir():
        sys.exit(f"capture not found: {args.capture} (the shared beer_can capture)")
    args.out.mkdir(parents=True, exist_ok=True)
    print(
        f"# {shlex.join(sys.argv)}  ({platform.node()}, {platform.processor() or platform.machine()})"
    )
    for name in args.only:
        if name == "import":
            result = section_import(args.capture, args.out)
        elif name == "process":
            result = section_process(args.capture, args.out)
        elif name == "poses":
            result = section_poses(args.out)
        elif name == "edit":
            result = section_edit(args.out, args.prompt)
        else:
            result = section_train(args.out, args.minutes, colour_only=name == "train-colour")
        result["date"] = time.strftime("%Y-%m-%d %H:%M")
        (args.out / f"{name}.json").write_text(json.dumps(result, indent=2))


if __name__ == "__main__":
    main()

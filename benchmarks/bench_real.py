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
- train: ``neo train --max-minutes 5`` on the processed dataset (radiance field, then the
  label-free geometric language field); held-out PSNR, the language vocabulary, and a strip
  of held-out renders over the photos (OUT/heldout_strip.png).
- edit: ``neo query SCENE "can"`` (box picture) and ``neo remove SCENE "can"`` (before/after
  renders); wall times.
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

SECTIONS = ("import", "process", "poses", "train", "edit")


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


def section_train(out: Path, minutes: float) -> dict:
    scene = out / "scene"
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
    )
    if scene.exists():
        subprocess.run(["rm", "-rf", str(scene)], check=True)
    rc, seconds, text = run(cmd)
    meta = json.loads((scene / "scene.json").read_text())
    last = meta["history"][-1]
    strip = _strip(scene, out / "processed", out / "heldout_strip.png")
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
        "command": shlex.join(cmd[2:]),
    }
    print(result)
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
    box = json.loads((out / "query_box.json").read_text()) if rc_q == 0 else None
    return {
        "prompt": prompt,
        "query_exit": rc_q,
        "query_s": round(t_q, 1),
        "box": box,
        "remove_exit": rc_r,
        "remove_s": round(t_r, 1),
        "remove_output": " ".join(text_r.split())[-600:],
        "commands": [shlex.join(query[2:]), shlex.join(remove[2:])],
    }


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
            result = section_train(args.out, args.minutes)
        result["date"] = time.strftime("%Y-%m-%d %H:%M")
        (args.out / f"{name}.json").write_text(json.dumps(result, indent=2))


if __name__ == "__main__":
    main()

"""A real removal with ground truth: SPIn-NeRF scene 1 (../shared/data/real/spinnerf_1).

    python benchmarks/bench_spinnerf.py --out outputs/bench_spinnerf
    python benchmarks/bench_spinnerf.py --out outputs/bench_spinnerf_room --room on --prompt box

The capture's README protocol: train on the 60 photos with the box, remove the box, render
the poses of the 40 photos taken after it was carried away and compare. Steps (run alone):

1. ``neo import llff`` of the capture; the split set to train = the photos with a label
   mask, test = the photos without one (the "after" walk). ``--every K`` keeps every K-th
   "after" photo as the test set (renders of this forward-facing capture take seconds).
2. ``neo train --max-minutes M --skip-language`` (the room field as ``neo train`` decides,
   or ``--room on|off``).
3. The box the masks give: :func:`neoedit.edit.points.box_from_masks` on the label masks
   of the training photos, grown by ``--margin`` of its size, written to OUT/box.json.
4. ``neo remove SCENE --box OUT/box.json``; with ``--prompt P``, also the label-free
   language trained on a copy of the scene, ``neo query`` of P (the IoU of its box with
   the masks' box) and ``neo remove COPY P`` (no masks at all), evaluated as in 5.
5. ``neo eval`` of the unedited and the edited scene against the "after" photos: the PSNR
   of the whole image and inside the box's projection (``--out-box``), and a strip of
   after photo | unedited | removed for three views (OUT/strip.png).

Writes OUT/results.json; prints the figures and the commands that made them.
"""

from __future__ import annotations

import argparse
import json
import platform
import shlex
import shutil
import subprocess
import sys
import time
from pathlib import Path

import imageio.v3 as iio
import numpy as np

from neoedit.errors import NeoError

CAPTURE = Path("../shared/data/real/spinnerf_1")


def neo(*args: str) -> list[str]:
    return [sys.executable, "-m", "neoedit", *args]


def run(cmd: list[str], no_match_ok: bool = False) -> float:
    """Run a command, stop the benchmark when it fails (with ``no_match_ok``, ``neo query``'s
    exit status 1 for a prompt that matched nothing is no failure; a crash, whose traceback
    also exits 1, is)."""
    print("$", shlex.join(cmd[2:] if cmd[:2] == [sys.executable, "-m"] else cmd), flush=True)
    t0 = time.perf_counter()
    proc = subprocess.run(cmd, capture_output=True, text=True)
    said = proc.stdout + proc.stderr  # neo query says "error: no object matched" on stderr
    no_match = no_match_ok and proc.returncode == 1 and "no object matched" in said
    if proc.returncode != 0 and not no_match:
        sys.exit(f"failed ({proc.returncode}):\n{proc.stdout[-3000:]}\n{proc.stderr[-3000:]}")
    return time.perf_counter() - t0


def prepare(capture: Path, data: Path, every: int, extra: list[str]) -> dict:
    seconds = run(neo("import", "llff", str(capture), "--out", str(data), "--overwrite", *extra))
    labels = {p.stem for p in (capture / "images_8" / "label").glob("*.png")}
    meta = json.loads((data / "transforms.json").read_text())
    names = [f["file_path"] for f in meta["frames"]]
    meta["train_filenames"] = [n for n in names if Path(n).stem in labels]
    meta["test_filenames"] = [n for n in names if Path(n).stem not in labels][::every]
    (data / "transforms.json").write_text(json.dumps(meta, indent=1))
    return {
        "seconds": round(seconds, 1),
        "train": len(meta["train_filenames"]),
        "test": len(meta["test_filenames"]),
    }


def find_box(capture: Path, scene_dir: Path, data: Path, margin: float) -> dict:
    from neoedit.data import load_scene_data
    from neoedit.data.masks import read_object_masks
    from neoedit.edit.points import box_from_masks
    from neoedit.geometry import OrientedBox
    from neoedit.scene import load_scene

    scene, d = load_scene(scene_dir), load_scene_data(data)
    # the label masks of the training photos (the CLI's reader: neo remove --masks)
    train = set(int(i) for i in d.split["train"])
    masks = read_object_masks(capture / "images_8" / "label", list(d.file_paths), d.cameras)
    masks = {i: m for i, m in masks.items() if i in train}
    t0 = time.perf_counter()
    box = box_from_masks(scene, d.cameras, masks)
    grown = OrientedBox(box.center_m, tuple(s * (1 + 2 * margin) for s in box.size_m), box.yaw_deg)
    (scene_dir.parent / "box.json").write_text(json.dumps(grown.to_dict()))
    return {"box": grown.to_dict(), "seconds": round(time.perf_counter() - t0, 1)}


def by_prompt(scene: Path, data: Path, out: Path, prompt: str, margin: float) -> dict:
    """The label-free language field trained on a copy of ``scene``, ``prompt`` queried (its
    box's IoU with the masks' box, ungrown) and removed by name; the removal evaluated."""
    from neoedit.geometry import OrientedBox
    from neoedit.geometry.box import box_iou_3d

    lang, found = out / "scene_language", out / "query.json"
    shutil.copytree(scene, lang)
    result: dict = {"prompt": prompt}
    resume = neo("train", str(data), "--out", str(lang), "--resume", "--max-steps", "1", "--quiet")
    result["language_seconds"] = round(run(resume), 1)
    query = neo("query", str(lang), prompt, "--json", str(found), "--out", str(out / "query"))
    found.unlink(missing_ok=True)  # an earlier run's box must not read as this run's match
    result["query_seconds"] = round(run([*query, "--overwrite"], no_match_ok=True), 1)
    if not found.is_file():  # exit 1: nothing matched the prompt
        return {**result, "matched": False}
    box = OrientedBox.from_dict(json.loads(found.read_text()))
    grown = OrientedBox.from_dict(json.loads((out / "box.json").read_text()))
    masks = OrientedBox(
        grown.center_m, tuple(s / (1 + 2 * margin) for s in grown.size_m), grown.yaw_deg
    )
    result["iou_with_masks_box"] = round(box_iou_3d(box, masks), 3)
    removed = out / "removed_by_prompt"
    remove = neo("remove", str(lang), prompt, "--out", str(removed), "--overwrite")
    result["remove_seconds"] = round(run(remove), 1)
    return {**result, "matched": True, "removed": evaluate(removed, data, out / "box.json", out)}


def evaluate(scene_dir: Path, data: Path, box: Path | None, out: Path) -> dict:
    json_path = out / f"eval_{scene_dir.name}.json"
    region = [] if box is None else ["--out-box", str(box)]
    cmd = neo("eval", str(scene_dir), "--data", str(data), *region, "--json", str(json_path))
    seconds = run([*cmd, "--overwrite"])
    metrics = json.loads(json_path.read_text())
    return {
        "full_psnr": metrics["full"]["psnr"],
        "box_psnr": metrics.get("out", {}).get("psnr"),
        "full_ssim": metrics["full"]["ssim"],
        "seconds": round(seconds, 1),
    }


def strip(scenes: list[Path], data: Path, path: Path, views: int = 3) -> None:
    import torch

    from neoedit.cameras.rays import CameraTensors
    from neoedit.data import load_scene_data
    from neoedit.scene import load_scene

    d = load_scene_data(data)
    cams = CameraTensors(d.cameras)
    test = d.split["test"]
    chosen = test[np.linspace(0, len(test) - 1, views).round().astype(int)]
    rows = []
    loaded = [load_scene(s) for s in scenes]
    for i in chosen:
        tiles = [d.images[i]]
        for scene in loaded:
            with torch.no_grad():
                rgb = scene.render_image(cams, int(i), d.height, d.width)["rgb"]
            tiles.append((rgb.clamp(0, 1).numpy() * 255).round().astype(np.uint8))
        rows.append(np.concatenate(tiles, 1))
    iio.imwrite(path, np.concatenate(rows, 0))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--capture", type=Path, default=CAPTURE)
    ap.add_argument("--out", type=Path, default=Path("outputs/bench_spinnerf"))
    ap.add_argument("--minutes", type=float, default=5.0)
    ap.add_argument("--every", type=int, default=4, help="keep every K-th 'after' photo")
    ap.add_argument("--margin", type=float, default=0.1, help="box growth per side, of its size")
    ap.add_argument(
        "--room",
        choices=("auto", "on", "off"),
        default="auto",
        help="the room field around the box (auto: neo train's default)",
    )
    ap.add_argument(
        "--prompt",
        help="also find the object by this prompt (label-free language), remove it by name, "
        "and score that removal (e.g. --prompt box)",
    )
    ap.add_argument(
        "--train-arg",
        action="append",
        default=[],
        help="one more option of neo train (repeat: --train-arg=--photo-appearance=True)",
    )
    ap.add_argument(
        "--import-arg",
        action="append",
        default=[],
        help="one more option of neo import llff (repeat: --import-arg=--no-triangulate)",
    )
    args = ap.parse_args()
    if not (args.capture / "poses_bounds.npy").is_file():
        sys.exit(f"{args.capture}: not the spinnerf_1 capture (no poses_bounds.npy)")
    out = args.out
    out.mkdir(parents=True, exist_ok=True)
    data, scene, removed = out / "data", out / "scene", out / "removed"
    if scene.exists() or removed.exists():
        sys.exit(f"{out} holds an earlier run (scene/ or removed/): choose another --out")
    results: dict = {
        "date": time.strftime("%Y-%m-%d %H:%M"),
        "machine": platform.node(),
        "command": shlex.join(sys.argv),
        "room": args.room,
        "import_args": args.import_arg,
        "train_args": args.train_arg,
    }
    results["data"] = prepare(args.capture, data, args.every, args.import_arg)
    train = neo(
        "train",
        str(data),
        "--out",
        str(scene),
        "--max-minutes",
        str(args.minutes),
        "--skip-language",
        "--quiet",
    )
    if args.room != "auto":
        train += ["--field.room", str(args.room == "on")]
    train += args.train_arg
    results["train_seconds"] = round(run(train), 1)
    history = json.loads((scene / "scene.json").read_text())["history"][-1]
    results["train"] = {k: history[k] for k in ("step", "train_psnr", "eval_psnr", "rays_per_s")}
    try:
        results["box"] = find_box(args.capture, scene, data, args.margin)
    except NeoError as e:  # e.g. the object is not in the scene box: nothing to remove
        results["box"] = {"refused": str(e)}
        if args.prompt:
            results["by_prompt"] = {"skipped": "no masks' box to score the prompt's against"}
        results["unedited"] = evaluate(scene, data, None, out)
        (out / "results.json").write_text(json.dumps(results, indent=1))
        print(json.dumps(results, indent=1))
        return
    results["remove_seconds"] = round(
        run(
            neo(
                "remove",
                str(scene),
                "--box",
                str(out / "box.json"),
                "--out",
                str(removed),
                "--overwrite",
            )
        ),
        1,
    )
    results["unedited"] = evaluate(scene, data, out / "box.json", out)
    results["removed"] = evaluate(removed, data, out / "box.json", out)
    if args.prompt:
        results["by_prompt"] = by_prompt(scene, data, out, args.prompt, args.margin)
    strip([scene, removed], data, out / "strip.png")
    (out / "results.json").write_text(json.dumps(results, indent=1))
    print(json.dumps(results, indent=1))


if __name__ == "__main__":
    main()

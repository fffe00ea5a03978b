"""Speed on a 2-core CPU: training convergence, image rendering, `neo remove`, shared machine.

    python benchmarks/bench_speed.py --data outputs/neosim_rm/removal_1/pre --out outputs/bench_speed
    python benchmarks/bench_speed.py ... --only train          # one section (train, render, remove, contention)

Sections (run alone, on an otherwise idle machine):
- train: held-out PSNR (all test views) after 30/45/60/90/120 s of training time with the
  default options and a 2-minute schedule (``--max-minutes 2``), the rays/s, and the PSNR
  after a fixed number of steps (``--fixed-steps``, default 1000) for "same results".
  Run it with ``PYTHONPATH`` pointing at an older checkout to get that code's figures.
- render: the test views of the trained scene at 320x240, training sampler vs fast march.
- remove: wall time of ``neo remove --box`` (the scene's removed object, its true box) on
  that scene, ``--repeat`` times (median), and the edit's Out / Full PSNR on the post
  scan's test views when the scan has one.
- contention: 120 training steps alone, two trainings side by side, a training beside a
  render loop, and a training beside a ``nice``d busy loop (Python); wall time of each.
Writes ``OUT/<section>.json``.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import os
import platform
import shlex
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import torch

from neoedit.cameras.rays import CameraTensors
from neoedit.data import load_scene_data
from neoedit.data.scan import scan_record
from neoedit.fields.radiance import RadianceFieldConfig
from neoedit.rendering.occupancy import OccupancyGridConfig
from neoedit.rendering.renderer import RenderConfig, render_image
from neoedit.scene import Scene, SceneMeta, load_scene, save_scene
from neoedit.training.defaults import median_camera_distance, scene_box
from neoedit.training.trainer import TrainConfig, Trainer

MARKS_S = (30, 45, 60, 90, 120)


def make_trainer(data_dir: Path, out: Path, max_steps: int, max_minutes: float | None) -> Trainer:
    """A trainer with the defaults of ``neo train`` (as the checkout on the path has them)."""
    data = load_scene_data(data_dir)
    cfg = TrainConfig(max_steps=max_steps, max_minutes=max_minutes, eval_views=100)
    cfg = dataclasses.replace(
        cfg,
        sparsity_loss_weight=0.1 if data.scene_aabb_m is None else 0.0,
        depth_loss_weight=0.1 if data.depth_m is not None else 0.0,
    )
    render = RenderConfig()
    render.near_m = round(0.25 * median_camera_distance(data), 4)
    meta = SceneMeta(
        data_path=str(data_dir.resolve()),
        aabb_m=scene_box(data),
        background_rgb=list(data.background_rgb or (1.0, 1.0, 1.0)),
        field=RadianceFieldConfig(),
        grid=OccupancyGridConfig(),
        render=render,
        train=dataclasses.asdict(cfg),
        scan=scan_record(data.cameras, data.file_paths, data.split),
    )
    scene = Scene.create(meta, torch.device("cpu"), seed=cfg.seed)
    return Trainer(data, scene, cfg, out, torch.device("cpu"))


def warm_up(trainer: Trainer) -> None:
    """Compile the CPU kernels (numba caches them on disk; a first run compiles) outside
    the timed part."""
    with torch.no_grad():
        trainer.scene.field.density(trainer.scene.field.aabb.mean(0, keepdim=True))


def train_section(args: argparse.Namespace) -> dict:
    trainer = make_trainer(args.data, args.out / "scene", 10**6, 2.0)
    warm_up(trainer)
    curve, t_train, step = [], 0.0, 0
    marks = list(MARKS_S)
    while marks:
        t0 = time.perf_counter()
        trainer.step(step, t_train)
        t_train += time.perf_counter() - t0
        step += 1
        if t_train >= marks[0]:
            marks.pop(0)
            value = trainer.evaluate()
            curve.append({"seconds": round(t_train, 1), "step": step, "psnr": round(value, 2)})
            rays = step * trainer.cfg.rays_per_batch / t_train
            print(f"  {curve[-1]} {rays:.0f} rays/s", flush=True)
    rays_per_s = step * trainer.cfg.rays_per_batch / t_train
    finish = getattr(trainer, "finish_grid", None)
    if finish is not None:
        finish()
    trainer.scene.meta.step = step
    save_scene(args.out / "scene", trainer.scene, trainer.optimizer)
    fixed = make_trainer(args.data, args.out / "fixed", args.fixed_steps, None)
    warm_up(fixed)
    t0 = time.perf_counter()
    for s in range(args.fixed_steps):
        fixed.step(s)
    fixed_seconds = time.perf_counter() - t0
    fixed_psnr = fixed.evaluate()
    first_30 = next((c["seconds"] for c in curve if c["psnr"] >= 30.0), None)
    return {
        "curve": curve,
        "rays_per_s": round(rays_per_s),
        "seconds_to_30db": first_30,
        "fixed_steps": args.fixed_steps,
        "fixed_psnr": round(fixed_psnr, 3),
        "fixed_seconds": round(fixed_seconds, 1),
    }


def open_views(scene_dir: Path, data_dir: Path):
    """The scene, its dataset and that dataset's cameras (CPU)."""
    data = load_scene_data(data_dir)
    return load_scene(scene_dir, torch.device("cpu")), data, CameraTensors(data.cameras, "cpu")


def render_view(scene, data, cams, index: int, cfg: RenderConfig) -> dict[str, torch.Tensor]:
    return render_image(
        scene.field, scene.grid, cams, index, data.height, data.width, cfg, scene.background
    )


def render_section(args: argparse.Namespace) -> dict:
    scene, data, cams = open_views(args.scene or args.out / "scene", args.data)
    test = data.split["test"]
    result = {}
    for name, fast in (("training sampler", False), ("fast march", True)):
        cfg = dataclasses.replace(scene.meta.render)
        if hasattr(cfg, "fast_render"):
            cfg.fast_render = fast
        elif fast:
            continue
        render_view(scene, data, cams, int(test[0]), cfg)  # warm-up (compilation)
        errors, seconds = [], []
        for i in test:
            t0 = time.perf_counter()
            out = render_view(scene, data, cams, int(i), cfg)
            seconds.append(time.perf_counter() - t0)
            gt = torch.as_tensor(data.images[i]).float() / 255.0
            errors.append(float(torch.mean((out["rgb"] - gt) ** 2)))
        per_view = float(np.median(seconds))
        result[name] = {
            "views": len(test),
            "seconds_per_view": round(per_view, 3),
            "rays_per_s": round(data.height * data.width / per_view),
            "psnr": round(-10 * math.log10(float(np.mean(errors))), 3),
        }
        print(f"  {name}: {result[name]}", flush=True)
    return result


def neo(*argv: str) -> list[str]:
    return [str(Path(sys.executable).with_name("neo")), *argv]


def remove_section(args: argparse.Namespace) -> dict:
    scene_dir = args.scene or args.out / "scene"
    # the ground-truth box of the removed object (the scene of the train section has no
    # language field; the query itself takes well under a second)
    action = json.loads((args.data.parent / "scene.json").read_text())["actions"][0]
    box = args.out / "remove_box.json"
    box.write_text(json.dumps(action["source_box"]))
    out = args.out / "removed"
    runs = []
    for _ in range(args.repeat):
        subprocess.run(["rm", "-rf", str(out)], check=True)
        t0 = time.perf_counter()
        argv = neo("remove", str(scene_dir), "--box", str(box), "--out", str(out))
        subprocess.run(argv, check=True)
        wall = time.perf_counter() - t0
        edit = json.loads((out / "scene.json").read_text())["edits"][-1]
        runs.append({"wall_s": round(wall, 1), "edit": edit.get("seconds"), **edit["timings"]})
        print(f"  {runs[-1]}", flush=True)
    result = {
        "object": action["object"],
        "runs": runs,
        "median_edit_s": float(np.median([r["edit"] or math.nan for r in runs])),
        "median_wall_s": float(np.median([r["wall_s"] for r in runs])),
    }
    post = args.data.parent / "post"
    if (post / "transforms.json").is_file():  # the edit's quality: the post scan's test views
        from neoedit.eval.evaluate import evaluate
        from neoedit.geometry import OrientedBox

        metrics = evaluate(
            load_scene(out), load_scene_data(post), "test",
            out_boxes=[OrientedBox.from_dict(action["source_box"])],
        )  # fmt: skip
        result.update(out_psnr=metrics["out"]["psnr"], full_psnr=metrics["full"]["psnr"])
    print(f"  {dict((k, v) for k, v in result.items() if k != 'runs')}", flush=True)
    return result


WORKER = """
import sys, time
sys.path.insert(0, {bench!r})
from pathlib import Path
from bench_speed import make_trainer, render_loop
kind, data, out = sys.argv[1], Path(sys.argv[2]), Path(sys.argv[3])
if kind == "render":
    render_loop(data, out)
else:
    trainer = make_trainer(data, out, 10**6, None)
    for s in range(20):
        trainer.step(s)
    t0 = time.perf_counter()
    for s in range(20, 140):
        trainer.step(s)
    print(round(time.perf_counter() - t0, 2))
"""


def render_loop(data_dir: Path, scene_dir: Path) -> None:
    """Render the scene's test views over and over (a competing renderer)."""
    scene, data, cams = open_views(scene_dir, data_dir)
    while True:
        for i in data.split["test"]:
            render_view(scene, data, cams, int(i), scene.meta.render)


def contention_section(args: argparse.Namespace) -> dict:
    script = WORKER.format(bench=str(Path(__file__).resolve().parent))
    env = dict(os.environ)

    def start(kind: str, extra: list[str] | None = None) -> subprocess.Popen:
        target = (args.scene or args.out / "scene") if kind == "render" else args.out / "tmp"
        cmd = [*(extra or []), sys.executable, "-c", script, kind, str(args.data), str(target)]
        return subprocess.Popen(cmd, stdout=subprocess.PIPE, text=True, env=env)

    def seconds(p: subprocess.Popen) -> float:
        return float(p.communicate()[0].strip().splitlines()[-1])

    result = {"solo_s": seconds(start("train"))}
    a, b = start("train"), start("train")
    result["two_trainings_s"] = [seconds(a), seconds(b)]
    loop = start("render")
    try:
        result["beside_render_s"] = seconds(start("train"))
    finally:
        loop.kill()
        loop.wait()
    busy = subprocess.Popen(["nice", "-n", "19", sys.executable, "-c", "while True: pass"])
    try:
        result["beside_nice_busy_loop_s"] = seconds(start("train"))
    finally:
        busy.kill()
        busy.wait()
    solo = result["solo_s"]
    result["slowdown"] = {
        "two_trainings": round(max(result["two_trainings_s"]) / solo, 2),
        "beside_render": round(result["beside_render_s"] / solo, 2),
        "beside_nice_busy_loop": round(result["beside_nice_busy_loop_s"] / solo, 2),
    }
    print(f"  {result}", flush=True)
    return result


SECTIONS = {
    "train": train_section,
    "render": render_section,
    "remove": remove_section,
    "contention": contention_section,
}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--data", type=Path, required=True, help="a NEO-Sim pre scan")
    parser.add_argument("--out", type=Path, required=True)
    parser.add_argument(
        "--scene",
        type=Path,
        default=None,
        help="a trained scene for render/remove/contention (default: OUT/scene)",
    )
    parser.add_argument("--only", nargs="*", choices=list(SECTIONS), default=list(SECTIONS))
    parser.add_argument("--fixed-steps", type=int, default=1000)
    parser.add_argument(
        "--repeat", type=int, default=1, help="remove: runs (the figures: their median)"
    )
    args = parser.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    print("$ python " + shlex.join(sys.argv))
    print(
        f"machine: {platform.processor() or platform.machine()}, {os.cpu_count()} cores, "
        f"torch {torch.__version__}, {time.strftime('%Y-%m-%d')}"
    )
    for name in args.only:
        print(f"[{name}]", flush=True)
        result = SECTIONS[name](args)
        (args.out / f"{name}.json").write_text(json.dumps(result, indent=2))


if __name__ == "__main__":
    main()

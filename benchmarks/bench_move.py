"""Pick-and-place on the NEO-Sim pick-and-place scenes, in the layout of the paper's Tables II
and III.

    python benchmarks/bench_move.py --data outputs/neosim_standard --scenes-dir outputs/bench_language --out outputs/bench_move

For each scene: the pre scan's scene (trained by bench_language.py or here, 500 steps) is
edited with the box `neo query` finds for the moved object's name and the motion of
scene.json (``transform_world``), by: the composite preview, NEO full, the Seal-3D-style
baseline and (with --ablations) NEO without virtual views / without 2x2 grid inpainting /
without mask-conditioned training / with field distillation only; plus an oracle trained on
the post scan with the pre scene's budget. Each is evaluated on the post scan's held-out
views: PSNR, SSIM, depth RMSE, E_rep over Out (the source box's silhouette), In (the target
box's), Full and Rest (outside Out). After each edit the object's name is queried on the
new version: IoU with the true target box, and how many of its relevant surface points
remain in the source box. Writes results.json and a strip per scene (truth, pre-edit,
preview, NEO, Seal-3D-style, oracle) to benchmarks/figures/move_strips.png.
"""

from __future__ import annotations

import argparse
import json
import platform
import shlex
import sys
import time
from pathlib import Path

import numpy as np

from neoedit.bench.methods import ABLATIONS, move_edit
from neoedit.cameras.rays import CameraTensors
from neoedit.data import load_scene_data
from neoedit.edit.pipeline import apply_edit
from neoedit.edit.relocate import Motion, Move
from neoedit.errors import NeoError
from neoedit.eval.evaluate import evaluate
from neoedit.geometry import OrientedBox
from neoedit.geometry.box import box_iou_3d
from neoedit.language.localize import QueryConfig, query_scene
from neoedit.language.relevancy import CANONICAL_PHRASES, relevancy
from neoedit.language.text import load_text_encoder
from neoedit.language.training import LanguageTrainConfig
from neoedit.scene import Scene, load_scene, save_scene
from neoedit.training.trainer import TrainConfig, train
from neoedit.utils.io import write_png
from neoedit.viz.contact_sheet import tile_images

MAIN = ("pre-edit", "preview", "neo", "seal3d", "oracle")


def query_check(scene: Scene, name: str, target: OrientedBox, source: OrientedBox) -> dict:
    """IoU of the query box with the true target box, and the share of the object's
    relevant surface points (relevancy above the query threshold) that lie in the true source box."""
    text = load_text_encoder(scene.meta.language.text)  # type: ignore[union-attr]
    try:
        box = query_scene(scene, name, text).box
        iou_t, iou_s = box_iou_3d(box, target), box_iou_3d(box, source)
    except NeoError:
        iou_t = iou_s = 0.0
    pts = scene.surface_points_m
    feats = scene.language.language(pts)  # type: ignore[union-attr]
    rel = relevancy(feats, text.encode([name])[0], text.encode(list(CANONICAL_PHRASES)))
    hot = pts[(rel >= QueryConfig().threshold).cpu()].cpu().numpy()
    at_source = int(source.grown(0.01).contains(hot).sum()) if len(hot) else 0
    return {
        "iou_target": round(iou_t, 3),
        "iou_source": round(iou_s, 3),
        "relevant_points": len(hot),
        "relevant_at_source": at_source,
    }


def run_scene(name: str, args: argparse.Namespace, methods: list[str]) -> tuple[dict, np.ndarray]:
    spec = json.loads((args.data / name / "scene.json").read_text())
    action = spec["actions"][0]
    source = OrientedBox.from_dict(action["source_box"])
    target = OrientedBox.from_dict(action["target_box"])
    transform = np.asarray(action["transform_world"], dtype=np.float64)
    pre_dir = args.scenes_dir / f"{name}_pre"
    if not (pre_dir / "scene.json").is_file():
        train(
            args.data / name / "pre",
            pre_dir,
            TrainConfig(max_steps=args.train_steps, eval_every=0, checkpoint_every=0),
            language=LanguageTrainConfig(),
        )
    pre = load_scene(pre_dir)
    text = load_text_encoder(pre.meta.language.text)  # type: ignore[union-attr]
    found = query_scene(pre, action["object"], text).box
    post = load_scene_data(args.data / name / "post")
    view = int(post.split["test"][0])
    cams = CameraTensors(post.cameras)
    result: dict = {
        "object": action["object"],
        "query_box": found.to_dict(),
        "query_iou_pre": round(box_iou_3d(found, source), 3),
    }
    tiles = [post.images[view]]
    labels = ["post (truth)"]
    for method in methods:
        out = args.out / name / method
        if method == "pre-edit":
            scene, seconds = pre, pre.meta.train_seconds
        elif method == "oracle":
            if not (out / "scene.json").is_file():
                train(
                    args.data / name / "post",
                    out,
                    TrainConfig(max_steps=args.train_steps, eval_every=0, checkpoint_every=0),
                )
            scene = load_scene(out)
            seconds = scene.meta.train_seconds
        else:
            t0 = time.perf_counter()
            edit = move_edit(method, [Motion(found, transform)], 1.0, action["object"])
            # NEO's patch student only (not the preview; the baseline has no such option)
            if isinstance(edit, Move) and not edit.cfg.preview:
                edit.cfg.reuse_removal_patch = args.reuse_removal_patch
            scene = apply_edit(pre, edit)
            seconds = time.perf_counter() - t0
            save_scene(out, scene)
        metrics = evaluate(scene, post, "test", [source], [target], max_views=args.views)
        row = {"seconds": round(seconds, 1), **metrics}
        if method not in ("pre-edit", "oracle") and scene.language is not None:
            row["query"] = query_check(scene, action["object"], target, source)
            row["timings"] = scene.meta.edits[-1].timings
        result[method] = row
        if method in MAIN:
            rgb = scene.render_image(cams, view, post.height, post.width)["rgb"]
            tiles.append((rgb.clamp(0, 1).numpy() * 255).round().astype(np.uint8))
            labels.append(method)
        q = row.get("query", {})
        print(
            f"{name:13s} {method:18s} Out {metrics['out']['psnr']:.2f}  In {metrics['in']['psnr']:.2f}  "
            f"Full {metrics['full']['psnr']:.2f}  Rest {metrics['rest']['psnr']:.2f}  "
            f"time {seconds:.1f} s  query IoU {q.get('iou_target', float('nan'))}",
            flush=True,
        )
    return result, tile_images(tiles, cols=len(tiles), labels=labels)


def table(results: dict, methods: list[str]) -> str:
    head = (
        "| method | "
        + " | ".join(
            f"{r} {m}" for r in ("Out", "In") for m in ("PSNR", "SSIM", "RMSE [m]", "E_rep")
        )
        + " | Full PSNR | Rest PSNR | time [s] | query IoU>=0.5 |"
    )
    rows = [head, "|---|" + "---|" * 12]
    for method in methods:
        have = [r for r in results.values() if method in r]
        if not have:
            continue

        def mean(region: str, metric: str, have: list = have, method: str = method) -> float:
            vals = [
                r[method][region][metric] for r in have if r[method][region][metric] is not None
            ]
            return float(np.mean(vals)) if vals else float("nan")

        cells = [
            f"{mean(r, m):.{4 if m != 'psnr' else 2}f}"
            for r in ("out", "in")
            for m in ("psnr", "ssim", "depth_rmse_m", "e_rep")
        ]
        hits = [r[method]["query"]["iou_target"] >= 0.5 for r in have if "query" in r[method]]
        q = f"{sum(hits)}/{len(hits)}" if hits else "-"
        t = np.mean([r[method]["seconds"] for r in have])
        rows.append(
            f"| {method} (n={len(have)}) | "
            + " | ".join(cells)
            + f" | {mean('full', 'psnr'):.2f} | {mean('rest', 'psnr'):.2f} | {t:.1f} | {q} |"
        )
    return "\n".join(rows)


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--data", type=Path, default=Path("outputs/neosim_standard"))
    parser.add_argument("--scenes-dir", type=Path, default=Path("outputs/bench_language"))
    parser.add_argument("--out", type=Path, default=Path("outputs/bench_move"))
    parser.add_argument("--scenes", nargs="+", default=[f"pick_place_{k}" for k in range(1, 7)])
    parser.add_argument("--methods", nargs="+", default=list(MAIN), choices=[*MAIN, *ABLATIONS])
    parser.add_argument(
        "--views", type=int, default=None, help="held-out views per scene (default: all)"
    )
    parser.add_argument("--train-steps", type=int, default=500, help="pre / oracle budget")
    parser.add_argument("--tag", default="", help="suffix of results/strip files")
    parser.add_argument(
        "--figure",
        type=Path,
        default=None,
        help="where the strips go (default: benchmarks/figures/move_strips{TAG}.png, the "
        "committed figure; give a path under --out for a run that should not replace it)",
    )
    parser.add_argument(
        "--reuse-removal-patch",
        action="store_true",
        help="NEO's moves keep the removal's patch as the source part (MoveConfig option)",
    )
    args = parser.parse_args()
    print("command: python " + " ".join(shlex.quote(a) for a in sys.argv))
    print(f"machine: {platform.machine()}, {platform.system()}, {time.strftime('%Y-%m-%d %H:%M')}")
    res_file = args.out / f"results{args.tag}.json"
    results = json.loads(res_file.read_text()) if res_file.is_file() else {}
    strips = []
    for name in args.scenes:
        row, strip = run_scene(name, args, args.methods)
        results.setdefault(name, {}).update(row)
        strips.append(strip)
        args.out.mkdir(parents=True, exist_ok=True)
        res_file.write_text(json.dumps(results, indent=1))
    print(table(results, [*MAIN, *ABLATIONS]))
    if any(m in MAIN for m in args.methods):
        figure = args.figure or Path(f"benchmarks/figures/move_strips{args.tag}.png")
        write_png(figure, np.concatenate(strips, 0))


if __name__ == "__main__":
    main()

"""The 4-step assembly of NEO-Sim (paper Sec. V-C, VI-D, Fig. 7): one scan, four moves, each
predicted from the previous *edited* version.

    python benchmarks/bench_assembly.py --data outputs/neosim_asm/assembly --out outputs/bench_assembly

Inputs are only the pre scan and the four moves (the object's name and the relative world
transform of scene.json); every post_k scan is ground truth. For each step k the object is
found by a query of its name on the current version (IoU with the true box before the
move), moved, and the new version is evaluated against post_k's held-out views: PSNR, SSIM,
depth RMSE, E_rep over Full, Out (the source box's silhouette) and In (the target box's).
Rows: NEO (written into a scene store: storage per step), the same chain with the
Seal-3D-style baseline, and an oracle trained on each post_k with the pre scene's budget.
Writes results.json and benchmarks/figures/assembly.png (predicted views over ground truth,
initial state and every step).
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

from neoedit.bench.methods import move_edit
from neoedit.cameras.rays import CameraTensors
from neoedit.data import load_scene_data
from neoedit.edit.pipeline import apply_edit
from neoedit.edit.relocate import Motion
from neoedit.errors import NeoError
from neoedit.eval.evaluate import evaluate
from neoedit.geometry import OrientedBox
from neoedit.geometry.box import box_iou_3d
from neoedit.language.localize import query_scene
from neoedit.language.text import load_text_encoder
from neoedit.language.training import LanguageTrainConfig
from neoedit.scene import Scene, load_scene, save_scene
from neoedit.storage import SceneStore
from neoedit.training.trainer import TrainConfig, train
from neoedit.utils.io import write_png
from neoedit.viz.contact_sheet import tile_images


def trained(data: Path, out: Path, steps: int, language: bool) -> Scene:
    if not (out / "scene.json").is_file():
        train(
            data,
            out,
            TrainConfig(max_steps=steps, eval_every=0, checkpoint_every=0),
            language=LanguageTrainConfig() if language else None,
        )
    return load_scene(out)


def render_view(scene: Scene, data, view: int) -> np.ndarray:
    rgb = scene.render_image(CameraTensors(data.cameras), view, data.height, data.width)["rgb"]
    return (rgb.clamp(0, 1).numpy() * 255).round().astype(np.uint8)


def run_chain(method: str, pre: Scene, args: argparse.Namespace, actions: list) -> dict:
    """The four moves by ``method``, each from the previous version; per-step metrics."""
    store = SceneStore.create(args.out / f"{method}_store") if method == "neo" else None
    if store is not None and "step_0" not in store.names():
        save_scene(store.root / "step_0", pre)
    scene, rows, tiles = pre, [], []
    text = load_text_encoder(pre.meta.language.text)  # type: ignore[union-attr]
    for k, action in enumerate(actions, 1):
        post = load_scene_data(args.data / f"post_{k}")
        source = OrientedBox.from_dict(action["source_box"])
        target = OrientedBox.from_dict(action["target_box"])
        try:
            found = query_scene(scene, action["object"], text).box
        except NeoError as e:
            rows.append({"step": k, "object": action["object"], "error": str(e)})
            print(f"{method} step {k}: query failed: {e}", flush=True)
            break
        transform = np.asarray(action["transform_world"], dtype=np.float64)
        t0 = time.perf_counter()
        child = apply_edit(
            scene, move_edit(method, [Motion(found, transform)], 1.0, action["object"])
        )
        seconds = time.perf_counter() - t0
        if store is not None:
            save_scene(store.root / f"step_{k}", child)
        metrics = evaluate(child, post, "test", [source], [target], max_views=args.views)
        row = {
            "step": k,
            "object": action["object"],
            "query_iou": round(box_iou_3d(found, source), 3),
            "seconds": round(seconds, 1),
            **metrics,
        }
        if store is not None:
            row["store_mb"] = round(store.size_bytes() / 1e6, 1)
        rows.append(row)
        tiles.append(render_view(child, post, int(post.split["test"][args.view])))
        print(
            f"{method:7s} step {k} {action['object']:20s} IoU {row['query_iou']:.2f}  "
            f"Full {metrics['full']['psnr']:.2f}  Out {metrics['out']['psnr']:.2f}  "
            f"In {metrics['in']['psnr']:.2f}  time {seconds:.1f} s",
            flush=True,
        )
        scene = child
    return {"rows": rows, "tiles": tiles}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--data", type=Path, default=Path("outputs/neosim_asm/assembly"))
    parser.add_argument("--out", type=Path, default=Path("outputs/bench_assembly"))
    parser.add_argument("--methods", nargs="+", default=["neo", "seal3d", "oracle"])
    parser.add_argument("--train-steps", type=int, default=500, help="pre / oracle budget")
    parser.add_argument("--views", type=int, default=6, help="held-out views evaluated")
    parser.add_argument("--view", type=int, default=0, help="held-out view of the figure")
    parser.add_argument(
        "--figure",
        type=Path,
        default=Path("benchmarks/figures/assembly.png"),
        help="where the figure goes (default: the committed one; give a path under --out "
        "for a run that should not replace it)",
    )
    args = parser.parse_args()
    print("command: python " + " ".join(shlex.quote(a) for a in sys.argv))
    print(f"machine: {platform.machine()}, {platform.system()}, {time.strftime('%Y-%m-%d %H:%M')}")
    spec = json.loads((args.data / "scene.json").read_text())
    actions = spec["actions"]
    pre = trained(args.data / "pre", args.out / "pre", args.train_steps, language=True)
    pre_data = load_scene_data(args.data / "pre")
    results: dict = {"pre_train_seconds": pre.meta.train_seconds}
    view0 = int(pre_data.split["test"][args.view])
    figure = {"truth": [pre_data.images[view0]], "initial": render_view(pre, pre_data, view0)}
    for k in range(1, len(actions) + 1):
        post = load_scene_data(args.data / f"post_{k}")
        figure["truth"].append(post.images[int(post.split["test"][args.view])])
    for method in args.methods:
        if method == "oracle":
            rows = []
            for k, action in enumerate(actions, 1):
                post = load_scene_data(args.data / f"post_{k}")
                oracle = trained(
                    args.data / f"post_{k}", args.out / f"oracle_{k}", args.train_steps, False
                )
                boxes = [OrientedBox.from_dict(action[b]) for b in ("source_box", "target_box")]
                metrics = evaluate(oracle, post, "test", boxes[:1], boxes[1:], max_views=args.views)
                rows.append({"step": k, "seconds": oracle.meta.train_seconds, **metrics})
                print(
                    f"oracle  step {k} Full {metrics['full']['psnr']:.2f}  In {metrics['in']['psnr']:.2f}",
                    flush=True,
                )
            results["oracle"] = {"rows": rows}
            continue
        chain = run_chain(method, pre, args, actions)
        results[method] = {"rows": chain["rows"]}
        figure[method] = chain["tiles"]
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "results.json").write_text(json.dumps(results, indent=1))
    # Fig. 7: predicted views (NEO) over ground truth, initial state then each step
    predicted = [figure["initial"], *figure.get("neo", [])]
    n = len(predicted)
    labels = ["initial"] + [f"NEO step {k}" for k in range(1, n)]
    labels += ["truth: pre"] + [f"truth: post_{k}" for k in range(1, n)]
    write_png(
        args.figure,
        tile_images([*predicted, *figure["truth"][:n]], cols=n, labels=labels),
    )
    print(json.dumps(summary(results), indent=1))


def summary(results: dict) -> dict:
    out = {}
    for method, res in results.items():
        if not isinstance(res, dict) or "rows" not in res:
            continue
        out[method] = [
            {
                "step": r["step"],
                **({"iou": r["query_iou"]} if "query_iou" in r else {}),
                **{reg: r[reg]["psnr"] for reg in ("full", "out", "in") if reg in r},
                "seconds": r.get("seconds"),
            }
            for r in res["rows"]
            if "full" in r
        ]
    return out


if __name__ == "__main__":
    main()

"""Object removal on the NEO-Sim removal scenes, in the layout of the paper's Table I.

    python benchmarks/bench_remove.py --data outputs/neosim_standard --scenes-dir outputs/bench_language --out outputs/bench_remove

For each removal scene: the pre scan's scene (trained by bench_language.py, or here with
--train-steps) is edited with the box that `neo query` finds for the removed object's
name, four ways: resampling only (no inpainting), DFF-style density suppression, NEO full
(resampling + multiview-consistent progressive inpainting), and an oracle field trained on
the post scan with the pre scene's budget. Each is evaluated on the post scan's held-out
views: PSNR, SSIM, depth RMSE, E_rep over the full image ("Full"), the removed object's
projected ground-truth box ("Out") and the rest ("Rest"); plus the edit / training time.
Writes results.json, and a before/after strip per scene to benchmarks/figures/.
"""

from __future__ import annotations

import argparse
import json
import platform
import shlex
import sys
import time
from pathlib import Path

import imageio.v3 as iio
import numpy as np

from neoedit.cameras.rays import CameraTensors
from neoedit.data import load_scene_data
from neoedit.edit.remove import RemoveConfig, remove_object
from neoedit.eval.evaluate import evaluate
from neoedit.geometry import OrientedBox
from neoedit.language.localize import query_scene
from neoedit.language.text import load_text_encoder
from neoedit.scene import load_scene
from neoedit.training.trainer import TrainConfig, train
from neoedit.utils.io import write_png
from neoedit.viz.contact_sheet import tile_images

METHODS = ("pre-edit", "resample", "suppress", "neo", "oracle")


def run_scene(
    name: str,
    data_root: Path,
    scenes_dir: Path,
    out: Path,
    steps: int,
    previous: dict | None = None,
    rerun: tuple[str, ...] = METHODS,
) -> tuple[dict, np.ndarray]:
    """Edit, evaluate and picture one scene; methods not in ``rerun`` keep their figures
    from ``previous`` (an earlier results.json entry; same query box)."""
    spec = json.loads((data_root / name / "scene.json").read_text())
    action = spec["actions"][0]
    truth = OrientedBox.from_dict(action["source_box"])
    pre_dir = scenes_dir / f"{name}_pre"
    pre = load_scene(pre_dir)
    text = load_text_encoder(pre.meta.language.text)
    t0 = time.perf_counter()
    found = query_scene(pre, action["object"], text)
    query_s = time.perf_counter() - t0
    dirs = {"pre-edit": pre_dir}
    seconds = {"pre-edit": pre.meta.train_seconds}
    for method, cfg in (
        ("resample", RemoveConfig(inpaint=False, removal="resample")),
        ("suppress", RemoveConfig(inpaint=False, removal="suppress")),
        ("neo", RemoveConfig()),
    ):
        dirs[method] = out / name / method
        if previous is not None and method not in rerun:
            continue
        t0 = time.perf_counter()
        remove_object(pre_dir, dirs[method], [found.box], cfg, action["object"], overwrite=True)
        seconds[method] = time.perf_counter() - t0
    dirs["oracle"] = out / name / "oracle"
    if not (dirs["oracle"] / "scene.json").is_file():
        train(
            data_root / name / "post",
            dirs["oracle"],
            TrainConfig(max_steps=steps, eval_every=0, checkpoint_every=0),
        )
    seconds["oracle"] = load_scene(dirs["oracle"]).meta.train_seconds
    post = load_scene_data(data_root / name / "post")
    result = {
        "object": action["object"],
        "query_box": found.box.to_dict(),
        "truth_box": truth.to_dict(),
        "query_s": round(query_s, 2),
    }
    tiles = [post.images[int(post.split["test"][0])]]
    cams = CameraTensors(post.cameras)
    view = int(post.split["test"][0])
    for method in METHODS:
        scene = load_scene(dirs[method])
        if previous is not None and method not in rerun:
            result[method] = previous[method]
            metrics = result[method]
        else:
            metrics = evaluate(scene, post, "test", out_boxes=[truth])
            result[method] = {"seconds": round(seconds[method], 1), **metrics}
        rgb = scene.render_image(cams, view, post.height, post.width)["rgb"]
        tiles.append((rgb.clamp(0, 1).numpy() * 255).round().astype(np.uint8))
        print(
            f"{name:10s} {method:9s} Full PSNR {metrics['full']['psnr']:.2f}  Out PSNR {metrics['out']['psnr']:.2f}  "
            f"Rest PSNR {metrics['rest']['psnr']:.2f}  time {result[method]['seconds']:.1f} s",
            flush=True,
        )
    return result, tile_images(tiles, cols=len(tiles), labels=["post (truth)", *METHODS])


def table(results: dict) -> str:
    rows = [
        "| method | Full PSNR | Full SSIM | Full depth RMSE [m] | Full E_rep | Out PSNR | Out SSIM | Out depth RMSE [m] | Out E_rep | Rest PSNR | time [s] |",
        "|---|" + "---|" * 10,
    ]
    for method in METHODS:

        def mean(region: str, metric: str, method: str = method) -> float:
            vals = [
                r[method][region][metric]
                for r in results.values()
                if r[method][region][metric] is not None
            ]
            return float(np.mean(vals)) if vals else float("nan")

        t = np.mean([r[method]["seconds"] for r in results.values()])
        rows.append(
            f"| {method} | {mean('full', 'psnr'):.2f} | {mean('full', 'ssim'):.3f} | {mean('full', 'depth_rmse_m'):.4f} | "
            f"{mean('full', 'e_rep'):.4f} | {mean('out', 'psnr'):.2f} | {mean('out', 'ssim'):.3f} | "
            f"{mean('out', 'depth_rmse_m'):.4f} | {mean('out', 'e_rep'):.4f} | {mean('rest', 'psnr'):.2f} | {t:.1f} |"
        )
    return "\n".join(rows)


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--data", type=Path, default=Path("outputs/neosim_standard"))
    parser.add_argument("--scenes-dir", type=Path, default=Path("outputs/bench_language"))
    parser.add_argument("--out", type=Path, default=Path("outputs/bench_remove"))
    parser.add_argument("--scenes", nargs="+", default=[f"removal_{k}" for k in range(1, 6)])
    parser.add_argument(
        "--train-steps", type=int, default=500, help="oracle budget (= the pre scenes')"
    )
    parser.add_argument(
        "--rerun",
        nargs="+",
        choices=METHODS,
        default=list(METHODS),
        help="methods to run again; the others keep their figures from OUT/results.json",
    )
    args = parser.parse_args()
    print("command: python " + " ".join(shlex.quote(a) for a in sys.argv))
    print(f"machine: {platform.machine()}, {platform.system()}")
    old_file = args.out / "results.json"
    old = json.loads(old_file.read_text()) if old_file.is_file() else {}
    results, strips = dict(old), []
    for name in args.scenes:
        results[name], strip = run_scene(
            name,
            args.data,
            args.scenes_dir,
            args.out,
            args.train_steps,
            old.get(name) if set(args.rerun) != set(METHODS) else None,
            tuple(args.rerun),
        )
        write_png(args.out / name / "strip.png", strip)
        args.out.mkdir(parents=True, exist_ok=True)
        (args.out / "results.json").write_text(json.dumps(results, indent=1))
    print(table(results))
    # the figure holds every scene in results.json whose strip exists (earlier runs included)
    for name in sorted(results):
        if (args.out / name / "strip.png").is_file():
            strips.append(iio.imread(args.out / name / "strip.png"))
    write_png(Path("benchmarks/figures/removal_strips.png"), np.concatenate(strips, 0))


if __name__ == "__main__":
    main()

"""Radiance-field speed and quality on this machine.

    python benchmarks/bench_field.py encoding
    python benchmarks/bench_field.py train --scenes removal_1 removal_4 --minutes 3 --data outputs/neosim_standard

``encoding``: hash-grid forward+backward throughput, compiled (numba) vs PyTorch.
``train``: trains on NEO-Sim ``standard`` pre scans (and a Blender-format copy of the first
one) for a fixed time budget, evaluating held-out PSNR along the way; prints the curves
and training throughput and plots them to benchmarks/figures/psnr_vs_time.png.
"""

from __future__ import annotations

import argparse
import json
import platform
import shlex
import shutil
import sys
import time
from pathlib import Path

import numpy as np
import torch

from neoedit.data import load_scene_data
from neoedit.fields.hashgrid import HashGridConfig, HashGridEncoding
from neoedit.training.trainer import TrainConfig, train
from neoedit.utils.io import write_png


def bench_encoding(n_points: int, repeats: int) -> None:
    x = torch.rand(n_points, 3, generator=torch.Generator().manual_seed(0))
    rows = []
    for log2 in (16, 18):
        cfg = HashGridConfig(log2_hashmap_size=log2)
        rates = {}
        for backend in ("numba", "torch"):
            enc = HashGridEncoding(HashGridConfig(**{**cfg.__dict__, "backend": backend}))
            for _ in range(2):  # warm-up (and JIT compile)
                enc(x).sum().backward()
            times = []
            for _ in range(repeats):
                t0 = time.perf_counter()
                y = enc(x)
                y.backward(torch.ones_like(y))
                times.append(time.perf_counter() - t0)
            rates[backend] = n_points / float(np.median(times))
        rows.append((log2, rates["numba"], rates["torch"], rates["numba"] / rates["torch"]))
    print(
        f"hash-grid encoding fwd+bwd, {n_points} points, 16 levels x 2 features, median of {repeats}"
    )
    print("| log2 T | numba (points/s) | PyTorch (points/s) | speed-up |\n|---|---|---|---|")
    for log2, a, b, s in rows:
        print(f"| {log2} | {a / 1e6:.2f} M | {b / 1e6:.2f} M | {s:.1f}x |")


def blender_copy(scan: Path, out: Path) -> Path:
    """Write a NEO-Sim scan in the Blender synthetic format (RGBA, alpha 0 on background)."""
    data = load_scene_data(scan)
    if out.exists():
        shutil.rmtree(out)
    angle = 2 * np.arctan(0.5 * data.width / data.cameras.fx[0])
    for split in ("train", "test"):
        frames = []
        for k, i in enumerate(data.split[split]):
            alpha = np.where(data.instance_ids[i] > 0, 255, 0).astype(np.uint8)
            write_png(
                out / split / f"r_{k}.png", np.concatenate([data.images[i], alpha[..., None]], -1)
            )
            frames.append(
                {
                    "file_path": f"./{split}/r_{k}",
                    "transform_matrix": data.cameras.camera_to_world[i].tolist(),
                }
            )
        (out / f"transforms_{split}.json").write_text(
            json.dumps({"camera_angle_x": float(angle), "frames": frames})
        )
    return out


def bench_train(
    data_root: Path, scenes: list[str], minutes: float, eval_every: int, out_root: Path
) -> None:
    runs = {f"{name}/pre": data_root / name / "pre" for name in scenes}
    runs[f"{scenes[0]}/pre (Blender format)"] = blender_copy(
        data_root / scenes[0] / "pre", out_root / "blender_copy"
    )
    curves = {}
    for label, path in runs.items():
        out = out_root / label.replace("/", "_").replace(" ", "_").replace("(", "").replace(")", "")
        shutil.rmtree(out, ignore_errors=True)
        cfg = TrainConfig(
            max_steps=100_000, max_minutes=minutes, eval_every=eval_every, eval_views=4
        )
        t0 = time.perf_counter()
        scene = train(path, out, cfg, device="cpu")
        wall = time.perf_counter() - t0
        rays = scene.meta.step * cfg.rays_per_batch
        curves[label] = scene.meta.history
        last = scene.meta.history[-1]
        print(
            f"\n{label}: {scene.meta.step} steps, {scene.meta.train_seconds:.0f} s training "
            f"({wall:.0f} s with evaluation), {rays / scene.meta.train_seconds:.0f} rays/s, "
            f"held-out PSNR {last['eval_psnr']} dB"
        )
        print("| step | training s | train PSNR | held-out PSNR |\n|---|---|---|---|")
        for h in scene.meta.history:
            print(f"| {h['step']} | {h['seconds']} | {h['train_psnr']} | {h['eval_psnr']} |")
    _plot(curves, Path("benchmarks/figures/psnr_vs_time.png"))


def _plot(curves: dict, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6, 4))
    for label, hist in curves.items():
        ax.plot(
            [h["seconds"] for h in hist], [h["eval_psnr"] for h in hist], marker="o", label=label
        )
    ax.axhline(30, color="gray", ls="--", lw=0.8)
    ax.set_xlabel("training time [s] (2 CPU cores)")
    ax.set_ylabel("held-out PSNR [dB]")
    ax.legend(fontsize=8)
    ax.grid(alpha=0.3)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    print(f"plot: {path}")


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    sub = parser.add_subparsers(dest="what", required=True)
    e = sub.add_parser("encoding")
    e.add_argument("--points", type=int, default=65536)
    e.add_argument("--repeats", type=int, default=7)
    t = sub.add_parser("train")
    t.add_argument("--data", type=Path, default=Path("outputs/neosim_standard"))
    t.add_argument("--scenes", nargs="+", default=["removal_1", "removal_4"])
    t.add_argument("--minutes", type=float, default=3.0)
    t.add_argument("--eval-every", type=int, default=250)
    t.add_argument("--out", type=Path, default=Path("outputs/bench_field"))
    args = parser.parse_args()
    print(f"command: python {shlex.join(sys.argv)}")
    print(
        f"machine: {platform.machine()}, {torch.get_num_threads()} torch threads, torch {torch.__version__}"
    )
    if args.what == "encoding":
        bench_encoding(args.points, args.repeats)
    else:
        bench_train(args.data, args.scenes, args.minutes, args.eval_every, args.out)


if __name__ == "__main__":
    main()

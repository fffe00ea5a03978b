"""Where a move's In error lies: the moved object's pixels or the support around it.

    python benchmarks/bench_in_split.py --sim /tmp/neosim/pick_place_1 --scenes MOVED ORACLE
    python benchmarks/bench_in_split.py --sim /tmp/neosim/pick_place_1 --scan pre --scenes PRE

For each scene version (a NEO move of the scan's pre field, the oracle trained on its post
scan, ...) rendered at the post scan's held-out views: the PSNR over the target box's pixels
("In", the benchmark's region) pooled over the views, split into the object's pixels (the
post scan's instance labels) and the rest of the box (the support and what lies behind),
each part's share of the In error, and the object's mean colour offset (rendered - truth,
0-255): a lighting or colour bias shows there, detail and edges do not.
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

import neoedit
from neoedit.data.load import load_scene_data
from neoedit.eval.evaluate import render_views
from neoedit.geometry import OrientedBox
from neoedit.geometry.masks import masks_for_boxes
from neoedit.scene import load_scene

FIGURE_VIEWS = 3
"""Held-out views drawn by ``--figure``."""


def split(scene_dir: Path, sim: Path, scan: str = "post") -> dict:
    """In, object and rest at ``scan``'s held-out views: "post" over the action's target
    box, "pre" over the object's box where it stood (what the edit starts from)."""
    action = json.loads((sim / "scene.json").read_text())["actions"][0]
    objects = json.loads((sim / scan / "objects.json").read_text())
    if scan == "post":
        target = OrientedBox.from_dict(action["target_box"])
    else:
        placed = next(o for o in objects["objects"] if o["name"] == action["object"])
        target = OrientedBox.from_dict(placed["box"])
    data = load_scene_data(sim / scan)
    if data.instance_ids is None:
        raise SystemExit(f"{sim}/{scan} has no instance labels")
    obj_id = next(i["id"] for i in objects["instances"] if i["name"] == action["object"])
    indices = [int(i) for i in data.indices("test")]
    renders = render_views(load_scene(scene_dir, "cpu"), data, indices)
    sums = {"in": [0.0, 0], "object": [0.0, 0], "rest": [0.0, 0]}
    offsets, crops = [], []
    for k, i in enumerate(indices):
        truth = data.images[i].astype(np.float32) / 255
        pred = renders[k]["rgb"].clip(0, 1)
        inside = masks_for_boxes(data.cameras, i, [target])
        if k < FIGURE_VIEWS and inside.any():
            ys, xs = np.nonzero(masks_for_boxes(data.cameras, i, [target.grown(0.02)]))
            window = np.s_[ys.min() : ys.max() + 1, xs.min() : xs.max() + 1]
            crops.append((truth[window], pred[window]))
        obj = inside & (data.instance_ids[i] == obj_id)
        err = ((pred - truth) ** 2).mean(-1)
        for key, m in (("in", inside), ("object", obj), ("rest", inside & ~obj)):
            sums[key][0] += float(err[m].sum())
            sums[key][1] += int(m.sum())
        if obj.any():
            offsets.append((pred[obj] - truth[obj]).mean(0))
    total = sums["in"][0]
    out = {
        key: {
            "psnr": round(float(-10 * np.log10(max(s / max(n, 1), 1e-12))), 2),
            "share": round(s / max(total, 1e-12), 2),
        }
        for key, (s, n) in sums.items()
    }
    out["colour_offset"] = [round(float(v) * 255, 1) for v in np.mean(offsets, 0)]
    out["crops"] = crops
    return out


def figure(path: Path, results: list[tuple[Path, dict]]) -> None:
    """Rows: the first held-out views; columns: the truth, then each scene (its In PSNR)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rows = min(len(r["crops"]) for _, r in results)
    if rows == 0:
        print(f"no figure: the first {FIGURE_VIEWS} held-out views do not see the box")
        return
    cols = 1 + len(results)
    fig, axes = plt.subplots(rows, cols, figsize=(2.4 * cols, 2.4 * rows), squeeze=False)
    for row in range(rows):
        axes[row, 0].imshow(results[0][1]["crops"][row][0])
        for col, (scene, r) in enumerate(results, start=1):
            axes[row, col].imshow(r["crops"][row][1])
            if row == 0:
                axes[row, col].set_title(f"{scene.name}\nIn {r['in']['psnr']} dB", fontsize=9)
    axes[0, 0].set_title("truth", fontsize=9)
    for ax in axes.ravel():
        ax.axis("off")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    print(f"figure: {path}")


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--sim", type=Path, required=True, help="a NEO-Sim pick-and-place scene")
    parser.add_argument("--scenes", type=Path, nargs="+", required=True)
    parser.add_argument("--figure", type=Path, help="write the target box's crops here (PNG)")
    parser.add_argument(
        "--scan",
        choices=("post", "pre"),
        default="post",
        help="post: the moved object at the post scan's views (an edit, the oracle); pre: "
        "the object where it stood, at the pre scan's views (the field an edit starts from)",
    )
    args = parser.parse_args()
    print("command: python " + " ".join(shlex.quote(a) for a in sys.argv))
    print(f"code: {Path(neoedit.__file__).parent}; machine: {platform.machine()}, "
          f"{time.strftime('%Y-%m-%d %H:%M')}")  # fmt: skip
    print(
        "| scene | In PSNR | object PSNR (share of In error) | rest PSNR (share) | object colour offset |"
    )
    print("|---|---|---|---|---|")
    results = []
    for scene in args.scenes:
        r = split(scene, args.sim, args.scan)
        results.append((scene, r))
        print(f"| {scene} | {r['in']['psnr']} | {r['object']['psnr']} ({r['object']['share']}) | "
              f"{r['rest']['psnr']} ({r['rest']['share']}) | {r['colour_offset']} |", flush=True)  # fmt: skip
    if args.figure:
        figure(args.figure, results)


if __name__ == "__main__":
    main()

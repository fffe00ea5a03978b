"""Where a move's In error lies: the moved object's pixels or the support around it.

    python benchmarks/bench_in_split.py --sim /tmp/neosim/pick_place_1 --scenes MOVED ORACLE

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


def split(scene_dir: Path, sim: Path) -> dict:
    action = json.loads((sim / "scene.json").read_text())["actions"][0]
    target = OrientedBox.from_dict(action["target_box"])
    data = load_scene_data(sim / "post")
    if data.instance_ids is None:
        raise SystemExit(f"{sim}/post has no instance labels")
    instances = json.loads((sim / "post/objects.json").read_text())["instances"]
    obj_id = next(i["id"] for i in instances if i["name"] == action["object"])
    indices = [int(i) for i in data.indices("test")]
    renders = render_views(load_scene(scene_dir, "cpu"), data, indices)
    sums = {"in": [0.0, 0], "object": [0.0, 0], "rest": [0.0, 0]}
    offsets = []
    for k, i in enumerate(indices):
        truth = data.images[i].astype(np.float32) / 255
        pred = renders[k]["rgb"].clip(0, 1)
        inside = masks_for_boxes(data.cameras, i, [target])
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
    return out


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--sim", type=Path, required=True, help="a NEO-Sim pick-and-place scene")
    parser.add_argument("--scenes", type=Path, nargs="+", required=True)
    args = parser.parse_args()
    print("command: python " + " ".join(shlex.quote(a) for a in sys.argv))
    print(f"code: {Path(neoedit.__file__).parent}; machine: {platform.machine()}, "
          f"{time.strftime('%Y-%m-%d %H:%M')}")  # fmt: skip
    print(
        "| scene | In PSNR | object PSNR (share of In error) | rest PSNR (share) | object colour offset |"
    )
    print("|---|---|---|---|---|")
    for scene in args.scenes:
        r = split(scene, args.sim)
        print(f"| {scene} | {r['in']['psnr']} | {r['object']['psnr']} ({r['object']['share']}) | "
              f"{r['rest']['psnr']} ({r['rest']['share']}) | {r['colour_offset']} |", flush=True)  # fmt: skip


if __name__ == "__main__":
    main()

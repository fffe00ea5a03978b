"""Which OpenCV inpainter makes the best removals: Out-PSNR of `neo remove` with each.

    python benchmarks/bench_inpainters.py --scenes removal_1 removal_2

Uses the pre scenes of bench_language.py and the post scans' held-out views, like
neo bench's Table I; only the inpainter changes.
"""

from __future__ import annotations

import argparse
import json
import shlex
import sys
from pathlib import Path

import numpy as np

from neoedit.data import load_scene_data
from neoedit.edit.remove import RemoveConfig, remove_object
from neoedit.eval.evaluate import evaluate
from neoedit.geometry import OrientedBox
from neoedit.language.localize import query_scene
from neoedit.language.text import load_text_encoder
from neoedit.scene import load_scene


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--data", type=Path, default=Path("outputs/neosim_standard"))
    parser.add_argument("--scenes-dir", type=Path, default=Path("outputs/bench_language"))
    parser.add_argument("--out", type=Path, default=Path("outputs/bench_inpainters"))
    parser.add_argument("--scenes", nargs="+", default=["removal_1", "removal_2"])
    parser.add_argument("--methods", nargs="+", default=["telea", "ns", "fsr"])
    args = parser.parse_args()
    print("command: python " + " ".join(shlex.quote(a) for a in sys.argv))
    table: dict[str, dict[str, float]] = {}
    for name in args.scenes:
        action = json.loads((args.data / name / "scene.json").read_text())["actions"][0]
        pre_dir = args.scenes_dir / f"{name}_pre"
        pre = load_scene(pre_dir)
        box = query_scene(pre, action["object"], load_text_encoder(pre.meta.language.text)).box
        post = load_scene_data(args.data / name / "post")
        truth = OrientedBox.from_dict(action["source_box"])
        for method in args.methods:
            out = args.out / name / method
            remove_object(
                pre_dir,
                out,
                [box],
                RemoveConfig(inpainter=method),
                action["object"],
                overwrite=True,
            )
            m = evaluate(load_scene(out), post, "test", out_boxes=[truth])
            table.setdefault(method, {})[name] = m["out"]["psnr"]
            print(
                f"{name} {method}: Out PSNR {m['out']['psnr']:.2f}  Rest PSNR {m['rest']['psnr']:.2f}",
                flush=True,
            )
    print("| inpainter | " + " | ".join(args.scenes) + " | mean |")
    print("|---|" + "---|" * (len(args.scenes) + 1))
    for method, per in table.items():
        vals = [per[s] for s in args.scenes]
        print(f"| {method} | " + " | ".join(f"{v:.2f}" for v in vals) + f" | {np.mean(vals):.2f} |")


if __name__ == "__main__":
    main()

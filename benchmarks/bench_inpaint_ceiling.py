"""How much of the gap to the oracle is the 2-D inpainter's? (a diagnostic, not a method)

    python benchmarks/bench_inpaint_ceiling.py --bench outputs/bench_standard --data outputs/neosim_standard --scenes removal_1 removal_2

Runs `neo remove`'s default pipeline twice per scene with the same box: once with the
default inpainter, once with a *perfect* one that returns what the oracle field (trained
on the post scan, which saw the table under the object) renders in the same virtual-view
crops. The second Out-PSNR is the ceiling of the rest of the pipeline (virtual views,
visibility, patch training, refinement) with ideal 2-D inpainting. Reads a ``neo bench``
run with the scenes' ``neo`` and ``oracle`` units (pre scenes, oracle fields, their Out PSNR).
"""

from __future__ import annotations

import argparse
import json
import shlex
import sys
from pathlib import Path

import numpy as np

from neoedit.bench.folder import RunFolder
from neoedit.bench.methods import found_box
from neoedit.data import load_scene_data
from neoedit.edit.inpaint import tile_2x2
from neoedit.edit.refine import crop_window, render_crops
from neoedit.edit.remove import RemoveConfig, remove_object, working_boxes
from neoedit.edit.views import virtual_cameras
from neoedit.errors import NeoError
from neoedit.eval.evaluate import evaluate
from neoedit.geometry import OrientedBox
from neoedit.geometry.masks import project_box_mask
from neoedit.language.localize import QueryConfig
from neoedit.scene import load_scene


class ReplayInpainter:
    """Fills the mask with the oracle's render of the same composite (in request order)."""

    def __init__(self, composites: list[np.ndarray]):
        self.composites, self.calls = composites, 0

    def inpaint(self, image: np.ndarray, mask: np.ndarray, strength: float) -> np.ndarray:
        truth = self.composites[self.calls % len(self.composites)]
        self.calls += 1
        return np.where(mask[..., None], truth, image)


def oracle_composites(pre_dir: Path, oracle_dir: Path, box: OrientedBox, cfg: RemoveConfig):
    parent, oracle = load_scene(pre_dir), load_scene(oracle_dir)
    (work,) = working_boxes(parent, [box], cfg)
    cameras, _, split = parent.scan_cameras()
    virtual = virtual_cameras(box, cameras.subset(split["train"]), cfg.views)
    masks = [project_box_mask(virtual, i, work) for i in range(len(virtual))]
    window = crop_window(masks, cfg.refine.crop_margin_px)
    crops, _, _ = render_crops(oracle.field, oracle, virtual, window, [])
    return [tile_2x2(crops[k : k + 4]) for k in range(0, len(crops) - 3, 4)]


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument(
        "--data", type=Path, default=None, help="the suite of the bench run (its --data)"
    )
    parser.add_argument("--bench", type=Path, default=Path("outputs/bench_standard"))
    parser.add_argument("--out", type=Path, default=Path("outputs/bench_inpaint_ceiling"))
    parser.add_argument("--scenes", nargs="+", default=["removal_1", "removal_2"])
    parser.add_argument(
        "--image-scale", type=float, default=0.5, help="virtual-view resolution (default 0.5)"
    )
    parser.add_argument(
        "--inpaint-all",
        action="store_true",
        help="fill all of the box silhouette, seen pixels included (no pre-scan shadow left)",
    )
    parser.add_argument("--steps", type=int, default=120, help="patch training steps")
    args = parser.parse_args()
    print("command: python " + " ".join(shlex.quote(a) for a in sys.argv))
    bench = RunFolder(args.bench, args.data)
    try:
        figures = {s: (bench.result(s, "neo"), bench.result(s, "oracle")) for s in args.scenes}
    except NeoError as e:
        parser.error(str(e))
    rows = []
    for name in args.scenes:
        action = json.loads((bench.scene_data(name) / "scene.json").read_text())["actions"][0]
        truth = OrientedBox.from_dict(action["source_box"])
        pre_dir, oracle_dir = bench.trained(name, "pre"), bench.trained(name, "post")
        box = found_box(load_scene(pre_dir), action["object"], QueryConfig())
        cfg = RemoveConfig()
        cfg.views.image_scale = args.image_scale
        cfg.refine.inpaint_unseen_only = not args.inpaint_all
        cfg.refine.steps = args.steps
        replay = ReplayInpainter(oracle_composites(pre_dir, oracle_dir, box, cfg))
        out = (
            args.out
            / name
            / f"neo_perfect_inpainting_{args.image_scale:g}{'_all' if args.inpaint_all else ''}_{args.steps}"
        )
        remove_object(pre_dir, out, [box], cfg, action["object"], overwrite=True, inpainter=replay)
        post = load_scene_data(bench.scene_data(name) / "post")
        m = evaluate(load_scene(out), post, "test", out_boxes=[truth])
        neo, oracle = (f["out"]["psnr"] for f in figures[name])
        rows.append((name, neo, m["out"]["psnr"], oracle))
        print(
            f"{name}: Out-PSNR NEO {rows[-1][1]:.2f}, perfect inpainting {rows[-1][2]:.2f}, oracle {rows[-1][3]:.2f}",
            flush=True,
        )
    print("| scene | NEO (FSR) | NEO with perfect 2-D inpainting | oracle |\n|---|---|---|---|")
    for name, neo, ceiling, oracle in rows:
        print(f"| {name} | {neo:.2f} | {ceiling:.2f} | {oracle:.2f} |")


if __name__ == "__main__":
    main()

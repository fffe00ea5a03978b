"""Strips of the pick-and-place benchmark's versions: one held-out view of the post scan
per scene — ground truth, pre-edit, preview, NEO, Seal-3D-style, oracle.

    python benchmarks/move_strips.py --out outputs/bench_move --scenes pick_place_1 pick_place_2

Reads the versions bench_move.py saved (OUT/SCENE/METHOD, the pre scenes under
--scenes-dir) and writes benchmarks/figures/move_strips.png.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from neoedit.cameras.rays import CameraTensors
from neoedit.data import load_scene_data
from neoedit.scene import load_scene
from neoedit.utils.io import write_png
from neoedit.viz.contact_sheet import tile_images

METHODS = ("preview", "neo", "seal3d", "oracle")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--data", type=Path, default=Path("outputs/neosim_standard"))
    parser.add_argument("--scenes-dir", type=Path, default=Path("outputs/bench_language"))
    parser.add_argument("--out", type=Path, default=Path("outputs/bench_move"))
    parser.add_argument("--scenes", nargs="+", required=True)
    parser.add_argument("--figure", type=Path, default=Path("benchmarks/figures/move_strips.png"))
    args = parser.parse_args()
    rows = []
    for name in args.scenes:
        post = load_scene_data(args.data / name / "post")
        view = int(post.split["test"][len(post.split["test"]) // 4])
        cams = CameraTensors(post.cameras)
        tiles, labels = [post.images[view]], [f"{name}: post (truth)"]
        dirs = [("pre-edit", args.scenes_dir / f"{name}_pre")]
        dirs += [(m, args.out / name / m) for m in METHODS]
        for label, path in dirs:
            scene = load_scene(path)
            rgb = scene.render_image(cams, view, post.height, post.width)["rgb"]
            tiles.append((rgb.clamp(0, 1).numpy() * 255).round().astype(np.uint8))
            labels.append(label)
        rows.append(tile_images(tiles, cols=len(tiles), labels=labels))
    write_png(args.figure, np.concatenate(rows, 0))
    print(f"wrote {args.figure}")


if __name__ == "__main__":
    main()

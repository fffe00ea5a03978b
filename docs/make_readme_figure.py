"""Regenerate docs/neosim.png from a standard NEO-Sim run.

python benchmarks/bench_sim.py --out outputs/neosim_standard && python docs/make_readme_figure.py
"""

from pathlib import Path

import imageio.v3 as iio

from neoedit.utils.io import write_png
from neoedit.viz.contact_sheet import tile_images

ROOT = Path("outputs/neosim_standard")
VIEWS = {"removal_1": "eval_0004", "pick_place_1": "eval_0006"}
images, labels = [], []
for scene, view in VIEWS.items():
    for scan in ("pre", "post"):
        images.append(iio.imread(ROOT / scene / scan / "images" / f"{view}.png"))
        labels.append(f"{scene} {scan}")
write_png(Path("docs/neosim.png"), tile_images(images, cols=2, labels=labels))

"""Localisation accuracy of `neo query` on the NEO-Sim standard pre scans.

    python benchmarks/bench_language.py --data outputs/neosim_standard --scenes-dir outputs/bench_language --train-steps 500

For every pre scan: train a scene (radiance field for --train-steps, then the language
field from the label teacher) unless one already exists under --scenes-dir, then query
every object by its name and by its paraphrase (neoedit.sim.catalog.PARAPHRASES) and
compare the box with the ground truth in objects.json: 3-D IoU, centre error [cm], yaw
error [deg] modulo the box symmetry. Prints a per-query table and the summary, writes
results.json and a picture of the boxes of one scene to --scenes-dir.
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

from neoedit.errors import NeoError
from neoedit.geometry.box import OrientedBox, box_iou_3d, yaw_error_deg
from neoedit.language.localize import query_scene
from neoedit.language.text import load_text_encoder
from neoedit.language.training import LanguageTrainConfig
from neoedit.scene import load_scene
from neoedit.sim.catalog import PARAPHRASES
from neoedit.training.trainer import TrainConfig, train


def ensure_scene(scan: Path, out: Path, steps: int) -> None:
    if (out / "scene.json").is_file():
        return
    cfg = TrainConfig(max_steps=steps, eval_every=0, checkpoint_every=0)
    train(scan, out, cfg, language=LanguageTrainConfig())


def bench(data: Path, scenes_dir: Path, names: list[str], steps: int) -> list[dict]:
    rows = []
    for name in names:
        scan = data / name / "pre"
        scene_dir = scenes_dir / f"{name}_pre"
        ensure_scene(scan, scene_dir, steps)
        scene = load_scene(scene_dir)
        if scene.meta.language is None:
            raise NeoError(f"{scene_dir} has no language field")
        text = load_text_encoder(scene.meta.language.text)
        objects = json.loads((scan / "objects.json").read_text())["objects"]
        for obj in objects:
            truth = OrientedBox.from_dict(obj["box"])
            for kind, prompt in (
                ("name", obj["name"]),
                ("paraphrase", PARAPHRASES.get(obj["name"])),
            ):
                if prompt is None:
                    continue
                t0 = time.perf_counter()
                try:
                    res = query_scene(scene, prompt, text)
                    box, score = res.box, res.score
                except NeoError:
                    box, score = None, float("nan")
                row = {
                    "scene": name,
                    "object": obj["name"],
                    "prompt": prompt,
                    "kind": kind,
                    "seconds": round(time.perf_counter() - t0, 3),
                    "score": round(score, 4),
                    "iou": 0.0 if box is None else round(box_iou_3d(box, truth), 4),
                    "center_err_cm": None
                    if box is None
                    else round(
                        100 * float(np.linalg.norm(np.subtract(box.center_m, truth.center_m))), 2
                    ),
                    "yaw_err_deg": None if box is None else round(yaw_error_deg(box, truth), 2),
                    "box": None if box is None else box.to_dict(),
                    "truth": truth.to_dict(),
                }
                rows.append(row)
                print(
                    f"{name:13s} {prompt:22s} IoU {row['iou']:.2f}  centre {row['center_err_cm']} cm  "
                    f"yaw {row['yaw_err_deg']} deg  score {row['score']}",
                    flush=True,
                )
    return rows


def summary(rows: list[dict]) -> str:
    iou = np.array([r["iou"] for r in rows])
    found = [r for r in rows if r["box"] is not None]
    cerr = np.array([r["center_err_cm"] for r in found])
    yerr = np.array([r["yaw_err_deg"] for r in found])
    lines = [
        "| queries | no match | IoU >= 0.5 | median IoU | median centre error | median yaw error | median query time |",
        "|---|---|---|---|---|---|---|",
        f"| {len(rows)} | {len(rows) - len(found)} | {100 * np.mean(iou >= 0.5):.1f} % | "
        f"{np.median(iou):.3f} | {np.median(cerr):.2f} cm | {np.median(yerr):.1f} deg | "
        f"{np.median([r['seconds'] for r in rows]):.2f} s |",
    ]
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--data", type=Path, default=Path("outputs/neosim_standard"))
    parser.add_argument("--scenes-dir", type=Path, default=Path("outputs/bench_language"))
    parser.add_argument(
        "--scenes", nargs="+", default=None, help="scene names (default: all in --data)"
    )
    parser.add_argument(
        "--train-steps", type=int, default=500, help="radiance-field steps (~2.5 min here)"
    )
    args = parser.parse_args()
    names = args.scenes or sorted(p.name for p in args.data.iterdir() if (p / "pre").is_dir())
    print("command: python " + " ".join(shlex.quote(a) for a in sys.argv))
    print(f"machine: {platform.processor() or platform.machine()}, {platform.system()}")
    rows = bench(args.data, args.scenes_dir, names, args.train_steps)
    text = summary(rows)
    print(text)
    args.scenes_dir.mkdir(parents=True, exist_ok=True)
    (args.scenes_dir / "results.json").write_text(json.dumps(rows, indent=1))


if __name__ == "__main__":
    main()

"""Localisation accuracy of `neo query` with the label-free geometric teacher.

    python benchmarks/bench_language_free.py --data outputs/neosim_standard \
        --source-dir outputs/bench_language --scenes-dir outputs/bench_language_free

For every NEO-Sim pre scan: take the scene trained by benchmarks/bench_language.py (its
radiance field is reused, never modified), copy it to --scenes-dir and retrain only its
language field with ``--language.teacher geometric`` on the scan with its instance masks
and names withheld; then query every object by its catalogue name and its paraphrase and
score the box against objects.json exactly like bench_language.py (3-D IoU, centre and yaw
error; its query loop and summary are reused). Also queries a few generic prompts
("can", "ball", "box", "the tall object", "the object on the left") and prints the box and
score each gets (no ground truth). Prints the discovered vocabulary per scene, the
per-query table and the summary; writes results.json to --scenes-dir.
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
from bench_language import bench, summary

from neoedit.data import load_scene_data
from neoedit.errors import NeoError
from neoedit.language.localize import query_scene
from neoedit.language.text import load_text_encoder
from neoedit.language.training import LanguageTrainConfig, train_language
from neoedit.scene import load_scene, save_scene

GENERIC = ("can", "ball", "box", "cube", "the tall object", "the object on the left")


def retrain(source: Path, scan: Path, out: Path, cfg: LanguageTrainConfig) -> float:
    """Copy the scene ``source`` to ``out`` (never overwritten) and retrain its language field
    with ``cfg`` on ``scan`` without its labels; returns the seconds it took."""
    if (out / "scene.json").exists():
        return float("nan")  # done by an earlier run
    if not (source / "scene.json").is_file():
        raise NeoError(f"{source} is not a trained scene: run benchmarks/bench_language.py first")
    tmp = out.with_name(out.name + ".partial")
    shutil.rmtree(tmp, ignore_errors=True)
    shutil.copytree(source, tmp, ignore=shutil.ignore_patterns("optimizer.safetensors"))
    data = load_scene_data(scan)
    data.instance_ids, data.instance_names = None, {}  # labels withheld
    scene = load_scene(tmp, "cpu")
    t0 = time.perf_counter()
    train_language(scene, data, cfg)
    seconds = time.perf_counter() - t0
    save_scene(tmp, scene)
    tmp.rename(out)
    return seconds


def generic_queries(scenes_dir: Path, names: list[str]) -> list[dict]:
    rows = []
    for name in names:
        scene = load_scene(scenes_dir / f"{name}_pre")
        text = load_text_encoder(scene.meta.language.text)  # type: ignore[union-attr]
        for prompt in GENERIC:
            try:
                res = query_scene(scene, prompt, text)
                row = {"scene": name, "prompt": prompt, "score": round(res.score, 4)}
                row["box"] = res.box.to_dict()
            except NeoError as e:
                row = {"scene": name, "prompt": prompt, "score": None, "box": None}
                row["why"] = str(e)
            rows.append(row)
            where = "no match" if row["box"] is None else f"centre {row['box']['center']}"
            print(f"{name:13s} {prompt:24s} score {row['score']}  {where}", flush=True)
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--data", type=Path, default=Path("outputs/neosim_standard"))
    parser.add_argument("--source-dir", type=Path, default=Path("outputs/bench_language"))
    parser.add_argument("--scenes-dir", type=Path, default=Path("outputs/bench_language_free"))
    parser.add_argument(
        "--scenes", nargs="+", default=None, help="scene names (default: those in --source-dir)"
    )
    args = parser.parse_args()
    names = args.scenes or sorted(
        p.name.removesuffix("_pre") for p in args.source_dir.glob("*_pre") if p.is_dir()
    )
    print("command: python " + " ".join(shlex.quote(a) for a in sys.argv))
    print(f"machine: {platform.processor() or platform.machine()}, {platform.system()}")
    args.scenes_dir.mkdir(parents=True, exist_ok=True)
    cfg = LanguageTrainConfig(teacher="geometric")
    for name in names:
        out = args.scenes_dir / f"{name}_pre"
        seconds = retrain(args.source_dir / f"{name}_pre", args.data / name / "pre", out, cfg)
        meta = load_scene(out).meta.language
        assert meta is not None and meta.teacher == "geometric", out
        print(f"{name}: language field in {seconds:.1f} s, loss {meta.loss}; vocabulary:")
        for word in meta.vocabulary:
            print(f"    {word}")
    rows = bench(args.data, args.scenes_dir, names, steps=0)
    print(summary(rows))
    named = [r for r in rows if r["kind"] == "name"]
    print(
        f"name queries with IoU >= 0.5: {sum(r['iou'] >= 0.5 for r in named)} / {len(named)} "
        f"({100 * np.mean([r['iou'] >= 0.5 for r in named]):.1f} %)"
    )
    generic = generic_queries(args.scenes_dir, names)
    result = {"queries": rows, "generic": generic}
    (args.scenes_dir / "results.json").write_text(json.dumps(result, indent=1))


if __name__ == "__main__":
    main()

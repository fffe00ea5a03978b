"""A 10-edit chain (small moves and removals, each found by a query on the current edited
version) written into one scene store: storage, render time and drift outside the edits.

    python benchmarks/bench_chain.py --scene outputs/bench_standard/units/train/assembly/pre/scene --data outputs/neosim_standard/assembly/pre --out outputs/bench_chain

Figures (issue targets in brackets): total bytes of the store's 11 versions against one
trained scene (field + language, the files a version needs) [<= 3x]; render time of version
10 against version 0, min of 2 runs over the same held-out views [<= 1.3x]; Rest-PSNR of
version 10 against version 0 on the scan's held-out views, over the pixels outside every
box the chain edited [within 0.5 dB]. ``--student field`` runs the chain with whole-field
students instead of patches (the drift the patches avoid).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import platform
import shlex
import sys
import time
from pathlib import Path

from neoedit.cameras.rays import CameraTensors
from neoedit.data import load_scene_data
from neoedit.edit.plan import PlanConfig, apply_action, parse_plan
from neoedit.eval.evaluate import evaluate
from neoedit.geometry import OrientedBox
from neoedit.language.localize import query_scene
from neoedit.language.text import load_text_encoder
from neoedit.scene import load_scene, save_scene
from neoedit.storage import SceneStore

CHAIN = [
    {"type": "move", "prompt": "green cube", "translate_m": [0.02, 0.0, 0.0]},
    {"type": "remove", "prompt": "blue cube"},
    {"type": "move", "prompt": "red mug", "translate_m": [0.0, 0.015, 0.0], "yaw_deg": 10},
    {"type": "remove", "prompt": "orange cube"},
    {"type": "move", "prompt": "yellow rubber duck", "translate_m": [0.02, -0.01, 0.0]},
    {"type": "move", "prompt": "green cube", "translate_m": [0.0, -0.015, 0.0], "yaw_deg": 5},
    {"type": "move", "prompt": "red mug", "translate_m": [0.02, 0.0, 0.0]},
    {"type": "remove", "prompt": "yellow rubber duck"},
    {"type": "move", "prompt": "green cube", "translate_m": [0.01, 0.0, 0.0]},
    {"type": "remove", "prompt": "red mug"},
]


def render_seconds(path: Path, data, views: list[int], runs: int = 2) -> float:
    scene = load_scene(path)
    cams = CameraTensors(data.cameras)
    best = float("inf")
    for _ in range(runs):
        t0 = time.perf_counter()
        for v in views:
            scene.render_image(cams, v, data.height, data.width)
        best = min(best, time.perf_counter() - t0)
    return best / len(views)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument(
        "--scene",
        type=Path,
        default=Path("outputs/bench_standard/units/train/assembly/pre/scene"),
        help="the assembly pre scan trained with language (neo bench --scenes assembly, or neo train)",
    )
    parser.add_argument(
        "--data",
        type=Path,
        default=Path("outputs/bench_standard/units/sim/assembly/scene/pre"),
        help="the assembly's pre scan (the bench's own simulation; with neo bench --data D: "
        "D/assembly/pre)",
    )
    parser.add_argument("--out", type=Path, default=Path("outputs/bench_chain"))
    parser.add_argument("--student", default="patch", choices=["patch", "field"])
    parser.add_argument("--views", type=int, default=6)
    parser.add_argument(
        "--measure-only", action="store_true", help="re-measure render time on the existing store"
    )
    args = parser.parse_args()
    print("command: python " + " ".join(shlex.quote(a) for a in sys.argv))
    print(f"machine: {platform.machine()}, {platform.system()}, {time.strftime('%Y-%m-%d %H:%M')}")
    root = args.out / f"store_{args.student}"
    data = load_scene_data(args.data)
    if args.measure_only:
        views = [int(i) for i in data.split["test"][: args.views]]
        first = render_seconds(root / "step_0", data, views)
        last = render_seconds(root / f"step_{len(CHAIN)}", data, views)
        print(f"render s/view: v0 {first:.3f}, v10 {last:.3f}, ratio {last / first:.2f}")
        return
    if root.exists():
        raise SystemExit(f"{root} exists: remove it to rerun")
    store = SceneStore.create(root)
    scene = load_scene(args.scene)
    cfg = PlanConfig()
    cfg.move = dataclasses.replace(cfg.move, student=args.student)
    save_scene(root / "step_0", scene)
    text = load_text_encoder(scene.meta.language.text)  # type: ignore[union-attr]
    edited: list[OrientedBox] = []
    steps = []
    for k, action in enumerate(parse_plan(CHAIN), 1):
        t0 = time.perf_counter()
        box = query_scene(scene, action.prompt or "", text).box
        child = apply_action(scene, action, lambda _, box=box: [box], cfg)
        rec = child.meta.edits[-1]
        edited += rec.boxes("source_boxes", "target_boxes", "edit_boxes")
        save_scene(root / f"step_{k}", child)
        nbytes = store.info(f"step_{k}").manifest["bytes"]
        steps.append(
            {
                "step": k,
                "edit": action.label,
                "seconds": round(time.perf_counter() - t0, 1),
                "bytes": nbytes,
            }
        )
        print(
            f"step {k}: {action.label:30s} {steps[-1]['seconds']:6.1f} s  +{nbytes / 1e6:.1f} MB",
            flush=True,
        )
        scene = child
    full = sum(
        (args.scene / f).stat().st_size for f in ("field.safetensors", "language.safetensors")
    )
    optim = (
        (args.scene / "optimizer.safetensors").stat().st_size
        if (args.scene / "optimizer.safetensors").is_file()
        else 0
    )
    total = sum(store.info(n).manifest["bytes"] for n in store.names())
    views = [int(i) for i in data.split["test"][: args.views]]
    t_first = render_seconds(root / "step_0", data, views)
    t_last = render_seconds(root / f"step_{len(CHAIN)}", data, views)
    rest = {}
    for name in ("step_0", f"step_{len(CHAIN)}"):
        m = evaluate(load_scene(root / name), data, "test", edited, [], max_views=args.views)
        rest[name] = m["rest"]
    result = {
        "student": args.student,
        "steps": steps,
        "one_scene_bytes": full,
        "one_scene_with_optimizer_bytes": full + optim,
        "store_tensor_bytes": total,
        "store_disk_bytes": store.size_bytes(),
        "storage_ratio": round(total / full, 2),
        "render_s_per_view": {"v0": round(t_first, 3), "v10": round(t_last, 3)},
        "render_ratio": round(t_last / t_first, 2),
        "rest": rest,
        "rest_psnr_drop_db": round(rest["step_0"]["psnr"] - rest[f"step_{len(CHAIN)}"]["psnr"], 3),
    }
    (args.out / f"results_{args.student}.json").write_text(json.dumps(result, indent=1))
    print(json.dumps({k: v for k, v in result.items() if k not in ("steps", "rest")}, indent=1))
    print(
        f"Rest PSNR v0 {rest['step_0']['psnr']:.2f} dB, v10 {rest[f'step_{len(CHAIN)}']['psnr']:.2f} dB"
    )


if __name__ == "__main__":
    main()

"""What the shadow search changes in a removal, on NEO-Sim removal scenes, with the true box.

    python benchmarks/bench_shadow.py --data /tmp/neosim --scenes-dir /tmp/rm_scenes --scenes removal_1 removal_4 removal_5

For each scene, the pre scan's scene (``SCENES_DIR/<scene>_pre``, e.g. from ``neo train
DATA/<scene>/pre --skip-language``) loses the removed object's ground-truth box twice: with
the shadow search off and with it on (the defaults). Each version is evaluated on the post
scan's held-out views: PSNR over the removed object's projected box ("Out") and over the
image ("Full"), the shadow slabs found and the edit's time. Run it with another checkout on
PYTHONPATH to compare two versions of the search (it uses only ``Remove`` and
``RemoveConfig.shadow.enabled``). The moves' side is ``neo bench --methods neo
no-shadow-follow no-shadow``.
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

import neoedit
from neoedit.data.load import load_scene_data
from neoedit.edit.pipeline import apply_edit
from neoedit.edit.remove import Remove, RemoveConfig
from neoedit.eval.evaluate import evaluate
from neoedit.geometry import OrientedBox
from neoedit.scene import load_scene


def run(name: str, data: Path, scenes_dir: Path, shadow: bool) -> dict:
    spec = json.loads((data / name / "scene.json").read_text())
    truth = OrientedBox.from_dict(spec["actions"][0]["source_box"])
    pre = load_scene(scenes_dir / f"{name}_pre")
    cfg = RemoveConfig()
    cfg = dataclasses.replace(cfg, shadow=dataclasses.replace(cfg.shadow, enabled=shadow))
    t0 = time.perf_counter()
    child = apply_edit(pre, Remove([truth], cfg, spec["actions"][0].get("object")))
    seconds = time.perf_counter() - t0
    m = evaluate(child, load_scene_data(data / name / "post"), "test", out_boxes=[truth])
    slabs = child.meta.edits[-1].details.get("shadow_boxes", [])
    return {
        "out": round(m["out"]["psnr"], 2),
        "full": round(m["full"]["psnr"], 2),
        "slabs": [[round(v, 3) for v in b["size"][:2]] for b in slabs],
        "seconds": round(seconds, 1),
    }


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--data", type=Path, default=Path("outputs/neosim_standard"))
    parser.add_argument("--scenes-dir", type=Path, default=Path("outputs/bench_shadow"))
    parser.add_argument("--scenes", nargs="+", default=[f"removal_{k}" for k in range(1, 6)])
    args = parser.parse_args()
    print("command: python " + " ".join(shlex.quote(a) for a in sys.argv))
    print(f"code: {Path(neoedit.__file__).parent}; machine: {platform.machine()}, "
          f"{time.strftime('%Y-%m-%d %H:%M')}")  # fmt: skip
    print("| scene | shadow search | Out PSNR | Full PSNR | slabs (x, y) [m] | time [s] |")
    print("|---|---|---|---|---|---|")
    for name in args.scenes:
        for shadow in (False, True):
            r = run(name, args.data, args.scenes_dir, shadow)
            print(f"| {name} | {'on' if shadow else 'off'} | {r['out']} | {r['full']} | "
                  f"{r['slabs']} | {r['seconds']} |", flush=True)  # fmt: skip


if __name__ == "__main__":
    main()

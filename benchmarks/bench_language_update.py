"""The language field after edits: the default update (the parent's field read through the
edit's map) against the paper's distilled one, on a trained scene with a language field.

    python benchmarks/bench_language_update.py --scene S --object "red mug" --other "soccer ball" --out O

Per method: a preview move of the object (``--translate``, ``--yaw``; nothing trained:
``preview_s`` is the name's lookup and the language update, ``preview_language_s`` the
update alone), the object found by name on the moved
version (3-D IoU with the edit's target box, centre error), another object found where it
was, then a removal of the moved object (its language update's seconds) and what its name
finds afterwards. Run alone: the seconds are wall time on this machine.
"""

from __future__ import annotations

import argparse
import json
import platform
import shlex
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

import neoedit as neo
from neoedit.edit.language_update import LanguageUpdateConfig
from neoedit.edit.pipeline import apply_edit
from neoedit.edit.relocate import MoveConfig
from neoedit.edit.remove import Remove, RemoveConfig
from neoedit.geometry import OrientedBox
from neoedit.geometry.box import box_iou_3d
from neoedit.language.localize import NoMatch
from neoedit.utils.threads import configure_threads


def _found(scene: neo.EditableScene, name: str) -> OrientedBox | None:
    try:
        return scene.find(name)[0]
    except NoMatch:
        return None


def run_method(
    s: neo.EditableScene, args: argparse.Namespace, method: str, other_before: OrientedBox
) -> dict:
    lang = LanguageUpdateConfig(method=method)
    t0 = time.perf_counter()
    moved = s.move(args.object, args.translate, args.yaw, MoveConfig(language=lang), preview=True)
    row: dict = {"method": method, "preview_s": round(time.perf_counter() - t0, 2)}
    rec = moved.scene.meta.edits[-1]
    row["preview_language_s"] = rec.timings.get("language_s")
    target = OrientedBox.from_dict(rec.details["target_boxes"][0])
    found = _found(moved, args.object)
    if found is not None:
        row["moved_iou"] = round(box_iou_3d(found, target), 3)
        row["moved_centre_mm"] = round(
            1000 * float(np.linalg.norm(np.subtract(found.center_m, target.center_m))), 1
        )
    other = _found(moved, args.other)
    row["other_iou"] = None if other is None else round(box_iou_3d(other, other_before), 3)
    if found is None:
        return row
    t0 = time.perf_counter()
    removed = apply_edit(moved.scene, Remove([found], RemoveConfig(), args.object, language=lang))
    row["remove_s"] = round(time.perf_counter() - t0, 2)
    row["remove_language_s"] = removed.meta.edits[-1].timings.get("language_s")
    after = _found(neo.EditableScene(removed, moved.source), args.object)
    row["after_removal"] = (
        "no match"
        if after is None
        else {
            "centre_m": [round(v, 3) for v in after.center_m],
            "iou_target": round(box_iou_3d(after, target), 3),
        }
    )
    return row


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--scene", type=Path, required=True)
    p.add_argument("--object", default="red mug")
    p.add_argument("--other", default="soccer ball", help="an object the edits leave alone")
    p.add_argument("--translate", type=float, nargs=3, default=[0.1, 0.05, 0.0])
    p.add_argument("--yaw", type=float, default=45.0)
    p.add_argument("--methods", nargs="+", default=["distil", "compose"])
    p.add_argument("--threads", type=int, default=None)
    p.add_argument("--out", type=Path, required=True)
    args = p.parse_args()
    configure_threads(args.threads)
    s = neo.load(args.scene)
    found = {name: _found(s, name) for name in (args.object, args.other)}
    missing = [name for name, box in found.items() if box is None]
    if missing:  # before any edit: the comparison needs both objects
        sys.exit(f"error: {args.scene}: no object matched {', '.join(map(repr, missing))}")
    rows = [run_method(s, args, m, found[args.other]) for m in args.methods]  # type: ignore[arg-type]
    commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True)
    result = {
        "command": shlex.join([sys.executable, *sys.argv]),
        "commit": commit.stdout.strip(),
        "machine": platform.processor() or platform.machine(),
        "date": time.strftime("%Y-%m-%d %H:%M"),
        "rows": rows,
    }
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "results.json").write_text(json.dumps(result, indent=2))
    print(json.dumps(result, indent=2))


if __name__ == "__main__":
    main()

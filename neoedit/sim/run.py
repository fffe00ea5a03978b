"""Simulate one scene: pre scan, then each action and the scan after it, plus scene.json."""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

import numpy as np

from neoedit.sim.capture import capture_scan
from neoedit.sim.spec import SceneSpec
from neoedit.sim.world import SimWorld
from neoedit.utils.io import atomic_directory, atomic_write_json


def post_scan_names(n_actions: int) -> list[str]:
    """``post`` for a single action, ``post_1 .. post_n`` for a sequence."""
    return ["post"] if n_actions == 1 else [f"post_{k + 1}" for k in range(n_actions)]


def simulate_scene(
    spec: SceneSpec,
    out_dir: Path,
    spec_dir: Path | None = None,
    objects_dir: Path | None = None,
    overwrite: bool = False,
) -> dict[str, Any]:
    """Write ``out_dir`` (atomically): ``pre/``, the post scans and ``scene.json``."""
    t0 = time.perf_counter()
    with (
        atomic_directory(out_dir, overwrite=overwrite) as tmp,
        SimWorld(spec, spec_dir, objects_dir) as world,
    ):
        capture_scan(world, spec.scan, tmp / "pre", label=f"{spec.name}/pre")
        actions = []
        for action, scan_name in zip(
            spec.actions, post_scan_names(len(spec.actions)), strict=False
        ):
            source = world.object_box(action.object)
            entry: dict[str, Any] = {
                "type": action.type,
                "object": action.object,
                "source_box": source.to_dict(),
                "scan": scan_name,
            }
            transform = world.apply(action)
            if transform is not None:
                target = world.object_box(action.object)
                entry.update(
                    {
                        "requested": {
                            "translate_m": list(action.translate_m),
                            "yaw_deg": action.yaw_deg,
                        },
                        "transform_world": np.round(transform, 6).tolist(),
                        "target_box": target.to_dict(),
                        "source_box_moved": source.transformed(transform).to_dict(),
                    }
                )
            capture_scan(world, spec.scan, tmp / scan_name, label=f"{spec.name}/{scan_name}")
            actions.append(entry)
        scene: dict[str, Any] = {
            "name": spec.name,
            "kind": spec.kind,
            "scans": ["pre", *post_scan_names(len(spec.actions))] if spec.actions else ["pre"],
            "actions": actions,
            "spec": spec.to_dict(),
        }
        atomic_write_json(tmp / "scene.json", scene)
    scene["seconds"] = round(time.perf_counter() - t0, 2)
    return scene

"""The NEO-Sim benchmark suite, mirroring the paper's NEO-Dataset protocol (Sec. IV-V):
5 single-object removal scenes, 6 single-object pick-and-place scenes with a known target
pose, and 1 multi-object assembly sequence of 4 moves, over two robot setups.

Profiles: ``small`` (64x48 px, 12 + 3 views; for tests) and ``standard`` (320x240 px,
96 training views on a 3-turn spiral + 12 held-out ring views; for benchmarks).
"""

from __future__ import annotations

import dataclasses
from typing import Literal

import numpy as np

from neoedit.sim.catalog import SETUPS, catalog_object
from neoedit.sim.spec import ActionSpec, ObjectSpec, ScanSpec, SceneSpec

Profile = Literal["small", "standard"]

SCANS: dict[str, ScanSpec] = {
    "small": ScanSpec(width=64, height=48, n_train=12, n_eval=3),
    "standard": ScanSpec(width=320, height=240, n_train=96, n_eval=12),
}

# (target, distractors, setup)
REMOVAL = [
    ("red mug", ["yellow rubber duck", "soccer ball"], "panda_wood"),
    ("yellow rubber duck", ["green cube", "yellow lego brick"], "panda_wood"),
    ("soccer ball", ["red mug", "wooden jenga block"], "panda_wood"),
    ("pink teddy bear", ["blue cube", "red ball"], "kuka_checker"),
    ("wooden jenga block", ["yellow rubber duck", "orange cube"], "kuka_checker"),
]
# (target, distractors, setup, translate (x, y) m, yaw deg)
PICK_PLACE = [
    ("red mug", ["soccer ball"], "panda_wood", (0.16, 0.06), 45.0),
    ("yellow rubber duck", ["blue cube"], "panda_wood", (-0.12, -0.12), 90.0),
    ("yellow lego brick", ["red mug"], "panda_wood", (0.14, -0.10), -30.0),
    ("blue cube", ["pink teddy bear"], "kuka_checker", (0.10, 0.10), 30.0),
    ("soccer ball", ["wooden jenga block"], "kuka_checker", (-0.10, 0.09), 0.0),
    ("pink teddy bear", ["green cube"], "kuka_checker", (0.09, -0.11), 60.0),
]


def _place(
    rng: np.random.Generator,
    n: int,
    half_extent: tuple[float, float],
    reserved: list[np.ndarray],
    min_dist_m: float = 0.13,
) -> list[np.ndarray]:
    """Rejection-sample n (x, y) positions at least ``min_dist_m`` from each other and the reserved ones."""
    out: list[np.ndarray] = []
    hx, hy = half_extent
    for _ in range(n):
        for _attempt in range(2000):
            p = rng.uniform([-hx, -hy], [hx, hy])
            if all(np.linalg.norm(p - q) >= min_dist_m for q in reserved + out):
                out.append(p)
                break
        else:
            raise RuntimeError("could not place objects without overlap; enlarge the workspace")
    return out


def _obj(name: str, xy: np.ndarray, rng: np.random.Generator) -> ObjectSpec:
    return catalog_object(
        name, round(float(xy[0]), 4), round(float(xy[1]), 4), round(float(rng.uniform(-90, 90)), 2)
    )


def benchmark_scenes(profile: Profile = "standard", seed: int = 0) -> list[SceneSpec]:
    """The 12 scene specs of the suite (deterministic for a seed)."""
    rng = np.random.default_rng(seed)
    scan = SCANS[profile]
    settle = 1.5
    scenes: list[SceneSpec] = []
    for k, (target, others, setup_name) in enumerate(REMOVAL, start=1):
        setup = SETUPS[setup_name]
        pos = _place(rng, 1 + len(others), setup.workspace_half_extent_m, [])
        objects = [_obj(n, p, rng) for n, p in zip([target, *others], pos, strict=True)]
        scenes.append(
            SceneSpec(
                f"removal_{k}",
                objects,
                [ActionSpec("remove", target)],
                setup,
                scan,
                kind="removal",
                settle_s=settle,
            )
        )
    for k, (target, others, setup_name, (dx, dy), yaw) in enumerate(PICK_PLACE, start=1):
        setup = SETUPS[setup_name]
        hx, hy = setup.workspace_half_extent_m
        # The source must leave room for the target inside the workspace.
        src = _place(rng, 1, (hx - abs(dx) / 2, hy - abs(dy) / 2), [])[0] - np.array([dx, dy]) / 2
        dst = src + np.array([dx, dy])
        pos = _place(rng, len(others), setup.workspace_half_extent_m, [src, dst], min_dist_m=0.14)
        objects = [_obj(target, src, rng)] + [
            _obj(n, p, rng) for n, p in zip(others, pos, strict=True)
        ]
        move = ActionSpec("move", target, (dx, dy, 0.0), yaw)
        scenes.append(
            SceneSpec(
                f"pick_place_{k}", objects, [move], setup, scan, kind="pick_place", settle_s=settle
            )
        )
    scenes.append(_assembly(rng, scan, settle))
    return scenes


def _round3(v: tuple[float, float, float]) -> tuple[float, float, float]:
    return (round(float(v[0]), 4), round(float(v[1]), 4), round(float(v[2]), 4))


def _assembly(rng: np.random.Generator, scan: ScanSpec, settle: float) -> SceneSpec:
    """Stack two cubes on a third, then bring the mug and the duck next to the tower."""
    setup = SETUPS["panda_wood"]
    names = ["green cube", "blue cube", "orange cube", "red mug", "yellow rubber duck"]
    base = np.array([0.0, 0.0])
    pos = [base, *_place(rng, 4, setup.workspace_half_extent_m, [base], min_dist_m=0.14)]
    objects = [_obj(n, p, rng) for n, p in zip(names, pos, strict=True)]
    objects[0] = dataclasses.replace(objects[0], yaw_deg=0.0)
    cube_m = 0.05
    actions = [
        ActionSpec("move", "blue cube", (*(base - pos[1]), cube_m), 0.0),
        ActionSpec("move", "orange cube", (*(base - pos[2]), 2 * cube_m), 0.0),
        ActionSpec("move", "red mug", (*(base + np.array([0.0, 0.12]) - pos[3]), 0.0), 30.0),
        ActionSpec(
            "move", "yellow rubber duck", (*(base + np.array([0.0, -0.12]) - pos[4]), 0.0), -45.0
        ),
    ]
    actions = [dataclasses.replace(a, translate_m=_round3(a.translate_m)) for a in actions]
    return SceneSpec("assembly", objects, actions, setup, scan, kind="assembly", settle_s=settle)

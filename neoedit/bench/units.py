"""The units of a benchmark run and their cache keys.

A unit is one independent piece of work with a result: simulating a scene, training a scan
(pre or oracle), or running one method on one scene and evaluating it. Its key hashes what
it depends on — its own parameters, the profile's budget, the seed, the keys of the units it
needs and the code version (a hash of the neoedit sources) — so a re-run redoes exactly the
units whose inputs or code changed.
"""

from __future__ import annotations

import functools
import hashlib
import json
from collections.abc import Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import neoedit
from neoedit.bench.methods import (
    ABLATIONS,
    ALL_METHODS,
    ASSEMBLY_METHODS,
    MOVE_METHODS,
    REMOVAL_ABLATIONS,
    REMOVAL_METHODS,
)
from neoedit.bench.profiles import Profile, budget_of
from neoedit.errors import NeoError
from neoedit.sim.spec import SceneSpec
from neoedit.sim.suite import benchmark_scenes


@dataclass(frozen=True)
class Unit:
    """One unit of work: ``kind`` is 'sim', 'train' or the scene kind of a method unit
    ('removal', 'pick_place', 'assembly')."""

    id: str
    """Unique, path-like: 'sim/removal_1', 'train/removal_1/pre', 'removal_1/neo'."""
    kind: str
    scene: str
    params: dict[str, Any] = field(default_factory=dict)
    deps: tuple[str, ...] = ()


PRESENTATION = ("cli/", "viewer/", "grasp/", "bench/report.py", "bench/runner.py")
"""Sources that cannot change any unit's result (the command line, the viewer, grasping,
the report and the scheduling): editing them keeps the cache."""
EDITING = ("edit/", "eval/", "bench/")
"""Sources that cannot change a simulation or a training: editing an edit method redoes the
method units, not the trainings."""
TRAIN_BUDGET = ("train_steps", "rays_per_batch", "radiance", "render", "grid", "language")
"""The part of a profile's budget that a training depends on."""


@functools.cache
def code_version(scope: str = "method") -> str:
    """A hash of the neoedit sources (path and content) that a unit of ``scope`` ('sim' /
    'train', or 'method') can depend on."""
    skip = PRESENTATION + (EDITING if scope in ("sim", "train") else ())
    h = hashlib.sha256()
    root = Path(neoedit.__file__).parent
    for path in sorted(root.rglob("*.py")):
        rel = path.relative_to(root).as_posix()
        if rel.startswith(skip):
            continue
        h.update(rel.encode())
        h.update(path.read_bytes())
    return h.hexdigest()[:16]


def unit_keys(
    units: list[Unit],
    profile: Profile,
    seed: int,
    data_ids: dict[str, str],
    train_steps: int | None = None,
) -> dict:
    """Cache key of every unit (units come in dependency order). ``data_ids``: scene -> a
    hash of its reused suite folder's files (none for simulated scenes: their sim unit's
    key stands for them); ``train_steps``: the profile's training steps replaced."""
    keys: dict[str, str] = {}
    budget = budget_of(profile, train_steps).to_dict()
    train_budget = {k: budget[k] for k in TRAIN_BUDGET}
    for u in units:
        scope = u.kind if u.kind in ("sim", "train") else "method"
        payload = {
            "id": u.id,
            "params": u.params,
            "budget": {} if scope == "sim" else train_budget if scope == "train" else budget,
            "profile": profile if scope == "sim" else None,
            "seed": seed,
            "data": data_ids.get(u.scene, ""),
            "deps": [keys[d] for d in u.deps],
            "code": code_version(scope),
        }
        blob = json.dumps(payload, sort_keys=True, default=str).encode()
        keys[u.id] = hashlib.sha256(blob).hexdigest()[:20]
    return keys


def folder_hash(folder: Path) -> str:
    """A hash of every file under ``folder`` (relative path and content)."""
    h = hashlib.sha256()
    for path in sorted(p for p in folder.rglob("*") if p.is_file()):
        h.update(path.relative_to(folder).as_posix().encode())
        with path.open("rb") as f:
            for block in iter(lambda: f.read(1 << 20), b""):
                h.update(block)
    return h.hexdigest()[:16]


def suite_specs(profile: Profile, seed: int) -> dict[str, SceneSpec]:
    return {s.name: s for s in benchmark_scenes(profile, seed)}


def scene_kind(name: str) -> str:
    return "assembly" if name == "assembly" else name.rsplit("_", 1)[0]


def methods_for(kind: str) -> tuple[str, ...]:
    return {
        "removal": (*REMOVAL_METHODS, *REMOVAL_ABLATIONS),
        "pick_place": (*MOVE_METHODS, *ABLATIONS),
        "assembly": ASSEMBLY_METHODS,
    }[kind]


def check_selection(scenes: Iterable[str], methods: Iterable[str], known: Iterable[str]) -> None:
    """One clear error for an unknown scene or method, before any work."""
    known = list(known)
    bad = [s for s in scenes if s not in known]
    if bad:
        raise NeoError(f"unknown scene(s) {', '.join(bad)} (choose from {', '.join(known)})")
    bad = [m for m in methods if m not in ALL_METHODS]
    if bad:
        raise NeoError(f"unknown method(s) {', '.join(bad)} (choose from {', '.join(ALL_METHODS)})")


def plan_units(
    scenes: list[str],
    methods: list[str],
    post_scans: dict[str, list[str]],
    simulate: bool,
) -> list[Unit]:
    """Every unit the selection needs, in dependency order: simulation (unless the suite
    is reused), the pre scan's training (with language), the oracles' trainings, then one
    unit per (scene, method) that applies to the scene."""
    units: list[Unit] = []
    for name in scenes:
        kind = scene_kind(name)
        chosen = [m for m in methods if m in methods_for(kind)]
        if not chosen:
            continue
        sim = f"sim/{name}"
        if simulate:
            units.append(Unit(sim, "sim", name))
        base = (sim,) if simulate else ()
        pre = Unit(f"train/{name}/pre", "train", name, {"scan": "pre", "language": True}, base)
        if any(m != "oracle" for m in chosen):
            units.append(pre)
        oracles = []
        if "oracle" in chosen:
            for scan in post_scans[name]:
                oracles.append(
                    Unit(
                        f"train/{name}/{scan}",
                        "train",
                        name,
                        {"scan": scan, "language": False},
                        base,
                    )
                )
            units.extend(oracles)
        for method in chosen:
            deps = tuple(o.id for o in oracles) if method == "oracle" else (pre.id,)
            units.append(Unit(f"{name}/{method}", kind, name, {"method": method}, deps))
    return units

"""Running one unit and caching its result.

Each unit owns the folder ``OUT/units/<unit id>``; its ``unit.json`` (key, result, time),
written atomically last, is what marks it done. A unit whose ``unit.json`` is missing
(interrupted) or holds another key (changed inputs or code) is run again from an empty
folder. Units run the same way in this process and in a Ray worker: :func:`run_unit` is a
plain function of picklable arguments.
"""

from __future__ import annotations

import hashlib
import json
import platform
import shutil
import time
import traceback
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from neoedit.bench.folder import RunFolder
from neoedit.bench.methods import NO_EDIT, RUNNERS, Refusal, SceneInputs
from neoedit.bench.profiles import Budget, Profile, budget_of
from neoedit.bench.units import Unit, code_version, suite_specs
from neoedit.errors import NeoError
from neoedit.utils.io import atomic_write_json, mark_output, output_kind, write_png

UNIT_FILE = "unit.json"
UNIT_KIND = "bench-unit"


@dataclass(frozen=True)
class Context:
    """Where a run reads and writes, and what it spends (picklable for Ray)."""

    out: Path
    profile: Profile
    seed: int
    data: Path | None = None
    """A reused NEO-Sim suite folder (None: the run simulates its scenes)."""
    threads: int | None = None
    """torch / numba threads of each unit (None: the cores the process may use)."""
    device: str = "auto"
    """Training device ('auto': CUDA when available)."""
    train_steps: int | None = None
    """Steps of every pre scan and oracle training (None: the profile's)."""
    keep_versions: bool = False
    """Save each method's edited version in its unit folder (``scene``; the assembly: a
    scene store ``store``)."""

    @property
    def budget(self) -> Budget:
        return budget_of(self.profile, self.train_steps)

    @property
    def folder(self) -> RunFolder:
        return RunFolder(self.out, self.data)

    def unit_dir(self, unit_id: str) -> Path:
        return self.folder.unit_dir(unit_id)

    def scene_data(self, scene: str) -> Path:
        return self.folder.scene_data(scene)

    def trained(self, scene: str, scan: str) -> Path:
        return self.folder.trained(scene, scan)


def kept_version(ctx: Context, unit: Unit) -> Path | None:
    """Where ``unit`` saves its edited version when the run keeps them (None: it has none
    to keep — simulations, trainings, the pre-edit field and the oracle, which are scenes
    of the ``train`` units already)."""
    if not ctx.keep_versions or unit.kind not in RUNNERS:
        return None
    method = unit.params["method"]
    if method in NO_EDIT:
        return None
    return ctx.folder.version(unit.scene, method)


def cached(ctx: Context, unit: Unit, key: str) -> dict[str, Any] | None:
    """The unit's record when it finished with this key (else None); a finished edit whose
    version a ``keep_versions`` run wants and the unit did not keep is run again."""
    path = ctx.unit_dir(unit.id) / UNIT_FILE
    try:
        record = json.loads(path.read_text())
    except (OSError, ValueError):
        return None
    if not isinstance(record, dict) or record.get("key") != key:
        return None
    kept = kept_version(ctx, unit)
    if kept is not None and "result" in record and not kept.exists():
        return None
    return record


def run_unit(ctx: Context, unit: Unit, key: str) -> dict[str, Any]:
    """Run ``unit`` from an empty folder, write its record, return it. A method that cannot
    run on its scene (:class:`~neoedit.bench.methods.Refusal`: the query finds nothing, the
    found box moved by the action leaves the scene) is an outcome and is cached; any other
    error (a missing package or weights, a crash) is recorded with its traceback and not
    cached: the next run tries again."""
    from neoedit.utils.threads import configure_threads, max_threads

    if ctx.threads is not None:  # else the process's own budget (--threads / NEO_THREADS)
        configure_threads(min(ctx.threads, max_threads()))  # a worker may have fewer cores
    _seed_everything(ctx.seed)
    folder = ctx.unit_dir(unit.id)
    if folder.exists():  # a stale or interrupted unit of this run folder
        if output_kind(folder) != UNIT_KIND:
            raise NeoError(f"{folder} is not a benchmark unit folder; not replacing it")
        shutil.rmtree(folder)
    folder.mkdir(parents=True)
    mark_output(folder, UNIT_KIND)
    t0 = time.perf_counter()
    record: dict[str, Any] = {"id": unit.id, "key": key}
    try:
        record["result"] = _execute(ctx, unit, folder)
    except Refusal as e:  # the method could not run (its query found nothing): an outcome
        record["error"] = f"{type(e).__name__}: {e}"
        record["refused"] = True
    except Exception as e:  # noqa: BLE001 - one crashed unit must not stop the others
        record["error"] = f"{type(e).__name__}: {e}"
        record["traceback"] = traceback.format_exc(limit=6)
        record["key"] = None  # not cached: the next run tries again
    record["seconds"] = round(time.perf_counter() - t0, 1)
    record["ran_on"] = {"host": platform.node(), "threads": _threads(), "code": code_version()}
    atomic_write_json(folder / UNIT_FILE, record)
    return record


def _threads() -> int:
    import torch

    return torch.get_num_threads()


def _seed_everything(seed: int) -> None:
    """torch's global generator (every other random draw of neoedit has its own seed)."""
    import torch

    torch.manual_seed(seed)


def _execute(ctx: Context, unit: Unit, folder: Path) -> dict[str, Any]:
    if unit.kind == "sim":
        from neoedit.sim.run import simulate_scene  # pybullet: only where it is needed

        spec = suite_specs(ctx.profile, ctx.seed)[unit.scene]
        summary = simulate_scene(spec, folder / "scene")
        return {"seconds": round(summary["seconds"], 1)}
    if unit.kind == "train":
        return _train(ctx, unit, folder)
    kind_dir = ctx.scene_data(unit.scene)
    post_names = [p.name for p in sorted(kind_dir.glob("post*")) if p.is_dir()]
    inputs = SceneInputs(
        data=kind_dir,
        pre=ctx.trained(unit.scene, "pre"),
        oracles={p: ctx.trained(unit.scene, p) for p in post_names},
        eval_views=ctx.budget.eval_views,
        seed=ctx.seed,
        query=ctx.budget.query,
        edit_scale=ctx.budget.edit_scale,
        keep=kept_version(ctx, unit),
    )
    row, tile = RUNNERS[unit.kind](unit.params["method"], inputs)
    write_png(folder / "view.png", tile)
    return row


def _train(ctx: Context, unit: Unit, folder: Path) -> dict[str, Any]:
    from neoedit.training.trainer import train

    budget = ctx.budget
    scene = train(
        ctx.scene_data(unit.scene) / unit.params["scan"],
        folder / "scene",
        budget.train_config(ctx.seed),
        budget.radiance,
        budget.render,
        budget.grid,
        device=ctx.device,
        language=budget.language if unit.params["language"] else None,
    )
    return {"train_seconds": round(scene.meta.train_seconds, 1), "steps": scene.meta.step}


def field_quality(ctx: Context, unit: Unit) -> dict[str, Any]:
    """A trained field's PSNR / SSIM on its own scan's held-out views (the budget's
    ``eval_views``), so the report can state the quality the tables were built on. Kept
    beside the training (``held_out.json``) under a key of the evaluation's own inputs (the
    training's folder, ``eval_views``, the evaluation code): an evaluation setting or a
    metric fix re-evaluates without retraining, and trainings cached before this existed
    get their figures."""
    from neoedit.data import load_scene_data
    from neoedit.eval.evaluate import evaluate
    from neoedit.scene import load_scene
    from neoedit.utils.device import resolve_device

    folder = ctx.unit_dir(unit.id)
    record = json.loads((folder / UNIT_FILE).read_text())
    key = hashlib.sha256(
        json.dumps([record.get("key"), ctx.budget.eval_views, code_version("method")]).encode()
    ).hexdigest()[:20]
    path = folder / "held_out.json"
    if path.is_file():
        kept = json.loads(path.read_text())
        if kept.get("key") == key:
            return kept["held_out"]
    scan = load_scene_data(ctx.scene_data(unit.scene) / unit.params["scan"])
    scene = load_scene(folder / "scene", resolve_device(ctx.device))
    result = evaluate(scene, scan, "test", max_views=ctx.budget.eval_views)
    held = {
        "psnr": result["full"]["psnr"],
        "ssim": result["full"]["ssim"],
        "views": result["n_views"],
    }
    atomic_write_json(path, {"key": key, "held_out": held})
    return held

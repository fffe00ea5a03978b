"""``neo bench``: plan the units, run what is not cached (here or on Ray), write the report.

Units are independent once their dependencies are done, so the Ray executor submits every
unit whose dependencies have finished and collects them as they complete; the serial
executor runs them in dependency order. Both call the same :func:`run_unit`, so a unit's
result does not depend on where it ran (given the same ``threads``: float reductions on a
different thread count may differ in their last bits).
"""

from __future__ import annotations

import json
import socket
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from neoedit.bench.methods import ALL_METHODS
from neoedit.bench.profiles import Profile
from neoedit.bench.report import write_report
from neoedit.bench.units import (
    Unit,
    check_selection,
    folder_hash,
    plan_units,
    suite_specs,
    unit_keys,
)
from neoedit.bench.work import Context, cached, field_quality, run_unit
from neoedit.errors import NeoError
from neoedit.sim.run import post_scan_names
from neoedit.sim.spec import SceneSpec
from neoedit.utils.io import atomic_write_json, mark_output, output_kind
from neoedit.utils.progress import make_progress

RUN_KIND = "bench"


@dataclass
class BenchConfig:
    out: Path
    """Run folder: units/ (cached work), figures/, REPORT.md, results.json."""
    profile: Profile = "small"
    """small: 64x48 scans, tiny field (minutes); standard: 320x240, neo train's field, 1500
    steps (hours)."""
    scenes: tuple[str, ...] = ()
    """Scenes to run (default: all 12 of the suite)."""
    methods: tuple[str, ...] = ()
    """Methods to run where they apply (default: all)."""
    data: Path | None = None
    """Reuse this NEO-Sim suite folder (neo sim benchmark's output) instead of simulating."""
    seed: int = 0
    workers: int = 1
    """Units run at once: 1 = here, serially; N > 1 = a local Ray with N workers."""
    ray_address: str | None = None
    """Join this Ray cluster (e.g. 'auto' or 'ray://host:10001') instead."""
    train_steps: int | None = None
    """Steps of every pre scan and oracle training (default: the profile's: small 200,
    standard 1500); the tables then measure edits of fields trained that far (the report
    gives each field's held-out PSNR)."""
    keep_versions: bool = False
    """Save every edited version (units/<scene>/<method>/scene; the assembly's chain as a
    scene store, units/assembly/<method>/store) for the grasp benchmark, the viewer or
    neo eval; a scene is tens of MB at the standard profile."""
    threads: int | None = None
    """torch / numba threads per unit (default: ``--threads`` / ``NEO_THREADS`` when given,
    else the cores of the process; with Ray, the cores divided by the workers)."""


def _data_ids(cfg: BenchConfig, scenes: list[str], specs: dict[str, SceneSpec]) -> dict[str, str]:
    """A reused suite's scenes enter the keys by the hash of their files (a re-rendered scan
    is new data); scans of another profile's size are refused (the profile's budget is
    sized for its scans: a small run on 320x240 scans trains its tiny field for hours)."""
    if cfg.data is None:
        return {}
    ids = {}
    for name in scenes:
        spec = cfg.data / name / "scene.json"
        if not spec.is_file():
            raise NeoError(f"{cfg.data} has no scene {name} (no {spec}); run neo sim benchmark")
        try:
            scan = json.loads(spec.read_text())["spec"]["scan"]
            size = (int(scan["width"]), int(scan["height"]))
        except (OSError, ValueError, TypeError, KeyError) as e:
            raise NeoError(f"{spec} is not a NEO-Sim scene ({e}); run neo sim benchmark") from None
        want = (specs[name].scan.width, specs[name].scan.height)
        if size != want:
            raise NeoError(
                f"{cfg.data / name} holds {size[0]}x{size[1]} scans, the {cfg.profile} profile "
                f"{want[0]}x{want[1]}: give the --profile its suite was written with"
            )
        ids[name] = folder_hash(cfg.data / name)
    return ids


def _check_out(out: Path) -> None:
    if out.exists() and any(out.iterdir()) and output_kind(out) != RUN_KIND:
        raise NeoError(f"{out} exists and is not a neo bench folder; choose another --out")


def check_ray_address(address: str, timeout_s: float = 5.0) -> None:
    """A 'host:port' or 'ray://host:port' cluster address must answer before any work (Ray's
    own client retries an unreachable address for minutes); 'auto' is left to Ray."""
    if address == "auto":
        return
    hostport = address.split("://", 1)[-1].rstrip("/")
    host, sep, port = hostport.rpartition(":")
    if not sep or not host or not port.isdigit() or not 0 < int(port) < 65536:
        raise NeoError(f"--ray must be 'auto', HOST:PORT or ray://HOST:PORT, got {address!r}")
    try:
        socket.create_connection((host.strip("[]"), int(port)), timeout=timeout_s).close()
    except OSError as e:
        raise NeoError(
            f"cannot reach the Ray cluster at {address} ({e.strerror or e}); start one with "
            "'ray start --head' or check --ray"
        ) from None


def prepare(cfg: BenchConfig) -> tuple[Context, list[Unit], dict[str, str]]:
    """Check the selection and plan the units, before any work."""
    if cfg.workers < 1:
        raise NeoError(f"--workers must be at least 1, got {cfg.workers}")
    if cfg.train_steps is not None and not 1 <= cfg.train_steps <= 1_000_000:
        raise NeoError(f"--train-steps must be in 1 .. 1000000, got {cfg.train_steps}")
    if cfg.workers > 1 and cfg.ray_address:
        raise NeoError("give --workers N (a local Ray) or --ray ADDRESS (a cluster), not both")
    if cfg.ray_address:
        check_ray_address(cfg.ray_address)
    specs = suite_specs(cfg.profile, cfg.seed)
    scenes = list(dict.fromkeys(cfg.scenes)) or list(specs)  # a repeated name runs once
    methods = list(dict.fromkeys(cfg.methods)) or list(ALL_METHODS)
    check_selection(scenes, methods, specs)
    _check_out(cfg.out)
    ids = _data_ids(cfg, scenes, specs)
    posts = {s: post_scan_names(len(specs[s].actions)) for s in scenes}
    units = plan_units(scenes, methods, posts, simulate=cfg.data is None)
    if not units:
        raise NeoError("no method of the selection applies to the selected scenes")
    from neoedit.utils.threads import available_cores, chosen_threads

    # the user's --threads / NEO_THREADS reaches the Ray workers too (their processes do
    # not inherit this one's budget); by default each gets its share of the cores
    threads = cfg.threads if cfg.threads is not None else chosen_threads()
    if threads is None and (cfg.workers > 1 or cfg.ray_address):
        threads = max(available_cores() // max(cfg.workers, 1), 1)
    data = None if cfg.data is None else cfg.data.resolve()  # Ray workers have another cwd
    out = cfg.out.resolve()
    ctx = Context(
        out,
        cfg.profile,
        cfg.seed,
        data,
        threads,
        train_steps=cfg.train_steps,
        keep_versions=cfg.keep_versions,
    )
    return ctx, units, unit_keys(units, cfg.profile, cfg.seed, ids, cfg.train_steps)


def run_bench(cfg: BenchConfig) -> dict[str, Any]:
    """Run (or reuse) every unit of the selection and write the report -> summary."""
    ctx, units, keys = prepare(cfg)
    cfg.out.mkdir(parents=True, exist_ok=True)
    mark_output(cfg.out, RUN_KIND)
    t0 = time.perf_counter()
    records: dict[str, dict[str, Any]] = {}
    todo = []
    for u in units:
        rec = cached(ctx, u, keys[u.id])
        if rec is not None:
            records[u.id] = rec
        else:
            todo.append(u)
    ray_wanted = (cfg.workers > 1 or cfg.ray_address) and todo  # nothing to run: no cluster
    execute = _ray_executor(cfg) if ray_wanted else _serial
    with make_progress() as progress:
        task = progress.add_task("bench units", total=len(units), completed=len(records), status="")

        def done(rec: dict[str, Any]) -> None:
            records[rec["id"]] = rec
            outcome = "refused" if rec.get("refused") else "failed"
            status = f"{rec['id']}: " + (outcome if "error" in rec else f"{rec['seconds']} s")
            progress.update(task, advance=1, status=status)

        execute(ctx, todo, keys, records, done)
    skipped = [i for i, r in records.items() if r.get("skipped")]
    summary = {
        "units": len(units),
        "ran": len(todo) - len(skipped),
        "skipped": len(skipped),
        "cached": len(units) - len(todo),
        "failed": sorted(i for i, r in records.items() if "error" in r and not r.get("refused")),
        "refused": sorted(i for i, r in records.items() if r.get("refused")),
        "seconds": round(time.perf_counter() - t0, 1),
    }
    ordered = {u.id: records[u.id] for u in units if u.id in records}
    _state_field_quality(ctx, units, ordered)
    write_report(ctx, units, ordered, summary)
    atomic_write_json(cfg.out / "results.json", {"summary": summary, "units": ordered})
    return summary


Done = Callable[[dict[str, Any]], None]


def _state_field_quality(ctx: Context, units: list[Unit], records: dict[str, dict]) -> None:
    """Every finished training's held-out PSNR / SSIM into its record (``held_out``; kept
    beside the training, evaluated once per setting: :func:`field_quality`)."""
    for u in units:
        result = records.get(u.id, {}).get("result")
        if u.kind == "train" and result is not None:
            try:
                result["held_out"] = field_quality(ctx, u)
            except (NeoError, OSError, ValueError) as e:  # a figure missing, not the run
                result["held_out_error"] = str(e)


def _blocked(u: Unit, records: dict[str, dict[str, Any]]) -> str | None:
    """The first dependency of ``u`` that failed or never ran, if any."""
    return next((d for d in u.deps if d not in records or "error" in records[d]), None)


def _skipped(u: Unit, dep: str, records: dict[str, dict[str, Any]]) -> dict[str, Any]:
    """The record of a unit whose dependency could not run or failed (not written: the next
    run decides again from the dependency's own record)."""
    refused = bool(records.get(dep, {}).get("refused"))
    return {
        "id": u.id,
        "error": f"skipped: {dep} {'could not run' if refused else 'failed'}",
        "refused": refused,
        "skipped": True,
        "seconds": 0.0,
    }


def _serial(ctx: Context, todo: list[Unit], keys: dict, records: dict, done: Done) -> None:
    for u in todo:
        dep = _blocked(u, records)
        done(_skipped(u, dep, records) if dep else run_unit(ctx, u, keys[u.id]))


def _ray_executor(cfg: BenchConfig) -> Callable[..., None]:
    try:
        import ray
    except ImportError:
        raise NeoError(
            "Ray is not installed: pip install 'neoedit[cluster]' (or run without --workers / --ray)"
        ) from None

    def execute(ctx: Context, todo: list[Unit], keys: dict, records: dict, done: Done) -> None:
        started = not ray.is_initialized()
        if started and cfg.ray_address:
            ray.init(address=cfg.ray_address, log_to_driver=False)
        elif started:
            ray.init(num_cpus=cfg.workers, include_dashboard=False, log_to_driver=False)
        try:
            _ray_loop(ray, ctx, todo, keys, records, done)
        finally:
            if started:
                ray.shutdown()

    return execute


def _ray_loop(ray: Any, ctx: Context, todo: list[Unit], keys: dict, records: dict, done: Done):
    remote = ray.remote(num_cpus=1, max_retries=0)(run_unit)
    waiting = list(todo)
    running: dict[Any, Unit] = {}
    while waiting or running:
        for u in list(waiting):
            dep = _blocked(u, records)
            if dep is not None and dep not in records:
                continue  # still to run
            waiting.remove(u)
            if dep is not None:
                done(_skipped(u, dep, records))
            else:
                running[remote.remote(ctx, u, keys[u.id])] = u
        if not running:
            for u in waiting:  # cannot happen with a plan in dependency order
                done(_skipped(u, "a dependency outside the plan", records))
            return
        ready, _ = ray.wait(list(running), num_returns=1)
        for ref in ready:
            u = running.pop(ref)
            try:
                done(ray.get(ref))
            except Exception as e:  # noqa: BLE001 - a worker died (killed, out of memory)
                done({"id": u.id, "key": None, "error": f"Ray: {e}", "seconds": 0.0})

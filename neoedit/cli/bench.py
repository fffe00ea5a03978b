"""``neo bench``: the paper's tables on NEO-Sim with one command."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Literal

from rich.console import Console

console = Console()


@dataclass
class BenchCommand:
    """Regenerate Table I (removal), II (pick-and-place), III (ablations) and the assembly
    sequence on NEO-Sim: simulate (or reuse) the suite, train every pre scan and oracle once,
    run every method on every scene it applies to, evaluate, and write OUT/REPORT.md.
    Every unit of work is cached by its inputs and the code version: a re-run redoes only
    what changed, an interrupted run resumes."""

    out: Path
    """Run folder (units/, figures/, REPORT.md, results.json); reused by the next run."""
    profile: Literal["small", "standard"] = "small"
    """small: 64x48 scans and a tiny field (minutes on 2 cores); standard: 320x240 scans,
    neo train's field, 1500 steps (fields of >= 31 dB held out; hours on 2 cores)."""
    scenes: tuple[str, ...] = ()
    """Scenes to run, e.g. removal_1 pick_place_2 assembly (default: all 12)."""
    methods: tuple[str, ...] = ()
    """Methods to run where they apply (default: all): pre-edit resample suppress neo
    nerfiller nerfiller-no-depth seal3d preview oracle; the removal ablations
    remove-no-shadow remove-no-grid-inpaint inpaint-telea inpaint-ns; the move ablations
    no-virtual-views no-grid-inpaint no-mask-cond field-distill-only no-shadow
    no-shadow-follow distil-target no-relight."""
    data: Path | None = None
    """Reuse this NEO-Sim suite (neo sim benchmark --out DATA, same profile) instead of
    simulating the scenes."""
    seed: int = 0
    train_steps: int | None = None
    """Steps of every pre scan and oracle training (default: the profile's, small 200,
    standard 1500: fields near neo train's quality; fewer for a quicker, rougher run)."""
    keep_versions: bool = False
    """Save every edited version in its unit folder (units/SCENE/METHOD/scene; the assembly:
    a scene store) to open with neo view / neo eval or benchmarks/bench_grasp.py."""
    workers: int = 1
    """1: run the units here, one after another; N > 1: a local Ray with N workers
    (pip install 'neoedit[cluster]')."""
    ray: str | None = None
    """Address of a running Ray cluster to fan the units out to (OUT must be on storage
    every node sees)."""

    def run(self) -> None:
        from neoedit.bench import BenchConfig, run_bench

        cfg = BenchConfig(
            out=self.out,
            profile=self.profile,
            scenes=self.scenes,
            methods=self.methods,
            data=self.data,
            seed=self.seed,
            train_steps=self.train_steps,
            keep_versions=self.keep_versions,
            workers=self.workers,
            ray_address=self.ray,
        )
        summary = run_bench(cfg)
        console.print(
            f"{summary['units']} units: {summary['ran']} run, {summary['cached']} cached, "
            f"{len(summary['refused'])} refused, {len(summary['failed'])} failed, "
            f"{summary['seconds']} s -> {self.out / 'REPORT.md'}",
            markup=False,
        )
        if summary["refused"]:
            console.print(f"[yellow]refused (see REPORT.md):[/] {', '.join(summary['refused'])}")
        if summary["failed"]:
            console.print(f"[red]failed:[/] {', '.join(summary['failed'])}")
            raise SystemExit(1)

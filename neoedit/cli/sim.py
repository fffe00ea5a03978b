"""``neo sim scene`` and ``neo sim benchmark``."""

from __future__ import annotations

import json
import math
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

import tyro
from rich.console import Console
from rich.markup import escape
from rich.table import Table

from neoedit.errors import NeoError
from neoedit.sim.specfile import load_scene_spec
from neoedit.sim.suite import benchmark_scenes
from neoedit.utils.io import (
    atomic_write_json,
    check_writable_output,
    mark_output,
    output_kind,
    probe_writable,
)
from neoedit.utils.userfile import read_data_file

console = Console()


def _dir_size_mb(path: Path) -> float:
    return sum(f.stat().st_size for f in path.rglob("*") if f.is_file()) / 1e6


def _is_suite(folder: Path) -> bool:
    """An earlier `neo sim benchmark` output: marked, or (written before the marker) with a
    suite.json of its shape."""
    if output_kind(folder) == "sim-suite":
        return True
    try:
        suite = json.loads((folder / "suite.json").read_text())
    except (OSError, ValueError):
        return False
    return isinstance(suite, dict) and {"profile", "seed", "scenes"} <= suite.keys()


@dataclass
class SimSceneCommand:
    """Simulate one scene from a YAML/JSON spec: pre scan, then a scan after every action."""

    spec: tyro.conf.Positional[Path]
    """Scene spec file (.yaml/.yml/.json); see neoedit.sim.spec.SceneSpec."""
    out: Path
    """Output scene directory (pre/, post*/ and scene.json); written atomically."""
    objects_dir: Path | None = None
    """Folder of extra URDF models, referenced as 'objects_dir:NAME' in the spec (e.g. YCB)."""
    overwrite: bool = False
    """Replace OUT if it exists."""

    def run(self) -> None:
        from neoedit.sim.run import simulate_scene  # imports pybullet, which prints a banner

        spec = load_scene_spec(self.spec)
        check_writable_output(self.out, [self.spec, self.objects_dir], "sim", self.overwrite)
        summary = simulate_scene(spec, self.out, self.spec.parent, self.objects_dir, self.overwrite)
        console.print(
            f"wrote {self.out} ({', '.join(summary['scans'])}) in {summary['seconds']:.1f} s, "
            f"{_dir_size_mb(self.out):.1f} MB",
            markup=False,
        )


@dataclass
class SimBenchmarkCommand:
    """Write the NEO-Sim suite: 5 removal, 6 pick-and-place and 1 four-step assembly scene."""

    out: Path
    """Output folder: one sub-folder per scene plus suite.json."""
    profile: Literal["small", "standard"] = "standard"
    """small: 64x48 px, 12+3 views (tests); standard: 320x240 px, 96+12 views (benchmarks)."""
    seed: int = 0
    """Seed of the object placement; same seed, same files."""
    only: tuple[str, ...] = ()
    """Generate only these scenes (e.g. removal_1 assembly)."""
    overwrite: bool = False
    """Regenerate scenes that already exist (otherwise they are kept and skipped)."""

    def run(self) -> None:
        from neoedit.sim.run import simulate_scene  # imports pybullet, which prints a banner

        scenes = benchmark_scenes(self.profile, self.seed)
        known = [s.name for s in scenes]
        unknown = sorted(set(self.only) - set(known))
        if unknown:
            raise NeoError(f"unknown scene(s) {unknown}; the suite has {known}")
        if self.only:
            scenes = [s for s in scenes if s.name in self.only]
        earlier = self._check_out(scenes)
        self.out.mkdir(parents=True, exist_ok=True)
        mark_output(self.out, "sim-suite")  # a run killed midway can be resumed into it
        table = Table(title=f"NEO-Sim {self.profile} (seed {self.seed}) -> {escape(str(self.out))}")
        for col in ("scene", "kind", "setup", "scans", "objects", "seconds", "MB"):
            table.add_column(col)
        t0 = time.perf_counter()
        rows = []
        for spec in scenes:
            target = self.out / spec.name
            if (target / "scene.json").is_file() and not self.overwrite:
                console.print(f"[dim]{spec.name}: exists, skipped (--overwrite to regenerate)[/]")
                summary = json.loads((target / "scene.json").read_text())
                summary["seconds"] = earlier.get(spec.name, {}).get("seconds")  # when made
            else:
                summary = simulate_scene(spec, target, overwrite=self.overwrite)
            size = _dir_size_mb(target)
            rows.append(
                {
                    "name": spec.name,
                    "kind": spec.kind,
                    "setup": spec.setup.name,
                    "scans": summary["scans"],
                    "seconds": summary["seconds"],
                    "size_mb": round(size, 2),
                }
            )
            table.add_row(
                spec.name,
                spec.kind,
                spec.setup.name,
                " ".join(summary["scans"]),
                str(len(spec.objects)),
                "-" if summary["seconds"] is None else f"{summary['seconds']:.1f}",
                f"{size:.1f}",
            )
        total_s = time.perf_counter() - t0
        done = {r["name"] for r in rows}  # the earlier run's other scenes stay listed
        rows = [*(r for n, r in earlier.items() if n not in done), *rows]
        atomic_write_json(
            self.out / "suite.json", {"profile": self.profile, "seed": self.seed, "scenes": rows}
        )
        console.print(table)
        console.print(f"total {total_s:.1f} s, {_dir_size_mb(self.out):.1f} MB")

    def _check_out(self, scenes: list) -> dict[str, dict]:
        """OUT is new, empty or an earlier suite of the same profile and seed (its scenes
        are kept, or replaced with --overwrite); never a folder of something else. Returns
        the earlier suite's rows by scene name."""
        if self.out.exists() and not self.out.is_dir():
            raise NeoError(f"{self.out} exists and is not a folder")
        earlier: dict[str, dict] = {}
        if self.out.is_dir() and any(self.out.iterdir()):
            if not _is_suite(self.out):
                raise NeoError(
                    f"{self.out} is not empty and holds no earlier `neo sim benchmark` output; "
                    "choose a new or empty --out"
                )
            earlier = self._earlier_rows()
            probe_writable(self.out)
        else:
            check_writable_output(self.out, [], "sim-suite")
        for spec in scenes:
            target = self.out / spec.name
            if target.exists() and output_kind(target) != "sim":
                check_writable_output(target, [], "sim", self.overwrite)
        return earlier

    def _earlier_rows(self) -> dict[str, dict]:
        """The rows of OUT's suite.json (a time that is no finite number: None). A suite of
        another profile or seed is refused (its scenes would be listed under this run's
        name), unless --overwrite regenerates every scene of it (no --only): then nothing
        of it is kept."""
        try:
            suite = json.loads((self.out / "suite.json").read_text())
        except (OSError, ValueError):
            return {}  # a suite written before suite.json existed: no rows to keep
        if not isinstance(suite, dict):
            return {}
        profile, seed = suite.get("profile"), suite.get("seed")
        if (profile, seed) != (self.profile, self.seed):
            if self.overwrite and not self.only:
                return {}
            raise NeoError(
                f"{self.out} holds the {profile} suite of seed {seed}; add to it with "
                f"--profile {profile} --seed {seed}, regenerate all of it with --overwrite "
                "(without --only), or choose another --out"
            )
        rows = {}
        for row in suite.get("scenes") or []:
            if isinstance(row, dict) and isinstance(row.get("name"), str):
                seconds = row.get("seconds")
                finite = isinstance(seconds, (int, float)) and math.isfinite(seconds)
                rows[row["name"]] = {**row, "seconds": seconds if finite else None}
        return rows


@dataclass
class SimExecuteCommand:
    """Execute one move of a NEO-Sim scene with a planned grasp: the simulated Panda reaches
    the grasp along its approach, closes, lifts, carries the object by the action's
    transform, places it and retreats; the outcome is scanned with the scene's cameras
    (OUT/scan, a dataset `neo eval` takes) and reported in OUT/execution.json (success, the
    stage that failed and why, placement error). Exit status 1 when the execution fails."""

    scene: tyro.conf.Positional[Path]
    """NEO-Sim scene folder (scene.json + scans)."""
    action: int
    """Which action (1-based) to execute; earlier ones are replayed as simulated."""
    grasp: Path
    """Grasp JSON from `neo grasp --json`: one grasp, or a list, best first, of which the
    first one the arm reaches at every waypoint is executed (a kinematic check; the first of
    the list when none is reachable, so the failure is reported)."""
    out: Path
    """Output folder (scan/ and execution.json)."""
    overwrite: bool = False

    def run(self) -> None:
        from neoedit.sim.execute import (
            ExecuteConfig,
            check_grasp,
            execute_action,
            reachable_first,
        )

        raw = read_data_file(self.grasp, "grasp file")
        grasps = raw if isinstance(raw, list) else [raw]
        if not grasps or not all(isinstance(g, dict) for g in grasps):
            raise NeoError(f"{self.grasp}: expected a grasp or a list of grasps (JSON objects)")
        for k, g in enumerate(grasps):
            try:
                check_grasp(g)
            except NeoError as e:
                raise NeoError(f"{self.grasp}, grasp {k + 1}: {e}") from None
        check_writable_output(self.out, [self.scene, self.grasp], "execution", self.overwrite)
        cfg = ExecuteConfig()
        pick = 0
        if len(grasps) > 1:
            best = reachable_first(self.scene, self.action, grasps, cfg)[0]
            pick = best.grasp
            console.print(
                f"executing grasp {pick + 1} of {len(grasps)} (reach check: "
                f"{best.error_m * 100:.1f} cm off at worst, at {best.stage or 'no stage'})"
            )
        ex = execute_action(self.scene, self.action, grasps[pick], self.out, cfg, self.overwrite)
        if not ex.success:
            console.print(f"[bold red]execution failed at {ex.stage}: {escape(str(ex.cause))}[/]")
            raise SystemExit(1)
        console.print(
            f"executed action {self.action}; outcome scanned into {escape(str(self.out / 'scan'))}"
        )

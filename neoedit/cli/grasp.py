"""``neo grasp``: parallel-jaw grasps of an object named by a prompt, on any version."""

from __future__ import annotations

import dataclasses
import json
import time
from dataclasses import dataclass
from pathlib import Path

import tyro
from rich.console import Console
from rich.markup import escape

from neoedit.errors import NeoError
from neoedit.grasp import GraspConfig
from neoedit.language.localize import QueryConfig
from neoedit.utils.options import at_least_one

console = Console()


@dataclass
class GraspCommand:
    """Plan parallel-jaw grasps (Franka hand) for the object a prompt names, on the scene's
    own field: antipodal contact pairs in a friction cone, checked for collisions against
    the whole scene. Prints the grasps as JSON (best first) and draws them over a render in
    OUT/grasps.png. No collision-free grasp: a message and exit status 1."""

    scene: tyro.conf.Positional[Path]
    """Scene folder, store or store version."""
    prompt: tyro.conf.Positional[str | None] = None
    """What to grasp, e.g. "red mug"; or use --box."""
    box: Path | None = None
    """JSON box file instead of a prompt."""
    top: int = at_least_one(5)
    """How many grasps to keep."""
    json: Path | None = None
    """Also write the grasps (a list, best first) to this file."""
    out: Path | None = None
    """Folder for grasps.png (default: a new outputs/grasp/<scene name>-<prompt>[-N])."""
    grasp: GraspConfig = dataclasses.field(default_factory=GraspConfig)
    query: QueryConfig = dataclasses.field(default_factory=QueryConfig)
    overwrite: bool = False
    """Replace OUT if it holds an earlier grasp picture, and an existing --json file that
    holds a previous JSON result (never a dataset or scene file)."""
    device: str = "auto"

    def run(self) -> None:
        self.query.check()  # before any loading or training
        from neoedit.cli.edit import find_boxes
        from neoedit.grasp.antipodal import plan_grasps, scene_density
        from neoedit.scene import load_scene
        from neoedit.utils.device import resolve_device
        from neoedit.utils.io import atomic_write_json, check_writable_output, default_output

        if (self.prompt is None) == (self.box is None):
            raise NeoError('give either a prompt ("red mug") or --box BOX.json, not both')
        if not (0 < self.grasp.friction < 10):
            raise NeoError("--grasp.friction must be in (0, 10)")
        if not (0.0005 <= self.grasp.surface.voxel_m <= 0.02):
            raise NeoError("--grasp.surface.voxel-m must be in [0.0005, 0.02] m")
        if not (0.0 < self.grasp.surface.opacity < 1.0):
            raise NeoError("--grasp.surface.opacity must be in (0, 1)")
        if not self.grasp.collision_density > 0:
            raise NeoError("--grasp.collision-density must be > 0 [1/m]")
        if self.grasp.min_width_m >= self.grasp.gripper.max_width_m:
            raise NeoError(
                f"--grasp.min-width-m ({self.grasp.min_width_m:g} m) must be below the "
                f"gripper's widest opening (--grasp.gripper.max-width-m "
                f"{self.grasp.gripper.max_width_m:g} m)"
            )
        request = self.prompt if self.prompt is not None else Path(self.box or "box").stem
        out = self.out or default_output("grasp", self.scene, request)
        check_writable_output(out, [self.scene], "grasp", self.overwrite)
        if self.json is not None:
            check_writable_output(self.json, [self.scene, self.box], "json", self.overwrite)
        scene = load_scene(self.scene, resolve_device(self.device))
        box = find_boxes(scene, self.prompt, self.box, self.query)[0]
        cfg = self.grasp
        if scene.meta.language is not None:  # the scan's up axis (z in NEO-Sim)
            x, y, z = (float(v) for v in scene.meta.language.up)
            cfg = dataclasses.replace(cfg, up=(x, y, z))
        t0 = time.perf_counter()
        grasps = plan_grasps(scene_density(scene), box, cfg, self.top)
        seconds = time.perf_counter() - t0
        if not grasps:
            console.print(
                f"[bold red]no collision-free grasp of {escape(self.prompt or 'the box')} "
                f"(planned in {seconds:.1f} s): the object may be wider than the "
                f"{self.grasp.gripper.max_width_m * 100:.0f} cm opening, or boxed in[/]"
            )
            raise SystemExit(1)
        records = [g.to_dict() for g in grasps]
        console.print_json(json.dumps(records))
        console.print(f"{len(grasps)} grasps in {seconds:.1f} s")
        self._picture(scene, box, grasps, out)
        if self.json is not None:
            atomic_write_json(self.json, records)

    def _picture(self, scene, box, grasps, out: Path) -> None:
        from neoedit.utils.io import atomic_directory, write_png
        from neoedit.viz.grasps import grasp_picture

        picture = grasp_picture(scene, box, grasps, self.grasp.gripper)
        with atomic_directory(out, overwrite=self.overwrite, kind="grasp") as tmp:
            write_png(tmp / "grasps.png", picture)
        console.print(f"wrote {escape(str(out / 'grasps.png'))}")

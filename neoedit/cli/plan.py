"""``neo plan``: apply an action plan step by step into a scene store."""

from __future__ import annotations

import dataclasses
import shutil
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Literal

import numpy as np
import tyro
from rich.console import Console
from rich.markup import escape

from neoedit.bench.seal3d import Seal3dConfig
from neoedit.cli.edit import (
    check_json_output,
    check_move_method,
    edit_result,
    find_boxes,
    report_writer,
)
from neoedit.edit.plan import FindBoxes, PlanConfig
from neoedit.edit.remove import RemoveConfig
from neoedit.errors import NeoError
from neoedit.language.localize import QueryConfig
from neoedit.utils.options import at_least_one, changed_options, spelt

if TYPE_CHECKING:
    from neoedit.scene import Scene

console = Console()


@dataclass
class PlanCommand:
    """Apply a plan — a YAML list of moves and removals (see neoedit.edit.plan) — one step
    after another, each step querying the version the previous one wrote. OUT becomes a
    scene store: OUT/step_0 (the input), OUT/step_1 .. OUT/step_N (each a scene every verb
    accepts, with report/before_after.png), and OUT/plan.png (the same views after every
    step). A step whose prompt matches nothing stops the plan; the versions done so far stay."""

    scene: tyro.conf.Positional[Path]
    """Scene to start from (a scene folder, a store or a store version)."""
    plan: tyro.conf.Positional[Path]
    """Plan file (.yaml / .yml / .json)."""
    out: Path
    """New scene store to write (must not exist yet)."""
    preview: bool = False
    """Instant previews only: moves composed at render time, removals cut, no training."""
    method: Literal["neo", "seal3d"] = "neo"
    """How moves are distilled: NEO, or the Seal-3D-style baseline (--seal3d.*)."""
    seal3d: Seal3dConfig = dataclasses.field(default_factory=Seal3dConfig)
    """The baseline's settings, with --method seal3d (--seal3d.schedule.render-steps ...)."""
    edit: PlanConfig = dataclasses.field(default_factory=PlanConfig)
    """NEO's move and removal settings (--edit.move.distill.render-steps, --edit.remove.margin-m
    ...); with --method seal3d the move steps take --seal3d.* instead."""
    query: QueryConfig = dataclasses.field(default_factory=QueryConfig)
    views: int = at_least_one(3)
    """Held-out views in plan.png."""
    json: Path | None = None
    """Also write the result here as JSON: every step's version folder, id, boxes, seconds
    and timings (written when the whole plan ran)."""
    overwrite: bool = False
    """Replace an existing --json file that holds JSON that is no dataset or scene file
    (OUT, the store, is always new)."""
    report: bool = True
    """Render every step's before/after pictures (step_K/report/; --no-report: only
    plan.png, seconds sooner per step)."""
    device: str = "auto"

    def run(self) -> None:
        self.query.check()  # before any loading or training
        check_move_method(self.method, self.preview, self.edit.move, self.seal3d, "--edit.move")
        if self.edit.preview:
            raise NeoError("--edit.preview is set by --preview: write --preview")
        self.edit.remove.check("--edit.remove")
        cut_uses = ("removal", "margin_m", "neighbour_similarity")  # a preview's removals cut
        ignored = (
            changed_options(self.edit.remove, RemoveConfig(), cut_uses) if self.preview else []
        )
        if ignored:
            flags = ", ".join(spelt("--edit.remove", n.replace("_", "-")) for n in ignored)
            raise NeoError(f"a preview's removals are cuts: {flags} would be ignored")
        from neoedit.edit.plan import apply_action, check_plan, load_plan, plan_boxes
        from neoedit.scene import load_scene, save_scene
        from neoedit.storage import SceneStore
        from neoedit.utils.device import resolve_device
        from neoedit.utils.io import atomic_write_json, check_writable_output
        from neoedit.viz.versions import pick_views, render_versions

        actions = load_plan(self.plan)  # every step checked before any work
        for a in actions:
            for step in a.steps:
                plan_boxes(step)
        if self.out.exists():
            raise NeoError(f"{self.out} already exists: a plan writes a new scene store")
        check_writable_output(self.out, [self.scene, self.plan], "store")
        check_json_output(self.json, self.out, (self.scene, self.plan), self.overwrite)
        scene = load_scene(self.scene, resolve_device(self.device))
        if scene.meta.language is None and any(s.prompt for a in actions for s in a.steps):
            raise NeoError("this scene has no language field: give the plan's steps a box")
        check_plan(scene, actions)
        cfg = dataclasses.replace(self.edit, preview=self.preview)
        move_edit = self.seal3d.move_edit() if self.method == "seal3d" else None
        store = SceneStore.create(self.out)
        views = pick_views(scene, self.views)
        columns = [render_versions([scene], views)]
        names = ["step_0"]
        steps = []
        failed: NeoError | None = None
        with store.lock():
            save_scene(self.out / "step_0", scene)
            for k, action in enumerate(actions, 1):
                try:
                    child = apply_action(
                        scene, action, self._finder(scene), cfg, move_edit=move_edit
                    )
                except NeoError as e:  # NoMatch too
                    failed = NeoError(f"step {k} ({action.label}): {e}; the plan stopped")
                    failed.exit_code = e.exit_code
                    break
                out = self.out / f"step_{k}"
                save_scene(out, child, extras=report_writer(self.report, scene, child))
                rec = child.meta.edits[-1]
                console.print(
                    f"step {k}: {escape(str(action.label))} -> {escape(str(out))} in {rec.seconds or 0:.1f} s"
                )
                steps.append(
                    {"step": k, "action": action.label, **edit_result(out, child, self.report)}
                )
                columns.append(render_versions([child], views))
                names.append(f"step_{k}")
                scene = child
        if failed is not None:
            self._stop(failed, columns, names)
        self._strip(columns, names)
        if self.json is not None:
            result = {"out": str(self.out), "plan_png": str(self.out / "plan.png"), "steps": steps}
            atomic_write_json(self.json, result)
        console.print(
            f"wrote {self.out} ({len(names)} versions); pictures in {self.out / 'plan.png'}",
            markup=False,
        )

    def _stop(self, failed: NeoError, columns: list, names: list[str]) -> None:
        """A step failed: the versions before it stay (with plan.png); when it was the first,
        the store holds only a copy of the input, and is removed (this command made it)."""
        if len(names) == 1:
            shutil.rmtree(self.out, ignore_errors=True)
            stop = NeoError(f"{failed}; nothing was written")
        else:
            self._strip(columns, names)
            stop = NeoError(f"{failed}, versions step_0 .. {names[-1]} are in {self.out}")
        stop.exit_code = failed.exit_code  # 1 when the step's prompt matched nothing
        raise stop from None

    def _finder(self, scene: Scene) -> FindBoxes:
        """The boxes of a step's objects on ``scene``: its own, or its prompt's query."""
        from neoedit.edit.plan import plan_boxes

        return lambda a: plan_boxes(a) or find_boxes(scene, a.prompt, None, self.query)

    def _strip(self, columns: list[list[list[np.ndarray]]], names: list[str]) -> None:
        """plan.png: one row per view, one column per version."""
        from neoedit.utils.io import write_png
        from neoedit.viz.contact_sheet import tile_images

        tiles, labels = [], []
        for v in range(len(columns[0])):
            for name, col in zip(names, columns, strict=True):
                tiles.append(col[v][0])
                labels.append(name)
        write_png(self.out / "plan.png", tile_images(tiles, cols=len(names), labels=labels))

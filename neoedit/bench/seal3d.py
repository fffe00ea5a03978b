"""The Seal-3D-style baseline (Wang et al., ICCV 2023), as the paper's Tables I-III run it.

One teacher: the current field, with the source boxes empty (nothing inpainted) and each
target box showing the field under the inverse motion. One student: the whole field,
initialised from the current weights. Two stages: a local one on points in and around the
boxes with the MLPs frozen (only the hash table learns), then a global one on the teacher's
rendered colour and depth over random rays of the scan's views (no virtual views).

:class:`SealMove` and :class:`SealRemove` are edits like NEO's
(:func:`neoedit.edit.pipeline.apply_edit` runs them; ``neo move --method seal3d``,
``neo plan --method seal3d`` and ``neo bench`` use them); the distillation machinery is
NEO's (:mod:`neoedit.edit.move_distill`), only the teacher and the schedule are the
baseline's. A parent with render-time edits (a preview move, a cut) is first settled by
NEO's default distillation (:func:`neoedit.edit.settle.settled_start`), as before any edit.
"""

from __future__ import annotations

import copy
import dataclasses
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from neoedit.edit.checks import check_edit_boxes
from neoedit.edit.distill import DistillConfig, RayPool, distill
from neoedit.edit.language_update import LanguageEdit, LanguageUpdateConfig
from neoedit.edit.motion import Motion, MoveRegions, check_motions
from neoedit.edit.move_distill import (
    base_field,
    distillation_grids,
    finish_grid,
    moved_parts,
    scan_ray_pool,
    with_patch_regions,
)
from neoedit.edit.pipeline import Prepared
from neoedit.edit.refine import RefineConfig
from neoedit.edit.remove import RemoveConfig, working_boxes
from neoedit.edit.settle import settled_start
from neoedit.errors import NeoError
from neoedit.fields.composed import ComposedField, EmptyField, MaskedField
from neoedit.fields.patched import edit_region
from neoedit.fields.radiance import Field, RadianceField
from neoedit.geometry import OrientedBox
from neoedit.records import EditRecord
from neoedit.rendering.occupancy import OccupancyGrid
from neoedit.scene import Scene
from neoedit.utils.timings import Timings

__all__ = ["Seal3dConfig", "SealMove", "SealRemove"]


def _schedule() -> DistillConfig:
    # Seal-3D's schedule, scaled to our budget: a local stage with frozen MLPs at a high
    # table rate, then global fine-tuning on random rays of the training views (no focus).
    return DistillConfig(
        field_steps=100,
        render_steps=200,
        focus=0.0,
        box_points=8192,
        lr=1e-2,
        mlp_lr_factor=0.1,
        local_rows=False,
    )


@dataclass
class Seal3dConfig:
    """How the baseline edits: its schedule and the boxes it empties."""

    schedule: DistillConfig = field(default_factory=_schedule)
    """Stage 1 (``field_steps``): the local point stage, MLPs frozen, on points in and
    around the boxes (grown by 2 cm); stage 2 (``render_steps``): the global stage, all
    weights, on the teacher's rendered colour and depth. The stages set ``freeze_mlp`` and
    ``regions_only`` themselves, and a whole-field student has no ``patch_mlp_lr_factor``:
    those three are not read."""
    margin_m: float = RemoveConfig.margin_m
    """Each box is grown by this much (short of neighbouring objects), as NEO's are."""
    below_m: float = RefineConfig.below_m
    """The emptied region reaches this far under each source box (the support under it is
    taught again)."""
    target_floor_m: float = 0.004
    """Each target box starts this far above its source box's bottom (as NEO's)."""
    language: LanguageUpdateConfig = field(default_factory=LanguageUpdateConfig)
    """How the language field follows the edit (as after NEO's edits)."""

    def check(self, where: str = "--seal3d") -> None:
        """Refuse settings the baseline cannot run with (before any work starts)."""
        self.schedule.check(f"{where}.schedule")
        self.language.check(f"{where}.language")
        for name in ("margin_m", "below_m", "target_floor_m"):
            if not np.isfinite(getattr(self, name)) or getattr(self, name) < 0:
                raise NeoError(f"{where}.{name.replace('_', '-')} must be a finite number >= 0")

    def move_edit(self) -> Callable[[list[Motion], str | None], SealMove]:
        """Makes a move step's edit from its motions and prompt (``neo plan``)."""
        return lambda motions, prompt: SealMove(motions, self, prompt)

    def working_boxes(self, parent: Scene, boxes: list[OrientedBox]) -> list[OrientedBox]:
        """The boxes the baseline empties: seated on the support, grown by ``margin_m``."""
        return working_boxes(parent, boxes, RemoveConfig(margin_m=self.margin_m))


@dataclass
class SealMove:
    """Move every ``motions[i].box`` by its transform, the Seal-3D way (the paper's
    Table II row)."""

    motions: list[Motion]
    cfg: Seal3dConfig = field(default_factory=Seal3dConfig)
    prompt: str | None = None

    def prepare(self, parent: Scene) -> Prepared:
        cfg = self.cfg
        cfg.check()
        check_motions(parent, self.motions)
        sources = cfg.working_boxes(parent, [m.box for m in self.motions])
        move = MoveRegions.of(self.motions, sources, cfg.target_floor_m)
        record = move.record(self.prompt, "seal3d", self.motions, [], cfg)

        def run(child: Scene, timings: Timings) -> None:
            start = settled_start(parent, child, DistillConfig(), timings)  # NEO's settling
            seal3d_distil(start, child, sources, move.targets, move.transforms, cfg, timings)

        return Prepared(record, run, move.language(), cfg.language)


@dataclass
class SealRemove:
    """The Seal-3D-style removal (the paper's Table I row): the grown boxes emptied in the
    teacher, the whole field distilled from it; nothing is inpainted."""

    boxes: list[OrientedBox]
    cfg: Seal3dConfig = field(default_factory=Seal3dConfig)
    prompt: str | None = None

    def prepare(self, parent: Scene) -> Prepared:
        cfg = self.cfg
        cfg.check()
        if not self.boxes:
            raise NeoError("nothing to remove: give a prompt or --box")
        check_edit_boxes(parent, self.boxes)
        sources = cfg.working_boxes(parent, self.boxes)
        details = {
            "removal": "seal3d",
            "boxes": [b.to_dict() for b in self.boxes],
            "edit_boxes": [b.to_dict() for b in sources],
            "config": dataclasses.asdict(cfg),
        }
        record = EditRecord("remove", self.prompt, "seal3d", details=details)

        def run(child: Scene, timings: Timings) -> None:
            start = settled_start(parent, child, DistillConfig(), timings)  # NEO's settling
            seal3d_distil(start, child, sources, [], [], cfg, timings)

        return Prepared(record, run, LanguageEdit(source=sources, targets=[]), cfg.language)


def seal3d_distil(
    parent: Scene,
    child: Scene,
    sources: list[OrientedBox],
    targets: list[OrientedBox],
    transforms: list[np.ndarray],
    cfg: Seal3dConfig,
    timings: Timings,
) -> None:
    """The baseline's teacher distilled into a whole-field student (``child.field``) by
    its two stages; ``child.grid`` refreshed."""
    with timings.stage("teacher"):
        moving = MaskedField(parent.field, parent.grid.is_occupied)
        empty: Field = EmptyField(parent.field.aabb)
        teacher = ComposedField(
            moving, [(sources, empty), *moved_parts(parent, targets, transforms)]
        )
    with timings.stage("setup"):
        regions = [*(edit_region(s, cfg.below_m) for s in sources), *targets]
        regions = with_patch_regions(parent, regions)  # earlier patches are baked in
        teacher_grid, student_grid = distillation_grids(parent, teacher, regions)
        pool = scan_ray_pool(parent, regions, cfg.schedule.seed)
        student = copy.deepcopy(base_field(parent.field))
    with timings.stage("distill"):
        losses = _two_stages(
            student, student_grid, teacher, teacher_grid, pool, regions, parent, cfg.schedule
        )
    with timings.stage("grid"):
        child.field = student
        finish_grid(parent, child, regions)
    timings.merge({k: round(v, 5) for k, v in losses.items()}, prefix="loss_")


def _two_stages(
    student: RadianceField,
    student_grid: OccupancyGrid,
    teacher: Field,
    teacher_grid: OccupancyGrid,
    pool: RayPool,
    regions: list[OrientedBox],
    parent: Scene,
    schedule: DistillConfig,
) -> dict[str, float]:
    """Seal-3D's stages: a local one (MLPs frozen, points in and around the boxes, every
    ray's colour held), then a global one (all weights, rendered colour + depth)."""
    dcfg = dataclasses.replace(schedule, freeze_mlp=True, regions_only=False)
    local = dataclasses.replace(dcfg, render_steps=0)
    glob = dataclasses.replace(dcfg, field_steps=0, freeze_mlp=False)
    grown = [b.grown(0.02) for b in regions]
    render, bg = parent.meta.render, parent.background
    losses = distill(student, student_grid, teacher, teacher_grid, pool, grown, render, bg, local)
    losses.update(
        distill(student, student_grid, teacher, teacher_grid, pool, regions, render, bg, glob)
    )
    return losses

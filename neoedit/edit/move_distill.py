"""The distillation of a move (paper Sec. III-C/D): the region-composed teacher (the current
field outside, the removed and inpainted field in the source boxes, the moved field in the
target boxes), the student (a patch for the hole beside the carried targets, two patches,
or the whole field) and the two-stage distillation between them.

The parts any distillation of a move shares (the moved parts of a teacher, the teacher's
and student's grids, the ray pool, the final grid) are functions here; the Seal-3D-style
baseline (:mod:`neoedit.bench.seal3d`) builds its own teacher and schedule from them."""

from __future__ import annotations

import copy
import dataclasses
from typing import cast

import numpy as np
import torch

from neoedit.edit.distill import DistillConfig, RayPool, distill
from neoedit.edit.inpaint import Inpainter
from neoedit.edit.motion import MoveConfig
from neoedit.edit.pipeline import Timings
from neoedit.edit.relight import (
    MIN_TURN_DEG,
    Light,
    estimate_light,
    relight_grid,
    turn_deg,
)
from neoedit.edit.remove import inpaint_removal
from neoedit.edit.views import VirtualViewConfig, virtual_views
from neoedit.fields.composed import ComposedField, MaskedField, TransformedField
from neoedit.fields.patched import PatchedField, edit_region
from neoedit.fields.radiance import Field, RadianceField
from neoedit.fields.shade import Shade
from neoedit.geometry import OrientedBox
from neoedit.rendering.occupancy import OccupancyGrid, cells_in_boxes, refresh_grid
from neoedit.scene import Scene


def moved_parts(
    parent: Scene, targets: list[OrientedBox], transforms: list[np.ndarray]
) -> list[tuple[list[OrientedBox], Field]]:
    """Each target box with the parent's field (as it renders: its grid applied) seen
    through the motion, the target parts of a composed teacher."""
    moving = MaskedField(parent.field, parent.grid.is_occupied)
    return [([g], TransformedField(moving, tf)) for g, tf in zip(targets, transforms, strict=True)]


def _teacher(
    parent: Scene,
    sources: list[OrientedBox],
    targets: list[OrientedBox],
    transforms: list[np.ndarray],
    cfg: MoveConfig,
    inpainter: Inpainter | None,
    shadows: list[OrientedBox],
) -> tuple[Field, PatchedField, dict[str, float]]:
    """The composed teacher S' (every part as it renders, its grid applied), the parent's
    field with the removal's patch (its region: the sources and the ``shadows`` slabs) and
    the timings of building it."""
    # the parent's field (earlier patches included) plus the removal's patch
    removed = Scene(
        copy.deepcopy(parent.field),
        copy.deepcopy(parent.grid),
        parent.meta,
        parent.language,
        parent.surface_points_m,
    )
    remove_cfg = dataclasses.replace(cfg.remove, virtual_views=cfg.virtual_views)
    timings = inpaint_removal(removed, [*sources, *shadows], sources, remove_cfg, inpainter)
    removed.field.requires_grad_(False)
    region = [edit_region(s, remove_cfg.refine.below_m) for s in [*sources, *shadows]]
    refresh_grid(removed.grid, removed.field.density, cells_in_boxes(removed.grid, region))
    base = MaskedField(removed.field, removed.grid.is_occupied)
    timings = {f"inpaint_{k}": v for k, v in timings.items()}
    return ComposedField(base, moved_parts(parent, targets, transforms)), removed.patched(), timings


def total_motions(
    parent: Scene, sources: list[OrientedBox], transforms: list[np.ndarray]
) -> list[np.ndarray]:
    """Per source: the motion its carried part will have over the scan's weights (this
    edit's after the one that carried the object there, if any)."""
    pf = parent.field
    totals = []
    for source, motion in zip(sources, transforms, strict=True):
        inside = pf.renderer_inside(source) if isinstance(pf, PatchedField) else None
        earlier = inside.matrix() if isinstance(inside, TransformedField) else np.eye(4)
        totals.append(np.asarray(motion, dtype=np.float64) @ earlier)
    return totals


def scan_light(
    parent: Scene, sources: list[OrientedBox], transforms: list[np.ndarray]
) -> tuple[Light | None, str]:
    """The scan's light read from the objects at ``sources`` when a carried object ends up
    turned from where the scan saw it (a translation needs no relighting, but a turned and
    relit object moved again still does), and what became of it (for the record)."""
    if all(turn_deg(t) < MIN_TURN_DEG for t in total_motions(parent, sources, transforms)):
        return None, "no turn"
    light = estimate_light(parent, sources)
    if light is None:
        return None, "too little surface seen"
    return light, "used" if light.usable else "the light explains too little of the brightness"


def relight_carried(patched: PatchedField, targets: list[OrientedBox], light: Light) -> None:
    """Give each carried part (the last ``len(targets)`` parts of ``patched``) that is
    turned the shading of its orientation under ``light`` (its total motion: a part carried
    again is relit from the scan's weights); a part that is not turned gets none."""
    parts = list(patched.parts)[len(patched.parts) - len(targets) :]
    for target, part in zip(targets, parts, strict=True):
        part = cast(TransformedField, part)
        if turn_deg(part.matrix()) >= MIN_TURN_DEG:
            part.relight = relight_grid(part.field, target, part.matrix(), light)


def base_field(field_: Field) -> RadianceField:
    """The radiance field under a patched field's patches (the field itself otherwise)."""
    return field_.base if isinstance(field_, PatchedField) else field_  # type: ignore[return-value]


def with_patch_regions(parent: Scene, regions: list[OrientedBox]) -> list[OrientedBox]:
    """``regions`` and the regions of the parent's earlier patches and shades: a whole-field
    student bakes them in, so it is taught there too."""
    if not isinstance(parent.field, PatchedField):
        return regions
    shades = [s.box for s in cast(list[Shade], list(parent.field.shades))]
    return [*regions, *(b for region in parent.field.regions for b in region), *shades]


def distillation_grids(
    parent: Scene, teacher: Field, regions: list[OrientedBox]
) -> tuple[OccupancyGrid, OccupancyGrid]:
    """The teacher's grid (the parent's, refreshed from the teacher in ``regions``) and the
    student's (sampled wherever the teacher or the parent's weights have content)."""
    teacher_grid = copy.deepcopy(parent.grid)
    refresh_grid(teacher_grid, teacher.density, cells_in_boxes(teacher_grid, regions))
    student_grid = copy.deepcopy(teacher_grid)
    student_grid.density.copy_(torch.maximum(teacher_grid.density, parent.grid.density))
    student_grid.refresh_mask()
    return teacher_grid, student_grid


def finish_grid(parent: Scene, child: Scene, regions: list[OrientedBox]) -> None:
    """``child.grid``: the parent's, refreshed from the child's field in ``regions``."""
    child.grid = copy.deepcopy(parent.grid)
    refresh_grid(child.grid, child.field.density, cells_in_boxes(child.grid, regions))


def scan_ray_pool(
    parent: Scene,
    regions: list[OrientedBox],
    seed: int,
    virtual_around: list[OrientedBox] | None = None,
    views: VirtualViewConfig | None = None,
) -> RayPool:
    """Rays of the scan's training views, and of virtual views around ``virtual_around``."""
    cameras, _, split = parent.scan_cameras()
    scan = cameras.subset(split.get("train", np.arange(len(cameras))))
    virtual = None
    if virtual_around:
        views = views or VirtualViewConfig()
        # a source of rays, not inpainted: the views' own scale, however small the box
        virtual = virtual_views(virtual_around, scan, views, views.image_scale)
    return RayPool(scan, virtual, regions, parent.field.aabb.device, seed)


def _distil_config(cfg: MoveConfig, patch_mode: bool) -> DistillConfig:
    """NEO's distillation schedule under ``cfg``'s ablation."""
    dcfg = cfg.distill
    if cfg.field_only:
        dcfg = dataclasses.replace(
            dcfg, field_steps=dcfg.field_steps + dcfg.render_steps, render_steps=0
        )
    # a patch student is its parent, bit for bit, outside its boxes: only rays through them
    # teach it, and no row mask is needed (a whole-field student must also be held where it
    # is everywhere else)
    if patch_mode:
        return dataclasses.replace(dcfg, regions_only=True, local_rows=False)
    return dataclasses.replace(dcfg, regions_only=False)


def _students(
    parent: Scene,
    child: Scene,
    source_regions: list[OrientedBox],
    targets: list[OrientedBox],
    dcfg: DistillConfig,
    patch_mode: bool,
    removed: PatchedField | None,
    carried: list[tuple[OrientedBox, np.ndarray]] | None = None,
) -> RadianceField | list[tuple[RadianceField, float]]:
    """What the distillation trains, with each part's MLP rate factor; sets ``child.field``
    for a patch student. ``removed`` (the parent's field with the removal's patch): keep
    that patch as the source part. ``carried`` (per target: its source box and motion):
    the target parts are the parent's own weights under the motion, frozen, not students."""
    if carried is not None:
        pf = parent.field
        inits = [pf.renderer_inside(s) if isinstance(pf, PatchedField) else pf for s, _ in carried]
        child.field = copy.deepcopy(removed if removed is not None else parent.field)
        patched = child.patched()
        students = []
        if removed is None:  # the hole is distilled from the composed teacher
            students.append((patched.add_patch(source_regions), dcfg.mlp_lr_factor))
        for target, init, (_, motion) in zip(targets, inits, carried, strict=True):
            patched.add_carried([target], motion, init)
        return students
    if removed is not None:
        # the removal's patch is the teacher in the source region: keep its weights, and train
        # only the target boxes' patch, initialised from what renders them in the parent (rays
        # still cross both regions: measured on pick_place_3, drawing them all through the
        # target left a haze above the moved brick and its query box 0.72 -> 0.46 IoU)
        pf = parent.field
        init = pf.trained_part_of(targets) if isinstance(pf, PatchedField) else base_field(pf)
        child.field = copy.deepcopy(removed)
        return [(child.patched().add_patch(list(targets), init), dcfg.patch_mlp_lr_factor)]
    if patch_mode:
        # two patches: the source regions (MLPs frozen, as the inpainted hole needs only the
        # table's rows) and the target boxes (MLPs learning: a new object stands there)
        child.field = copy.deepcopy(parent.field)
        patched = child.patched()
        return [
            (patched.add_patch(source_regions), dcfg.mlp_lr_factor),
            (patched.add_patch(list(targets)), dcfg.patch_mlp_lr_factor),
        ]
    return copy.deepcopy(base_field(parent.field))


def distil_move(
    parent: Scene,
    child: Scene,
    sources: list[OrientedBox],
    targets: list[OrientedBox],
    transforms: list[np.ndarray],
    cfg: MoveConfig,
    inpainter: Inpainter | None,
    timings: Timings,
    shadows: list[OrientedBox] | None = None,
    shades: list[tuple[OrientedBox, np.ndarray]] | None = None,
) -> None:
    """Build NEO's teacher, distil it into ``child.field`` (a patch for the hole and a
    carried part per target; with ``carry`` off two patches, with ``student='field'`` a
    plain radiance field initialised from the parent's weights) and refresh ``child.grid``.
    ``shadows``: slabs on the support around the sources (their shadows), emptied and
    inpainted with them; ``shades`` (slab, ratio map): the shadows laid around the targets
    of a carried object."""
    shadows = shadows or []
    # the object carried under the motion: NEO's patch student (a whole-field student
    # distils everything, so --edit.carry does not apply to it)
    carry = cfg.carry and cfg.student == "patch"
    light = None
    if cfg.relight and carry:  # first: it fails before the work
        with timings.stage("light"):
            light, outcome = scan_light(parent, sources, transforms)
        found = {} if light is None else light.to_dict()
        child.meta.edits[-1].details["light"] = {**found, "used": outcome == "used", "why": outcome}
    with timings.stage("teacher"):
        teacher, removed, built = _teacher(
            parent, sources, targets, transforms, cfg, inpainter, shadows
        )
    timings.merge(built)  # inpaint_<stage>_s
    with timings.stage("setup"):
        # edited regions: the boxes, the removal patch's region, earlier patches being baked in
        below = cfg.remove.refine.below_m
        emptied = [*sources, *shadows]
        regions = [*(edit_region(s, below) for s in emptied), *targets]
        patch_mode = cfg.student == "patch"
        if not patch_mode:
            regions = with_patch_regions(parent, regions)
        teacher_grid, student_grid = distillation_grids(parent, teacher, regions)
        virtual = [*sources, *targets] if cfg.virtual_views else None
        pool = scan_ray_pool(parent, regions, cfg.distill.seed, virtual, cfg.remove.views)
        dcfg = _distil_config(cfg, patch_mode)
        keep = removed if patch_mode and cfg.reuse_removal_patch else None
        source_regions = regions[: len(emptied)]
        carried = list(zip(sources, transforms, strict=True)) if carry else None
        students = _students(
            parent, child, source_regions, targets, dcfg, patch_mode, keep, carried
        )
    losses: dict[str, float] = {}
    with timings.stage("distill"):
        if students:  # nothing to distil: a carried object beside the removal's own patch
            losses = distill(
                students, student_grid, teacher, teacher_grid, pool, regions,
                parent.meta.render, parent.background, dcfg,
                view=child.field if patch_mode else None,
            )  # fmt: skip
    if light is not None and light.usable:
        with timings.stage("relight"):
            relight_carried(child.patched(), targets, light)
    if carried is not None and shades:
        # after the distillation (the teacher has no shades: a student under one would learn
        # to undo it), under the carried objects (their own colours stay)
        patched = child.patched()
        first_carried = len(patched.parts) - len(carried)
        for slab, ratio in shades:
            patched.add_shade(slab, torch.as_tensor(ratio), after=first_carried)
    with timings.stage("grid"):
        if isinstance(students, RadianceField):
            child.field = students
        finish_grid(parent, child, regions)
    timings.merge({k: round(v, 5) for k, v in losses.items()}, prefix="loss_")

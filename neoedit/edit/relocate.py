"""``neo move``: relocate objects by region-composed teacher -> student distillation
(paper Sec. III-C, III-D) as a new scene version.

* ``preview``: no training. The version records the move; every render composes the
  current field (outside), nothing in the source box, and the field under the inverse
  motion in the target box (about a second, like Seal-3D's preview).
* ``neo`` (the paper): the source box is removed and inpainted (the removal pipeline,
  :func:`neoedit.edit.remove.inpaint_removal`), the teacher is composed region by region
  — current field outside, removed+inpainted field in the source box, moved field in the
  target box (target wins) — and distilled into a student initialised from the current
  weights, on rays of the scan cameras and of virtual views around source and target.
* ``seal3d`` (the baseline, Seal-3D, Wang et al. ICCV 2023): one teacher — the current
  field with the target box mapped back by the inverse motion and the source box empty,
  no inpainting —, a local point-level stage (density + colour on points in and around the
  boxes, MLPs frozen: only the hash table learns) and a global stage on the teacher's
  rendered RGB + depth over random rays of the scan's views.

The output has the structure of its input (one radiance field + language field), so it is
a valid input to every verb, another move included.
"""

from __future__ import annotations

import copy
import dataclasses
import time
from dataclasses import dataclass, field

import numpy as np
import torch

from neoedit.edit.checks import check_edit_boxes
from neoedit.edit.distill import DistillConfig, RayPool, distill
from neoedit.edit.history import new_version
from neoedit.edit.inpaint import Inpainter
from neoedit.edit.language_update import LanguageEdit, LanguageUpdateConfig, update_language
from neoedit.edit.refine import RefineConfig
from neoedit.edit.remove import RemoveConfig, inpaint_removal, working_boxes
from neoedit.edit.settle import settle
from neoedit.edit.views import concat_cameras, virtual_cameras
from neoedit.errors import NeoError
from neoedit.fields.composed import ComposedField, EmptyField, MaskedField, TransformedField
from neoedit.fields.patched import PatchedField, edit_region
from neoedit.fields.radiance import Field, RadianceField
from neoedit.geometry import OrientedBox, is_rigid
from neoedit.geometry.box import box_iou_3d
from neoedit.rendering.occupancy import OccupancyGrid, cells_in_boxes, refresh_grid
from neoedit.scene import Scene

METHODS = ("neo", "seal3d")
STUDENTS = ("patch", "field")
MAX_TILT_DEG = 5.0
"""Largest tilt a motion may have (a placement that settled slightly askew, as NEO-Sim's
realised transforms do); the field turns the object exactly, its boxes keep only the yaw."""


def _seal3d_default() -> DistillConfig:
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
class MoveConfig:
    method: str = "neo"
    """'neo' (region-composed teachers, inpainted source) or 'seal3d' (the baseline)."""
    preview: bool = False
    """Instant preview: record the move, render it by composition, train nothing."""
    remove: RemoveConfig = field(
        default_factory=lambda: RemoveConfig(refine=RefineConfig(steps=90))
    )
    """How the source box is emptied and inpainted (neo): box margin, inpainter, refinement."""
    distill: DistillConfig = field(default_factory=DistillConfig)
    """NEO's two-stage distillation."""
    seal3d: DistillConfig = field(default_factory=_seal3d_default)
    """The Seal-3D-style baseline's schedule (stage 1 = its local point stage, MLPs frozen;
    stage 2 = its global stage)."""
    language: LanguageUpdateConfig = field(default_factory=LanguageUpdateConfig)
    target_floor_m: float = 0.004
    """The target region starts this far above the source box's bottom, so the support
    surface at the target stays the current field's (not the source's table, shadow
    included)."""
    virtual_views: bool = True
    """Distil on rays of virtual views around source and target too (False: the ablation
    'without virtual view distribution', which also inpaints on scan views)."""
    field_only: bool = False
    """Distil with stage 1 only, for the whole budget (the ablation 'field distillation
    only')."""
    reuse_removal_patch: bool = False
    """Patch student: keep the removal's own patch (the teacher there: the same weights) as
    the source region's part instead of distilling the source into a fresh patch; only the
    target patch learns (NEO's patch student only).
    Measured on NEO-Sim pick_place_2-6: 7-18 % less edit time (mean 12 %) at the same
    In-PSNR and query boxes; Out-PSNR -0.44 dB on average (-1.2 / -1.6 dB on pick_place_2
    / 3: distilling the hole from the scan's views too makes it more consistent than the
    removal's virtual views alone); see benchmarks/RESULTS.md."""
    student: str = "patch"
    """'patch': the student is two new patches of the field, initialised from the current
    weights: one owns the source boxes with the support under them (its MLPs learn at
    ``distill.mlp_lr_factor``, 0 by default: the hole needs only table rows;
    ``reuse_removal_patch``: the removal's own patch instead), one owns the target boxes
    (its MLPs learn at ``distill.patch_mlp_lr_factor``: a new object stands there); the rest
    of the scene stays bit-identical, so a chain of edits cannot wash it out. 'field': the
    whole field is the student (updates limited to the table rows that samples in the boxes
    read; earlier patches are baked in). The Seal-3D-style baseline always distils the whole
    field, as Seal-3D does."""


@dataclass
class Motion:
    """One object to move: its box (from a query or a file) and the 4x4 world transform."""

    box: OrientedBox
    transform: np.ndarray


def check_motions(scene: Scene, motions: list[Motion]) -> None:
    """Refuse non-rigid or non-finite transforms and targets outside the scene box."""
    if not motions:
        raise NeoError("nothing to move: give a prompt or --box")
    check_edit_boxes(scene, [m.box for m in motions])  # inside the scene box, not empty
    aabb = scene.field.aabb.cpu().numpy()
    for m in motions:
        if not is_rigid(m.transform):
            raise NeoError(
                "the transform must be a finite rigid motion (orthonormal rotation, det +1, "
                f"last row 0 0 0 1); got {np.round(np.asarray(m.transform), 4).tolist()}"
            )
        if np.allclose(m.transform, np.eye(4), atol=1e-6):
            raise NeoError("the motion is the identity: nothing would move")
        rot = np.asarray(m.transform)[:3, :3]
        tilt = float(np.degrees(np.arccos(np.clip(rot[2, 2], -1.0, 1.0))))
        if tilt > MAX_TILT_DEG:
            raise NeoError(
                f"the motion tilts the object by {tilt:.1f} degrees: only motions that keep it "
                f"upright (rotation about the vertical axis, up to {MAX_TILT_DEG:.0f} degrees of "
                "tilt, as a settled real placement has) are supported; the boxes are yaw-only"
            )
        corners = m.box.transformed(m.transform).corners()
        if np.any(corners.min(0) < aabb[0] - 1e-6) or np.any(corners.max(0) > aabb[1] + 1e-6):
            raise NeoError(
                f"the target box (centre {np.round(m.box.transformed(m.transform).center_m, 3).tolist()}"
                f" m) leaves the scene box {np.round(aabb, 3).tolist()}"
            )


def move(
    parent: Scene,
    motions: list[Motion],
    cfg: MoveConfig,
    prompt: str | None = None,
    inpainter: Inpainter | None = None,
) -> Scene:
    """A new version of ``parent`` with every ``motions[i].box`` moved by its transform
    (``parent`` is left unchanged)."""
    if cfg.method not in METHODS:
        raise NeoError(f"unknown method {cfg.method!r} (choose from {', '.join(METHODS)})")
    if cfg.student not in STUDENTS:
        raise NeoError(f"unknown student {cfg.student!r} (choose from {', '.join(STUDENTS)})")
    if cfg.reuse_removal_patch and (cfg.preview or cfg.method != "neo" or cfg.student != "patch"):
        raise NeoError(
            "--edit.reuse-removal-patch applies to NEO's patch student only (not with "
            "--preview, --method seal3d or --edit.student field)"
        )
    check_motions(parent, motions)
    cfg.distill.check("--edit.distill")
    cfg.seal3d.check("--edit.seal3d")
    cfg.remove.refine.check("--edit.remove.refine")
    cfg.language.check("--edit.language")
    t0 = time.perf_counter()
    sources = working_boxes(parent, [m.box for m in motions], cfg.remove)
    transforms = [np.asarray(m.transform, dtype=np.float64) for m in motions]
    targets = [
        s.transformed(t).lifted_bottom(cfg.target_floor_m)
        for s, t in zip(sources, transforms, strict=True)
    ]
    record = {
        "type": "move",
        "prompt": prompt,
        "method": "preview" if cfg.preview else cfg.method,
        "boxes": [m.box.to_dict() for m in motions],
        "source_boxes": [b.to_dict() for b in sources],
        "target_boxes": [b.to_dict() for b in targets],
        "transforms": [t.round(9).tolist() for t in transforms],
        "config": dataclasses.asdict(cfg),
    }
    if cfg.preview:
        _check_not_into_cuts(parent, targets)
    child = new_version(parent, record)
    if cfg.preview:
        timings = _preview(child, sources, targets, transforms)
    else:
        start, timings = _settled(parent, child, cfg)
        timings.update(_distil_move(start, child, sources, targets, transforms, cfg, inpainter))
    t = time.perf_counter()
    edit = LanguageEdit(sources, list(zip(targets, transforms, strict=True)))
    timings.update(update_language(parent, child, edit, cfg.language))
    timings["language_total_s"] = round(time.perf_counter() - t, 2)
    child.meta.edits[-1]["timings"] = timings
    child.meta.edits[-1]["seconds"] = round(time.perf_counter() - t0, 2)
    return child


def distil_removal(
    parent: Scene,
    boxes: list[OrientedBox],
    cfg: MoveConfig | None = None,
    prompt: str | None = None,
) -> Scene:
    """The Seal-3D-style removal (the paper's Table I row): the whole field distilled from one
    teacher, the current field with the grown boxes emptied, by the baseline's two stages;
    nothing is inpainted. ``parent`` is left unchanged."""
    cfg = dataclasses.replace(cfg or MoveConfig(), method="seal3d", preview=False)
    if not boxes:
        raise NeoError("nothing to remove: give a prompt or --box")
    check_edit_boxes(parent, boxes)
    t0 = time.perf_counter()
    sources = working_boxes(parent, boxes, cfg.remove)
    record = {
        "type": "remove",
        "prompt": prompt,
        "removal": "seal3d",
        "boxes": [b.to_dict() for b in boxes],
        "edit_boxes": [b.to_dict() for b in sources],
        "config": dataclasses.asdict(cfg),
    }
    child = new_version(parent, record)
    start, timings = _settled(parent, child, cfg)
    timings.update(_distil_move(start, child, sources, [], [], cfg, None))
    timings.update(update_language(parent, child, LanguageEdit(source=sources, targets=[])))
    child.meta.edits[-1]["timings"] = timings
    child.meta.edits[-1]["seconds"] = round(time.perf_counter() - t0, 2)
    return child


def _settled(parent: Scene, child: Scene, cfg: MoveConfig) -> tuple[Scene, dict[str, float]]:
    """A preview or cut parent: settle its render-time edits into ``child`` first, and start
    the distillation from what it shows; -> (the scene to start from, timings)."""
    timings = settle(child, cfg.distill)
    if not timings:
        return parent, timings
    start = Scene(copy.deepcopy(child.field), copy.deepcopy(child.grid), child.meta)
    start.language, start.surface_points_m = parent.language, parent.surface_points_m
    return start, timings


def _check_not_into_cuts(parent: Scene, targets: list[OrientedBox]) -> None:
    """Render-time removals apply after render-time moves: a preview move into a box that
    this version cuts or suppresses would be cut too."""
    pending = [
        OrientedBox.from_dict(b) for b in [*parent.meta.cut_boxes, *parent.meta.suppress_boxes]
    ]
    for t in targets:
        if any(box_iou_3d(t, c) > 0 for c in pending):
            raise NeoError(
                "the target box meets a box this version removes at render time (a removal "
                "without inpainting): a preview move there would be cut away too; move "
                "without --preview, or remove with inpainting first"
            )


def _preview(
    child: Scene,
    sources: list[OrientedBox],
    targets: list[OrientedBox],
    transforms: list[np.ndarray],
) -> dict[str, float]:
    t = time.perf_counter()
    for s, g, tf in zip(sources, targets, transforms, strict=True):
        child.meta.moves.append(
            {"source": s.to_dict(), "target": g.to_dict(), "transform": tf.round(9).tolist()}
        )
    field_, _ = child.renderable()
    refresh_grid(child.grid, field_.density, cells_in_boxes(child.grid, [*sources, *targets]))
    return {"preview_s": round(time.perf_counter() - t, 2)}


def _teacher(
    parent: Scene,
    sources: list[OrientedBox],
    targets: list[OrientedBox],
    transforms: list[np.ndarray],
    cfg: MoveConfig,
    inpainter: Inpainter | None,
) -> tuple[Field, PatchedField | None, dict[str, float]]:
    """The composed teacher S' (every part as it renders, its grid applied), the parent's
    field with the removal's patch (None for the baseline) and the timings of building it."""
    moving = MaskedField(parent.field, parent.grid.is_occupied)
    moved = [([g], TransformedField(moving, tf)) for g, tf in zip(targets, transforms, strict=True)]
    if cfg.method == "seal3d":
        empty: Field = EmptyField(parent.field.aabb)
        return ComposedField(moving, [(sources, empty), *moved]), None, {}
    # the parent's field (earlier patches included) plus the removal's patch
    removed = Scene(
        copy.deepcopy(parent.field),
        copy.deepcopy(parent.grid),
        parent.meta,
        parent.language,
        parent.surface_points_m,
    )
    remove_cfg = dataclasses.replace(cfg.remove, virtual_views=cfg.virtual_views)
    timings = inpaint_removal(removed, sources, sources, remove_cfg, inpainter)
    removed.field.requires_grad_(False)
    region = [edit_region(s, remove_cfg.refine.below_m) for s in sources]
    refresh_grid(removed.grid, removed.field.density, cells_in_boxes(removed.grid, region))
    base = MaskedField(removed.field, removed.grid.is_occupied)
    timings = {f"inpaint_{k}": v for k, v in timings.items()}
    return ComposedField(base, moved), removed.patched(), timings


def _base(field_: Field) -> RadianceField:
    return field_.base if isinstance(field_, PatchedField) else field_  # type: ignore[return-value]


def _distil_config(cfg: MoveConfig, patch_mode: bool) -> DistillConfig:
    """The distillation schedule of ``cfg``'s method and ablation."""
    dcfg = cfg.seal3d if cfg.method == "seal3d" else cfg.distill
    if cfg.method == "seal3d":
        dcfg = dataclasses.replace(dcfg, freeze_mlp=True)
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


def _seal3d_distil(
    student: RadianceField,
    student_grid: OccupancyGrid,
    teacher: Field,
    teacher_grid: OccupancyGrid,
    pool: RayPool,
    regions: list[OrientedBox],
    parent: Scene,
    dcfg: DistillConfig,
) -> dict[str, float]:
    """Seal-3D's two stages: a local one (MLPs frozen, points in and around the boxes),
    then a global one (all weights, rendered RGB + depth)."""
    local = dataclasses.replace(dcfg, render_steps=0)
    glob = dataclasses.replace(dcfg, field_steps=0, freeze_mlp=False)
    grown = [b.grown(0.02) for b in regions]
    render, bg = parent.meta.render, parent.background
    losses = distill(student, student_grid, teacher, teacher_grid, pool, grown, render, bg, local)
    losses.update(
        distill(student, student_grid, teacher, teacher_grid, pool, regions, render, bg, glob)
    )
    return losses


def _students(
    parent: Scene,
    child: Scene,
    source_regions: list[OrientedBox],
    targets: list[OrientedBox],
    dcfg: DistillConfig,
    patch_mode: bool,
    removed: PatchedField | None,
) -> RadianceField | list[tuple[RadianceField, float]]:
    """What the distillation trains, with each part's MLP rate factor; sets ``child.field``
    for a patch student. ``removed`` (the parent's field with the removal's patch): keep
    that patch as the source part and train only the target's."""
    if removed is not None:
        # the removal's patch is the teacher in the source region: keep its weights, and train
        # only the target boxes' patch, initialised from what renders them in the parent (rays
        # still cross both regions: measured on pick_place_3, drawing them all through the
        # target left a haze above the moved brick and its query box 0.72 -> 0.46 IoU)
        pf = parent.field
        init = pf.renderer_of(targets) if isinstance(pf, PatchedField) else _base(pf)
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
    return copy.deepcopy(_base(parent.field))


def _distil_move(
    parent: Scene,
    child: Scene,
    sources: list[OrientedBox],
    targets: list[OrientedBox],
    transforms: list[np.ndarray],
    cfg: MoveConfig,
    inpainter: Inpainter | None,
) -> dict[str, float]:
    """Build the teacher, distil it into ``child.field`` (two new patches of the parent's
    field, or with ``student='field'`` a plain radiance field initialised from the parent's
    weights) and refresh ``child.grid``."""
    t = time.perf_counter()
    teacher, removed, timings = _teacher(parent, sources, targets, transforms, cfg, inpainter)
    timings["teacher_s"] = round(time.perf_counter() - t, 2)
    t = time.perf_counter()
    # edited regions: the boxes, the removal patch's region, earlier patches being baked in
    below = cfg.remove.refine.below_m
    regions = [*(edit_region(s, below) for s in sources), *targets]
    patch_mode = cfg.student == "patch" and cfg.method == "neo"
    if isinstance(parent.field, PatchedField) and not patch_mode:
        # a whole-field student bakes the earlier patches in
        regions += [b for region in parent.field.regions for b in region]
    teacher_grid = copy.deepcopy(parent.grid)
    refresh_grid(teacher_grid, teacher.density, cells_in_boxes(teacher_grid, regions))
    # the student is sampled wherever the teacher or the student's initial weights have content
    student_grid = copy.deepcopy(teacher_grid)
    student_grid.density.copy_(torch.maximum(teacher_grid.density, parent.grid.density))
    student_grid.refresh_mask()
    cameras, _, split = parent.scan_cameras()
    scan = cameras.subset(split.get("train", np.arange(len(cameras))))
    virtual = None
    if cfg.virtual_views and cfg.method == "neo":
        views = cfg.remove.views
        virtual = concat_cameras([virtual_cameras(b, scan, views) for b in [*sources, *targets]])
    pool = RayPool(scan, virtual, regions, parent.field.aabb.device, cfg.distill.seed)
    dcfg = _distil_config(cfg, patch_mode)
    keep = removed if patch_mode and cfg.reuse_removal_patch else None
    students = _students(parent, child, regions[: len(sources)], targets, dcfg, patch_mode, keep)
    timings["setup_s"] = round(time.perf_counter() - t, 2)
    t = time.perf_counter()
    args = (student_grid, teacher, teacher_grid, pool)
    if cfg.method == "seal3d" and isinstance(students, RadianceField):  # always a whole field
        losses = _seal3d_distil(students, *args, regions, parent, dcfg)
    else:
        losses = distill(
            students, *args, regions, parent.meta.render, parent.background, dcfg,
            view=child.field if patch_mode else None,
        )  # fmt: skip
    timings["distill_s"] = round(time.perf_counter() - t, 2)
    t = time.perf_counter()
    if isinstance(students, RadianceField):
        child.field = students
    child.grid = copy.deepcopy(parent.grid)
    refresh_grid(child.grid, child.field.density, cells_in_boxes(child.grid, regions))
    timings["grid_s"] = round(time.perf_counter() - t, 2)
    timings.update({f"loss_{k}": round(v, 5) for k, v in losses.items()})
    return timings

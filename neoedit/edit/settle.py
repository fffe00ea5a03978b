"""Settle a version's render-time edits into weights before another edit builds on it.

A ``--preview`` move or a removal without inpainting changes how a version renders without
training anything (the renderer composes the move, cuts or suppresses the boxes). An edit
that trains on such a version must start from what the version *shows*, so it first
distils that view into a patch owning the pending boxes (the same two-stage distillation a
move uses) and clears the render-time records. Instant edits need none of this: they just
add their own record.
"""

from __future__ import annotations

import copy
import dataclasses

import numpy as np

from neoedit.edit.distill import DistillConfig, RayPool, distill
from neoedit.fields.suppressed import SuppressedField
from neoedit.geometry import OrientedBox
from neoedit.rendering.occupancy import cells_in_boxes, refresh_grid
from neoedit.scene import Scene
from neoedit.utils.timings import Timings


def pending_boxes(scene: Scene) -> list[OrientedBox]:
    """Every box a render-time edit of ``scene`` changes (cut, suppressed, moved from/to)."""
    meta = scene.meta
    records = [*meta.cut_boxes, *meta.suppress_boxes]
    records += [b for m in meta.moves for b in (m["source"], m["target"])]
    return [OrientedBox.from_dict(b) for b in records]


def settle(scene: Scene, cfg: DistillConfig | None = None) -> dict[str, float]:
    """Distil ``scene``'s render-time edits into a new patch (in place); returns timings
    (empty when there is nothing pending)."""
    boxes = pending_boxes(scene)
    if not boxes:
        return {}
    timings = Timings()
    with timings.stage("settle"):
        # the patch is the field, bit for bit, outside the pending boxes: only rays through them teach
        cfg = dataclasses.replace(cfg or DistillConfig(), local_rows=False, regions_only=True)
        shown = Scene(copy.deepcopy(scene.field), scene.grid, scene.meta)
        view, cut = shown.renderable()  # built now: clearing the records below does not change it
        teacher = SuppressedField(view, cut) if cut else view  # a cut box shows nothing
        teacher_grid = copy.deepcopy(scene.grid)
        scene.meta.moves, scene.meta.cut_boxes, scene.meta.suppress_boxes = [], [], []
        cameras, _, split = scene.scan_cameras()
        scan = cameras.subset(split.get("train", np.arange(len(cameras))))
        device = scene.field.aabb.device
        pool = RayPool(scan, None, boxes, device, cfg.seed)
        patch = scene.patched().add_patch(boxes)
        distill(
            patch, teacher_grid, teacher, teacher_grid, pool, boxes,
            scene.meta.render, scene.background, cfg, view=scene.field,
        )  # fmt: skip
        refresh_grid(scene.grid, scene.field.density, cells_in_boxes(scene.grid, boxes))
    return timings


def settled_start(
    parent: Scene, child: Scene, cfg: DistillConfig, timings: dict[str, float]
) -> Scene:
    """The scene an edit that trains starts from: ``parent`` itself, or, when it has
    render-time edits, what it shows (they are settled into ``child`` first; their timings
    are added to ``timings``)."""
    settled = settle(child, cfg)
    timings.update(settled)
    if not settled:
        return parent
    start = Scene(copy.deepcopy(child.field), copy.deepcopy(child.grid), child.meta)
    start.language, start.surface_points_m = parent.language, parent.surface_points_m
    return start

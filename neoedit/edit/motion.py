"""What a move is: the objects' boxes and rigid motions (:class:`Motion`, checked by
:func:`check_motions`) and how NEO does it (:class:`MoveConfig`: the removal at the source,
the distillation, the ablations' switches)."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import Any, Literal, get_args

import numpy as np

from neoedit.edit.checks import check_edit_boxes
from neoedit.edit.distill import DistillConfig
from neoedit.edit.language_update import LanguageEdit, LanguageUpdateConfig
from neoedit.edit.refine import RefineConfig
from neoedit.edit.remove import RemoveConfig
from neoedit.errors import NeoError
from neoedit.geometry import OrientedBox, is_rigid
from neoedit.geometry.box import box_iou_3d
from neoedit.records import EditRecord
from neoedit.scene import Scene

Student = Literal["patch", "field"]
STUDENTS: tuple[str, ...] = get_args(Student)
MAX_TILT_DEG = 5.0
"""Largest tilt a motion may have (a placement that settled slightly askew, as NEO-Sim's
realised transforms do); the field turns the object exactly, its boxes keep only the yaw."""


@dataclass
class MoveConfig:
    """How NEO moves objects (the Seal-3D-style baseline has its own configuration,
    :class:`neoedit.bench.seal3d.Seal3dConfig`; the instant preview,
    :class:`neoedit.edit.relocate.PreviewMove`, uses ``remove``'s margins,
    ``target_floor_m`` and ``language``)."""

    remove: RemoveConfig = field(
        default_factory=lambda: RemoveConfig(refine=RefineConfig(steps=90))
    )
    """How the source box is emptied and inpainted (neo): box margin, inpainter, refinement."""
    distill: DistillConfig = field(default_factory=DistillConfig)
    """NEO's two-stage distillation."""
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
    carry: bool = True
    """The moved object keeps its own weights: each target box is a frozen copy of the
    parent's field seen through the motion (exactly what the teacher shows there), and
    only the source region (the inpainted hole) is distilled; with
    ``reuse_removal_patch`` nothing is distilled at all. Measured on NEO-Sim pick_place_1-3
    (benchmarks/RESULTS.md): In-PSNR +0.47 dB on average over distilling the target
    (+0.92 / +0.56 / -0.06), Out +0.06 dB, 7 % less time; on beer_can the moved can keeps
    its print. False: the paper's design, the target patch distilled from the composed
    teacher (NEO's patch student only)."""
    shadow_follows: bool = True
    """The shadow found at a source (``remove.shadow``) is laid down again around its
    target: a shade, a ratio map on the target's support (neoedit/fields/shade.py),
    translated with the object. NEO's carried object only (``carry``, the patch student; not
    the preview): a distilled target learns from a teacher without it."""
    relight: bool = True
    """A carried object is relit: the scan's light is estimated from the object as the
    scan's views show it (neoedit/edit/relight.py) and its colours take the shading of
    their new orientation (a turned object's lit side no longer stays lit; a translation
    reads no light). NEO's carried object only (``carry``, the patch student). Measured on
    NEO-Sim pick_place_1 (yaw 45): In +0.15-0.18 dB, the mug's pixels +0.28 dB; +1.7 s."""
    student: Student = "patch"
    """'patch': the student is a new patch of the field, initialised from the current
    weights, owning the source boxes with the support under them (its MLPs learn at
    ``distill.mlp_lr_factor``, 0 by default: the hole needs only table rows;
    ``reuse_removal_patch``: the removal's own patch instead); the targets are carried
    (``carry``) or, without it, a second patch owning them (its MLPs learn at
    ``distill.patch_mlp_lr_factor``: a new object stands there); the rest
    of the scene stays bit-identical, so a chain of edits cannot wash it out. 'field': the
    whole field is the student (updates limited to the table rows that samples in the boxes
    read; earlier patches are baked in), as the Seal-3D-style baseline always does."""


@dataclass
class Motion:
    """One object to move: its box (from a query or a file) and the 4x4 world transform."""

    box: OrientedBox
    transform: np.ndarray


@dataclass
class MoveRegions:
    """A move resolved on its parent, whatever the method: per object the source box (as the
    method grew it), the 4x4 motion and the target region (the source under the motion, its
    bottom lifted so the support there stays the current field's)."""

    sources: list[OrientedBox]
    transforms: list[np.ndarray]
    targets: list[OrientedBox]

    @classmethod
    def of(
        cls, motions: list[Motion], sources: list[OrientedBox], target_floor_m: float
    ) -> MoveRegions:
        transforms = [np.asarray(m.transform, dtype=np.float64) for m in motions]
        targets = [
            s.transformed(t).lifted_bottom(target_floor_m)
            for s, t in zip(sources, transforms, strict=True)
        ]
        return cls(sources, transforms, targets)

    def record(
        self,
        prompt: str | None,
        method: str,
        motions: list[Motion],
        shadows: list[OrientedBox],
        config: Any,
    ) -> EditRecord:
        """The history entry of the move (``config``: the method's configuration)."""
        details = {
            "boxes": [m.box.to_dict() for m in motions],
            "source_boxes": [b.to_dict() for b in self.sources],
            "shadow_boxes": [b.to_dict() for b in shadows],
            "target_boxes": [b.to_dict() for b in self.targets],
            "transforms": [t.round(9).tolist() for t in self.transforms],
            "config": dataclasses.asdict(config),
        }
        return EditRecord("move", prompt, method, details=details)

    def language(self) -> LanguageEdit:
        """The query cloud loses the sources and gains the targets."""
        return LanguageEdit(self.sources, list(zip(self.targets, self.transforms, strict=True)))


SAME_OBJECT_IOU = 0.5
"""Two motions of one edit whose source boxes overlap this much move the same object."""


def check_rigid(transform: np.ndarray, where: str = "the transform") -> None:
    """Refuse a (4,4) transform that is no finite rigid motion (``where`` names it)."""
    if not is_rigid(transform):
        raise NeoError(
            f"{where} must be a finite rigid motion (orthonormal rotation, det +1, last row "
            f"0 0 0 1); got {np.round(np.asarray(transform, dtype=np.float64), 4).tolist()}"
        )


def check_motions(scene: Scene, motions: list[Motion]) -> None:
    """Refuse non-rigid or non-finite transforms and targets outside the scene box."""
    if not motions:
        raise NeoError("nothing to move: give a prompt or --box")
    check_edit_boxes(scene, [m.box for m in motions])  # inside the scene box, not empty
    for i, a in enumerate(motions):
        for j in range(i + 1, len(motions)):
            if box_iou_3d(a.box, motions[j].box) >= SAME_OBJECT_IOU:
                raise NeoError(
                    f"motions {i + 1} and {j + 1} start from the same region (box IoU "
                    f"{box_iou_3d(a.box, motions[j].box):.2f}): an object moves once per edit"
                )
    aabb = scene.field.aabb.cpu().numpy().astype(np.float64)  # printed: no float32 noise
    for m in motions:
        check_rigid(m.transform)
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

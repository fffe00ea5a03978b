"""``neo move``: relocate objects by region-composed teacher -> student distillation
(paper Sec. III-C, III-D) as a new scene version.

* the preview (:class:`PreviewMove`): no training. The version records the move; every
  render composes the current field (outside), nothing in the source box, and the field
  under the inverse motion in the target box (about a second, like Seal-3D's preview).
* ``neo`` (the paper): the source box is removed and inpainted (the removal pipeline,
  :func:`neoedit.edit.remove.inpaint_removal`), the teacher is composed region by region
  — current field outside, removed+inpainted field in the source box, moved field in the
  target box (target wins). The target box is carried (the parent's own weights seen
  through the motion, exactly the teacher there); the source region is distilled into a
  patch initialised from the current weights, on rays of the scan cameras and of virtual
  views around source and target (``carry`` off: the target is distilled too, the
  paper's design).

The Seal-3D-style baseline is its own edit, :class:`neoedit.bench.seal3d.SealMove`.

The output has the structure of its input (one radiance field + language field), so it is
a valid input to every verb, another move included.
"""

from dataclasses import dataclass, field

import numpy as np

from neoedit.edit.inpaint import Inpainter
from neoedit.edit.motion import STUDENTS, Motion, MoveConfig, MoveRegions, check_motions
from neoedit.edit.move_distill import distil_move
from neoedit.edit.pipeline import Prepared, Timings, apply_edit
from neoedit.edit.remove import working_boxes
from neoedit.edit.settle import settled_start
from neoedit.edit.shadow import Shadow, scene_shadows
from neoedit.errors import NeoError
from neoedit.geometry import OrientedBox
from neoedit.geometry.box import box_iou_3d
from neoedit.rendering.occupancy import cells_in_boxes, refresh_grid
from neoedit.scene import Scene
from neoedit.utils.options import changed_options

__all__ = [
    "Motion",
    "Move",
    "MoveConfig",
    "PreviewMove",
    "check_motions",
    "preview_ignored",
    "check_move_config",
    "move",
]


@dataclass
class Move:
    """Move every ``motions[i].box`` by its transform (paper Sec. III-C/D): NEO's composed
    teacher distilled into patches. Run it with :func:`~neoedit.edit.pipeline.apply_edit`;
    :class:`PreviewMove` is the instant preview."""

    motions: list[Motion]
    cfg: MoveConfig = field(default_factory=MoveConfig)
    prompt: str | None = None
    inpainter: Inpainter | None = None

    def prepare(self, parent: Scene) -> Prepared:
        cfg = self.cfg
        sources = _checked_sources(parent, self.motions, cfg)
        found = scene_shadows(parent, sources, cfg.remove.shadow)  # inpainted with the source
        shadows = [s.slab for s in found if s is not None]
        move = MoveRegions.of(self.motions, sources, cfg.target_floor_m)
        targets, transforms = move.targets, move.transforms
        shades = _shades(found, transforms, cfg)
        record = move.record(self.prompt, "neo", self.motions, shadows, cfg)
        record.details["shade_boxes"] = [box.to_dict() for box, _ in shades]

        def run(child: Scene, timings: Timings) -> None:
            start = settled_start(parent, child, cfg.distill, timings)
            distil_move(
                start, child, sources, targets, transforms, cfg, self.inpainter, timings, shadows,
                shades,
            )  # fmt: skip

        return Prepared(record, run, move.language(), cfg.language)


@dataclass
class PreviewMove:
    """The instant preview of a move: the version records it, and every render composes
    the current field outside, nothing in the source box and the field under the inverse
    motion in the target box (about a second, like Seal-3D's preview); nothing is trained,
    so it can be :func:`~neoedit.edit.pipeline.sketch`-ed. Of ``cfg`` it uses the source's
    margins (``cfg.remove``), ``target_floor_m`` and the language update."""

    motions: list[Motion]
    cfg: MoveConfig = field(default_factory=MoveConfig)
    prompt: str | None = None

    def prepare(self, parent: Scene) -> Prepared:
        cfg = self.cfg
        sources = _checked_sources(parent, self.motions, cfg)
        move = MoveRegions.of(self.motions, sources, cfg.target_floor_m)
        record = move.record(self.prompt, "preview", self.motions, [], cfg)
        record.details["shade_boxes"] = []
        _check_clear_of_cuts(parent, sources, "the object's box")
        _check_clear_of_cuts(parent, move.targets, "the target box")

        def run(child: Scene, timings: Timings) -> None:
            with timings.stage("preview"):
                _preview(child, sources, move.targets, move.transforms)

        return Prepared(record, run, move.language(), cfg.language, instant=True)


def _checked_sources(parent: Scene, motions: list[Motion], cfg: MoveConfig) -> list[OrientedBox]:
    """The checks every move runs before any work, then its sources: the objects' boxes as
    the removal works on them (seated, grown by the margin)."""
    check_move_config(cfg)
    check_motions(parent, motions)
    return working_boxes(parent, [m.box for m in motions], cfg.remove)


def _shades(
    found: list[Shadow | None], transforms: list[np.ndarray], cfg: MoveConfig
) -> list[tuple[OrientedBox, np.ndarray]]:
    """The shadows found at the sources laid down under their motions (slab, ratio map),
    when they follow the object: NEO's carried object only (a distilled target, or the
    whole-field student, learns the target from a teacher without them)."""
    if not (cfg.shadow_follows and cfg.carry and cfg.student == "patch"):
        return []
    return [s.shade_at(t) for s, t in zip(found, transforms, strict=True) if s is not None]


PREVIEW_USES = ("remove.margin_m", "remove.neighbour_similarity", "target_floor_m", "language")
"""What a :class:`PreviewMove` reads of its :class:`MoveConfig` (the source's margins, the
target's floor, the language update); it trains nothing, so the rest does not apply."""


def preview_ignored(cfg: MoveConfig) -> list[str]:
    """The options of ``cfg`` set away from their defaults that a preview does not use
    (:func:`~neoedit.utils.options.changed_options`: 'distill.field_steps', 'no_carry')."""
    return changed_options(cfg, MoveConfig(), PREVIEW_USES)


def check_move_config(cfg: MoveConfig, where: str = "--edit") -> None:
    """Refuse settings NEO's move cannot run with (before any loading or training);
    ``where``: the option prefix the messages name."""
    if cfg.student not in STUDENTS:
        raise NeoError(f"unknown student {cfg.student!r} (choose from {', '.join(STUDENTS)})")
    if cfg.reuse_removal_patch and cfg.student != "patch":
        raise NeoError(
            f"{where}.reuse-removal-patch applies to NEO's patch student only (not with "
            f"{where}.student field)"
        )
    cfg.remove.check(f"{where}.remove")
    cfg.distill.check(f"{where}.distill")
    cfg.language.check(f"{where}.language")


def move(
    parent: Scene,
    motions: list[Motion],
    cfg: MoveConfig,
    prompt: str | None = None,
    inpainter: Inpainter | None = None,
) -> Scene:
    """A new version of ``parent`` with every ``motions[i].box`` moved by its transform
    (``parent`` is left unchanged)."""
    return apply_edit(parent, Move(motions, cfg, prompt, inpainter))


def _check_clear_of_cuts(parent: Scene, boxes: list[OrientedBox], what: str) -> None:
    """Render-time removals apply after render-time moves: a preview move into a box that
    this version cuts or suppresses would be cut too, and one out of such a box would bring
    back what the cut removed (the field under it still holds the object)."""
    pending = [
        OrientedBox.from_dict(b) for b in [*parent.meta.cut_boxes, *parent.meta.suppress_boxes]
    ]
    if any(box_iou_3d(b, c) > 0 for b in boxes for c in pending):
        raise NeoError(
            f"{what} meets a box this version removes at render time (a removal without "
            "inpainting): a preview move there would show what was removed, or be cut away; "
            "make the full move (neo move without --preview), or remove with inpainting first"
        )


def _preview(
    child: Scene,
    sources: list[OrientedBox],
    targets: list[OrientedBox],
    transforms: list[np.ndarray],
) -> None:
    for s, g, tf in zip(sources, targets, transforms, strict=True):
        child.meta.moves.append(
            {"source": s.to_dict(), "target": g.to_dict(), "transform": tf.round(9).tolist()}
        )
    field_, _ = child.renderable()
    refresh_grid(child.grid, field_.density, cells_in_boxes(child.grid, [*sources, *targets]))

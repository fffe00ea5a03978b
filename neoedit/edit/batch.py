"""Several edits as one version: :class:`Batch`.

One robot action can change more than one object (it clears two objects off the table, or
moves one and knocks another away). A batch applies its edits to one new version and the
history records one entry, type 'batch', that lists them; the parent stays the version
before all of them, so restoring it undoes them together. The language field is updated
once, for every region the batch changed.

Every edit of a batch is checked on the parent before any work, and they must touch
separate places: their regions (working boxes with their margins, shadows, targets) may not
overlap (edits of one object after one another are a plan, :mod:`neoedit.edit.plan`, each
step a version that sees the last). They run in order, each on what the ones before it
made: an edit that trains is prepared again on a copy of the version so far, its teacher
(a move rebuilds its student from its teacher's field). The edits either all train or are
all instant (cuts, previews): an instant edit beside a training one would be settled into
patches by it.
"""

from __future__ import annotations

import copy
import dataclasses
import itertools
from dataclasses import dataclass

from neoedit.edit.language_update import LanguageEdit
from neoedit.edit.pipeline import Edit, Prepared
from neoedit.errors import NeoError
from neoedit.geometry.box import box_iou_3d
from neoedit.records import BOX_KEYS, EditRecord
from neoedit.scene import Scene
from neoedit.utils.timings import Timings


@dataclass
class Batch:
    """``edits`` (any edits :func:`~neoedit.edit.pipeline.apply_edit` runs, in separate
    places) applied as one version, in order."""

    edits: list[Edit]

    def prepare(self, parent: Scene) -> Prepared:
        if not self.edits:
            raise NeoError("a batch needs at least one edit")
        if any(isinstance(e, Batch) for e in self.edits):
            raise NeoError("a batch holds edits, not batches: list all the edits in one batch")
        parts = [e.prepare(parent) for e in self.edits]
        check_separate([p.record for p in parts])
        if len({p.instant for p in parts}) > 1:
            raise NeoError(
                "a batch's edits either all train or are all instant (cuts and previews): an "
                "instant edit would be settled into patches by the others; make two batches"
            )
        record = EditRecord(
            "batch",
            # the parts' prompts, "box" for one given by boxes (None when none has a prompt)
            "; ".join(p.record.prompt or "box" for p in parts)
            if any(p.record.prompt for p in parts)
            else None,
            details={"edits": [_entry(p.record) for p in parts]},
        )

        def run(child: Scene, timings: Timings) -> None:
            entries = []
            for k, (edit, part) in enumerate(zip(self.edits, parts, strict=True), 1):
                if k > 1 and not part.instant:
                    part = edit.prepare(_so_far(child, parent))
                # each edit runs with its own record last in the history (what it adds to
                # it, e.g. the light a move read, stays with it), then the batch's is last
                mine = dataclasses.replace(
                    part.record, parent=child.meta.parent, version=child.meta.version_id
                )
                child.meta.edits.append(mine)
                stages = Timings()
                try:
                    part.run(child, stages)
                finally:
                    entries.append(_entry(child.meta.edits.pop()))
                timings.merge(stages, prefix=f"edit{k}_")
            if child.meta.version_id != parent.meta.version_id:  # a new version, not a sketch
                own = child.meta.edits[-1]
                own.details = {**own.details, "edits": entries}

        language = LanguageEdit(
            [b for p in parts for b in p.language.source],
            [t for p in parts for t in p.language.targets],
        )
        # the one language update takes the first edit's settings that has any
        cfg = next((p.language_cfg for p in parts if p.language_cfg is not None), None)
        return Prepared(record, run, language, cfg, instant=parts[0].instant)


def _so_far(child: Scene, parent: Scene) -> Scene:
    """A copy of the batch's version as its earlier edits left it (field, grid and
    metadata), with the parent's language (updated once, after the batch)."""
    return Scene(
        copy.deepcopy(child.field),
        copy.deepcopy(child.grid),
        copy.deepcopy(child.meta),
        parent.language,
        parent.surface_points_m,
    )


OVERLAP_IOU = 1e-6
"""Boxes of two edits whose IoU exceeds this share space (below: touching, up to the
rounding of the footprint clipping)."""


REGION_KEYS = tuple(k for k in BOX_KEYS if k != "shade_boxes")
"""The boxes of an edit's region: all its boxes but the slabs where a moved object's shadow
is laid (a ratio map that is 1 outside the shadow; it darkens whatever lies there)."""


def check_separate(records: list[EditRecord]) -> None:
    """Refuse edits whose regions overlap (any box of one meets any box of another)."""
    regions = [r.boxes(*REGION_KEYS) for r in records]
    for (i, a), (j, b) in itertools.combinations(enumerate(regions, 1), 2):
        if any(box_iou_3d(x, y) > OVERLAP_IOU for x in a for y in b):
            raise NeoError(
                f"edits {i} ({records[i - 1].type}) and {j} ({records[j - 1].type}) of the "
                "batch touch the same place (their boxes, margins or shadows overlap): apply "
                "them one after another, as the steps of a plan"
            )


def _entry(record: EditRecord) -> dict:
    """A batch's stored entry for one of its edits: its record without the version links
    (the batch's own)."""
    return {k: v for k, v in record.to_dict().items() if k not in ("parent", "version")}

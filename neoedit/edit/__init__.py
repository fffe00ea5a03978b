"""Editing a trained scene (paper Sec. III): every edit is a typed object run by the one
pipeline, :func:`apply_edit` (:mod:`neoedit.edit.pipeline`)::

    from neoedit.edit import Batch, Motion, Move, PreviewMove, Remove, apply_edit, sketch

    no_mug = apply_edit(scene, Remove([mug_box]))
    moved = apply_edit(scene, Move([Motion(mug_box, transform)]))
    both = apply_edit(scene, Batch([Remove([duck]), Move([Motion(mug_box, transform)])]))
    at_once = sketch(scene, PreviewMove([Motion(mug_box, transform)]))

The edits: :class:`Remove` (NEO's removal and inpainting, or the instant preview),
:class:`Move` (NEO's distillation), :class:`PreviewMove` (the move composed at render
time) and :class:`Batch` (several edits in separate places as one version); the
baselines are edits of their own beside the benchmark: ``neoedit.bench.seal3d.SealMove`` /
``SealRemove`` (Seal-3D-style), ``neoedit.bench.nerfiller.NerfillerRemove``
(NeRFiller-style) and ``neoedit.bench.dff.DffRemove`` (DFF-style). Exports load lazily
(the modules import torch).
"""

from __future__ import annotations

from neoedit.utils.lazy import lazy_exports

_EXPORTS = {
    "apply_edit": "neoedit.edit.pipeline",
    "Batch": "neoedit.edit.batch",
    "Edit": "neoedit.edit.pipeline",
    "Prepared": "neoedit.edit.pipeline",
    "sketch": "neoedit.edit.pipeline",
    "Remove": "neoedit.edit.remove",
    "RemoveConfig": "neoedit.edit.remove",
    "Move": "neoedit.edit.relocate",
    "PreviewMove": "neoedit.edit.relocate",
    "Motion": "neoedit.edit.motion",
    "MoveConfig": "neoedit.edit.motion",
}

__all__ = sorted(_EXPORTS)


__getattr__ = lazy_exports(__name__, _EXPORTS)

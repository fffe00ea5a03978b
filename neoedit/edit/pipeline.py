"""One edit pipeline: every edit of a scene, whatever its method, runs the same sequence.

An edit is a typed object (:class:`~neoedit.edit.remove.Remove`,
:class:`~neoedit.edit.relocate.Move`, and the baselines beside the benchmark:
``neoedit.bench.seal3d.SealMove`` / ``SealRemove``, ``neoedit.bench.nerfiller.NerfillerRemove``,
``neoedit.bench.dff.DffRemove``);
:func:`apply_edit` runs it on a scene and returns the new version::

    prepared = edit.prepare(parent)        # checks, edit boxes, the history record: no work
    child = new_version(parent, record)    # a deep copy with a fresh id; parent unchanged
    prepared.run(child, timings)           # the method: patches trained, grids refreshed
    update_language(parent, child, ...)    # the query cloud follows the edit
    record timings and seconds             # into the child's last history entry

An edit whose method trains nothing (a removal cut at render time, a preview move) can also
be *sketched*: :func:`sketch` runs it on a light copy of the parent (field shared) with no
history entry and no language update, at once — what the viewer draws while the user drags.

A new method is a new class with a ``prepare`` method; nothing here changes. Work is timed
with :meth:`Timings.stage`, so every edit's record holds the same kind of entries
(``<stage>_s`` seconds, ``loss_<name>`` values).
"""

from __future__ import annotations

import copy
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Protocol

from neoedit.edit.history import new_version
from neoedit.edit.language_update import LanguageEdit, LanguageUpdateConfig, update_language
from neoedit.errors import NeoError
from neoedit.records import EditRecord
from neoedit.scene import Scene
from neoedit.utils.timings import Timings

__all__ = ["Edit", "Prepared", "Timings", "apply_edit", "sketch"]


@dataclass
class Prepared:
    """What an edit resolves to on one parent scene, before any work is done."""

    record: EditRecord
    """The history entry (type, prompt, method; boxes and configuration in its details)."""
    run: Callable[[Scene, Timings], None]
    """The method's work on the new version (in place), timed into the Timings."""
    language: LanguageEdit
    """Where the query cloud loses points and where it gains them."""
    language_cfg: LanguageUpdateConfig | None = None
    instant: bool = False
    """The run trains nothing (it only records render-time edits and refreshes the grid):
    :func:`sketch` may run it on a light copy."""


class Edit(Protocol):
    """Anything :func:`apply_edit` can run: checks its input against ``parent`` (raising
    NeoError before any long work) and says what it will do."""

    def prepare(self, parent: Scene) -> Prepared: ...


def apply_edit(parent: Scene, edit: Edit) -> Scene:
    """The new version of ``parent`` with ``edit`` applied; ``parent`` is left unchanged."""
    t0 = time.perf_counter()
    prepared = edit.prepare(parent)
    child = new_version(parent, prepared.record)
    timings = Timings()
    prepared.run(child, timings)
    with timings.stage("language_total"):
        timings.merge(update_language(parent, child, prepared.language, prepared.language_cfg))
    record = child.meta.edits[-1]
    record.timings = dict(timings)
    record.seconds = round(time.perf_counter() - t0, 2)
    return child


def sketch(parent: Scene, edit: Edit) -> Scene:
    """``edit`` as it will render, at once, for an edit that trains nothing (a removal cut
    at render time, a preview move): run on a light copy of ``parent`` that shares its field
    and language field (metadata and occupancy grid copied), with no history entry and no
    language update. ``parent`` is left unchanged; an edit that trains is refused."""
    prepared = edit.prepare(parent)
    if not prepared.instant:
        raise NeoError("only an edit that trains nothing can be sketched (a cut or a preview)")
    light = Scene(
        parent.field,
        copy.deepcopy(parent.grid),
        copy.deepcopy(parent.meta),
        parent.language,
        parent.surface_points_m,
    )
    prepared.run(light, Timings())
    return light

"""One entry of a version's edit history: :class:`EditRecord`.

Every edit (:func:`neoedit.edit.pipeline.apply_edit`) appends one to the new version's
``SceneMeta.edits``: what was asked (type, prompt), how (method), where it sits in the
history (parent and version ids) and what it cost (seconds, per-stage timings), typed;
what the method records besides (its boxes, motions and configuration) in ``details``.

On disk (``scene.json``) a record is one flat JSON object, as scenes have always stored it,
so every scene written before this type loads unchanged; :meth:`EditRecord.parse` reads a
record a user may have edited by hand without failing (``neo log`` must list every
version).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

from neoedit.errors import NeoError
from neoedit.geometry import OrientedBox

BOX_KEYS = ("boxes", "edit_boxes", "source_boxes", "shadow_boxes", "target_boxes", "shade_boxes")
"""The ``details`` entries that hold lists of boxes (``OrientedBox.to_dict`` form)."""


@dataclass
class EditRecord:
    type: str
    """'remove', 'move' or 'batch' (several edits as one version, listed in ``parts()``)."""
    prompt: str | None = None
    """The words that named the object (None: boxes given)."""
    method: str | None = None
    """How: 'neo', 'preview', 'seal3d', 'nerfiller', 'suppress' (the DFF-style baseline), ...
    (None for NEO's removals, whose ``details`` say 'removal' and 'inpaint')."""
    parent: str | None = None
    """Version id of the scene the edit started from."""
    version: str | None = None
    """Version id of the scene it made."""
    seconds: float | None = None
    """Wall time of the whole edit (None until it ran)."""
    timings: dict[str, float] = field(default_factory=dict)
    """Per stage: ``<stage>_s`` seconds and ``loss_<name>`` values."""
    details: dict[str, Any] = field(default_factory=dict)
    """What the method records besides: boxes, motions, its configuration (JSON values)."""

    @classmethod
    def parse(cls, raw: Any) -> EditRecord:
        """A record from its stored JSON object; malformed fields are kept in ``details`` or
        dropped, never raised (a non-object gives a record of type '?')."""
        if isinstance(raw, EditRecord):
            return raw
        if not isinstance(raw, dict):
            return cls(type="?")
        rest = {k: v for k, v in raw.items() if k not in _TYPED}

        def text(key: str) -> str | None:
            v = raw.get(key)
            return v if isinstance(v, str) else None

        seconds = raw.get("seconds")
        ok_seconds = _number(seconds) and math.isfinite(float(seconds))  # type: ignore[arg-type]
        timings = raw.get("timings")
        timings = (
            {k: v for k, v in timings.items() if _number(v)} if isinstance(timings, dict) else {}
        )
        return cls(
            type=text("type") or "?",
            prompt=text("prompt"),
            method=text("method"),
            parent=text("parent"),
            version=text("version"),
            seconds=float(seconds) if ok_seconds else None,  # type: ignore[arg-type]
            timings=timings,
            details=rest,
        )

    def to_dict(self) -> dict[str, Any]:
        """The flat JSON object stored in scene.json (absent values left out)."""
        out: dict[str, Any] = {"type": self.type, "prompt": self.prompt}
        if self.method is not None:
            out["method"] = self.method
        out.update(self.details)
        for key in ("parent", "version", "seconds"):
            if getattr(self, key) is not None:
                out[key] = getattr(self, key)
        if self.timings:
            out["timings"] = dict(self.timings)
        return out

    @property
    def label(self) -> str:
        """How ``neo log`` and the viewer name the edit: 'remove', 'remove (cut)',
        'remove (suppress)', 'move (neo)', 'move (preview)', 'remove (nerfiller)',
        'batch (remove, move (neo))'... (a suppression recorded before it had a method is
        named by its details)."""
        if self.type == "batch":
            parts = ", ".join(p.label for p in self.parts())
            return f"batch ({parts})" if parts else "batch"
        text = self.type + (f" ({self.method})" if self.method else "")
        if self.type == "remove" and not self.details.get("inpaint") and not self.method:
            text += " (suppress)" if self.details.get("removal") == "suppress" else " (cut)"
        return text

    def boxes(self, *keys: str) -> list[OrientedBox]:
        """The boxes stored under ``keys`` of :data:`BOX_KEYS` (all of them when none are
        named), in that order (a batch: its edits' boxes, edit by edit); malformed entries
        are skipped."""
        if self.type == "batch":
            return [b for part in self.parts() for b in part.boxes(*keys)]
        found = []
        for key in keys or BOX_KEYS:
            entries = self.details.get(key)
            for b in entries if isinstance(entries, list) else []:
                if not isinstance(b, dict):
                    continue
                try:
                    found.append(OrientedBox.from_dict(b))
                except NeoError:
                    continue
        return found

    def parts(self) -> list[EditRecord]:
        """The records of a batch's edits, in order (empty for any other edit)."""
        entries = self.details.get("edits") if self.type == "batch" else None
        return [EditRecord.parse(e) for e in entries] if isinstance(entries, list) else []


def own_edit(meta: Any) -> EditRecord | None:
    """The record of the edit that made the version whose scene.json object is ``meta``
    (raw JSON, as a store lists its versions); None for a trained scan or an unreadable
    history."""
    edits = meta.get("edits") if isinstance(meta, dict) else None
    if not isinstance(edits, list) or not edits or not isinstance(edits[-1], dict):
        return None
    record = EditRecord.parse(edits[-1])
    return record if record.version == meta.get("version_id") else None


def _number(value: Any) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool)


_TYPED = ("type", "prompt", "method", "parent", "version", "seconds", "timings")
"""The stored keys that are typed fields of :class:`EditRecord` (the rest: ``details``)."""

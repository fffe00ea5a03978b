"""The DFF-style removal baseline (distilled feature fields, Kobayashi et al., NeurIPS 2022),
as the paper's Table I runs it.

The object's box, grown by NEO's margin, is emptied at render time by zeroing the field's
density inside it; rays are sampled as before (a suppressed box is not cut out of the rays,
as NEO's resampling does), and nothing is inpainted, so what the object hid shows as the
field left it: the object's underside, floaters, or the background. :class:`DffRemove` is an
edit like NEO's (:func:`neoedit.edit.pipeline.apply_edit` runs it; ``neo bench`` uses it);
the render-time suppression itself is the scene's (``SceneMeta.suppress_boxes``, drawn by
:mod:`neoedit.fields.suppressed`), so a saved version renders the same anywhere.
"""

from __future__ import annotations

from dataclasses import dataclass

from neoedit.edit.language_update import LanguageUpdateConfig
from neoedit.edit.pipeline import Prepared
from neoedit.edit.remove import Remove, RemoveConfig
from neoedit.geometry import OrientedBox
from neoedit.scene import Scene

__all__ = ["DffRemove"]


@dataclass
class DffRemove:
    """Suppress the density inside ``boxes`` (each grown by ``margin_m`` as NEO's removal
    grows its own): no training, no inpainting. It is ``neo remove --removal suppress
    --no-inpaint``, recorded as method 'suppress' (with the removal's whole configuration,
    as every removal records it)."""

    boxes: list[OrientedBox]
    prompt: str | None = None
    margin_m: float = RemoveConfig.margin_m
    language: LanguageUpdateConfig | None = None
    """How the language field follows the removal (None: the defaults, as after NEO's)."""

    def prepare(self, parent: Scene) -> Prepared:
        cfg = RemoveConfig(removal="suppress", inpaint=False, margin_m=self.margin_m)
        return Remove(self.boxes, cfg, self.prompt, language=self.language).prepare(parent)

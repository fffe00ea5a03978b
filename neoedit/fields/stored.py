"""A field as a version stores it: flat tensors, and the records of its parts.

The base radiance field's weights are stored under ``field.``, patch (or carried part) i
under ``patch{i}.``, shade i under ``shade{i}.``; scene.json holds each part's region (and a
carried part's motion) and each shade's slab, with the version that added it. Used by
:mod:`neoedit.scene` to save and load a version.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any, cast

import numpy as np
import torch

from neoedit.fields.composed import TransformedField
from neoedit.fields.patched import PatchedField
from neoedit.fields.radiance import RadianceField
from neoedit.fields.relight import Relight
from neoedit.fields.shade import Shade
from neoedit.geometry import OrientedBox


def field_tensors(field: RadianceField | PatchedField) -> dict[str, torch.Tensor]:
    """Flat tensors of a field: the base, its patches and its shades, by prefix."""
    parts: list[tuple[str, torch.nn.Module]] = [("field.", field)]
    if isinstance(field, PatchedField):
        parts = [("field.", cast(torch.nn.Module, field.base))]
        parts += [(f"patch{i}.", p) for i, p in enumerate(field.patches)]
        parts += [(f"shade{i}.", s) for i, s in enumerate(field.shades)]
    return {
        prefix + k: v.detach().cpu().contiguous()
        for prefix, module in parts
        for k, v in module.state_dict().items()
    }


def prefixed(tensors: Mapping[str, torch.Tensor], prefix: str) -> dict[str, torch.Tensor]:
    """The tensors under ``prefix``, the prefix removed (a module's state dict)."""
    return {k.removeprefix(prefix): v for k, v in tensors.items() if k.startswith(prefix)}


def part_records(
    field: RadianceField | PatchedField,
    patches: list[dict[str, Any]],
    shades: list[dict[str, Any]],
    version: str,
) -> tuple[list[dict[str, Any]], list[dict[str, Any]]]:
    """scene.json's ``patches`` and ``shades`` for ``field``: those it was loaded with keep
    their version (``patches``, ``shades``: the records so far), new ones get ``version``;
    a plain field (a whole-field student replaced the patched one) has none."""
    if not isinstance(field, PatchedField):
        return [], []
    new_patches = []
    for i, (region, motion) in enumerate(zip(field.regions, field.part_transforms(), strict=True)):
        entry: dict[str, Any] = {
            "region": [b.to_dict() for b in region],
            "version": patches[i]["version"] if i < len(patches) else version,
        }
        if motion is not None:
            entry["transform"] = np.round(motion, 12).tolist()
        new_patches.append(entry)
    new_shades = [
        {
            "box": shade.box.to_dict(),
            "after": shade.after,
            "version": shades[i]["version"] if i < len(shades) else version,
        }
        for i, shade in enumerate(cast(list[Shade], list(field.shades)))
    ]
    return new_patches, new_shades


def _load_part(part: torch.nn.Module, state: dict[str, torch.Tensor]) -> None:
    """Load a part's state; a relit carried part gets its grid (shaped as stored) first."""
    if isinstance(part, TransformedField) and "relight.ratio" in state:
        part.relight = Relight.like(prefixed(state, "relight."))
    part.load_state_dict(state)


def load_parts(
    patched: PatchedField,
    patches: list[dict[str, Any]],
    shades: list[dict[str, Any]],
    tensors: Mapping[str, torch.Tensor],
) -> None:
    """Load (or, for parts it lacks, add) the recorded patches and shades into ``patched``
    (its base already loaded). Raises KeyError / RuntimeError / ValueError on tensors that
    do not match the records."""
    for i, p in enumerate(patches):
        state = prefixed(tensors, f"patch{i}.")
        if i < len(patched.patches):
            _load_part(patched.patches[i], state)
            continue
        region = [OrientedBox.from_dict(b) for b in p["region"]]
        if "transform" in p:  # a carried part: frozen weights under a motion
            motion = np.asarray(p["transform"], dtype=np.float64)
            _load_part(patched.add_carried(region, motion, patched.base), state)
        else:
            patched.add_patch(region).load_state_dict(state)
    for i, entry in enumerate(shades):
        ratio = tensors[f"shade{i}.ratio"]
        if i < len(patched.shades):
            cast(Shade, patched.shades[i]).ratio.copy_(ratio.float().clamp(0.0, 1.0))
        else:
            patched.shades.append(Shade(OrientedBox.from_dict(entry["box"]), ratio, entry["after"]))

"""Local edits of a radiance field: a base field plus patches that own oriented regions.

An edit (removal + inpainting) fine-tunes a *patch*: a copy of the field that answers only
for points inside the edit's region. Everywhere else the base field answers, untouched, so
an edit cannot leak into the rest of the scene through shared MLP weights or hash
collisions (a fine-tuned copy of the whole field did: -1.1 dB outside the box on
NEO-Sim removal_1). The edit is still persistent in weights: the patch is saved with the
version and every renderer evaluates the patched field.

A patch owns one or more boxes (a removal of several objects trains one patch). Later
patches take precedence over earlier ones where regions overlap. A *carried* part (a move
that keeps the object's own weights) is a frozen copy of the field seen through the move's
rigid motion, owning the target box. A *shade* (:mod:`neoedit.fields.shade`) darkens the
support where a moved object now casts its shadow.
"""

from __future__ import annotations

import copy
from typing import cast

import numpy as np
import torch
from torch import nn

from neoedit.fields.composed import ComposedField, TransformedField
from neoedit.fields.radiance import Field, RadianceField
from neoedit.fields.room import RoomField
from neoedit.fields.shade import Shade, apply_shades
from neoedit.geometry import OrientedBox, points_in_box


def inside_box(points: torch.Tensor, box: OrientedBox) -> torch.Tensor:
    """(N,) bool: which world points (N,3) lie inside the oriented box (faces included)."""
    return points_in_box(points, box)


class PatchedField(ComposedField):
    """Base field + patches (trainable copies owning regions); same interface as
    :class:`RadianceField` (``aabb``, ``density``, ``forward``)."""

    def __init__(self, base: RadianceField):
        super().__init__(base)
        self.shades = nn.ModuleList()

    def forward(
        self, points: torch.Tensor, directions: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """sigma (N,) and rgb (N,3) of the composed parts, the shades applied."""
        sigma, rgb = super().forward(points, directions)
        if len(self.shades) and len(points):
            shades = cast(list[Shade], list(self.shades))
            rgb = apply_shades(shades, points, rgb, self.owner)
        return sigma, rgb

    def add_shade(self, box: OrientedBox, ratio: torch.Tensor, after: int | None = None) -> Shade:
        """Darken the colours in the slab ``box`` by the ratio map ``ratio`` (n, n) over its
        x/y extent, for what the base and the parts with an index below ``after`` answer
        (default: the parts that exist now; later ones, such as the object carried to the
        target, are not darkened)."""
        after = len(self.parts) if after is None else after
        shade = Shade(box, ratio.to(self.aabb.device), after=after)
        self.shades.append(shade)
        return shade

    @property
    def patches(self) -> nn.ModuleList:
        return self.parts

    def _owners(self, region: list[OrientedBox]) -> list[int]:
        """Parts owning a corner or the centre of one of the boxes ``region``."""
        if not region:
            raise ValueError("a region needs at least one box")
        probe = torch.cat(
            [
                torch.as_tensor(np.vstack([b.corners(), b.center_m]), dtype=torch.float32)
                for b in region
            ]
        ).to(self.aabb.device)
        return [int(k) for k in self.owner(probe).tolist() if k >= 0]

    def renderer_of(self, region: list[OrientedBox]) -> RadianceField | TransformedField:
        """The part that renders the boxes ``region`` now: the newest part owning a corner or
        the centre of one of them, else the base."""
        owners = self._owners(region)
        return self.parts[max(owners)] if owners else self.base  # type: ignore[return-value]

    def trained_part_of(self, region: list[OrientedBox]) -> RadianceField:
        """:meth:`renderer_of`, never a carried part: a patch to train starts from weights in
        world coordinates (the base, or a trained patch)."""
        owners = [
            k for k in self._owners(region) if not isinstance(self.parts[k], TransformedField)
        ]
        return self.parts[max(owners)] if owners else self.base  # type: ignore[return-value]

    def renderer_inside(self, box: OrientedBox) -> RadianceField | TransformedField:
        """The part that renders most of ``box``: the owner of most points of a 5x5x5 grid
        over its inner 80 % (a neighbour's region touching a corner does not count)."""
        steps = np.linspace(-0.4, 0.4, 5)
        local = np.stack(np.meshgrid(steps, steps, steps, indexing="ij"), -1).reshape(-1, 3)
        world = (local * np.asarray(box.size_m)) @ box.rotation.T + np.asarray(box.center_m)
        owners = self.owner(torch.as_tensor(world, dtype=torch.float32, device=self.aabb.device))
        values, counts = torch.unique(owners, return_counts=True)
        top = int(values[int(torch.argmax(counts))])
        return self.base if top < 0 else self.parts[top]  # type: ignore[return-value]

    def add_patch(
        self, region: list[OrientedBox], init: RadianceField | None = None
    ) -> RadianceField:
        """Append a patch owning the boxes ``region``, initialised from ``init`` (by default
        the trained field that renders them now, :meth:`trained_part_of`); returns it
        (the part an edit trains)."""
        if not region:
            raise ValueError("a patch needs at least one box")
        source = init if init is not None else self.trained_part_of(region)
        new: RadianceField = copy.deepcopy(source)
        _drop_room(new)
        self.regions.append(list(region))
        self.parts.append(new)
        return new

    def add_carried(
        self,
        region: list[OrientedBox],
        transform: np.ndarray,
        source: Field,
    ) -> TransformedField:
        """Append a frozen part owning the boxes ``region`` that answers with ``source``
        (what rendered the object at its old place, :meth:`renderer_of` its source box)
        seen through the rigid ``transform``: a moved object keeps its own weights,
        exactly, at its new place. A carried part carried again composes the motions
        (one transform over the original weights)."""
        if not region:
            raise ValueError("a patch needs at least one box")
        motion = np.asarray(transform, dtype=np.float64)
        weights = source
        if isinstance(source, TransformedField):
            motion = motion @ source.matrix()
            weights = source.field
        inner = cast(nn.Module, copy.deepcopy(weights)).requires_grad_(False)
        _drop_room(inner)
        part = TransformedField(cast(Field, inner), motion)
        self.regions.append(list(region))
        self.parts.append(part)
        return part

    def part_transforms(self) -> list[np.ndarray | None]:
        """Per part: the 4x4 motion of a carried part, None for a trained patch."""
        return [p.matrix() if isinstance(p, TransformedField) else None for p in self.parts]


def _drop_room(field: nn.Module) -> None:
    """The scene's room stays the base's: patches are local."""
    if isinstance(getattr(field, "background_head", None), RoomField):
        field.background_head = None  # type: ignore[assignment]


def edit_region(box: OrientedBox, below_m: float) -> OrientedBox:
    """The region a removal's patch owns: the (grown) box extended ``below_m`` under its
    bottom, so the support surface it stood on is re-learnt inside the patch."""
    sx, sy, sz = box.size_m
    cx, cy, cz = box.center_m
    return OrientedBox((cx, cy, cz - below_m / 2), (sx, sy, sz + below_m), box.yaw_deg)

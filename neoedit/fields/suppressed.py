"""Render-time removals of a radiance field: density suppression (the DFF-style baseline)
and the boxes the renderer cuts out of every ray (removal by resampling)."""

from __future__ import annotations

import torch

from neoedit.fields.radiance import Field
from neoedit.geometry import OrientedBox, points_in_boxes


class SuppressedField(torch.nn.Module):
    """A radiance field whose density is zero inside some boxes (DFF-style removal: the
    rays are sampled as usual, the object's density is just switched off)."""

    def __init__(self, field: Field, boxes: list[OrientedBox]):
        super().__init__()
        self.field, self.boxes = field, boxes
        self.aabb = field.aabb

    def _outside(self, points: torch.Tensor) -> torch.Tensor:
        return ~points_in_boxes(points, self.boxes)

    def density(self, points: torch.Tensor) -> torch.Tensor:
        return self.field.density(points) * self._outside(points)

    def forward(
        self, points: torch.Tensor, directions: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor]:
        sigma, rgb = self.field(points, directions)
        return sigma * self._outside(points), rgb


def with_removals(
    field: Field, cut: list[OrientedBox], suppress: list[OrientedBox]
) -> tuple[Field, list[OrientedBox]]:
    """The field to render and the boxes to cut out of every ray: ``suppress`` boxes wrap
    the field (density zero inside, rays sampled as usual), ``cut`` boxes go to the renderer
    (no sample inside them)."""
    return (SuppressedField(field, suppress) if suppress else field), list(cut)

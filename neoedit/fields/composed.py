"""Fields composed region by region, and a field seen through a rigid motion.

These are the building blocks of the paper's teacher for a move (Sec. III-C): outside every
edit box the current field answers; inside the source box the field with the object removed
and the hole inpainted; inside the target box the current field under the inverse motion.
Nothing here is trained: composing is free, so a composite is also the instant preview.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator, Sequence

import numpy as np
import torch
from torch import nn

from neoedit.fields.radiance import Field
from neoedit.fields.relight import Relight
from neoedit.geometry import OrientedBox, points_in_box


class TransformedField(nn.Module):
    rotation: torch.Tensor  # (3,3) R of the motion
    translation: torch.Tensor  # (3,) t of the motion

    """``field`` moved by the rigid world motion ``transform`` (4,4): at x it answers what
    ``field`` answers at T^-1 x, seen along R^-1 d (so a view-dependent highlight turns
    with the object), its colours times ``relight``'s ratio there when one is set (the
    shading under the world's light, :mod:`neoedit.fields.relight`)."""

    relight: Relight | None

    def __init__(self, field: Field, transform: np.ndarray, relight: Relight | None = None):
        super().__init__()
        self.field = field
        self.relight = relight
        t = np.asarray(transform, dtype=np.float64)
        self._matrix = t.copy()
        device = field.aabb.device  # the motion lives where the field does
        self.register_buffer(
            "rotation", torch.as_tensor(t[:3, :3], dtype=torch.float32, device=device)
        )
        self.register_buffer(
            "translation", torch.as_tensor(t[:3, 3], dtype=torch.float32, device=device)
        )

    @property
    def aabb(self) -> torch.Tensor:
        return self.field.aabb

    def matrix(self) -> np.ndarray:
        """The motion as a 4x4 float64 matrix."""
        return self._matrix.copy()

    def source_points(self, points: torch.Tensor) -> torch.Tensor:
        """T^-1 x for world points (N,3) (row vectors: (x - t) R)."""
        return (points - self.translation) @ self.rotation

    def density(self, points: torch.Tensor) -> torch.Tensor:
        return self.field.density(self.source_points(points))

    def forward(
        self, points: torch.Tensor, directions: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor]:
        source = self.source_points(points)
        sigma, rgb = self.field(source, directions @ self.rotation)
        if self.relight is not None and len(points):
            rgb = (rgb * self.relight.ratio_at(source)[:, None].to(rgb)).clamp(0.0, 1.0)
        return sigma, rgb


def region_owner(points: torch.Tensor, regions: Sequence[Sequence[OrientedBox]]) -> torch.Tensor:
    """(N,) int64: index of the last region (a list of boxes) holding each point, -1 for
    none: later regions take precedence where they overlap. Points outside the axis-aligned
    bounds of every box (most samples: edits are small) skip the per-box tests."""
    who = torch.full((len(points),), -1, dtype=torch.long, device=points.device)
    boxes = [(i, box) for i, region in enumerate(regions) for box in region]
    if not boxes or not len(points):
        return who
    corners = np.concatenate([b.corners() for _, b in boxes])
    lo = torch.as_tensor(corners.min(0), dtype=points.dtype, device=points.device)
    hi = torch.as_tensor(corners.max(0), dtype=points.dtype, device=points.device)
    near = torch.nonzero(((points >= lo) & (points <= hi)).all(-1)).squeeze(1)
    if not len(near):
        return who
    sub = points[near]
    sub_who = who[near]
    for i, box in boxes:
        sub_who[points_in_box(sub, box)] = i
    who[near] = sub_who
    return who


class ComposedField(nn.Module):
    """``base`` everywhere, except inside the boxes of a part, where that part's field
    answers (later parts over earlier ones). Same interface as a radiance field."""

    def __init__(self, base: Field, parts: Sequence[tuple[list[OrientedBox], Field]] = ()) -> None:
        super().__init__()
        self.base = base
        self.regions: list[list[OrientedBox]] = [list(r) for r, _ in parts]
        self.parts = nn.ModuleList([f for _, f in parts])  # type: ignore[misc]

    @property
    def aabb(self) -> torch.Tensor:
        return self.base.aabb

    def owner(self, points: torch.Tensor) -> torch.Tensor:
        """(N,) index of the part answering for each point, -1 for the base. A coarse grid
        of the cells any region touches sends only the points in those cells to the exact
        box tests, so rendering costs little more with many edits."""
        who = torch.full((len(points),), -1, dtype=torch.long, device=points.device)
        if not self.regions or not len(points):
            return who
        cells = self._touched_cells(points.device)
        lo, hi = self.aabb[0].to(points), self.aabb[1].to(points)
        n = cells.shape[0]
        ijk = ((points - lo) / (hi - lo) * n).long().clamp_(0, n - 1)
        near = torch.nonzero(cells[ijk[:, 0], ijk[:, 1], ijk[:, 2]]).squeeze(1)
        if len(near):
            who[near] = region_owner(points[near], self.regions)
        return who

    def _touched_cells(self, device: torch.device, n: int = 64) -> torch.Tensor:
        """(n,n,n) bool: the cells of the scene box that meet a region's box (cached until
        the regions change)."""
        key = (len(self.regions), sum(len(r) for r in self.regions), str(device))
        cached = getattr(self, "_cells", None)
        if cached is not None and cached[0] == key:
            return cached[1]
        lo, hi = self.aabb[0].to(device), self.aabb[1].to(device)
        size = (hi - lo) / n
        axes = [lo[k] + size[k] * (torch.arange(n, device=device) + 0.5) for k in range(3)]
        centres = torch.stack(torch.meshgrid(*axes, indexing="ij"), -1).reshape(-1, 3)
        reach = float(torch.linalg.norm(size)) / 2  # a cell meets a box grown by this
        touched = torch.zeros(len(centres), dtype=torch.bool, device=device)
        for region in self.regions:
            for box in region:
                touched |= points_in_box(centres, box.grown(reach))
        cells = touched.reshape(n, n, n)
        self._cells = (key, cells)
        return cells

    def _members(self, points: torch.Tensor) -> Iterator[tuple[Field, torch.Tensor]]:
        """(field, indices of its points) for every field that answers for some points."""
        who = self.owner(points)
        edited = who >= 0
        base = torch.nonzero(~edited).squeeze(1)
        if len(base):
            yield self.base, base
        idx = torch.nonzero(edited).squeeze(1)
        if not len(idx):
            return
        for k in torch.unique(who[idx]).tolist():
            yield self.parts[k], idx[who[idx] == k]

    def density(self, points: torch.Tensor) -> torch.Tensor:
        """sigma (N,) [1/m] at world points (N,3)."""
        if not self.regions:
            return self.base.density(points)
        sigma = points.new_zeros(len(points))
        for f, idx in self._members(points):
            sigma = sigma.index_put((idx,), f.density(points[idx]))
        return sigma

    def forward(
        self, points: torch.Tensor, directions: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """sigma (N,) [1/m] and rgb (N,3) at world points (N,3) seen along directions (N,3)."""
        if not self.regions:
            return self.base(points, directions)
        sigma = points.new_zeros(len(points))
        rgb = points.new_zeros(len(points), 3)
        for f, idx in self._members(points):
            s, c = f(points[idx], directions[idx])
            sigma = sigma.index_put((idx,), s)
            rgb = rgb.index_put((idx,), c)
        return sigma, rgb


class MaskedField(nn.Module):
    """``field`` as it renders: zero density where ``occupied(points)`` (an occupancy grid's
    test) is False. A field holds arbitrary density in space its training never sampled,
    which the grid hides at render time; a teacher must hide it too."""

    def __init__(self, field: Field, occupied: Callable[[torch.Tensor], torch.Tensor]):
        super().__init__()
        self.field = field
        self.occupied = occupied

    @property
    def aabb(self) -> torch.Tensor:
        return self.field.aabb

    def density(self, points: torch.Tensor) -> torch.Tensor:
        return self.field.density(points) * self.occupied(points)

    def forward(
        self, points: torch.Tensor, directions: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor]:
        sigma, rgb = self.field(points, directions)
        return sigma * self.occupied(points), rgb


class EmptyField(nn.Module):
    """No density anywhere (what a removal without inpainting leaves in its box)."""

    aabb: torch.Tensor

    def __init__(self, aabb: torch.Tensor):
        super().__init__()
        self.register_buffer("aabb", aabb.clone())

    def density(self, points: torch.Tensor) -> torch.Tensor:
        return points.new_zeros(len(points))

    def forward(
        self, points: torch.Tensor, directions: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor]:
        return points.new_zeros(len(points)), points.new_zeros(len(points), 3)


def moved_field(
    base: Field,
    moving: Field,
    source: Sequence[OrientedBox],
    target: Sequence[OrientedBox],
    transform: np.ndarray,
    source_field: Field | None = None,
) -> ComposedField:
    """The composite of a move: ``base`` outside the boxes; inside ``source`` the
    ``source_field`` (the removed + inpainted field; empty when None); inside ``target`` the
    ``moving`` field under ``transform``. The target wins where the boxes overlap."""
    filler: Field = source_field if source_field is not None else EmptyField(base.aabb)
    return ComposedField(
        base, [(list(source), filler), (list(target), TransformedField(moving, transform))]
    )

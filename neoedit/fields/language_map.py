"""Where an edited scene's language field reads its parent's (paper Sec. III-D, made exact).

After a geometric edit the language field must say what the edited scene shows: inside a
target box what the object said before the motion (the parent's features at T^-1 x); inside
a source box, emptied and inpainted, what the support around the object's footprint said
(the parent's features at the point pushed horizontally out of the box); elsewhere what
the parent said. That is a map of points, not new weights. :class:`LanguageMap` is one
edit's map; a :class:`~neoedit.fields.language.LanguageField` carries the maps of the edits
made since its weights were trained and looks a point up through them, the latest edit
first. scene.json stores them (``language.maps``) beside the unchanged weights.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import torch

from neoedit.errors import NeoError
from neoedit.fields.composed import region_owner
from neoedit.geometry import OrientedBox, is_rigid


def pushed_out_of_footprint(points: torch.Tensor, box: OrientedBox, ring_m: float) -> torch.Tensor:
    """Points (N,3) inside ``box`` moved horizontally to ``ring_m`` outside its footprint
    through the nearest side face (height kept)."""
    rot = points.new_tensor(box.rotation)
    centre = points.new_tensor(box.center_m)
    local = (points - centre) @ rot
    half = points.new_tensor(box.half_extents)
    gap = half[:2] - local[:, :2].abs()  # distance to the x and y side faces
    axis = torch.argmin(gap, dim=1)
    rows = torch.arange(len(points), device=points.device)
    side = torch.sign(local[rows, axis])
    side = torch.where(side == 0, torch.ones_like(side), side)
    local = local.clone()
    local[rows, axis] = side * (half[axis] + ring_m)
    return local @ rot.T + centre


@dataclass(frozen=True, eq=False)
class LanguageMap:
    """One edit's map from the edited scene's points to the parent's: ``sources`` were
    emptied; each of ``targets`` is a box that shows its content moved by a rigid 4x4
    world ``transform``. Target boxes take precedence over source boxes where they overlap
    (the object set down where it stood). Compared by identity (compare ``to_dict()``s)."""

    sources: tuple[OrientedBox, ...]
    targets: tuple[tuple[OrientedBox, np.ndarray], ...]
    ring_m: float = 0.02
    """A point in a source box reads the surface this far outside the box's footprint."""

    @classmethod
    def of(
        cls,
        sources: Sequence[OrientedBox],
        targets: Sequence[tuple[OrientedBox, Any]],
        ring_m: float,
    ) -> LanguageMap:
        """The map as scene.json will store it (boxes and transforms rounded as saved), so a
        version reloaded from disk looks points up exactly as the one in memory."""
        raw = cls(tuple(sources), tuple((b, np.asarray(t)) for b, t in targets), ring_m)
        return cls.from_dict(raw.to_dict())

    def __call__(self, points: torch.Tensor) -> torch.Tensor:
        """Where the parent is asked for the features at ``points`` (N,3)."""
        regions = [[b] for b in self.sources] + [[b] for b, _ in self.targets]
        who = region_owner(points, regions)
        if not bool((who >= 0).any()):
            return points
        query = points.clone()
        for k, box in enumerate(self.sources):
            sel = who == k
            if sel.any():
                query[sel] = pushed_out_of_footprint(points[sel], box, self.ring_m)
        for j, (_, transform) in enumerate(self.targets):
            sel = who == len(self.sources) + j
            if sel.any():
                t = points.new_tensor(np.asarray(transform, dtype=np.float64))
                query[sel] = (points[sel] - t[:3, 3]) @ t[:3, :3]
        return query

    def boxes(self) -> list[OrientedBox]:
        """Every box the map moves points out of (its sources and targets)."""
        return [*self.sources, *(b for b, _ in self.targets)]

    def to_dict(self) -> dict[str, Any]:
        return {
            "sources": [b.to_dict() for b in self.sources],
            "targets": [
                {"box": b.to_dict(), "transform": np.round(np.asarray(t, float), 12).tolist()}
                for b, t in self.targets
            ],
            "ring_m": float(self.ring_m),
        }

    @classmethod
    def from_dict(cls, d: Mapping[str, Any], where: str = "language map") -> LanguageMap:
        """The map of a scene.json entry; a malformed one is refused with ``where`` named."""
        try:
            sources = tuple(OrientedBox.from_dict(b) for b in d["sources"])
            targets = []
            for t in d["targets"]:
                matrix = np.asarray(t["transform"], dtype=np.float64)
                if not is_rigid(matrix):
                    raise ValueError("a target's transform must be a rigid 4x4 matrix")
                targets.append((OrientedBox.from_dict(t["box"]), matrix))
            ring = float(d.get("ring_m", 0.02))
            if not (math.isfinite(ring) and ring >= 0):
                raise ValueError(f"ring_m must be a finite number >= 0, got {ring}")
        except NeoError as e:
            raise NeoError(f"{where}: {e}") from None
        except (KeyError, TypeError, ValueError) as e:
            raise NeoError(
                f"{where}: expected {{'sources': [boxes], 'targets': [{{'box', 'transform'}}], "
                f"'ring_m'}}: {e}"
            ) from None
        return cls(sources, tuple(targets), ring)

"""The boxes an edit works on must be worth editing: each meets the scene box and holds
density the scene renders (an edit elsewhere would write a version that changes nothing)."""

from __future__ import annotations

from typing import Any

import numpy as np
import torch

from neoedit.errors import NeoError


def check_edit_boxes(scene: Any, boxes: list[Any], samples: int = 12) -> list[Any]:
    """``boxes`` if each meets the scene box and holds something (density above the
    occupancy threshold at one of a grid of points inside it); an edit of any other box
    would write a version that changes nothing."""
    lo, hi = np.asarray(scene.meta.aabb_m, dtype=np.float64)
    field_, cut = scene.renderable()
    # the occupancy grid's own rule for "occupied" (relative on barely trained scenes)
    threshold = min(
        scene.meta.grid.threshold, float(scene.grid.density.clamp_max(1e3).mean().cpu())
    )
    g = (np.arange(samples) + 0.5) / samples - 0.5
    unit = np.stack(np.meshgrid(g, g, g, indexing="ij"), -1).reshape(-1, 3)
    for box in boxes:
        corners = box.corners()
        if np.any(corners.max(0) < lo) or np.any(corners.min(0) > hi):
            raise NeoError(
                f"box {box.to_dict()} does not intersect the scene box "
                f"{np.round([lo, hi], 3).tolist()}: there is nothing to edit there"
            )
        points = np.asarray(box.center_m) + (unit * np.asarray(box.size_m)) @ box.rotation.T
        keep = np.all((points >= lo) & (points <= hi), axis=1)
        for other in cut:
            keep &= ~other.contains(points)
        pts = torch.as_tensor(points[keep], dtype=torch.float32, device=scene.field.aabb.device)
        with torch.no_grad():
            sigma = field_.density(pts) if len(pts) else torch.zeros(0)
        if len(sigma) == 0 or float(sigma.max()) < threshold:
            raise NeoError(
                f"box {box.to_dict()} holds nothing the scene has rendered (no density inside): "
                "an edit there would change nothing"
            )
    return boxes

"""Working boxes of an edit: grown by a margin, their sides stopping short of neighbours."""

from __future__ import annotations

import numpy as np

from neoedit.geometry import OrientedBox


def grown_box(box: OrientedBox, margin_m: float) -> OrientedBox:
    """The box grown by ``margin_m`` on its sides and top, its bottom kept on the support
    surface (so the table under a removed object is not cut away)."""
    sx, sy, sz = box.size_m
    cx, cy, cz = box.center_m
    return OrientedBox(
        (cx, cy, cz + margin_m / 2),
        (sx + 2 * margin_m, sy + 2 * margin_m, sz + margin_m),
        box.yaw_deg,
    )


def grown_box_clear_of(
    box: OrientedBox,
    margin_m: float,
    obstacles_m: np.ndarray,
    gap_m: float = 0.003,
    min_points: int = 3,
) -> OrientedBox:
    """:func:`grown_box`, but each side face grows only until ``gap_m`` short of the obstacle
    points (K,3) in front of it (a neighbouring object the margin must not cut into; the
    ``min_points``-th nearest counts, so a stray point does not stop it); never less than
    the box itself."""
    grown = grown_box(box, margin_m)
    if len(obstacles_m) == 0:
        return grown
    local = box.world_to_local(np.asarray(obstacles_m, dtype=np.float64))
    half = box.half_extents
    in_height = (local[:, 2] >= -half[2]) & (local[:, 2] <= half[2] + margin_m)
    lo, hi = -half[:2] - margin_m, half[:2] + margin_m
    for axis in range(2):  # local x and y faces, both signs
        other = 1 - axis
        across = np.abs(local[:, other]) <= half[other] + margin_m
        for sign in (1.0, -1.0):
            beyond = sign * local[:, axis] - half[axis]
            near = in_height & across & (beyond > 0) & (beyond < margin_m + gap_m)
            if near.sum() >= min_points:
                nearest = float(np.sort(beyond[near])[min_points - 1])
                room = float(np.clip(nearest - gap_m, 0.0, margin_m))
                if sign > 0:
                    hi[axis] = half[axis] + room
                else:
                    lo[axis] = -half[axis] - room
    size = np.array([hi[0] - lo[0], hi[1] - lo[1], grown.size_m[2]])
    shift = np.array([(hi[0] + lo[0]) / 2, (hi[1] + lo[1]) / 2, 0.0]) @ box.rotation.T
    center = np.array(grown.center_m) + shift
    return OrientedBox(
        (float(center[0]), float(center[1]), float(center[2])),
        (float(size[0]), float(size[1]), float(size[2])),
        box.yaw_deg,
    )

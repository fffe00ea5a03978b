"""instant-ngp's scene box: ``aabb_scale``, ``scale`` and ``offset`` of a transforms.json.

instant-ngp maps a pose's point p to ``p * scale + offset`` and bounds the scene by the cube
of side ``aabb_scale`` centred on (0.5, 0.5, 0.5) there; :func:`ngp_box` gives that cube in
the poses' own coordinates.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from neoedit.data.validate import MAX_COORD_M, finite_number, is_finite_number
from neoedit.errors import DataError

NGP_SCALE = 0.33
NGP_OFFSET = (0.5, 0.5, 0.5)
NGP_MAX_AABB_SCALE = 128.0
"""instant-ngp clamps ``aabb_scale`` to 2**(cascades - 1) = 128."""


def box_ok(box: np.ndarray) -> bool:
    return bool(np.all(np.abs(box) <= MAX_COORD_M) and np.all(box[1] > box[0]))


def ngp_box(meta: dict[str, Any], tf_path: Path) -> np.ndarray | None:
    """instant-ngp's scene box in the poses' coordinates (None without ``aabb_scale``)."""
    where = f"{tf_path}: instant-ngp"
    scale = finite_number(meta, "scale", where) if "scale" in meta else NGP_SCALE
    if scale <= 0:
        raise DataError(f"{where} 'scale' must be positive, got {scale:g}")
    offset = np.asarray(NGP_OFFSET, dtype=np.float64)
    if "offset" in meta:
        raw = meta["offset"]
        items = raw if isinstance(raw, list) else [raw] * 3
        if len(items) != 3 or not all(is_finite_number(v) for v in items):
            raise DataError(f"{where} 'offset' must be 3 finite numbers, got {raw!r}")
        offset = np.asarray(items, dtype=np.float64)
    if "aabb_scale" not in meta:
        return None
    aabb_scale = finite_number(meta, "aabb_scale", where)
    if aabb_scale <= 0:
        raise DataError(f"{where} 'aabb_scale' must be a positive number, got {aabb_scale:g}")
    half = 0.5 * min(aabb_scale, NGP_MAX_AABB_SCALE)
    box = np.stack([(0.5 - half - offset) / scale, (0.5 + half - offset) / scale])
    if not box_ok(box):
        raise DataError(
            f"{where} 'aabb_scale', 'scale' and 'offset' give a box beyond {MAX_COORD_M:g}"
        )
    return box

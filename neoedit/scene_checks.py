"""What a scene.json must hold beyond its types (called by :func:`neoedit.scene.load_scene`
before anything is allocated): a real scene box, a background colour, sane configs, and
well-formed boxes, patches, moves and scan record."""

from __future__ import annotations

import math
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from neoedit.data.validate import check_scan_record
from neoedit.errors import NeoError
from neoedit.fields.language_map import LanguageMap
from neoedit.utils.validate import check_config, finite_number, shorten


def check_box_values(value: Any, what: str) -> np.ndarray:
    """A ``[[xmin,ymin,zmin],[xmax,ymax,zmax]]`` box with max > min, as a (2,3) array."""
    try:
        box = np.asarray(value, dtype=np.float64).reshape(2, 3)
    except (TypeError, ValueError):
        raise NeoError(
            f"{what} must be [[xmin,ymin,zmin],[xmax,ymax,zmax]], got {shorten(value)}"
        ) from None
    if not np.all(np.abs(box) <= 1e6) or not np.all(box[1] > box[0]):
        raise NeoError(
            f"{what} must be finite (within 1e6) with max > min on every axis, got {box.tolist()}"
        )
    return box


def check_box_dicts(items: Any, what: str) -> None:
    """A list of oriented-box dicts ``{"center", "size", "yaw_deg"}`` as stored in scene.json."""
    if not isinstance(items, list):
        raise NeoError(f"{what} must be a list of boxes")
    for b in items:
        ok = isinstance(b, Mapping) and all(
            isinstance(b.get(k), (list, tuple))
            and len(b[k]) == 3
            and all(finite_number(v) for v in b[k])
            for k in ("center", "size")
        )
        if not ok or not all(v > 0 for v in b["size"]) or not finite_number(b.get("yaw_deg", 0.0)):
            raise NeoError(f"{what}: bad box {shorten(b)}")


def _is_rigid(value: Any) -> bool:
    try:
        m = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        return False
    return m.shape == (4, 4) and bool(np.all(np.isfinite(m)))


def check_scene_meta(meta: Any, path: Path) -> None:
    """What a scene.json must hold beyond its types: a real scene box, a background colour,
    sane configs and well-formed boxes (called by ``load_scene`` before any allocation)."""
    where = str(path)
    check_box_values(meta.aabb_m, f"{where}: aabb_m")
    bg = meta.background_rgb
    if len(bg) != 3 or not all(finite_number(v) and 0.0 <= v <= 1.0 for v in bg):
        raise NeoError(f"{where}: background_rgb must be 3 numbers in [0, 1], got {bg}")
    for name in ("field", "grid", "render"):
        check_config(getattr(meta, name), f"{where}: {name}")
    if meta.language is not None:
        check_config(meta.language.field, f"{where}: language.field")
        density = meta.language.cloud_rays_per_pixel
        if not (finite_number(density) and density >= 0):
            raise NeoError(
                f"{where}: language.cloud_rays_per_pixel must be a finite number >= 0, "
                f"got {density}"
            )
        for i, entry in enumerate(meta.language.maps):
            LanguageMap.from_dict(entry, f"{where}: language.maps[{i}]")
    check_box_dicts(meta.cut_boxes, f"{where}: cut_boxes")
    check_box_dicts(meta.suppress_boxes, f"{where}: suppress_boxes")
    for i, p in enumerate(meta.patches):
        if not isinstance(p, Mapping) or "region" not in p or "version" not in p:
            raise NeoError(f"{where}: patches[{i}] needs 'region' and 'version'")
        check_box_dicts(p["region"], f"{where}: patches[{i}].region")
        if "transform" in p and not _is_rigid(p["transform"]):
            raise NeoError(f"{where}: patches[{i}].transform must be a rigid 4x4 matrix")
    for i, shade in enumerate(getattr(meta, "shades", None) or []):
        after = shade.get("after") if isinstance(shade, Mapping) else None
        ok = isinstance(after, int) and not isinstance(after, bool)
        ok = ok and 0 <= int(after or 0) <= len(meta.patches)
        if not ok or not {"box", "version"} <= set(shade):
            raise NeoError(
                f"{where}: shades[{i}] needs a 'box', a 'version' and an 'after' count within "
                f"0..{len(meta.patches)} (the patches)"
            )
        check_box_dicts([shade["box"]], f"{where}: shades[{i}].box")
    for i, move in enumerate(getattr(meta, "moves", None) or []):
        ok = isinstance(move, Mapping) and {"source", "target", "transform"} <= move.keys()
        if not ok or not _is_rigid(move["transform"]):
            raise NeoError(f"{where}: moves[{i}] needs 'source', 'target' and a 4x4 'transform'")
        check_box_dicts([move["source"], move["target"]], f"{where}: moves[{i}]")
    if getattr(meta, "scan", None) is not None:
        check_scan_record(meta.scan, where)
    if meta.step < 0 or not math.isfinite(meta.train_seconds):
        raise NeoError(f"{where}: step and train_seconds must be non-negative numbers")

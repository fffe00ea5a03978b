"""Reading a scene spec: a preset setup's name resolved (:data:`~neoedit.sim.catalog.SETUPS`),
the data validated into :class:`~neoedit.sim.spec.SceneSpec`, and the semantic checks no type
can express (object names, actions on present objects, a scan a camera can take). Errors
name the offending field."""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path
from typing import Any

import numpy as np
from pydantic import TypeAdapter, ValidationError

from neoedit.errors import NeoError, SpecError
from neoedit.sim.catalog import SETUPS
from neoedit.sim.spec import ScanSpec, SceneSpec
from neoedit.utils.userfile import read_data_file

_ADAPTER = TypeAdapter(SceneSpec)


def _format_validation_error(err: ValidationError, source: str) -> str:
    first = err.errors()[0]
    loc = "".join(f"[{p}]" if isinstance(p, int) else f".{p}" for p in first["loc"]).lstrip(".")
    loc = loc.replace(".SceneSpec", "").replace(".SetupSpec", "").replace(".ObjectSpec", "")
    more = f" (and {err.error_count() - 1} more problems)" if err.error_count() > 1 else ""
    return f"{source}: field '{loc or '<root>'}': {first['msg']}{more}"


def scene_spec_from_dict(data: Any, source: str = "scene spec") -> SceneSpec:
    """Validate plain data into a :class:`SceneSpec`; errors name the offending field."""
    if isinstance(data, dict) and isinstance(data.get("setup"), str):
        if data["setup"] not in SETUPS:
            raise SpecError(
                f"{source}: field 'setup': unknown preset {data['setup']!r}, choose from {sorted(SETUPS)}"
            )
        data = {**data, "setup": dataclasses.asdict(SETUPS[data["setup"]])}
    try:
        spec = _ADAPTER.validate_python(data)
    except ValidationError as e:
        raise SpecError(_format_validation_error(e, source)) from None
    _check_semantics(spec, source)
    return spec


def _check_semantics(spec: SceneSpec, source: str) -> None:
    names = [o.name for o in spec.objects]
    if not spec.objects:
        raise SpecError(f"{source}: field 'objects': a scene needs at least one object")
    for i, name in enumerate(names):
        if not name.strip():
            raise SpecError(f"{source}: field 'objects[{i}].name': must not be empty")
        if names.index(name) != i:
            raise SpecError(f"{source}: field 'objects[{i}].name': duplicate name {name!r}")
    for i, o in enumerate(spec.objects):
        for key in ("position_m", "yaw_deg", "rpy_deg", "scale"):
            values = np.atleast_1d(np.asarray(getattr(o, key), dtype=np.float64))
            if not np.isfinite(values).all():
                raise SpecError(f"{source}: field 'objects[{i}].{key}': must be finite numbers")
        if o.scale <= 0:
            raise SpecError(f"{source}: field 'objects[{i}].scale': must be > 0")
    present = set(names)
    for i, a in enumerate(spec.actions):
        if a.object not in present:
            raise SpecError(
                f"{source}: field 'actions[{i}].object': {a.object!r} is not an object in the scene at that step"
            )
        if a.type == "remove":
            present.discard(a.object)
    _check_scan(spec.scan, source)


MAX_SCAN_SIDE = 4096
"""Largest simulated image side (the renderer's buffers; a 4K scan is already hours)."""


def _check_scan(s: ScanSpec, source: str) -> None:
    for f in dataclasses.fields(s):
        values = getattr(s, f.name)
        for v in values if isinstance(values, tuple) else (values,):
            if not math.isfinite(v):
                raise SpecError(f"{source}: field 'scan.{f.name}': must be finite, got {v}")
    if not (8 <= s.width <= MAX_SCAN_SIDE and 8 <= s.height <= MAX_SCAN_SIDE):
        raise SpecError(
            f"{source}: field 'scan.width/height': images must be 8 to {MAX_SCAN_SIDE} "
            f"pixels a side, got {s.width}x{s.height}"
        )
    if not (0 <= s.n_eval <= 1000 and s.n_train <= 5000):
        raise SpecError(f"{source}: field 'scan.n_train/n_eval': at most 5000 / 1000 views")
    for name in ("radius_m", "eval_radius_m"):
        if not 0.1 <= getattr(s, name) <= 50:
            raise SpecError(
                f"{source}: field 'scan.{name}': the cameras must stand 0.1 to 50 m from the "
                f"table centre, got {getattr(s, name)}"
            )
    elevations = (s.elevation_min_deg, s.elevation_max_deg, s.eval_elevation_deg)
    if not all(-89 <= e <= 89 for e in elevations) or s.elevation_min_deg > s.elevation_max_deg:
        raise SpecError(
            f"{source}: field 'scan.elevation_*_deg': need -89 <= min <= max <= 89 "
            "(a camera straight above the table has no up direction)"
        )
    if s.turns <= 0:
        raise SpecError(f"{source}: field 'scan.turns': must be > 0")
    if s.n_train < 2:
        raise SpecError(f"{source}: field 'scan.n_train': need at least 2 training views")
    if not 0 < s.fov_y_deg < 170:
        raise SpecError(f"{source}: field 'scan.fov_y_deg': must be in (0, 170)")
    if not s.azimuth_range_deg[0] < s.azimuth_range_deg[1]:
        raise SpecError(f"{source}: field 'scan.azimuth_range_deg': need min < max")
    if not 0 < s.near_m < s.far_m:
        raise SpecError(f"{source}: field 'scan.near_m/far_m': need 0 < near < far")


def load_scene_spec(path: Path) -> SceneSpec:
    """Read a scene spec from ``.yaml``/``.yml``/``.json``."""
    path = Path(path)
    try:
        data = read_data_file(path, "scene spec", yaml_ok=True)
    except NeoError as e:
        raise SpecError(str(e)) from None
    return scene_spec_from_dict(data, source=str(path))

"""Checks of stored weights against the scene config that describes them: finite, shaped
as the field and grid configs say (found on the 'meta' device, without allocating), on the
scene box of scene.json. Run by :func:`neoedit.scene.load_scene` before a scene is built."""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np
import torch

from neoedit.errors import NeoError
from neoedit.fields.language import LanguageField
from neoedit.fields.radiance import RadianceField


def _shapes(module: torch.nn.Module, prefix: str) -> dict[str, tuple[int, ...]]:
    return {prefix + k: tuple(v.shape) for k, v in module.state_dict().items()}


def expected_field_shapes(meta: Any) -> dict[str, tuple[int, ...]]:
    """Tensor shapes the configs in ``meta`` give the field and the occupancy grid, found
    without allocating memory (on the 'meta' device)."""
    aabb = torch.tensor(meta.aabb_m, dtype=torch.float32)
    with torch.device("meta"):
        shapes = _shapes(RadianceField(meta.field, aabb), "field.")
    r = meta.grid.resolution
    return {**shapes, "grid.density": (r, r, r), "grid.n_updates": (1,)}


def check_finite(tensors: Mapping[str, torch.Tensor], path: Path) -> None:
    for key, value in tensors.items():
        if value.is_floating_point() and not bool(torch.isfinite(value).all()):
            raise NeoError(
                f"{path}: the weights '{key}' hold NaN or infinite values (the field is broken: "
                "retrain it, or use an earlier version)"
            )


def check_weights(meta: Any, tensors: Mapping[str, torch.Tensor], path: Path) -> None:
    """Loaded weights: finite, shaped as the scene config says (checked before the field is
    built, so a wrong config cannot allocate huge tables), on the scene box of scene.json."""
    check_finite(tensors, path)
    for key, shape in expected_field_shapes(meta).items():
        if key not in tensors:
            raise NeoError(f"{path}: weights do not match the scene config: '{key}' is missing")
        if tuple(tensors[key].shape) != shape:
            raise NeoError(
                f"{path}: weights do not match the scene config: '{key}' is "
                f"{tuple(tensors[key].shape)}, the config says {shape}"
            )
    aabb = tensors["field.aabb"].double().numpy()
    if not np.allclose(aabb, np.asarray(meta.aabb_m, dtype=np.float64), atol=1e-4):
        raise NeoError(
            f"{path}: scene.json aabb_m {meta.aabb_m} is not the box the field was trained on "
            f"({np.round(aabb, 4).tolist()})"
        )


def check_language(meta: Any, path: Path, scene: Any = None) -> None:
    """language.safetensors: before loading (``scene`` None) shaped as the language config
    says (read from its header); once loaded into ``scene``, finite."""
    from safetensors import safe_open

    file = Path(path) / "language.safetensors"
    if scene is not None:
        state = dict(scene.language.state_dict())
        check_finite({**state, "surface_points_m": scene.surface_points_m}, file)
        return
    if meta.language is None or not file.is_file():
        return  # load_scene reports a missing file
    with torch.device("meta"):
        expected = _shapes(
            LanguageField(meta.language.field, torch.tensor(meta.aabb_m)), "language."
        )
    try:
        with safe_open(str(file), framework="pt") as f:
            found = {k: tuple(f.get_slice(k).get_shape()) for k in f.keys()}  # noqa: SIM118
    except Exception as e:  # safetensors raises its own error types for corrupt files
        raise NeoError(f"{file}: cannot read the language field: {e}") from None
    for key, shape in expected.items():
        if found.get(key) != shape:
            raise NeoError(
                f"{file}: the language field does not match the scene config ('{key}': "
                f"{found.get(key)}, the config says {shape})"
            )

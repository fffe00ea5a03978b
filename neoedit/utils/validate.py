"""Input checks that run before any long work: options, devices, scene metadata, weights,
removal boxes. Each failure is one clear :class:`NeoError`."""

from __future__ import annotations

import dataclasses
import math
import re
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np
import torch

from neoedit.errors import NeoError

MAX_PROMPT_ECHO = 80
"""Longest prompt (or other user text) quoted back in a message; longer ones are cut."""
# (lowest, highest) accepted value of config fields, by field name; None = no bound
BOUNDS: dict[str, tuple[float | None, float | None]] = {
    "n_levels": (1, 32),
    "features_per_level": (1, 8),
    "log2_hashmap_size": (1, 26),
    "base_resolution": (1, 1 << 16),
    "max_resolution": (1, 1 << 20),
    "hidden_dim": (1, 4096),
    "geo_feat_dim": (1, 1024),
    "hidden_dim_color": (1, 4096),
    "density_bias": (None, None),
    "resolution": (1, 1024),
    "update_every": (1, None),
    "decay": (0.0, 1.0),
    "threshold": (0.0, None),
    "warmup_steps": (0, None),
    "n_march_samples": (1, 1 << 16),
    "n_coarse_samples": (1, 1 << 14),
    "n_samples": (1, 1 << 14),
    "near_m": (None, None),
    "chunk_rays": (1, 1 << 24),
    "dim": (1, 1 << 14),
    "dino_dim": (0, 1 << 14),
}
_DEVICE_RE = re.compile(r"^(auto|cpu|mps|cuda(:\d+)?)$")


def shorten(text: Any, limit: int = MAX_PROMPT_ECHO) -> str:
    """``text`` as a string of at most ``limit`` characters (the cut is marked)."""
    s = str(text)
    if len(s) <= limit:
        return s
    return f"{s[: limit - 20]}... ({len(s)} characters)"


def user_message(error: Exception, limit: int = 2000) -> str:
    """The one-line text the CLI prints for an error: rich markup escaped, overlong text cut,
    an OSError as 'reason: path'."""
    from rich.markup import escape

    if isinstance(error, OSError) and not isinstance(error, NeoError):
        text = f"{error.strerror or error}: {error.filename}" if error.filename else str(error)
    else:
        text = str(error)
    return escape(shorten(text, limit))


def resource_message(error: Exception) -> str | None:
    """The CLI's one line for running out of memory or disk (torch's allocator and
    safetensors report these as RuntimeError / their own errors, not as MemoryError /
    OSError), None for any other error."""
    text = str(error)
    if isinstance(error, MemoryError) or "DefaultCPUAllocator" in text or "out of memory" in text:
        return user_message(
            RuntimeError(
                "out of memory: lower --rays-per-batch, the image size (--downscale) or the "
                f"number of views ({shorten(text.splitlines()[0] if text else 'MemoryError', 200)})"
            )
        )
    if "No space left on device" in text or "Disk quota exceeded" in text:
        return user_message(RuntimeError(f"the disk is full: free space and run again ({text})"))
    return None


def check_device(name: str) -> None:
    """'auto', 'cpu', 'mps' or 'cuda[:N]' with that GPU present."""
    if not isinstance(name, str) or not _DEVICE_RE.match(name):
        raise NeoError(f"--device {shorten(name)!r} is not a device (use auto, cpu or cuda[:N])")
    if name == "mps" and not (torch.backends.mps.is_available()):
        raise NeoError("--device mps requested but this torch build has no Metal (MPS) support")
    if name.startswith("cuda"):
        if not torch.cuda.is_available():
            raise NeoError(f"--device {name} requested but CUDA is not available")
        index = int(name.split(":")[1]) if ":" in name else 0
        if index >= torch.cuda.device_count():
            raise NeoError(f"--device {name}: only {torch.cuda.device_count()} GPU(s) present")


def _finite_number(value: Any) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)


def check_config(cfg: Any, where: str) -> None:
    """Every numeric field of a config dataclass (nested ones too) finite and within
    :data:`BOUNDS`; integer fields whole numbers."""
    for f in dataclasses.fields(cfg):
        value = getattr(cfg, f.name)
        name = f"{where}.{f.name}"
        if dataclasses.is_dataclass(value):
            check_config(value, name)
            continue
        if f.name not in BOUNDS:
            if isinstance(value, float) and not math.isfinite(value):
                raise NeoError(f"{name} must be a finite number, got {value!r}")
            continue
        if not _finite_number(value):
            raise NeoError(f"{name} must be a finite number, got {shorten(value)!r}")
        lo, hi = BOUNDS[f.name]
        if (lo is not None and value < lo) or (hi is not None and value > hi):
            raise NeoError(
                f"{name} = {value} is out of range [{'-inf' if lo is None else lo}, "
                f"{'inf' if hi is None else hi}]"
            )
    if getattr(cfg, "backend", "auto") not in ("auto", "numba", "torch"):
        raise NeoError(
            f"{where}.backend must be auto, numba or torch, got {shorten(cfg.backend)!r}"
        )
    if hasattr(cfg, "base_resolution") and cfg.max_resolution < cfg.base_resolution:
        raise NeoError(f"{where}.max_resolution must be at least base_resolution")


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
            and all(_finite_number(v) for v in b[k])
            for k in ("center", "size")
        )
        if not ok or not all(v > 0 for v in b["size"]) or not _finite_number(b.get("yaw_deg", 0.0)):
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
    if len(bg) != 3 or not all(_finite_number(v) and 0.0 <= v <= 1.0 for v in bg):
        raise NeoError(f"{where}: background_rgb must be 3 numbers in [0, 1], got {bg}")
    for name in ("field", "grid", "render"):
        check_config(getattr(meta, name), f"{where}: {name}")
    if meta.language is not None:
        check_config(meta.language.field, f"{where}: language.field")
        density = meta.language.cloud_rays_per_pixel
        if not (_finite_number(density) and density >= 0):
            raise NeoError(
                f"{where}: language.cloud_rays_per_pixel must be a finite number >= 0, "
                f"got {density}"
            )
    check_box_dicts(meta.cut_boxes, f"{where}: cut_boxes")
    check_box_dicts(meta.suppress_boxes, f"{where}: suppress_boxes")
    for i, p in enumerate(meta.patches):
        if not isinstance(p, Mapping) or "region" not in p or "version" not in p:
            raise NeoError(f"{where}: patches[{i}] needs 'region' and 'version'")
        check_box_dicts(p["region"], f"{where}: patches[{i}].region")
    for i, move in enumerate(getattr(meta, "moves", None) or []):
        ok = isinstance(move, Mapping) and {"source", "target", "transform"} <= move.keys()
        if not ok or not _is_rigid(move["transform"]):
            raise NeoError(f"{where}: moves[{i}] needs 'source', 'target' and a 4x4 'transform'")
        check_box_dicts([move["source"], move["target"]], f"{where}: moves[{i}]")
    if getattr(meta, "scan", None) is not None:
        from neoedit.data.validate import check_scan_record

        check_scan_record(meta.scan, where)
    if meta.step < 0 or not math.isfinite(meta.train_seconds):
        raise NeoError(f"{where}: step and train_seconds must be non-negative numbers")


def _shapes(module: torch.nn.Module, prefix: str) -> dict[str, tuple[int, ...]]:
    return {prefix + k: tuple(v.shape) for k, v in module.state_dict().items()}


def expected_field_shapes(meta: Any) -> dict[str, tuple[int, ...]]:
    """Tensor shapes the configs in ``meta`` give the field and the occupancy grid, found
    without allocating memory (on the 'meta' device)."""
    from neoedit.fields.radiance import RadianceField

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

    from neoedit.fields.language import LanguageField

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


def _require(ok: bool, message: str) -> None:
    if not ok:
        raise NeoError(message)


def _is_int(value: Any, lo: int) -> bool:
    return isinstance(value, int) and not isinstance(value, bool) and value >= lo


def check_train_options(
    train: Any, field: Any, grid: Any, render: Any, language: Any, resume: bool
) -> None:
    """Options of ``neo train`` that cannot work (checked before any data is read)."""
    first = 0 if resume else 1
    _require(
        _is_int(train.max_steps, first),
        f"--max-steps must be at least {first}, got {train.max_steps}",
    )
    _require(
        train.max_minutes is None or (_finite_number(train.max_minutes) and train.max_minutes > 0),
        f"--max-minutes must be a positive number of minutes, got {train.max_minutes}",
    )
    for name in ("rays_per_batch", "sparsity_points"):
        _require(_is_int(getattr(train, name), 1), f"--{name.replace('_', '-')} must be at least 1")
    for name in ("eval_every", "eval_views", "checkpoint_every", "sparse_depth_rays"):
        _require(_is_int(getattr(train, name), 0), f"--{name.replace('_', '-')} must be >= 0")
    for name in ("lr", "lr_final_factor"):
        value = getattr(train, name)
        _require(_finite_number(value) and value > 0, f"--{name.replace('_', '-')} must be > 0")
    for name in ("weight_decay_mlp", "distortion_loss_weight", "mlp_lr_factor"):
        value = getattr(train, name)
        _require(_finite_number(value) and value >= 0, f"--{name.replace('_', '-')} must be >= 0")
    for name in ("sparsity_loss_weight", "depth_loss_weight"):
        _require(_finite_number(getattr(train, name)), f"--{name.replace('_', '-')} must be finite")
    check_config(field, "--field")
    check_config(grid, "--grid")
    check_config(render, "--render")
    if language is not None:
        check_language_options(language)


def check_language_options(cfg: Any) -> None:
    _require(
        cfg.teacher in ("auto", "labels", "clip", "geometric"),
        f"--language.teacher must be auto, labels, clip or geometric, got {shorten(cfg.teacher)!r}",
    )
    if hasattr(cfg, "geometric"):
        cfg.geometric.check()
    for name in ("rays", "batch", "max_surface_points"):
        _require(
            _is_int(getattr(cfg, name), 1), f"--language.{name.replace('_', '-')} must be >= 1"
        )
    _require(_is_int(cfg.steps, 0), "--language.steps must be >= 0")
    _require(_finite_number(cfg.lr) and cfg.lr > 0, "--language.lr must be > 0")
    _require(
        _finite_number(cfg.min_accumulation) and 0 <= cfg.min_accumulation <= 1,
        "--language.min-accumulation must be in [0, 1]",
    )
    for name in ("text_path", "clip_path", "dino_path"):
        value = getattr(cfg, name)
        _require(
            value is None or Path(value).exists(),
            f"--language.{name.replace('_', '-')} {shorten(value)} does not exist",
        )


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

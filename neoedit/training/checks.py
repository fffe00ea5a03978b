"""What a training checks before its work starts: the options of ``neo train``
(:func:`check_train_options`), that ``--resume`` continues the same scan with the same model
(options that would change the saved model are refused, not dropped), and that one training
step fits in memory."""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np
import torch

from neoedit.data import SceneData
from neoedit.data.scan import scan_from_record
from neoedit.errors import NeoError
from neoedit.fields.radiance import RadianceFieldConfig
from neoedit.rendering.occupancy import OccupancyGridConfig
from neoedit.rendering.renderer import RenderConfig
from neoedit.scene import Scene
from neoedit.utils.options import flag
from neoedit.utils.validate import check_config, check_memory, finite_number, is_int, require


def fingerprint(data: SceneData, frames: int = 8) -> dict[str, list[list[float]]]:
    """Mean colour (0-255) of the first frames: tells two scans with the same cameras apart
    (NEO-Sim's scenes share their camera paths)."""
    means = data.images[:frames].reshape(min(frames, len(data.images)), -1, 3).mean(1)
    return {"image_means": np.round(means, 2).tolist()}


def check_same_scan(scene: Scene, data: SceneData) -> None:
    """--resume continues a training on the data it started with (the same frames and
    cameras; the folder may have moved): anything else would mix two scenes silently."""
    if not scene.meta.scan:
        return
    cameras, paths, _ = scan_from_record(scene.meta.scan, corrected=False)
    means = scene.meta.scan.get("image_means")  # scenes trained before it: cameras only
    same = (
        paths == list(data.file_paths)
        and len(cameras) == len(data.cameras)
        and np.allclose(cameras.camera_to_world, data.cameras.camera_to_world, atol=1e-5)
        and (means is None or np.allclose(means, fingerprint(data)["image_means"], atol=1.0))
    )
    if not same:
        raise NeoError(
            f"--resume: {data.root} is not the dataset this scene was trained on "
            f"({scene.meta.data_path}); train a new scene with another --out"
        )


def check_resume_options(
    scene: Scene,
    field_cfg: RadianceFieldConfig | None,
    render_cfg: RenderConfig | None,
    grid_cfg: OccupancyGridConfig | None,
) -> None:
    """--resume keeps the saved model: an option the user set (it differs from its default)
    to a value other than the saved one is refused, naming it, instead of being ignored."""
    pairs = (
        ("field", field_cfg, RadianceFieldConfig(), scene.meta.field),
        ("render", render_cfg, RenderConfig(), scene.meta.render),
        ("grid", grid_cfg, OccupancyGridConfig(), scene.meta.grid),
    )
    for prefix, given, default, saved in pairs:
        clash = [] if given is None else _set_and_different(given, default, saved, (prefix,))
        if clash:
            name, value, kept = clash[0]
            raise NeoError(
                f"--resume continues the saved model: {name} {value} differs from its saved "
                f"{kept}; drop {name} (or train a new scene with another --out)"
            )


def _set_and_different(
    given: Any, default: Any, saved: Any, path: tuple[str, ...]
) -> list[tuple[str, Any, Any]]:
    found: list[tuple[str, Any, Any]] = []
    for f in dataclasses.fields(given):
        g, d, s = (getattr(x, f.name, None) for x in (given, default, saved))
        here = (*path, f.name)
        if dataclasses.is_dataclass(g) and not isinstance(g, type):
            found += _set_and_different(g, d, s, here)
        elif g is not None and g != d and g != s:
            found.append((flag(here), g, s))
    return found


BYTES_PER_SAMPLE_VALUE = 4
"""float32 bytes per value a fine sample keeps for the backward pass. Measured (default
field, NEO-Sim 64x48 scan): 30,000 rays per batch peaked 1.0 GB above 2,048 rays, 36 KB per
ray; this estimate gives 37 KB (32 samples x 288 values x 4 bytes)."""


def check_step_memory(
    rays: int,
    field_cfg: RadianceFieldConfig,
    render_cfg: RenderConfig,
    device: torch.device | None = None,
) -> None:
    """Refuse a ``--rays-per-batch`` whose training step cannot fit in the free memory
    (hash features and MLP activations of every fine sample of every ray), before the data
    is loaded, instead of the process being killed mid-step."""
    hashgrid = field_cfg.hashgrid
    per_sample = (
        hashgrid.n_levels * hashgrid.features_per_level
        + 2 * field_cfg.hidden_dim
        + 2 * field_cfg.hidden_dim_color
    )
    need = rays * render_cfg.n_samples * per_sample * BYTES_PER_SAMPLE_VALUE
    what = f"a training step of --rays-per-batch {rays}"
    if device is not None and device.type == "cuda":
        free = torch.cuda.mem_get_info(device)[0]
        if need > free:
            raise NeoError(
                f"{what} needs about {need / 2**30:.1f} GiB of GPU memory, "
                f"{free / 2**30:.1f} GiB are free"
            )
        return
    check_memory(need, what)


def check_finite_weights(field: torch.nn.Module, steps: int) -> None:
    """Stop a training whose weights stopped being numbers (a learning rate or loss weight
    far too large), naming the cause, before it is saved or evaluated."""
    for name, p in field.named_parameters():
        if not bool(torch.isfinite(p).all()):
            raise NeoError(
                f"training diverged by step {steps}: the weights {name!r} are no longer finite "
                "numbers; lower --lr or the loss weights"
            )


def check_train_options(
    train: Any, field: Any, grid: Any, render: Any, language: Any, resume: bool
) -> None:
    """Options of ``neo train`` that cannot work (checked before any data is read)."""
    first = 0 if resume else 1
    require(
        is_int(train.max_steps, first),
        f"--max-steps must be at least {first}, got {train.max_steps}",
    )
    require(
        train.max_minutes is None or (finite_number(train.max_minutes) and train.max_minutes > 0),
        f"--max-minutes must be a positive number of minutes, got {train.max_minutes}",
    )
    for name in ("rays_per_batch", "sparsity_points"):
        require(is_int(getattr(train, name), 1), f"--{name.replace('_', '-')} must be at least 1")
    for name in ("eval_every", "eval_views", "checkpoint_every", "sparse_depth_rays"):
        require(is_int(getattr(train, name), 0), f"--{name.replace('_', '-')} must be >= 0")
    for name in ("lr", "lr_final_factor", "pose_lr"):
        value = getattr(train, name)
        require(finite_number(value) and value > 0, f"--{name.replace('_', '-')} must be > 0")
    for name in (
        "weight_decay_mlp",
        "distortion_loss_weight",
        "mlp_lr_factor",
        "sparse_opacity_weight",
    ):
        value = getattr(train, name)
        require(finite_number(value) and value >= 0, f"--{name.replace('_', '-')} must be >= 0")
    share = train.object_ray_share
    require(
        finite_number(share) and 0 <= share < 1,
        f"--object-ray-share must be in [0, 1), got {share}",
    )
    for name in ("sparsity_loss_weight", "depth_loss_weight"):
        require(finite_number(getattr(train, name)), f"--{name.replace('_', '-')} must be finite")
    check_config(field, "--field")
    check_config(grid, "--grid")
    check_config(render, "--render")
    if language is not None:
        language.check()

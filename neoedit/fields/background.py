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
    """rgb (N,3) in [0,1] of rays with unit directions (N,3) past the scene box.

    With ``closed_box`` (the scene box, z up, its bottom under the table or floor), rays that
    leave the box through its bottom face get black instead: they must have hit the support,
    so a plain floor has to be learnt as a surface rather than painted in as far away."""

    closed_box: torch.Tensor | None

    def __init__(self, hidden_dim: int = 64, closed_box: torch.Tensor | None = None):
        super().__init__()
        box = None if closed_box is None else torch.as_tensor(closed_box, dtype=torch.float32)
        self.register_buffer("closed_box", box, persistent=False)
        self.mlp = nn.Sequential(
            nn.Linear(16 + 6 * N_FREQUENCIES, hidden_dim),
            nn.ReLU(),
            nn.Linear(hidden_dim, hidden_dim),
            nn.ReLU(),
            nn.Linear(hidden_dim, 3),
        )

    def forward(
        self, directions: torch.Tensor, origins: torch.Tensor | None = None
    ) -> torch.Tensor:
        d = directions / directions.norm(dim=-1, keepdim=True).clamp_min(1e-12)
        rgb = torch.sigmoid(self.mlp(direction_encoding(d)))
        if self.closed_box is not None and origins is not None:
            rgb = rgb * ~exits_bottom(origins, d, self.closed_box)[:, None]
        return rgb


def exits_bottom(
    origins: torch.Tensor, directions: torch.Tensor, box: torch.Tensor
) -> torch.Tensor:
    """(N,) rays that cross the axis-aligned ``box`` (2,3) and leave it through its bottom face."""
    inv = 1.0 / torch.where(
        directions.abs() < 1e-12, torch.full_like(directions, 1e-12), directions
    )
    t0, t1 = (box[0] - origins) * inv, (box[1] - origins) * inv
    t_near, t_far = torch.minimum(t0, t1).amax(-1), torch.maximum(t0, t1).amin(-1)
    exit_z = origins[:, 2] + t_far * directions[:, 2]
    return (t_near < t_far) & (t_far > 0) & (directions[:, 2] < 0) & (exit_z <= box[0, 2] + 1e-5)


Background = torch.Tensor | nn.Module
"""A constant colour (3,) / per-ray colours (N,3), or a module of the ray directions."""


def background_colors(
    background: Background, origins: torch.Tensor, directions: torch.Tensor
) -> torch.Tensor:
    """The background of rays (origins, directions (N,3)): the module's colours, or the
    constant as given (broadcast by the compositor)."""
    if isinstance(background, nn.Module):
        return background(directions, origins)
    return background

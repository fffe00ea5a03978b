"""The scene field F_Theta: hash-grid encoding + small MLPs -> density and view-dependent colour.

Queryable at arbitrary world points (``density``, ``forward``), clonable with
``copy.deepcopy`` (teacher/student), device-agnostic.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Protocol

import torch
from torch import nn

from neoedit.fields.background import DirectionalBackground
from neoedit.fields.encodings import spherical_harmonics_deg3
from neoedit.fields.hashgrid import HashGridConfig, HashGridEncoding
from neoedit.fields.room import RoomConfig, RoomField


@dataclass
class RadianceFieldConfig:
    hashgrid: HashGridConfig = field(default_factory=HashGridConfig)
    """Position encoding."""
    hidden_dim: int = 64
    """Width of the density MLP."""
    geo_feat_dim: int = 15
    """Features passed from the density MLP to the colour MLP."""
    hidden_dim_color: int = 64
    """Width of the colour MLP (two hidden layers)."""
    density_bias: float = -1.0
    """Initial pre-activation bias of the density (exp activation)."""
    learned_background: bool | None = None
    """Rays leaving the box take the colour of a learned environment map
    (:mod:`neoedit.fields.background`) instead of the constant background colour. Default
    (None): learned for photos without an alpha channel (real captures see a room beyond the
    box), constant for RGBA renders such as NEO-Sim."""
    room: bool | None = False
    """Model everything outside the scene box as a second, coarser field in contracted space
    (:mod:`neoedit.fields.room`): the walls and furniture around the table get geometry and
    parallax instead of a colour per ray direction (beer_can: 28.5 against 25.1 dB held out
    after 5 minutes). Off by default: with it, the floor *inside* the box stays transparent
    on beer_can (2-5 % opacity 15 cm from the can; the room paints the floor far away
    instead), so edits and grasps lose their support surface. None: on for photos taken
    from outside the box (most camera centres outside it) with the learned background and
    no ``closed_bottom``; off for RGBA renders and forward-facing captures."""
    room_field: RoomConfig = field(default_factory=RoomConfig)
    """The room field's size and sampling (with ``room``)."""
    closed_bottom: bool = False
    """With a learned background, rays leaving the box through its bottom face see black,
    so a plain floor is learnt as a surface instead of painted in as far away (the box's
    bottom must lie under the table / floor, as in z-up data from ``neo import``). Off by
    default: on beer_can it gave the floor a surface but cost 4 dB of held-out PSNR in a
    5-minute training (benchmarks/RESULTS.md)."""


class Field(Protocol):
    """What the renderers need of a field (a :class:`RadianceField`, a patched or suppressed
    one): its scene box and density / colour at world points."""

    @property
    def aabb(self) -> torch.Tensor: ...

    def density(self, points: torch.Tensor) -> torch.Tensor: ...

    def __call__(
        self, points: torch.Tensor, directions: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor]: ...


MAX_LOG_DENSITY = 15.0
"""Densities are capped at exp(15) = 3.3e6 /m: opaque within a micrometre, and finite. Without
the cap, the inside of objects, which no ray constrains, drifts with the shared hash-grid
and MLP weights: a tiny scene trained 1,200 steps reached 1e37 /m and then inf, and its
saved occupancy grid was refused as broken (issue 39)."""


class TruncExp(torch.autograd.Function):
    """exp with its value capped at exp(:data:`MAX_LOG_DENSITY`) and a gradient clamped for
    stability (Instant-NGP). Above the cap the gradient still flows as if uncapped (clamped),
    so a capped density the loss wants lower can come down."""

    @staticmethod
    def forward(ctx, x: torch.Tensor) -> torch.Tensor:
        ctx.save_for_backward(x)
        return torch.exp(x.clamp(max=MAX_LOG_DENSITY))

    @staticmethod
    def backward(ctx, g: torch.Tensor) -> torch.Tensor:
        (x,) = ctx.saved_tensors
        return g * torch.exp(x.clamp(-15.0, 15.0))


class RadianceField(nn.Module):
    aabb: torch.Tensor  # (2, 3) scene box, world metres

    def __init__(self, cfg: RadianceFieldConfig, aabb: torch.Tensor, seed: int = 0):
        super().__init__()
        self.cfg = cfg
        torch.manual_seed(seed)
        self.register_buffer(
            "aabb", torch.as_tensor(aabb, dtype=torch.float32).clone()
        )  # (2,3) world metres
        self.encoding = HashGridEncoding(cfg.hashgrid, seed=seed)
        density_head = nn.Linear(cfg.hidden_dim, 1 + cfg.geo_feat_dim)
        with torch.no_grad():
            density_head.bias[0] = cfg.density_bias
        self.density_mlp = nn.Sequential(
            nn.Linear(self.encoding.output_dim, cfg.hidden_dim), nn.ReLU(), density_head
        )
        self.color_mlp = nn.Sequential(
            nn.Linear(cfg.geo_feat_dim + 16, cfg.hidden_dim_color),
            nn.ReLU(),
            nn.Linear(cfg.hidden_dim_color, cfg.hidden_dim_color),
            nn.ReLU(),
            nn.Linear(cfg.hidden_dim_color, 3),
        )
        self.background_head: nn.Module | None = None
        if cfg.room:
            self.background_head = RoomField(cfg.room_field, self.aabb, seed=seed)
        elif cfg.learned_background:
            self.background_head = DirectionalBackground(
                closed_box=self.aabb if cfg.closed_bottom else None
            )

    def normalize(self, points: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """World points (N,3) -> unit-cube coordinates (N,3) and an inside-the-box mask (N,)."""
        u = (points - self.aabb[0]) / (self.aabb[1] - self.aabb[0])
        return u, ((u >= 0) & (u <= 1)).all(-1)

    def density_and_features(self, points: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """sigma (N,) [1/m] and geometry features (N, G) at world points (N,3)."""
        u, inside = self.normalize(points)
        h = self.density_mlp(self.encoding(u))
        sigma = TruncExp.apply(h[:, 0]) * inside
        return sigma, h[:, 1:]

    def density(self, points: torch.Tensor) -> torch.Tensor:
        return self.density_and_features(points)[0]

    def forward(
        self, points: torch.Tensor, directions: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """sigma (N,) [1/m] and rgb (N,3) in [0,1] at world points (N,3) seen along unit directions (N,3)."""
        sigma, geo = self.density_and_features(points)
        rgb = torch.sigmoid(
            self.color_mlp(torch.cat([geo, spherical_harmonics_deg3(directions)], -1))
        )
        return sigma, rgb

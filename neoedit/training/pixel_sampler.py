"""Which training pixels a step draws: uniformly, or in part where the field is still wrong.

Uniform draws give every object a share of the gradient equal to its share of the pixels: on
a tabletop the table takes almost all of it, and small objects keep a colour pulled towards
the table's (issue 39: a grey arm rendered cream, a yellow duck with a blue channel 12/255
too high, on a small scene). The error map (Instant-NGP's idea) keeps, per image and per
cell of ``cell_px`` x ``cell_px`` pixels, a running mean of the squared colour error of the
rays drawn there, and draws a share of each batch from cells in proportion to it
(``neo train --error-sampling``; see TrainConfig.error_sampling for what it was measured to
give and cost).
"""

from __future__ import annotations

import math

import torch


class ErrorMapSampler:
    """Draws (image, row, column) of training pixels; ``share`` of them by the error map."""

    def __init__(
        self,
        n_images: int,
        height: int,
        width: int,
        share: float,
        device: torch.device,
        cell_px: int = 8,
        blend: float = 0.5,
    ):
        if not 0.0 <= share < 1.0:
            raise ValueError(f"share must be in [0, 1), got {share}")
        self.h, self.w, self.share, self.cell, self.blend = height, width, share, cell_px, blend
        self.rows, self.cols = math.ceil(height / cell_px), math.ceil(width / cell_px)
        self.device = device
        self.error = torch.ones(n_images * self.rows * self.cols, device=device)
        """Running mean squared error per cell (1 before a cell was drawn: sampled often)."""
        self.visited = torch.zeros_like(self.error, dtype=torch.bool)

    def draw(self, n: int, generator: torch.Generator) -> tuple[torch.Tensor, ...]:
        """``n`` pixels: image index, row, column (each (n,) long)."""
        k = round(self.share * n) if self.share > 0 else 0
        t = self.error.numel() // (self.rows * self.cols)
        img = torch.randint(0, t, (n - k,), device=self.device, generator=generator)
        v = torch.randint(0, self.h, (n - k,), device=self.device, generator=generator)
        u = torch.randint(0, self.w, (n - k,), device=self.device, generator=generator)
        if k == 0:
            return img, v, u
        cells = torch.multinomial(self.error, k, replacement=True, generator=generator)
        per_image = self.rows * self.cols
        ci, rest = cells // per_image, cells % per_image
        cy, cx = rest // self.cols, rest % self.cols
        jitter = torch.randint(0, self.cell, (2, k), device=self.device, generator=generator)
        cv = (cy * self.cell + jitter[0]).clamp_max(self.h - 1)
        cu = (cx * self.cell + jitter[1]).clamp_max(self.w - 1)
        return torch.cat([img, ci]), torch.cat([v, cv]), torch.cat([u, cu])

    @torch.no_grad()
    def update(
        self, img: torch.Tensor, v: torch.Tensor, u: torch.Tensor, sq_err: torch.Tensor
    ) -> None:
        """Blend the squared errors (n,) of the pixels just trained into their cells."""
        if self.share == 0:
            return
        cells = (img * self.rows + v // self.cell) * self.cols + u // self.cell
        sums = torch.zeros_like(self.error).index_add_(0, cells, sq_err.float())
        counts = torch.zeros_like(self.error).index_add_(
            0, cells, torch.ones_like(sq_err, dtype=sums.dtype)
        )
        seen = counts > 0
        mean = sums[seen] / counts[seen]
        first = ~self.visited[seen]  # a cell's first errors replace its initial 1
        self.error[seen] = torch.where(first, mean, torch.lerp(self.error[seen], mean, self.blend))
        self.visited |= seen
        self.error.clamp_(min=1e-6)  # never impossible to draw

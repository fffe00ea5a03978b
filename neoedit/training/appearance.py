"""Per-photo appearance: the exposure and white balance of each training photo.

Phone and camera captures change exposure and white balance from photo to photo; a field
that must match every photo exactly learns their average as flicker and floaters. Here
each training photo gets a colour gain and offset per channel, ``rgb' = rgb * (1 + g) + b``,
learnt with the field (NeRF-W's appearance embedding reduced to what a camera's automatic
exposure does). Renders of the field (evaluation, novel views, edits) use the neutral
appearance (g = b = 0): the field is the scene as an average photo shows it. The gains are
a training-time variable only: they are not saved, and ``--resume`` starts them again at
neutral.
"""

from __future__ import annotations

import torch


class PhotoAppearance:
    """Gains and offsets (T,6) of T training photos, with their own Adam optimiser."""

    def __init__(self, n_photos: int, lr: float, device: torch.device, weight: float = 1e-2):
        self.params = torch.zeros(n_photos, 6, device=device, requires_grad=True)
        self.optimizer = torch.optim.Adam([self.params], lr=lr)
        self.weight = weight

    def apply(self, rgb: torch.Tensor, photo: torch.Tensor) -> torch.Tensor:
        """Rendered colours (N,3) as training photos ``photo`` (N,) would show them."""
        p = self.params[photo]
        return rgb * (1.0 + p[:, :3]) + p[:, 3:]

    def penalty(self) -> torch.Tensor:
        """Keeps the photos near neutral on average: the field, not the gains, holds the
        scene's colours (without it the gains could drift together)."""
        mean = self.params.mean(0)
        return self.weight * (mean**2).sum()

    def zero_grad(self) -> None:
        self.optimizer.zero_grad(set_to_none=True)

    def step(self) -> None:
        self.optimizer.step()

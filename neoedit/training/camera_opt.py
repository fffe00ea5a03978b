"""Camera pose refinement: a small rigid correction per training photo, learnt with the field.

The poses of a phone capture come from structure from motion and are off by a fraction of a
degree (beer_can: 0.39 deg median between two reconstructions of the same photos), a few
pixels at a photo's edge; a field made to fit photos that disagree by pixels blurs. As
nerfstudio's camera optimiser (its SO(3) x R^3 mode) does, each training photo gets a
rotation vector w and a translation t [m] applied about its camera centre: a ray from o along
d becomes a ray from o + t along exp(w) d. The points along it move with them, and the
hash grid's gradient with respect to its input points (``backward_x`` of the compiled
kernels) carries the photometric loss back to w and t.

The corrections' mean is removed after every step: they could otherwise drift together,
moving the whole scene against the held-out photos, which keep their poses (measured on
NEO-Sim removal_1, training photos turned 1 deg and shifted 5 mm, 600 steps, learning rate
3e-4, no warm-up: held out 24.7 dB with a penalty on the mean, 28.2 dB with the mean
removed, 26.8 dB without refinement; with the defaults, 1e-3 after a 20 % warm-up, 30.1 dB).
Their learning rate follows the field's decay. At the end they are stored in the scene's scan
record (``pose_corrections``) and every later reader of the scan's cameras (the language
field, the edits' views, the viewer) gets the corrected poses
(:func:`neoedit.data.scan.scan_from_record`, :mod:`neoedit.cameras.pose_correction`).
"""

from __future__ import annotations

import numpy as np
import torch

from neoedit.cameras.pose_correction import corrected_rays
from neoedit.cameras.rays import RayBundle


class PoseRefinement:
    """Corrections (T,6) of T training photos, with their own Adam optimiser."""

    def __init__(
        self,
        n_photos: int,
        lr: float,
        device: torch.device,
        start: np.ndarray | None = None,
    ):
        init = torch.zeros(n_photos, 6) if start is None else torch.as_tensor(start).float()
        self.params = init.to(device).requires_grad_(True)
        self.lr = lr
        self.optimizer = torch.optim.Adam([self.params], lr=lr)

    def apply(self, rays: RayBundle, photo: torch.Tensor) -> RayBundle:
        """``rays`` of training photos ``photo`` (N,) as their corrected poses cast them."""
        return corrected_rays(rays, self.params, photo)

    @torch.no_grad()
    def apply_fixed(self, rays: RayBundle, photo: torch.Tensor) -> RayBundle:
        """:meth:`apply` with the corrections held (no gradient reaches them)."""
        return self.apply(rays, photo)

    def zero_grad(self) -> None:
        self.optimizer.zero_grad(set_to_none=True)

    def step(self, lr_scale: float = 1.0) -> None:
        """One Adam step at ``lr`` times ``lr_scale`` (the field's decay so far), then the
        corrections' mean removed: the photos move against each other, never all together
        (that would move the scene against the held-out photos and their poses)."""
        self.optimizer.param_groups[0]["lr"] = self.lr * lr_scale
        self.optimizer.step()
        with torch.no_grad():
            self.params -= self.params.mean(0, keepdim=True)

    def corrections(self) -> np.ndarray:
        return self.params.detach().cpu().numpy().astype(np.float64)

"""Volume rendering (Max 1995; NeRF): weights, colour, depth and accumulation."""

from __future__ import annotations

import torch


def render_weights(sigma: torch.Tensor, deltas: torch.Tensor) -> torch.Tensor:
    """Weights (N, M) from densities (N, M) [1/m] and bin widths (N, M) [m]:
    w_i = T_i (1 - exp(-sigma_i delta_i)), T_i = exp(-sum_{j<i} sigma_j delta_j)."""
    tau = sigma * deltas
    alpha = 1.0 - torch.exp(-tau)
    transmittance = torch.exp(
        -torch.cumsum(torch.cat([torch.zeros_like(tau[:, :1]), tau[:, :-1]], -1), -1)
    )
    return alpha * transmittance


def composite(
    weights: torch.Tensor, rgb: torch.Tensor, t_mid: torch.Tensor, background: torch.Tensor
) -> dict[str, torch.Tensor]:
    """rgb (N,3) over ``background`` (3,) or (N,3), expected ray distance (N,) and accumulation (N,)."""
    acc = weights.sum(-1)
    color = (weights[..., None] * rgb).sum(-2) + (1.0 - acc)[:, None] * background
    depth = (weights * t_mid).sum(-1) / acc.clamp_min(1e-6)
    return {"rgb": color, "depth": depth, "accumulation": acc}


def distortion_loss(weights: torch.Tensor, s_lo: torch.Tensor, s_hi: torch.Tensor) -> torch.Tensor:
    """Mip-NeRF 360 distortion loss per ray (N,): pulls each ray's weights into one compact
    interval, which removes semi-transparent fog ("floaters").

    L = sum_ij w_i w_j |m_i - m_j| + 1/3 sum_i w_i^2 (s_hi_i - s_lo_i), with bin midpoints m.
    """
    mid = 0.5 * (s_lo + s_hi)
    pairwise = (
        weights[:, :, None] * weights[:, None, :] * (mid[:, :, None] - mid[:, None, :]).abs()
    ).sum((-1, -2))
    return pairwise + (weights**2 * (s_hi - s_lo)).sum(-1) / 3.0


def opacity_penalty(sigma: torch.Tensor, scale_m: float = 0.01) -> torch.Tensor:
    """Mean opacity of ``scale_m``-long steps at densities ``sigma`` [1/m]: a bounded penalty
    that pushes density towards zero (sparsity in training, L_reg in an edit's box)."""
    return torch.mean(1.0 - torch.exp(-scale_m * sigma))


def light_missing(
    weights: torch.Tensor, t_mid: torch.Tensor, t_lo: torch.Tensor, t_hi: torch.Tensor
) -> torch.Tensor:
    """(N,) the share of each ray's light that does not end in [``t_lo``, ``t_hi``] (N,):
    1 - the summed weights of the samples whose midpoint lies there. A ray that sees a
    surface there (a structure-from-motion point) should end there: the expected depth
    alone cannot tell an opaque surface from a faint one at the same distance, and light
    stopped before the window (a lid of fog nearer the camera) counts as missing too."""
    inside = (t_mid >= t_lo[:, None]) & (t_mid <= t_hi[:, None])
    return 1.0 - (weights * inside).sum(-1)

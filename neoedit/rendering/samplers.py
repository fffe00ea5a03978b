"""Samplers on the concatenated domain: uniform (stratified) and PDF (hierarchical).

Samples are bins: ``edges`` (N, M+1) in domain coordinates; the field is evaluated at bin
midpoints and the bin widths are the volume-rendering deltas. Because deltas are measured
in the domain, a removed segment contributes neither samples nor optical depth.
"""

from __future__ import annotations

import torch


def uniform_edges(
    total: torch.Tensor, n_bins: int, jitter: bool, generator: torch.Generator | None = None
) -> torch.Tensor:
    """(N, n_bins+1) evenly spaced edges over [0, total]; ``jitter`` shifts each interior edge
    uniformly within its bin (stratified sampling) for training."""
    u = torch.linspace(0.0, 1.0, n_bins + 1, device=total.device).expand(total.shape[0], -1)
    if jitter:
        noise = (
            torch.rand(total.shape[0], n_bins - 1, device=total.device, generator=generator) - 0.5
        )
        u = u.clone()
        u[:, 1:-1] += noise / n_bins
    return u * total[:, None]


PDF_EPS = 1e-5
"""The uniform floor added to every bin's weight before inverse-CDF sampling."""


def pdf_positions(
    n: int,
    n_bins: int,
    jitter: bool,
    device: torch.device | str = "cpu",
    generator: torch.Generator | None = None,
) -> torch.Tensor:
    """(n, n_bins+1) ascending CDF positions in [0, 1] for :func:`pdf_edges`: evenly spaced,
    or one uniform draw in each of n_bins+1 strata when ``jitter``."""
    if jitter:
        u = (
            torch.arange(n_bins + 1, device=device)
            + torch.rand(n, n_bins + 1, device=device, generator=generator)
        ) / (n_bins + 1)
    else:
        u = torch.linspace(0.0, 1.0, n_bins + 1, device=device).expand(n, -1)
    return u.clamp(0.0, 1.0).contiguous()


def pdf_edges(
    edges: torch.Tensor,
    weights: torch.Tensor,
    n_bins: int,
    jitter: bool = False,
    generator: torch.Generator | None = None,
    eps: float = PDF_EPS,
    u: torch.Tensor | None = None,
) -> torch.Tensor:
    """Draw (N, n_bins+1) new edges by inverse-CDF sampling of piecewise-constant ``weights``
    (N, M) over bins ``edges`` (N, M+1). A small uniform floor keeps every bin reachable.
    ``u``: the CDF positions to use (default: :func:`pdf_positions`)."""
    w = weights + eps
    pdf = w / w.sum(-1, keepdim=True)
    cdf = torch.cat([torch.zeros_like(pdf[:, :1]), torch.cumsum(pdf, -1).clamp_max(1.0)], dim=-1)
    if u is None:
        u = pdf_positions(edges.shape[0], n_bins, jitter, edges.device, generator)
    idx = torch.searchsorted(cdf.contiguous(), u, right=True).clamp(1, cdf.shape[-1] - 1)
    c0, c1 = torch.gather(cdf, -1, idx - 1), torch.gather(cdf, -1, idx)
    e0, e1 = torch.gather(edges, -1, idx - 1), torch.gather(edges, -1, idx)
    frac = ((u - c0) / (c1 - c0).clamp_min(1e-12)).clamp(0.0, 1.0)
    new = e0 + frac * (e1 - e0)
    return torch.sort(new, dim=-1).values

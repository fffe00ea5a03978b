"""Per-ray valid intervals and the concatenated 1-D sampling domain (paper Sec. III-A).

A ray's valid part is a set of disjoint intervals [start_k, end_k] of ray distance t. The
removal stage cuts the segment inside each box out of [near, far]; sampling then works on
the *domain* coordinate s in [0, total length), which runs over the intervals one after
the other, so no sample can ever land in a removed segment.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import torch

from neoedit.geometry import OrientedBox
from neoedit.geometry.rays import ray_oriented_box


@dataclass
class RayIntervals:
    starts: torch.Tensor  # (N, K) ray distance, sorted along K; zero-length entries are padding
    ends: torch.Tensor  # (N, K)

    @property
    def lengths(self) -> torch.Tensor:
        return (self.ends - self.starts).clamp_min(0.0)

    @property
    def total(self) -> torch.Tensor:
        """(N,) length of the concatenated domain."""
        return self.lengths.sum(-1)

    def domain_to_t(self, s: torch.Tensor) -> torch.Tensor:
        """Map domain positions s (N, M) in [0, total] to ray distances t (N, M)."""
        cum = torch.cumsum(self.lengths, dim=-1)  # (N, K) domain position of each interval's end
        k = torch.searchsorted(cum.contiguous(), s.contiguous(), right=True).clamp_max(
            cum.shape[-1] - 1
        )
        before = torch.gather(cum - self.lengths, -1, k)
        # s exactly at the very end maps to the last interval's end
        return torch.gather(self.starts, -1, k) + (s - before).clamp_min(0.0)


def near_far_intervals(near: torch.Tensor, far: torch.Tensor) -> RayIntervals:
    return RayIntervals(near[:, None], torch.maximum(far, near)[:, None])


def cut_boxes(
    intervals: RayIntervals,
    origins: torch.Tensor,
    directions: torch.Tensor,
    boxes: Sequence[OrientedBox],
) -> RayIntervals:
    """Remove the part of every interval that lies inside any of ``boxes``."""
    starts, ends = intervals.starts, intervals.ends
    for box in boxes:
        t_in, t_out = ray_oriented_box(origins, directions, box)
        hit = (t_out > t_in)[:, None]
        t_in, t_out = t_in[:, None], t_out[:, None]
        # [a, b] minus [t_in, t_out] = [a, min(b, t_in)] and [max(a, t_out), b]
        left_end = torch.where(hit, torch.minimum(ends, t_in), ends)
        right_start = torch.where(hit, torch.maximum(starts, t_out), ends)
        new_starts = torch.cat([starts, right_start], dim=-1)
        new_ends = torch.cat(
            [torch.maximum(left_end, starts), torch.maximum(ends, right_start)], dim=-1
        )
        order = torch.argsort(new_starts, dim=-1)
        starts, ends = torch.gather(new_starts, -1, order), torch.gather(new_ends, -1, order)
    return RayIntervals(starts, ends)

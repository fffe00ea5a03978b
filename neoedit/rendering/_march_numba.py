"""Compiled CPU kernel of the occupancy march (numba; imported lazily by ``march``).

For each ray, walk ``n_bins`` even bins over its valid domain (the concatenated intervals,
as :meth:`RayIntervals.domain_to_t`), and write the ray distance of every bin whose centre
lies in an occupied grid cell, front to back. No (rays x bins x 3) points are built, which
is what makes it much cheaper than the same march in PyTorch on a CPU.
"""

from __future__ import annotations

import numba
import numpy as np


@numba.njit(parallel=True, fastmath=False, cache=True)
def _march(origins, dirs, starts, ends, n_bins, occupied, lo, hi, t_out, count):  # pragma: no cover
    n, n_int = starts.shape
    r = occupied.shape[0]
    for i in numba.prange(n):
        total = 0.0
        for k in range(n_int):
            total += max(ends[i, k] - starts[i, k], 0.0)
        c = 0
        if total > 0.0:
            step = total / n_bins
            k = 0
            seg_s = 0.0  # domain position where interval k starts
            seg_len = max(ends[i, 0] - starts[i, 0], 0.0)
            for b in range(n_bins):
                s = (b + 0.5) * step
                while k < n_int - 1 and s >= seg_s + seg_len:
                    seg_s += seg_len
                    k += 1
                    seg_len = max(ends[i, k] - starts[i, k], 0.0)
                t = starts[i, k] + max(s - seg_s, 0.0)
                ux = (origins[i, 0] + t * dirs[i, 0] - lo[0]) / (hi[0] - lo[0])
                uy = (origins[i, 1] + t * dirs[i, 1] - lo[1]) / (hi[1] - lo[1])
                uz = (origins[i, 2] + t * dirs[i, 2] - lo[2]) / (hi[2] - lo[2])
                if ux < 0.0 or uy < 0.0 or uz < 0.0 or ux >= 1.0 or uy >= 1.0 or uz >= 1.0:
                    continue
                ix, iy, iz = (
                    min(int(ux * r), r - 1),
                    min(int(uy * r), r - 1),
                    min(int(uz * r), r - 1),
                )
                if occupied[ix, iy, iz]:
                    t_out[i, c] = t
                    c += 1
        count[i] = c


def march(
    origins: np.ndarray,
    dirs: np.ndarray,
    starts: np.ndarray,
    ends: np.ndarray,
    n_bins: int,
    occupied: np.ndarray,
    lo: np.ndarray,
    hi: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """Ray distances (N, n_bins) of the occupied bins, front first (rows padded past their
    count), and the count per ray (N,)."""
    t_out = np.zeros((origins.shape[0], n_bins), dtype=np.float32)
    count = np.zeros(origins.shape[0], dtype=np.int64)
    _march(origins, dirs, starts, ends, n_bins, occupied, lo, hi, t_out, count)
    return t_out, count

"""Compiled CPU kernels of the occupancy march and the training sampler's proposal (numba;
imported lazily by ``march`` and ``coarse``).

:func:`_march_bins` walks ``n_bins`` even bins over each ray's valid domain (the
concatenated intervals, as :meth:`RayIntervals.domain_to_t`) and writes the ray distance
of every bin whose centre lies in an occupied grid cell, front to back: the fast render's
march (bin centres) and the training sampler's (a per-ray jitter). :func:`_coarse_points`
and :func:`_fine_edges` are the rest of the training proposal (``coarse.fine_edges``). No
(rays x bins x 3) points are built, which is what makes them much cheaper than the same
steps in PyTorch on a CPU.
"""

from __future__ import annotations

import numba
import numpy as np


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
    n = origins.shape[0]
    t_out = np.zeros((n, n_bins), dtype=np.float32)
    count = np.zeros(n, dtype=np.int64)
    offset = np.full(n, 0.5, dtype=np.float32)  # bin centres
    occ = np.zeros((n, n_bins), dtype=np.uint8)
    _march_bins(origins, dirs, starts, ends, offset, n_bins, occupied, lo, hi, occ, t_out, count)
    return t_out, count


@numba.njit(parallel=True, fastmath=False, cache=True)
def _march_bins(
    origins, dirs, starts, ends, offset, n_bins, occupied, lo, hi, occ, t_occ, count
):  # pragma: no cover
    """Bins at ``(b + offset) * step`` over each ray's valid domain,
    each bin's occupancy written to ``occ`` and the ray distances of the occupied ones to
    ``t_occ``, front first (float32 positions, as the PyTorch reference computes them)."""
    n, n_int = starts.shape
    r = occupied.shape[0]
    zero = np.float32(0.0)
    for i in numba.prange(n):
        total = zero
        for k in range(n_int):
            total += max(ends[i, k] - starts[i, k], zero)
        c = 0
        if total > zero:
            step = total / np.float32(n_bins)
            k = 0
            seg_s = zero
            seg_len = max(ends[i, 0] - starts[i, 0], zero)
            for b in range(n_bins):
                s = (np.float32(b) + offset[i]) * step
                while k < n_int - 1 and s >= seg_s + seg_len:
                    seg_s += seg_len
                    k += 1
                    seg_len = max(ends[i, k] - starts[i, k], zero)
                t = starts[i, k] + max(s - seg_s, zero)
                ux = (origins[i, 0] + t * dirs[i, 0] - lo[0]) / (hi[0] - lo[0])
                uy = (origins[i, 1] + t * dirs[i, 1] - lo[1]) / (hi[1] - lo[1])
                uz = (origins[i, 2] + t * dirs[i, 2] - lo[2]) / (hi[2] - lo[2])
                if not (zero <= ux < 1.0 and zero <= uy < 1.0 and zero <= uz < 1.0):
                    continue  # outside the grid (or NaN)
                ix, iy, iz = (
                    min(int(ux * r), r - 1),
                    min(int(uy * r), r - 1),
                    min(int(uz * r), r - 1),
                )
                if occupied[ix, iy, iz]:
                    occ[i, b] = 1
                    t_occ[i, c] = t
                    c += 1
        count[i] = c


@numba.njit(parallel=True, fastmath=False, cache=True)
def _coarse_points(origins, dirs, t_occ, count, n_query, first, points):  # pragma: no cover
    """The points of the ``min(count, n_query)`` occupied bins queried on each ray, spread
    evenly over its occupied bins, written from row ``first[i]`` on."""
    m = np.float32(n_query)
    for i in numba.prange(origins.shape[0]):
        c = count[i]
        spread = np.float32(max(c, n_query))
        for j in range(min(c, n_query)):
            t = t_occ[i, int(np.floor(np.float32(j) * spread / m))]
            row = first[i] + j
            for a in range(3):
                points[row, a] = origins[i, a] + t * dirs[i, a]


@numba.njit(parallel=True, fastmath=False, cache=True)
def _fine_edges(
    starts, ends, offset, occ, count, first, sigma, n_query, u, eps, edges, cdf, out
):  # pragma: no cover
    """Per ray: the coarse bins' weights (each occupied bin takes the density queried for
    it), then inverse-CDF edges at the positions ``u`` (see ``samplers.pdf_edges``)."""
    n, n_bins = occ.shape
    n_out = u.shape[1]
    zero = np.float32(0.0)
    m = np.float32(n_query)
    for i in numba.prange(n):
        total = zero
        for k in range(starts.shape[1]):
            total += max(ends[i, k] - starts[i, k], zero)
        step = total / np.float32(n_bins)
        e, f = edges[i], cdf[i]
        e[0] = zero
        for b in range(1, n_bins):
            e[b] = (np.float32(b) + offset[i] - np.float32(0.5)) * step
        e[n_bins] = total
        c = count[i]
        spread = np.float32(max(c, n_query))
        seen, tau_sum, w_sum = 0, 0.0, 0.0
        for b in range(n_bins):
            w = eps  # an empty bin: no optical depth
            if occ[i, b]:
                seen += 1
                owner = min(int(np.floor(np.float32(seen - 1) * m / spread)), n_query - 1)
                tau = sigma[first[i] + owner] * (e[b + 1] - e[b])
                if tau != zero:  # (a NaN density too: it spoils the ray, as in the reference)
                    w += np.float32((1.0 - np.exp(-tau)) * np.exp(-tau_sum))
                    tau_sum += tau
            f[b + 1] = w
            w_sum += w
        if not w_sum == w_sum:  # NaN
            out[i, :] = np.nan
            continue
        f[0] = zero
        acc = 0.0
        for b in range(n_bins):
            acc += np.float32(f[b + 1] / w_sum)
            f[b + 1] = min(acc, 1.0)
        p, last = 0, -1.0
        for j in range(n_out):
            uj = u[i, j]
            if uj < last:
                p = 0
            last = uj
            while p <= n_bins and f[p] <= uj:
                p += 1
            idx = min(max(p, 1), n_bins)
            c0, c1 = f[idx - 1], f[idx]
            frac = min(max((uj - c0) / max(c1 - c0, np.float32(1e-12)), zero), np.float32(1.0))
            out[i, j] = e[idx - 1] + frac * (e[idx] - e[idx - 1])
        for j in range(1, n_out):  # already in order for sorted u; kept sorted for any u
            v = out[i, j]
            q = j - 1
            while q >= 0 and out[i, q] > v:
                out[i, q + 1] = out[i, q]
                q -= 1
            out[i, q + 1] = v

"""Compiled CPU kernels of the hash-grid encoding (numba; imported lazily).

Work is split over levels, so parallel threads never write the same table rows and the
backward scatter-add needs no atomics.
"""

from __future__ import annotations

import numba
import numpy as np

P1 = np.uint64(2654435761)
P2 = np.uint64(805459861)


@numba.njit(inline="always")
def _row(cx: int, cy: int, cz: int, res: int, table_size: int) -> int:
    side = res + 1
    if side * side * side <= table_size:
        return np.int64(cx + cy * side + cz * side * side)
    h = np.uint64(cx) ^ (np.uint64(cy) * P1) ^ (np.uint64(cz) * P2)
    return np.int64(h & np.uint64(table_size - 1))


@numba.njit(parallel=True, fastmath=True, cache=True)
def _forward(x, table, resolutions, out):  # pragma: no cover - compiled
    n = x.shape[0]
    n_levels, table_size, n_feat = table.shape
    for level in numba.prange(n_levels):
        res = resolutions[level]
        for i in range(n):
            px = min(max(x[i, 0], 0.0), 1.0 - 1e-6) * res
            py = min(max(x[i, 1], 0.0), 1.0 - 1e-6) * res
            pz = min(max(x[i, 2], 0.0), 1.0 - 1e-6) * res
            bx, by, bz = int(np.floor(px)), int(np.floor(py)), int(np.floor(pz))
            fx, fy, fz = px - bx, py - by, pz - bz
            for f in range(n_feat):
                out[i, level * n_feat + f] = 0.0
            for c in range(8):
                ox, oy, oz = c & 1, (c >> 1) & 1, (c >> 2) & 1
                w = (fx if ox else 1.0 - fx) * (fy if oy else 1.0 - fy) * (fz if oz else 1.0 - fz)
                row = _row(bx + ox, by + oy, bz + oz, res, table_size)
                for f in range(n_feat):
                    out[i, level * n_feat + f] += w * table[level, row, f]


@numba.njit(parallel=True, fastmath=True, cache=True)
def _backward(x, grad_out, resolutions, grad_table):  # pragma: no cover - compiled
    n = x.shape[0]
    n_levels, table_size, n_feat = grad_table.shape
    for level in numba.prange(n_levels):
        res = resolutions[level]
        for i in range(n):
            px = min(max(x[i, 0], 0.0), 1.0 - 1e-6) * res
            py = min(max(x[i, 1], 0.0), 1.0 - 1e-6) * res
            pz = min(max(x[i, 2], 0.0), 1.0 - 1e-6) * res
            bx, by, bz = int(np.floor(px)), int(np.floor(py)), int(np.floor(pz))
            fx, fy, fz = px - bx, py - by, pz - bz
            for c in range(8):
                ox, oy, oz = c & 1, (c >> 1) & 1, (c >> 2) & 1
                w = (fx if ox else 1.0 - fx) * (fy if oy else 1.0 - fy) * (fz if oz else 1.0 - fz)
                row = _row(bx + ox, by + oy, bz + oz, res, table_size)
                for f in range(n_feat):
                    grad_table[level, row, f] += w * grad_out[i, level * n_feat + f]


def forward(x: np.ndarray, table: np.ndarray, resolutions: np.ndarray) -> np.ndarray:
    out = np.empty((x.shape[0], table.shape[0] * table.shape[2]), dtype=np.float32)
    _forward(x, table, resolutions, out)
    return out


def backward(x: np.ndarray, grad_out: np.ndarray, resolutions: np.ndarray, table_shape) -> np.ndarray:
    grad_table = np.zeros(tuple(table_shape), dtype=np.float32)
    _backward(x, grad_out, resolutions, grad_table)
    return grad_table

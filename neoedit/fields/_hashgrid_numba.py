"""Compiled CPU kernels of the hash-grid encoding (numba; imported lazily).

Forward runs in parallel over (level, chunk of points) jobs, so each thread streams one
level's table at a time (cache-friendly). Backward runs in parallel over levels, so threads
never write the same table rows and the scatter-add needs no atomics. The gradient with
respect to the points (pose refinement only) runs in parallel over points. Inputs must already be clamped to
[0, 1) (the wrapper does it), so truncation equals floor.
"""

from __future__ import annotations

import sys
import threading

import numba
import numpy as np

P1 = np.uint64(2654435761)
P2 = np.uint64(805459861)
FORWARD_CHUNK = 4096
"""Points per forward job (one level each)."""


@numba.njit(inline="always")
def _row(cx: int, cy: int, cz: int, res: int, table_size: int) -> np.int64:
    side = res + 1
    if side * side * side <= table_size:
        return np.int64(cx + cy * side + cz * side * side)
    h = np.uint64(cx) ^ (np.uint64(cy) * P1) ^ (np.uint64(cz) * P2)
    return np.int64(h & np.uint64(table_size - 1))


@numba.njit(parallel=True, fastmath=True, cache=True)
def _forward(x, table, resolutions, out, chunk):  # pragma: no cover - compiled
    n_levels, table_size, n_feat = table.shape
    n = x.shape[0]
    n_chunks = (n + chunk - 1) // chunk
    # one job = one level over one chunk of points, so a thread reads a single level's table
    # (2 MB at T = 2^18) while it works: 1.6x faster than looping over all levels per point
    for job in numba.prange(n_levels * n_chunks):
        level = job // n_chunks
        start = (job % n_chunks) * chunk
        res = resolutions[level]
        for i in range(start, min(n, start + chunk)):
            px, py, pz = x[i, 0] * res, x[i, 1] * res, x[i, 2] * res
            bx, by, bz = int(px), int(py), int(pz)
            fx, fy, fz = px - bx, py - by, pz - bz
            # accumulate in locals (up to 4 features): the compiler keeps them in registers
            a0 = a1 = a2 = a3 = np.float32(0.0)
            for c in range(8):
                ox, oy, oz = c & 1, (c >> 1) & 1, (c >> 2) & 1
                w = (fx if ox else 1.0 - fx) * (fy if oy else 1.0 - fy) * (fz if oz else 1.0 - fz)
                row = _row(bx + ox, by + oy, bz + oz, res, table_size)
                a0 += w * table[level, row, 0]
                if n_feat > 1:
                    a1 += w * table[level, row, 1]
                if n_feat > 2:
                    a2 += w * table[level, row, 2]
                if n_feat > 3:
                    a3 += w * table[level, row, 3]
            out[i, level, 0] = a0
            if n_feat > 1:
                out[i, level, 1] = a1
            if n_feat > 2:
                out[i, level, 2] = a2
            if n_feat > 3:
                out[i, level, 3] = a3


@numba.njit(parallel=True, fastmath=True, cache=True)
def _backward(x, grad_out, resolutions, grad_table):  # pragma: no cover - compiled
    n_levels, table_size, n_feat = grad_table.shape
    for level in numba.prange(n_levels):
        res = resolutions[level]
        for i in range(x.shape[0]):
            px, py, pz = x[i, 0] * res, x[i, 1] * res, x[i, 2] * res
            bx, by, bz = int(px), int(py), int(pz)
            fx, fy, fz = px - bx, py - by, pz - bz
            for c in range(8):
                ox, oy, oz = c & 1, (c >> 1) & 1, (c >> 2) & 1
                w = (fx if ox else 1.0 - fx) * (fy if oy else 1.0 - fy) * (fz if oz else 1.0 - fz)
                row = _row(bx + ox, by + oy, bz + oz, res, table_size)
                for f in range(n_feat):
                    grad_table[level, row, f] += w * grad_out[level, i, f]


@numba.njit(parallel=True, fastmath=True, cache=True)
def _backward_x(x, table, grad_out, resolutions, grad_x):  # pragma: no cover - compiled
    n_levels, table_size, n_feat = table.shape
    for i in numba.prange(x.shape[0]):
        g0 = g1 = g2 = np.float32(0.0)
        for level in range(n_levels):
            res = resolutions[level]
            px, py, pz = x[i, 0] * res, x[i, 1] * res, x[i, 2] * res
            bx, by, bz = int(px), int(py), int(pz)
            fx, fy, fz = px - bx, py - by, pz - bz
            for c in range(8):
                ox, oy, oz = c & 1, (c >> 1) & 1, (c >> 2) & 1
                wx, wy, wz = (
                    (fx if ox else 1.0 - fx),
                    (fy if oy else 1.0 - fy),
                    (fz if oz else 1.0 - fz),
                )
                row = _row(bx + ox, by + oy, bz + oz, res, table_size)
                dot = np.float32(0.0)  # the output gradient . this corner's features
                for f in range(n_feat):
                    dot += grad_out[level, i, f] * table[level, row, f]
                dot *= res  # d(frac)/dx
                g0 += dot * (1.0 if ox else -1.0) * wy * wz
                g1 += dot * wx * (1.0 if oy else -1.0) * wz
                g2 += dot * wx * wy * (1.0 if oz else -1.0)
        grad_x[i, 0], grad_x[i, 1], grad_x[i, 2] = g0, g1, g2


def backward_x(
    x: np.ndarray, table: np.ndarray, grad_out: np.ndarray, resolutions: np.ndarray
) -> np.ndarray:
    """Gradient (N, 3) of the loss with respect to the points x (N, 3), from the output
    gradient laid out level-major (L, N, F): the trilinear weights' derivatives times the
    corners' features (what a camera's pose correction learns from)."""
    grad_x = np.empty((x.shape[0], 3), dtype=np.float32)
    _backward_x(x, table, grad_out, resolutions, grad_x)
    return grad_x


def forward(x: np.ndarray, table: np.ndarray, resolutions: np.ndarray) -> np.ndarray:
    """Features (N, L, F) of points x (N, 3) clamped to [0, 1); F is at most 4."""
    if table.shape[2] > 4:
        raise ValueError("the numba hash-grid kernel supports at most 4 features per level")
    out = np.empty((x.shape[0], table.shape[0], table.shape[2]), dtype=np.float32)
    _forward(x, table, resolutions, out, FORWARD_CHUNK)
    return out


_GRAD_BUFFERS: dict[tuple[int, ...], list[np.ndarray]] = {}
"""Table-gradient buffers kept between backward passes, by shape (see :func:`backward`)."""
_MAX_BUFFERS = 4
_POOL_LOCK = threading.Lock()


def _references(pool: list[np.ndarray], i: int) -> int:
    """References to ``pool[i]`` as counted from here (compared with :data:`_UNUSED`)."""
    return sys.getrefcount(pool[i])


_UNUSED = _references([np.empty(0)], 0)
"""What :func:`_references` counts for an array only a pool list holds (measured, not
assumed: the count's details differ between Python versions)."""


def _free_buffer(shape: tuple[int, ...]) -> np.ndarray:
    """A (L, T, F) float32 buffer no tensor uses any more, reused when one is free.

    A fresh 33 MB array (T = 2^18) is mapped page by page as it is first written: those
    page faults cost as much as the scatter itself. The gradient handed to autograd wraps
    the array without a copy (``torch.from_numpy``) and becomes the parameter's ``.grad``;
    that storage holds a reference to the array until the gradient is dropped
    (``zero_grad(set_to_none=True)``). So an array whose only references are this pool's is
    free: reusing it never overwrites a gradient that is still alive (accumulation over
    several backward passes, or two encodings of one shape in one pass, get other arrays)."""
    with _POOL_LOCK:  # the caller's reference exists before another thread looks
        pool = _GRAD_BUFFERS.setdefault(shape, [])
        for i in range(len(pool)):
            if _references(pool, i) <= _UNUSED:
                return pool[i]
        buf = np.empty(shape, dtype=np.float32)
        if len(pool) < _MAX_BUFFERS:
            pool.append(buf)
        return buf


def backward(
    x: np.ndarray, grad_out: np.ndarray, resolutions: np.ndarray, table_shape
) -> np.ndarray:
    """Table gradient (L, T, F) from the output gradient laid out level-major (L, N, F).

    The result may be a buffer of an earlier call whose gradient is no longer referenced
    (:func:`_free_buffer`); it is zeroed here in one sequential pass before the scatter."""
    grad_table = _free_buffer(tuple(int(s) for s in table_shape))
    grad_table.fill(0.0)
    _backward(x, grad_out, resolutions, grad_table)
    return grad_table

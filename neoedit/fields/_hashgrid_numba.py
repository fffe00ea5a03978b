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
def _corners(px, py, pz, res, table_size):  # pragma: no cover - compiled
    """The 8 table rows, then their 8 trilinear weights, of a point scaled to the level's
    grid (px, py, pz; float32); corner c = x-bit | y-bit << 1 | z-bit << 2. Every kernel
    finds its corners here, in float32, so forward and backward agree on the cell of a
    point that lies within rounding of a cell face. The y and z hash terms are shared by
    the corners that share them and no float64 is mixed in (measured against hashing each
    corner in float64: forward 10-15 %, backward 25-40 % faster; a default training step
    8 %)."""
    bx, by, bz = int(px), int(py), int(pz)
    fx, fy, fz = px - np.float32(bx), py - np.float32(by), pz - np.float32(bz)  # float32
    one = np.float32(1.0)
    gx, gy, gz = one - fx, one - fy, one - fz
    side = res + 1
    if side * side * side <= table_size:  # a dense level: one row per grid vertex
        r0 = np.int64(bx + by * side + bz * side * side)
        r1, r2, r4 = r0 + 1, r0 + side, r0 + side * side
        r3, r5, r6 = r2 + 1, r4 + 1, r4 + side
        r7 = r6 + 1
    else:
        mask = np.uint64(table_size - 1)
        ux0, ux1 = np.uint64(bx), np.uint64(bx + 1)
        hy0, hy1 = np.uint64(by) * P1, np.uint64(by + 1) * P1
        hz0, hz1 = np.uint64(bz) * P2, np.uint64(bz + 1) * P2
        a, b, c, d = hy0 ^ hz0, hy1 ^ hz0, hy0 ^ hz1, hy1 ^ hz1
        r0, r1 = np.int64((ux0 ^ a) & mask), np.int64((ux1 ^ a) & mask)
        r2, r3 = np.int64((ux0 ^ b) & mask), np.int64((ux1 ^ b) & mask)
        r4, r5 = np.int64((ux0 ^ c) & mask), np.int64((ux1 ^ c) & mask)
        r6, r7 = np.int64((ux0 ^ d) & mask), np.int64((ux1 ^ d) & mask)
    gyz, fyz, gyf, fyf = gy * gz, fy * gz, gy * fz, fy * fz
    return (
        r0, r1, r2, r3, r4, r5, r6, r7,
        gx * gyz, fx * gyz, gx * fyz, fx * fyz, gx * gyf, fx * gyf, gx * fyf, fx * fyf,
    )  # fmt: skip


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
        fres = np.float32(res)
        for i in range(start, min(n, start + chunk)):
            r0, r1, r2, r3, r4, r5, r6, r7, w0, w1, w2, w3, w4, w5, w6, w7 = _corners(
                x[i, 0] * fres, x[i, 1] * fres, x[i, 2] * fres, res, table_size
            )
            for f in range(n_feat):
                out[i, level, f] = (
                    w0 * table[level, r0, f] + w1 * table[level, r1, f]
                    + w2 * table[level, r2, f] + w3 * table[level, r3, f]
                    + w4 * table[level, r4, f] + w5 * table[level, r5, f]
                    + w6 * table[level, r6, f] + w7 * table[level, r7, f]
                )  # fmt: skip


@numba.njit(parallel=True, fastmath=True, cache=True)
def _backward(x, grad_out, resolutions, grad_table):  # pragma: no cover - compiled
    n_levels, table_size, n_feat = grad_table.shape
    for level in numba.prange(n_levels):
        for row in range(table_size):  # zeroed by the thread that scatters into the level
            for f in range(n_feat):
                grad_table[level, row, f] = 0.0
        res = resolutions[level]
        fres = np.float32(res)
        for i in range(x.shape[0]):
            r0, r1, r2, r3, r4, r5, r6, r7, w0, w1, w2, w3, w4, w5, w6, w7 = _corners(
                x[i, 0] * fres, x[i, 1] * fres, x[i, 2] * fres, res, table_size
            )
            for f in range(n_feat):
                g = grad_out[level, i, f]
                grad_table[level, r0, f] += w0 * g
                grad_table[level, r1, f] += w1 * g
                grad_table[level, r2, f] += w2 * g
                grad_table[level, r3, f] += w3 * g
                grad_table[level, r4, f] += w4 * g
                grad_table[level, r5, f] += w5 * g
                grad_table[level, r6, f] += w6 * g
                grad_table[level, r7, f] += w7 * g


@numba.njit(parallel=True, fastmath=True, cache=True)
def _backward_x(x, table, grad_out, resolutions, grad_x):  # pragma: no cover - compiled
    n_levels, table_size, n_feat = table.shape
    for i in numba.prange(x.shape[0]):
        g0 = g1 = g2 = np.float32(0.0)
        for level in range(n_levels):
            res = resolutions[level]
            fres = np.float32(res)
            px, py, pz = x[i, 0] * fres, x[i, 1] * fres, x[i, 2] * fres
            fx = px - np.float32(int(px))
            fy = py - np.float32(int(py))
            fz = pz - np.float32(int(pz))
            rows = _corners(px, py, pz, res, table_size)[:8]
            one = np.float32(1.0)
            for c in range(8):
                ox, oy, oz = c & 1, (c >> 1) & 1, (c >> 2) & 1
                wx = fx if ox else one - fx
                wy = fy if oy else one - fy
                wz = fz if oz else one - fz
                dot = np.float32(0.0)  # the output gradient . this corner's features
                for f in range(n_feat):
                    dot += grad_out[level, i, f] * table[level, rows[c], f]
                dot *= fres  # d(frac)/dx
                g0 += dot * (one if ox else -one) * wy * wz
                g1 += dot * wx * (one if oy else -one) * wz
                g2 += dot * wx * wy * (one if oz else -one)
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
    """Features (N, L, F) of points x (N, 3) clamped to [0, 1)."""
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
    (:func:`_free_buffer`); the kernel zeroes each level before its scatter (in parallel,
    while the level is in cache)."""
    grad_table = _free_buffer(tuple(int(s) for s in table_shape))
    _backward(x, grad_out, resolutions, grad_table)
    return grad_table

"""The height of a horizontal surface among scattered heights: where a table or a shelf is.

A table seen around an object's footprint gives many points within a few millimetres of one
height; the object's own base, fog above the table, or a coaster's rim spread theirs over
many heights. :func:`surface_level` takes the highest band where the points crowd (at least
half as many as in the most crowded band) and returns the densest height within it.
"""

from __future__ import annotations

import numpy as np

LEVEL_BIN_M = 0.005
"""Height bins in which a surface is looked for."""


def surface_level(heights: np.ndarray, bin_m: float = LEVEL_BIN_M) -> float:
    """The densest height of the highest crowded band of ``heights`` (K,) [m], K >= 1: the
    median of the band's points, moved to the median of those within half a bin of it until
    it settles (a median over the band and its neighbours took in the fog above a table)."""
    heights = np.asarray(heights, dtype=np.float64)
    counts, edges = np.histogram(heights, bins=max(int(np.ptp(heights) / bin_m), 1))
    k = int(np.nonzero(counts >= 0.5 * counts.max())[0][-1])
    z = float(np.median(heights[(heights >= edges[k]) & (heights <= edges[k + 1])]))
    half = 0.5 * float(edges[k + 1] - edges[k])
    for _ in range(4):
        window = heights[np.abs(heights - z) <= half]
        if not len(window):
            break
        z = float(np.median(window))
    return z

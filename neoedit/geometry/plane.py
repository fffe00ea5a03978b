"""Dominant plane of a point cloud (RANSAC + least-squares refit)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Plane:
    """Points x with ``normal . x = offset`` (unit normal)."""

    normal: np.ndarray  # (3,)
    offset: float
    inliers: np.ndarray  # (P,) bool mask over the points it was fitted to

    def signed_distance(self, points: np.ndarray) -> np.ndarray:
        return np.asarray(points, dtype=np.float64) @ self.normal - self.offset

    def flipped(self) -> Plane:
        return Plane(-self.normal, -self.offset, self.inliers)


def fit_plane(
    points: np.ndarray,
    inlier_distance: float,
    iterations: int = 512,
    seed: int = 0,
    max_points: int = 20000,
    near_normal: np.ndarray | None = None,
    max_angle_deg: float = 90.0,
) -> Plane | None:
    """The plane with the most points within ``inlier_distance`` (RANSAC over point triples),
    refitted to its inliers by least squares; None with fewer than 3 points. With
    ``near_normal``, only planes whose normal is within ``max_angle_deg`` of it count (a
    floor, not the wall behind it)."""
    pts = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    if len(pts) < 3:
        return None
    rng = np.random.default_rng(seed)
    sample = pts[rng.choice(len(pts), min(len(pts), max_points), replace=False)]
    triples = rng.integers(0, len(sample), size=(iterations, 3))
    a, b, c = sample[triples[:, 0]], sample[triples[:, 1]], sample[triples[:, 2]]
    normals = np.cross(b - a, c - a)
    norms = np.linalg.norm(normals, axis=1)
    ok = norms > 1e-12
    if not ok.any():
        return None
    normals, a = normals[ok] / norms[ok, None], a[ok]
    if near_normal is not None:
        ref = np.asarray(near_normal, dtype=np.float64) / np.linalg.norm(near_normal)
        ok = np.abs(normals @ ref) >= np.cos(np.radians(max_angle_deg))
        if not ok.any():
            return None
        normals, a = normals[ok], a[ok]
    counts = [
        (np.abs((sample - p) @ n) < inlier_distance).sum() for n, p in zip(normals, a, strict=True)
    ]
    best = int(np.argmax(counts))
    n, p = normals[best], a[best]
    inliers = np.abs((pts - p) @ n) < inlier_distance
    if inliers.sum() >= 3:  # least-squares refit: the normal is the smallest principal axis
        q = pts[inliers]
        centre = q.mean(0)
        n = np.linalg.svd(q - centre, full_matrices=False)[2][-1]
        p = centre
        inliers = np.abs((pts - p) @ n) < inlier_distance
    return Plane(n / np.linalg.norm(n), float(n @ p) / float(np.linalg.norm(n)), inliers)

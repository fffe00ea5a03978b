"""Is a reconstruction one consistent piece? Checks consecutive photos of a capture.

A walk around an object gives photos whose neighbours in name order overlap. When
structure-from-motion breaks such a walk into pieces and folds them onto each other (a
repeating print or floor tiles can do that), consecutive photos across a break share
(almost) no sparse points, yet their images still match each other well -- only not under
the model's poses. So a break is a consecutive pair that

1. shares few sparse points (fewer than ``min_shared`` and a small fraction of the median;
   with no sparse points (LLFF) every pair is examined), and
2. has enough SIFT matches that a fundamental matrix explains (the photos do overlap), and
3. whose matches lie far from the epipolar lines the model's poses predict (median distance
   above ``max_epipolar_px``).

Pairs that do not overlap at all (an unordered photo collection) are never called breaks.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from neoedit.data.capture import Capture, read_photo


@dataclass
class PieceCheckConfig:
    min_shared: int = 10
    """Consecutive photos sharing fewer sparse points than this (and than
    ``shared_fraction`` of the median) are examined with feature matches."""
    shared_fraction: float = 0.1
    match_width_px: int = 800
    """Photos are matched at this width (SIFT)."""
    min_matches: int = 15
    """Fewer fundamental-matrix inliers than this: the photos do not overlap (no break)."""
    max_epipolar_px: float = 10.0
    """Median distance of the matches to the epipolar lines of the model's poses, in pixels
    at ``match_width_px``, above which the poses contradict the photos. Consistent pairs
    measure under 1 px with a lens model, up to ~5 px when the lens distortion is unknown
    (LLFF); pairs across a folded break measure tens of pixels."""


@dataclass
class PairCheck:
    first: int
    shared_points: int
    matches: int
    epipolar_px: float | None
    """Median epipolar distance under the model's poses (None: too few matches to tell)."""

    def is_break(self, cfg: PieceCheckConfig) -> bool:
        return self.epipolar_px is not None and self.epipolar_px > cfg.max_epipolar_px


def _read_gray(capture: Capture, i: int, width: int):  # noqa: ANN202 (cv2 array, scale)
    import cv2

    image = read_photo(capture.image_dir / capture.names[i], grey=True)
    scale = min(1.0, width / image.shape[1])
    if scale < 1.0:
        image = cv2.resize(image, None, fx=scale, fy=scale, interpolation=cv2.INTER_AREA)
    return image, scale


def _undistorted_points(capture: Capture, i: int, uv: np.ndarray) -> np.ndarray:
    """Pixel coordinates (full resolution) -> normalised camera coordinates (x/z, y/z)."""
    import cv2

    lens = capture.lenses[i]
    k = lens.matrix()
    k[:2, 2] -= 0.5  # COLMAP's principal point -> OpenCV's pixel-centre convention
    pts = cv2.undistortPoints(uv.reshape(-1, 1, 2), k, lens.distortion())
    return pts.reshape(-1, 2)


def _relative_essential(capture: Capture, i: int, j: int) -> np.ndarray:
    """E with x_j^T E x_i = 0 for normalised OpenCV camera coordinates of photos i, j."""
    flip = np.diag([1.0, -1.0, -1.0, 1.0])
    w2c_i = np.linalg.inv(capture.camera_to_world[i] @ flip)
    w2c_j = np.linalg.inv(capture.camera_to_world[j] @ flip)
    rel = w2c_j @ np.linalg.inv(w2c_i)
    r, t = rel[:3, :3], rel[:3, 3]
    tx = np.array([[0, -t[2], t[1]], [t[2], 0, -t[0]], [-t[1], t[0], 0]])
    return tx @ r


def check_pair(capture: Capture, i: int, shared: int, cfg: PieceCheckConfig) -> PairCheck:
    """Match photos i and i+1 and measure their epipolar distance under the model."""
    import cv2

    j = i + 1
    (img_i, s_i), (img_j, s_j) = (_read_gray(capture, k, cfg.match_width_px) for k in (i, j))
    sift = cv2.SIFT_create(nfeatures=3000)  # type: ignore[attr-defined]
    kp_i, des_i = sift.detectAndCompute(img_i, None)
    kp_j, des_j = sift.detectAndCompute(img_j, None)
    if des_i is None or des_j is None or len(kp_i) < 8 or len(kp_j) < 8:
        return PairCheck(i, shared, 0, None)
    pairs = cv2.BFMatcher().knnMatch(des_i, des_j, k=2)
    good = [m[0] for m in pairs if len(m) == 2 and m[0].distance < 0.75 * m[1].distance]
    if len(good) < cfg.min_matches:
        return PairCheck(i, shared, len(good), None)
    # OpenCV keypoints (pixel centres on integers) at the matching scale -> full resolution
    uv_i = (np.array([kp_i[m.queryIdx].pt for m in good], dtype=np.float64) + 0.5) / s_i - 0.5
    uv_j = (np.array([kp_j[m.trainIdx].pt for m in good], dtype=np.float64) + 0.5) / s_j - 0.5
    _, inlier = cv2.findFundamentalMat(uv_i, uv_j, cv2.FM_RANSAC, 1.0 / s_i, 0.999)
    if inlier is None or int(inlier.sum()) < cfg.min_matches:
        return PairCheck(i, shared, 0 if inlier is None else int(inlier.sum()), None)
    keep = inlier.ravel().astype(bool)
    x_i = _undistorted_points(capture, i, uv_i[keep])
    x_j = _undistorted_points(capture, j, uv_j[keep])
    e = _relative_essential(capture, i, j)
    h_i = np.c_[x_i, np.ones(len(x_i))]
    h_j = np.c_[x_j, np.ones(len(x_j))]
    lines = h_i @ e.T  # epipolar lines in photo j (normalised coordinates)
    dist = np.abs((h_j * lines).sum(1)) / np.linalg.norm(lines[:, :2], axis=1).clip(1e-12)
    focal_px = capture.lenses[j].matrix()[0, 0] * s_j
    return PairCheck(i, shared, int(keep.sum()), float(np.median(dist) * focal_px))


def find_pieces(
    capture: Capture, cfg: PieceCheckConfig | None = None
) -> tuple[list[np.ndarray], list[PairCheck]]:
    """Index arrays of the consistent pieces (in name order) and the pairs examined."""
    cfg = cfg or PieceCheckConfig()
    n = len(capture)
    if capture.point_tracks:
        shared = capture.shared_with_next()
        limit = min(cfg.min_shared, cfg.shared_fraction * float(np.median(shared)))
        suspects = [i for i in range(n - 1) if shared[i] < max(limit, 1)]
    else:
        shared = np.zeros(n - 1, np.int64)
        suspects = list(range(n - 1))
    checks = [check_pair(capture, i, int(shared[i]), cfg) for i in suspects]
    cuts = [c.first + 1 for c in checks if c.is_break(cfg)]
    pieces = np.split(np.arange(n), cuts)
    return pieces, checks

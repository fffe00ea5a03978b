"""Metrics on rendered vs ground-truth views, each restricted to an optional pixel mask.

PSNR and SSIM (scikit-image) on RGB in [0,1]; depth RMSE in metres on pixels with ground
truth depth; photometric reprojection error E_rep (Engel et al. 2014): one rendered view is
warped into another with its rendered depth and the poses, and the mean absolute
photometric difference is taken where the warp lands inside the other image.
"""

from __future__ import annotations

import cv2
import numpy as np
from skimage.metrics import structural_similarity

from neoedit.cameras import Cameras


def psnr(pred: np.ndarray, gt: np.ndarray, mask: np.ndarray | None = None) -> float:
    """PSNR [dB] of images (H,W,3) in [0,1] over ``mask`` (H,W) (all pixels if None)."""
    err = (pred.astype(np.float64) - gt.astype(np.float64)) ** 2
    mse = err.mean() if mask is None else err[mask].mean() if mask.any() else np.nan
    return float(-10.0 * np.log10(max(mse, 1e-12))) if np.isfinite(mse) else float("nan")


def ssim(pred: np.ndarray, gt: np.ndarray, mask: np.ndarray | None = None) -> float:
    """Mean SSIM (7x7 Gaussian-free window, scikit-image) over ``mask``."""
    _, smap = structural_similarity(gt, pred, channel_axis=-1, data_range=1.0, full=True)
    smap = smap.mean(-1)
    if mask is None:
        return float(smap.mean())
    return float(smap[mask].mean()) if mask.any() else float("nan")


def depth_rmse_m(pred_z_m: np.ndarray, gt_z_m: np.ndarray, mask: np.ndarray | None = None) -> float:
    """RMSE [m] of z-depth where ground truth exists (gt > 0) and inside ``mask``."""
    valid = gt_z_m > 0
    if mask is not None:
        valid &= mask
    if not valid.any():
        return float("nan")
    return float(np.sqrt(np.mean((pred_z_m[valid] - gt_z_m[valid]) ** 2)))


def reprojection_error(
    rgb_i: np.ndarray,
    depth_z_i: np.ndarray,
    rgb_j: np.ndarray,
    cameras: Cameras,
    i: int,
    j: int,
    mask_i: np.ndarray | None = None,
) -> tuple[float, int]:
    """Mean |I_i(p) - I_j(pi_j(D_i(p)))| over pixels of view i whose warp lands in view j.

    Returns (error, number of pixels used)."""
    pts = cameras.backproject_depth(i, depth_z_i)
    uv, z = cameras.project(j, pts.reshape(-1, 3))
    h, w = depth_z_i.shape
    map_x = (uv[:, 0] - 0.5).reshape(h, w).astype(np.float32)  # pixel centres -> array coordinates
    map_y = (uv[:, 1] - 0.5).reshape(h, w).astype(np.float32)
    valid = (depth_z_i > 0) & (z.reshape(h, w) > 0)
    valid &= (map_x >= 0) & (map_x <= w - 1) & (map_y >= 0) & (map_y <= h - 1)
    if mask_i is not None:
        valid &= mask_i
    if not valid.any():
        return float("nan"), 0
    warped = cv2.remap(
        rgb_j.astype(np.float32),
        map_x,
        map_y,
        interpolation=cv2.INTER_LINEAR,
        borderMode=cv2.BORDER_REPLICATE,
    )
    err = np.abs(rgb_i.astype(np.float32) - warped).mean(-1)
    return float(err[valid].mean()), int(valid.sum())


class ObjectColours:
    """Mean colour of each labelled object over several views, rendered vs ground truth
    (issue 39: a field that renders a grey arm cream or a black patch dark red). Pixels on
    an object's silhouette edge are left out (``erode_px``): there a few pixels of
    misalignment would count as colour error."""

    def __init__(self, names: dict[int, str], erode_px: int = 2):
        self.names, self.erode_px = names, erode_px
        self.sums: dict[int, np.ndarray] = {}

    def add(self, pred: np.ndarray, gt: np.ndarray, labels: np.ndarray) -> None:
        """One view: images (H,W,3) in [0,1] and its instance labels (H,W)."""
        kernel = np.ones((2 * self.erode_px + 1,) * 2, np.uint8)
        for obj in self.names:
            inside = cv2.erode((labels == obj).astype(np.uint8), kernel) > 0
            if not inside.any():
                continue
            s = self.sums.setdefault(obj, np.zeros(7))
            s[:3] += pred[inside].sum(0)
            s[3:6] += gt[inside].sum(0)
            s[6] += inside.sum()

    def result(self) -> dict[str, dict[str, float | list[float]]]:
        """name -> render / truth mean colour (0-255) and the worst channel's error."""
        out = {}
        for obj, s in sorted(self.sums.items()):
            render, truth = 255 * s[:3] / s[6], 255 * s[3:6] / s[6]
            out[self.names[obj]] = {
                "render": np.round(render, 1).tolist(),
                "truth": np.round(truth, 1).tolist(),
                "error": round(float(np.abs(render - truth).max()), 1),
                "pixels": int(s[6]),
            }
        return out

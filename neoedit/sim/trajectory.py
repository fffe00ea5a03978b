"""Camera trajectories of a scan: a robot-like upward spiral over a hemisphere for training
and a separate ring of held-out evaluation views (never used for training)."""

from __future__ import annotations

import numpy as np

from neoedit.cameras import look_at
from neoedit.sim.spec import ScanSpec


def _on_sphere(
    center: np.ndarray, radius_m: float, azimuth_deg: float, elevation_deg: float
) -> np.ndarray:
    az, el = np.deg2rad(azimuth_deg), np.deg2rad(elevation_deg)
    return center + radius_m * np.array(
        [np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)]
    )


def spiral_poses(scan: ScanSpec, center_m: np.ndarray) -> np.ndarray:
    """(n_train, 4, 4) camera-to-world poses looking at ``center_m``: the camera sweeps back
    and forth across ``azimuth_range_deg`` ``turns`` times while rising in elevation."""
    t = np.linspace(0.0, 1.0, scan.n_train)
    phase = scan.turns * t
    triangle = 1.0 - np.abs(np.mod(phase, 2.0) - 1.0)  # 0 -> 1 -> 0 ...
    lo, hi = scan.azimuth_range_deg
    az = lo + (hi - lo) * triangle
    el = scan.elevation_min_deg + (scan.elevation_max_deg - scan.elevation_min_deg) * t
    return np.stack(
        [
            look_at(_on_sphere(center_m, scan.radius_m, a, e), center_m)
            for a, e in zip(az, el, strict=True)
        ]
    )


def eval_ring_poses(scan: ScanSpec, center_m: np.ndarray) -> np.ndarray:
    """(n_eval, 4, 4) held-out poses on a ring, offset in azimuth from the spiral."""
    if scan.n_eval == 0:
        return np.zeros((0, 4, 4))
    lo, hi = scan.azimuth_range_deg
    az = lo + (np.arange(scan.n_eval) + 0.5) * (hi - lo) / scan.n_eval
    return np.stack(
        [
            look_at(_on_sphere(center_m, scan.eval_radius_m, a, scan.eval_elevation_deg), center_m)
            for a in az
        ]
    )


def intrinsics(scan: ScanSpec) -> dict[str, float]:
    """nerfstudio intrinsics (square pixels, principal point at the centre)."""
    fy = 0.5 * scan.height / np.tan(0.5 * np.deg2rad(scan.fov_y_deg))
    return {
        "fl_x": float(fy),
        "fl_y": float(fy),
        "cx": scan.width / 2.0,
        "cy": scan.height / 2.0,
        "w": scan.width,
        "h": scan.height,
    }

"""World frame of an imported capture: z up from the support plane, origin on that plane
under the object the cameras look at, metric scale, and a scene box.

Structure-from-motion returns poses in an arbitrary frame and scale. The edit boxes of
neoedit are yaw-only about z and its query and edit defaults are in metres, so an import
turns the model into a z-up metric frame:

* **up**: the normal of the dominant plane of the sparse points (RANSAC), turned towards
  the cameras; without points (LLFF) or without a dominant plane, the mean camera up.
* **origin**: the point the cameras' optical axes pass closest to (least squares),
  dropped onto the plane.
* **scale**: a given factor, or the metric median distance of the cameras to that point
  (``camera_distance_m``; when nothing is given it is *assumed*, and the dataset says so).
* **box**: horizontally the disc the cameras circle (or look into), vertically from just
  below the plane to above the highest sparse point inside it.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from neoedit.data.capture import Capture
from neoedit.errors import DataError
from neoedit.geometry.plane import fit_plane

ASSUMED_CAMERA_DISTANCE_M = 0.5


@dataclass
class OrientConfig:
    scale: float | None = None
    """Multiply the model's units by this to get metres (overrides ``camera_distance_m``)."""
    camera_distance_m: float | None = None
    """Known median distance of the cameras to the object they look at, in metres. Without
    it (and without ``scale``) 0.5 m is assumed: the scale is then only roughly metric."""
    aruco_size_m: float | None = None
    """Side length of the ArUco markers lying on the table, in metres: scale, up, origin
    and x axis then come from the markers (the paper's registration; see
    :mod:`neoedit.data.markers`), and every scan of the same table gets the same frame."""
    aruco_dict: str = "4X4_50"
    """OpenCV ArUco dictionary of the markers."""
    plane_inlier_fraction: float = 0.01
    """Plane inlier distance as a fraction of the median camera distance."""
    min_plane_share: float = 0.15
    """The plane must hold this share of the sparse points to define up."""
    max_plane_tilt_deg: float = 25.0
    """The support plane's normal is within this angle of the cameras' up (the normal of the
    ring they stand on; so a wall with many points behind the object is not taken for the
    floor)."""
    max_plane_tilt_forward_deg: float = 60.0
    """The same limit when up is only the cameras' mean up axis (no ring: a forward-facing
    capture), which leans back by as much as the photos look down (spinnerf_1: 46 deg); a
    wall facing the cameras is still ~90 deg from it."""
    box_extent: float = 1.5
    """Horizontal half-size of the box as a multiple of the cameras' median distance from
    the vertical through the origin (beyond it, what the photos see is left to the learned
    background)."""
    box_margin: float = 0.15
    """Box growth on each side, as a fraction of the median camera distance."""


@dataclass
class Orientation:
    transform: np.ndarray
    """(4,4) similarity: model coordinates -> metric world (z up)."""
    scale: float
    scale_source: str
    up_source: str
    aabb_m: np.ndarray
    """(2,3) scene box in the new frame."""
    notes: list[str] = field(default_factory=list)

    def to_dict(self) -> dict:
        return {
            "transform": np.round(self.transform, 9).tolist(),
            "scale": self.scale,
            "scale_source": self.scale_source,
            "up_source": self.up_source,
            "notes": self.notes,
        }


NOT_LEVELLED = "mean camera up"
"""The ``up_source`` of an import that found nothing better than the cameras' mean up."""


def levelled_at_import(meta: Any) -> bool:
    """Whether a dataset file's contents ``meta`` (a parsed transforms.json) say that ``neo
    import`` / ``neo process`` levelled it on something measured (a support plane, a marker
    plane, the ring of camera centres): then its +z is that up. False for anything else."""
    try:
        source = meta["neoedit_import"]["orientation"]["up_source"]
    except (KeyError, TypeError):
        return False
    # an import without a plane writes "mean camera up; <how the floor was placed>"
    return isinstance(source, str) and source.split(";")[0].strip() != NOT_LEVELLED


def look_centre(capture: Capture) -> np.ndarray:
    """The point the cameras look at: the point closest (least squares) to all optical axes
    when it lies in front of nearly all cameras (a walk around an object); for a forward-
    facing capture, whose axes are nearly parallel, a point straight ahead of the mean camera
    at the scene's depth (the LLFF bounds, else the median depth of the sparse points). A
    least-squares point of a forward-facing capture whose median depth lies outside the
    content's near..far range (LLFF bounds, or the sparse points') is moved along the mean
    view into it."""
    c2w = capture.camera_to_world
    origins = c2w[:, :3, 3]
    dirs = -c2w[:, :3, 2]  # OpenGL: the camera looks down -z
    dirs = dirs / np.linalg.norm(dirs, axis=1, keepdims=True)
    proj = np.eye(3)[None] - dirs[:, :, None] * dirs[:, None, :]
    a = proj.sum(0)
    b = (proj @ origins[:, :, None]).sum(0)[:, 0]
    ahead = dirs.mean(0) / max(float(np.linalg.norm(dirs.mean(0))), 1e-12)
    if np.linalg.cond(a) < 1e6:
        point = np.linalg.solve(a, b)
        depth = ((point - origins) * dirs).sum(1)
        if (depth > 0).mean() >= 0.9:
            content = _content_depths(capture, origins.mean(0), ahead, dirs)
            if content is None:
                return point
            # nearly parallel axes (a forward-facing capture) can meet closer than anything
            # the photos see, or beyond it: the point is then moved along the view to the
            # nearest (farthest) depth of the scene's content, each depth measured as the
            # content's is (per camera for bounds, from the mean camera for points)
            near, far, from_mean = content
            median = (
                float((point - origins.mean(0)) @ ahead) if from_mean else float(np.median(depth))
            )
            if near <= median <= far:
                return point
            return origins.mean(0) + ahead * float(np.clip(median, near, far))
    if capture.bounds is not None:
        depth = float(np.median(capture.bounds.mean(1)))
    elif len(capture.points):
        depth = float(np.median((capture.points - origins.mean(0)) @ ahead))
    else:
        depth = float(np.median(np.linalg.norm(origins - origins.mean(0), axis=1))) or 1.0
    return origins.mean(0) + ahead * max(depth, 1e-6)


FORWARD_FACING_DEG = 20.0
"""A capture faces one way when every view is within this angle of the mean view."""


def _content_depths(
    capture: Capture, origin: np.ndarray, ahead: np.ndarray, dirs: np.ndarray
) -> tuple[float, float, bool] | None:
    """(near, far, measured from the mean camera) depth of what a forward-facing capture
    sees: its LLFF bounds (per camera), else its sparse points' 5th..95th depth percentiles
    from the mean camera along the mean view (photos processed by SfM); None for a capture
    whose views spread wider (an arc or a walk around an object)."""
    if capture.bounds is not None:
        near, far = np.median(capture.bounds, axis=0)
        return float(near), float(far), False
    spread = np.degrees(np.arccos(np.clip(dirs @ ahead, -1.0, 1.0))).max()
    if len(capture.points) < 10 or spread > FORWARD_FACING_DEG:
        return None
    near, far = np.percentile((capture.points - origin) @ ahead, [5, 95])
    return (float(near), float(far), True) if near > 0 else None


MIN_PLANE_POINTS = 50
"""Sparse points near the look centre a support plane is fitted to, at least."""


def _camera_up(capture: Capture) -> tuple[np.ndarray, str]:
    """Up from the cameras alone: the normal of the plane of their centres when they circle
    the object (a walk around it at one height), else their mean up axis."""
    cam_up = capture.camera_to_world[:, :3, 1].mean(0)
    cam_up /= max(float(np.linalg.norm(cam_up)), 1e-12)
    centres = capture.centres - capture.centres.mean(0)
    if len(centres) >= 5:
        _, spread, axes = np.linalg.svd(centres, full_matrices=False)
        ring = axes[2] if axes[2] @ cam_up >= 0 else -axes[2]
        if spread[2] < 0.35 * spread[1] and ring @ cam_up > np.cos(np.radians(60)):
            return ring, "plane of the camera centres"
    return cam_up, NOT_LEVELLED


def _support(
    capture: Capture, centre: np.ndarray, distance: float, cfg: OrientConfig
) -> tuple[np.ndarray, float, str]:
    """(up, height of the support surface along up, how up was found)."""
    ref, ref_source = _camera_up(capture)
    pts = capture.points[np.linalg.norm(capture.points - centre, axis=1) < 1.5 * distance]
    if len(pts) >= MIN_PLANE_POINTS:
        ring = ref_source.startswith("plane")
        plane = fit_plane(
            pts,
            cfg.plane_inlier_fraction * distance,
            near_normal=ref,
            max_angle_deg=cfg.max_plane_tilt_deg if ring else cfg.max_plane_tilt_forward_deg,
        )
        if plane is not None and plane.inliers.mean() >= cfg.min_plane_share:
            plane = plane if plane.normal @ ref > 0 else plane.flipped()
            if (plane.signed_distance(capture.centres) > 0).mean() >= 0.9:
                return plane.normal, plane.offset, "support plane of the sparse points"
    if len(pts) >= 10:  # the lowest points near the object: its foot on the support
        return ref, float(np.percentile(pts @ ref, 2)), ref_source + "; floor at the lowest points"
    return ref, float(centre @ ref), ref_source + "; no points: origin at the look centre"


def _frame(up: np.ndarray, cam_axes: np.ndarray) -> np.ndarray:
    """Rotation whose rows are the new x, y, z axes (z = up, x = the mean camera right
    projected on the plane)."""
    x = cam_axes - (cam_axes @ up) * up
    if np.linalg.norm(x) < 1e-6:
        x = np.cross(up, [1.0, 0.0, 0.0]) if abs(up[0]) < 0.9 else np.cross(up, [0.0, 1.0, 0.0])
    x /= np.linalg.norm(x)
    return np.stack([x, np.cross(up, x), up])


def orient(capture: Capture, cfg: OrientConfig | None = None) -> Orientation:
    """The metric z-up frame of ``capture`` and its scene box."""
    cfg = cfg or OrientConfig()
    centre = look_centre(capture)
    distance = float(np.median(np.linalg.norm(capture.centres - centre, axis=1)))
    if not np.isfinite(distance) or distance <= 0:
        raise DataError(f"{capture.source}: the cameras have no common point to look at")
    if cfg.aruco_size_m is not None:
        return _marker_orientation(capture, distance, cfg)
    up, floor, up_source = _support(capture, centre, distance, cfg)
    origin = centre - (centre @ up - floor) * up
    rot = _frame(up, capture.camera_to_world[:, :3, 0].mean(0))
    if cfg.scale is not None:
        scale, source = cfg.scale, "given factor"
    elif cfg.camera_distance_m is not None:
        scale, source = (
            cfg.camera_distance_m / distance,
            f"camera distance {cfg.camera_distance_m} m (given)",
        )
    else:
        scale = ASSUMED_CAMERA_DISTANCE_M / distance
        source = f"ASSUMED: median camera distance {ASSUMED_CAMERA_DISTANCE_M} m"
    if not (np.isfinite(scale) and scale > 0):
        raise DataError(f"scale must be a positive number, got {scale!r}")
    transform = np.eye(4)
    transform[:3, :3] = scale * rot
    transform[:3, 3] = -scale * rot @ origin
    notes = (
        []
        if "support plane" in up_source
        else [f"no support plane in the points: up from the {up_source}"]
    )
    aabb = _box(capture, transform, scale * distance, len(capture.points) >= 10, cfg)
    return Orientation(transform, float(scale), source, up_source, aabb, notes)


def _marker_orientation(capture: Capture, distance: float, cfg: OrientConfig) -> Orientation:
    from neoedit.data.markers import capture_markers, marker_frame

    markers = capture_markers(capture, cfg.aruco_dict)
    transform, scale = marker_frame(markers, float(cfg.aruco_size_m or 0.0), capture.centres)
    notes = [f"ArUco markers {sorted(markers.corners)} ({cfg.aruco_dict}, {cfg.aruco_size_m} m)"]
    aabb = _box(capture, transform, scale * distance, len(capture.points) >= 10, cfg)
    source = f"ArUco markers, side {cfg.aruco_size_m} m"
    return Orientation(transform, scale, source, "ArUco marker plane", aabb, notes)


def _box(
    capture: Capture, transform: np.ndarray, distance_m: float, has_plane: bool, cfg: OrientConfig
) -> np.ndarray:
    cams = capture.centres @ transform[:3, :3].T + transform[:3, 3]
    radius = float(np.median(np.linalg.norm(cams[:, :2], axis=1)))
    margin = cfg.box_margin * distance_m
    half = max(cfg.box_extent * radius, 0.25 * distance_m)
    pts = capture.points @ transform[:3, :3].T + transform[:3, 3] if len(capture.points) else None
    top = 0.5 * distance_m
    if pts is not None:
        inside = pts[(np.linalg.norm(pts[:, :2], axis=1) < half) & (pts[:, 2] > margin * 0.1)]
        if len(inside) >= 10:
            top = float(np.percentile(inside[:, 2], 99))
    bottom = -margin if has_plane else -0.5 * distance_m
    return np.array([[-half, -half, bottom], [half, half, top + margin]])

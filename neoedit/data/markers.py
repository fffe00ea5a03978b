"""ArUco markers of known size lying on the table: metric scale, z-up and origin for a scan,
and the registration of a later scan to an earlier one (paper, Sec. IV).

Each marker's four corners are detected in every photo (OpenCV ``aruco``, corners refined
by fitting the marker's edges), turned into rays with the photo's pose and lens, and triangulated (the point
closest to all its rays). From the corners:

* **scale**: the known side length over the median measured side;
* **up**: the normal of the plane through all corners, turned towards the cameras;
* **origin and x axis**: the centre of the markers; x along the first edge (corner 0 -> 1)
  of the marker with the lowest id, so every scan of the same table gets the same frame;
* **registration**: the similarity (rotation, translation, scale; Umeyama) that maps one
  scan's corners onto another's.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable
from dataclasses import dataclass

import numpy as np

from neoedit.errors import DataError
from neoedit.utils.aruco import aruco_dictionary


def detect_markers(image: np.ndarray, dictionary_name: str = "4X4_50") -> dict[int, np.ndarray]:
    """Marker id -> (4,2) corner pixels (pixel centres at +0.5, as in COLMAP and neoedit)."""
    import cv2

    grey = image if image.ndim == 2 else cv2.cvtColor(image, cv2.COLOR_RGB2GRAY)
    params = cv2.aruco.DetectorParameters()
    # AprilTag's edge-fitting refinement: sub-pixel SUBPIX corners sat ~0.4 px inside a
    # 40 px marker on our renders (a 1 % scale error); these measure within 0.15 %
    params.cornerRefinementMethod = cv2.aruco.CORNER_REFINE_APRILTAG
    detector = cv2.aruco.ArucoDetector(aruco_dictionary(dictionary_name), params)
    corners, ids, _ = detector.detectMarkers(grey)
    if ids is None:
        return {}
    found: dict[int, np.ndarray] = {}
    for marker, c in zip(ids.ravel(), corners, strict=True):
        if int(marker) in found:  # the same id twice in one photo: ambiguous, drop it
            found.pop(int(marker))
            continue
        found[int(marker)] = c.reshape(4, 2).astype(np.float64) + 0.5
    return found


def closest_point(origins: np.ndarray, directions: np.ndarray) -> np.ndarray:
    """The point with the least summed squared distance to the rays (origins, directions)."""
    d = directions / np.linalg.norm(directions, axis=1, keepdims=True)
    proj = np.eye(3)[None] - d[:, :, None] * d[:, None, :]
    return np.linalg.solve(proj.sum(0), (proj @ origins[:, :, None]).sum(0)[:, 0])


@dataclass
class MarkerMap:
    """Triangulated marker corners of one scan (model frame)."""

    corners: dict[int, np.ndarray]
    """id -> (4,3) corners."""
    views: dict[int, int]
    """id -> number of photos it was triangulated from."""

    def points(self, ids: Iterable[int]) -> np.ndarray:
        return np.concatenate([self.corners[i] for i in ids])


def triangulate_markers(
    n_views: int,
    detections: Callable[[int], dict[int, np.ndarray]],
    rays: Callable[[int, np.ndarray], tuple[np.ndarray, np.ndarray]],
    min_views: int = 2,
) -> MarkerMap:
    """``detections(i)`` are the markers found in photo i; ``rays(i, pixels)`` turns its
    pixels into world rays (origins, directions)."""
    seen: dict[int, list[tuple[np.ndarray, np.ndarray]]] = {}
    for i in range(n_views):
        for marker, pixels in detections(i).items():
            seen.setdefault(marker, []).append(rays(i, pixels))
    corners, views = {}, {}
    for marker, obs in seen.items():
        if len(obs) < min_views:
            continue
        corners[marker] = np.stack(
            [
                closest_point(np.stack([o[0][k] for o in obs]), np.stack([o[1][k] for o in obs]))
                for k in range(4)
            ]
        )
        views[marker] = len(obs)
    return MarkerMap(corners, views)


def marker_frame(
    markers: MarkerMap, side_m: float, camera_centres: np.ndarray
) -> tuple[np.ndarray, float]:
    """(4,4) similarity model -> metric table frame, and its scale, from the markers."""
    if not markers.corners:
        raise DataError("no ArUco marker was seen in two or more photos")
    ids = sorted(markers.corners)
    pts = markers.points(ids)
    sides = [np.linalg.norm(np.roll(c, -1, axis=0) - c, axis=1) for c in markers.corners.values()]
    scale = side_m / float(np.median(np.concatenate(sides)))
    centre = pts.mean(0)
    normal = np.linalg.svd(pts - centre, full_matrices=False)[2][-1]
    if np.median((camera_centres - centre) @ normal) < 0:
        normal = -normal
    first = markers.corners[ids[0]]
    x = first[1] - first[0]
    x -= (x @ normal) * normal
    if np.linalg.norm(x) < 1e-12:
        raise DataError("degenerate ArUco marker corners")
    x /= np.linalg.norm(x)
    rot = np.stack([x, np.cross(normal, x), normal])
    transform = np.eye(4)
    transform[:3, :3] = scale * rot
    transform[:3, 3] = -scale * rot @ centre
    return transform, scale


def umeyama(source: np.ndarray, target: np.ndarray) -> np.ndarray:
    """(4,4) similarity T with T(source) ~ target (least squares, Umeyama 1991)."""
    mu_s, mu_t = source.mean(0), target.mean(0)
    s, t = source - mu_s, target - mu_t
    u, d, vt = np.linalg.svd(t.T @ s / len(source))
    sign = np.eye(3)
    if np.linalg.det(u) * np.linalg.det(vt) < 0:
        sign[2, 2] = -1
    rot = u @ sign @ vt
    scale = float(np.trace(np.diag(d) @ sign) / (s**2).sum(1).mean())
    out = np.eye(4)
    out[:3, :3] = scale * rot
    out[:3, 3] = mu_t - scale * rot @ mu_s
    return out


def capture_markers(capture, dictionary_name: str) -> MarkerMap:  # noqa: ANN001 (Capture)
    """Markers of a :class:`~neoedit.data.capture.Capture` (photos with lens distortion)."""
    import cv2

    def detections(i: int) -> dict[int, np.ndarray]:
        from neoedit.data.capture import read_photo

        return detect_markers(
            read_photo(capture.image_dir / capture.names[i], grey=True), dictionary_name
        )

    def rays(i: int, pixels: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        lens = capture.lenses[i]
        k = lens.matrix()
        k[:2, 2] -= 0.5
        xy = cv2.undistortPoints((pixels - 0.5).reshape(-1, 1, 2), k, lens.distortion())
        xy = xy.reshape(-1, 2)
        c2w = capture.camera_to_world[i]
        d_cv = np.c_[xy, np.ones(len(xy))]  # OpenCV camera axes: x right, y down, z forward
        d = d_cv @ (c2w[:3, :3] @ np.diag([1.0, -1.0, -1.0])).T
        return np.repeat(c2w[None, :3, 3], len(xy), 0), d

    return triangulate_markers(len(capture), detections, rays)


def dataset_markers(data, dictionary_name: str) -> MarkerMap:  # noqa: ANN001 (SceneData)
    """Markers of a loaded dataset (undistorted pinhole photos, OpenGL cameras)."""
    cams = data.cameras

    def rays(i: int, pixels: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        x = (pixels[:, 0] - cams.cx[i]) / cams.fx[i]
        y = -(pixels[:, 1] - cams.cy[i]) / cams.fy[i]
        d = np.c_[x, y, -np.ones(len(x))] @ cams.camera_to_world[i, :3, :3].T
        return np.repeat(cams.camera_to_world[None, i, :3, 3], len(x), 0), d

    return triangulate_markers(
        len(data), lambda i: detect_markers(data.images[i], dictionary_name), rays
    )

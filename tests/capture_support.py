"""Synthetic captures for the importer tests: a ring of cameras over a textured floor with a
small object, written as a COLMAP text model (and LLFF poses) with images the test renders.

World (metres, z up): floor z = 0, the cameras circle (0, 0) at ``RADIUS`` and ``HEIGHT``
looking at ``TARGET``. The model frame is that world under a known similarity ``MODEL``, as
structure-from-motion would return it (arbitrary rotation, scale and origin).
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
from scipy.spatial.transform import Rotation

from neoedit.cameras.cameras import look_at

W, H = 320, 240
F = 260.0
RING_N = 12
"""Photos in the ring of :func:`colmap_project`."""
RADIUS, HEIGHT = 0.5, 0.3
TARGET = np.array([0.0, 0.0, 0.05])
TRUE_DISTANCE = float(np.hypot(RADIUS, HEIGHT - TARGET[2]))
MODEL_SCALE = 3.7
MODEL = np.eye(4)
MODEL[:3, :3] = MODEL_SCALE * Rotation.from_euler("xyz", [25, -40, 70], degrees=True).as_matrix()
MODEL[:3, 3] = [1.5, -2.0, 0.7]


def ring_c2w(
    n: int, arc_deg: float = 360.0, radius: float = RADIUS, height: float = HEIGHT
) -> np.ndarray:
    """(n,4,4) OpenGL camera-to-world of the ring, in world metres."""
    angles = np.radians(np.arange(n) * arc_deg / n)
    eyes = np.stack([radius * np.cos(angles), radius * np.sin(angles), np.full(n, height)], 1)
    return np.stack([look_at(e, TARGET) for e in eyes])


def scene_points(seed: int = 0) -> np.ndarray:
    """Floor points and points on a small upright cylinder at the origin (world metres)."""
    rng = np.random.default_rng(seed)
    floor = np.c_[rng.uniform(-0.3, 0.3, (300, 2)), np.zeros(300)]
    a = rng.uniform(0, 2 * np.pi, 120)
    can = np.c_[0.03 * np.cos(a), 0.03 * np.sin(a), rng.uniform(0.0, 0.12, 120)]
    return np.concatenate([floor, can])


def to_model(points_or_c2w: np.ndarray, model: np.ndarray = MODEL) -> np.ndarray:
    """World -> model frame (points (P,3) or OpenGL camera-to-world (N,4,4), kept rigid)."""
    a = np.asarray(points_or_c2w, dtype=np.float64)
    if a.ndim == 2:
        return a @ model[:3, :3].T + model[:3, 3]
    out = model[None] @ a
    out[:, :3, :3] /= np.cbrt(np.linalg.det(model[:3, :3]))
    return out


def _w2c_cv(c2w_gl: np.ndarray) -> np.ndarray:
    return np.linalg.inv(c2w_gl @ np.diag([1.0, -1.0, -1.0, 1.0]))


def project(c2w_gl: np.ndarray, k: np.ndarray, dist: np.ndarray, points: np.ndarray) -> np.ndarray:
    """COLMAP pixel coordinates (pixel centres at +0.5) of ``points`` (distortion applied)."""
    w2c = _w2c_cv(c2w_gl)
    rvec = cv2.Rodrigues(w2c[:3, :3])[0]
    k_cv = k.copy()
    k_cv[:2, 2] -= 0.5
    uv = cv2.projectPoints(points.reshape(-1, 1, 3), rvec, w2c[:3, 3], k_cv, dist)[0]
    return uv.reshape(-1, 2) + 0.5


def write_colmap_text(
    folder: Path,
    c2w_model: np.ndarray,
    points_model: np.ndarray,
    tracks: list[list[tuple[int, np.ndarray]]],
    model: str = "PINHOLE",
    params: list[float] | None = None,
    names: list[str] | None = None,
) -> None:
    """cameras.txt / images.txt / points3D.txt with one shared camera."""
    folder.mkdir(parents=True, exist_ok=True)
    params = params or [F, F, W / 2, H / 2]
    names = names or [f"{i:04d}.png" for i in range(len(c2w_model))]
    (folder / "cameras.txt").write_text(f"1 {model} {W} {H} " + " ".join(map(str, params)) + "\n")
    obs: list[list[str]] = [[] for _ in c2w_model]
    point_lines = []
    for pid, (xyz, track) in enumerate(zip(points_model, tracks, strict=True), start=1):
        elems = []
        for img, uv in track:
            elems.append(f"{img + 1} {len(obs[img])}")
            obs[img].append(f"{uv[0]} {uv[1]} {pid}")
        point_lines.append(f"{pid} {xyz[0]} {xyz[1]} {xyz[2]} 128 128 128 0.5 " + " ".join(elems))
    lines = []
    for i, c2w in enumerate(c2w_model):
        w2c = _w2c_cv(c2w)
        qx, qy, qz, qw = Rotation.from_matrix(w2c[:3, :3]).as_quat()
        t = w2c[:3, 3]
        lines.append(f"{i + 1} {qw} {qx} {qy} {qz} {t[0]} {t[1]} {t[2]} 1 {names[i]}")
        lines.append(" ".join(obs[i]))
    (folder / "images.txt").write_text("\n".join(lines) + "\n")
    (folder / "points3D.txt").write_text("\n".join(point_lines) + "\n")


def tracks_for(c2w_world: np.ndarray, points_world: np.ndarray, k: np.ndarray, dist: np.ndarray):  # noqa: ANN201
    """Per point, the (image, pixel) of every camera that sees it inside the frame."""
    tracks: list[list[tuple[int, np.ndarray]]] = [[] for _ in points_world]
    for i, c2w in enumerate(c2w_world):
        uv = project(c2w, k, dist, points_world)
        depth = (_w2c_cv(c2w)[:3, :3] @ points_world.T).T[:, 2] + _w2c_cv(c2w)[2, 3]
        inside = (uv[:, 0] > 0) & (uv[:, 0] < W) & (uv[:, 1] > 0) & (uv[:, 1] < H) & (depth > 0)
        for p in np.nonzero(inside)[0]:
            tracks[p].append((i, uv[p]))
    return tracks


def floor_texture(seed: int = 0, size: int = 1024) -> np.ndarray:
    """A feature-rich grey texture for the floor square [-1, 1]^2 m."""
    rng = np.random.default_rng(seed)
    tex = np.zeros((size, size), np.float32)
    for scale in (4, 16, 64):
        noise = rng.random((size // scale, size // scale)).astype(np.float32)
        tex += cv2.resize(noise, (size, size), interpolation=cv2.INTER_CUBIC)
    tex = (tex - tex.min()) / (tex.max() - tex.min())
    return (tex * 255).astype(np.uint8)


def render_floor(
    c2w_world: np.ndarray, k: np.ndarray, texture: np.ndarray, supersample: int = 1
) -> np.ndarray:
    """The textured floor as a pinhole camera sees it (H, W, 3) uint8; ``supersample``
    renders at that many times the size and averages (a camera integrates over pixels)."""
    size = texture.shape[0]
    # texel u grows with +x and v with -y, so a camera above the floor sees the texture
    # unmirrored (the markers in it stay readable)
    tex_from_plane = np.array([[size / 2, 0, size / 2], [0, -size / 2, size / 2], [0, 0, 1.0]])
    w2c = _w2c_cv(c2w_world)
    k_cv = k.copy()
    k_cv[:2] *= supersample
    k_cv[:2, 2] -= 0.5
    img_from_plane = k_cv @ np.c_[w2c[:3, 0], w2c[:3, 1], w2c[:3, 3]]
    # texture pixel centres sit at integers in OpenCV: texel (i, j) covers plane cell i..i+1
    texel = np.array([[1, 0, -0.5], [0, 1, -0.5], [0, 0, 1.0]])
    warp = img_from_plane @ np.linalg.inv(texel @ tex_from_plane)
    big = (W * supersample, H * supersample)
    grey = cv2.warpPerspective(texture, warp, big, flags=cv2.INTER_LINEAR, borderValue=90)
    if supersample > 1:
        grey = cv2.resize(grey, (W, H), interpolation=cv2.INTER_AREA)
    return np.repeat(grey[:, :, None], 3, axis=2)


def marker_texture(
    side_m: float, centres: list[tuple[float, float]], size: int = 4096
) -> np.ndarray:
    """The floor texture with ArUco markers (4X4_50, ids 0, 1, ...) of ``side_m`` at
    ``centres`` (plane metres), each in a white quiet zone; texel u = +x, v = -y, so corner
    0 -> 1 of every marker points along +x."""
    tex = cv2.resize(floor_texture(), (size, size), interpolation=cv2.INTER_LINEAR)
    tex = (tex // 2 + 64).astype(np.uint8)  # keep the markers the darkest and brightest
    dictionary = cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_4X4_50)
    px = size / 2  # texels per metre / 1
    side = int(round(side_m * px))
    for marker, (x, y) in enumerate(centres):
        u0, v0 = int(round((x + 1) * px - side / 2)), int(round((1 - y) * px - side / 2))
        pad = side // 4
        tex[v0 - pad : v0 + side + pad, u0 - pad : u0 + side + pad] = 255
        tex[v0 : v0 + side, u0 : u0 + side] = cv2.aruco.generateImageMarker(
            dictionary, marker, side
        )
    return tex


def pinhole_k() -> np.ndarray:
    return np.array([[F, 0, W / 2], [0, F, H / 2], [0, 0, 1.0]])


def colmap_project(root: Path, model="PINHOLE", params=None, dist=None, images=True) -> Path:  # noqa: ANN001
    """A COLMAP project (sparse/0 text model + images) of the synthetic ring."""
    c2w = ring_c2w(RING_N)
    pts = scene_points()
    k = pinhole_k()
    dist = np.zeros(4) if dist is None else dist
    write_colmap_text(
        root / "sparse" / "0",
        to_model(c2w),
        to_model(pts),
        tracks_for(c2w, pts, k, dist),
        model,
        params,
    )
    if images:
        (root / "images").mkdir(parents=True)
        tex = floor_texture()
        for i in range(RING_N):
            cv2.imwrite(str(root / "images" / f"{i:04d}.png"), render_floor(c2w[i], k, tex))
    return root


def fold_model(src: Path, at: int) -> None:
    """Rewrite the model of ``src`` folded at photo ``at``: the later photos turned 180 deg
    about the vertical through the target, sharing no points with the earlier ones."""
    c2w = ring_c2w(RING_N)
    pts = scene_points()
    k = pinhole_k()
    tracks = tracks_for(c2w, pts, k, np.zeros(4))
    folded = c2w.copy()
    turn = np.diag([-1.0, -1.0, 1.0, 1.0])
    folded[at:] = turn @ c2w[at:]
    tracks = [[(i, uv) for i, uv in t if i < at] or t for t in tracks]
    tracks = [
        t if {i < at for i, _ in t} != {True, False} else [e for e in t if e[0] < at]
        for t in tracks
    ]
    write_colmap_text(src / "sparse" / "0", to_model(folded), to_model(pts), tracks)

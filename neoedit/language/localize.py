"""Prompt -> oriented 3-D box (paper, section III opening).

relevancy of the language feature at every stored surface point -> points close to the best
relevancy -> DBSCAN (the best-matching cluster) -> yaw-only box (:func:`footprint_box`): yaw
from the minimum-area rectangle on the ground plane, or from the principal axis of an
elongated footprint; extents lightly trimmed; extended down to the support surface found
just around the cluster.

"Up" is world +z (NEO-Sim, and nerfstudio data after its default orientation). For other
data :func:`estimate_up` estimates it when the language field is trained: the normal of the
dominant plane of the surface points (the table top, found by RANSAC), turned to agree with
the mean camera up vector (which alone is used when no plane dominates). Queries refuse
scenes whose up is far from +z, since the box format (yaw about z) could not express the box.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import torch

from neoedit.cameras.cameras import Cameras
from neoedit.errors import NeoError
from neoedit.geometry.box import OrientedBox
from neoedit.geometry.clusters import core_clusters
from neoedit.geometry.levels import surface_level
from neoedit.geometry.plane import fit_plane
from neoedit.language.relevancy import CANONICAL_PHRASES, relevancy
from neoedit.language.text import TextEncoder
from neoedit.scene import Scene
from neoedit.utils.validate import shorten


class NoMatch(NeoError):
    """The prompt matched nothing in the scene (carries the best relevancy). Every verb
    that looks an object up (query, remove, move, grasp, plan) exits with status 1 on it,
    as ``grep`` does for no match: the input was fine, the scene holds no such object."""

    exit_code = 1

    def __init__(self, prompt: str, best: float, threshold: float, reason: str | None = None):
        why = reason or f"best relevancy {best:.3f} < threshold {threshold:.3f}"
        super().__init__(f"no object matched {shorten(prompt)!r}: {why}")
        self.prompt, self.best = prompt, best


@dataclass
class QueryConfig:
    canonical: tuple[str, ...] = CANONICAL_PHRASES
    """Canonical negative phrases of the relevancy."""
    threshold: float = 0.52
    """Minimum relevancy (0.5 = no better than a canonical phrase) for a match."""
    keep_fraction: float = 0.5
    """Points kept: relevancy >= best - keep_fraction * (best - threshold), so a closely
    related object that matches less well (e.g. 'red ball' for 'red mug') is left out."""
    best_quantile: float = 0.999
    """'best' is this quantile of the relevancy (robust to a few noisy points)."""
    voxel_m: float = 0.004
    """Points are thinned to one per voxel of this size before clustering."""
    eps_m: float = 0.015
    """DBSCAN neighbourhood radius."""
    min_samples: int = 12
    min_cluster_points: int = 25
    """Smallest cluster accepted as an object (fewer -> no match)."""
    trim: float = 0.003
    """Fraction of the cluster's points left out on each side of the footprint's two axes.
    Small, so a thin part with few points (a mug's handle) stays in the box: the cluster is
    already its DBSCAN core points, free of sparse stragglers."""
    trim_top: float = 0.02
    """Fraction left out at the top and at the bottom: a reconstructed top surface is fuzzy
    by a few mm, which matters for flat objects, and so is the contact with the table (the
    bottom is then extended down to the support when one is found below the cluster)."""
    support_search_m: float = 0.1
    """How far below the cluster to look for the surface it stands on."""
    elongation: float = 1.15
    """A footprint whose principal spreads (standard deviations) differ by more than this
    ratio takes its yaw from its long axis rather than from the minimum-area rectangle...
    (NEO-Sim's mugs: 1.20-1.30 from their scans' surface points; cubes and balls 1.01-1.14)"""
    area_slack: float = 0.15
    """...when that box's footprint is at most this fraction larger."""

    def check(self) -> None:
        """Refuse values that cannot describe a query (a NeoError naming the option)."""
        if not self.canonical or not all(str(c).strip() for c in self.canonical):
            raise NeoError(
                "--query.canonical needs at least one non-empty phrase (the negatives a match "
                "must beat, e.g. object things stuff texture)"
            )
        for name in ("trim", "trim_top"):
            value = getattr(self, name)
            if not 0.0 <= value < 0.5:
                raise NeoError(f"--query.{name.replace('_', '-')} must be in [0, 0.5), not {value}")
        for name in ("voxel_m", "eps_m"):
            if not getattr(self, name) > 0:
                raise NeoError(
                    f"--query.{name.replace('_', '-')} must be > 0, not {getattr(self, name)}"
                )
        if not 0.0 <= self.best_quantile <= 1.0:
            raise NeoError(f"--query.best-quantile must be in [0, 1], not {self.best_quantile}")
        if self.min_samples < 1 or self.min_cluster_points < 3:
            raise NeoError(
                "--query.min-samples must be >= 1 and --query.min-cluster-points >= 3, not "
                f"{self.min_samples} and {self.min_cluster_points}"
            )
        if not (self.elongation >= 1.0 and self.area_slack >= 0.0):
            raise NeoError(
                "--query.elongation must be >= 1 and --query.area-slack >= 0, not "
                f"{self.elongation} and {self.area_slack}"
            )


@dataclass
class QueryResult:
    prompt: str
    box: OrientedBox
    score: float
    """Median relevancy of the cluster's points."""
    best: float
    points_m: np.ndarray = field(repr=False)
    """(K,3) points of the chosen cluster."""

    def to_dict(self) -> dict:
        return {**self.box.to_dict(), "score": round(self.score, 4), "prompt": self.prompt}


def dominant_plane(
    points_m: np.ndarray,
    inlier_m: float = 0.005,
    iterations: int = 256,
    seed: int = 0,
    near_normal: np.ndarray | None = None,
    max_angle_deg: float = 90.0,
) -> tuple[np.ndarray, np.ndarray, float] | None:
    """The plane of the most points (:func:`~neoedit.geometry.plane.fit_plane`: RANSAC over
    at most 20000 points, refitted to its inliers; with ``near_normal``, among the planes
    within ``max_angle_deg`` of it): (unit normal (3,), a point on it (3,), inlier
    fraction), or None for fewer than 50 points or only degenerate triples. The normal's
    sign is arbitrary."""
    if len(points_m) < 50:
        return None
    plane = fit_plane(
        points_m, inlier_m, iterations, seed, near_normal=near_normal, max_angle_deg=max_angle_deg
    )
    if plane is None:
        return None
    return plane.normal, plane.normal * plane.offset, float(plane.inliers.mean())


def camera_up(cameras: Cameras) -> np.ndarray:
    """Unit mean of the cameras' up axes (OpenGL +y)."""
    cam_up = cameras.camera_to_world[:, :3, 1].mean(0)
    return cam_up / max(np.linalg.norm(cam_up), 1e-9)


def estimate_up(
    cameras: Cameras,
    points_m: np.ndarray | None = None,
    inlier_m: float = 0.005,
    min_inlier_fraction: float = 0.2,
    iterations: int = 256,
    seed: int = 0,
    max_tilt_deg: float = 45.0,
    rough_factor: float = 2.0,
    levelled: bool = False,
) -> np.ndarray:
    """Unit up vector (3,): normal of the dominant plane of ``points_m`` (RANSAC) among the
    planes within ``max_tilt_deg`` of world +z (the data's up after import), oriented like
    the mean camera up axis (OpenGL +y); that mean alone without such a plane. A wall, a
    box's side or the side of a can is not the ground, however many surface points it
    holds; data tilted further than ``max_tilt_deg`` finds no plane and falls back to the
    cameras, which :func:`check_up` then judges. When the cameras' up is too far from +z
    for :func:`check_up` (a capture looking down: spinnerf_1 levelled on its sparse points,
    46 deg), one more look for the support is taken at ``rough_factor`` times ``inlier_m``
    (a support reconstructed from photos is not flat to 5 mm: spinnerf_1's bench holds 16 %
    of the points within 5 mm, 27 % within 10 mm). Where the cameras' up would pass, it
    stays the fallback: on tiny or briefly trained fields a rough plane is the less exact.
    ``levelled``: the data's +z is already a measured up (``neo import`` / ``neo process``
    levelled it on a support plane, marker plane or camera ring: :func:`levelled_at_import`),
    so +z, not the cameras' up, is the fallback."""
    cam_up = camera_up(cameras)
    plane = None
    if points_m is not None:
        z = np.array([0.0, 0.0, 1.0])
        looks = [inlier_m]
        if _tilt_deg(cam_up) > MAX_UP_TILT_DEG and rough_factor != 1:
            looks.append(inlier_m * rough_factor)
        for tol in looks:
            plane = dominant_plane(points_m, tol, iterations, seed, z, max_tilt_deg)
            if plane is not None and plane[2] >= min_inlier_fraction:
                break
    if plane is None or plane[2] < min_inlier_fraction:
        return np.array([0.0, 0.0, 1.0]) if levelled else cam_up
    n = plane[0]
    return n if n @ cam_up >= 0 else -n


def _tilt_deg(up: np.ndarray) -> float:
    return float(np.degrees(np.arccos(np.clip(up[2], -1.0, 1.0))))


MAX_UP_TILT_DEG = 30.0
"""Yaw-only boxes are refused in a scene whose up is further than this from +z."""


def check_up(up: np.ndarray, max_angle_deg: float = MAX_UP_TILT_DEG) -> None:
    angle = _tilt_deg(up)
    if angle > max_angle_deg:
        raise NeoError(
            f"the scene's up direction is {angle:.0f} deg from world +z; boxes are yaw-only about "
            "z, so orient the data z-up first: `neo import` / `neo process` level it on the "
            "support plane of its sparse points (for LLFF, without --no-triangulate)"
        )


def voxel_thin(points: np.ndarray, voxel_m: float) -> np.ndarray:
    """Indices of one point per occupied voxel."""
    keys = np.floor(points / voxel_m).astype(np.int64)
    _, first = np.unique(keys, axis=0, return_index=True)
    return np.sort(first)


def support_height(
    points: np.ndarray, cluster: np.ndarray, box: OrientedBox, cfg: QueryConfig
) -> float | None:
    """z of the surface the cluster stands on: the densest height of the highest band where
    the points in a ring around its footprint, below it, crowd (:func:`surface_level`; the
    points under the footprint too when the ring holds fewer than 10), or None if there are
    too few (the cluster already reaches down to its support, or nothing is seen around it)."""
    z0 = float(cluster[:, 2].min())

    def grown(m: float) -> OrientedBox:
        return OrientedBox(
            box.center_m, (box.size_m[0] + 2 * m, box.size_m[1] + 2 * m, 10.0), box.yaw_deg
        )

    near = (
        grown(0.02).contains(points)
        & (points[:, 2] < z0 - 0.002)
        & (points[:, 2] > z0 - cfg.support_search_m)
    )
    # the support shows around the footprint; under it lies the object's own base (a ball's
    # lower half spreads its points over every height down to the table)
    ring = near & ~grown(0.005).contains(points)
    if int(ring.sum()) >= 10:
        near = ring
    elif int(near.sum()) < 10:
        return None
    # a support is a horizontal surface: the height where the points below crowd (the
    # object's own sides, under a cluster that holds only its top, spread over theirs)
    return surface_level(points[near, 2])


def localize(
    prompt: str,
    features: torch.Tensor,
    points_m: np.ndarray,
    text: TextEncoder,
    cfg: QueryConfig | None = None,
) -> QueryResult:
    """Box of the object ``prompt`` names, from unit language features (P,D) at points (P,3)."""
    cfg = cfg or QueryConfig()
    cfg.check()
    if not prompt.strip():
        raise NeoError('empty prompt: say which object to find, e.g. "red mug"')
    emb = text.encode([prompt, *cfg.canonical])
    rel = relevancy(features.float().cpu(), emb[0], emb[1:]).numpy()
    if len(rel) == 0:
        raise NoMatch(prompt, 0.0, cfg.threshold)
    best = float(np.quantile(rel, cfg.best_quantile))
    if best < cfg.threshold:
        raise NoMatch(prompt, best, cfg.threshold)
    cut = max(cfg.threshold, best - cfg.keep_fraction * (best - cfg.threshold))
    sel = np.nonzero(rel >= cut)[0]
    sel = sel[voxel_thin(points_m[sel], cfg.voxel_m)]
    too_few = (
        f"best relevancy {best:.3f}, but the relevant points form no cluster of "
        f"{cfg.min_cluster_points}+ points (scattered noise, not an object)"
    )
    if len(sel) < cfg.min_cluster_points:
        raise NoMatch(prompt, best, cfg.threshold, too_few)
    labels, core = core_clusters(points_m[sel], cfg.eps_m, cfg.min_samples)
    if (labels >= 0).sum() == 0:
        raise NoMatch(prompt, best, cfg.threshold, too_few)
    # the box is fitted to the cluster's core points: sparse stragglers at its rim (floaters,
    # silhouette pixels whose depth hit the table behind) would inflate it
    members = sel[(labels == best_cluster(labels, core, rel[sel], cfg.min_cluster_points)) & core]
    if len(members) < cfg.min_cluster_points:
        raise NoMatch(prompt, best, cfg.threshold, too_few)
    cluster = points_m[members]
    box = footprint_box(cluster, cfg)
    support = support_height(points_m, cluster, box, cfg)
    if support is not None:
        box = box.extended_down(support)
    return QueryResult(prompt, box, float(np.median(rel[members])), best, cluster)


def footprint_box(cluster: np.ndarray, cfg: QueryConfig) -> OrientedBox:
    """Yaw-only box of a cluster (K,3), its extents trimmed of the outermost points per side.

    The yaw is the minimum-area rectangle's, which lies along the faces of boxy objects. An
    elongated footprint takes the yaw of its principal axis instead, unless that box is
    clearly larger: a mug's minimum-area rectangle is diagonal (its handle fits into a
    corner), its principal axis runs through the handle, as the object's own frame does."""
    trim = (cfg.trim, cfg.trim, cfg.trim_top)
    box = OrientedBox.fit_with_yaw(cluster, OrientedBox.fit_to_points(cluster).yaw_deg, trim)
    xy = cluster[:, :2] - cluster[:, :2].mean(0)
    spread, axes = np.linalg.eigh(xy.T @ xy)  # ascending: axes[:, 1] is the long axis
    if spread[1] > cfg.elongation**2 * max(spread[0], 1e-18):
        yaw = float(np.degrees(np.arctan2(axes[1, 1], axes[0, 1])))
        yaw = yaw - 180.0 if yaw > 90.0 else yaw + 180.0 if yaw <= -90.0 else yaw  # (-90, 90]
        along = OrientedBox.fit_with_yaw(cluster, yaw, trim)
        if (
            along.size_m[0] * along.size_m[1]
            <= (1.0 + cfg.area_slack) * box.size_m[0] * box.size_m[1]
        ):
            box = along
    return box


def best_cluster(labels: np.ndarray, core: np.ndarray, rel: np.ndarray, min_points: int) -> int:
    """The cluster the prompt names best: the highest median relevancy of its core points
    among clusters of at least ``min_points`` core points (else the largest). Two objects
    whose names embed alike ("orange cube", "green cube") both pass the relevancy cut; the
    larger one is not the better match."""
    ids = np.unique(labels[labels >= 0])
    sizes = np.array([int(((labels == k) & core).sum()) for k in ids])
    if not (sizes >= min_points).any():
        return int(ids[np.argmax(sizes)])
    medians = np.array(
        [
            float(np.median(rel[(labels == k) & core])) if n >= min_points else -np.inf
            for k, n in zip(ids, sizes, strict=True)
        ]
    )
    # near-ties (one object split in two, e.g. a mug's body and handle): the larger part
    close = medians >= medians.max() - 0.01
    return int(ids[close][int(np.argmax(sizes[close]))])


def query_scene(
    scene: Scene, prompt: str, text: TextEncoder, cfg: QueryConfig | None = None
) -> QueryResult:
    """Localise ``prompt`` in a scene with a trained language field."""
    if scene.language is None or scene.surface_points_m is None:
        raise NeoError(
            "this scene has no language field: train it with one (neo train without "
            "--skip-language; --resume with no more steps adds it to a trained scene)"
        )
    up = np.asarray(scene.meta.language.up if scene.meta.language else [0, 0, 1], dtype=float)
    check_up(up)
    feats = scene.language.language(scene.surface_points_m)
    return localize(
        prompt, feats, scene.surface_points_m.cpu().numpy().astype(np.float64), text, cfg
    )


def find_objects(scene: Scene, prompt: str, cfg: QueryConfig | None = None) -> list[QueryResult]:
    """One result per prompt of ``prompt`` (``;`` separates several objects), each found by
    the scene's language field with the encoder it was trained with. :class:`NoMatch` when a
    prompt matches nothing."""
    from neoedit.language.relevancy import split_prompts
    from neoedit.language.text import load_text_encoder

    prompts = split_prompts(prompt or "")
    if not prompts:
        raise NeoError('empty prompt: say which object, e.g. "red mug"')
    if scene.meta.language is None:
        raise NeoError("this scene has no language field: give a box instead of a prompt (--box)")
    text = load_text_encoder(scene.meta.language.text)
    return [query_scene(scene, p, text, cfg) for p in prompts]

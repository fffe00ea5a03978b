"""A label-free, offline language teacher: objects discovered in the geometry, described with
words measured from the data.

On the surface points the language training renders (one per training pixel):

1. the support plane: the dominant plane (RANSAC, :func:`dominant_plane`), refitted to its
   inliers by least squares and oriented like the cameras' up axis;
2. the objects: points clearly above the plane whose footprint lies over the plane's
   extent, thinned to a voxel grid and clustered (DBSCAN); small clusters are dropped;
3. a description per object (:mod:`neoedit.language.describe`): colour names from the
   pixels of its points, a shape class and its nouns, size / height / position words
   relative to the other objects;
4. per point the target is the text embedding of its description (several short phrases,
   averaged): the plane is "table / floor / ground", everything else "background". Points
   between the plane and "clearly above" that belong to no object are left out.

Left / right / front / back are as seen along the mean horizontal viewing direction of the
training cameras; when the cameras look from all around (that mean is shorter than
``GeometricConfig.min_view_bias``) they are the world axes instead: +x right, +y back.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np
import torch

from neoedit.data import SceneData
from neoedit.errors import NeoError
from neoedit.language.describe import (
    Shape,
    colour_words,
    measure_shape,
    phrases,
    relative_words,
)
from neoedit.language.localize import dominant_plane, voxel_thin
from neoedit.language.text import TextEncoder

TABLE, BACKGROUND, IGNORED = -1, -2, -3
"""Labels of points that are no object (object instances are 0, 1, ...)."""
TABLE_PHRASES = ("table", "tabletop", "floor", "ground", "table surface")
BACKGROUND_PHRASES = ("background", "wall", "room")


class NoSupportPlane(NeoError):
    """No plane holds enough of the surface points to be the table / floor."""

    def __init__(self, looks: list[tuple[float, float]], needed: float):
        """``looks``: (inlier distance [m], share of the surface points) of each plane
        looked for; ``needed``: the share a support must hold."""
        held = " and ".join(f"{100 * share:.0f} % within {1000 * d:.0f} mm" for d, share in looks)
        super().__init__(
            "the geometric language teacher found no support plane (table / floor): the "
            f"largest plane holds {held} of the surface points, < {100 * needed:.0f} %; "
            "train with --skip-language, or give a teacher (--language.clip-path)"
        )
        self.looks, self.needed = looks, needed

    def __reduce__(self):  # noqa: ANN204 -- pickled across processes (the bench's workers)
        return (type(self), (self.looks, self.needed))


@dataclass
class GeometricConfig:
    inlier_m: float = 0.006
    """Points within this distance of the support plane belong to it."""
    above_m: float = 0.01
    """Points higher than this above the plane can belong to an object."""
    min_support_fraction: float = 0.15
    """The dominant plane must hold this share of the surface points to be the support."""
    max_support_tilt_deg: float = 30.0
    """Only planes whose normal is within this angle of world +z can be the support (z is
    up in NEO-Sim, in nerfstudio's convention and after ``neo import``; queries check the
    same): a wall or a backdrop with more surface points is not the floor (beer_can, a
    1000-step field: a plane with a horizontal normal won)."""
    voxel_m: float = 0.004
    """Object points are thinned to one per voxel of this size before clustering."""
    eps_m: float = 0.015
    """DBSCAN neighbourhood radius: objects closer than this merge into one."""
    min_samples: int = 4
    """DBSCAN core-point neighbours."""
    min_points: int = 60
    """Smallest object, in surface points (smaller clusters become background)."""
    min_size_m: float = 0.015
    """Smallest object height and footprint length (smaller clusters become background)."""
    bump_chroma: float = 0.02
    """A cluster lower than its footprint is long whose mean chromaticity (r, g, b over their
    sum; shading changes brightness only) is this close to the support's is a bump of the
    support (a reconstruction artefact, e.g. a poorly seen corner of the table), not an
    object. Low objects of exactly the table's colour are lost with them."""
    min_view_bias: float = 0.3
    """Below this length of the mean horizontal camera direction, left/right use world axes."""
    iterations: int = 256
    """RANSAC iterations of the plane fit."""
    rough_factor: float = 2.0
    """When no plane holds ``min_support_fraction`` of the points, the search is made once
    more with ``inlier_m`` and ``above_m`` this many times larger (1: never): the surface
    of a field trained minutes on photos is rougher than a simulated table (spinnerf_1's
    stone bench, 5 minutes: 12 % of the points within 6 mm of a plane; at 10 mm it is
    found, and the box on it; NEO-Sim and beer_can find theirs at 6 mm)."""
    seed: int = 0

    def check(self) -> None:
        """NeoError naming the first field out of its range."""
        positive = ("inlier_m", "above_m", "voxel_m", "eps_m", "min_size_m", "bump_chroma")
        for name in positive:
            value = getattr(self, name)
            if not (isinstance(value, int | float) and np.isfinite(value) and value > 0):
                raise NeoError(f"--language.geometric.{name.replace('_', '-')} must be > 0")
        if self.above_m < self.inlier_m:
            raise NeoError("--language.geometric.above-m must be >= --language.geometric.inlier-m")
        if not 0 <= self.min_support_fraction <= 1 or not 0 <= self.min_view_bias <= 1:
            raise NeoError(
                "--language.geometric.min-support-fraction and min-view-bias must be in [0, 1]"
            )
        if not (np.isfinite(self.rough_factor) and self.rough_factor >= 1):
            raise NeoError("--language.geometric.rough-factor must be >= 1")
        for name in ("min_samples", "min_points", "iterations"):
            if not (isinstance(getattr(self, name), int) and getattr(self, name) >= 1):
                raise NeoError(f"--language.geometric.{name.replace('_', '-')} must be >= 1")


@dataclass
class Plane:
    """Support plane ``normal . x = offset`` with an orthonormal frame (e1, e2, normal)."""

    normal: np.ndarray
    offset: float
    e1: np.ndarray
    e2: np.ndarray

    def local(self, points: np.ndarray) -> np.ndarray:
        """World points (N,3) -> plane frame (x along e1, y along e2, z height)."""
        return np.c_[points @ self.e1, points @ self.e2, points @ self.normal - self.offset]


@dataclass
class Instance:
    """One discovered object."""

    shape: Shape
    colours: list[str]
    points: int
    relative: list[str] = field(default_factory=list)
    """Size, height and position words relative to the other instances."""
    description: str = ""
    phrases: list[str] = field(default_factory=list)


@dataclass
class Discovery:
    labels: np.ndarray
    """(N,) per point: an instance index, TABLE, BACKGROUND or IGNORED."""
    instances: list[Instance]
    plane: Plane


def support_plane(points: np.ndarray, up_hint: np.ndarray, cfg: GeometricConfig) -> Plane:
    """The dominant plane of ``points`` tilted at most ``cfg.max_support_tilt_deg`` from
    world +z, refitted to its inliers, normal along ``up_hint``."""
    found = dominant_plane(
        points,
        cfg.inlier_m,
        cfg.iterations,
        cfg.seed,
        np.array([0.0, 0.0, 1.0]),
        cfg.max_support_tilt_deg,
    )
    if found is None or found[2] < cfg.min_support_fraction:
        share = 0.0 if found is None else float(found[2])
        raise NoSupportPlane([(cfg.inlier_m, share)], cfg.min_support_fraction)
    normal, anchor = found[0], found[1]  # refitted to its inliers by least squares
    normal = normal if normal @ up_hint >= 0 else -normal
    e1 = np.cross([0.0, 1.0, 0.0], normal)  # world +x when the normal is +z
    if np.linalg.norm(e1) < 1e-6:
        e1 = np.cross([0.0, 0.0, 1.0], normal)
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(normal, e1)
    return Plane(normal, float(normal @ anchor), e1, e2)


def cluster_objects(local: np.ndarray, cfg: GeometricConfig) -> np.ndarray:
    """Labels (N,) of plane-frame points: object clusters 0.. (above the plane, over its
    extent, not tiny), TABLE, BACKGROUND or IGNORED (the band between plane and objects)."""
    height = local[:, 2]
    labels = np.full(len(local), BACKGROUND, np.int64)
    on_plane = np.abs(height) <= cfg.inlier_m
    labels[on_plane] = TABLE
    above = np.nonzero(height > cfg.above_m)[0]
    band = np.nonzero((height > cfg.inlier_m) & (height <= cfg.above_m))[0]
    labels[band] = IGNORED
    if len(above) < cfg.min_points:
        return labels
    # objects stand on the support: their footprint lies inside the plane's extent
    from scipy.spatial import Delaunay, QhullError, cKDTree  # lazy: 0.6 s of imports with sklearn
    from sklearn.cluster import DBSCAN

    table_xy = local[on_plane, :2][voxel_thin(local[on_plane, :2], 4 * cfg.voxel_m)]
    try:
        above = above[Delaunay(table_xy).find_simplex(local[above, :2]) >= 0]
    except (QhullError, ValueError):
        pass  # a degenerate support (a line of points): no footprint test
    if len(above) < cfg.min_points:
        return labels
    thin = above[voxel_thin(local[above], cfg.voxel_m)]
    db = DBSCAN(eps=cfg.eps_m, min_samples=cfg.min_samples).fit(local[thin])
    # every point (object candidates and the low band) takes its nearest thinned point's
    # cluster, if that is near enough
    candidates = np.concatenate([above, band])
    dist, nearest = cKDTree(local[thin]).query(local[candidates], k=1)
    cluster = np.where(dist <= cfg.eps_m, db.labels_[nearest], -1)
    next_id = 0
    for k in np.unique(cluster[cluster >= 0]):
        members = candidates[cluster == k]
        pts = local[members]
        extent = np.ptp(pts[:, :2], axis=0).max()
        small = min(extent, pts[:, 2].max()) < cfg.min_size_m
        if len(members) < cfg.min_points or small or (pts[:, 2] > cfg.above_m).sum() < 3:
            continue
        labels[members] = next_id
        next_id += 1
    return labels


def chromaticity(rgb: np.ndarray) -> np.ndarray:
    """(3,) mean colour of pixels (N,3) divided by its sum (brightness removed)."""
    mean = rgb.reshape(-1, 3).astype(np.float64).mean(0) if len(rgb) else np.ones(3)
    return mean / max(float(mean.sum()), 1e-9)


def view_axes(
    cam_to_world: np.ndarray, plane: Plane, cfg: GeometricConfig
) -> tuple[np.ndarray, np.ndarray]:
    """(right, forward) unit plane-frame (2,) directions for left/right/front/back words."""
    view = -cam_to_world[:, :3, 2].mean(0)  # OpenGL cameras look along -z
    forward = np.array([view @ plane.e1, view @ plane.e2])
    if np.linalg.norm(forward) < cfg.min_view_bias:
        forward = np.array([plane.e1[1], plane.e2[1]])  # world +y in the plane frame
        forward = forward if np.linalg.norm(forward) > 1e-6 else np.array([0.0, 1.0])
    forward = forward / np.linalg.norm(forward)
    right = np.array([forward[1], -forward[0]])  # forward x up, in the plane frame
    return right, forward


def discover(
    points: np.ndarray, rgb: np.ndarray, cam_to_world: np.ndarray, cfg: GeometricConfig
) -> Discovery:
    """Objects and their descriptions from surface points (N,3), their pixels' colours
    (N,3 uint8) and the training cameras (F,4,4)."""
    up_hint = cam_to_world[:, :3, 1].mean(0)
    try:
        plane = support_plane(points, up_hint, cfg)
    except NoSupportPlane as fine:
        if cfg.rough_factor == 1:
            raise
        cfg = replace(
            cfg,
            inlier_m=cfg.inlier_m * cfg.rough_factor,
            above_m=cfg.above_m * cfg.rough_factor,
        )
        try:
            plane = support_plane(points, up_hint, cfg)
        except NoSupportPlane as rough:  # say what both looks found
            raise NoSupportPlane(fine.looks + rough.looks, cfg.min_support_fraction) from None
    local = plane.local(points)
    labels = cluster_objects(local, cfg)
    instances: list[Instance] = []
    table_chroma = chromaticity(rgb[labels == TABLE])
    for k in range(int(labels.max()) + 1 if (labels >= 0).any() else 0):
        members = labels == k
        obj = local[members & (local[:, 2] > cfg.above_m)]
        shape = measure_shape(obj)
        bump = np.linalg.norm(chromaticity(rgb[members]) - table_chroma) < cfg.bump_chroma
        if bump and shape.height_m < shape.length_m:
            labels[members] = TABLE  # a low bump of the support's colour: the support itself
            continue
        labels[members] = len(instances)
        instances.append(Instance(shape, colour_words(rgb[members]), len(obj)))
    right, forward = view_axes(cam_to_world, plane, cfg)
    relative = relative_words([inst.shape for inst in instances], right, forward)
    for inst, words in zip(instances, relative, strict=True):
        inst.relative = words
        inst.description, inst.phrases = phrases(inst.colours, inst.shape.kind, words)
    return Discovery(labels, instances, plane)


def embed_phrases(text: TextEncoder, groups: list[list[str]]) -> torch.Tensor:
    """(K, D) unit targets: the normalised mean embedding of each group of phrases."""
    flat = [p for group in groups for p in group]
    emb = text.encode(flat)
    out, start = [], 0
    for group in groups:
        out.append(emb[start : start + len(group)].mean(0))
        start += len(group)
    return torch.nn.functional.normalize(torch.stack(out), dim=-1)


class GeometricTeacher:
    """Point-based teacher: targets for surface points from the discovered objects."""

    name = "geometric"

    def __init__(self, text: TextEncoder, cfg: GeometricConfig | None = None):
        self.text = text
        self.dim = text.dim
        self.cfg = cfg or GeometricConfig()
        self.names: list[str] = []
        self.discovery: Discovery | None = None

    def prepare(self, data: SceneData, frames: np.ndarray) -> None:
        self.images = data.images
        self.frames = np.asarray(frames)
        self.cam_to_world = data.cameras.camera_to_world[self.frames]

    def targets_at(
        self, points: torch.Tensor, frame: torch.Tensor, v_px: torch.Tensor, u_px: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """Targets (N,D) and validity (N,) of surface points (N,3) seen at pixels (v, u) of
        the prepared frames (positions ``frame``)."""
        pts = points.detach().cpu().numpy().astype(np.float64)
        rgb = self.images[self.frames[frame.cpu().numpy()], v_px.cpu().numpy(), u_px.cpu().numpy()]
        found = discover(pts, rgb, self.cam_to_world, self.cfg)
        self.discovery = found
        groups = [inst.phrases for inst in found.instances]
        table = embed_phrases(self.text, [*groups, list(TABLE_PHRASES), list(BACKGROUND_PHRASES)])
        self.names = [inst.description for inst in found.instances] + [
            "table / floor / ground",
            "background",
        ]
        n = len(found.instances)
        rows = torch.from_numpy(found.labels.copy())
        rows = torch.where(rows == TABLE, n, torch.where(rows == BACKGROUND, n + 1, rows))
        valid = rows >= 0
        return table[rows.clamp_min(0)], valid

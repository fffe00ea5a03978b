"""Antipodal grasp sampling on a field's surface, with collision checks against the whole
scene and a ranking by antipodal quality, approach angle, clearance and finger margin.

1. Contacts: surface points of the object (marching cubes, in its box, of how opaque the
   object is in front of each point seen from outside: :mod:`neoedit.grasp.surface`).
2. Pairs: from a contact p1 with outward normal n1, march inward along -n1 through the
   object (where it is opaque seen from outside) until it exits at p2 (normal n2). The pair
   is antipodal when both normals lie in the friction cone of the closing axis (half-angle
   atan(mu)) and the width fits the gripper.
3. Poses: several approach directions perpendicular to the closing axis; a pose survives if
   the fingers, opened a little wider than the object, and the palm hold no density of the
   *scene* (table, neighbours, the object itself elsewhere) and no point inside the object's
   surface, at the grasp and along the last part of the approach.
4. Score: 0.5 quality (cosine of the worse contact angle) + 0.3 top-down approach + 0.2
   clearance (free share of the gripper grown by 1 cm) + ``margin_weight`` finger margin
   (how far the open pads clear the object on each side, as a share of the gripper's
   ``open_margin_m``: what a field's geometric error may eat before a finger lands on the
   object), divided by the weights' sum; nearby duplicates are dropped.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import torch

from neoedit.fields.suppressed import SuppressedField
from neoedit.geometry import OrientedBox
from neoedit.grasp.gripper import GripperConfig, box_lattice, gripper_boxes, opening
from neoedit.grasp.surface import DensityFn, Surface, SurfaceConfig, Volume, object_surface
from neoedit.scene import Scene
from neoedit.utils.options import at_least_one


@dataclass
class GraspConfig:
    gripper: GripperConfig = field(default_factory=GripperConfig)
    surface: SurfaceConfig = field(default_factory=SurfaceConfig)
    friction: float = 0.5
    """Friction coefficient mu: contact normals may deviate atan(mu) from the closing axis."""
    contacts: int = at_least_one(600)
    """First contacts sampled on the surface."""
    approaches: int = at_least_one(8)
    """Approach directions tried per antipodal pair (around the closing axis)."""
    min_width_m: float = 0.006
    """Thinner pairs are skipped (noise in a wall)."""
    collision_density: float = 100.0
    """A gripper point collides where the scene's density exceeds this [1/m] (about 40 %
    opacity over 5 mm), or where it lies inside the object's surface."""
    approach_path_m: tuple[float, ...] = (0.03, 0.06, 0.1)
    """The gripper is also checked this far back along its approach (the simulated robot
    starts its approach 10 cm back: ``ExecuteConfig.pregrasp_m``)."""
    collision_step_m: float = 0.006
    """Spacing of the points that test the fingers (the palm: 2.5x coarser)."""
    up: tuple[float, float, float] = (0.0, 0.0, 1.0)
    """World up (a top-down approach scores best)."""
    margin_weight: float = 0.15
    """Weight of the finger margin in the score (0.5 quality, 0.3 approach and 0.2
    clearance beside it). Objects near the gripper's widest opening leave less margin: on
    NEO-Sim the mug's field is ~1 cm narrower than the mug, and grasps across it at 8 cm
    opening stop on its rim."""
    distinct_m: float = 0.01
    """Grasps closer than this (centre) with a similar axis count once."""
    seed: int = 0


@dataclass
class Grasp:
    position_m: np.ndarray
    rotation: np.ndarray
    """Columns: closing axis, finger axis, approach axis."""
    width_m: float
    score: float
    quality: float
    clearance: float
    approach_deg: float
    """Angle between the approach and straight down."""
    opening_m: float
    """How far apart the finger pads were checked on the approach (open this far)."""

    @property
    def margin_m(self) -> float:
        """How far each open pad clears the object (the contacts) on the approach."""
        return (self.opening_m - self.width_m) / 2

    def to_dict(self) -> dict[str, Any]:
        return {
            "position_m": np.round(self.position_m, 5).tolist(),
            "rotation": np.round(self.rotation, 6).tolist(),
            "width_m": round(float(self.width_m), 5),
            "opening_m": round(float(self.opening_m), 5),
            "score": round(float(self.score), 4),
            "quality": round(float(self.quality), 4),
            "clearance": round(float(self.clearance), 4),
            "approach_deg": round(float(self.approach_deg), 1),
            "margin_m": round(float(self.margin_m), 5),
        }


def antipodal_pairs(surface: Surface, cfg: GraspConfig) -> tuple[np.ndarray, ...]:
    """(p1, p2, quality) of the antipodal contact pairs (world), from up to ``cfg.contacts``
    first contacts."""
    rng = np.random.default_rng(cfg.seed)
    n = len(surface.points_m)
    pick = rng.choice(n, size=min(cfg.contacts, n), replace=False)
    p1, n1 = surface.points_m[pick], surface.normals[pick]
    vol: Volume = surface.volume
    level = surface.level
    step = vol.voxel_m / 2
    ts = np.arange(2 * step, cfg.gripper.max_width_m + step, step)
    local = vol.to_local(p1[:, None, :] - ts[None, :, None] * n1[:, None, :])
    values = vol.sample(local)
    inside = values > level
    # the first sample where the ray, having entered the object, leaves it; the exit is
    # placed where the opacity seen from outside crosses the surface level between that
    # sample and the one before
    entered = np.maximum.accumulate(inside, axis=1)
    exits = entered & ~inside
    exits[:, 0] = False
    has = exits.any(1)
    k = np.maximum(np.argmax(exits, axis=1), 1)
    rows = np.arange(len(k))
    v_in, v_out = values[rows, k - 1], values[rows, k]
    frac = np.clip((v_in - level) / np.maximum(v_in - v_out, 1e-9), 0.0, 1.0)
    width = ts[k - 1] + frac * step
    p2 = p1 - width[:, None] * n1
    # an exit on the grid's faces (its floor above the support, its sides) is where the
    # sampled field ends, not the object: no contact there
    p2_local = vol.to_local(p2)
    far_end = vol.origin + vol.voxel_m * (np.asarray(vol.values.shape) - 1)
    has &= ((p2_local > vol.origin + vol.voxel_m) & (p2_local < far_end - vol.voxel_m)).all(-1)
    n2 = vol.outward_normals(vol.to_local(p2)) @ vol.box.rotation.T
    axis = (p2 - p1) / np.maximum(width[:, None], 1e-12)  # = -n1
    cos1 = np.sum(-n1 * axis, -1)
    cos2 = np.sum(n2 * axis, -1)
    quality = np.minimum(cos1, cos2)
    cone = math.cos(math.atan(cfg.friction))
    ok = has & (quality >= cone) & (width >= cfg.min_width_m)
    return p1[ok], p2[ok], quality[ok]


def _frames(axis: np.ndarray, n_approach: int, up: np.ndarray) -> np.ndarray:
    """(P, A, 3, 3) grasp rotations: closing axis ``axis[p]``, approach directions spread
    around it, starting from the one closest to straight down."""
    down = -up / np.linalg.norm(up)
    a = -(down - np.sum(down * axis, -1, keepdims=True) * axis)  # up, minus its axis part
    a_norm = np.linalg.norm(a, axis=-1, keepdims=True)
    fallback = np.cross(axis, np.array([1.0, 0.0, 0.0]))
    a = np.where(a_norm > 1e-6, a / np.maximum(a_norm, 1e-12), fallback)
    a /= np.linalg.norm(a, axis=-1, keepdims=True)
    z0 = -a  # the approach nearest to straight down
    y0 = np.cross(z0, axis)
    out = []
    for k in range(n_approach):
        th = 2 * math.pi * k / n_approach
        z = math.cos(th) * z0 + math.sin(th) * y0
        y = np.cross(z, axis)
        out.append(np.stack([axis, y, z], -1))
    return np.stack(out, 1)


@torch.no_grad()
def _occupied_share(
    density: DensityFn,
    centres: np.ndarray,
    rotations: np.ndarray,
    local_points: np.ndarray,
    level: float,
) -> np.ndarray:
    """(C,) share of ``local_points`` (gripper frame: (K,3), or (C,K,3) per pose) holding
    density above ``level`` for each pose (centre (C,3), rotation (C,3,3))."""
    if local_points.ndim == 2:
        local_points = np.broadcast_to(local_points, (len(centres), *local_points.shape))
    world = np.einsum("cij,ckj->cki", rotations, local_points) + centres[:, None, :]
    pts = torch.as_tensor(world.reshape(-1, 3), dtype=torch.float32)
    sigma = torch.cat([density(chunk) for chunk in pts.split(262144)]).cpu().numpy()
    return (sigma.reshape(len(centres), -1) > level).mean(1)


def _gripper_points(cfg: GraspConfig, widths: np.ndarray, grow: float = 0.0) -> np.ndarray:
    """(C,K,3) points filling the fingers (each pose opened to its own width) and the palm,
    gripper frame."""
    ref = gripper_boxes(cfg.gripper, 0.0)
    parts, finger = [], []
    for k, (c, h) in enumerate(ref):
        step = cfg.collision_step_m * (2.5 if k == 2 else 1.0)
        lattice = box_lattice(c, h + grow, step)
        parts.append(lattice)
        finger.append(np.full(len(lattice), (-1.0, 1.0, 0.0)[k]))
    pts, side = np.concatenate(parts), np.concatenate(finger)
    # each finger moves out by half the pose's opening beyond the reference's
    shift = np.array([gripper_boxes(cfg.gripper, float(w))[1][0][0] - ref[1][0][0] for w in widths])
    out = np.repeat(pts[None], len(widths), axis=0)
    out[:, :, 0] += shift[:, None] * side[None, :]
    return out


def plan_grasps(
    density: DensityFn, box: OrientedBox, cfg: GraspConfig, top_k: int = 5
) -> list[Grasp]:
    """Collision-free antipodal grasps of the object in ``box``, best first (empty when none
    survives). ``density`` is the *scene's* density as it renders."""
    surface = object_surface(density, box, cfg.surface)
    p1, p2, quality = antipodal_pairs(surface, cfg)
    if len(p1) == 0:
        return []
    up = np.asarray(cfg.up, dtype=np.float64)
    axis = (p2 - p1) / np.linalg.norm(p2 - p1, axis=-1, keepdims=True)
    rot = _frames(axis, cfg.approaches, up).reshape(-1, 3, 3)
    centre = np.repeat((p1 + p2) / 2, cfg.approaches, axis=0)
    width = np.repeat(np.linalg.norm(p2 - p1, axis=-1), cfg.approaches)
    qual = np.repeat(quality, cfg.approaches)
    vertical = np.clip(-(rot[:, :, 2] @ up), 0.0, 1.0)
    open_m = np.array([opening(cfg.gripper, float(w)) for w in width])
    margin = np.minimum(1.0, (open_m - width) / 2 / cfg.gripper.open_margin_m)
    # most promising first (all but the clearance, which needs the collision test)
    order = np.argsort(-(0.5 * qual + 0.3 * vertical + cfg.margin_weight * margin))
    level = cfg.collision_density

    def blocking(points: torch.Tensor) -> torch.Tensor:
        """The scene's density, infinite inside the object (its foggy inside included)."""
        sigma = density(points)
        inside = torch.as_tensor(surface.solid(points.cpu().numpy().astype(np.float64)))
        return torch.where(inside.to(sigma.device), torch.full_like(sigma, math.inf), sigma)

    found: list[Grasp] = []
    for chunk in np.array_split(order, max(1, math.ceil(len(order) / 256))):
        hand = _gripper_points(cfg, width[chunk])  # each pose at its own opening
        free = _occupied_share(blocking, centre[chunk], rot[chunk], hand, level) == 0
        for back in cfg.approach_path_m:
            shifted = hand - np.array([0.0, 0.0, back])  # further back along the approach
            free &= _occupied_share(blocking, centre[chunk], rot[chunk], shifted, level) == 0
        keep = chunk[free]
        if len(keep) == 0:
            continue
        grown = _gripper_points(cfg, width[keep], grow=0.01)
        clearance = 1.0 - _occupied_share(blocking, centre[keep], rot[keep], grown, level)
        for i, c in zip(keep, clearance, strict=True):
            score = 0.5 * qual[i] + 0.3 * vertical[i] + 0.2 * c + cfg.margin_weight * margin[i]
            score /= 1.0 + cfg.margin_weight
            angle = math.degrees(math.acos(float(np.clip(vertical[i], -1, 1))))
            found.append(Grasp(centre[i], rot[i], width[i], score, qual[i], c, angle, open_m[i]))
        if len(found) >= 8 * top_k:
            break
    found.sort(key=lambda g: -g.score)
    return _distinct(found, cfg.distinct_m)[:top_k]


def _distinct(grasps: list[Grasp], distance_m: float) -> list[Grasp]:
    kept: list[Grasp] = []
    for g in grasps:
        if all(
            np.linalg.norm(g.position_m - k.position_m) > distance_m
            or abs(float(g.rotation[:, 0] @ k.rotation[:, 0])) < 0.9
            or float(g.rotation[:, 2] @ k.rotation[:, 2]) < 0.9
            for k in kept
        ):
            kept.append(g)
    return kept


def scene_density(scene: Scene) -> DensityFn:
    """The density of a scene version as it renders (render-time removals, occupancy)."""
    field_, cut = scene.renderable()
    shown = SuppressedField(field_, cut) if cut else field_
    device = scene.field.aabb.device

    def density(points: torch.Tensor) -> torch.Tensor:
        pts = points.to(device)
        return (shown.density(pts) * scene.grid.is_occupied(pts)).cpu()

    return density

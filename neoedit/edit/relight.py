"""Relighting a carried object (beyond the paper): the light estimated from the scan, the
shading ratio of a motion on a grid.

A moved object keeps its weights (``--edit.carry``) and with them the shading it had in the
scan; turned by a yaw, its lit side faces away from a light that stayed in the world. The
light is estimated from the object itself, as the scan shows it: rays of a dozen training
views through the object's box end on its visible surface (normals from the opacity's
gradient there, colours as rendered); the points are grouped by chromaticity (shading
changes brightness, not hue, under white light) and, for each light direction on the upper
hemisphere, every group's brightness is fitted as ``albedo * (1 + k * max(0, n . l))`` (an
ambient and a diffuse term); the direction with the least residual wins. The carried
object's colours are then multiplied by ``shade(R n) / shade(n)`` on a grid over its
weights (:class:`~neoedit.fields.relight.Relight`).

Measured on NEO-Sim pick_place_1 (PyBullet's light: ambient 0.55, diffuse 0.45, direction
(0.4, 0.3, 1)): the direction within 1.2 degrees, the diffuse term 0.29 (0.82 in the
simulator: the fit under-reads it; the truth's value gains 0.1 dB more); benchmarks/RESULTS.md
has what it changes.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
from scipy import ndimage

from neoedit.cameras.rays import CameraTensors
from neoedit.fields.radiance import Field
from neoedit.fields.relight import Relight
from neoedit.geometry import OrientedBox
from neoedit.geometry.masks import masks_for_boxes
from neoedit.rendering.renderer import render_chunked
from neoedit.scene import Scene

GRID = 40
"""Cells per axis of a relight grid."""
STEPS = 20
"""Normals are the opacity's gradient over a step of 1/STEPS of the box's smallest side
(measured on NEO-Sim pick_place_1's mug: 1/40 put the light 6 degrees off, 1/20 1 degree,
1/10 7 degrees)."""
JITTER = 8
"""Points each normal is averaged over."""
SURFACE = 0.05
"""Opacity gradient (per step) at which a cell counts fully as surface (a sharp surface
reads about 0.3-0.8 within a step of it; empty space and solid insides read 0)."""
VIEWS = 12
"""Scan views the light is estimated from."""
MAX_PIXELS = 3000
"""Pixels per view (every k-th of those the box covers)."""
MAX_DIFFUSE = 1.5
"""The diffuse-to-ambient ratio is capped (a scan with no ambient light would divide by 0):
a turn changes a colour by at most 2.5x."""
MIN_TURN_DEG = 0.5
"""A motion that turns the object less than this is not relit (a translation needs none)."""
MAX_POINTS = 20000
"""Surface points a light is fitted on (more are thinned evenly)."""
MIN_FIT = 0.05
"""A light that explains less of the brightness than this is not used (diffuse light, or
surfaces too varied to tell): nothing is relit."""


@dataclass
class Light:
    """A light estimated from a scan: ``direction`` (3,) towards it (world, unit),
    ``diffuse``: its diffuse term over the ambient one, ``fit``: the share of the brightness
    variance within colour groups that the shading explains (0..1), ``points``: how many
    surface points it was fitted on."""

    direction: np.ndarray
    diffuse: float
    fit: float
    points: int

    def shading(self, normals: np.ndarray) -> np.ndarray:
        """(...,) the relative shading ``1 + diffuse * max(0, n . l)`` of unit normals (...,3)."""
        return 1.0 + self.diffuse * np.maximum(normals @ self.direction, 0.0)

    @property
    def usable(self) -> bool:
        """Clear enough to relight by (:data:`MIN_FIT`)."""
        return self.fit >= MIN_FIT and self.diffuse > 0.0

    def to_dict(self) -> dict:
        return {
            "direction": np.round(self.direction, 4).tolist(),
            "diffuse_over_ambient": round(self.diffuse, 4),
            "fit": round(self.fit, 4),
            "points": self.points,
        }


def seen_surface(
    scene: Scene, box: OrientedBox, views: int = VIEWS
) -> tuple[np.ndarray, np.ndarray]:
    """The surface of ``scene`` inside ``box`` as the scan's training views see it: (P,3)
    outward normals (the opacity's gradient where each ray ends, turned to the camera)
    and (P,3) rendered colours, from up to ``views`` views spread over the scan (the
    support under the object included: measured on pick_place_1, it steadies the
    direction)."""
    cameras, _, split = scene.scan_cameras()
    train = np.asarray(split.get("train", np.arange(len(cameras))))
    picked = train[np.linspace(0, len(train) - 1, min(views, len(train))).round().astype(int)]
    device = scene.field.aabb.device
    tensors = CameraTensors(cameras, device)
    field_, cuts = scene.renderable()
    normals, colours = [], []
    for i in np.unique(picked):
        v, u = np.nonzero(masks_for_boxes(cameras, int(i), [box]))
        keep = np.arange(len(v))[:: max(1, -(-len(v) // MAX_PIXELS))]
        if not len(keep):
            continue
        cam = torch.full((len(keep),), int(i), dtype=torch.long, device=device)
        rays = tensors.rays(
            cam, torch.as_tensor(v[keep], device=device), torch.as_tensor(u[keep], device=device)
        )
        out = render_chunked(field_, scene.grid, rays, scene.meta.render, scene.background, cuts)
        points = rays.origins + rays.directions * (out["depth_z"] / rays.z_scale)[:, None]
        local = (points.cpu().numpy() - box.center_m) @ box.rotation
        inside = (np.abs(local) <= np.asarray(box.half_extents)).all(-1)
        solid = inside & (out["accumulation"].cpu().numpy() > 0.95)
        if not solid.any():
            continue
        idx = torch.as_tensor(np.nonzero(solid)[0], device=device)
        n = _outward(_gradient(field_, points[idx], _step_m(np.asarray(box.size_m))))
        facing = torch.where((n * rays.directions[idx]).sum(-1, keepdim=True) > 0, -n, n)
        normals.append(facing.cpu().numpy())
        colours.append(out["rgb"][idx].clamp(0, 1).cpu().numpy())
    if not normals:
        return np.zeros((0, 3)), np.zeros((0, 3))
    return np.concatenate(normals).astype(np.float64), np.concatenate(colours).astype(np.float64)


@torch.no_grad()
def _gradient(field: Field, points: torch.Tensor, step_m: float) -> torch.Tensor:
    """(N,3) the gradient of opacity ``1 - exp(-sigma * step)`` at ``points`` (N,3),
    smoothed over ``step_m``: central differences over a quarter step, averaged at
    :data:`JITTER` points drawn around each point within a step (one wide difference
    saturates where the opacity reaches 1 and bends the normals: 18 degrees off on a
    sphere, 2 this way). In opacity per step: 0 in empty space and inside solids."""
    gen = torch.Generator(device=points.device).manual_seed(0)
    h = step_m / 4
    total = torch.zeros_like(points)
    for _ in range(JITTER):
        shifted = (
            points
            + (torch.rand(points.shape, generator=gen, device=points.device) - 0.5) * 2 * step_m
        )
        for k in range(3):
            e = torch.zeros(3, device=points.device)
            e[k] = h
            ahead = torch.cat([field.density(c) for c in (shifted + e).split(65536)])
            behind = torch.cat([field.density(c) for c in (shifted - e).split(65536)])
            total[:, k] += torch.exp(-behind * step_m) - torch.exp(-ahead * step_m)
    return total * (2 / JITTER)  # per step: h is a quarter step, differences span two


def _outward(gradient: torch.Tensor) -> torch.Tensor:
    """Unit outward normals (against the opacity's gradient)."""
    return -gradient / gradient.norm(dim=-1, keepdim=True).clamp_min(1e-9)


def _step_m(box_size: np.ndarray) -> float:
    return float(np.min(box_size)) / STEPS


def _hemisphere(count: int = 600) -> np.ndarray:
    """(count,3) unit directions spread over the upper hemisphere (a Fibonacci spiral)."""
    k = np.arange(count) + 0.5
    z = 1.0 - k / count  # (0, 1]
    r = np.sqrt(1.0 - z**2)
    phi = k * np.pi * (3.0 - np.sqrt(5.0))
    return np.stack([r * np.cos(phi), r * np.sin(phi), z], -1)


def fit_light(normals: np.ndarray, rgb: np.ndarray, groups: int = 4, seed: int = 0) -> Light | None:
    """The light that best explains the brightness of surface points (normals and colours,
    (P,3) each) as ``albedo * (1 + k max(0, n . l))`` with one albedo per chromaticity
    group; None with fewer than 50 points."""
    if len(normals) < 50:
        return None
    if len(normals) > MAX_POINTS:  # evenly thinned: the fit's cost is points x directions
        pick = np.linspace(0, len(normals) - 1, MAX_POINTS).round().astype(int)
        normals, rgb = normals[pick], rgb[pick]
    luma = rgb.mean(-1)
    chroma = rgb / np.maximum(rgb.sum(-1, keepdims=True), 1e-3)
    distinct = len(np.unique(chroma.round(3), axis=0))
    k = int(min(groups, len(normals) // 50, distinct))
    labels = np.zeros(len(chroma), dtype=int)
    if k > 1:
        from sklearn.cluster import KMeans  # lazy: 0.6 s of imports every edit command paid

        labels = KMeans(k, n_init=3, random_state=seed).fit_predict(chroma)
    _, labels = np.unique(labels, return_inverse=True)  # no empty group
    onehot = np.eye(int(labels.max()) + 1)[labels]  # (P,k)
    coarse = _hemisphere()
    fit = _fit_directions(normals, luma, onehot, coarse)
    best = coarse[int(np.argmin(fit["resid"]))]
    fine = _around(best)  # the coarse grid is ~6 degrees apart: refine around its best
    fit = _fit_directions(normals, luma, onehot, fine)
    i = int(np.argmin(fit["resid"]))
    # each group's diffuse/ambient ratio, weighted by how much its normals vary towards the
    # light (a flat support, all one normal, says nothing about the slope)
    info = fit["spread"][:, i]
    ratio = fit["slope"][:, i] / np.maximum(fit["icept"][:, i], 1e-3)
    diffuse = float(np.sum(info * ratio) / max(float(np.sum(info)), 1e-12))
    explained = 1.0 - float(fit["resid"][i]) / max(fit["flat"], 1e-12)
    return Light(
        fine[i],
        float(np.clip(diffuse, 0.0, MAX_DIFFUSE)),
        float(np.clip(explained, 0.0, 1.0)),
        len(normals),
    )


def _fit_directions(
    normals: np.ndarray, luma: np.ndarray, onehot: np.ndarray, dirs: np.ndarray
) -> dict:
    """Per light direction (D,3): each group's least-squares line of brightness on
    ``max(0, n . l)`` (slope >= 0), the summed residual (D,), and the groups' spread of
    ``max(0, n . l)`` (k,D); ``flat``: the residual with no light (each group's mean)."""
    m = np.maximum(normals @ dirs.T, 0.0)  # (P,D)
    count = onehot.sum(0)[:, None]  # (k,1), every group non-empty
    sy, syy = onehot.T @ luma, onehot.T @ luma**2  # (k,)
    sx, sxx, sxy = onehot.T @ m, onehot.T @ m**2, onehot.T @ (m * luma[:, None])  # (k,D)
    var_x = count * sxx - sx**2
    slope = np.where(var_x > 1e-9, (count * sxy - sx * sy[:, None]) / np.maximum(var_x, 1e-9), 0)
    slope = np.maximum(slope, 0.0)  # a light only adds
    icept = (sy[:, None] - slope * sx) / count
    resid = syy[:, None] - 2 * icept * sy[:, None] - 2 * slope * sxy
    resid += count * icept**2 + 2 * icept * slope * sx + slope**2 * sxx
    flat = float(np.sum(syy - sy**2 / count[:, 0]))
    return {
        "slope": slope,
        "icept": icept,
        "resid": resid.sum(0),
        "spread": np.maximum(var_x, 0.0) / count,
        "flat": flat,
    }


def _around(direction: np.ndarray, degrees: float = 8.0, count: int = 300) -> np.ndarray:
    """(count,3) unit directions in a cap of ``degrees`` around ``direction`` (itself
    first), kept on the upper hemisphere."""
    k = np.arange(count) + 0.5
    cos_t = 1.0 - (1.0 - np.cos(np.radians(degrees))) * k / count
    sin_t = np.sqrt(1.0 - cos_t**2)
    phi = k * np.pi * (3.0 - np.sqrt(5.0))
    local = np.stack([sin_t * np.cos(phi), sin_t * np.sin(phi), cos_t], -1)
    z = direction / np.linalg.norm(direction)
    x = np.cross([0.0, 1.0, 0.0] if abs(z[0]) > 0.9 else [1.0, 0.0, 0.0], z)
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    cap = np.vstack([z, local @ np.stack([x, y, z])])
    return cap[cap[:, 2] > 0]


def estimate_light(scene: Scene, boxes: list[OrientedBox]) -> Light | None:
    """The scan's light as the surfaces inside ``boxes`` show it in the scan's views."""
    parts = [seen_surface(scene, box) for box in boxes]
    return fit_light(np.concatenate([p[0] for p in parts]), np.concatenate([p[1] for p in parts]))


def relight_grid(
    field: Field, target: OrientedBox, motion: np.ndarray, light: Light, n: int = GRID
) -> Relight:
    """The ratio ``shade(R n) / shade(n)`` for an object carried by ``motion`` (4,4) into
    ``target``, over the region of ``field``'s coordinates that the target reads
    (:func:`weights_region`), under ``light``; fading to 1 away from surfaces (nothing to
    relight)."""
    lo, hi = weights_region(target, motion)
    rotation = np.asarray(motion, dtype=np.float64)[:3, :3]
    axes = [np.linspace(lo[k], hi[k], n) for k in range(3)]
    centres = np.stack(np.meshgrid(*axes, indexing="ij"), -1).reshape(-1, 3)
    points = torch.as_tensor(centres, dtype=torch.float32, device=field.aabb.device)
    step = _step_m(np.asarray(target.size_m))  # the object's box, not the turned bounds
    with torch.no_grad():
        sigma = torch.cat([field.density(c) for c in points.split(65536)])
    opacity = (1 - torch.exp(-sigma * step)).reshape(n, n, n).cpu().numpy()
    # normals only near a surface (an opacity transition within two cells): elsewhere
    # there is nothing to see (empty space) or nothing seen (inside a solid)
    near = (ndimage.maximum_filter(opacity, 5) > 0.3) & (ndimage.minimum_filter(opacity, 5) < 0.7)
    idx = np.nonzero(near.reshape(-1))[0]
    ratio = np.ones(n**3)
    if len(idx):
        gradient = _gradient(field, points[torch.as_tensor(idx, device=points.device)], step)
        normals = _outward(gradient).cpu().numpy().astype(np.float64)
        turned = light.shading(normals @ rotation.T) / light.shading(normals)
        weight = np.clip(gradient.norm(dim=-1).cpu().numpy() / SURFACE, 0.0, 1.0)
        ratio[idx] = 1.0 + weight * (turned - 1.0)
    device = field.aabb.device
    grid = torch.as_tensor(ratio.reshape(n, n, n), device=device)
    return Relight(torch.as_tensor(lo, device=device), torch.as_tensor(hi, device=device), grid)


def turn_deg(motion: np.ndarray) -> float:
    """How far the rigid ``motion`` (4,4) turns, in degrees (about any axis)."""
    cos = (np.trace(np.asarray(motion, dtype=np.float64)[:3, :3]) - 1.0) / 2.0
    return float(np.degrees(np.arccos(np.clip(cos, -1.0, 1.0))))


def weights_region(target: OrientedBox, motion: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The axis-aligned box (lo, hi) of the weights' coordinates that a carried part owning
    ``target`` under ``motion`` (4,4) reads."""
    inverse = np.linalg.inv(np.asarray(motion, dtype=np.float64))
    corners = target.corners() @ inverse[:3, :3].T + inverse[:3, 3]
    return corners.min(0), corners.max(0)

"""An object's surface from a radiance field: density sampled on a grid in the object's box,
marching cubes (scikit-image) for contact points, outward normals from the density gradient
(finite differences: the hash-grid kernel gives no gradient with respect to positions)."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
import torch
from scipy.ndimage import map_coordinates
from skimage.measure import marching_cubes

from neoedit.errors import NeoError
from neoedit.geometry import OrientedBox

MAX_SAMPLES = 8_000_000
"""Largest density grid sampled for one object."""
DensityFn = Callable[[torch.Tensor], torch.Tensor]
"""World points (N,3) -> density (N,) as the scene renders (occupancy applied)."""


@dataclass
class SurfaceConfig:
    voxel_m: float = 0.003
    """Grid spacing of the density samples."""
    level: float = 100.0
    """Density [1/m] of the surface (about 40 % opacity over 5 mm)."""
    margin_m: float = 0.015
    """The grid covers the object's box grown by this much (sides and top)."""
    above_support_m: float = 0.004
    """The grid starts this far above the box's bottom, so the table is not the object."""


@dataclass
class Volume:
    """Density on a regular grid in a box's local frame (for contacts and ray marching)."""

    box: OrientedBox
    origin: np.ndarray
    """Local coordinates of sample [0, 0, 0]."""
    voxel_m: float
    values: np.ndarray
    """(nx, ny, nz) density."""
    _gradients: list[np.ndarray] | None = field(default=None, repr=False)

    def to_world(self, local: np.ndarray) -> np.ndarray:
        return local @ self.box.rotation.T + np.asarray(self.box.center_m)

    def to_local(self, world: np.ndarray) -> np.ndarray:
        return self.box.world_to_local(world)

    def outward_normals(self, local: np.ndarray) -> np.ndarray:
        """Unit normals (..., 3), local frame, down the density gradient (finite differences,
        computed once per volume); zero where the density is flat."""
        if self._gradients is None:
            self._gradients = np.gradient(self.values, self.voxel_m)
        g = np.stack([self.sample(local, gk) for gk in self._gradients], -1)
        norm = np.linalg.norm(g, axis=-1, keepdims=True)
        return np.where(norm > 1e-9, -g / np.maximum(norm, 1e-12), 0.0)

    def sample(self, local: np.ndarray, values: np.ndarray | None = None) -> np.ndarray:
        """Trilinear density (or ``values``) at local points (..., 3); 0 outside the grid."""
        idx = (local.reshape(-1, 3) - self.origin) / self.voxel_m
        grid = self.values if values is None else values
        out = map_coordinates(grid, idx.T, order=1, mode="constant", cval=0.0)
        return out.reshape(local.shape[:-1])


@dataclass
class Surface:
    points_m: np.ndarray
    """(N,3) world surface points (marching-cubes vertices)."""
    normals: np.ndarray
    """(N,3) outward unit normals (down the density gradient)."""
    volume: Volume


@torch.no_grad()
def sample_volume(density: DensityFn, box: OrientedBox, cfg: SurfaceConfig) -> Volume:
    grown = box.grown(cfg.margin_m)
    half = grown.half_extents
    lo = np.array([-half[0], -half[1], -box.half_extents[2] + cfg.above_support_m])
    hi = half
    n = np.maximum(2, np.ceil((hi - lo) / cfg.voxel_m).astype(int) + 1)
    if int(np.prod(n)) > MAX_SAMPLES:
        raise NeoError(
            f"the object's box ({np.round(box.size_m, 3).tolist()} m) is too large to grasp at "
            f"{cfg.voxel_m * 1000:.1f} mm ({int(np.prod(n)):,} samples > {MAX_SAMPLES:,})"
        )
    axes = [lo[k] + cfg.voxel_m * np.arange(n[k]) for k in range(3)]
    local = np.stack(np.meshgrid(*axes, indexing="ij"), -1).reshape(-1, 3)
    volume = Volume(box, lo, cfg.voxel_m, np.zeros(tuple(n)))
    world = torch.as_tensor(volume.to_world(local), dtype=torch.float32)
    values = torch.cat([density(chunk) for chunk in world.split(65536)])
    volume.values = values.cpu().numpy().astype(np.float64).reshape(tuple(n))
    return volume


def object_surface(density: DensityFn, box: OrientedBox, cfg: SurfaceConfig) -> Surface:
    """Surface points and outward normals of what the field holds in ``box``."""
    volume = sample_volume(density, box, cfg)
    if float(volume.values.max()) <= cfg.level:
        raise NeoError(
            f"no surface in the object's box (peak density {volume.values.max():.0f} /m <= "
            f"{cfg.level:.0f} /m): nothing to grasp there"
        )
    # close the grid's faces so a surface cut by the grid edge is still closed
    padded = np.pad(volume.values, 1, constant_values=0.0)
    verts, _, _, _ = marching_cubes(padded, level=cfg.level, spacing=(cfg.voxel_m,) * 3)
    local = verts - cfg.voxel_m + volume.origin
    normals = volume.outward_normals(local)
    ok = np.linalg.norm(normals, axis=-1) > 0.5
    return Surface(volume.to_world(local[ok]), normals[ok] @ box.rotation.T, volume)

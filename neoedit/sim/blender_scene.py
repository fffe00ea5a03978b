"""A Blender-format synthetic scene from NEO-Sim objects: RGBA renders, no table, no robot.

The NeRF paper's synthetic scenes (``transforms_{train,test}.json``, ``camera_angle_x``,
RGBA PNGs with a transparent background, the object inside the +-1.5 cube, cameras on the
upper hemisphere at radius ~4) are what many users try first. Those files cannot be
downloaded here, so this writes a scene in exactly that convention from the objects that
ship with ``pybullet_data``, scaled up to fill about +-1 unit. It is a regression target for
training on RGBA data (random backgrounds, the scene box of the convention, the occupancy
grid and the fast march) that does not depend on NEO-Sim's table, depth or labels.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from neoedit.cameras import look_at
from neoedit.sim._pybullet import pb
from neoedit.sim.world import resolve_asset
from neoedit.utils.io import atomic_write_json, write_png
from neoedit.utils.progress import track


@dataclass
class BlenderObject:
    urdf: str
    """A ``pybullet_data:`` reference (or a path) to the object's URDF."""
    position: tuple[float, float, float]
    """Where the object's base goes, in scene units."""
    scale: float
    """PyBullet's global scaling (catalogue objects are ~10 cm: ~10 makes them ~1 unit)."""
    rpy_deg: tuple[float, float, float] = (0.0, 0.0, 0.0)
    rgba: tuple[float, float, float, float] | None = None


def _default_objects() -> list[BlenderObject]:
    return [
        BlenderObject("pybullet_data:duck_vhacd.urdf", (-0.45, -0.3, 0.0), 9.0, (90.0, 0.0, 30.0)),
        BlenderObject("pybullet_data:soccerball.urdf", (0.55, 0.35, 0.0), 0.9),
        BlenderObject("pybullet_data:lego/lego.urdf", (0.35, -0.6, -0.35), 12.0, (0.0, 0.0, 20.0)),
        BlenderObject("pybullet_data:objects/mug.urdf", (-0.4, 0.55, -0.45), 7.0),
        BlenderObject(
            "pybullet_data:cube_small.urdf", (0.1, 0.0, -0.55), 6.0, rgba=(0.15, 0.3, 0.85, 1.0)
        ),
    ]


@dataclass
class BlenderSceneSpec:
    objects: list[BlenderObject] = field(default_factory=_default_objects)
    size: int = 200
    """Image width and height in pixels (the published scenes: 800)."""
    n_train: int = 100
    n_test: int = 25
    radius: float = 4.0
    """Camera distance from the origin (the published scenes: ~4.03)."""
    camera_angle_x: float = 0.6911112070083618
    """Horizontal field of view [rad], the published scenes' value."""
    seed: int = 0


def hemisphere_poses(n: int, radius: float, rng: np.random.Generator) -> np.ndarray:
    """(n, 4, 4) cameras at random points of the upper hemisphere looking at the origin."""
    az = rng.uniform(0.0, 2.0 * np.pi, n)
    el = np.arcsin(rng.uniform(0.05, 0.95, n))  # uniform in area over the hemisphere
    eyes = radius * np.stack([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)], -1)
    return np.stack([look_at(eye, np.zeros(3)) for eye in eyes])


def _render(client: int, c2w: np.ndarray, size: int, fov_x: float) -> np.ndarray:
    view = np.linalg.inv(c2w).T.reshape(-1).tolist()
    proj = pb.computeProjectionMatrixFOV(np.rad2deg(fov_x), 1.0, 0.5, 20.0)
    _, _, rgba, _, seg = pb.getCameraImage(
        size,
        size,
        view,
        proj,
        renderer=pb.ER_TINY_RENDERER,
        lightDirection=[0.4, 0.3, 1.0],
        lightAmbientCoeff=0.55,
        lightDiffuseCoeff=0.45,
        lightSpecularCoeff=0.0,
        shadow=1,
        physicsClientId=client,
    )
    rgba = np.asarray(rgba, dtype=np.uint8).reshape(size, size, 4).copy()
    hit = np.asarray(seg, dtype=np.int64).reshape(size, size) >= 0
    rgba[..., 3] = np.where(hit, 255, 0)
    rgba[~hit, :3] = 0  # a transparent pixel carries no colour (Blender writes black)
    return rgba


def write_blender_scene(spec: BlenderSceneSpec, out: Path) -> dict[str, Any]:
    """Render ``spec`` into ``out`` (``transforms_train.json``, ``transforms_test.json``,
    ``train/r_N.png``, ``test/r_N.png``). Returns a summary."""
    out = Path(out)
    rng = np.random.default_rng(spec.seed)
    client = pb.connect(pb.DIRECT)
    try:
        for obj in spec.objects:
            rot = pb.getQuaternionFromEuler(np.deg2rad(obj.rpy_deg).tolist())
            body = pb.loadURDF(
                str(resolve_asset(obj.urdf, None, None)),
                list(obj.position),
                rot,
                globalScaling=obj.scale,
                useFixedBase=True,
                physicsClientId=client,
            )
            if obj.rgba is not None:
                for vs in pb.getVisualShapeData(body, physicsClientId=client):
                    pb.changeVisualShape(body, vs[1], rgbaColor=obj.rgba, physicsClientId=client)
        for split, n in (("train", spec.n_train), ("test", spec.n_test)):
            frames = []
            for i, c2w in enumerate(
                track(hemisphere_poses(n, spec.radius, rng), f"render {split}")
            ):
                write_png(
                    out / split / f"r_{i}.png", _render(client, c2w, spec.size, spec.camera_angle_x)
                )
                frames.append(
                    {"file_path": f"./{split}/r_{i}", "transform_matrix": np.round(c2w, 8).tolist()}
                )
            atomic_write_json(
                out / f"transforms_{split}.json",
                {"camera_angle_x": spec.camera_angle_x, "frames": frames},
            )
    finally:
        pb.disconnect(client)
    return {"n_train": spec.n_train, "n_test": spec.n_test, "size": spec.size}

"""Where each object of a trained scan loses its fidelity: the field, the rendering or the data.

    python benchmarks/bench_objects.py SCENE DATA [--views 12] [--ceiling-steps 400]

SCENE is a trained scene (``neo train``), DATA its dataset with depth and instance images
(a NEO-Sim scan). For every instance (table, robot arm, each object), on ``--views`` of the
*training* views (masks eroded by 2 px, so edges between instances do not count):

- ``train PSNR`` and ``colour``: the field's render against the photo on those pixels, and
  the worst channel of the difference of the mean colours (0-255);
- ``within / front / behind``: the share of each ray's light that ends within +-3 mm of the
  scan's own depth, nearer than that, or beyond it. A fitted surface is opaque where the
  depth says; light behind it means the surface is semi-transparent;
- ``ceiling``: the PSNR on held-out *views* (every 10th training view, the same eroded
  masks) of a fresh field of the scene's architecture fitted *directly* to the object's
  surface points in the other training views (positions from the depth images, colours
  from the photos), without volume rendering. An estimate of what this field can reach
  from these photos when sampling and opacity do not enter (``--ceiling-steps`` at a
  constant learning rate, not a converged bound): an aliased texture (a renderer without
  anti-aliasing) caps it. ``--ceiling-steps 0`` skips it.

The renders use the training sampler without the occupancy grid (the field's own answer,
not the fast renderer's). Prints a table and the command that produced it.
"""

from __future__ import annotations

import argparse
import shlex
import sys
from pathlib import Path

import numpy as np
import torch
from scipy.ndimage import binary_erosion

from neoedit.cameras.rays import CameraTensors
from neoedit.data import SceneData, load_scene_data
from neoedit.errors import NeoError
from neoedit.fields.radiance import RadianceField
from neoedit.rendering.renderer import render_rays
from neoedit.scene import Scene, load_scene
from neoedit.utils.optim import field_param_groups, make_adam

SURFACE_WINDOW_M = 0.003
"""Light ending this close to the scan's depth counts as on the surface."""


def object_pixels(data: SceneData, view: int, instance: int, erode: int = 2) -> np.ndarray:
    """(H, W) bool: the instance's pixels in ``view`` with depth, eroded by ``erode`` px
    (``data`` has instance and depth images: :func:`main` checks)."""
    mask = np.asarray(data.instance_ids)[view] == instance
    if erode:
        mask = binary_erosion(mask, iterations=erode)
    return mask & (np.asarray(data.depth_m)[view] > 0)


@torch.no_grad()
def render_stats(scene: Scene, data: SceneData, views: np.ndarray, instance: int) -> dict:
    """PSNR, mean-colour error and where the light ends, over the instance's pixels."""
    cams = CameraTensors(data.cameras)
    sums = {"sq": 0.0, "within": 0.0, "front": 0.0, "behind": 0.0, "n": 0}
    rendered, truth = [], []
    chunk = scene.meta.render.chunk_rays
    for view in views:
        mask = object_pixels(data, int(view), instance)
        ys, xs = np.nonzero(mask)
        for start in range(0, len(ys), chunk):
            _accumulate(scene, data, cams, int(view), ys[start : start + chunk],
                        xs[start : start + chunk], sums, rendered, truth)  # fmt: skip
    n = sums["n"]
    if n == 0:
        return {"pixels": 0}
    colour = (torch.cat(rendered).mean(0) - torch.cat(truth).mean(0)).abs().max() * 255
    return {
        "pixels": n,
        "train_psnr": -10.0 * np.log10(max(sums["sq"] / n, 1e-12)),
        "colour": float(colour),
        **{k: 100.0 * sums[k] / n for k in ("within", "front", "behind")},
    }


def _accumulate(
    scene: Scene,
    data: SceneData,
    cams: CameraTensors,
    view: int,
    ys: np.ndarray,
    xs: np.ndarray,
    sums: dict,
    rendered: list[torch.Tensor],
    truth: list[torch.Tensor],
) -> None:
    """Render the pixels (ys, xs) of ``view`` and add their statistics to ``sums``."""
    v, u = torch.as_tensor(ys), torch.as_tensor(xs)
    rays = cams.rays(torch.full_like(v, view), v, u)
    out = render_rays(scene.field, None, rays, scene.meta.render, scene.background)
    t_gt = torch.as_tensor(np.asarray(data.depth_m)[view][ys, xs]) / rays.z_scale
    offset = out["t_mid"] - t_gt[:, None]
    w = out["weights"]
    sums["within"] += float((w * (offset.abs() < SURFACE_WINDOW_M)).sum())
    sums["front"] += float((w * (offset <= -SURFACE_WINDOW_M)).sum())
    sums["behind"] += float((w * (offset >= SURFACE_WINDOW_M)).sum())
    target = torch.as_tensor(data.images[view][ys, xs]).float() / 255.0
    sums["sq"] += float(((out["rgb"] - target) ** 2).mean(-1).sum())
    sums["n"] += len(v)
    rendered.append(out["rgb"])
    truth.append(target)


def surface_points(
    data: SceneData, views: np.ndarray, instance: int
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """World points (N,3), view directions (N,3) and colours (N,3) of the instance's pixels
    in ``views``, placed at the scan's depth (pixel centres)."""
    cams, depth = data.cameras, np.asarray(data.depth_m)
    points, dirs, colours = [], [], []
    for view in views:
        mask = object_pixels(data, int(view), instance)
        world = cams.backproject_depth(int(view), depth[view])[mask]
        d = world - cams.camera_to_world[view][:3, 3]
        points.append(world)
        dirs.append(d / np.linalg.norm(d, axis=1, keepdims=True))
        colours.append(data.images[view][mask] / 255.0)
    p, d, c = (
        torch.as_tensor(np.concatenate(a), dtype=torch.float32) for a in (points, dirs, colours)
    )
    return p, d, c


def ceiling_psnr(scene: Scene, data: SceneData, instance: int, steps: int, seed: int = 0) -> float:
    """PSNR on every 10th training view of a fresh field of the scene's architecture fitted
    to the instance's surface points in the other training views (nan: too few pixels)."""
    train = data.indices("train")
    held_views = np.zeros(len(train), bool)
    held_views[::10] = True
    points, dirs, colours = surface_points(data, train[~held_views], instance)
    test_points, test_dirs, test_colours = surface_points(data, train[held_views], instance)
    if len(points) == 0 or len(test_points) == 0:
        return float("nan")
    gen = torch.Generator().manual_seed(seed)
    field = RadianceField(scene.meta.field, scene.field.aabb.cpu(), seed=seed)
    optimizer = make_adam(field_param_groups(field, 2e-2), 2e-2, "cpu")
    for _ in range(steps):
        batch = torch.randint(0, len(points), (4096,), generator=gen)
        _, rgb = field(points[batch], dirs[batch])
        loss = ((rgb - colours[batch]) ** 2).mean()
        optimizer.zero_grad(set_to_none=True)
        loss.backward()
        optimizer.step()
    with torch.no_grad():
        _, rgb = field(test_points, test_dirs)
        mse = float(((rgb - test_colours) ** 2).mean())
    return -10.0 * np.log10(max(mse, 1e-12))


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("scene", type=Path)
    parser.add_argument("data", type=Path)
    parser.add_argument("--views", type=int, default=12, help="training views measured")
    parser.add_argument("--ceiling-steps", type=int, default=400)
    args = parser.parse_args(argv)
    if args.views < 1 or args.ceiling_steps < 0:
        parser.error("--views must be at least 1 and --ceiling-steps at least 0")
    try:
        data = load_scene_data(args.data)
        scene = load_scene(args.scene)
    except NeoError as e:
        raise SystemExit(str(e)) from e
    if data.instance_ids is None or data.depth_m is None:
        raise SystemExit(f"{args.data}: needs depth and instance images (a NEO-Sim scan)")
    train = data.indices("train")
    views = train[:: max(1, len(train) // args.views)][: args.views]
    print(
        "command: python benchmarks/bench_objects.py "
        + shlex.join(sys.argv[1:] if argv is None else argv)
    )
    print(f"scene {args.scene} (step {scene.meta.step}), {len(views)} training views")
    header = (
        "| instance | pixels | train PSNR | colour /255 | within ±3 mm | front | behind | ceiling |"
    )
    print(header)
    print("|" + "---|" * (header.count("|") - 1))
    for instance, name in sorted(data.instance_names.items()):
        stats = render_stats(scene, data, views, instance)
        if stats["pixels"] == 0:
            continue
        ceiling = (
            f"{ceiling_psnr(scene, data, instance, args.ceiling_steps):.2f} dB"
            if args.ceiling_steps > 0
            else "-"
        )
        print(
            f"| {name} | {stats['pixels']} | {stats['train_psnr']:.2f} dB | {stats['colour']:.1f} "
            f"| {stats['within']:.0f} % | {stats['front']:.0f} % | {stats['behind']:.0f} % "
            f"| {ceiling} |",
            flush=True,
        )


if __name__ == "__main__":
    main()

"""Pictures of a query: per view, the render with the box(es) drawn and the relevancy map."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch

from neoedit.cameras import Cameras
from neoedit.cameras.rays import CameraTensors
from neoedit.language.localize import QueryConfig, QueryResult
from neoedit.language.relevancy import relevancy
from neoedit.language.text import TextEncoder
from neoedit.scene import Scene
from neoedit.utils.io import write_png
from neoedit.utils.progress import track
from neoedit.viz.boxes import draw_box, relevancy_overlay
from neoedit.viz.contact_sheet import tile_images

COLORS = [(255, 40, 40), (40, 200, 255), (255, 200, 0), (120, 255, 80), (255, 80, 220)]


@torch.no_grad()
def write_query_images(
    scene: Scene,
    results: list[QueryResult],
    prompts: list[str],
    text: TextEncoder,
    cameras: Cameras,
    out: Path,
    cfg: QueryConfig | None = None,
) -> Path:
    """Render every camera; write ``query.png``: one row per view, [render + boxes,
    relevancy of each prompt]. Returns the image path."""
    cfg = cfg or QueryConfig()
    device = scene.field.aabb.device
    cams = CameraTensors(cameras, device)
    emb = text.encode([*prompts, *cfg.canonical])
    query_emb, canon = emb[: len(prompts)], emb[len(prompts) :]
    tiles, labels = [], []
    for i in track(range(len(cameras)), "query views"):
        h, w = int(cameras.height[i]), int(cameras.width[i])
        r = scene.render_image(cams, i, h, w)
        rgb = (r["rgb"].clamp(0, 1).cpu().numpy() * 255).round().astype(np.uint8)
        boxed = rgb
        for k, res in enumerate(results):  # coloured as its prompt's column (misses skip)
            k = prompts.index(res.prompt) if res.prompt in prompts else k
            boxed = draw_box(boxed, cameras, i, res.box, COLORS[k % len(COLORS)])
        tiles.append(boxed)
        labels.append(f"view {i}")
        valid = (r["accumulation"] > 0.5).cpu().numpy()
        pts = torch.as_tensor(
            cameras.backproject_depth(i, r["depth_z"].cpu().numpy()), dtype=torch.float32
        )
        feats = scene.language.language(pts.reshape(-1, 3).to(device)).cpu()  # type: ignore[union-attr]
        for k, prompt in enumerate(prompts):
            rel = relevancy(feats, query_emb[k], canon).reshape(h, w).numpy()
            tiles.append(relevancy_overlay(rgb, rel, valid))
            labels.append(prompt)
    out.mkdir(parents=True, exist_ok=True)
    path = out / "query.png"
    write_png(path, tile_images(tiles, cols=1 + len(prompts), labels=labels))
    return path

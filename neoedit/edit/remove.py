"""``neo remove``: object removal by neural-field resampling + progressive inpainting
(paper Sec. III-A, III-B) as a new scene version.

* Removal alone (``inpaint=False``) is instant: the new version records the box and every
  render cuts it out of the rays (``resample``: samples are drawn on the rest of each ray) or
  zeroes the density inside it (``suppress``: the DFF-style baseline).
* With inpainting, the new version's weights are trained (:mod:`neoedit.edit.refine`) so
  the removal is persistent and the hidden surface is completed; no box is cut at render
  time any more.

The language side of a removal: surface points inside the box are dropped from the
version's query cloud, so the removed object can no longer be found.
"""

from __future__ import annotations

import dataclasses
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch

from neoedit.cameras.rays import CameraTensors
from neoedit.data import load_scene_data
from neoedit.edit.history import check_output, new_version
from neoedit.edit.inpaint import make_inpainter
from neoedit.edit.masks import grown_box
from neoedit.edit.refine import RefineConfig, refine_removal
from neoedit.edit.views import VirtualViewConfig, concat_cameras, virtual_cameras
from neoedit.errors import NeoError
from neoedit.geometry import OrientedBox
from neoedit.scene import Scene, load_scene, save_scene
from neoedit.utils.io import write_png
from neoedit.viz.contact_sheet import tile_images

REMOVAL_MODES = ("resample", "suppress")


@dataclass
class RemoveConfig:
    removal: str = "resample"
    """'resample' (cut the box out of every ray, sample the rest) or 'suppress' (zero density
    in the box, standard sampling: the DFF-style baseline)."""
    inpaint: bool = True
    """Complete what the object hid (virtual views + inpainting + training). Off: the instant
    removal preview, no training."""
    margin_m: float = 0.01
    """The box is grown by this much on its sides and top (its bottom stays on the support)."""
    inpainter: str = "fsr"
    """'fsr' (opencv-contrib frequency-selective reconstruction; the default: best Out-PSNR of
    the OpenCV methods on NEO-Sim, see benchmarks/RESULTS.md), 'telea', 'ns' (OpenCV) or
    'diffusion' (local diffusers pipeline, --inpaint-path)."""
    inpaint_path: str | None = None
    """Local diffusers inpainting pipeline directory (for --inpainter diffusion)."""
    inpaint_prompt: str = "an empty table surface"
    """Text prompt of the diffusion inpainter."""
    views: VirtualViewConfig = field(default_factory=VirtualViewConfig)
    refine: RefineConfig = field(default_factory=RefineConfig)


def remove_object(
    scene_dir: Path,
    out: Path,
    boxes: list[OrientedBox],
    cfg: RemoveConfig,
    prompt: str | None = None,
    device: torch.device | str = "cpu",
    overwrite: bool = False,
) -> Scene:
    """Write a new version of the scene at ``out`` with ``boxes`` removed; returns it."""
    if cfg.removal not in REMOVAL_MODES:
        raise NeoError(f"unknown removal {cfg.removal!r} (choose from {', '.join(REMOVAL_MODES)})")
    if not boxes:
        raise NeoError("nothing to remove: give a prompt or --box")
    check_output(scene_dir, out, overwrite)
    t0 = time.perf_counter()
    parent = load_scene(scene_dir, device)
    work = [grown_box(b, cfg.margin_m) for b in boxes]
    record = {
        "type": "remove",
        "prompt": prompt,
        "boxes": [b.to_dict() for b in boxes],
        "removal": cfg.removal,
        "inpaint": cfg.inpainter if cfg.inpaint else None,
        "config": dataclasses.asdict(cfg),
    }
    child = new_version(parent, record)
    box_dicts = [b.to_dict() for b in work]
    report = Path(out) / "report"
    strips: list[tuple[int, list[np.ndarray]]] = []
    if not cfg.inpaint:
        if cfg.removal == "resample":
            child.meta.cut_boxes += box_dicts
        else:
            child.meta.suppress_boxes += box_dicts
    else:
        inpainter = make_inpainter(cfg.inpainter, cfg.inpaint_path, cfg.inpaint_prompt, str(device))
        data = load_scene_data(Path(parent.meta.data_path))
        train_cams = data.cameras.subset(data.split["train"])
        virtual = concat_cameras([virtual_cameras(b, train_cams, cfg.views) for b in boxes])

        def keep_strip(k, rendered, masks, inpainted):
            masked = [
                np.where(m[..., None], np.array([255, 0, 255], np.uint8), r)
                for r, m in zip(rendered, masks, strict=True)
            ]
            strips.append((k, [*rendered, *masked, *inpainted]))

        child.meta.edits[-1]["timings"] = refine_removal(
            child, data, work, virtual, inpainter, cfg.refine, keep_strip, cfg.removal
        )
    if child.surface_points_m is not None:
        pts = child.surface_points_m.cpu().numpy()
        keep = np.ones(len(pts), bool)
        for b in work:
            keep &= ~b.contains(pts)
        child.surface_points_m = child.surface_points_m[
            torch.as_tensor(keep, device=child.surface_points_m.device)
        ]
    child.meta.edits[-1]["seconds"] = round(time.perf_counter() - t0, 2)
    save_scene(Path(out), child)
    _write_report(report, parent, child, strips)
    return child


@torch.no_grad()
def _write_report(
    report: Path, parent: Scene, child: Scene, strips: list[tuple[int, list[np.ndarray]]]
) -> None:
    """before_after.png (three training views, before | after) and virtual_views_round_K.png
    (rows: rendered, masked, inpainted)."""
    from neoedit.rendering.export import scene_cameras

    for k, tiles in strips:
        n = len(tiles) // 3
        write_png(report / f"virtual_views_round_{k}.png", tile_images(tiles, cols=n))
    try:
        cameras, _, split = scene_cameras(Path(parent.meta.data_path))
    except NeoError:
        return
    train = split["train"]
    pick = train[np.linspace(0, len(train) - 1, min(3, len(train))).round().astype(int)]
    cams = CameraTensors(cameras, parent.field.aabb.device)
    tiles, labels = [], []
    for i in pick:
        h, w = int(cameras.height[i]), int(cameras.width[i])
        for name, version in (("before", parent), ("after", child)):
            rgb = version.render_image(cams, int(i), h, w)["rgb"]
            tiles.append((rgb.clamp(0, 1).cpu().numpy() * 255).round().astype(np.uint8))
            labels.append(f"{name} (view {i})")
    write_png(report / "before_after.png", tile_images(tiles, cols=2, labels=labels))

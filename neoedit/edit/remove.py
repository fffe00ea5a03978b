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
from neoedit.edit.history import check_output, new_version
from neoedit.edit.inpaint import Inpainter, make_inpainter
from neoedit.edit.masks import grown_box, grown_box_clear_of
from neoedit.edit.refine import RefineConfig, refine_removal
from neoedit.edit.views import VirtualViewConfig, concat_cameras, virtual_cameras
from neoedit.errors import NeoError
from neoedit.geometry import OrientedBox
from neoedit.rendering.export import scene_cameras
from neoedit.scene import Scene, load_scene, save_scene
from neoedit.utils.io import write_png
from neoedit.viz.boxes import scaled_cameras
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
    """The box is grown by this much on its sides and top (its bottom stays on the support);
    a side stops short of a neighbouring object (surface points whose language feature
    differs from the removed object's), so the edit does not cut into it."""
    neighbour_similarity: float = 0.8
    """Surface points next to the box whose language feature has a cosine similarity below
    this to the mean feature inside the box count as another object."""
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
    inpainter: Inpainter | None = None,
) -> Scene:
    """Write a new version of the scene at ``out`` with ``boxes`` removed; returns it.
    ``inpainter`` overrides ``cfg.inpainter`` with any object of the :class:`Inpainter`
    protocol (your own 2-D inpainting model)."""
    if cfg.removal not in REMOVAL_MODES:
        raise NeoError(f"unknown removal {cfg.removal!r} (choose from {', '.join(REMOVAL_MODES)})")
    if not boxes:
        raise NeoError("nothing to remove: give a prompt or --box")
    check_output(scene_dir, out, overwrite)
    t0 = time.perf_counter()
    parent = load_scene(scene_dir, device)
    work = working_boxes(parent, boxes, cfg)
    record = {
        "type": "remove",
        "prompt": prompt,
        "boxes": [b.to_dict() for b in boxes],
        "edit_boxes": [b.to_dict() for b in work],
        "removal": cfg.removal,
        "inpaint": (type(inpainter).__name__ if inpainter else cfg.inpainter)
        if cfg.inpaint
        else None,
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
        if inpainter is None:
            inpainter = make_inpainter(
                cfg.inpainter, cfg.inpaint_path, cfg.inpaint_prompt, str(device)
            )
        cameras, _, split = scene_cameras(Path(parent.meta.data_path))
        train_cams = cameras.subset(split["train"])
        virtual = concat_cameras([virtual_cameras(b, train_cams, cfg.views) for b in boxes])

        def keep_strip(k, rendered, masks, inpainted):
            masked = [
                np.where(m[..., None], np.array([255, 0, 255], np.uint8), r)
                for r, m in zip(rendered, masks, strict=True)
            ]
            strips.append((k, [*rendered, *masked, *inpainted]))

        child.meta.edits[-1]["timings"] = refine_removal(
            child, work, virtual, inpainter, cfg.refine, keep_strip, cfg.removal, train_cams
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


def working_boxes(scene: Scene, boxes: list[OrientedBox], cfg: RemoveConfig) -> list[OrientedBox]:
    """The boxes an edit cuts, inpaints and regularises: each seated on the table and grown
    by ``cfg.margin_m``, short of neighbouring objects."""
    seated = [seated_on_support(scene, b) for b in boxes]
    return [grown_box_clear_of(b, cfg.margin_m, neighbour_points(scene, b, cfg)) for b in seated]


def seated_on_support(scene: Scene, box: OrientedBox, ring_m: float = 0.03) -> OrientedBox:
    """``box`` with its bottom raised to the support surface when it reaches below it (a
    query box can end a few mm under the table top; cutting that would open a hole in the
    table). The support is the median height of the surface points in a ring around the
    box's footprint near its bottom; the box is returned unchanged without such points."""
    if scene.surface_points_m is None:
        return box
    pts = scene.surface_points_m.cpu().numpy().astype(np.float64)
    local = box.world_to_local(pts)
    half = box.half_extents
    outside = (np.abs(local[:, :2]) > half[:2] + 0.005).any(1)
    near = (np.abs(local[:, :2]) <= half[:2] + ring_m).all(1)
    low = np.abs(local[:, 2] + half[2]) < 0.02
    ring = outside & near & low
    if int(ring.sum()) < 20:
        return box
    support = float(np.median(pts[ring, 2]))
    bottom = box.center_m[2] - box.size_m[2] / 2
    top = box.center_m[2] + box.size_m[2] / 2
    return box if support <= bottom or support >= top - 0.005 else box.with_bottom(support)


@torch.no_grad()
def neighbour_points(scene: Scene, box: OrientedBox, cfg: RemoveConfig) -> np.ndarray:
    """(K,3) surface points in the margin around ``box`` that belong to something else: above
    the box's bottom (not the support surface) and unlike the object in the language field.
    Empty for scenes without a language field."""
    if scene.language is None or scene.surface_points_m is None or cfg.margin_m <= 0:
        return np.zeros((0, 3))
    pts = scene.surface_points_m.cpu().numpy().astype(np.float64)
    local = box.world_to_local(pts)
    inside = box.contains(pts)
    shell = grown_box(box, cfg.margin_m).contains(pts) & ~inside
    shell &= local[:, 2] > -box.half_extents[2] + 0.01  # not the support (+-5 mm in NEO-Sim)
    if not inside.any() or not shell.any():
        return np.zeros((0, 3))
    device = scene.surface_points_m.device
    feats = scene.language.language(
        torch.as_tensor(pts[inside | shell], dtype=torch.float32, device=device)
    ).float()
    feats = torch.nn.functional.normalize(feats, dim=-1)
    own = torch.nn.functional.normalize(
        feats[torch.as_tensor(inside[inside | shell])].mean(0), dim=0
    )
    similar = (feats[torch.as_tensor(shell[inside | shell])] @ own).cpu().numpy()
    return pts[shell][similar < cfg.neighbour_similarity]


@torch.no_grad()
def _write_report(
    report: Path, parent: Scene, child: Scene, strips: list[tuple[int, list[np.ndarray]]]
) -> None:
    """before_after.png (three training views, ~160 px wide, before | after) and virtual_views_round_K.png
    (rows: rendered, masked, inpainted)."""
    for k, tiles in strips:
        n = len(tiles) // 3
        write_png(report / f"virtual_views_round_{k}.png", tile_images(tiles, cols=n))
    try:
        cameras, _, split = scene_cameras(Path(parent.meta.data_path))
    except NeoError:
        return
    train = split["train"]
    pick = train[np.linspace(0, len(train) - 1, min(3, len(train))).round().astype(int)]
    # a picture, not a measurement: at most ~160 px wide (halves a 320 px scan's cost)
    cameras = scaled_cameras(cameras, min(1.0, 160.0 / float(np.max(cameras.width))))
    cams = CameraTensors(cameras, parent.field.aabb.device)
    tiles, labels = [], []
    for i in pick:
        h, w = int(cameras.height[i]), int(cameras.width[i])
        for name, version in (("before", parent), ("after", child)):
            rgb = version.render_image(cams, int(i), h, w)["rgb"]
            tiles.append((rgb.clamp(0, 1).cpu().numpy() * 255).round().astype(np.uint8))
            labels.append(f"{name} (view {i})")
    write_png(report / "before_after.png", tile_images(tiles, cols=2, labels=labels))

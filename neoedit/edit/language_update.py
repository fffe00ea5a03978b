"""Keep the language field true after a geometric edit (paper Sec. III-D).

Renders carry no labels, so the update must work for every teacher (simulator labels,
CLIP, DINO). It composes the *parent's* language field region by region, exactly like the
radiance field's teacher (:class:`~neoedit.fields.language_map.LanguageMap`):

* inside a target box: the parent's features at T^-1 x (the object moved with its meaning);
* inside a source box grown by a margin (the object is gone, the support was inpainted,
  down to the support under its box's floor): the parent's features at the point pushed
  horizontally out of that footprint, onto the surface that surrounded it (the table);
  with no motion this is the whole removal update;
* elsewhere: the parent's own features.

By default (``method="compose"``) the new version's field *is* that composition: the
parent's weights and this edit's map, exact and untrained. ``method="distil"`` is the
paper's: a copy of the parent's field trained on the composed features at surface points.

The query cloud is refreshed the same way: the parent's surface points outside the edited
boxes are kept, and surface points inside them are re-rendered from the *edited* radiance
field at the scan's camera poses (the original poses Omega of the paper).
"""

from __future__ import annotations

import copy
import math
from dataclasses import dataclass
from typing import Literal

import numpy as np
import torch

from neoedit.cameras.rays import CameraTensors
from neoedit.errors import NeoError
from neoedit.fields.language import LanguageField
from neoedit.fields.language_map import LanguageMap
from neoedit.fields.suppressed import SuppressedField
from neoedit.geometry import OrientedBox, points_in_boxes
from neoedit.geometry.masks import box_pixels
from neoedit.language.training import LanguageTrainConfig, fit_language
from neoedit.rendering.surface import render_surface
from neoedit.scene import Scene
from neoedit.utils.timings import Timings


@dataclass
class LanguageUpdateConfig:
    method: Literal["compose", "distil"] = "compose"
    """compose: the new version's language field is its parent's weights read through
    this edit's map (exact, nothing trained: a removal's update took 0.7 s instead of
    6.4 s on NEO-Sim pick_place_1, the query cloud's re-render included). distil: the
    paper's, a copy of the parent's field trained ``steps`` steps to the composed features
    at surface points, the maps of earlier edits baked into its weights; ``steps``,
    ``batch``, ``edited_share`` and ``lr`` apply to it alone."""
    rays: int = 24576
    """At most this many scan pixels through the edited boxes are rendered to new surface
    points."""
    density_factor: float = 1.0
    """Pixels rendered per box pixel, relative to the rays per training pixel the parent's
    query cloud was rendered at: at 1 the edited region's new points are as dense as the
    cloud around them, so a query clusters a moved object as it did before the move.
    (Rendering a fixed 24576 pixels made a mug's region 5.5x denser than the rest of its
    cloud on NEO-Sim removal_1, and took 2 of the update's 4 s.) 0: ``rays`` pixels (or all
    the box's, if fewer)."""
    min_rays: int = 2048
    """Fewest pixels rendered (when the box has that many), so a small box still gets points."""
    steps: int = 120
    """Distillation steps of the language field."""
    batch: int = 4096
    edited_share: float = 0.5
    """Share of each batch from points inside the edited boxes (the rest holds the parent's
    features elsewhere)."""
    lr: float = 5e-3
    ring_m: float = 0.02
    """A point in a source box takes the features of the surface this far outside the grown
    box's footprint (``margin_m + ring_m`` from the box: the support it stood on)."""
    margin_m: float = 0.01
    """The edited boxes are grown by this much where query points are re-rendered, and the
    source boxes where the map sends points out of them."""
    min_accumulation: float = 0.5
    seed: int = 0

    def check(self, where: str = "--edit.language") -> None:
        """Refuse settings the update cannot run with (before any work starts)."""
        if not (math.isfinite(self.density_factor) and self.density_factor >= 0):
            raise NeoError(f"{where}.density-factor must be a finite number >= 0")
        if self.method not in ("compose", "distil"):
            raise NeoError(f"{where}.method must be 'compose' or 'distil', got {self.method!r}")
        for name in ("rays", "min_rays", "steps", "batch"):
            if getattr(self, name) < 1:
                raise NeoError(f"{where}.{name.replace('_', '-')} must be at least 1")


@dataclass
class LanguageEdit:
    """What moved where: ``source`` boxes were emptied; each target box shows its source
    under ``transform`` (4,4)."""

    source: list[OrientedBox]
    targets: list[tuple[OrientedBox, np.ndarray]]


def language_map(edit: LanguageEdit, cfg: LanguageUpdateConfig) -> LanguageMap:
    """The map from the edited scene's points to the parent's for ``edit``: its source
    boxes grown by ``cfg.margin_m``, as where the query cloud is re-rendered (so the support
    right under a removed object, below its box's floor, reads as the support around it,
    not as the object's contact), its target boxes as they are."""
    sources = [b.grown(cfg.margin_m) for b in edit.source]
    return LanguageMap.of(sources, edit.targets, cfg.ring_m)


@torch.no_grad()
def _teacher_targets(
    parent: LanguageField, query: torch.Tensor
) -> tuple[torch.Tensor, torch.Tensor | None]:
    out = [parent(query[i : i + 65536]) for i in range(0, len(query), 65536)]
    lang = torch.cat([o["language"] for o in out])
    dino = torch.cat([o["dino"] for o in out]) if "dino" in out[0] else None
    return lang, dino


def edited_rays(rays_per_pixel: float, n_box_pixels: int, cfg: LanguageUpdateConfig) -> int:
    """How many of the ``n_box_pixels`` scan pixels through the edited boxes to render: the
    query cloud's ``rays_per_pixel`` times ``cfg.density_factor``, at least ``cfg.min_rays``
    and at most ``cfg.rays`` (``cfg.rays`` when the density is unknown, 0), and never more
    than the box has."""
    n = cfg.rays
    if cfg.density_factor > 0 and math.isfinite(rays_per_pixel) and rays_per_pixel > 0:
        wanted = int(np.ceil(n_box_pixels * rays_per_pixel * cfg.density_factor))
        n = min(max(wanted, cfg.min_rays), n)
    return min(n, n_box_pixels)


def cloud_density(scene: Scene, scan_pixels: int) -> float:
    """The density the query cloud of ``scene`` was rendered at (rays per training pixel):
    as recorded at training, else its points per pixel (of ``scan_pixels``), which counts
    only the rays that hit a surface (79 % of them on NEO-Sim) and so errs on the sparse
    side."""
    lang = scene.meta.language
    if lang is not None and lang.cloud_rays_per_pixel > 0:
        return lang.cloud_rays_per_pixel
    cloud = scene.surface_points_m
    return len(cloud) / scan_pixels if cloud is not None and scan_pixels > 0 else 0.0


@torch.no_grad()
def _edited_surface(
    parent: Scene, child: Scene, boxes: list[OrientedBox], cfg: LanguageUpdateConfig
):
    """Surface points (K,3) of the edited field inside the boxes, from scan pixels whose ray
    crosses them (as many as :func:`edited_rays` says for the parent's query cloud)."""
    cameras, _, split = child.scan_cameras()
    cams = cameras.subset(split.get("train", np.arange(len(cameras))))
    pix = box_pixels(cams, boxes)
    device = child.field.aabb.device
    if len(pix) == 0:
        return torch.zeros((0, 3), device=device)
    rng = np.random.default_rng(cfg.seed)
    scan_pixels = int(np.sum(cams.width.astype(np.int64) * cams.height))
    n = edited_rays(cloud_density(parent, scan_pixels), len(pix), cfg)
    pix = pix[rng.choice(len(pix), n, replace=False)]
    pix_t = torch.as_tensor(pix, device=device)
    rays = CameraTensors(cams, device).rays(pix_t[:, 0], pix_t[:, 1], pix_t[:, 2])
    field_, cut = child.renderable()
    if cut:  # a preview version's cut boxes: surface points behind them
        field_ = SuppressedField(field_, cut)
    points, acc = render_surface(field_, child.grid, rays, child.meta.render)
    points = points[acc >= cfg.min_accumulation]
    return points[points_in_boxes(points, boxes)]


def update_language(
    parent: Scene, child: Scene, edit: LanguageEdit, cfg: LanguageUpdateConfig | None = None
) -> dict[str, float]:
    """Update ``child``'s language field and query cloud (in place) for ``edit``; the
    parent is read only. Returns timings (with a distillation, its final loss; empty
    without a language field)."""
    cfg = cfg or LanguageUpdateConfig()
    cfg.check()  # the Python API's configs too
    if parent.language is None or parent.surface_points_m is None:
        return {}
    timings = Timings()
    with timings.stage("language"):
        boxes = [b.grown(cfg.margin_m) for b in [*edit.source, *(b for b, _ in edit.targets)]]
        old = parent.surface_points_m
        new_points = _edited_surface(parent, child, boxes, cfg)
        kept = old[~points_in_boxes(old, boxes)]
        if cfg.method == "compose":
            lang = copy.deepcopy(parent.language)
            lang.maps.append(language_map(edit, cfg))
        else:
            lang, loss = _distilled(parent.language, new_points, kept, edit, cfg)
            timings["language_loss"] = loss
        child.language = lang.requires_grad_(False)
        child.surface_points_m = torch.cat([kept, new_points])
    timings["new_points"] = len(new_points)
    return timings


def _distilled(
    parent: LanguageField,
    new_points: torch.Tensor,
    kept: torch.Tensor,
    edit: LanguageEdit,
    cfg: LanguageUpdateConfig,
) -> tuple[LanguageField, float]:
    """The paper's update: a copy of ``parent``'s weights (no maps kept) trained on the
    composed features at the edited points ``new_points`` and, to hold the rest, at a
    sample of the ``kept`` ones; returns it and its final loss. Kept points inside the
    boxes of the parent's own maps (earlier edits composed, not in its weights) count as
    edited: the copy learns them too."""
    earlier = [b.grown(cfg.margin_m) for m in parent.maps for b in m.boxes()]
    redo = points_in_boxes(kept, earlier)
    query = torch.cat([language_map(edit, cfg)(new_points), kept[redo]])
    edited, kept = torch.cat([new_points, kept[redo]]), kept[~redo]
    gen = torch.Generator().manual_seed(cfg.seed)
    n_hold = min(len(kept), max(len(edited), 4 * cfg.batch))
    hold = kept[torch.randperm(len(kept), generator=gen)[:n_hold].to(kept.device)]
    points = torch.cat([edited, hold])
    targets, dino = _teacher_targets(parent, torch.cat([query, hold]))
    # batches: edited_share from the edited points, the rest from the held ones
    weights = torch.cat(
        [
            torch.full((len(edited),), cfg.edited_share / max(len(edited), 1)),
            torch.full((len(hold),), (1 - cfg.edited_share) / max(len(hold), 1)),
        ]
    )
    draw = torch.multinomial(weights, cfg.steps * cfg.batch, replacement=True, generator=gen)
    student = copy.deepcopy(parent).requires_grad_(True)
    student.maps = []
    train_cfg = LanguageTrainConfig(steps=cfg.steps, batch=cfg.batch, lr=cfg.lr, seed=cfg.seed)
    loss = fit_language(
        student, points, targets, dino, draw, train_cfg, gen, label="language update"
    )
    return student, round(loss, 5)

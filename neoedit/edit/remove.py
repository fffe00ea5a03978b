"""``neo remove``: object removal by neural-field resampling + progressive inpainting
(paper Sec. III-A, III-B) as a new scene version.

* Removal alone (``inpaint=False``) is instant: the new version records the box and every
  render cuts it out of the rays (``resample``: samples are drawn on the rest of each ray) or
  zeroes the density inside it (``suppress``: the DFF-style baseline, recorded as method
  'suppress'; ``neo bench`` runs it as ``neoedit.bench.dff.DffRemove``).
* With inpainting, the new version's weights are trained (:mod:`neoedit.edit.refine`) so
  the removal is persistent and the hidden surface is completed; no box is cut at render
  time any more.

The language side of a removal: surface points inside the box are dropped from the
version's query cloud, so the removed object can no longer be found.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch

from neoedit.cameras import Cameras
from neoedit.edit.checks import check_edit_boxes
from neoedit.edit.history import check_output
from neoedit.edit.inpaint import Inpainter, make_inpainter
from neoedit.edit.language_update import LanguageEdit, LanguageUpdateConfig
from neoedit.edit.masks import grown_box, grown_box_clear_of
from neoedit.edit.pipeline import Prepared, Timings, apply_edit
from neoedit.edit.refine import RefineConfig, refine_removal
from neoedit.edit.settle import settle
from neoedit.edit.shadow import ShadowConfig, scene_shadows
from neoedit.edit.views import VirtualViewConfig, view_scale, virtual_views
from neoedit.errors import NeoError
from neoedit.fields.patched import edit_region
from neoedit.geometry import OrientedBox
from neoedit.geometry.levels import surface_level
from neoedit.records import EditRecord
from neoedit.rendering.occupancy import cells_in_boxes, refresh_grid
from neoedit.scene import Scene, load_scene, save_scene
from neoedit.utils.io import write_png
from neoedit.utils.options import check_options, option_path, spelt
from neoedit.viz.contact_sheet import tile_images
from neoedit.viz.zoom import before_after, edited_boxes, report_views

REMOVAL_MODES = ("resample", "suppress")

Strip = tuple[int, list[np.ndarray]]
"""(round, tiles: rendered, masked and inpainted virtual views)."""


@dataclass
class RemoveConfig:
    removal: str = "resample"
    """'resample' (cut the box out of every ray, sample the rest) or 'suppress' (zero density
    in the box, standard sampling: the DFF-style baseline when nothing is inpainted; with
    inpainting it only changes the first round's preview)."""
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
    virtual_views: bool = True
    """Inpaint on virtual object-centred views (the paper's view distribution); False: on
    the scan cameras that face the box (the ablation)."""
    views: VirtualViewConfig = field(default_factory=VirtualViewConfig)
    refine: RefineConfig = field(default_factory=RefineConfig)
    shadow: ShadowConfig = field(default_factory=ShadowConfig)
    """The object's shadow on its support, found around its footprint, is removed with it
    (inpainted edits only; a thin slab on the support joins the edited region)."""

    def check(self, where: str = "") -> None:
        """Refuse settings the removal cannot run with, before any loading or query;
        ``where``: the prefix its options carry on the command line ('': none, as in
        ``neo remove --margin-m``, whose groups keep theirs: ``--refine.steps``;
        '--edit.remove' in ``neo move``)."""
        if self.removal not in REMOVAL_MODES:
            raise NeoError(
                f"{spelt(where, 'removal')} {self.removal!r} is unknown (choose from "
                f"{', '.join(REMOVAL_MODES)})"
            )
        check_options(self.views, option_path(spelt(where, "views")))
        self.refine.check(spelt(where, "refine"))
        self.shadow.check(spelt(where, "shadow"))


@dataclass
class Remove:
    """Remove ``boxes`` (paper Sec. III-A/B): cut at render time (``cfg.inpaint`` off: the
    instant preview, or the DFF-style suppression) or inpainted into a trained patch. Run
    it with :func:`~neoedit.edit.pipeline.apply_edit`."""

    boxes: list[OrientedBox]
    cfg: RemoveConfig = field(default_factory=RemoveConfig)
    prompt: str | None = None
    inpainter: Inpainter | None = None
    """Overrides ``cfg.inpainter`` with any object of the :class:`Inpainter` protocol."""
    strips: list[Strip] = field(default_factory=list, repr=False)
    """Filled by the run: every inpainting round's virtual views (for the report)."""
    language: LanguageUpdateConfig | None = None
    """How the language field follows the removal (None: the defaults)."""

    def prepare(self, parent: Scene) -> Prepared:
        cfg = self.cfg
        cfg.check()
        if not self.boxes:
            raise NeoError("nothing to remove: give a prompt or --box")
        check_edit_boxes(parent, self.boxes)  # inside the scene box, not empty
        work = working_boxes(parent, self.boxes, cfg)
        shadows = []
        if cfg.inpaint:  # the shadow goes with the object (a render-time cut keeps it)
            found = scene_shadows(parent, work, cfg.shadow)
            shadows = [s.slab for s in found if s is not None]
            work += shadows
        inpaint = type(self.inpainter).__name__ if self.inpainter else cfg.inpainter
        details = {
            "boxes": [b.to_dict() for b in self.boxes],
            "edit_boxes": [b.to_dict() for b in work],
            "shadow_boxes": [b.to_dict() for b in shadows],
            "removal": cfg.removal,
            "inpaint": inpaint if cfg.inpaint else None,
            "config": dataclasses.asdict(cfg),
            "language": dataclasses.asdict(self.language or LanguageUpdateConfig()),
        }
        # a suppression that trains nothing is the DFF-style baseline, not NEO's removal
        method = "suppress" if cfg.removal == "suppress" and not cfg.inpaint else None
        record = EditRecord("remove", self.prompt, method, details=details)

        def run(child: Scene, timings: Timings) -> None:
            if not cfg.inpaint:
                key = "cut_boxes" if cfg.removal == "resample" else "suppress_boxes"
                getattr(child.meta, key).extend(b.to_dict() for b in work)
                return
            timings.merge(settle(child))  # a preview or cut parent: start from what it shows
            timings.merge(
                inpaint_removal(child, work, self.boxes, cfg, self.inpainter, self.strips)
            )
            with timings.stage("grid"):
                region = [edit_region(b, cfg.refine.below_m) for b in work]
                refresh_grid(child.grid, child.field.density, cells_in_boxes(child.grid, region))

        language = LanguageEdit(source=work, targets=[])
        return Prepared(record, run, language, self.language, instant=not cfg.inpaint)


def remove(
    parent: Scene,
    boxes: list[OrientedBox],
    cfg: RemoveConfig,
    prompt: str | None = None,
    inpainter: Inpainter | None = None,
) -> tuple[Scene, list[Strip]]:
    """A new version of ``parent`` with ``boxes`` removed (``parent`` is left unchanged),
    and the virtual-view strips of every inpainting round (for the report)."""
    edit = Remove(boxes, cfg, prompt, inpainter)
    return apply_edit(parent, edit), edit.strips


def inpaint_removal(
    child: Scene,
    work: list[OrientedBox],
    boxes: list[OrientedBox],
    cfg: RemoveConfig,
    inpainter: Inpainter | None = None,
    strips: list[Strip] | None = None,
) -> dict[str, float]:
    """Train the removal patch of ``child`` (in place): virtual views around ``boxes``
    (spiral) or, with ``cfg.virtual_views`` off, the scan cameras that face them; returns
    timings. Each round's (rendered, masked, inpainted) crops go to ``strips``."""
    if inpainter is None:
        inpainter = make_inpainter(
            cfg.inpainter, cfg.inpaint_path, cfg.inpaint_prompt, str(child.field.aabb.device)
        )
    cameras, _, split = child.scan_cameras()
    train_cams = cameras.subset(split.get("train", np.arange(len(cameras))))
    if cfg.virtual_views:
        virtual = virtual_views(boxes, train_cams, cfg.views)
    else:
        virtual = facing_cameras(train_cams, boxes, 4 * cfg.views.turns).scaled(
            view_scale(boxes, train_cams, cfg.views)
        )

    def keep_strip(k, rendered, masks, inpainted):
        if strips is None:
            return
        masked = [
            np.where(m[..., None], np.array([255, 0, 255], np.uint8), r)
            for r, m in zip(rendered, masks, strict=True)
        ]
        strips.append((k, [*rendered, *masked, *inpainted]))

    return refine_removal(
        child, work, virtual, inpainter, cfg.refine, keep_strip, cfg.removal, train_cams
    )


def facing_cameras(cameras: Cameras, boxes: list[OrientedBox], n: int) -> Cameras:
    """The ``n`` cameras whose optical axis points most directly at the boxes' centre (the
    ablation without the virtual object-centred views)."""
    centre = np.mean([b.center_m for b in boxes], axis=0)
    to_box = centre - cameras.camera_to_world[:, :3, 3]
    to_box /= np.linalg.norm(to_box, axis=1, keepdims=True)
    forward = -cameras.camera_to_world[:, :3, 2]  # OpenGL: cameras look down -z
    order = np.argsort(-np.sum(forward * to_box, axis=1))
    return cameras.subset(np.sort(order[:n]))


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
    """Load the scene at ``scene_dir``, remove ``boxes`` (:func:`remove`) and write the new
    version to ``out`` with its report; returns it. ``inpainter`` overrides
    ``cfg.inpainter`` with any object of the :class:`Inpainter` protocol."""
    check_output(scene_dir, out, overwrite)
    parent = load_scene(scene_dir, device)
    child, strips = remove(parent, boxes, cfg, prompt, inpainter)
    save_scene(Path(out), child, extras=lambda d: write_report(d / "report", parent, child, strips))
    return child


def working_boxes(scene: Scene, boxes: list[OrientedBox], cfg: RemoveConfig) -> list[OrientedBox]:
    """The boxes an edit cuts, inpaints and regularises: each seated on the table and grown
    by ``cfg.margin_m``, short of neighbouring objects."""
    seated = [seated_on_support(scene, b) for b in boxes]
    return [grown_box_clear_of(b, cfg.margin_m, neighbour_points(scene, b, cfg)) for b in seated]


def seated_on_support(scene: Scene, box: OrientedBox, ring_m: float = 0.03) -> OrientedBox:
    """``box`` with its bottom on the support surface when it ends within 2 cm of it:
    raised when it reaches below (a query box can end a few mm under the table top; cutting
    that would open a hole in the table), lowered when it stops short (the object's base
    would stay behind: a ball's lower cap, left as a pale disc on the table). The support is
    the surface level (:func:`~neoedit.geometry.levels.surface_level`) of the surface points
    in a ring around the box's footprint near its bottom; the box is returned unchanged
    without such points."""
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
    support = surface_level(pts[ring, 2])  # a coaster's rim over the table: its top
    top = box.center_m[2] + box.size_m[2] / 2
    return box if support >= top - 0.005 else box.with_bottom(support)


@torch.no_grad()
def neighbour_points(scene: Scene, box: OrientedBox, cfg: RemoveConfig) -> np.ndarray:
    """(K,3) surface points in the margin around ``box`` that belong to something else: above
    the box's bottom (not the support surface) and, in the language field, unlike the object
    and unlike the support (a short field's table rises a centimetre or two into the
    object's contact: it is no neighbour to stop at). Empty without a language field."""
    if scene.language is None or scene.surface_points_m is None or cfg.margin_m <= 0:
        return np.zeros((0, 3))
    pts = scene.surface_points_m.cpu().numpy().astype(np.float64)
    local = box.world_to_local(pts)
    inside = box.contains(pts)
    around = grown_box(box, cfg.margin_m).contains(pts) & ~inside
    low = local[:, 2] <= -box.half_extents[2] + 0.01  # the support (+-5 mm in NEO-Sim)
    shell, support = around & ~low, around & low
    if not inside.any() or not shell.any():
        return np.zeros((0, 3))

    device, language = scene.surface_points_m.device, scene.language

    def features(mask: np.ndarray) -> torch.Tensor:
        at = torch.as_tensor(pts[mask], dtype=torch.float32, device=device)
        return torch.nn.functional.normalize(language.language(at).float(), dim=-1)

    def mean(feats: torch.Tensor) -> torch.Tensor:
        return torch.nn.functional.normalize(feats.mean(0), dim=0)

    near = features(shell)
    other = (near @ mean(features(inside))).cpu().numpy() < cfg.neighbour_similarity
    if support.sum() >= 10:
        other &= (near @ mean(features(support))).cpu().numpy() < cfg.neighbour_similarity
    return pts[shell][other]


@torch.no_grad()
def write_report(
    report: Path, parent: Scene, child: Scene, strips: list[tuple[int, list[np.ndarray]]]
) -> None:
    """before_after.png (two training views, before | after, each beside a zoom on the
    edited boxes) and virtual_views_round_K.png (rows: rendered, masked, inpainted)."""
    for k, tiles in strips:
        n = len(tiles) // 3
        write_png(report / f"virtual_views_round_{k}.png", tile_images(tiles, cols=n))
    views = report_views(parent, edited_boxes(child))
    tiles, labels, cols = before_after(parent, child, views)
    write_png(report / "before_after.png", tile_images(tiles, cols=cols, labels=labels))

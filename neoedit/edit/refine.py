"""Multiview-consistent progressive inpainting of a removal (paper Sec. III-B).

The edit trains a *patch* (:mod:`neoedit.fields.patched`): a copy of the current field that
answers only inside the removal's region (the grown box, extended under its bottom so the
support surface is re-learnt there). The paper's loss (eq. 4-5) is

    L = L_rgb(original views, M_o) + lambda_v * L_rgb(inpainted virtual views, M_v)
        + lambda_reg * L_reg(density inside the box -> 0)

Original-view pixels in M_o (rays that miss the box) never reach the patch, so they render
exactly as the parent did: their term holds by construction, and training needs only the
virtual views (their RGB, plus the depth of the removal preview: the surface the field
already continues behind the object) and L_reg. Every ``steps / rounds`` steps the virtual
views are re-rendered from the patched field and re-inpainted with a smaller strength xi, so
the targets converge to one multiview-consistent completion.

Virtual views are rendered and inpainted as a central crop (all of them look at the box
centre, so its silhouette is in the middle): the crop holds the mask plus a border of
context, which keeps the edit fast.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import cv2
import numpy as np
import torch

from neoedit.cameras import Cameras
from neoedit.cameras.rays import CameraTensors
from neoedit.edit.inpaint import Inpainter, inpaint_views
from neoedit.edit.points import original_box_rays, support_points
from neoedit.edit.removal_loss import RemovalLoss
from neoedit.edit.visibility import raised_masks, seen_by_cameras
from neoedit.fields.patched import edit_region
from neoedit.fields.radiance import Field
from neoedit.fields.suppressed import with_removals
from neoedit.geometry import OrientedBox
from neoedit.geometry.masks import project_box_mask
from neoedit.rendering.occupancy import cells_in_boxes, refresh_grid
from neoedit.rendering.renderer import render_chunked
from neoedit.scene import Scene
from neoedit.utils.fit import fit
from neoedit.utils.optim import field_param_groups, make_adam
from neoedit.utils.options import at_least_one, check_options, option_path
from neoedit.utils.progress import make_progress
from neoedit.utils.timings import Timings


@dataclass
class RefineConfig:
    steps: int = at_least_one(120)
    """Training steps of the patch."""
    rounds: int = at_least_one(3, most=20)
    """Progressive refinement rounds (re-render + re-inpaint at the start of each)."""
    strength: float = 1.0
    """Inpainting strength xi of the first round."""
    strength_final: float = 0.3
    """xi of the last round (linear in between)."""
    virtual_rays: int = at_least_one(1024)
    """Rays per step from the inpainted virtual views (their M_v pixels)."""
    lambda_depth: float = 1.0
    """Weight of the L1 depth loss [1/m] on the virtual views against the removal preview's
    depth (0: colour only). Without it the object's foot, which L_reg leaves alone, stays as
    a ghost ring (measured on removal_1: Out-PSNR 29.4 dB at 0.1, 32.2 dB at 1.0)."""
    lambda_reg: float = 1.0
    """Weight of L_reg, relative to the virtual-view colour loss."""
    reg_points: int = 4096
    """Random points in the box per step for L_reg."""
    reg_floor_m: float = 0.005
    """L_reg leaves out the box's lowest 5 mm, where the support surface is (query boxes end
    within 5 mm of it on NEO-Sim)."""
    below_m: float = 0.03
    """The patch's region reaches this far under the box's bottom (the support surface)."""
    lambda_keep: float = 1.0
    """Weight of L_keep: the patch keeps at least the unedited field's density (as 1 cm
    opacity, L1 on what it takes away; it may add) on random points of the region under the
    box's bottom (the support). Without it L_reg
    can empty the table through the patch's own MLP (measured on NEO-Sim pick_place_1: the
    table under the mug went transparent, a white patch)."""
    lr: float = 1e-2
    """Constant learning rate of the patch's hash table (fresh Adam). Only the patch moves, so
    this can be the scan's rate (removal_1 Out-PSNR: 32.1 dB at 2e-3, 33.4 dB at 1e-2)."""
    mlp_lr_factor: float = 1.0
    """Learning rate of the patch's MLPs relative to its table's (the patch is local, so its
    MLPs can move freely)."""
    inpaint_unseen_only: bool = True
    """Inpaint only the pixels of M_v that show the table under the box or a surface no scan
    camera saw past the object; the rest of M_v keeps the preview's colour as its target (a
    neighbour inside or behind the box). False: inpaint all of M_v (the paper's box mask)."""
    hole_margin_m: float = 0.015
    """Unseen holes are grown by about this much (converted to pixels at the box's distance):
    the ring around an object's foot was seen, but with its contact shadow baked in."""
    fill_from_support: bool = True
    """The hidden support is inpainted from the support around it only: what stands higher
    than ``support_band_m`` over it in a view (a neighbouring object) is hidden from the
    inpainter, and the holes' growth stops at it (measured on the README demo's plan: a mug
    nudged away from the duck beside it left a yellow smear of the duck where it stood).
    False: the whole crop is the inpainter's context."""
    support_band_m: float = 0.01
    """Surface points less than this above a box's bottom, inside its footprint, are always
    inpainted (the table under the object)."""
    scan_views: int = at_least_one(16)
    """Scan cameras (evenly chosen) that the visibility test looks from."""
    crop_margin_px: int = 12
    """Context around the mask in the rendered / inpainted virtual-view crops."""
    grid: bool = True
    """Inpaint virtual views in 2x2 composites of four (False: one by one)."""
    mask_conditioned: bool = True
    """Original views supervise only M_o = 1 - M_v (which the patch never sees). False (the
    ablation): their pixels inside the box silhouette, which show the object, are trained
    on too, ``original_rays`` per step."""
    original_rays: int = 512
    span_only: bool = True
    """Sample the network only where a virtual ray crosses the patch's region; what lies in
    front of it and behind it (frozen) is marched once (:mod:`neoedit.rendering.span`).
    False: every step renders the whole ray, as the renderer does."""
    span_samples: int = at_least_one(24)
    """Coarse density queries and rendered PDF samples per ray on the span (a few
    decimetres at most: fewer than a whole ray's 32 + 32; on NEO-Sim removal_1 the edit's
    Out-PSNR is the same at 24 and 32, within 0.2 dB, see benchmarks/RESULTS.md)."""
    seed: int = 0

    def check(self, where: str = "") -> None:
        """Refuse settings the training cannot run with (before any work starts), by the
        one range check the command line runs (:func:`~neoedit.utils.options.check_options`:
        counts at least 1, rounds at most 20, ...); ``where``: the options' prefix on the
        command line ('': none)."""
        check_options(self, option_path(where))


def crop_window(masks: list[np.ndarray], margin_px: int) -> tuple[slice, slice]:
    """One window (rows, cols) holding every mask plus a margin, clipped to the image."""
    union = np.any(np.stack(masks), axis=0)
    h, w = union.shape
    if not union.any():
        return slice(0, h), slice(0, w)
    rows, cols = np.nonzero(union.any(1))[0], np.nonzero(union.any(0))[0]
    r0, r1 = max(rows[0] - margin_px, 0), min(rows[-1] + margin_px + 1, h)
    c0, c1 = max(cols[0] - margin_px, 0), min(cols[-1] + margin_px + 1, w)
    return slice(int(r0), int(r1)), slice(int(c0), int(c1))


@torch.no_grad()
def render_crops(
    scene_field: Field,
    scene: Scene,
    cameras: Cameras,
    window: tuple[slice, slice],
    boxes: list[OrientedBox],
) -> tuple[list[np.ndarray], torch.Tensor, torch.Tensor]:
    """(h,w,3) uint8 renders of the window of every camera, their z-depths (V,h,w) [m] and
    accumulations (V,h,w) (the share of each ray a surface stopped)."""
    device = scene.field.aabb.device
    cams = CameraTensors(cameras, device)
    rows, cols = window
    images, depths, accumulations = [], [], []
    for i in range(len(cameras)):
        v, u = torch.meshgrid(
            torch.arange(rows.start, rows.stop, device=device),
            torch.arange(cols.start, cols.stop, device=device),
            indexing="ij",
        )
        rays = cams.rays(torch.full((v.numel(),), i, device=device), v.reshape(-1), u.reshape(-1))
        out = render_chunked(
            scene_field,
            scene.grid,
            rays,
            scene.meta.render,
            scene.background,
            boxes,
        )
        img = out["rgb"].reshape(v.shape[0], v.shape[1], 3)
        images.append((img.clamp(0, 1).cpu().numpy() * 255).round().astype(np.uint8))
        depths.append(out["depth_z"].reshape(v.shape))
        accumulations.append(out["accumulation"].reshape(v.shape))
    return images, torch.stack(depths), torch.stack(accumulations)


def unseen_masks(
    scene: Scene,
    virtual: Cameras,
    window: tuple[slice, slice],
    pix: torch.Tensor,
    depth_z: torch.Tensor,
    masks: list[np.ndarray],
    scan_cameras: Cameras,
    cfg: RefineConfig,
    boxes: list[OrientedBox],
    raised: list[np.ndarray] | None = None,
) -> list[np.ndarray]:
    """The pixels of M_v to inpaint: those whose preview surface point (from ``depth_z``
    (V,h,w)) no scan camera saw, or that lie on the support inside a box's footprint (what
    the field shows there is the object's contact: its shadow, colour bled into the table);
    per view (h,w) bool, grown by ``cfg.hole_margin_m`` (within M_v, not onto the
    ``raised`` pixels: a neighbour standing beside the hole). Kept: what was seen above the
    support (a neighbour inside or behind the box) or beyond the footprint."""
    vcams = CameraTensors(virtual, depth_z.device)
    rays = vcams.rays(pix[:, 0], pix[:, 1] + window[0].start, pix[:, 2] + window[1].start)
    dist = depth_z[pix[:, 0], pix[:, 1], pix[:, 2]] / rays.z_scale
    points = rays.origins + rays.directions * dist[:, None]
    pick = np.linspace(0, len(scan_cameras) - 1, min(cfg.scan_views, len(scan_cameras)))
    seen = seen_by_cameras(
        scene.field,
        scene.grid,
        points,
        scan_cameras.subset(np.unique(pick.round().astype(np.int64))),
        scene.meta.render.near_m,
    )
    pts = points.cpu().numpy().astype(np.float64)
    on_support = np.zeros(len(pts), bool)
    for b in boxes:
        local = b.world_to_local(pts)
        footprint = (np.abs(local[:, :2]) <= b.half_extents[:2]).all(1)
        on_support |= footprint & (local[:, 2] < -b.half_extents[2] + cfg.support_band_m)
    hole = np.zeros((len(masks), *masks[0].shape), bool)
    p = pix[~seen | torch.as_tensor(on_support, device=seen.device)].cpu().numpy()
    hole[p[:, 0], p[:, 1], p[:, 2]] = True
    out = []
    for v, (h, m) in enumerate(zip(hole, masks, strict=True)):
        if not m.any():
            out.append(m)
            continue
        dist_m = float(depth_z[v][torch.as_tensor(m, device=depth_z.device)].median())
        radius_px = float(virtual.fx[v]) * cfg.hole_margin_m / max(dist_m, 1e-3)
        grown = grow_mask(h, radius_px)
        if raised is not None:
            grown &= ~raised[v]
        out.append((grown | h) & m)
    return out


def grow_mask(mask: np.ndarray, radius_px: float) -> np.ndarray:
    """``mask`` (h,w) bool grown by a disc of ``radius_px``: the pixels within that
    (Euclidean) distance of it. A distance transform, so its cost does not grow with the
    radius (a 90 px dilation kernel took 4.5 s a view on beer_can)."""
    if not mask.any():
        return mask.copy()
    free = (~mask).astype(np.uint8)
    dist = cv2.distanceTransform(free, cv2.DIST_L2, cv2.DIST_MASK_PRECISE)
    return dist <= radius_px


def _round_status(k: int, rounds: int, xi: float, step: int, ema: float) -> str:
    return f"round {k}/{rounds} xi {xi:.2f} | loss {ema:.4f}"


def _patch_training(
    scene: Scene,
    boxes: list[OrientedBox],
    virtual: Cameras,
    cfg: RefineConfig,
    scan_cameras: Cameras | None,
) -> tuple[RemovalLoss, torch.optim.Optimizer, list[np.ndarray]]:
    """Add the patch owning the boxes' region to ``scene``; its loss (M_v pixels of the
    virtual views' crop window, empty targets), its optimiser and the crop masks M_v."""
    device = scene.field.aabb.device
    gen = torch.Generator().manual_seed(cfg.seed)
    scene.field.requires_grad_(False)
    region = [edit_region(b, cfg.below_m) for b in boxes]
    originals = None
    if not cfg.mask_conditioned and scan_cameras is not None:
        originals = original_box_rays(scene, scan_cameras, boxes, 16 * cfg.original_rays, gen)
    keep_pts, keep_alpha = support_points(scene.field, boxes, cfg.below_m, gen, device)
    patch = scene.patched().add_patch(region).requires_grad_(True)
    optimizer = make_adam(field_param_groups(patch, cfg.lr, cfg.mlp_lr_factor), cfg.lr, device)
    # M_v in the virtual views and the crop window
    masks_full = [
        np.any([project_box_mask(virtual, i, b) for b in boxes], axis=0)
        for i in range(len(virtual))
    ]
    window = crop_window(masks_full, cfg.crop_margin_px)
    masks = [m[window] for m in masks_full]
    pix = torch.nonzero(torch.as_tensor(np.stack(masks), device=device))  # (P,3) view,row,col
    targets = torch.zeros((len(masks), *masks[0].shape, 3), device=device)
    loss = RemovalLoss(
        scene=scene, cfg=cfg, boxes=boxes, region=region,
        vcams=CameraTensors(virtual, device), window=window, pix=pix,
        targets=targets, target_depth=torch.zeros(targets.shape[:3], device=device),
        keep_pts=keep_pts, keep_alpha=keep_alpha, originals=originals, gen=gen,
        train_gen=torch.Generator(device=device).manual_seed(cfg.seed),
    )  # fmt: skip
    return loss, optimizer, masks


def refine_removal(
    scene: Scene,
    boxes: list[OrientedBox],
    virtual: Cameras,
    inpainter: Inpainter,
    cfg: RefineConfig,
    on_round=None,
    removal: str = "resample",
    scan_cameras: Cameras | None = None,
) -> dict:
    """Add a patch owning ``boxes`` to ``scene`` (in place: pass a copy) and train it into
    the edited field F~. The first round inpaints the removal preview (``removal``:
    'resample' cuts the boxes out of the rays, 'suppress' zeroes their density); with
    ``scan_cameras`` only what they did not see (:mod:`neoedit.edit.visibility`).
    ``on_round(k, rendered, holes, inpainted)`` receives each round's crops (for the
    strips). Returns timings (``total_s`` and its stages)."""
    timings = Timings(visibility_s=0.0, outside_s=0.0)  # stages that may not run
    device = scene.field.aabb.device
    with timings.stage("total"), timings.stage("setup"):  # the patch, L_keep's targets, a march
        loss_step, optimizer, masks = _patch_training(scene, boxes, virtual, cfg, scan_cameras)
    region, window, pix = loss_step.region, loss_step.window, loss_step.pix
    targets, target_depth = loss_step.targets, loss_step.target_depth
    rounds = max(cfg.rounds, 1)
    per_round = int(np.ceil(cfg.steps / rounds))
    step = 0
    holes = masks
    avoid: list[np.ndarray] | None = None  # set in round 0: the neighbours, never filled from
    preview_rgb = np.zeros((len(masks), *masks[0].shape, 3), np.uint8)  # set in round 0
    with timings.stage("total"), make_progress() as progress:
        task = progress.add_task("inpaint+train", total=cfg.steps, status="")
        for k in range(rounds):
            xi = cfg.strength + (cfg.strength_final - cfg.strength) * (k / max(rounds - 1, 1))
            # round 0 renders the removal preview (boxes cut or suppressed), later rounds F~
            preview = k == 0
            with timings.stage("render"):
                rendered, depth, accumulation = _render_round(
                    scene, boxes, virtual, window, region, removal, k
                )
            if not preview and loss_step.outside is not None:
                with timings.stage("outside"):  # the refreshed cells reach a little outside
                    loss_step.march_outside()
            if preview:
                target_depth.copy_(depth)
                preview_rgb = np.stack(rendered)
                raised = (
                    raised_masks(virtual, window, depth, accumulation, boxes, cfg.support_band_m)
                    if cfg.fill_from_support
                    else None
                )
                if cfg.inpaint_unseen_only and scan_cameras is not None and len(pix):
                    with timings.stage("visibility"):
                        holes = unseen_masks(
                            scene, virtual, window, pix, depth, masks, scan_cameras, cfg, boxes,
                            raised,
                        )  # fmt: skip
                if raised is not None:
                    avoid = [r & ~h for r, h in zip(raised, holes, strict=True)]
            with timings.stage("inpaint"):
                inpainted = inpaint_views(inpainter, rendered, holes, xi, cfg.grid, avoid)
                # seen pixels of M_v keep the preview's colour as their target
                keep = np.stack(holes)[..., None]
                inpainted = list(np.where(keep, np.stack(inpainted), preview_rgb))
            targets.copy_(torch.as_tensor(np.stack(inpainted), device=device).float() / 255.0)
            if on_round is not None:
                on_round(k, rendered, holes, inpainted)
            n = min(per_round, cfg.steps - step)
            with timings.stage("train"):
                fit(
                    optimizer,
                    n,
                    lambda _: loss_step(),
                    "inpaint+train",
                    status=functools.partial(_round_status, k + 1, rounds, xi),
                    bar=(progress, task),
                )
            step += n
    scene.field.requires_grad_(False)
    return timings


def _render_round(
    scene: Scene,
    boxes: list[OrientedBox],
    virtual: Cameras,
    window: tuple[slice, slice],
    region: list[OrientedBox],
    removal: str,
    k: int,
) -> tuple[list[np.ndarray], torch.Tensor, torch.Tensor]:
    """Round ``k``'s crops of the virtual views: the removal preview in round 0 (boxes cut
    or suppressed), the edited field after that (its grid refreshed in the region first:
    the fast renders march the grid's occupied cells)."""
    preview = k == 0
    field_, cut = with_removals(
        scene.field,
        cut=boxes if preview and removal == "resample" else [],
        suppress=boxes if preview and removal == "suppress" else [],
    )
    if not preview:
        refresh_grid(scene.grid, scene.field.density, cells_in_boxes(scene.grid, region))
    return render_crops(field_, scene, virtual, window, cut)

"""NeRFiller-style removal (Weber et al. 2023), the baseline of paper Table I: instead of
NEO's local patch, the *dataset* is edited and a fresh field retrained on it.

1. Every training view is inpainted inside the boxes' silhouettes, four views at a time
   in a 2x2 composite (the inpainter sees the hole from several sides; NEO's inpainter).
2. A fresh field (the parent's configs) is trained on them with the scan's own loop
   (:class:`~neoedit.training.trainer.Trainer`), as many steps as the scan was.
3. Every ``steps / rounds`` steps (the "iterative dataset update") the masked views are
   re-rendered from the field and re-inpainted with a smaller strength xi, so the dataset
   converges to one completion the field can hold.

'nerfiller' also supervises depth: the scan's depth, filled inside the masks from the ring
around them (harmonic fill of the inverse depth: exact for a plane), blended with the
rendered depth at each update like the colour. 'nerfiller-no-depth' has no depth loss.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field

import numpy as np
import scipy.ndimage
import scipy.sparse
import scipy.sparse.linalg
import torch

from neoedit.data import SceneData
from neoedit.data.sparse_depth import is_sparse
from neoedit.edit.checks import check_edit_boxes
from neoedit.edit.inpaint import Inpainter, inpaint_views, make_inpainter
from neoedit.edit.language_update import LanguageEdit, LanguageUpdateConfig
from neoedit.edit.pipeline import Prepared, Timings, apply_edit
from neoedit.edit.refine import crop_window, render_crops
from neoedit.edit.remove import RemoveConfig, working_boxes
from neoedit.errors import NeoError
from neoedit.fields.radiance import RadianceField
from neoedit.geometry import OrientedBox
from neoedit.geometry.masks import masks_for_boxes
from neoedit.records import EditRecord
from neoedit.scene import Scene
from neoedit.training.trainer import TrainConfig, Trainer, psnr
from neoedit.utils.progress import make_progress

Window = tuple[slice, slice]


@dataclass
class NerfillerConfig:
    depth: bool = True
    """Supervise depth with the scan's depth, inpainted inside the masks ('nerfiller');
    False: no depth loss anywhere ('nerfiller-no-depth')."""
    steps: int | None = None
    """Training steps of the fresh field; None: as many as the parent scene was trained
    (NeRFiller retrains the whole field, hence ~15x NEO's time in the paper)."""
    rounds: int = 3
    """Dataset updates, spread evenly over the steps; the first (the inpainting of the
    scan's photos) is at step 0."""
    strength: float = 1.0
    """Inpainting strength xi of the first round (1: the object's pixels are replaced)."""
    strength_final: float = 0.3
    """xi of the last round (linear in between); with the OpenCV inpainters a round's
    target is xi * inpainted + (1 - xi) * the field's render inside the mask."""
    inpainter: str = "fsr"
    """'fsr', 'telea', 'ns' (OpenCV) or 'diffusion' (--inpaint-path), as for NEO."""
    inpaint_path: str | None = None
    """Local diffusers inpainting pipeline directory (for the diffusion inpainter)."""
    inpaint_prompt: str = "an empty table surface"
    """Text prompt of the diffusion inpainter."""
    margin_m: float = 0.01
    """The boxes are grown by this much, as NEO's removal grows them
    (:func:`~neoedit.edit.remove.working_boxes`): the masks are the region NEO edits."""
    crop_margin_px: int = 16
    """Context around each view's mask in the crops that are rendered and inpainted."""
    seed: int = 0


@dataclass
class NerfillerRemove:
    """Remove ``boxes`` by retraining a fresh field on the scan ``data`` with its training
    views inpainted (the views are edited in a copy). Run it with
    :func:`~neoedit.edit.pipeline.apply_edit`."""

    data: SceneData
    boxes: list[OrientedBox]
    cfg: NerfillerConfig = field(default_factory=NerfillerConfig)
    prompt: str | None = None
    inpainter: Inpainter | None = None
    language: LanguageUpdateConfig | None = None
    """How the language field follows the removal (None: the defaults, as after NEO's)."""

    def prepare(self, parent: Scene) -> Prepared:
        cfg = self.cfg
        # the photos where the parent's training put them (pose corrections applied)
        data = dataclasses.replace(self.data, cameras=parent.scan_cameras()[0])
        _check_parent(parent, data, self.boxes, cfg)
        work = working_boxes(parent, self.boxes, RemoveConfig(margin_m=cfg.margin_m))
        inpainter = self.inpainter
        if inpainter is None:
            device = str(parent.field.aabb.device)
            inpainter = make_inpainter(cfg.inpainter, cfg.inpaint_path, cfg.inpaint_prompt, device)
        details = {
            "boxes": [b.to_dict() for b in self.boxes],
            "edit_boxes": [b.to_dict() for b in work],
            "inpaint": getattr(inpainter, "name", type(inpainter).__name__),
            "config": dataclasses.asdict(cfg),
            "language": dataclasses.asdict(self.language or LanguageUpdateConfig()),
        }
        method = "nerfiller" if cfg.depth else "nerfiller-no-depth"
        record = EditRecord("remove", self.prompt, method, details=details)
        steps = parent.meta.step if cfg.steps is None else cfg.steps
        train_cfg = _train_config(parent, data, cfg, steps)

        def run(child: Scene, timings: Timings) -> None:
            fresh = Scene.create(child.meta, parent.field.aabb.device, seed=cfg.seed)
            child.field, child.grid = fresh.field, fresh.grid
            _retrain(child, data, work, cfg, train_cfg, inpainter, timings)

        return Prepared(record, run, LanguageEdit(source=work, targets=[]), self.language)


def nerfiller(
    parent: Scene,
    data: SceneData,
    boxes: list[OrientedBox],
    cfg: NerfillerConfig,
    prompt: str | None = None,
    inpainter: Inpainter | None = None,
) -> Scene:
    """A new version of ``parent`` with ``boxes`` removed the NeRFiller way
    (:class:`NerfillerRemove`); ``parent`` unchanged."""
    return apply_edit(parent, NerfillerRemove(data, boxes, cfg, prompt, inpainter))


def _check_parent(
    parent: Scene, data: SceneData, boxes: list[OrientedBox], cfg: NerfillerConfig
) -> None:
    meta = parent.meta
    edited = meta.edits or meta.patches or meta.cut_boxes or meta.suppress_boxes or meta.moves
    if edited or not isinstance(parent.field, RadianceField):
        raise NeoError(
            "the NeRFiller-style baseline retrains from the scan: start from an unedited "
            f"version (this one has {len(meta.edits)} edit(s))"
        )
    if not boxes:
        raise NeoError("nothing to remove: give a box")
    if cfg.depth and (data.depth_m is None or is_sparse(data.depth_m)):
        raise NeoError(
            f"{data.root} has no metric depth (at most structure-from-motion points): use "
            "the variant without depth"
        )
    if len(data) != len(parent.scan_cameras()[0]):
        raise NeoError(f"{data.root} is not the scan this scene was trained on")
    if (parent.meta.step if cfg.steps is None else cfg.steps) < 1:
        raise NeoError("the NeRFiller-style baseline needs at least one training step")
    check_edit_boxes(parent, boxes)  # inside the scene box, not empty


def _train_config(parent: Scene, data: SceneData, cfg: NerfillerConfig, steps: int) -> TrainConfig:
    """The parent's training config for ``steps`` steps, automatic weights resolved as
    :func:`~neoedit.training.trainer.train` does; depth weight 0 without depth."""
    names = {f.name for f in dataclasses.fields(TrainConfig)}
    tc = TrainConfig(**{k: v for k, v in parent.meta.train.items() if k in names})
    sparsity = tc.sparsity_loss_weight
    if sparsity < 0:
        sparsity = 0.1 if data.scene_aabb_m is None else 0.0
    depth = (tc.depth_loss_weight if tc.depth_loss_weight > 0 else 0.1) if cfg.depth else 0.0
    tc = dataclasses.replace(tc, sparsity_loss_weight=sparsity, depth_loss_weight=depth)
    return dataclasses.replace(
        tc,
        max_steps=steps,
        max_minutes=None,
        seed=cfg.seed,
        pose_refinement=False,
        object_ray_share=0.0,  # the inpainted scan's labels still show the removed object
    )


def group_windows(masks: list[np.ndarray], margin_px: int) -> list[Window]:
    """A crop window per view around its mask (plus ``margin_px``); views in consecutive
    fours share one window size, so each four tiles into one 2x2 composite."""
    h, w = masks[0].shape
    wins = [crop_window([m], margin_px) for m in masks]
    out: list[Window] = []
    for g in range(0, len(wins), 4):
        group = wins[g : g + 4]
        gh = max(r.stop - r.start for r, _ in group)
        gw = max(c.stop - c.start for _, c in group)
        out.extend((_resized(r, gh, h), _resized(c, gw, w)) for r, c in group)
    return out


def _resized(s: slice, n: int, limit: int) -> slice:
    """A slice of length ``n`` centred on ``s``, shifted to lie in [0, limit)."""
    start = min(max((s.start + s.stop - n) // 2, 0), limit - n)
    return slice(start, start + n)


def inpaint_depth(depth_m: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """(h,w) z-depth [m] filled inside ``mask`` from the ring around it: the harmonic
    (Laplace) fill of the inverse depth, exact for a plane (its inverse depth is affine in
    the pixel coordinates). No-data pixels (0: beyond the scene) do not constrain the fill;
    a hole with no depth around it stays 0 (no depth target)."""
    out = depth_m.astype(np.float32)
    known = (depth_m > 0) & ~mask
    labels, _ = scipy.ndimage.label(mask)
    bordered = np.unique(labels[scipy.ndimage.binary_dilation(known) & mask])
    fill = np.isin(labels, bordered[bordered > 0])
    out[mask] = 0.0
    if fill.any():
        inv = np.where(known, 1.0 / np.maximum(depth_m, 1e-6), 0.0)
        out[fill] = 1.0 / harmonic_fill(inv, fill, known)
    return out


def harmonic_fill(values: np.ndarray, fill: np.ndarray, known: np.ndarray) -> np.ndarray:
    """Values at the ``fill`` pixels (row-major order) solving Laplace's equation on the
    4-neighbour pixel graph, the ``known`` pixels as boundary values; other pixels (no
    data) and the image border are free edges. Every hole must touch a known pixel."""
    h, w = fill.shape

    def path(n: int) -> scipy.sparse.spmatrix:
        return scipy.sparse.diags([1.0, 1.0], [-1, 1], shape=(n, n))

    eye = scipy.sparse.eye
    adj = (scipy.sparse.kron(eye(h), path(w)) + scipy.sparse.kron(path(h), eye(w))).tocsr()
    f, k = np.flatnonzero(fill), np.flatnonzero(known)
    a_ff, a_fk = adj[f][:, f], adj[f][:, k]
    degree = np.asarray(a_ff.sum(1)).ravel() + np.asarray(a_fk.sum(1)).ravel()
    laplacian = (scipy.sparse.diags(degree) - a_ff).tocsc()
    return scipy.sparse.linalg.spsolve(laplacian, a_fk @ values.ravel()[k])


@dataclass
class MaskedViews:
    """The training views a removal box shows in, cropped to their windows."""

    rows: list[int]
    """Positions in the training split (rows of the trainer's image tensor)."""
    frames: list[int]
    """Frame indices in the dataset (its cameras)."""
    windows: list[Window]
    masks: list[np.ndarray]
    """(h,w) bool per view: the boxes' silhouette in the window."""
    rgb: list[np.ndarray]
    """The scan's photo in the window (the context outside the mask)."""
    depth: list[np.ndarray] | None = None
    """The scan's depth in the window, filled inside the mask (the depth variant's target;
    both variants' opacity of the filled pixels)."""


def masked_views(data: SceneData, boxes: list[OrientedBox], margin_px: int) -> MaskedViews:
    """The training views whose pixels see the boxes: masks, crops (and, where the scan
    has depth, its depth filled inside the masks)."""
    train = data.split["train"]
    full = [masks_for_boxes(data.cameras, int(i), boxes) for i in train]
    rows = [t for t, m in enumerate(full) if m.any()]
    if not rows:
        raise NeoError("the boxes are in no training view: nothing to inpaint")
    frames = [int(train[t]) for t in rows]
    windows = group_windows([full[t] for t in rows], margin_px)
    masks = [full[t][w] for t, w in zip(rows, windows, strict=True)]
    rgb = [data.images[f][w] for f, w in zip(frames, windows, strict=True)]
    views = MaskedViews(rows, frames, windows, masks, rgb)
    if data.depth_m is not None:  # also decides the opacity of the filled pixels
        views.depth = [
            inpaint_depth(data.depth_m[f][w], m)
            for f, w, m in zip(frames, windows, masks, strict=True)
        ]
    return views


def _inpainted_data(
    data: SceneData, views: MaskedViews, inpainter: Inpainter, xi: float, depth: bool
) -> SceneData:
    """A copy of ``data`` whose masked training views are inpainted (round 0). Where the
    data has opacity (RGBA scans), a filled pixel is opaque where the filled depth finds a
    surface and empty where it does not (the object no longer hides empty space)."""
    images = data.images.copy()
    filled = inpaint_views(inpainter, views.rgb, views.masks, xi, grid=True)
    for f, w, crop in zip(views.frames, views.windows, filled, strict=True):
        images[f][w] = crop
    depth_m = alpha = None
    if views.depth is not None and data.depth_m is not None and depth:
        depth_m = data.depth_m.copy()
        for f, w, crop in zip(views.frames, views.windows, views.depth, strict=True):
            depth_m[f][w] = crop
    if views.depth is not None and data.alpha is not None:
        alpha = data.alpha.copy()
        for f, w, m, d in zip(views.frames, views.windows, views.masks, views.depth, strict=True):
            alpha[f][w] = np.where(m, np.where(d > 0, 255, 0), alpha[f][w]).astype(np.uint8)
    return dataclasses.replace(
        data, images=images, depth_m=depth_m, alpha=data.alpha if alpha is None else alpha
    )


def _retrain(
    child: Scene,
    data: SceneData,
    boxes: list[OrientedBox],
    cfg: NerfillerConfig,
    train_cfg: TrainConfig,
    inpainter: Inpainter,
    timings: Timings,
) -> None:
    """Inpaint the dataset and train ``child``'s fresh field on it (in place) with the
    dataset updates, timed into ``timings``."""
    rounds, steps = max(cfg.rounds, 1), train_cfg.max_steps
    xis = [
        cfg.strength + (cfg.strength_final - cfg.strength) * k / max(rounds - 1, 1)
        for k in range(rounds)
    ]
    with timings.stage("inpaint"):
        views = masked_views(data, boxes, cfg.crop_margin_px)
        inpainted = _inpainted_data(data, views, inpainter, xis[0], cfg.depth)
    timings["render_s"] = 0.0
    trainer = Trainer(inpainted, child, train_cfg, None, child.field.aabb.device)
    update_at = {round(k * steps / rounds): k for k in range(1, rounds)}
    ema, k = 1.0, 0
    with make_progress() as progress:
        task = progress.add_task("nerfiller", total=steps, status="")
        for step in range(steps):
            if step in update_at:
                k = update_at[step]
                _update_dataset(trainer, views, inpainter, xis[k], timings)
            with timings.stage("train"):  # the steps alone: the trainer's clock
                mse = trainer.step(step, timings.seconds("train"))
            ema = mse if step == 0 else 0.9 * ema + 0.1 * mse
            status = f"round {k + 1}/{rounds} xi {xis[k]:.2f} | PSNR {psnr(ema):5.2f} dB"
            progress.update(task, completed=step + 1, status=status)
    trainer.finish_grid()
    t_train = timings.seconds("train")
    meta = child.meta
    meta.train, meta.step, meta.train_seconds = dataclasses.asdict(train_cfg), steps, t_train
    meta.history = [
        {"step": steps, "seconds": round(t_train, 2), "train_psnr": round(psnr(ema), 3)}
    ]


def _update_dataset(
    trainer: Trainer,
    views: MaskedViews,
    inpainter: Inpainter,
    xi: float,
    timings: Timings,
) -> None:
    """One dataset update: render the masked views' windows from the current field,
    re-inpaint them with strength ``xi`` (the scan's photo around the mask as context) and
    write them into the trainer's targets; depth: xi * inpainted + (1 - xi) * rendered."""
    scene = trainer.scene
    rendered, depths = [], []
    with timings.stage("render"):
        for f, w in zip(views.frames, views.windows, strict=True):
            rgb, depth, _ = render_crops(
                scene.field, scene, trainer.data.cameras.subset([f]), w, []
            )
            rendered.append(rgb[0])
            depths.append(depth[0].cpu().numpy())
    with timings.stage("inpaint"):
        _refill(trainer, views, inpainter, xi, rendered, depths)


def _refill(
    trainer: Trainer,
    views: MaskedViews,
    inpainter: Inpainter,
    xi: float,
    rendered: list[np.ndarray],
    depths: list[np.ndarray],
) -> None:
    """Re-inpaint the rendered windows and write them (and the blended depth) into the
    trainer's targets."""
    given = [
        np.where(m[..., None], r, o)
        for m, r, o in zip(views.masks, rendered, views.rgb, strict=True)
    ]
    filled = inpaint_views(inpainter, given, views.masks, xi, grid=True)
    device = trainer.images.device
    for row, (rs, cs), crop in zip(views.rows, views.windows, filled, strict=True):
        trainer.images[row, rs, cs] = torch.as_tensor(crop, device=device)
    if trainer.depth is not None and views.depth is not None:
        for row, (rs, cs), m, d0, dr in zip(
            views.rows, views.windows, views.masks, views.depth, depths, strict=True
        ):
            target = np.where(m & (d0 > 0), xi * d0 + (1.0 - xi) * dr, d0)
            trainer.depth[row, rs, cs] = torch.as_tensor(target.astype(np.float32), device=device)

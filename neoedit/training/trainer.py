"""Training of the scene field from posed images (batched rays, Adam, live PSNR, checkpoints)."""

from __future__ import annotations

import dataclasses
import math
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from neoedit.cameras.rays import CameraTensors, RayBundle
from neoedit.data import SceneData, load_scene_data
from neoedit.data.downscale import DataConfig
from neoedit.data.scan import scan_record
from neoedit.data.sparse_depth import is_sparse, sparse_pixels
from neoedit.errors import NeoError
from neoedit.fields.patched import PatchedField
from neoedit.fields.radiance import RadianceField, RadianceFieldConfig
from neoedit.fields.room import RoomField
from neoedit.language.training import LanguageTrainConfig, train_language
from neoedit.rendering.occupancy import OccupancyGridConfig, rebuild_grid
from neoedit.rendering.renderer import RenderConfig, render_image, render_rays
from neoedit.rendering.volume import distortion_loss, light_missing, opacity_penalty
from neoedit.scene import Scene, SceneMeta, load_scene, save_scene
from neoedit.storage import find_store, is_store
from neoedit.training.appearance import PhotoAppearance
from neoedit.training.camera_opt import PoseRefinement
from neoedit.training.checks import (
    check_finite_weights,
    check_resume_options,
    check_same_scan,
    check_step_memory,
    fingerprint,
)
from neoedit.training.defaults import (
    AUTO_SPARSITY,
    _grown,
    field_config,
    median_camera_distance,
    scene_box_and_source,
)
from neoedit.training.object_rays import ObjectRays
from neoedit.utils.device import resolve_device
from neoedit.utils.fit import check_finite_loss
from neoedit.utils.optim import field_param_groups, load_optimizer_state, make_adam
from neoedit.utils.progress import make_progress

POSE_WARMUP = 0.2
"""Share of the run before the pose corrections start to learn: a blurry young field gives
them noisy gradients (measured on a 128x96 NEO-Sim scan, photos turned 1.5 deg: with no
warm-up the error grew to 1.8 deg, after 20 % it fell to 0.77, after 40 % to 0.88)."""
SPARSE_POINT_SLACK = 0.03
"""A structure-from-motion point's depth is trusted to this fraction of its distance."""


@dataclass
class TrainConfig:
    max_steps: int = 3000
    """Stop after this many optimisation steps."""
    max_minutes: float | None = None
    """Also stop after this much training time (periodic evaluation excluded)."""
    rays_per_batch: int = 2048
    """Rays per step, drawn at random from all training pixels (a share of them from the
    objects' pixels with ``object_ray_share``)."""
    lr: float = 2e-2
    """Adam learning rate at the start; decays exponentially to lr * lr_final_factor at
    --max-steps or at --max-minutes, whichever comes first. Measured on NEO-Sim removal_1
    with a 2-minute schedule: 2e-2 reaches 30 dB held-out in 60 s, 1e-2 in ~80 s."""
    lr_final_factor: float = 0.1
    weight_decay_mlp: float = 1e-6
    distortion_loss_weight: float = 2e-3
    """Weight of the mip-NeRF 360 distortion loss (suppresses floaters; 0 = off)."""
    sparsity_loss_weight: float = -1.0
    """Weight of a penalty on the opacity of random points in the scene box (pushes
    unobserved space to empty). Negative = automatic, by where the scene box comes from
    (:data:`AUTO_SPARSITY`): 0.1 for a loose cube around the cameras, 0.01 for the visual
    hull of RGBA images, 0 for a box the dataset gives."""
    sparsity_points: int = 4096
    """Random points per step for the sparsity penalty."""
    random_background: bool = True
    """With RGBA data, train over random background colours (transparent pixels stay empty)."""
    depth_loss_weight: float = -1.0
    """Weight of an L1 loss on z-depth [m] where the data has metric depth (RGB-D scans,
    NEO-Sim). Negative = automatic: 0.1 when the data has depth, else 0. Measured on NEO-Sim
    removal_1, 2 min: median depth error 0.7 mm with it vs 14 cm without, and +3 dB PSNR;
    the box queries and the edits need that geometry."""
    sparse_depth_rays: int = 512
    """Where the depth is sparse (under 5 % of the pixels have one: the structure-from-motion
    points ``neo import`` writes for photos), this many rays per step more are drawn from
    the pixels that have depth, so the depth loss sees them every step (0: none)."""
    sparse_opacity_weight: float = 0.05
    """With sparse depth (and ``sparse_depth_rays`` > 0), weight of the share of a
    sparse-depth ray's light that does not end within 3 % of its structure-from-motion
    point, for points inside the scene box: the photos saw a surface there. Without it the
    depth loss was met by faint layers (24 % of the light passed beer_can's floor points;
    the learned background painted the floor from far away) and the label-free teacher
    found no floor (0: off)."""
    object_ray_share: float = 0.0
    """Share of each batch drawn from the pixels of the dataset's objects (instance images
    and ``objects.json``, as NEO-Sim writes; :mod:`neoedit.training.object_rays`): each object
    covers 1-2 % of a tabletop scan's pixels. Measured on NEO-Sim pick_place_1, 600 steps,
    0.3 against 0 (two seeds): mean colour on held-out views off by mug 3.2 / 1.7-6.2,
    soccer ball 0.8 / 11.5-20.7 (0-255); the mug's training pixels 27.4 / 22.8-22.9 dB;
    whole held-out views 31.64 / 31.82-32.53 dB, SSIM 0.922 / 0.942 (the table gets fewer
    rays). Off (0) by default until the edit benchmarks are measured with it."""
    mlp_lr_factor: float = 1.0
    """Learning rate of the MLPs relative to the hash grid's (edits lower it: the MLPs are
    shared by the whole scene, the table entries are local)."""
    eval_every: int = 500
    """Steps between held-out evaluations (0 = never)."""
    eval_views: int = 3
    """Held-out views rendered at each evaluation."""
    photo_appearance: bool = False
    """Learn a colour gain and offset per training photo (exposure, white balance;
    :mod:`neoedit.training.appearance`); renders use the neutral one. Off by default: on
    beer_can (3 minutes, room field) it gave 27.5 dB held out against 28.5 without
    (benchmarks/RESULTS.md); for captures whose exposure visibly changes."""
    pose_refinement: bool = False
    """Refine each training photo's pose with the field (a small rotation and translation
    about its camera centre, :mod:`neoedit.training.camera_opt`); the corrections are saved
    with the scene and every later use of its scan's cameras applies them. For photos posed
    by structure from motion; off by default (NEO-Sim's and a robot's poses are exact)."""
    pose_lr: float = 1e-3
    """Adam learning rate of the pose corrections (rad and m), decaying with the field's."""
    checkpoint_every: int = 1000
    """Steps between checkpoints (0 = only at the end)."""
    seed: int = 0


def psnr(mse: float) -> float:
    return -10.0 * math.log10(max(mse, 1e-12))


class Trainer:
    """Fits ``scene``'s field to ``data``'s training views; :meth:`run` checkpoints to
    ``out`` (``None``: nothing is saved, the scene stays in memory)."""

    def __init__(
        self,
        data: SceneData,
        scene: Scene,
        cfg: TrainConfig,
        out: Path | None,
        device: torch.device,
    ):
        self.data, self.scene, self.cfg, self.out, self.device = data, scene, cfg, out, device
        self.cams = CameraTensors(data.cameras, device)
        train = data.split["train"]
        self.train_idx = torch.as_tensor(train, device=device)
        self.images = torch.as_tensor(data.images[train], device=device)  # (T, H, W, 3) uint8
        # Known opacity (RGBA data) -> train over random background colours, so the field
        # cannot paint the background colour into the scene as fog.
        self.alpha = None
        if (
            cfg.random_background
            and data.alpha is not None
            and not scene.meta.field.learned_background
        ):
            self.alpha = torch.as_tensor(data.alpha[train], device=device)
        # nerfstudio mask_path: pixels whose mask is 0 are left out of the loss
        self.loss_mask = (
            None
            if data.loss_mask is None
            else torch.as_tensor(data.loss_mask[train], device=device)
        )
        self.depth = None
        """Dense z-depth (T,H,W) [m] of the training views (a sensor's, NEO-Sim's), or None."""
        self.sparse_depth: tuple[torch.Tensor, torch.Tensor] | None = None
        """Sparse depth (structure-from-motion points): the (K,3) image, row, column of the
        pixels that have one and their (K,) z-depths; its rays are drawn separately."""
        if cfg.depth_loss_weight > 0 and data.depth_m is not None:
            depth = data.depth_m[train]
            if cfg.sparse_depth_rays > 0 and is_sparse(depth):
                mask = None if data.loss_mask is None else torch.as_tensor(data.loss_mask[train])
                where, values = sparse_pixels(torch.as_tensor(depth), mask)
                self.sparse_depth = (where.to(device), values.to(device))
            else:
                self.depth = torch.as_tensor(depth, device=device)
        self.object_rays = (
            ObjectRays(data, cfg.object_ray_share, device) if cfg.object_ray_share > 0 else None
        )
        self.generator = torch.Generator(device=device).manual_seed(cfg.seed)
        self.extra_losses: list[Callable[[int], torch.Tensor]] = []
        """More loss terms, called with the step number (edits add theirs here)."""
        if not isinstance(scene.field, RadianceField):
            raise NeoError("only an unedited radiance field can be trained from the scan")
        self.optimizer = make_adam(
            field_param_groups(scene.field, cfg.lr, 1.0, cfg.weight_decay_mlp), cfg.lr, device
        )
        self.appearance = (
            PhotoAppearance(len(train), 1e-3, device) if cfg.photo_appearance else None
        )
        self.poses = None
        if cfg.pose_refinement:  # the data's cameras are then as the dataset gives them
            fixes = (scene.meta.scan or {}).get("pose_corrections")  # a resumed run's
            start = None if fixes is None else np.asarray(fixes)[train]
            self.poses = PoseRefinement(len(train), cfg.pose_lr, device, start=start)

    def batch(
        self,
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor | None]:
        """Random training pixels: image index, row, column, target colour (N,3) in [0,1] and
        target z-depth (N,) [m] (0: none; None without depth). With sparse depth,
        ``sparse_depth_rays`` pixels that have one follow the ``rays_per_batch`` random ones
        (they train the depth only, so the colour loss stays that of the batch's pixels).
        With ``object_ray_share``, that share of the ``rays_per_batch`` pixels is drawn from
        the objects' pixels (:class:`~neoedit.training.object_rays.ObjectRays`)."""
        t, h, w = self.images.shape[:3]
        n = self.cfg.rays_per_batch
        img = torch.randint(0, t, (n,), device=self.device, generator=self.generator)
        v = torch.randint(0, h, (n,), device=self.device, generator=self.generator)
        u = torch.randint(0, w, (n,), device=self.device, generator=self.generator)
        if self.object_rays is not None:
            img, v, u = self.object_rays.mix(img, v, u, self.generator)
        depth = None if self.depth is None else self.depth[img, v, u]
        if self.sparse_depth is not None:
            where, values = self.sparse_depth
            pick = torch.randint(
                0,
                len(values),
                (self.cfg.sparse_depth_rays,),
                device=self.device,
                generator=self.generator,
            )
            img, v, u = (torch.cat([a, where[pick, k]]) for k, a in enumerate((img, v, u)))
            depth = torch.cat([torch.zeros(n, device=self.device), values[pick]])
        return img, v, u, self.images[img, v, u].float() / 255.0, depth

    def progress(self, step: int, seconds: float) -> float:
        """How far the run is, in [0, 1]: in steps or, with a time budget, in training time,
        whichever is further along."""
        progress = step / max(self.cfg.max_steps, 1)
        if self.cfg.max_minutes:
            progress = max(progress, seconds / (60.0 * self.cfg.max_minutes))
        return min(progress, 1.0)

    def learning_rate(self, step: int, seconds: float) -> float:
        """Exponential decay from lr to lr * lr_final_factor over the run."""
        return self.cfg.lr * self.cfg.lr_final_factor ** self.progress(step, seconds)

    def step(self, step: int, seconds: float = 0.0) -> float:
        """One optimisation step; ``seconds`` of training so far set the learning rate."""
        field, grid, meta = self.scene.field, self.scene.grid, self.scene.meta
        lr = self.learning_rate(step, seconds)
        self.optimizer.param_groups[0]["lr"] = lr  # hash-grid table
        self.optimizer.param_groups[1]["lr"] = lr * self.cfg.mlp_lr_factor
        if step % meta.grid.update_every == 0:
            grid.update(field.density, step, self.generator)
        img, v, u, target, depth_gt = self.batch()
        rays = self.cams.rays(self.train_idx[img], v, u)
        refine = self.poses is not None and self.progress(step, seconds) >= POSE_WARMUP
        if self.poses is not None:
            rays = self.poses.apply(rays, img) if refine else self.poses.apply_fixed(rays, img)
        background = self.background(step, seconds)
        if self.alpha is not None and isinstance(background, torch.Tensor):
            # the data was composited over the scene background: swap it for a random colour
            transparency = 1.0 - self.alpha[img, v, u].float()[:, None] / 255.0
            random_bg = torch.rand(target.shape, device=self.device, generator=self.generator)
            target = target + transparency * (random_bg - background)
            background = random_bg
        use_grid = grid if step >= meta.grid.warmup_steps else None
        out = render_rays(
            field, use_grid, rays, meta.render, background, jitter=True, generator=self.generator
        )
        n = self.cfg.rays_per_batch  # the random pixels (sparse-depth rays follow them)
        rgb = out["rgb"][:n]
        if self.appearance is not None:
            rgb = self.appearance.apply(rgb, img[:n])
        sq_err = ((rgb - target[:n]) ** 2).mean(-1)
        if self.loss_mask is not None:
            keep = self.loss_mask[img[:n], v[:n], u[:n]].float()
            mse = (sq_err * keep).sum() / keep.sum().clamp_min(1.0)
        else:
            mse = sq_err.mean()
        loss = mse
        if self.cfg.distortion_loss_weight > 0:
            loss = (
                loss
                + self.cfg.distortion_loss_weight
                * distortion_loss(out["weights"], out["s_lo"], out["s_hi"]).mean()
            )
            if "outside_distortion" in out:  # the room's, on its own warped domain
                loss = loss + self.cfg.distortion_loss_weight * out["outside_distortion"].mean()
        if depth_gt is not None:
            valid = depth_gt > 0
            if self.loss_mask is not None:
                valid &= self.loss_mask[img, v, u]
            if valid.any():
                loss = loss + self.depth_loss(out, rays, depth_gt, valid)
        if self.cfg.sparsity_loss_weight > 0:
            aabb = field.aabb
            u = torch.rand(
                self.cfg.sparsity_points, 3, device=self.device, generator=self.generator
            )
            sigma = field.density(aabb[0] + u * (aabb[1] - aabb[0]))
            loss = loss + self.cfg.sparsity_loss_weight * opacity_penalty(sigma)
        for extra in self.extra_losses:
            loss = loss + extra(step)
        if self.appearance is not None:
            loss = loss + self.appearance.penalty()
            self.appearance.zero_grad()
        if self.poses is not None:
            self.poses.zero_grad()
        self.optimizer.zero_grad(set_to_none=True)
        loss.backward()
        self.optimizer.step()
        if self.appearance is not None:
            self.appearance.step()
        if refine and self.poses is not None:
            self.poses.step(lr / self.cfg.lr)
        mse_value, loss_value = torch.stack([mse.detach(), loss.detach()]).tolist()  # one sync
        check_finite_loss(loss_value, step, "training", "--lr or the loss weights")
        return mse_value

    def depth_loss(
        self,
        out: dict[str, torch.Tensor],
        rays: RayBundle,
        depth_gt: torch.Tensor,
        valid: torch.Tensor,
    ) -> torch.Tensor:
        """L1 on z-depth where the data has one; with sparse depth, also the light that
        passes a structure-from-motion point inside the scene box (the surface there must be
        opaque, not a faint layer a learned background paints over)."""
        loss = self.cfg.depth_loss_weight * torch.mean(
            torch.abs(out["depth_z"][valid] - depth_gt[valid])
        )
        if self.sparse_depth is None or self.cfg.sparse_opacity_weight <= 0:
            return loss
        t_end = depth_gt / rays.z_scale
        aabb = self.scene.field.aabb
        point = rays.origins + rays.directions * t_end[:, None]
        keep = valid & ((point >= aabb[0]) & (point <= aabb[1])).all(-1)
        if not keep.any():
            return loss
        t_end = t_end[keep]
        lo, hi = t_end * (1.0 - SPARSE_POINT_SLACK), t_end * (1.0 + SPARSE_POINT_SLACK)
        missing = light_missing(out["weights"][keep], out["t_mid"][keep], lo, hi)
        return loss + self.cfg.sparse_opacity_weight * missing.mean()

    def store_pose_corrections(self) -> None:
        """The learnt pose corrections into the scene's scan record (every camera: the
        held-out ones keep zeros, their poses as the dataset gives them)."""
        if self.poses is None or self.scene.meta.scan is None:
            return
        fixes = np.zeros((len(self.data.cameras), 6))
        fixes[self.train_idx.cpu().numpy()] = self.poses.corrections()
        self.scene.meta.scan["pose_corrections"] = np.round(fixes, 8).tolist()

    def finish_grid(self) -> None:
        """Replace the grid's running maximum (it still remembers densities the field has
        since removed) by the trained field's density: renders then skip that empty space.
        Measured on NEO-Sim: a quarter fewer occupied cells, 2x faster renders."""
        rebuild_grid(self.scene.grid, self.scene.field.density, seed=self.cfg.seed)

    @torch.no_grad()
    def background(self, step: int, seconds: float):
        """The scene's background as this step trains it: a room's environment map alone
        during the room's warm-up (the box learns what it can explain first)."""
        background = self.scene.background
        warmup = self.scene.meta.field.room_field.warmup
        if isinstance(background, RoomField) and self.progress(step, seconds) < warmup:
            return background.environment
        return background

    def evaluate(self, step: int | None = None, seconds: float = 0.0) -> float | None:
        """Held-out PSNR of the views the config names, rendered as step ``step`` trains
        (None: the scene as it renders)."""
        test = self.data.split.get("test", np.empty(0, np.int64))
        if len(test) == 0 or self.cfg.eval_views == 0:
            return None
        chosen = test[
            np.linspace(0, len(test) - 1, min(self.cfg.eval_views, len(test))).round().astype(int)
        ]
        errs = []
        for i in chosen:
            out = render_image(
                self.scene.field,
                self.scene.grid,
                self.cams,
                int(i),
                self.data.height,
                self.data.width,
                self.scene.meta.render,
                self.scene.background if step is None else self.background(step, seconds),
            )
            gt = torch.as_tensor(self.data.images[i], device=self.device).float() / 255.0
            errs.append(float(torch.mean((out["rgb"] - gt) ** 2)))
        return psnr(float(np.mean(errs)))

    def run(self) -> Scene:
        meta, cfg = self.scene.meta, self.cfg
        t_train = t_start = meta.train_seconds
        first = meta.step
        ema = None
        extra = cfg.sparse_depth_rays if self.sparse_depth is not None else 0
        rays_per_step = cfg.rays_per_batch + extra  # every ray rendered, depth-only ones too
        with make_progress() as progress:
            task = progress.add_task("train", total=cfg.max_steps, completed=meta.step, status="")
            for step in range(meta.step, cfg.max_steps):
                t0 = time.perf_counter()
                mse = self.step(step, t_train)
                t_train += time.perf_counter() - t0
                ema = mse if ema is None else 0.9 * ema + 0.1 * mse
                meta.step, meta.train_seconds = step + 1, t_train
                rays_per_s = (step + 1 - first) * rays_per_step / max(t_train - t_start, 1e-9)
                last = step + 1 == cfg.max_steps or (
                    cfg.max_minutes is not None and t_train >= 60 * cfg.max_minutes
                )
                checkpoint = cfg.checkpoint_every and (step + 1) % cfg.checkpoint_every == 0
                if last or checkpoint:
                    check_finite_weights(self.scene.field, step + 1)
                if last:
                    self.finish_grid()
                if (cfg.eval_every and (step + 1) % cfg.eval_every == 0) or last:
                    eval_psnr = self.evaluate(step, t_train)
                    meta.history.append(
                        {
                            "step": step + 1,
                            "seconds": round(t_train, 2),
                            "train_psnr": round(psnr(ema), 3),
                            "eval_psnr": None if eval_psnr is None else round(eval_psnr, 3),
                            "rays_per_s": round(rays_per_s),
                        }
                    )
                progress.update(
                    task,
                    completed=step + 1,
                    status=f"PSNR {psnr(ema):5.2f} dB | {rays_per_s / 1e3:5.1f}k rays/s"
                    + (f" | eval {meta.history[-1]['eval_psnr']} dB" if meta.history else ""),
                )
                if last or checkpoint:
                    self.store_pose_corrections()
                if self.out is not None and (last or checkpoint):
                    save_scene(self.out, self.scene, self.optimizer)
                if last:
                    break
        return self.scene


def train(
    data_path: Path,
    out: Path,
    cfg: TrainConfig,
    field_cfg: RadianceFieldConfig | None = None,
    render_cfg: RenderConfig | None = None,
    grid_cfg: OccupancyGridConfig | None = None,
    device: str = "auto",
    resume: bool = False,
    language: LanguageTrainConfig | None = None,
    data_cfg: DataConfig | None = None,
) -> Scene:
    """Train a scene on a dataset (read as ``data_cfg`` says: downscaled, missing frames
    skipped) and write it to ``out`` (resume continues a saved run).

    Then, when ``language`` is enabled, the language field is trained on the frozen geometry
    (teacher: :func:`~neoedit.language.training.resolve_teacher`) and saved too."""
    dev = resolve_device(device)
    if is_store(Path(out)) or find_store(Path(out)) is not None:
        raise NeoError(
            f"{out} is (in) a scene store: training writes a plain scene folder; train there "
            "and start a store from it with neo plan"
        )
    check_step_memory(
        cfg.rays_per_batch, field_cfg or RadianceFieldConfig(), render_cfg or RenderConfig(), dev
    )
    torch.manual_seed(cfg.seed)
    data = load_scene_data(data_path, data_cfg)
    box, box_source = scene_box_and_source(data)
    if cfg.sparsity_loss_weight < 0:
        cfg = dataclasses.replace(cfg, sparsity_loss_weight=AUTO_SPARSITY[box_source])
    if cfg.depth_loss_weight < 0:
        cfg = dataclasses.replace(cfg, depth_loss_weight=0.1 if data.depth_m is not None else 0.0)
    given_field = field_cfg
    field_cfg = field_config(field_cfg, data, box)
    if resume:
        scene = load_scene(out, dev)
        check_same_scan(scene, data)
        check_resume_options(scene, given_field, render_cfg, grid_cfg)
        if not cfg.pose_refinement and "pose_corrections" in (scene.meta.scan or {}):
            # refined before, not now: the field goes on at the poses it was refined to
            data = dataclasses.replace(data, cameras=scene.scan_cameras()[0])
        scene.meta.train = dataclasses.asdict(cfg)
    else:
        if (Path(out) / "scene.json").exists():
            raise NeoError(
                f"{out} already holds a scene; pass --resume to continue it or choose another --out"
            )
        render_cfg = dataclasses.replace(render_cfg or RenderConfig())
        if render_cfg.near_m < 0:
            render_cfg.near_m = round(0.25 * median_camera_distance(data), 4)
        meta = SceneMeta(
            data_path=str(Path(data_path).resolve()),
            aabb_m=_grown(box),
            background_rgb=list(data.background_rgb or (1.0, 1.0, 1.0)),
            field=field_cfg,
            grid=grid_cfg or OccupancyGridConfig(),
            render=render_cfg,
            train=dataclasses.asdict(cfg),
            scan={**scan_record(data.cameras, data.file_paths, data.split), **fingerprint(data)},
        )
        scene = Scene.create(meta, dev, seed=cfg.seed)
    if resume and scene.meta.edits and language is not None:
        # its scan's images and labels show the scene before the edits: training on them
        # would label the inpainted table "red mug" (each edit updates the language itself)
        raise NeoError(
            f"{out} is an edited version ({len(scene.meta.edits)} edit(s)): its language field "
            "is kept true by its edits and cannot be retrained from the original scan; "
            "retrain the scan's own version, then edit again (or pass --skip-language)"
        )
    if isinstance(scene.field, PatchedField):
        # an edited version: its local patches are trained by their edits, not by the scan
        if cfg.max_steps > scene.meta.step:
            raise NeoError(
                f"{out} is an edited version ({len(scene.meta.patches)} local edit(s)); its "
                "radiance field cannot be trained further (train the original scan, or resume "
                "with no more steps to retrain only the language field)"
            )
        optimizer = None
    else:
        trainer = Trainer(data, scene, cfg, Path(out), dev)
        if resume:
            load_optimizer_state(out, scene.field, trainer.optimizer)
        scene = trainer.run()
        optimizer = trainer.optimizer
    if language is not None:
        if "pose_corrections" in (scene.meta.scan or {}):  # the photos as training placed them
            data = dataclasses.replace(data, cameras=scene.scan_cameras()[0])
        train_language(scene, data, language)
        save_scene(Path(out), scene, optimizer)
    return scene

